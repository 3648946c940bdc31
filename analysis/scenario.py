"""Scenario files (TOML): validation with field-level errors, and the models they build.

A scenario names the arm, the camera, the target and its motion, the reference
``g_d``, the weights and gains of (35)/(42), the disturbances and the simulation
settings. Every problem is reported as one :class:`ScenarioError` line that names the
field, e.g. ``gains.k_c: expected 6 entries, got 5``.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path
from typing import Annotated, Literal

import casadi as cs
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from dvfc.analysis.certify import GainPoint
from dvfc.analysis.implementation import Implementation
from dvfc.analysis.simulate import Settings
from dvfc.models.camera import Camera
from dvfc.models.disturbance import BandLimitedNoise, Disturbance, Sine, Step
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop, Gains, Weights
from dvfc.models.planar import TASK, PlanarLoop
from dvfc.models.robot import BUILTIN_ARMATURE, BUILTIN_CAMERA_FRAME, Payload, Robot, RobotModelError, builtin_urdf
from dvfc.models.target import TargetMotion

DEFAULT_SCENARIO = Path(__file__).parent / "scenarios" / "ur5_circle.toml"
"""The built-in default scenario (a copy of ``examples/ur5_circle.toml``)."""


class ScenarioError(ValueError):
    """Invalid scenario: the message is one line that names the field."""


Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Vector3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    """No unknown keys, no coercion (a string or a boolean is never a number)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class Pose(_Strict):
    xyz: Vector3 = [0.0, 0.0, 0.0]
    rpy: Vector3 = [0.0, 0.0, 0.0]

    def se3(self) -> SE3:
        return SE3.from_xyz_rpy(self.xyz, self.rpy)


class RobotSection(_Strict):
    model: str | None = None
    urdf: str | None = None
    camera_frame: str | None = None
    q0: list[Finite]
    qd0: list[Finite] | None = None
    mount: Pose = Pose()
    armature: list[Annotated[float, Field(ge=0, allow_inf_nan=False)]] | None = None

    @model_validator(mode="after")
    def _one_source(self) -> RobotSection:
        if (self.model is None) == (self.urdf is None):
            raise ValueError("give exactly one of 'model' (a built-in arm) or 'urdf' (a path)")
        return self


class CameraSection(_Strict):
    """Pinhole camera: focal length and, optionally, the sensor's size and principal point
    (pixels, from the top-left corner; the centre unless given)."""

    focal_length: Positive
    width: Positive | None = None
    height: Positive | None = None
    principal_point: Annotated[list[Finite], Field(min_length=2, max_length=2)] | None = None

    @model_validator(mode="after")
    def _image(self) -> CameraSection:
        if (self.width is None) != (self.height is None):
            raise ValueError("give both width and height (pixels), or neither")
        if self.principal_point is not None:
            if self.width is None:
                raise ValueError("principal_point needs the image size (width, height)")
            u0, v0 = self.principal_point
            if not (0 <= u0 <= self.width and 0 <= v0 <= self.height):
                raise ValueError("principal_point must lie inside the image")
        return self

    def camera(self, points: np.ndarray) -> Camera:
        pp = None if self.principal_point is None else tuple(self.principal_point)
        return Camera(self.focal_length, points, self.width, self.height, pp)


class MotionSection(_Strict):
    kind: Literal["static", "circle", "circle_spin"] = "static"
    radius: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0
    period: Positive = 1.0
    normal: Vector3 = [0.0, 0.0, 1.0]
    spin_axis: Vector3 = [0.0, 0.0, 1.0]
    spin_rate: Finite = 0.0

    @model_validator(mode="after")
    def _consistent(self) -> MotionSection:
        if self.kind == "static" and (self.radius != 0 or self.spin_rate != 0):
            raise ValueError("a static target has no radius or spin_rate")
        if self.kind == "circle" and self.spin_rate != 0:
            raise ValueError("kind 'circle' does not spin; use kind 'circle_spin'")
        if np.linalg.norm(self.normal) == 0 or np.linalg.norm(self.spin_axis) == 0:
            raise ValueError("normal and spin_axis must be non-zero vectors")
        return self


class TargetSection(_Strict):
    """The object: feature points in its frame, its pose ``g_wo(0)`` in the world (``xyz``,
    ``rpy``) or relative to the camera at ``q0`` (``relative_to_camera``: ``g_wo(0) =
    g_wc(q0) g_co``, so ``xyz = [0, 0, d]`` puts it on the optical axis at depth ``d``), and
    its motion."""

    points: Annotated[list[Vector3], Field(min_length=4)]
    xyz: Vector3 | None = None
    rpy: Vector3 = [0.0, 0.0, 0.0]
    relative_to_camera: Pose | None = None
    motion: MotionSection = MotionSection()

    @model_validator(mode="after")
    def _one_placement(self) -> TargetSection:
        if self.relative_to_camera is not None and {"xyz", "rpy"} & self.model_fields_set:
            raise ValueError("give either xyz/rpy (world frame) or relative_to_camera, not both")
        if self.relative_to_camera is None and self.xyz is None:
            raise ValueError("give xyz (the target's position in the world) or relative_to_camera = {xyz, rpy}")
        return self

    def start(self, camera_at_q0: SE3) -> SE3:
        """``g_wo(0)``, given the camera's pose ``g_wc(q0)``."""
        if self.relative_to_camera is not None:
            return camera_at_q0 @ self.relative_to_camera.se3()
        return SE3.from_xyz_rpy(self.xyz, self.rpy)

    @field_validator("points")
    @classmethod
    def _not_collinear(cls, points: list[list[float]]) -> list[list[float]]:
        p = np.asarray(points)
        if np.linalg.matrix_rank(p - p.mean(axis=0), tol=1e-9) < 2:
            raise ValueError("the feature points are collinear: J(gbar) cannot have rank 6")
        return points


class ReferenceSection(Pose):
    @field_validator("rpy")
    @classmethod
    def _below_pi(cls, rpy: list[float]) -> list[float]:
        r = np.asarray(cs.DM(SE3.from_xyz_rpy([0, 0, 0], rpy).rotation.matrix))
        theta = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
        if theta >= math.pi - 1e-6:
            raise ValueError("the reference rotation angle must be below pi (e_R vanishes at pi)")
        return rpy


class ObserverSection(_Strict):
    """Initial estimation error ``g_ee(0)``: ``gbar(0) = g(0) g_ee(0)^-1``."""

    error_xyz: Vector3 = [0.0, 0.0, 0.0]
    error_rpy: Vector3 = [0.0, 0.0, 0.0]


class WeightsSection(_Strict):
    w_pc: Positive
    w_rc: Positive
    w_pe: Positive
    w_re: Positive


GainValue = Positive | Annotated[list[Positive], Field(min_length=1)]


class GainsSection(_Strict):
    k_xi: GainValue
    k_c: GainValue
    k_e: GainValue


class DisturbanceSection(_Strict):
    kind: Literal["step", "sine", "noise"]
    amplitude: Finite | list[Finite] | None = None
    start: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0
    frequency: Positive | None = None
    phase: Finite = 0.0
    rms: Annotated[float, Field(ge=0, allow_inf_nan=False)] | list[Finite] | None = None
    bandwidth: Positive | None = None
    seed: int = 0

    @model_validator(mode="after")
    def _fields_of_kind(self) -> DisturbanceSection:
        needed = {"step": ("amplitude",), "sine": ("amplitude", "frequency"), "noise": ("rms", "bandwidth")}
        for name in needed[self.kind]:
            if getattr(self, name) is None:
                raise ValueError(f"kind {self.kind!r} needs '{name}'")
        return self


class DisturbancesSection(_Strict):
    torque: list[DisturbanceSection] = []


class SimulationSection(_Strict):
    duration: Positive = 10.0
    dt: Positive = 0.01
    mode: Literal["ideal", "image"] = "ideal"
    rtol: Annotated[float, Field(gt=0, lt=1)] = 1e-10
    atol: Annotated[float, Field(gt=0, lt=1)] = 1e-10
    jit: bool = False
    time_budget: Positive = 600.0
    sigma_min: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.02

    @model_validator(mode="after")
    def _grid(self) -> SimulationSection:
        if self.dt > self.duration:
            raise ValueError("dt must not exceed duration")
        if self.duration / self.dt > 1e6:
            raise ValueError("more than 1e6 output steps: raise dt")
        return self


class ImplementationSection(_Strict):
    """The digital controller (:class:`dvfc.analysis.implementation.Implementation`); absent: the
    paper's continuous loop."""

    control_rate: Positive
    camera_rate: Positive | None = None
    latency: NonNegative = 0.0
    pixel_noise: NonNegative = 0.0
    quantization: NonNegative = 0.0
    e_e: Literal["ideal", "image"] | None = None
    saturate: bool = False
    torque_scale: Positive = 1.0
    velocity_limits: Literal["report", "stop"] = "report"
    seed: int = 0
    integrator: Literal["rk4", "cvodes"] = "rk4"
    substeps: Annotated[int, Field(ge=1, le=1000)] = 1

    @model_validator(mode="after")
    def _samples(self) -> ImplementationSection:
        periods = self.latency * self.control_rate
        if abs(periods - round(periods)) > 1e-6:
            raise ValueError(
                f"latency {self.latency:g} s is not a whole number of control periods "
                f"({1 / self.control_rate:g} s): images are used at control samples"
            )
        if self.camera_rate is not None and self.camera_rate > self.control_rate:
            raise ValueError(f"camera_rate {self.camera_rate:g} Hz exceeds control_rate {self.control_rate:g} Hz")
        return self

    def implementation(self) -> Implementation:
        return Implementation(
            self.control_rate,
            self.camera_rate or self.control_rate,
            self.latency,
            self.pixel_noise,
            self.quantization,
            self.saturate,
            self.torque_scale,
            self.velocity_limits,
            self.seed,
            self.integrator,
            self.substeps,
        )


class PayloadSection(_Strict):
    """A body on the camera link that the controller does not know: mass (kg), centre of mass
    (m, link frame), inertia about it ``[ixx, ixy, ixz, iyy, iyz, izz]`` (kg m^2)."""

    mass: NonNegative
    com: Vector3 = [0.0, 0.0, 0.0]
    inertia: Annotated[list[Finite], Field(min_length=6, max_length=6)] = [0.0] * 6


class PlantSection(_Strict):
    """The arm as it is, when it differs from the URDF the controller uses."""

    payload: PayloadSection | None = None
    mass_scale: Positive = 1.0


class CertifySection(_Strict):
    """Region and requirement of the Theorem 2 certificate."""

    theta_max_deg: Annotated[float, Field(gt=0, le=180, allow_inf_nan=False)] = 180.0
    gamma: Positive | None = None


class EnvelopeSection(_Strict):
    """Bounds on the disturbance for the operating envelope (docs/math.md, facts 7-9): the target's
    speed (m/s) and angular rate (rad/s), the joint-torque disturbance ``|tau_d|`` (N m,
    Euclidean norm), and optionally ``theta_bar`` (degrees). Each one absent is derived
    from the scenario's own target motion and disturbances."""

    target_speed: NonNegative | None = None
    target_rate: NonNegative | None = None
    torque: NonNegative | None = None
    theta_bar_deg: Annotated[float, Field(gt=0, lt=180, allow_inf_nan=False)] | None = None


class ReportSection(_Strict):
    """What the report's gain map shows: the certified gamma, or (with an ``[envelope]``) the
    certified decay rate or the largest certified target speed."""

    map: Literal["gamma", "rate", "max_target_speed"] = "gamma"


Interval = Annotated[list[Positive], Field(min_length=2, max_length=2)]


class SynthesizeSection(_Strict):
    """Gain bounds ``[lower, upper]`` for ``synthesize``, the objective (the certified gamma, or
    the envelope's certified target speed), an optional gamma target, whether to search the
    weights on a log grid around the scenario's, and whether the design must run within the
    arm's effort and velocity limits (``respect_limits``: a search over shrunken gain boxes)."""

    k_xi: Interval = [1.0, 100.0]
    k_c: Interval = [0.1, 20.0]
    k_e: Interval = [0.1, 50.0]
    objective: Literal["gamma", "target_speed"] = "gamma"
    gamma: Positive | None = None
    search_weights: bool = False
    respect_limits: bool = False

    @model_validator(mode="after")
    def _ordered(self) -> SynthesizeSection:
        for name in ("k_xi", "k_c", "k_e"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name}: lower bound {lo} exceeds upper bound {hi}")
        if self.objective == "target_speed" and self.gamma is not None:
            raise ValueError('gamma: a gamma target applies to objective = "gamma" only')
        if self.objective == "target_speed" and self.search_weights:
            raise ValueError('search_weights: not available with objective = "target_speed"')
        if self.respect_limits and self.gamma is not None:
            raise ValueError(
                "respect_limits: not available with a gamma target (synthesize.gamma): the smallest gains "
                "reaching it are not made smaller by shrinking the gain box"
            )
        return self


class RangeSpec(_Strict):
    """``num`` values from ``start`` to ``stop``, linearly or logarithmically spaced."""

    start: Positive
    stop: Positive
    num: Annotated[int, Field(ge=1, le=10**7)]
    spacing: Literal["linear", "log"] = "linear"

    def values(self) -> np.ndarray:
        space = np.geomspace if self.spacing == "log" else np.linspace
        return space(self.start, self.stop, self.num)


class GridSection(_Strict):
    """Axes swept by ``certify``: any of :data:`dvfc.analysis.grid.AXES`."""

    model_config = ConfigDict(extra="allow", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _axes(cls, data: dict) -> dict:
        from dvfc.analysis.grid import AXES

        if not isinstance(data, dict) or not data:
            raise ValueError("the grid is empty: give at least one axis, e.g. k_c = [1, 2, 4]")
        for name in data:
            if name not in AXES:
                close = difflib.get_close_matches(name, AXES, n=1, cutoff=0.6)
                hint = f"did you mean {close[0]!r}? " if close else ""
                raise ValueError(f"unknown axis {name!r}; {hint}sweepable: {', '.join(AXES)}")
        return data

    def axes(self) -> list[tuple[str, np.ndarray]]:
        """The swept values per axis, validated (field-level errors)."""
        out = []
        for name, value in (self.model_extra or {}).items():
            if isinstance(value, dict):
                try:
                    values = RangeSpec.model_validate(value).values()
                except ValidationError as exc:
                    raise ScenarioError(f"grid.{name}.{_format(exc, RangeSpec)}") from exc
            else:
                values = np.asarray(value if isinstance(value, list) else [None], dtype=object)
                if not len(values) or not all(
                    isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v > 0
                    for v in values
                ):
                    raise ScenarioError(f"grid.{name}: expected a list of positive finite numbers or a range table")
                values = values.astype(float)
            out.append((name, values))
        return out


class Scenario(_Strict):
    """The whole scenario file. ``loop`` selects the paper's 6-D loop or the reduced planar
    loop of :mod:`dvfc.models.planar` (arms with fewer than six joints moving in a horizontal plane)."""

    name: str = "scenario"
    loop: Literal["paper", "planar"] = "paper"
    robot: RobotSection
    camera: CameraSection
    target: TargetSection
    reference: ReferenceSection
    observer: ObserverSection = ObserverSection()
    weights: WeightsSection
    gains: GainsSection
    disturbance: DisturbancesSection = DisturbancesSection()
    simulation: SimulationSection = SimulationSection()
    implementation: ImplementationSection | None = None
    plant: PlantSection = PlantSection()
    certify: CertifySection = CertifySection()
    envelope: EnvelopeSection | None = None
    report: ReportSection = ReportSection()
    grid: GridSection | None = None
    synthesize: SynthesizeSection = SynthesizeSection()

    @model_validator(mode="after")
    def _map_needs_envelope(self) -> Scenario:
        if self.report.map != "gamma" and self.envelope is None:
            raise ValueError(f"report.map = {self.report.map!r} needs an [envelope] section")
        return self


_UNION_TAGS = {"float", "int", "str", "bool", "list", "dict", "none"}
"""Parts of a pydantic error location that name a branch of a union, not a key."""

_TYPE_ERRORS = {"float_type", "int_type", "list_type", "dict_type", "model_type", "string_type", "bool_type",
                "model_attributes_type", "int_from_float"}  # fmt: skip


def _where(loc: tuple) -> str:
    """``gains.k_e[2]``: keys joined by dots, list indices in brackets, union branches dropped."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not (any(c in part for c in "-[]") or part in _UNION_TAGS):
            out += f".{part}" if out else part
    return out or "scenario"


def _describe(value) -> str:
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return repr(value)


def _keys_at(loc: tuple, root: type[BaseModel]) -> list[str]:
    """The keys ``root`` allows at ``loc`` (a table's location), by walking the models."""
    model: type[BaseModel] | None = root
    for part in loc:
        if model is None or not isinstance(part, str) or part not in model.model_fields:
            continue  # list indices and union branches
        model = next((a for a in _types(model.model_fields[part].annotation) if _is_model(a)), None)
    return list(model.model_fields) if model is not None else []


def _types(annotation) -> list:
    args = getattr(annotation, "__args__", None)
    if not args:
        return [annotation]
    return [t for a in args for t in _types(a)]


def _is_model(t) -> bool:
    return isinstance(t, type) and issubclass(t, BaseModel)


def _unknown_key(loc: tuple, value, root: type[BaseModel]) -> str:
    key, parent = loc[-1], loc[:-1]
    known = _keys_at(parent, root)
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    what = "section" if not parent and root is Scenario and isinstance(value, dict) else "key"
    hint = f" (did you mean {close[0]!r}?)" if close else f" (expected one of: {', '.join(known)})"
    return f"{_where(loc)}: unknown {what} {key!r}{hint}"


def _message(error: dict, root: type[BaseModel]) -> str:
    """One error in our words."""
    kind, ctx, value = error["type"], error.get("ctx", {}), error.get("input")
    if kind == "extra_forbidden":
        return _unknown_key(error["loc"], value, root)
    where = _where(error["loc"])
    bounds = {"greater_than": ("> ", "gt"), "greater_than_equal": (">= ", "ge"), "less_than": ("< ", "lt"),
              "less_than_equal": ("<= ", "le")}  # fmt: skip
    if kind in bounds:
        op, key = bounds[kind]
        return f"{where}: must be {op}{ctx[key]:g}, got {value!r}"
    if kind == "finite_number":
        return f"{where}: must be a finite number, got {value!r}"
    if kind == "missing":
        return f"{where}: required key missing"
    if kind in ("too_short", "too_long"):
        size = ctx.get("min_length") if kind == "too_short" else ctx.get("max_length")
        return f"{where}: expected {'at least' if kind == 'too_short' else 'at most'} {size} entries, got {len(value)}"
    if kind == "literal_error":
        return f"{where}: expected {ctx['expected']}, got {_describe(value)}"
    if kind in _TYPE_ERRORS:
        expected = {"float_type": "a number", "int_type": "an integer", "int_from_float": "an integer",
                    "list_type": "a list", "string_type": "a string", "bool_type": "true or false"}  # fmt: skip
        return f"{where}: expected {expected.get(kind, 'a table')}, got {_describe(value)}"
    return f"{where}: {error['msg'].removeprefix('Value error, ')}"


def _format(error: ValidationError, root: type[BaseModel] | None = None) -> str:
    """The most useful error of a validation, in our words: an unknown key first (a typo in a
    required key is also reported missing); of the branches of a union (a number or a list),
    the one the value's type selects."""
    root = root or Scenario
    errors = error.errors()
    unknown = [e for e in errors if e["type"] == "extra_forbidden"]
    if unknown:
        return _message(unknown[0], root)
    first = errors[0]
    field = _where(first["loc"])
    same = [e for e in errors if _where(e["loc"]).startswith(field)]
    if len(same) > 1:
        meaningful = [e for e in same if e["type"] not in _TYPE_ERRORS] or same
        deepest = max(len(e["loc"]) for e in meaningful)
        candidates = [e for e in meaningful if len(e["loc"]) == deepest]
        first = candidates[0]
        tied = [e for e in candidates if _where(e["loc"]) == _where(first["loc"])]
        if len(tied) > 1 and all(e["type"] in _TYPE_ERRORS for e in tied):
            return f"{field}: expected a number or a list of numbers, got {_describe(first['input'])}"
    return _message(first, root)


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
        raise ScenarioError(_format(exc)) from exc


def _vector(value: float | list[float], n: int, where: str) -> np.ndarray:
    if isinstance(value, list):
        if len(value) != n:
            raise ScenarioError(f"{where}: expected {n} entries, got {len(value)}")
        return np.asarray(value, dtype=float)
    return np.full(n, float(value))


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


def build_robot(section: RobotSection, base: Path) -> Robot:
    """The arm of a scenario (built-in name or URDF path relative to the scenario file)."""
    try:
        if section.model is not None:
            urdf = builtin_urdf(section.model)
            frame = section.camera_frame or BUILTIN_CAMERA_FRAME[section.model]
            armature = BUILTIN_ARMATURE.get(section.model, ())
        else:
            urdf = (base / section.urdf).resolve()
            if not urdf.is_file():
                raise ScenarioError(f"robot.urdf: no such file: {urdf}")
            if section.camera_frame is None:
                raise ScenarioError("robot.camera_frame: required with robot.urdf")
            frame = section.camera_frame
            armature = ()
        if section.armature is not None:
            armature = tuple(section.armature)
        return Robot(urdf, frame, section.mount.se3(), armature)
    except RobotModelError as exc:
        field = "robot.model" if "unknown robot model" in str(exc) else "robot.urdf"
        if "no link named" in str(exc):
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
            out.append(Step(_vector(d.amplitude, n, f"{where}.amplitude"), d.start))
        elif d.kind == "sine":
            out.append(Sine(_vector(d.amplitude, n, f"{where}.amplitude"), d.frequency, d.phase))
        else:
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
            f"[0, 0, -1]); this one is {math.degrees(math.asin(min(1.0, np.linalg.norm(normal[:2])))):.3g} deg "
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


def build(
    scenario: Scenario, base: Path, *, mode: str | None = None, check_view: bool = True
) -> tuple[ClosedLoop, np.ndarray, Settings]:
    """The closed loop (the paper's, or the reduced planar one), its initial state and the
    simulation settings of a scenario; ``check_view`` refuses a start with a feature behind
    the camera or outside the image, or a singular arm (:func:`dvfc.analysis.pose` shows them)."""
    robot = build_robot(scenario.robot, base)
    n = robot.n
    q0 = _vector(scenario.robot.q0, n, "robot.q0")
    _check_position_limits(robot, q0)
    if scenario.loop == "planar":
        _check_planar(scenario, robot, q0)
    qd0 = _vector(scenario.robot.qd0 or 0.0, n, "robot.qd0")
    t = scenario.target
    m = t.motion
    camera_at_q0 = SE3.from_matrix(cs.Function("g_wc", [robot.q], [robot.camera_pose.as_matrix()])(q0))
    target = TargetMotion(t.start(camera_at_q0), m.radius, m.period, tuple(m.normal), tuple(m.spin_axis), m.spin_rate)
    point = gain_point(scenario, n)
    kind = PlanarLoop if scenario.loop == "planar" else ClosedLoop
    loop = kind(
        robot=robot,
        camera=scenario.camera.camera(np.asarray(t.points, dtype=float)),
        target=target,
        reference=scenario.reference.se3(),
        weights=point.weights,
        gains=Gains(point.k_xi, point.k_c, point.k_e),
        mode=mode or _implementation_mode(scenario),
        disturbances=disturbances(scenario.disturbance, n),
    )
    o = scenario.observer
    s0 = loop.initial_state(q0, qd0, SE3.from_xyz_rpy(o.error_xyz, o.error_rpy))
    if check_view:
        _check_initial_view(loop, s0, scenario.simulation.sigma_min)
        if scenario.loop == "paper":
            _check_reference_view(loop.camera, loop.reference)
    sim = scenario.simulation
    settings = Settings(
        sim.duration,
        sim.dt,
        sim.rtol,
        sim.atol,
        sim.jit,
        sim.time_budget,
        sigma_min=sim.sigma_min,
        implementation=_implementation(scenario, loop.mode),
        plant=_plant(scenario.plant, robot),
    )
    return loop, s0, settings


def _implementation_mode(scenario: Scenario) -> str:
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
    payload = None if p is None else Payload(p.mass, tuple(p.com), tuple(p.inertia))
    if payload is None and section.mass_scale == 1.0:
        return None
    try:
        return Robot(robot.urdf, robot.frame, robot.mount, robot.armature, payload, section.mass_scale)
    except RobotModelError as exc:
        raise ScenarioError(f"plant: {exc}") from exc


def gain_point(scenario: Scenario, n: int) -> GainPoint:
    """The scenario's gains and weights as a certifier point (``n`` joints; ``K_c``, ``K_e``
    of 6 entries, or 2 for the planar loop)."""
    g = scenario.gains
    task = TASK if scenario.loop == "planar" else 6
    return GainPoint(
        _vector(g.k_xi, n, "gains.k_xi"),
        _vector(g.k_c, task, "gains.k_c"),
        _vector(g.k_e, task, "gains.k_e"),
        Weights(**scenario.weights.model_dump()),
    )


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
