"""The scenario file's schema: one strict pydantic model a section (no unknown keys, no coercion).

A scenario names the arm, the camera, the target and its motion, the reference ``g_d``, the
weights and gains of (35)/(42), the disturbances, the simulation, the implementation, the
plant, and the settings of each job. The wording of a validation error is
:mod:`dvfc.analysis.messages`; building the models is :mod:`dvfc.analysis.scenario`.
"""

from __future__ import annotations

import difflib
import math
from typing import Annotated, Any, Literal

import casadi as cs
import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from dvfc.analysis.implementation import STEP_ERROR, Implementation
from dvfc.analysis.messages import one_line
from dvfc.models.camera import Camera
from dvfc.models.lie import SE3


class ScenarioError(ValueError):
    """Invalid scenario: the message is one line that names the field."""


Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Vector3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]

CELL_SIZE = 10.0
"""Largest length (m) a robot cell holds: a position or length beyond it is taken for one given in mm."""
LONGEST_LATENCY = 1.0
"""Largest latency (s) accepted: a longer one is taken for one given in ms."""


def _radians(value: float) -> float:
    """An angle (rad); above ``2 pi`` in magnitude it is taken for one given in degrees."""
    if abs(value) > 2 * math.pi:
        raise ValueError(f"{value:g} rad is beyond 2 pi in magnitude: angles are in radians ({value:g} deg = "
                         f"{math.radians(value):.4g} rad)")  # fmt: skip
    return value


def _metres(value: float) -> float:
    """A position or length (m); beyond :data:`CELL_SIZE` it is taken for one given in mm."""
    if abs(value) > CELL_SIZE:
        raise ValueError(f"{value:g} m is not a plausible length in a robot cell (|x| <= {CELL_SIZE:g} m); lengths "
                         f"are in metres ({value:g} mm = {value / 1000:.4g} m)")  # fmt: skip
    return value


def _seconds(value: float) -> float:
    """A latency (s); above :data:`LONGEST_LATENCY` it is taken for one given in ms."""
    if value > LONGEST_LATENCY:
        raise ValueError(f"{value:g} s is more than {LONGEST_LATENCY:g} s: times are in seconds ({value:g} ms = "
                         f"{value / 1000:.4g} s)")  # fmt: skip
    return value


Angle = Annotated[float, Field(allow_inf_nan=False), AfterValidator(_radians)]
Length = Annotated[float, Field(allow_inf_nan=False), AfterValidator(_metres)]
Angles3 = Annotated[list[Angle], Field(min_length=3, max_length=3)]
Position3 = Annotated[list[Length], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    """No unknown keys, no coercion (a string or a boolean is never a number)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class Pose(_Strict):
    xyz: Position3 = [0.0, 0.0, 0.0]
    rpy: Angles3 = [0.0, 0.0, 0.0]

    def se3(self) -> SE3:
        return SE3.from_xyz_rpy(self.xyz, self.rpy)


class RobotSection(_Strict):
    model: str | None = None
    urdf: str | None = None
    camera_frame: str | None = None
    q0: list[Angle] | Literal["auto"]
    qd0: list[Finite] | None = None
    mount: Pose = Pose()
    armature: list[Annotated[float, Field(ge=0, allow_inf_nan=False)]] | None = None

    @model_validator(mode="after")
    def _one_source(self) -> RobotSection:
        if (self.model is None) == (self.urdf is None):
            raise ValueError("give exactly one of 'model' (a built-in arm) or 'urdf' (a path)")
        return self


Distortion = Annotated[list[Finite], Field(min_length=5, max_length=5)]
"""OpenCV's Brown-Conrady coefficients ``[k1, k2, p1, p2, k3]``."""
Probability = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]


class CameraSection(_Strict):
    """Pinhole camera: the focal length (``focal_length``, or ``fx`` and ``fy``, or a
    ``calibration`` file: :func:`dvfc.analysis.calibration.read_calibration`) and, optionally,
    the sensor's size, principal point (pixels, from the top-left corner; the centre unless
    given) and the distortion coefficients the controller undistorts with."""

    focal_length: Positive | None = None
    fx: Positive | None = None
    fy: Positive | None = None
    calibration: str | None = None
    width: Positive | None = None
    height: Positive | None = None
    principal_point: Annotated[list[Finite], Field(min_length=2, max_length=2)] | None = None
    distortion: Distortion | None = None

    @model_validator(mode="after")
    def _image(self) -> CameraSection:
        focal = (self.focal_length, self.fx if self.fx is not None else self.fy, self.calibration)
        given = [v is not None for v in focal]
        if sum(given) != 1:
            raise ValueError("give exactly one of focal_length, fx and fy, or calibration (a camera_info YAML file)")
        if (self.fx is None) != (self.fy is None):
            raise ValueError("give both fx and fy (pixels)")
        if self.calibration is not None and (self.principal_point is not None or self.distortion is not None):
            raise ValueError("principal_point and distortion come from the calibration file; do not give them too")
        if (self.width is None) != (self.height is None):
            raise ValueError("give both width and height (pixels), or neither")
        if self.principal_point is not None:
            if self.width is None or self.height is None:
                raise ValueError("principal_point needs the image size (width, height)")
            u0, v0 = self.principal_point
            if not (0 <= u0 <= self.width and 0 <= v0 <= self.height):
                raise ValueError("principal_point must lie inside the image")
        return self

    def camera(self, points: np.ndarray) -> Camera:
        """The nominal camera (without a calibration file: see :func:`dvfc.analysis.calibration.camera`)."""
        pp = None if self.principal_point is None else (self.principal_point[0], self.principal_point[1])
        fx = self.focal_length or self.fx
        assert fx is not None, "without a calibration file the focal length is given (_image)"
        aspect = 1.0 if self.fy is None else self.fy / fx
        return Camera(fx, points, self.width, self.height, pp, aspect, tuple(self.distortion or (0.0,) * 5))


class MotionSection(_Strict):
    kind: Literal["static", "circle", "circle_spin"] = "static"
    radius: Annotated[float, Field(ge=0, allow_inf_nan=False), AfterValidator(_metres)] = 0.0
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

    points: Annotated[list[Position3], Field(min_length=4)]
    xyz: Position3 | None = None
    rpy: Angles3 = [0.0, 0.0, 0.0]
    relative_to_camera: Pose | None = None
    motion: MotionSection = MotionSection()

    @model_validator(mode="after")
    def _one_placement(self) -> TargetSection:
        placed = self.xyz is not None or ("rpy" in self.model_fields_set and any(self.rpy))  # a dump has rpy 0
        if self.relative_to_camera is not None and placed:
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

    error_xyz: Position3 = [0.0, 0.0, 0.0]
    error_rpy: Angles3 = [0.0, 0.0, 0.0]


class StartSection(_Strict):
    """How the run starts (docs/math.md, fact 16). ``reference``: ``"constant"`` (the paper's
    ``g_d`` from ``t = 0``) or ``"planned"`` (``g_d(t)`` planned from the controller's estimate at
    start to ``[reference]`` in ``duration`` seconds by the quintic time law, with the
    feedforward ``-Ad_(g_d) V_d``). ``observer``: ``"scenario"`` (``gbar(0)`` from the
    ``[observer]`` error) or ``"image"`` (``gbar(0)`` a pose estimate from the first image; the
    ``[observer]`` error is then unused). ``ramp``: seconds of the smoothstep ramp of the
    camera-velocity command ``u_d = -sigma(t) K_c nu_c`` (fact 16a), with the constant reference."""

    reference: Literal["constant", "planned"] = "constant"
    duration: Positive = 2.0
    observer: Literal["scenario", "image"] = "scenario"
    ramp: Positive | None = None

    @model_validator(mode="after")
    def _ramp_alone(self) -> StartSection:
        if self.ramp is not None and self.reference == "planned":
            raise ValueError("ramp: with reference = \"planned\" the command already starts at rest; give one")
        return self


class WeightsSection(_Strict):
    w_pc: Positive
    w_rc: Positive
    w_pe: Positive
    w_re: Positive


GainValue = Positive | Annotated[list[Positive], Field(min_length=1)]


class FrictionModel(_Strict):
    """A friction model ``b v + c tanh(v / smoothing)``: viscous ``b`` and Coulomb ``c`` (a scalar
    for every joint, or one per joint)."""

    viscous: NonNegative | list[NonNegative] = 0.0
    coulomb: NonNegative | list[NonNegative] = 0.0
    smoothing: Positive = 0.05


class GainsSection(_Strict):
    """The gains of (42) and, optionally, the integral gain of ``u_xi = -K_xi xi - K_I z_I``
    (docs/math.md, fact 20): ``k_i`` (N m/rad; a scalar for every joint, or one per joint), or
    ``k_i_factor`` (``K_I = k_i_factor K_xi``, joint by joint), not both; neither: no integral
    action. ``integral_start``: the time (s) from which ``z_I`` integrates (0 before); default the
    end of the start's transient: the planned reference's hold plus duration, the ramp's end, else 0.
    ``friction_compensation``: what the law adds to (35): ``"none"``, ``"urdf"`` (the URDF's ``<dynamics
    damping friction>``) or a model ``{viscous, coulomb, smoothing}``, fed forward on the law's ``qd_d``
    (never the measured ``qd``: docs/math.md, fact 19)."""

    k_xi: GainValue
    k_c: GainValue
    k_e: GainValue
    k_i: GainValue | None = None
    k_i_factor: Positive | None = None
    integral_start: NonNegative | None = None
    friction_compensation: Literal["none", "urdf"] | FrictionModel = "none"

    @model_validator(mode="after")
    def _one_integral_gain(self) -> GainsSection:
        if self.k_i is not None and self.k_i_factor is not None:
            raise ValueError("give k_i or k_i_factor, not both")
        if self.integral_start is not None and self.k_i is None and self.k_i_factor is None:
            raise ValueError("integral_start: needs k_i or k_i_factor (integral action)")
        return self


class SynthesizedFromSection(_Strict):
    """The design a scenario's ``[gains]`` were synthesised from (written by ``dvfc synthesize
    --for-campaign``): the scenario's name then and its ``[gains]``; the report runs the campaign of
    both designs side by side (every other section the same)."""

    name: str | None = None
    gains: GainsSection


class DisturbanceSection(_Strict):
    kind: Literal["step", "sine", "noise"]
    amplitude: Finite | list[Finite] | None = None
    start: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0
    frequency: Positive | None = None
    phase: Angle = 0.0
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


class OutlierSection(_Strict):
    """Wrong detections: per feature point and image, the probability and the size (px)."""

    probability: Probability = 0.0
    size: NonNegative = 0.0


class ImplementationSection(_Strict):
    """The digital controller (:class:`dvfc.analysis.implementation.Implementation`); absent: the
    paper's continuous loop."""

    control_rate: Positive
    camera_rate: Positive | None = None
    latency: Annotated[float, Field(ge=0, allow_inf_nan=False), AfterValidator(_seconds)] = 0.0
    pixel_noise: NonNegative = 0.0
    quantization: NonNegative = 0.0
    e_e: Literal["ideal", "image"] | None = None
    saturate: bool = False
    torque_scale: Positive = 1.0
    velocity_limits: Literal["report", "stop"] = "report"
    seed: int = 0
    integrator: Literal["auto", "rk4", "rosenbrock", "cvodes"] = "auto"
    substeps: Annotated[int, Field(ge=1, le=1000)] | Literal["auto"] = "auto"
    step_error: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = STEP_ERROR
    latency_jitter: Annotated[int, Field(ge=0, le=1000)] = 0
    frame_drop: Probability = 0.0
    outliers: OutlierSection = OutlierSection()

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
            control_rate=self.control_rate,
            camera_rate=self.camera_rate or self.control_rate,
            latency=self.latency,
            pixel_noise=self.pixel_noise,
            quantization=self.quantization,
            saturate=self.saturate,
            torque_scale=self.torque_scale,
            velocity_limits=self.velocity_limits,
            seed=self.seed,
            integrator=self.integrator,
            substeps=self.substeps,
            step_error=self.step_error,
            latency_jitter=self.latency_jitter,
            frame_drop=self.frame_drop,
            outlier_probability=self.outliers.probability,
            outlier_size=self.outliers.size,
        )


class PayloadSection(_Strict):
    """A body on the camera link that the controller does not know: mass (kg), centre of mass
    (m, link frame), inertia about it ``[ixx, ixy, ixz, iyy, iyz, izz]`` (kg m^2)."""

    mass: NonNegative
    com: Position3 = [0.0, 0.0, 0.0]
    inertia: Annotated[list[Finite], Field(min_length=6, max_length=6)] = [0.0] * 6


class PlantCameraSection(_Strict):
    """The true intrinsics (each absent: the controller's ``[camera]`` value)."""

    focal_length: Positive | None = None
    fx: Positive | None = None
    fy: Positive | None = None
    principal_point: Annotated[list[Finite], Field(min_length=2, max_length=2)] | None = None
    distortion: Distortion | None = None

    @model_validator(mode="after")
    def _one_focal(self) -> PlantCameraSection:
        if self.focal_length is not None and (self.fx is not None or self.fy is not None):
            raise ValueError("give focal_length or fx/fy, not both")
        return self


class FrictionSection(FrictionModel):
    """Joint friction the law does not model, ``b qd + c tanh(qd / smoothing)``: viscous ``b``
    and Coulomb ``c`` (a scalar for every joint, or one per joint)."""


class PlantSection(_Strict):
    """The arm as it is, when it differs from the URDF the controller uses, and what else the
    controller's model gets wrong (:mod:`dvfc.models.errors`): the true camera mount relative
    to the nominal one, the true intrinsics, the error of each feature point (m), friction
    (or ``"urdf"``: the URDF's ``<dynamics damping friction>``)."""

    payload: PayloadSection | None = None
    mass_scale: Positive = 1.0
    mount: Pose | None = None
    camera: PlantCameraSection | None = None
    target_points: list[Position3] | None = None
    friction: FrictionSection | Literal["urdf"] | None = None

    @property
    def has_errors(self) -> bool:
        """Whether an entry beyond the payload and mass scale is given."""
        return any(v is not None for v in (self.mount, self.camera, self.target_points, self.friction))


class DistributionSection(_Strict):
    """The deviation of one field from the scenario's value (:mod:`dvfc.analysis.dispersion`):
    ``normal`` (``sigma``, truncated at ``clip`` sigmas), ``uniform`` (``low``, ``high``),
    ``lognormal`` (a factor ``exp(N(0, sigma))``) or ``choice`` (absolute ``values``); a scalar
    applies to every entry of a vector field, a list entry by entry."""

    dist: Literal["normal", "uniform", "lognormal", "choice"]
    sigma: NonNegative | list[NonNegative] | None = None
    clip: Positive | None = None
    low: Finite | list[Finite] | None = None
    high: Finite | list[Finite] | None = None
    values: Annotated[list[Finite | list[Finite]], Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _parameters(self) -> DistributionSection:
        needed = {"normal": {"sigma"}, "lognormal": {"sigma"}, "uniform": {"low", "high"}, "choice": {"values"}}
        allowed = needed[self.dist] | ({"clip"} if self.dist == "normal" else set())
        given = {k for k in ("sigma", "clip", "low", "high", "values") if getattr(self, k) is not None}
        if missing := needed[self.dist] - given:
            raise ValueError(f"dist = {self.dist!r} needs {', '.join(sorted(missing))}")
        if extra := given - allowed:
            raise ValueError(f"dist = {self.dist!r} takes no {', '.join(sorted(extra))}")
        if self.dist == "uniform":
            low, high = np.broadcast_arrays(np.asarray(self.low, float), np.asarray(self.high, float))
            if np.any(low > high):
                raise ValueError(f"low {self.low} exceeds high {self.high}")
        return self


class PerformanceOutput(_Strict):
    """Weights of the performance output ``z = S x``: ``xi`` (one for every joint, or one per
    joint), the control error ``e_c`` and the estimation error ``e_e``."""

    xi: GainValue = 1.0
    e_c: Positive = 1.0
    e_e: Positive = 1.0


class PerformanceDisturbance(_Strict):
    """Weights of the disturbance ``w = D_w d``: the joint torques ``tau_d`` (one, or one per
    joint) and the target's translational and rotational velocity."""

    tau_d: GainValue = 1.0
    translation: Positive = 1.0
    rotation: Positive = 1.0


class PerformanceSection(_Strict):
    """The generalized plant Theorem 2 bounds the gain of (docs/math.md, fact 17): ``d -> z`` with
    ``z = S x`` and ``w = D_w d``; every weight 1 (the default) is the paper's."""

    output: PerformanceOutput = PerformanceOutput()
    disturbance: PerformanceDisturbance = PerformanceDisturbance()


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


class CriterionSection(_Strict):
    """The tracking bound of the criterion of ``margins`` and ``campaign``, pinned: the true tracking
    error over the last half of a run within ``position`` (m) and ``angle_deg`` (deg). Absent: the
    design's certified operating envelope (docs/math.md, fact 7; with integral action the same design's
    without ``K_I``, fact 20.4), else twice the continuous loop's error. A design judged by the
    criterion of another (say, the one it replaces) pins that one's numbers here."""

    position: Positive
    angle_deg: Annotated[float, Field(gt=0, le=180, allow_inf_nan=False)]


class ReportSection(_Strict):
    """What the report's gain map shows: the certified gamma, or (with an ``[envelope]``) the
    certified decay rate or the largest certified target speed; and the runs of the campaign
    the report makes of the scenario's ``[dispersion]``."""

    map: Literal["gamma", "rate", "max_target_speed"] = "gamma"
    campaign_runs: Annotated[int, Field(ge=1)] = 100


Interval = Annotated[list[Positive], Field(min_length=2, max_length=2)]


class SynthesizeSection(_Strict):
    """Gain bounds ``[lower, upper]`` for ``synthesize`` (``k_xi``: one interval for every joint,
    or one per joint; absent: each joint's gain window, :mod:`dvfc.analysis.windows`), the
    objective (the certified gamma, or the envelope's certified target speed), an optional gamma
    target, whether to search the weights on a log grid around the scenario's, and whether the
    design must run within the arm's effort and velocity limits (``respect_limits``: a search
    over shrunken gain boxes)."""

    k_xi: Interval | list[Interval] | None = None
    k_c: Interval = [0.1, 20.0]
    k_e: Interval = [0.1, 50.0]
    objective: Literal["gamma", "target_speed"] = "gamma"
    gamma: Positive | None = None
    search_weights: bool = False
    respect_limits: bool = False

    @model_validator(mode="after")
    def _ordered(self) -> SynthesizeSection:
        intervals: list[tuple[str, Any]] = [("k_c", self.k_c), ("k_e", self.k_e)]
        if self.k_xi is not None:
            nested = isinstance(self.k_xi[0], list)
            intervals += [(f"k_xi[{i}]", b) for i, b in enumerate(self.k_xi)] if nested else [("k_xi", self.k_xi)]
        for name, (lo, hi) in intervals:
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
                    raise ScenarioError(f"grid.{name}.{one_line(exc, RangeSpec)}") from exc
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
    start: StartSection = StartSection()
    weights: WeightsSection
    gains: GainsSection
    synthesized_from: SynthesizedFromSection | None = None
    disturbance: DisturbancesSection = DisturbancesSection()
    simulation: SimulationSection = SimulationSection()
    implementation: ImplementationSection | None = None
    plant: PlantSection = PlantSection()
    performance: PerformanceSection = PerformanceSection()
    certify: CertifySection = CertifySection()
    envelope: EnvelopeSection | None = None
    criterion: CriterionSection | None = None
    report: ReportSection = ReportSection()
    grid: GridSection | None = None
    synthesize: SynthesizeSection = SynthesizeSection()
    dispersion: dict[str, DistributionSection] = {}

    @model_validator(mode="after")
    def _dispersed_fields(self) -> Scenario:
        from dvfc.analysis.dispersion import check_keys

        check_keys(self)
        return self

    @model_validator(mode="after")
    def _map_needs_envelope(self) -> Scenario:
        if self.report.map != "gamma" and self.envelope is None:
            raise ValueError(f"report.map = {self.report.map!r} needs an [envelope] section")
        return self
