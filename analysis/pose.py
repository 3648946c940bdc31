"""Where everything is at the start: the camera's pose ``g_wc(q0)``, the target's ``g_wo(0)``,
the relative pose ``g(0) = g_wc^-1 g_wo`` (10) and the feature points in the image (11),
(14), for placing a target in view before any simulation; and what a run of the scenario costs to integrate,
before a long job makes many of them."""

from __future__ import annotations

import time
from dataclasses import replace

import casadi as cs
import numpy as np

from dvfc.analysis.ik import Configuration
from dvfc.analysis.simulate import Settings
from dvfc.models.loop import ClosedLoop
from dvfc.models.robot import JointLimits

TIMED_HORIZON = 0.5
"""Seconds of the scenario's run :func:`integration_cost` makes and times (at most its duration)."""


def xyz_rpy(matrix: np.ndarray) -> dict[str, list[float]]:
    """A 4x4 pose as ``xyz`` and ``rpy`` (URDF convention ``Rz(yaw) Ry(pitch) Rx(roll)``:
    SciPy's extrinsic ``"xyz"``)."""
    from scipy.spatial.transform import Rotation

    m = np.asarray(matrix, dtype=float)
    return {"xyz": m[:3, 3].tolist(), "rpy": Rotation.from_matrix(m[:3, :3]).as_euler("xyz").tolist()}


def initial_view(loop: ClosedLoop, s0: np.ndarray) -> dict:
    """The poses at ``t = 0`` and each feature point's image position and depth: in pixels
    from the image's top-left corner when the camera's image size is known (with whether it
    is inside), otherwise about the principal point."""
    cam, g = loop.camera, loop.relative_pose
    outputs = [loop.robot.camera_pose.as_matrix(), loop.target.pose(loop.t).as_matrix(), g.as_matrix(),
               cam.project(g), cam.depths(g)]  # fmt: skip
    g_wc, g_wo, g0, f, depth = (np.asarray(v) for v in cs.Function("view", [loop.t, loop.state], outputs)(0.0, s0))
    xy, depth = f.reshape(-1, 2), depth.ravel()
    outside = set(cam.outside_image(f).tolist()) if cam.has_image else set()
    pixels = xy + cam.centre if cam.has_image else xy
    features = [
        {"point": i, "image": pixels[i].tolist(), "depth": float(depth[i]),
         "in_view": bool(depth[i] > 0 and i not in outside)}
        for i in range(cam.m)
    ]  # fmt: skip
    return {
        "camera_in_world": xyz_rpy(g_wc),
        "target_in_world": xyz_rpy(g_wo),
        "target_in_camera": xyz_rpy(g0),
        "image_coordinates": "pixels from the top-left corner" if cam.has_image else "pixels about the principal point",
        "image_size": [cam.width, cam.height] if cam.has_image else None,
        "features": features,
    }


def solution_record(config: Configuration, limits: JointLimits) -> dict:
    """A configuration of :func:`dvfc.analysis.ik.solve_configuration` for ``dvfc pose --solve``:
    ``q0`` (every digit, so that pasting it gives the same pose), the conditioning of ``J_b``
    there, the pose error left and, per joint, whether ``q0`` lies within the URDF's position
    limits (``limits``; no limit: within)."""
    q = np.asarray(config.q, dtype=float)
    within = (q >= limits.lower) & (q <= limits.upper)
    return {
        "q0": q.tolist(),
        "q0_toml": "q0 = [" + ", ".join(repr(float(x)) for x in q) + "]",
        "sigma_min_body_jacobian": config.sigma_min,
        "condition_number": config.condition,
        "position_error_m": config.position_error,
        "rotation_error_rad": config.rotation_error,
        "within_position_limits": bool(within.all()),
        "joints_within_limits": within.tolist(),
    }


def integration_cost(loop: ClosedLoop, s0: np.ndarray, settings: Settings) -> dict:
    """How the scenario's run as implemented is integrated and what one costs, measured: the loop as implemented
    (:func:`dvfc.analysis.sampled.as_implemented`) built, its RK4 substeps chosen from ``s0`` where they are
    ``"auto"`` (the choice a campaign's runs share), then its first :data:`TIMED_HORIZON` seconds run and timed;
    ``wall_time_per_run`` is that time scaled to the scenario's duration (building and compiling left out: a
    first run on an empty compile cache costs that too). ``integrator``: the sampled loop's choice
    (:class:`~dvfc.analysis.implementation.SubstepChoice`, with its text), or CVODES at the run's tolerances."""
    from dvfc.analysis.sampled import SampledSimulator, as_implemented

    horizon = min(TIMED_HORIZON, settings.duration)
    simulator = as_implemented(loop, replace(settings, duration=horizon))
    if isinstance(simulator, SampledSimulator):
        choice = simulator.settle(s0).substeps
        assert choice is not None, "settled"
        integrator = {**choice.as_dict(), "text": choice.text}
    else:
        integrator = {"text": f"CVODES (BDF) at rtol {settings.rtol:g}, atol {settings.atol:g}"}
    start = time.perf_counter()
    run = simulator.run(s0)
    elapsed = time.perf_counter() - start
    return {"integrator": integrator, "timed_horizon": horizon, "timed_status": str(run.status),
            "duration": settings.duration, "wall_time_per_run": elapsed * settings.duration / max(run.t[-1], 1e-12),
            "basis": f"measured on this machine: the first {horizon:g} s of the run as implemented, scaled to its "
                     f"{settings.duration:g} s (building and compiling left out)"}  # fmt: skip
