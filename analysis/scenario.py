"""Scenario files (TOML): read, validated (:mod:`dvfc.analysis.schema`, errors worded by
:mod:`dvfc.analysis.messages`) and built into the models they describe.

Every problem is reported as one :class:`ScenarioError` line that names the field, e.g.
``gains.k_c: expected 6 entries, got 5``.
"""

from __future__ import annotations

import math
import tomllib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TypeVar

import casadi as cs
import numpy as np
from pydantic import ValidationError

from dvfc.analysis.calibration import CalibrationError, read_calibration
from dvfc.analysis.certify import GainPoint
from dvfc.analysis.defaults import DEFAULT_SCENARIO
from dvfc.analysis.ik import Configuration, NoConfigurationError, solve_configuration
from dvfc.analysis.implementation import Implementation
from dvfc.analysis.messages import one_line
from dvfc.analysis.schema import (
    CameraSection,
    DisturbancesSection,
    FrictionModel,
    GainsSection,
    PlantSection,
    RobotSection,
    Scenario,
    ScenarioError,
)
from dvfc.analysis.simulate import Settings
from dvfc.analysis.start import image_start
from dvfc.models.camera import Camera
from dvfc.models.disturbance import BandLimitedNoise, Disturbance, Sine, Step
from dvfc.models.errors import PlantErrors
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop, Gains, Mode, PlantWeights, ReferencePlan, Weights
from dvfc.models.planar import TASK, PlanarLoop
from dvfc.models.robot import (
    BUILTIN_ARMATURE,
    BUILTIN_CAMERA_FRAME,
    ChainError,
    Payload,
    Robot,
    RobotModelError,
    builtin_urdf,
    joint_dynamics,
)
from dvfc.models.target import TargetMotion

__all__ = ["DEFAULT_SCENARIO", "Scenario", "ScenarioError", "build", "gain_point", "load"]


def load(path: str | Path) -> tuple[Scenario, Path]:
    """Read and validate a scenario file; returns it with its directory (for relative paths)."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read scenario file ({exc.__class__.__name__}: {exc})") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    try:
        return Scenario.model_validate(data), path.parent
    except ValidationError as exc:
        raise ScenarioError(one_line(exc, Scenario, sections=True)) from exc


def _vector(value: float | list[float], n: int, where: str) -> np.ndarray:
    if isinstance(value, list):
        if len(value) != n:
            raise ScenarioError(f"{where}: expected {n} entries, got {len(value)}")
        return np.asarray(value, dtype=float)
    return np.full(n, float(value))


def _xyz(values: list[float]) -> tuple[float, float, float]:
    x, y, z = values
    return x, y, z


def _check_position_limits(robot: Robot, q0: np.ndarray) -> None:
    """Refuse a ``q0`` outside a joint's position limits in the URDF (a continuous joint has none)."""
    lower, upper = robot.limits.lower, robot.limits.upper
    outside = np.flatnonzero((q0 < lower) | (q0 > upper))
    if outside.size:
        i = int(outside[0])
        raise ScenarioError(
            f"robot.q0[{i}]: {q0[i]:.6g} is outside the limits [{lower[i]:.6g}, {upper[i]:.6g}] of joint {i + 1} "
            f"({robot.joints[i]}) in the URDF"
        )


ARMS = 16
"""Arms and cameras kept built (the least recently used dropped): scenarios that differ only in numbers (a
synthesis' candidates, the gains of a sweep) get the same :class:`Robot` and :class:`Camera`, so that the
functions built on them (their symbolic structure, compiled libraries and linearisations, each keyed by the
objects' identity) are built once per arm, as the campaign's draws share them."""

_Built = TypeVar("_Built", Robot, Camera)
_built: OrderedDict[tuple, Robot | Camera] = OrderedDict()


def _interned(key: tuple, make: Callable[[], _Built]) -> _Built:
    """The object built for ``key`` before, else ``make()`` kept for it (at most :data:`ARMS` of them)."""
    if key in _built:
        _built.move_to_end(key)
    else:
        _built[key] = make()
        if len(_built) > ARMS:
            _built.popitem(last=False)
    return _built[key]  # type: ignore[return-value]


def build_robot(section: RobotSection, base: Path) -> Robot:
    """The arm of a scenario (built-in name or URDF path relative to the scenario file), one object for
    each URDF text, camera link, mount and armature (:func:`_interned`)."""
    try:
        if section.model is not None:
            urdf = builtin_urdf(section.model)
            frame = section.camera_frame or BUILTIN_CAMERA_FRAME[section.model]
            armature = BUILTIN_ARMATURE.get(section.model, ())
        else:
            assert section.urdf is not None, "a urdf without a model (RobotSection)"
            urdf = (base / section.urdf).resolve()
            if not urdf.is_file():
                raise ScenarioError(f"robot.urdf: no such file: {urdf}")
            if section.camera_frame is None:
                raise ScenarioError("robot.camera_frame: required with robot.urdf")
            frame = section.camera_frame
            armature = ()
        if section.armature is not None:
            armature = tuple(section.armature)
        key = ("robot", str(urdf), urdf.read_bytes(), frame, section.mount.model_dump_json(), armature)
        return _interned(key, lambda: Robot(urdf, frame, section.mount.se3(), armature))
    except RobotModelError as exc:
        field = "robot.model" if "unknown robot model" in str(exc) else "robot.urdf"
        if isinstance(exc, ChainError):
            field = "robot.camera_frame"
        elif str(exc).startswith("armature"):
            field = "robot"
        raise ScenarioError(f"{field}: {exc}") from exc


def disturbances(section: DisturbancesSection, n: int) -> list[Disturbance]:
    """The joint-torque disturbance components."""
    out: list[Disturbance] = []
    for i, d in enumerate(section.torque):
        where = f"disturbance.torque[{i}]"
        if d.kind == "step":
            assert d.amplitude is not None, "the fields of its kind (DisturbanceSection)"
            out.append(Step(_vector(d.amplitude, n, f"{where}.amplitude"), d.start))
        elif d.kind == "sine":
            assert d.amplitude is not None and d.frequency is not None, "the fields of its kind (DisturbanceSection)"
            out.append(Sine(_vector(d.amplitude, n, f"{where}.amplitude"), d.frequency, d.phase))
        else:
            assert d.rms is not None and d.bandwidth is not None, "the fields of its kind (DisturbanceSection)"
            out.append(BandLimitedNoise(_vector(d.rms, n, f"{where}.rms"), d.bandwidth, d.seed))
    return out


PLANAR_TILT_TOL = 1e-6
"""Largest angle (rad) between the camera's optical axis and the downward vertical, and largest
rate of that axis or of the camera's height per joint, that the planar loop accepts: (P12)
needs the camera looking straight down at a constant height."""


def _check_planar(scenario: Scenario, robot: Robot, q0: np.ndarray) -> None:
    """The reduced loop's assumptions (:mod:`dvfc.models.planar`): a target that does not rotate and
    moves in a horizontal plane (circle normal along +-z), and a camera looking straight down
    at ``q0`` whose optical axis and height no joint changes (every joint axis vertical). Then
    it keeps looking down at a constant height along any run (P12): a revolute joint about a
    vertical axis keeps the axes after it vertical, so the check at ``q0`` holds at every ``q``."""
    motion = scenario.target.motion
    if motion.kind == "circle_spin" or motion.spin_rate != 0:
        raise ScenarioError("target.motion.kind: the planar loop needs a target that does not rotate")
    normal = np.asarray(motion.normal) / np.linalg.norm(motion.normal)
    if motion.kind == "circle" and np.linalg.norm(normal[:2]) > PLANAR_TILT_TOL:
        raise ScenarioError(
            "target.motion.normal: the planar loop needs motion in a horizontal plane (normal [0, 0, 1] or "
            f"[0, 0, -1]); this one is {math.degrees(math.asin(min(1.0, float(np.linalg.norm(normal[:2]))))):.3g} deg "
            "from vertical"
        )
    pose = robot.camera_pose
    axis, height = pose.rotation.matrix[:, 2], pose.translation[2]
    geometry = cs.Function("geometry", [robot.q], [axis, cs.jacobian(cs.vertcat(axis, height), robot.q)])
    axis0, rates = (np.asarray(v) for v in geometry(q0))
    tilt = math.acos(max(-1.0, min(1.0, -float(axis0.ravel()[2]))))
    if tilt > PLANAR_TILT_TOL:
        raise ScenarioError(
            f"robot: the planar loop needs the camera looking straight down (P12); at q0 its optical axis is "
            f"{math.degrees(tilt):.3g} deg from the downward vertical"
        )
    moving = [robot.joints[j] for j in np.flatnonzero(np.abs(rates).max(axis=0) > PLANAR_TILT_TOL)]
    if moving:
        raise ScenarioError(
            f"robot: the planar loop needs every joint axis vertical (P12: the camera keeps looking down at a "
            f"constant height); joint(s) {', '.join(moving)} tilt the camera or change its height"
        )
    if any(scenario.reference.rpy):
        raise ScenarioError("reference.rpy: the planar loop controls the position only; give [0, 0, 0]")
    if any(scenario.observer.error_rpy):
        raise ScenarioError("observer.error_rpy: the planar loop estimates the position only; give [0, 0, 0]")
    if robot.n < TASK:
        raise ScenarioError(f"robot: the planar loop needs at least {TASK} joints, the arm has {robot.n}")


def auto_q0(scenario: Scenario, robot: Robot, asked_by: str = 'robot.q0: "auto"') -> Configuration:
    """The configuration of :func:`dvfc.analysis.ik.solve_configuration` for the camera at the
    reference pose relative to the target's ``g_wo(0)`` (given in the world frame); ``asked_by``
    begins the one line of a :class:`ScenarioError` (the field or option that asked)."""
    t = scenario.target
    if t.relative_to_camera is not None:
        raise ScenarioError(
            f"{asked_by} needs the target placed in the world (target.xyz, target.rpy); "
            "target.relative_to_camera follows the camera wherever q0 puts it"
        )
    goal = SE3.from_xyz_rpy(t.xyz, t.rpy) @ scenario.reference.se3().inverse()
    try:
        return solve_configuration(robot, np.asarray(cs.DM(goal.as_matrix())))
    except NoConfigurationError as exc:
        raise ScenarioError(f"{asked_by}: {exc}") from exc


def build(
    scenario: Scenario, base: Path, *, mode: Mode | None = None, check_view: bool = True
) -> tuple[ClosedLoop, np.ndarray, Settings]:
    """The closed loop (the paper's, or the reduced planar one), its initial state and the
    simulation settings of a scenario; ``check_view`` refuses a start with a feature behind
    the camera or outside the image, or a singular arm (:func:`dvfc.analysis.pose` shows them)."""
    robot = build_robot(scenario.robot, base)
    n = robot.n
    q0 = auto_q0(scenario, robot).q if scenario.robot.q0 == "auto" else _vector(scenario.robot.q0, n, "robot.q0")
    _check_position_limits(robot, q0)
    if scenario.loop == "planar":
        _check_planar(scenario, robot, q0)
    qd0 = _vector(scenario.robot.qd0 or 0.0, n, "robot.qd0")
    t = scenario.target
    m = t.motion
    camera_at_q0 = SE3.from_matrix(cs.Function("g_wc", [robot.q], [robot.camera_pose.as_matrix()])(q0))
    target = TargetMotion(t.start(camera_at_q0), m.radius, m.period, _xyz(m.normal), _xyz(m.spin_axis), m.spin_rate)
    point = gain_point(scenario, n)
    if scenario.synthesized_from is not None:  # the design before synthesis: refused here, not in the report
        gain_point(scenario, n, scenario.synthesized_from.gains, "synthesized_from.gains")
    kind = PlanarLoop if scenario.loop == "planar" else ClosedLoop
    loop = kind(
        robot=robot,
        camera=build_camera(scenario.camera, base, np.asarray(t.points, dtype=float)),
        target=target,
        reference=scenario.reference.se3(),
        weights=point.weights,
        gains=Gains(point.k_xi, point.k_c, point.k_e, point.k_i),
        mode=mode or _implementation_mode(scenario),
        disturbances=disturbances(scenario.disturbance, n),
        performance=point.plant,
        compensation=compensation(scenario, robot),
        integral_start=integral_start(scenario),
    )
    s0 = _initial_state(scenario, loop, q0, qd0)
    if scenario.start.reference == "planned":
        loop = replace(loop, plan=ReferencePlan(_estimate(loop, s0), loop.reference, scenario.start.duration,
                                                _first_image(scenario)))
    loop = replace(loop, ramp=scenario.start.ramp)
    if check_view:
        _check_initial_view(loop, s0, scenario.simulation.sigma_min)
        if scenario.loop == "paper":
            _check_reference_view(loop.camera, loop.reference)
    sim = scenario.simulation
    settings = Settings(
        duration=sim.duration,
        dt=sim.dt,
        rtol=sim.rtol,
        atol=sim.atol,
        jit=sim.jit,
        time_budget=sim.time_budget,
        sigma_min=sim.sigma_min,
        implementation=_implementation(scenario, loop.mode),
        plant=_plant(scenario.plant, robot),
        errors=plant_errors(scenario, loop),
    )
    return loop, s0, settings


def build_camera(section: CameraSection, base: Path, points: np.ndarray) -> Camera:
    """The controller's camera: from ``[camera]``, or its ``calibration`` file (relative to the
    scenario's folder), which must agree with ``width`` and ``height`` when they are given; one object
    for each set of values (:func:`_interned`)."""
    camera = _camera(section, base, points)
    key = ("camera", camera.focal_length, camera.points.tobytes(), camera.points.shape, camera.width, camera.height,
           camera.principal_point, camera.aspect, camera.distortion)  # fmt: skip
    return _interned(key, lambda: camera)


def _camera(section: CameraSection, base: Path, points: np.ndarray) -> Camera:
    """:func:`build_camera` before it is interned."""
    if section.calibration is None:
        return section.camera(points)
    path = base / section.calibration
    try:
        c = read_calibration(path)
    except CalibrationError as exc:
        raise ScenarioError(f"camera.calibration: {exc}") from exc
    for name, value in (("width", c.width), ("height", c.height)):
        given = getattr(section, name)
        if given is not None and given != value:
            raise ScenarioError(f"camera.{name}: {given:g} px, but the calibration file {path.name} says {value}")
    return Camera(c.fx, points, c.width, c.height, c.principal_point, c.fy / c.fx, c.distortion)


def plant_errors(scenario: Scenario, loop: ClosedLoop) -> PlantErrors | None:
    """What the controller's model gets wrong (``[plant]`` mount, camera, target_points, friction),
    or None when the scenario gives none of them; refused where it cannot act (no
    ``[implementation]``; camera entries with the ideal ``e_e``; friction with CVODES)."""
    section, imp, n = scenario.plant, scenario.implementation, loop.robot.n
    if not section.has_errors:
        return None
    given = next(k for k in ("mount", "camera", "target_points", "friction") if getattr(section, k) is not None)
    if imp is None:
        raise ScenarioError(f"plant.{given}: acts on the loop as implemented; add an [implementation] section")
    image = next((k for k in ("mount", "camera", "target_points") if getattr(section, k) is not None), None)
    if image is not None and loop.mode != "image":
        raise ScenarioError(f'plant.{image}: acts through the image; needs e_e = "image"')
    if section.friction is not None and imp.integrator == "cvodes":
        raise ScenarioError('plant.friction: needs a fixed-step integrator ("auto", "rosenbrock" or "rk4"; friction '
                            "acts within the control period)")
    errors = PlantErrors.none(loop.camera, n)
    changes: dict = {}
    if section.mount is not None:
        changes |= {"mount_xyz": np.asarray(section.mount.xyz), "mount_rpy": np.asarray(section.mount.rpy)}
    if (c := section.camera) is not None:
        if c.focal_length is not None:
            changes |= {"fx": c.focal_length, "fy": c.focal_length * loop.camera.aspect}
        changes |= {k: getattr(c, k) for k in ("fx", "fy") if getattr(c, k) is not None}
        if c.principal_point is not None:
            changes["principal_point"] = np.asarray(c.principal_point, dtype=float)
        if c.distortion is not None:
            changes["distortion"] = np.asarray(c.distortion, dtype=float)
    if section.target_points is not None:
        if len(section.target_points) != loop.camera.m:
            got = len(section.target_points)
            raise ScenarioError(f"plant.target_points: expected {loop.camera.m} points, got {got}")
        changes["point_errors"] = np.asarray(section.target_points, dtype=float)
    if section.friction == "urdf":
        changes["viscous"], changes["coulomb"] = joint_dynamics(loop.robot.urdf, loop.robot.joints)
    elif (f := section.friction) is not None:
        changes |= {"viscous": _vector(f.viscous, n, "plant.friction.viscous"),
                    "coulomb": _vector(f.coulomb, n, "plant.friction.coulomb"), "smoothing": f.smoothing}  # fmt: skip
    return replace(errors, **changes)


def _initial_state(scenario: Scenario, loop: ClosedLoop, q0: np.ndarray, qd0: np.ndarray) -> np.ndarray:
    """``s(0)``: the observer from ``[observer]``'s error, or from the first image (``[start]
    observer = "image"``, with the implementation's pixel noise and seed; docs/math.md, fact 16)."""
    start = scenario.start
    changed = [name for name, paper in (("reference", "constant"), ("observer", "scenario"), ("ramp", None))
               if getattr(start, name) != paper]  # fmt: skip
    if scenario.loop == "planar" and changed:
        field = changed[0]
        raise ScenarioError(f"start.{field}: the planar loop starts with the paper's constant reference, the "
                            "[observer] error and no ramp")  # fmt: skip
    if start.observer == "image":
        imp = scenario.implementation
        noise, seed = (0.0, 0) if imp is None else (imp.pixel_noise, imp.seed)
        try:
            return image_start(loop, q0, qd0, noise, seed)
        except ValueError as exc:
            raise ScenarioError(f"start.observer: {exc}") from exc
    o = scenario.observer
    return loop.initial_state(q0, qd0, SE3.from_xyz_rpy(o.error_xyz, o.error_rpy))


def _first_image(scenario: Scenario) -> float:
    """Seconds the arm is held at rest before the planned reference starts: with ``[start] observer
    = "image"`` and an ``[implementation]``, until the image captured at ``t = 0`` can have arrived
    (its latency, plus the largest jitter); 0 otherwise (the image is taken as there at once)."""
    imp = scenario.implementation
    if scenario.start.observer != "image" or imp is None:
        return 0.0
    return (round(imp.latency * imp.control_rate) + imp.latency_jitter) / imp.control_rate


def _estimate(loop: ClosedLoop, s0: np.ndarray) -> SE3:
    """``gbar(0)`` of the start ``s0`` (numeric)."""
    return SE3.from_matrix(cs.Function("gbar0", [loop.state], [loop.estimate.as_matrix()])(s0))


def _implementation_mode(scenario: Scenario) -> Mode:
    """``[implementation] e_e`` when given, else ``[simulation] mode``."""
    imp = scenario.implementation
    return imp.e_e if imp is not None and imp.e_e is not None else scenario.simulation.mode


def _implementation(scenario: Scenario, mode: str) -> Implementation | None:
    """The digital controller, checked against the output grid and the ``e_e`` it uses."""
    section = scenario.implementation
    if section is None:
        return None
    if mode == "ideal" and (section.pixel_noise > 0 or section.quantization > 0):
        name = "pixel_noise" if section.pixel_noise > 0 else "quantization"
        raise ScenarioError(f"implementation.{name}: needs e_e = \"image\" (the ideal e_e uses no pixels)")
    dt = scenario.simulation.dt
    periods = dt * section.control_rate
    if abs(periods - round(periods)) > 1e-6 or round(periods) < 1:
        raise ScenarioError(
            f"simulation.dt: {dt:g} s is not a whole number of control periods ({1 / section.control_rate:g} s)"
        )
    return section.implementation()


def _plant(section: PlantSection, robot: Robot) -> Robot | None:
    """The arm as it is (None when it is the URDF's)."""
    p = section.payload
    payload = None if p is None else Payload(p.mass, _xyz(p.com), tuple(p.inertia))
    if payload is None and section.mass_scale == 1.0:
        return None
    try:
        return Robot(robot.urdf, robot.frame, robot.mount, robot.armature, payload, section.mass_scale)
    except RobotModelError as exc:
        raise ScenarioError(f"plant: {exc}") from exc


def gain_point(scenario: Scenario, n: int, gains: GainsSection | None = None, where: str = "gains") -> GainPoint:
    """The scenario's gains (or ``gains``, named ``where`` in errors) and weights as a certifier point
    (``n`` joints; ``K_c``, ``K_e`` of 6 entries, or 2 for the planar loop; ``K_I`` from ``k_i`` or
    ``k_i_factor K_xi``)."""
    g = scenario.gains if gains is None else gains
    task = TASK if scenario.loop == "planar" else 6
    k_xi = _vector(g.k_xi, n, f"{where}.k_xi")
    if scenario.loop == "planar" and (g.k_i is not None or g.k_i_factor is not None):
        name = "k_i" if g.k_i is not None else "k_i_factor"
        raise ScenarioError(f"{where}.{name}: integral action is built for the paper's loop, not the planar one")
    return GainPoint(
        k_xi,
        _vector(g.k_c, task, f"{where}.k_c"),
        _vector(g.k_e, task, f"{where}.k_e"),
        Weights(**scenario.weights.model_dump()),
        plant_weights(scenario, n),
        integral_gain(g, k_xi, f"{where}.k_i"),
    )


def integral_gain(gains: GainsSection, k_xi: np.ndarray, where: str = "gains.k_i") -> np.ndarray | None:
    """``K_I`` of (42) with integral action (docs/math.md, fact 20) for a design with ``K_xi = k_xi``:
    ``gains``' fixed ``k_i`` (``len(k_xi)`` entries, named ``where`` in errors) or ``k_i_factor K_xi``;
    None without integral action."""
    if gains.k_i is not None:
        return _vector(gains.k_i, len(k_xi), where)
    return None if gains.k_i_factor is None else gains.k_i_factor * np.asarray(k_xi, dtype=float)


def design_before(scenario: Scenario) -> Scenario | None:
    """The scenario of the design its ``[gains]`` were synthesised from (``[synthesized_from]``): the
    same scenario with those gains (and no ``[synthesized_from]``); None without one."""
    origin = scenario.synthesized_from
    if origin is None:
        return None
    return scenario.model_copy(update={"gains": origin.gains, "synthesized_from": None})


def integral_start(scenario: Scenario) -> float:
    """``[gains] integral_start``, or the end of the start's transient: the planned reference's hold
    plus its duration, the ramp's end, else 0 (docs/math.md, fact 20)."""
    if scenario.gains.integral_start is not None:
        return scenario.gains.integral_start
    start = scenario.start
    if start.reference == "planned":
        return _first_image(scenario) + start.duration
    return start.ramp or 0.0


def compensation(scenario: Scenario, robot: Robot) -> np.ndarray | None:
    """The law's friction model ``[bhat; chat; epshat]`` of ``[gains] friction_compensation``
    (docs/math.md, fact 19.2), or None (``"none"``)."""
    model, n = scenario.gains.friction_compensation, robot.n
    if model == "none":
        return None
    if scenario.loop == "planar":
        raise ScenarioError("gains.friction_compensation: built for the paper's loop, not the planar one")
    if model == "urdf":
        viscous, coulomb = joint_dynamics(robot.urdf, robot.joints)
        return np.concatenate([viscous, coulomb, [FrictionModel().smoothing]]).astype(float)
    where = "gains.friction_compensation"
    viscous, coulomb = _vector(model.viscous, n, f"{where}.viscous"), _vector(model.coulomb, n, f"{where}.coulomb")
    return np.concatenate([viscous, coulomb, [model.smoothing]]).astype(float)


def plant_weights(scenario: Scenario, n: int) -> PlantWeights | None:
    """The ``[performance]`` weights of the generalized plant (docs/math.md, fact 17); None when
    every weight is 1 (the paper's plant)."""
    out, dist = scenario.performance.output, scenario.performance.disturbance
    weights = PlantWeights(
        tuple(map(float, _vector(out.xi, n, "performance.output.xi"))),
        tuple(map(float, _vector(dist.tau_d, n, "performance.disturbance.tau_d"))),
        out.e_c, out.e_e, dist.translation, dist.rotation,
    )  # fmt: skip
    return None if weights.is_unit else weights


def _check_reference_view(camera: Camera, reference: SE3) -> None:
    """At the reference pose ``g_d`` every feature must be in front of the camera and inside
    the image (when its size is given): the loop is to hold the target there."""
    depth = np.asarray(cs.DM(camera.depths(reference))).ravel()
    if (bad := np.flatnonzero(~(depth > 1e-9))).size:
        i = int(bad[0])
        raise ScenarioError(f"reference: feature point {i} is at depth {depth[i]:.4g} m (not in front of the camera)")
    f = np.asarray(cs.DM(camera.project(reference))).ravel()
    if camera.has_image and (outside := camera.outside_image(f)).size:
        i = int(outside[0])
        u, v = f[2 * i : 2 * i + 2] + camera.centre
        raise ScenarioError(
            f"reference: feature point {i} is at pixel ({u:.1f}, {v:.1f}), outside the "
            f"{camera.width:g} x {camera.height:g} image (camera.width, camera.height)"
        )


def _check_initial_view(loop: ClosedLoop, s0: np.ndarray, threshold: float) -> None:
    """At t = 0 every point must be in front of the camera (actual and estimated) and inside
    the image (when its size is given), the image Jacobian must have full column rank and the
    arm's Jacobian must not be near-singular."""
    cam = loop.camera
    (arm_name, arm), (image_name, image) = loop.conditioning.items()
    outputs = [cam.depths(loop.relative_pose), cam.depths(loop.estimate), image, arm, cam.project(loop.relative_pose)]
    check = cs.Function("view", [loop.t, loop.state], outputs)
    depth, depth_bar, jac, arm_jac, f = (np.asarray(v) for v in check(0.0, s0))
    for name, z in (("target.points", depth), ("observer", depth_bar)):
        bad = np.flatnonzero(~(z.ravel() > 1e-9))
        if bad.size:
            i = int(bad[0])
            depth_i = z.ravel()[i]
            raise ScenarioError(
                f"{name}: feature point {i} is at depth {depth_i:.4g} m at t = 0 (not in front of the camera; "
                "dvfc pose shows where every point lands)"
            )
    if cam.has_image and (outside := cam.outside_image(f)).size:
        i = int(outside[0])
        u, v = f.ravel()[2 * i : 2 * i + 2] + cam.centre
        raise ScenarioError(
            f"target.points: feature point {i} is at pixel ({u:.1f}, {v:.1f}) at t = 0, outside the "
            f"{cam.width:g} x {cam.height:g} image (camera.width, camera.height; dvfc pose shows where every point "
            "lands)"
        )
    s = np.linalg.svd(jac, compute_uv=False)
    if s[-1] < 1e-9 * s[0]:
        raise ScenarioError(f"target.points: {image_name} is rank-deficient at t = 0 (degenerate feature layout)")
    sigma = np.linalg.svd(arm_jac, compute_uv=False)[-1]
    if sigma < threshold:
        raise ScenarioError(f"robot.q0: {arm_name} is near-singular at q0 (sigma_min = {sigma:.3g} < {threshold:g})")
