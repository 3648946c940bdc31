"""A start the certificate covers (docs/math.md, fact 16): the observer started from the first
image, the certificates of a planned reference ``g_d(t)`` (fixed-level and tube forms, fact 16b)
and of a ramp of the camera-velocity command (fact 16a), all for the ideal continuous loop.

With the paper's start an arm at rest has ``xi(0) = -qd_d(0)``, so ``V(0)`` is mostly kinetic
and lies outside every certified set. With the planned reference of
:class:`dvfc.models.loop.ReferencePlan` (from the estimate ``gbar(0)`` to the scenario's ``g_d``)
and its feedforward ``-Ad_(g_d) V_d``, ``e_c(0) = 0`` and ``u_d(0) = V_d(0) = 0``: ``xi(0) = 0`` and
``V(0) = V_e(0)``. Along the ideal continuous loop (16b.1)
``dV/dt = -x^T N(t)^T K N(t) x + x^T G w`` exactly.

The fixed-level form (16b.3), for isotropic ``K_c`` and block-isotropic ``K_e`` (else ``K_min``):

- the rate of fact 7 at ``(s, theta_bar)`` depends on ``g_d`` only through ``|p_d|`` (16b.2); on
  the path ``|p_d| in [r_lo, r_hi]``, cut into cells of width ``h``, it is at least
  ``min_j k(r_j) - L h / 2`` over the cells' ends ``r_j``,
  ``L = max(k_c) max(w_pc, w_rc)^2 (2 r_hi + 1) / min(D_ce)`` (Weyl after the ``D^-1/2`` scaling),
  re-checked a posteriori at every ``r_j`` as ``lambda_min(Q - (kappa + L h / 2) D) >= 0``;
- ``c = max(V(0), c_inf,path)``, ``c_inf,path = wbar^2 / (4 s kappa_path)``, below the
  self-consistent ``c_max(theta_bar)``: by the first-exit argument ``V(t) <= c`` for all ``t >= 0``
  (``c`` lies strictly above ``b / k`` of the unshrunk rate: the shrink gives it);
- every feature is in the image for all ``t >= 0`` when the regions (16.0) of the balls
  ``B(g_d(tau) p_oi, rho_i(c) + drift_i)`` fit for ``tau`` on a grid of the path, ``drift_i``
  half a grid step of ``(|dp| + |omega| |p_oi|) dtau`` (how far a centre moves between two grid
  points), ``tau = 1`` included (the scenario's ``g_d`` from ``T_r`` on).

The tube form (16b.4, :func:`tube_start`) and the ramp (16a, :func:`ramp_start`) run fact 16a.3's
recursion on a time grid instead of one level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import casadi as cs
import numpy as np

from dvfc.analysis.certify import GainPoint
from dvfc.analysis.envelope import (
    SHRINK,
    THETA_GRID,
    Boxes,
    Design,
    DisturbanceBounds,
    Envelope,
    cone_interval,
    decays,
    design_of,
    desired_features,
    feature_boxes,
    joint_radius,
    kinetic_diagonal,
    rate_margin,
    rates,
    recheck,
    said_for,
    visible_level,
    xi_rates,
)
from dvfc.models.camera import Camera
from dvfc.models.lie import SE3, SO3
from dvfc.models.loop import ClosedLoop, ReferencePlan, quintic, smoothstep

PATH_STEPS = 2000
"""Grid steps in the plan's progress ``tau`` for the visibility check along the path."""

SLACK = 0.005
"""The Lipschitz slack of the path's rate (16b.2), relative to the rate at the scenario's ``g_d``:
the range of ``|p_d|`` is cut into cells fine enough (at most :data:`MAX_CELLS`)."""

MAX_CELLS = 400
"""Most cells of ``|p_d|`` in the fixed-level form (the slack then exceeds :data:`SLACK` on long paths)."""

PLANNED_ASSUMPTIONS = (
    "the ideal continuous loop with the planned reference g_d(t) and its feedforward -Ad_(g_d) V_d "
    "(docs/math.md, fact 16b), qdd_d its total time derivative",
    "V(0) as computed from the scenario's start (the observer's error e_e(0) known or bounded by it)",
    "J_b nonsingular along the run (not implied by V <= c)",
    "K_c isotropic (the rate depends on g_d only through |p_d|)",
    "with the observer from the image, the arm held at rest until that image arrives (g_d stays at the "
    "plan's start meanwhile, a point of the same path)",
)


def image_pose(camera: Camera, features: np.ndarray) -> SE3:
    """A pose ``g = (p, R)`` (camera to object) from one image of the 4+ feature points: OpenCV's
    ``solvePnP`` (``SOLVEPNP_IPPE`` for a planar target, ``SOLVEPNP_ITERATIVE`` otherwise) on the
    centred image coordinates ``f_i = lambda [x/z, y/z]`` (11), with the camera matrix
    ``diag(lambda, lambda, 1)``. ``features`` (2m,)."""
    import cv2  # here, as scipy's rotations: a command's imports without them
    from scipy.spatial.transform import Rotation

    points = np.asarray(camera.points, dtype=float)
    flat = np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-9) < 3
    method = cv2.SOLVEPNP_IPPE if flat else cv2.SOLVEPNP_ITERATIVE
    matrix = np.diag([camera.focal_length, camera.focal_length, 1.0])
    ok, rvec, tvec = cv2.solvePnP(points, np.asarray(features, dtype=float).reshape(-1, 1, 2), matrix, None,
                                  flags=method)  # fmt: skip
    if not ok:
        raise ValueError("the pose estimate from the first image failed (solvePnP)")
    rotation = Rotation.from_rotvec(rvec.ravel()).as_matrix()
    return SE3(cs.DM(tvec.ravel()), SO3(cs.DM(rotation)))


def image_start(loop: ClosedLoop, q0: np.ndarray, qd0: np.ndarray, noise_px: float, seed: int) -> np.ndarray:
    """``s(0)`` with the observer started from the first image: ``gbar(0)`` the pose estimate
    (:func:`image_pose`) of the image at ``t = 0``, with Gaussian pixel noise of standard
    deviation ``noise_px`` (the implementation's, 0 for the ideal loop) drawn from ``seed``."""
    image = cs.Function("f0", [loop.q, loop.t], [loop.features])
    features = np.asarray(image(q0, 0.0)).ravel()
    features = features + np.random.default_rng(seed).normal(0.0, noise_px, features.shape)
    pose = cs.Function("g0", [loop.q, loop.t], [loop.relative_pose.as_matrix()])
    g0 = SE3.from_matrix(pose(q0, 0.0))
    return loop.initial_state(q0, qd0, image_pose(loop.camera, features).inverse() @ g0)


def path_centres(plan: ReferencePlan, points: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``g_d(tau) p_oi`` (K, m, 3) at the plan's progress values ``tau`` (K,)."""
    from scipy.spatial.transform import Rotation

    dp, omega = plan.step
    p0 = np.asarray(cs.DM(plan.start.translation)).ravel()
    r0 = np.asarray(cs.DM(plan.start.rotation.matrix))
    r_d = r0 @ Rotation.from_rotvec(tau[:, None] * omega).as_matrix()
    return np.einsum("kij,mj->kmi", r_d, points) + (p0 + tau[:, None] * dp)[:, None, :]


def path_progress(plan: ReferencePlan, t: np.ndarray) -> np.ndarray:
    """``tau(t)`` (numeric) of the quintic time law."""
    return np.asarray(quintic(plan.fraction(t)))


def path_range(plan: ReferencePlan) -> tuple[float, float]:
    """``[min, max]`` of ``|p_d|`` over the plan (``p_d`` runs along a segment)."""
    dp, _ = plan.step
    p0 = np.asarray(cs.DM(plan.start.translation)).ravel()
    closest = float(np.clip(-(p0 @ dp) / (dp @ dp), 0.0, 1.0)) if dp @ dp > 0 else 0.0
    return float(np.linalg.norm(p0 + closest * dp)), float(max(np.linalg.norm(p0), np.linalg.norm(p0 + dp)))


def _axis_design(design: Design, radius: float) -> Design:
    """The design at the reference ``(radius e_z, I)``: the rate at every ``g_d`` with ``|p_d| = radius``."""
    return design_of(design.point, SE3(cs.DM([0.0, 0.0, radius]), SO3.identity()), design.mass)


@dataclass(frozen=True)
class PathRate:
    """The rate certified along a path at one ``(s, theta_bar)`` (16b.2): ``kappa`` (shrunk, the
    Lipschitz slack subtracted), the cells of ``|p_d|``, the slack and the a posteriori margin."""

    theta_bar: float
    s: float
    kappa: float
    cells: int
    slack: float
    margin: float


def path_rate(design: Design, radii: tuple[float, float], s: float, theta_bar: float) -> PathRate:
    """Fact 16b.2 at ``(s, theta_bar)`` over ``|p_d| in radii`` (module text), re-checked a
    posteriori at every cell end on the literal matrices (:func:`dvfc.analysis.envelope.recheck`)."""
    r_lo, r_hi = radii
    w, k_c = design.point.weights, design.point.k_c
    lipschitz = float(np.max(k_c)) * max(w.w_pc, w.w_rc) ** 2 * (2 * r_hi + 1) / float(
        design.d_diagonal(np.array([theta_bar]))[0].min())
    k_goal = float(rates(design, np.array([s]), np.array([theta_bar]))[0])
    cells = int(min(MAX_CELLS, max(1, math.ceil(lipschitz * (r_hi - r_lo) / (2 * SLACK * max(k_goal, 1e-12))))))
    designs = [_axis_design(design, r) for r in np.linspace(r_lo, r_hi, cells + 1)]
    slack = lipschitz * (r_hi - r_lo) / cells / 2
    kappa = float(min(rates(d, np.array([s]), np.array([theta_bar]))[0] for d in designs)) * (1 - SHRINK) - slack
    margin = min(recheck(d, s, theta_bar, kappa + slack) for d in designs)
    return PathRate(theta_bar, s, kappa, cells, slack, margin)


def planned_start(design: Design, camera: Camera, disturbance: DisturbanceBounds, env: Envelope,
                  plan: ReferencePlan) -> dict:  # fmt: skip
    """The start record of fact 16b's fixed-level form (module text): ``{"V0", "kinetic", "pose",
    "method": "planned", "inside", "level", "visible", ...}``; ``inside`` true means
    ``V(t) <= level`` is certified for all ``t >= 0``. ``theta_bar`` runs up the 1-degree grid from
    the envelope's until ``max(V(0), c_inf,path)`` lies below its self-consistent level (``s``
    the best one at the scenario's ``g_d`` for that ``theta_bar``)."""
    record = {**env.start, "method": "planned", "duration": plan.duration, "hold": plan.hold, "inside": False,
              "level": None,
              "visible": None, "assumptions": list(PLANNED_ASSUMPTIONS)}  # fmt: skip
    if env.rate is None:
        return {**record, "reason": "no rate certified at the scenario's reference"}
    if np.ptp(design.point.k_c) > 0:
        return {**record, "reason": "K_c is not isotropic: the rate along the path is not derived (fact 16b.2)"}
    radii = path_range(plan)
    record["path_radius_m"] = list(radii)
    assert env.theta_bar_deg is not None, "a planned reference is of the paper's loop (refused for the planar one)"
    for decay in decays(design, THETA_GRID[math.radians(env.theta_bar_deg) - 1e-9 <= THETA_GRID]):
        rate = path_rate(design, radii, decay.s, decay.theta_bar)
        if rate.kappa <= 0 or rate.margin < 0:
            continue
        c_inf = disturbance.wbar**2 / (4 * rate.s * rate.kappa)
        level = max(record["V0"], c_inf)
        if level < decay.c_max:
            break
    else:
        return {**record, "reason": "no theta_bar with a positive rate along the path (fact 16b.2) keeps "
                                    "max(V(0), c_inf,path) below its self-consistent level"}  # fmt: skip
    record.update({"inside": True, "level": level, "rate": rate.kappa, "gamma_prime": 1 / math.sqrt(2 * rate.s),
                   "theta_bar_deg": math.degrees(rate.theta_bar), "radius_cells": rate.cells,
                   "lipschitz_slack": rate.slack, "recheck_margin": rate.margin, "ultimate_V_path": c_inf,
                   "invariant_V": decay.c_max})  # fmt: skip
    if camera.has_image:
        boxes = path_boxes(design, camera, plan, level)
        record.update({"visible": bool(boxes.visible), "image_margin_px": boxes.margin_px, "depth_min": boxes.depth_min,
                       "boxes_px": boxes.boxes})  # fmt: skip
    record["tube"] = tube = tube_start(design, camera, disturbance, plan, record["V0"])
    if record["visible"] is False and tube["inside"] and tube.get("visible"):
        record["visible"] = True  # the tube form's regions fit where the fixed level's do not
    record["statement"] = StartStatement.of(record).text
    return record


def path_boxes(design: Design, camera: Camera, plan: ReferencePlan, level: float) -> Boxes:
    """The regions (16.0) at ``level`` along the whole plan: balls about ``g_d(tau) p_oi`` on a grid of
    :data:`PATH_STEPS` steps in ``tau``, each radius grown by half a step's drift of its centre; per
    feature the box enclosing its regions over the whole path."""
    dp, omega = plan.step
    tau = np.linspace(0.0, 1.0, PATH_STEPS + 1)
    drift = (np.linalg.norm(dp) + np.linalg.norm(omega) * np.linalg.norm(camera.points, axis=1)) / PATH_STEPS / 2
    return feature_boxes(design, camera, path_centres(plan, camera.points, tau), level, drift)


def run_regions(loop: ClosedLoop, t: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The regions (16.0) at ``level`` about ``g_d(t) p_oi`` at the output times ``t``: lower and
    upper pixel corners (K, m, 2), to compare with a run's features."""
    w = loop.weights
    radius = joint_radius((w.w_pc, w.w_rc, w.w_pe, w.w_re), True, loop.camera.points, level)
    assert loop.plan is not None, "the regions along a planned reference"
    centres = path_centres(loop.plan, loop.camera.points, path_progress(loop.plan, t))
    ends = [cone_interval(centres, axis, np.broadcast_to(radius, centres.shape[:2])) for axis in (0, 1)]
    scale, centre = loop.camera.focal_length, loop.camera.centre
    return (scale * np.stack([ends[0][0], ends[1][0]], axis=-1) + centre,
            scale * np.stack([ends[0][1], ends[1][1]], axis=-1) + centre)  # fmt: skip


def _planned_says(record: dict, when: str) -> str:
    """What a certified planned start says, over ``when`` (its times, loop and level)."""
    if record["visible"] is True:
        tube = record["tube"]
        margins = f"at least {record['image_margin_px']:.3g} px inside (fixed level)"
        if tube["inside"] and tube.get("visible"):
            margins += f", {tube['image_margin_px']:.3g} px (tube, V(t) <= {tube['level']:.4g})"
        return f"every feature stays in the image {when}, {margins}"
    if record["visible"] is False:
        return f"errors bounded {when}; visibility NOT certified: a region along the path leaves the image"
    return f"errors bounded {when}; no image size given"


RAMP_STEP = 0.01
"""Time step ``h`` (s) of fact 16a's recursion."""

RAMP_S = 60
"""Candidates for ``s_j`` per step (log-spaced in ``[1e-4, min k_xi)``): only tightness depends on them."""

RAMP_GROWTH = 1.05
"""Factor between the trial levels ``Y_j`` of a step (from just above ``Vbar_j``)."""

RAMP_ASSUMPTIONS = (
    "the ideal continuous loop with the ramp u_d = -sigma(t) K_c nu_c (smoothstep; docs/math.md, fact 16a), "
    "qdd_d its total time derivative",
    "V(0) as computed from the scenario's start",
    "J_b nonsingular along the run (not implied by V <= c)",
)


@dataclass(frozen=True)
class RampDesign:
    """``N^T K(sigma) N = A_0 + sigma A_1`` (linear in ``K_c``), on ``(e_c, e_e)`` (``pose``) and
    literally on the whole ``x`` (``full``), at ``R_ec = I`` with ``K_min`` (fact 5)."""

    pose: tuple[np.ndarray, np.ndarray]
    full: tuple[np.ndarray, np.ndarray]

    @staticmethod
    def of(design: Design) -> RampDesign:
        p = design.point
        held = design_of(GainPoint(p.k_xi, np.zeros_like(p.k_c), p.k_e, p.weights), design.reference, design.mass)
        return RampDesign((held.nkn, design.nkn - held.nkn), (held.full[0], design.full[0] - held.full[0]))


def _ramp_rates(design: Design, ramp: RampDesign, sigma: float, s: np.ndarray, y: float
                ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Fact 16a.2's rate ``k(sigma, s, y)`` for each ``s`` (S,) and the diagonal ``D`` it holds
    against (S, n + 12): ``lam_up`` against ``diag(D_M/2, D_y)`` when nonnegative, else ``lam_lo``
    against ``diag(m_lo/2, D_lo)``."""
    nkn = ramp.pose[0] + sigma * ramp.pose[1]
    w_pc, w_rc, w_pe, w_re = design.weights
    third = [w_pc / 2, w_rc / (2 - y / w_rc), w_pe / 2, w_re / (2 - y / w_re)]
    d_y, d_lo = np.repeat(third, 3), np.repeat([w_pc / 2, w_rc / 2, w_pe / 2, w_re / 2], 3)
    eye = np.eye(len(d_y))

    def pose_rate(d: np.ndarray) -> np.ndarray:
        inv = 1 / np.sqrt(d)
        scaled = inv[:, None] * nkn * inv[None, :]
        return np.linalg.eigvalsh(scaled - s[:, None, None] * (design.w * inv**2 * eye))[:, 0]

    upper = np.minimum(xi_rates(design.mass, design.k_xi, s), pose_rate(d_y))
    k = np.where(upper >= 0, upper, pose_rate(d_lo))
    d_m = kinetic_diagonal(design.mass, design.k_xi, s)
    lower = np.full_like(d_m, design.mass.m_lo)
    d = np.where((upper >= 0)[:, None], np.concatenate([d_m / 2, np.broadcast_to(d_y, d_m.shape[:1] + d_y.shape)], 1),
                 np.concatenate([lower / 2, np.broadcast_to(d_lo, lower.shape[:1] + d_lo.shape)], 1))  # fmt: skip
    return k, d


def ramp_start(design: Design, camera: Camera, disturbance: DisturbanceBounds, env: Envelope,
               ramp: float) -> dict:  # fmt: skip
    """Fact 16a.3's recursion from ``Vbar_0 = V(0)`` on the grid ``t_j = j h``: on each step
    ``sigma >= sigma(t_j)``, ``s_j`` minimises ``Vbar_(j+1) = e^(-k h) Vbar_j + (b/k)(1 - e^(-k h))``
    (``b = wbar^2 / (4 s_j)``) and ``Y_j`` is the first trial level above ``max(Vbar_j, Vbar_(j+1))``;
    every step's rate is re-checked a posteriori on the literal matrices. It runs past the ramp
    until ``Vbar`` is within 1% of its own limit (:func:`_settled`). ``V(t) <= c`` for all ``t >= 0``,
    ``c`` the largest ``Vbar_j`` and that limit;
    every feature is in the image from ``t_vis``, the first grid time after which ``Vbar`` stays at
    most the visible level (16.0)."""
    record = {**env.start, "method": "ramp", "ramp": ramp, "inside": False, "level": None, "visible": None,
              "assumptions": list(RAMP_ASSUMPTIONS)}  # fmt: skip
    if env.rate is None:
        return {**record, "reason": "no rate certified at the scenario's reference"}
    wbar2 = disturbance.wbar**2
    ceiling = 2 * min(design.weights[1], design.weights[3])
    s = np.geomspace(1e-4, design.k_xi_min * (1 - 1e-9), RAMP_S)
    ramp_design = RampDesign.of(design)
    bound, times, worst = [record["V0"]], [0.0], math.inf
    t = 0.0
    while True:
        sigma = float(smoothstep(min(t / ramp, 1.0)))
        v, y = bound[-1], bound[-1] * RAMP_GROWTH + 1e-12
        while y < ceiling:
            k, d = _ramp_rates(design, ramp_design, sigma, s, y)
            k = k - SHRINK * np.abs(k)
            b = wbar2 / (4 * s)
            decay = np.exp(-k * RAMP_STEP)
            moving = np.abs(k) > 1e-12
            nxt = np.where(moving, decay * v + b / np.where(moving, k, 1.0) * (1 - decay), v + b * RAMP_STEP)
            j = int(np.argmin(nxt))
            if max(v, nxt[j]) < y:
                break
            y *= RAMP_GROWTH
        else:
            return {**record, "reason": f"the recursion leaves the level 2 min(w_rc, w_re) = {ceiling:.3g} at "
                                        f"t = {t:.3g} s (a rotation of pi allowed)"}  # fmt: skip
        nkn = ramp_design.full[0] + sigma * ramp_design.full[1]
        worst = min(worst, float(rate_margin(nkn[None], design.full[1][None], d[j][None], s[j:j + 1], k[j:j + 1])[0]))
        bound.append(float(nxt[j]))
        t = (len(bound) - 1) * RAMP_STEP
        times.append(t)
        if sigma == 1.0 and _settled(bound[-1], b[j], k[j], y):
            break
    if worst < 0:
        return {**record, "reason": f"an a posteriori check of a step's rate fails ({worst:.3g})"}
    level = float(max(*bound, b[j] / k[j]))
    record.update({"inside": True, "level": level, "ultimate_V_ramp": bound[-1], "recheck_margin": worst,
                   "steps": len(bound) - 1, "step_s": RAMP_STEP})  # fmt: skip
    if camera.has_image:
        assert design.reference is not None, "a ramp is of the paper's loop (refused for the planar one)"
        desired = desired_features(camera, design.reference)
        c_vis = visible_level(design, camera, desired)
        above = np.flatnonzero(np.asarray(bound) > c_vis)
        record["visible_level"] = c_vis
        record["visible_boxes_px"] = feature_boxes(design, camera, desired, c_vis).boxes
        record["visible"] = bool(level <= c_vis)
        if not above.size:
            record["visible_from_s"] = 0.0
        elif above[-1] + 1 < len(bound):
            record["visible_from_s"] = times[above[-1] + 1]
        else:
            record["visible_from_s"] = None
        if not record["visible"]:
            record["reason"] = _ramp_visibility(record)
    record["statement"] = StartStatement.of(record).text
    return record


def _ramp_visibility(record: dict) -> str:
    """Why a ramp's record does not certify visibility from ``t = 0``, and from when it does
    (``visible_from_s``); with ``until_s`` (:func:`until_integral`) a time past it is not certified."""
    since, until = record["visible_from_s"], record.get("until_s")
    if since is not None:
        when = f"certified from t = {since:.3g} s"
    elif until is None:
        when = "not certified at all"
    else:
        when = f"not certified up to T_I = {until:.4g} s (integral action engages), and not certified after T_I"
    return (f"visibility NOT certified from t = 0: the bound on V reaches {record['level']:.4g} above the visible "
            f"level {record['visible_level']:.4g} of fact 16.0 (a sublevel set about the fixed g_d); {when}")


def until_integral(start: dict, t_i: float) -> dict:
    """The start record of a design without ``K_I`` as the statement of the same design with it,
    up to ``t_i`` (``integral_start``; docs/math.md, fact 20.6): ``z_I`` stays 0 until then, so the
    two loops are one ODE from one state and every bound of the start holds for ``0 <= t <= t_i``,
    and nothing after: a ramp's visibility from a time past ``t_i`` is not certified
    (``visible_from_s`` None), every time the statement names lies in ``[0, t_i]``. ``inside`` false
    (with the reason) when the start is not certified or ``t_i = 0``."""
    record = {**start, "until_s": t_i}
    if t_i <= 0:
        reason = ("integral action from t = 0 (integral_start = 0): no time before z_I moves, so the start of the "
                  "design without K_I says nothing of this one")  # fmt: skip
        return {**record, "inside": False, "level": None, "reason": reason}
    if not start["inside"]:
        return record
    if (record.get("visible_from_s") or 0.0) > t_i:  # visibility only after T_I: not certified up to it
        record["visible_from_s"] = None
        record["reason"] = _ramp_visibility(record)
    record["statement"] = StartStatement.of(record).text
    return record


def for_plant(start: dict, plant: str) -> dict:
    """The start record as computed for ``plant`` (:data:`dvfc.analysis.envelope.WITHOUT_FRICTION`:
    the ideal continuous loop's, when the scenario's plant has friction), its statement saying so."""
    record = {**start, "plant": plant}
    if "statement" in record:
        record["statement"] = StartStatement.of(record).text
    return record


@dataclass(frozen=True)
class StartStatement:
    """What a start record states (docs/math.md, facts 16, 20.6), read from it by :meth:`of`: of which
    loop and plant, over which times and, when the start is certified, what. The record's
    ``statement`` is its :attr:`text` and a statements table names its :attr:`about`: every printer
    reads the loop and the plant from here."""

    loop: str
    """The ideal continuous loop with the start's reference."""
    plant: str | None
    """The plant the statement is computed for when the scenario's is another (friction), else None."""
    until_s: float | None
    """The statement holds for ``0 <= t <= until_s`` (fact 20.6), or (None) for all ``t >= 0``."""
    says: str | None = None
    """What is certified over :attr:`span`, every time it names within it; None: not certified."""

    @staticmethod
    def of(record: dict) -> StartStatement:
        """The statement of a start record (``method``, ``inside`` and, when inside, its level)."""
        method = record.get("method", "constant")
        scope = StartStatement(_loop(record), record.get("plant"), record.get("until_s"))
        if not record["inside"]:
            return scope
        when = f"{scope.span} ({scope.loop}: V(t) <= {record['level']:.4g}, V(0) = {record['V0']:.3g})"
        says = {"planned": _planned_says, "ramp": _ramp_says, "constant": _constant_says}[method]
        return replace(scope, says=says(record, when))

    @property
    def span(self) -> str:
        """Over which times it holds: every ``t >= 0``, or up to ``until_s``."""
        until = self.until_s
        return "for all t >= 0" if until is None else f"for 0 <= t <= {until:.4g} s"

    @property
    def about(self) -> str:
        """The loop, the plant and the times, as a statements table's row names what it is about."""
        plant = [] if self.plant is None else [f"for {self.plant}"]
        return ", ".join([self.loop, *plant, self.span.removeprefix("for ")])

    @property
    def text(self) -> str:
        """The sentence of a certified start: for its plant, until integral action engages, what it says."""
        assert self.says is not None, "the sentence of a certified start"
        told = self.says
        if self.until_s is not None:
            told = (f"until integral action engages at t = {self.until_s:.4g} s (z_I = 0 before, so the run is "
                    f"the design's without K_I, fact 20.6): {told}")  # fmt: skip
        return said_for(self.plant, told)


def _loop(record: dict) -> str:
    """The loop a start record is about: the ideal continuous loop with its reference."""
    method = record.get("method", "constant")
    if method == "planned":
        return f"ideal continuous loop with the planned reference over {record['duration']:g} s"
    if method == "ramp":
        return f"ideal continuous loop with a {record['ramp']:g} s ramp of u_d"
    return "ideal continuous loop"


def _constant_says(record: dict, when: str) -> str:
    """What a start inside fact 7's certified set says, over ``when``."""
    return f"errors bounded {when}, by fact 7 from a start inside the certified set"


def _settled(v: float, b: float, k: float, y: float) -> bool:
    """Whether a recursion can stop at ``Vbar = v`` with the rate ``k > 0``, ``b = wbar^2 / (4 s)``,
    valid on ``{V <= y}``: ``v`` within 1% of its limit ``b / k``, both below ``y``. Fact 7's first
    exit then keeps ``V <= max(v, b / k)`` for all later times."""
    return k > 0 and abs(v - b / k) <= 0.01 * b / k and max(v, b / k) < y


def _ramp_says(record: dict, when: str) -> str:
    """What a certified ramp says, over ``when`` (its times, loop and level)."""
    if record["visible"] is True:
        return f"every feature stays in the image {when}"
    if record["visible"] is False:
        return f"errors bounded {when}; {record['reason']}"
    return f"errors bounded {when}; no image size given"


def _segment_radii(plan: ReferencePlan, tau: tuple[float, float]) -> tuple[float, float]:
    """``[min, max]`` of ``|p_d|`` for the plan's progress in ``[tau_0, tau_1]`` (a piece of a segment)."""
    dp, _ = plan.step
    p0 = np.asarray(cs.DM(plan.start.translation)).ravel()
    ends = [float(np.linalg.norm(p0 + a * dp)) for a in tau]
    closest = float(np.clip(-(p0 @ dp) / (dp @ dp), *tau)) if dp @ dp > 0 else tau[0]
    return min(*ends, float(np.linalg.norm(p0 + closest * dp))), max(ends)


def tube_start(design: Design, camera: Camera, disturbance: DisturbanceBounds, plan: ReferencePlan,
               v0: float) -> dict:  # fmt: skip
    """Fact 16b.4, the tube form: fact 16a.3's recursion at ``sigma = 1`` with, on each step, the rate
    of (16b.2) over the step's range of ``|p_d|`` (the smaller of its ends' rates, upper branch only,
    minus the Lipschitz slack ``L (r_hi - r_lo) / 2``, re-checked a posteriori at both ends), and
    the regions (16.0) of ``B(g_d(tau_j) p_oi, rho_i(max(Vbar_j, Vbar_(j+1))) + drift_j)``,
    ``drift_j = (tau_(j+1) - tau_j)(|dp| + |omega| |p_oi|)``. Runs past the plan until ``Vbar`` is
    within 1% of its limit (:func:`_settled`); the level is the largest ``Vbar_j`` and that limit.
    Returns ``{"inside", "level", "visible", "image_margin_px", ...}``."""
    wbar2 = disturbance.wbar**2
    ceiling = 2 * min(design.weights[1], design.weights[3])
    s = np.geomspace(1e-4, design.k_xi_min * (1 - 1e-9), RAMP_S)
    dp, omega = plan.step
    spread = np.linalg.norm(dp) + np.linalg.norm(omega) * np.linalg.norm(camera.points, axis=1)
    w, k_c = design.point.weights, design.point.k_c
    cache: dict[float, tuple[Design, RampDesign]] = {}

    def at(radius: float) -> tuple[Design, RampDesign]:
        if radius not in cache:
            d = _axis_design(design, radius)
            cache[radius] = d, RampDesign((d.nkn, np.zeros_like(d.nkn)), (d.full[0], np.zeros_like(d.full[0])))
        return cache[radius]

    bound, worst, margin, depth = [v0], math.inf, math.inf, math.inf
    while True:
        t0 = (len(bound) - 1) * RAMP_STEP
        tau = tuple(float(v) for v in path_progress(plan, np.array([t0, t0 + RAMP_STEP])))
        radii = _segment_radii(plan, (tau[0], tau[1]))
        v, y = bound[-1], bound[-1] * RAMP_GROWTH + 1e-12
        while y < ceiling:
            ends = [at(r) for r in radii]
            d_min = min(w.w_pc / 2, w.w_rc / (2 - y / w.w_rc), w.w_pe / 2, w.w_re / (2 - y / w.w_re))
            lipschitz = float(np.max(k_c)) * max(w.w_pc, w.w_rc) ** 2 * (2 * radii[1] + 1) / d_min
            slack = lipschitz * (radii[1] - radii[0]) / 2
            rated = [_ramp_rates(d, r, 1.0, s, y) for d, r in ends]
            upper = np.minimum(*[np.where(k >= 0, k, -np.inf) for k, _ in rated])
            k = upper - SHRINK * np.abs(upper) - slack
            usable = np.where(k > 0, k, 1.0)  # a step needs a positive rate here (upper branch only)
            decay = np.exp(-usable * RAMP_STEP)
            nxt = np.where(k > 0, decay * v + wbar2 / (4 * s) / usable * (1 - decay), np.inf)
            j = int(np.argmin(nxt))
            if max(v, nxt[j]) < y:
                break
            y *= RAMP_GROWTH
        else:
            return {"inside": False, "reason": f"the tube leaves the level {ceiling:.3g} at t = {t0:.3g} s"}
        for (d, r), (_, dd) in zip(ends, rated, strict=True):
            nkn = r.full[0]
            worst = min(worst, float(rate_margin(nkn[None], d.full[1][None], dd[j][None], s[j:j + 1],
                                                 k[j:j + 1] + slack)[0]))  # fmt: skip
        bound.append(float(nxt[j]))
        if camera.has_image:
            boxes = feature_boxes(design, camera, path_centres(plan, camera.points, np.array([tau[0]])),
                                  max(v, nxt[j]), (tau[1] - tau[0]) * spread)  # fmt: skip
            depth = min(depth, boxes.depth_min)
            margin = min(margin, -math.inf if boxes.margin_px is None else boxes.margin_px)
        if tau[0] >= 1.0 and _settled(bound[-1], wbar2 / (4 * s[j]), k[j], y):
            break
    level = float(max(*bound, wbar2 / (4 * s[j] * k[j])))
    if camera.has_image:  # from the last step on: the goal's regions at the final level
        boxes = feature_boxes(design, camera, path_centres(plan, camera.points, np.array([1.0])), level)
        depth = min(depth, boxes.depth_min)
        margin = min(margin, -math.inf if boxes.margin_px is None else boxes.margin_px)
    record: dict[str, Any] = {"inside": worst >= 0, "level": level, "recheck_margin": worst, "steps": len(bound) - 1,
              "step_s": RAMP_STEP, "ultimate_V": bound[-1]}  # fmt: skip
    if worst < 0:
        record["reason"] = f"an a posteriori check of a step's rate fails ({worst:.3g})"
    if camera.has_image:
        record.update({"visible": bool(worst >= 0 and depth > 0 and margin >= 0), "image_margin_px": margin,
                       "depth_min": depth})  # fmt: skip
    return record
