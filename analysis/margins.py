"""Where the loop as implemented stops working: measured margins of the nonlinear loop.

For each parameter of :data:`PARAMETERS` (the others at the scenario's values) the run of
:func:`dvfc.analysis.sampled.as_implemented` is repeated by bisection between the scenario's
value and the end of a stated range, and each run is judged by :func:`judge`: the loop
*holds* when the run completes (no divergence, singularity or stop, every feature in the
image), the joints stay within their position and velocity limits and, when ``saturate``
is off, the torques within the effort limits, and the
tracking error over the last half of the run stays within the operating envelope's
certified ultimate bound (docs/math.md, fact 7; twice the continuous loop's error where the design
has no certified envelope) (:data:`CRITERION`). A run judged to hold must also have reached a
steady state (:func:`envelope_growth`: over at least :data:`PERIODS` whole periods of the target's
motion, the last period's root-mean-square within ``exp(GROWTH_RATE period)`` of the one before it, the horizon
doubled, up to :data:`HORIZONS`, until it is), and where fact 14 applies a value at which the sampled
loop linearised at rest is unstable does not hold (the schedule's for the latency and camera rate, the
plant as declared with the value for :data:`PLANT`); a measured margin is never reported beyond fact
14's linear one (:data:`STEADY`). These are measurements on simulated runs, not
certificates.

Each parameter's search is one task (local processes or a Dask cluster); every run is
appended to ``DIR/<parameter>.jsonl`` as it finishes, so an interrupted search resumes
with the runs already made.
"""

from __future__ import annotations

import itertools
import math
import time
import xml.etree.ElementTree as ET
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.multirate import (
    RHO_MARGIN,
    DeclaredPlant,
    LocalVerdict,
    MultirateLoop,
    NotApplicableError,
    implemented_record,
    implemented_text,
    multirate_loop,
)
from dvfc.analysis.output import append_log, raise_if_interrupted, read_log
from dvfc.analysis.record import ABSENT, Absent, Record
from dvfc.analysis.results import envelope_record
from dvfc.analysis.sampled import SampledSimulator, as_implemented, limit_record, robot_limits, sampled_simulator
from dvfc.analysis.scenario import ScenarioError
from dvfc.analysis.simulate import RunStatus, Settings, Trajectory, rotation_angle
from dvfc.models.errors import PlantErrors
from dvfc.models.loop import ClosedLoop
from dvfc.models.robot import Payload, Robot

CRITERION = (
    "holds: the run as implemented completes (no divergence, singularity or stop, every feature inside the "
    "image), within the URDF's position and velocity limits and, when saturate is off, its effort limits, and "
    "the true tracking error g_d^-1 g over "
    "the last half of the run within {bound}"
)
TRACKING_FACTOR = 2.0
"""Without a certified envelope, the tracking bound is this times the continuous loop's
error over the last half of the run (position and angle each)."""

STEPS = 6
"""Bisection steps after the range end: the bracket shrinks to 1/64 of the range (a
factor ``(hi/lo)^(1/64)`` for the parameters searched geometrically)."""

PERIODS = 3
"""Whole periods of the target's motion a run's growth is judged on (docs/math.md, fact 26), at least, after its
first period (the start's transient): the last one's level against the one before it (:func:`envelope_growth`)."""

GROWTH_RATE = 0.01
"""1/s: a run is growing when its last period's root-mean-square tracking ratio exceeds the one before it by
more than ``exp(GROWTH_RATE T)`` (``T`` the period). A mode growing by ``rho = 1 + 1e-3`` per common period
``P`` of fact 14 grows at ``ln(1 + 1e-3) / P``, at least 0.01 1/s for ``P <= 0.1`` s (0.020 1/s at the
default's 50 ms): once it dominates, each period's level is ``rho^(T/P)`` times the last (1.083 on the
default's 4 s circle) against the 1.041 allowed."""

HORIZONS = (1, 2, 4)
"""The horizons a run is judged on, as multiples of the scenario's duration: the first whose
error envelope has stopped growing; still growing at the last, the run does not hold."""

LINEAR = ("latency", "camera_rate")
"""The searched parameters fact 14 has a linear margin for (its control-rate margin has no
measured twin: the control rate is not searched)."""

PLANT = ("payload_mass", "torque_scale", "mount_rotation", "focal_length_error", "friction_scale")
"""The searched parameters that change the plant fact 14 linearises (:class:`DeclaredPlant`): their linear
margin is where the plant as declared with the value, linearised anew, stops being stable (``rho >= 1``, no
equilibrium near the model's, or saturation there; :meth:`LinearCheck.margin`), and at each search point the
same check is made: a point where it fails does not hold."""

UNCHECKED = {
    "pixel_noise": "noise is an input of the linearised loop, not a change of it: its stability does not depend on "
                   "the noise's size",
    "frame_drop": "a dropped frame changes the schedule at random, and fact 14's monodromy is that of the fixed "
                  "schedule: drops are not certified",
}  # fmt: skip
"""The searched parameters fact 14 does not check, and why."""

PLANT_STEPS = 10
"""Bisection steps of a plant parameter's linear margin (:meth:`LinearCheck.margin`): its bracket is 1/1024
of the searched range (a factor ``(end/start)^(1/1024)`` for the torque scale)."""

PAYLOAD_FACTOR = 0.5
"""The payload's searched range ends at this times the URDF's total link mass (no rated
payload is known for an arm): 10.5 kg on the UR5 (20.99 kg of links; rated 5 kg)."""

STEADY = (
    "; a run that holds has reached a steady state: over whole periods of {period:.4g} s ({what}) after the first, "
    "at least {periods}, the root-mean-square tracking ratio (the larger of position and angle over their bounds) "
    "of the last at most exp({rate:g}/s x period) = {limit:.4g}x the one before it (a mode growing by rho = 1 + "
    "1e-3 per 50 ms fails it once it dominates), the horizon doubled up to {most:g}x the scenario's until it is "
    "(else: does not hold, error still growing or not judged); {linear}"
)
LINEAR_CLAUSE = (
    "where fact 14 applies, a latency or camera rate at which the sampled loop linearised at rest is unstable "
    "(rho >= 1) does not hold, and a measured margin is never reported beyond fact 14's linear one; at a payload, "
    "torque scale, mount rotation, focal-length error or friction scale the plant as declared with the value is "
    "linearised anew, and a point where its monodromy has rho >= 1 (or it has no equilibrium, or saturates there) "
    "does not hold"
)
"""Added to :data:`CRITERION` for the margins' runs (a campaign's runs are judged on their own horizon)."""


class MarginError(RuntimeError):
    """The scenario's own run does not hold: there is no margin to measure."""


@dataclass(frozen=True)
class Parameter:
    """A searched parameter: its unit, whether larger values are worse (``"up"``) or smaller
    (``"down"``, searched geometrically), and the end of the searched range (with
    ``per_arm_mass``, as a multiple of the URDF's total link mass)."""

    name: str
    unit: str
    worse: str
    end: float
    per_arm_mass: bool = False


PARAMETERS = {
    "latency": Parameter("latency", "s", "up", 0.25),
    "camera_rate": Parameter("camera_rate", "Hz", "down", 1.0),
    "payload_mass": Parameter("payload_mass", "kg", "up", PAYLOAD_FACTOR, per_arm_mass=True),
    "pixel_noise": Parameter("pixel_noise", "px", "up", 50.0),
    "torque_scale": Parameter("torque_scale", "x URDF effort", "down", 0.05),
    "mount_rotation": Parameter("mount_rotation", "deg", "up", 45.0),
    "focal_length_error": Parameter("focal_length_error", "relative", "up", 1.0),
    "friction_scale": Parameter("friction_scale", "x reference friction", "up", 20.0),
    "frame_drop": Parameter("frame_drop", "probability", "up", 0.95),
}
"""The searched parameters (the payload's end is :data:`PAYLOAD_FACTOR` of the URDF's total
link mass, :func:`range_end`). ``mount_rotation``: the true camera mount turned about the nominal
camera's x axis (a tilt of the optical axis) by this angle; ``focal_length_error``: the true
``fx`` and ``fy`` this fraction above the controller's; ``friction_scale``: joint friction this
multiple of the reference friction (:func:`reference_friction`); ``frame_drop``: the probability
an image is lost. Each is an input of the compiled loop (no run recompiles) except the payload."""

DEFAULT_FRICTION = (0.005, 0.02)
"""Viscous (per rad/s or m/s) and Coulomb friction as fractions of each joint's effort limit: the
reference friction where neither the scenario nor the URDF gives any (harmonic-drive joints lose a
few percent of their rated torque to friction; an assumed magnitude, stated)."""


def reference_friction(loop: ClosedLoop, settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    """The friction ``friction_scale`` multiplies: the scenario's ``[plant] friction`` (its
    viscous and Coulomb terms per joint) when it has any, else :data:`DEFAULT_FRICTION` of the
    URDF's effort limits (0 on a joint without one)."""
    e = settings.errors
    if e is not None and (np.any(e.viscous) or np.any(e.coulomb)):
        return np.asarray(e.viscous, float), np.asarray(e.coulomb, float)
    effort = np.where(np.isfinite(loop.robot.limits.effort), loop.robot.limits.effort, 0.0)
    return DEFAULT_FRICTION[0] * effort, DEFAULT_FRICTION[1] * effort


def base_value(name: str, settings: Settings) -> float:
    """The scenario's value of a parameter (the plant-error parameters: 0, or 1 for the friction
    scale of a scenario with friction)."""
    imp, e = settings.implementation, settings.errors
    if name == "payload_mass":
        plant = settings.plant
        return 0.0 if plant is None or plant.payload is None else plant.payload.mass
    if name == "friction_scale":
        return float(e is not None and (np.any(e.viscous) or np.any(e.coulomb)))
    if name in ("mount_rotation", "focal_length_error"):
        return 0.0
    return float(getattr(imp, name))


def urdf_mass(robot: Robot) -> float:
    """The total mass of the links of the robot's URDF (kg): the sum of every ``<inertial>``'s mass."""
    masses = ET.parse(robot.urdf).getroot().iterfind("link/inertial/mass")
    return float(sum(float(m.get("value", 0.0)) for m in masses))


def range_end(name: str, loop: ClosedLoop, settings: Settings) -> float:
    """The end of a parameter's searched range as simulated: :attr:`Parameter.end`, times the
    URDF's total link mass for the payload (:func:`urdf_mass`), on the grid of :func:`grid_value`."""
    p = PARAMETERS[name]
    end = p.end * urdf_mass(loop.robot) if p.per_arm_mass else p.end
    return grid_value(name, end, settings)


def grid_value(name: str, value: float, settings: Settings) -> float:
    """The value a run is made at: the latency in whole control periods, the camera rate an
    image every whole number ``N`` of control periods (``control_rate / N``: fact 14's exact
    schedules), any other parameter as given."""
    rate = settings.sampled.control_rate
    if name == "latency":
        return round(value * rate) / rate
    if name == "camera_rate":
        return rate / max(1, round(rate / value))
    return value


def with_value(loop: ClosedLoop, settings: Settings, name: str, value: float) -> Settings:
    """The settings with one parameter changed (latency and camera rate on the grid of
    :func:`grid_value`).

    Every parameter is an input of the compiled code (a payload's mass, centre and inertia are
    inputs of the plant's functions: a new mass compiles nothing), or acts between its calls; the
    plant-error parameters replace one entry of
    the settings' ``errors`` (none: :meth:`PlantErrors.none`), keeping the others."""
    if name == "payload_mass":
        plant = settings.plant
        r = loop.robot
        old = plant.payload if plant is not None and plant.payload is not None else Payload(0.0)
        scale = 1.0 if plant is None else plant.mass_scale
        payload = Robot(r.urdf, r.frame, r.mount, r.armature, replace(old, mass=value), scale)
        return replace(settings, plant=payload)
    if name in ("mount_rotation", "focal_length_error", "friction_scale"):
        errors = settings.errors or PlantErrors.none(loop.camera, loop.robot.n)
        if name == "mount_rotation":
            errors = replace(errors, mount_rpy=np.array([np.radians(value), 0.0, 0.0]))
        elif name == "focal_length_error":
            fx = loop.camera.focal_length * (1 + value)
            errors = replace(errors, fx=fx, fy=fx * loop.camera.aspect)
        else:
            viscous, coulomb = reference_friction(loop, settings)
            errors = replace(errors, viscous=value * viscous, coulomb=value * coulomb)
        return replace(settings, errors=errors)
    changed: dict[str, Any] = {name: grid_value(name, value, settings)}
    return replace(settings, implementation=replace(settings.sampled, **changed))


@dataclass(frozen=True)
class TrackingBound:
    """What the true tracking error ``g_d^-1 g`` over the last half of a run is held to: its
    position (m) and rotation angle (deg), and how the bound was obtained (``source``: ``"scenario"``,
    ``"envelope"`` or ``"continuous"``; ``text`` completes :data:`CRITERION`)."""

    position: float
    angle_deg: float
    source: str
    text: str

    def as_dict(self) -> dict:
        return {"position": self.position, "angle_deg": self.angle_deg, "source": self.source}

    @property
    def limits(self) -> tuple[float, float]:
        """``(position m, angle deg)``: what fact 29's tracking error at rest is judged against."""
        return self.position, self.angle_deg


def tracking_samples(traj: Trajectory, start: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The position ``|p|`` (m) and rotation angle (deg, by :func:`rotation_angle`) of the true
    tracking error ``g_d^-1 g`` at each output sample from ``start`` on."""
    err = traj["g_tracking"][start:].reshape(-1, 4, 4).transpose(0, 2, 1)  # CasADi vec: columns
    return np.linalg.norm(err[:, :3, 3], axis=1), np.degrees(rotation_angle(err[:, :3, :3]))


def tracking_error(traj: Trajectory) -> tuple[float, float]:
    """The largest position ``|p|`` (m) and rotation angle (deg) of the true tracking error
    ``g_d^-1 g`` over the last half of the run."""
    position, angle = tracking_samples(traj, len(traj.t) // 2)
    return float(position.max()), float(angle.max())


@dataclass(frozen=True)
class Growth:
    """The envelope of a run's tracking error over whole periods ``period`` of the target's motion, counted
    back from the run's end and after its first period, oldest first (at least :data:`PERIODS`): each
    period's root-mean-square tracking ratio (``levels``; the ratio the larger of position and angle over the
    bound's, sample by sample) and its peak (``peaks``). ``growing`` when the last period's level exceeds the
    one before it by more than ``limit = exp(GROWTH_RATE period)``: consecutive periods, so that no transient
    of an earlier period hides a growing mode, and levels (means over a period) so that what does not repeat
    with the period (pixel noise, a slower component) moves the comparison far less than it moves peaks."""

    period: float
    levels: tuple[float, ...]
    peaks: tuple[float, ...]

    @property
    def previous(self) -> float:
        """The level of the period before the last."""
        return self.levels[-2]

    @property
    def last(self) -> float:
        return self.levels[-1]

    @property
    def limit(self) -> float:
        return math.exp(GROWTH_RATE * self.period)

    @property
    def ratio(self) -> float:
        """``last / previous``."""
        return self.last / self.previous if self.previous > 0 else (math.inf if self.last > 0 else 1.0)

    @property
    def growing(self) -> bool:
        return self.ratio > self.limit

    def as_dict(self) -> dict:
        return {"period": self.period, "levels": list(self.levels), "peaks": list(self.peaks),
                "previous_level": self.previous, "last_level": self.last, "ratio": self.ratio, "limit": self.limit,
                "growing": self.growing}  # fmt: skip


def judged_period(loop: ClosedLoop, duration: float) -> float:
    """The period a run's growth is judged over: the target's motion's (:attr:`TargetMotion.motion_period`)
    when :data:`PERIODS` of them after the first fit the longest horizon (:data:`HORIZONS`), else (a target at
    rest, or too slow) ``duration / (PERIODS + 1)``."""
    period = loop.target.motion_period
    if period is None or (PERIODS + 1) * period > HORIZONS[-1] * duration * (1 + 1e-9):
        return duration / (PERIODS + 1)
    return period


def envelope_growth(traj: Trajectory, bound: TrackingBound, period: float) -> Growth | None:
    """:class:`Growth` of a completed run over whole periods ``period`` ending at its end and starting at or
    after ``period`` (the first period, the start's transient, left out); None when fewer than
    :data:`PERIODS` fit (a longer run is needed). A periodic steady error repeats its level every period
    (ratio 1); an error growing like ``exp(a t)`` gives ``exp(a period)`` once it dominates."""
    position, angle = tracking_samples(traj)
    ratio = np.maximum(position / bound.position, angle / bound.angle_deg)
    t, end = np.asarray(traj.t), float(traj.t[-1])
    count = math.floor(end / period + 1e-9) - 1  # whole periods after the first
    if count < PERIODS:
        return None
    edges = end - period * np.arange(count, -1, -1)
    periods = [ratio[(t > a + 1e-9) & (t <= b + 1e-9)] for a, b in itertools.pairwise(edges)]  # (a, b]: equal counts
    levels = tuple(float(np.sqrt(np.mean(r * r))) for r in periods)
    return Growth(period, levels, tuple(float(r.max()) for r in periods))


def judge(traj: Trajectory, loop: ClosedLoop, settings: Settings, bound: TrackingBound) -> tuple[bool, str]:
    """Whether a run holds by :data:`CRITERION`, with the reason when it does not."""
    if traj.status is not RunStatus.OK:
        return False, f"{traj.status}: {traj.message}"
    record = limit_record(traj, robot_limits(loop, settings))
    ratio = max(record["torque_commanded_ratio"])
    if ratio > 1 and not settings.sampled.saturate:
        return False, f"peak torque {ratio:.4g}x the effort limit"
    if not record["within_velocity"]:
        return False, f"peak joint speed {max(record['speed_ratio']):.4g}x the velocity limit"
    if not record["within_position"]:
        return False, f"joint range {max(record['position_ratio']):.4g}x the position limits (1: at a limit)"
    position, angle = tracking_error(traj)
    within = position <= bound.position and angle <= bound.angle_deg
    detail = (f"tracking error {position:.3g} m {'<=' if position <= bound.position else '>'} {bound.position:.3g} m, "
              f"{angle:.3g} deg {'<=' if angle <= bound.angle_deg else '>'} {bound.angle_deg:.3g} deg")  # fmt: skip
    return within, detail


def envelope_bound(case: Case, envelope: dict | None = None) -> TrackingBound | None:
    """The tracking bound the operating envelope certifies for the scenario's design (docs/math.md,
    fact 7, :func:`dvfc.analysis.results.envelope_record`): ``g_d^-1 g = g_ec g_ee`` (from (15),
    (24)), so its position is at most ``|p_ec| + |p_ee|`` and its angle at most
    ``theta_ec + theta_ee`` (the triangle inequality on SO(3)), each at the certified
    ultimate bound (of ``envelope``, the case's :func:`~dvfc.analysis.results.envelope_record`,
    computed here when not given). None when no envelope with rotation bounds is certified."""
    env = envelope_record(case, search=False) if envelope is None else envelope
    own = "without_integral" not in env
    env = env.get("without_integral", env)  # integral action (fact 20.4): the same design's without K_I
    b = env.get("bounds")
    if b is None or b["theta_ec_deg"] is None:
        return None
    position, angle = b["p_ec"] + b["p_ee"], min(180.0, b["theta_ec_deg"] + b["theta_ee_deg"])
    whose = "the operating envelope's" if own else "the same design's without integral action (K_I = 0):"
    text = (
        f"{whose} certified ultimate bound (docs/math.md, fact 7: the ideal continuous loop under its "
        f"disturbance bounds, wbar = {env['wbar']:.4g}): position <= |p_ec| + |p_ee| = {b['p_ec']:.4g} + "
        f"{b['p_ee']:.4g} = {position:.4g} m and angle <= theta_ec + theta_ee = {b['theta_ec_deg']:.4g} + "
        f"{b['theta_ee_deg']:.4g} = {angle:.4g} deg (g_d^-1 g = g_ec g_ee, triangle inequality; the envelope's "
        "xi bound is a joint-velocity error, not compared)"
    )
    return TrackingBound(position, angle, "envelope", text)


def continuous_bound(case: Case) -> TrackingBound:
    """:data:`TRACKING_FACTOR` times the continuous loop's tracking error, position and angle
    each (the scenario's loop without its ``[implementation]`` and ``[plant]``)."""
    paper = replace(case.settings, implementation=None, plant=None)
    traj = as_implemented(case.loop, paper).run(case.s0)
    if traj.status is not RunStatus.OK:
        raise MarginError(f"the continuous loop itself does not complete ({traj.message})")
    position, angle = (TRACKING_FACTOR * e for e in tracking_error(traj))
    text = (f"{TRACKING_FACTOR:g}x the continuous loop's (no operating envelope with rotation bounds is certified "
            f"for this design): position <= {position:.4g} m and angle <= {angle:.4g} deg")  # fmt: skip
    return TrackingBound(position, angle, "continuous", text)


def tracking_bound(case: Case, envelope: dict | None = None) -> TrackingBound:
    """The scenario's pinned ``[criterion]`` (source ``"scenario"``), else the envelope's certified
    tracking bound (:func:`envelope_bound`), else :func:`continuous_bound`."""
    pinned = case.scenario.criterion
    if pinned is not None:
        text = (f"the scenario's [criterion], pinned: position <= {pinned.position:.4g} m and angle <= "
                f"{pinned.angle_deg:.4g} deg")  # fmt: skip
        return TrackingBound(pinned.position, pinned.angle_deg, "scenario", text)
    return envelope_bound(case, envelope) or continuous_bound(case)


SIMULATORS = 4
"""Simulators kept per process (least recently used dropped): one a case, with and without plant errors."""

_simulators: OrderedDict[tuple[int, bool], tuple[Case, SampledSimulator]] = OrderedDict()


def shared_simulator(case: Case, errors: bool) -> SampledSimulator:
    """The simulator of ``case`` as implemented, with plant errors (none when the scenario gives
    none, as :func:`with_value` sets them) or without, built once per process: every run of a
    parameter other than the payload runs on it (:meth:`SampledSimulator.for_run`), without
    building its functions again."""
    key = (id(case), errors)
    if key in _simulators:
        _simulators.move_to_end(key)
        return _simulators[key][1]
    settings = case.settings
    if errors and settings.errors is None:
        settings = replace(settings, errors=PlantErrors.none(case.loop.camera, case.loop.robot.n))
    simulator = sampled_simulator(case.loop, settings)
    _simulators[key] = (case, simulator)  # the case held: its id stays its own while cached
    if len(_simulators) > SIMULATORS:
        _simulators.popitem(last=False)
    return simulator


@dataclass(frozen=True)
class LinearCheck:
    """Fact 14 beside the measured searches: the sampled loop linearised at rest for the plant as
    declared (``system``), its linear margins (``margins``, :func:`dvfc.analysis.multirate.linear_margins`)
    and the case (``case``: a plant parameter's value changes the plant, linearised anew; ``criterion``: what
    its dry friction's tracking error at rest is judged against, fact 29), or, where the statement does not
    apply, ``reason``."""

    system: MultirateLoop | None
    margins: dict | None
    reason: str | None
    case: Case | None = None
    criterion: tuple[float, float] | None = None

    @staticmethod
    def of(case: Case, record: dict, criterion: tuple[float, float] | None = None) -> LinearCheck:
        """The check of a case from its fact-14 record (:func:`implemented_record`)."""
        if record["margins"] is None:
            return LinearCheck(None, None, record["reason"])
        plant = DeclaredPlant.of(case.settings)
        system = multirate_loop(case.loop, case.s0[: case.loop.robot.n], case.settings.sampled, plant)
        return LinearCheck(system, record["margins"], None, case, criterion)

    def rho(self, name: str, value: float) -> float | None:
        """``rho(Pi)`` with ``name = value`` (a value of :func:`grid_value`): of the schedule for
        :data:`LINEAR`, of the plant as declared with the value for :data:`PLANT` (:meth:`plant_verdict`);
        None where not checked (not a parameter of either, the statement does not apply, no exact schedule)."""
        if self.system is None or name not in LINEAR + PLANT:
            return None
        if name in PLANT:
            verdict = self.plant_verdict(name, value)
            return None if verdict is None else verdict.rho
        try:
            return self.system.rho(**{name: value})
        except NotApplicableError:
            return None

    def plant_verdict(self, name: str, value: float) -> LocalVerdict | None:
        """Fact 14 for the plant as declared with ``name = value`` (one of :data:`PLANT`), by the one function
        ``certify`` and campaigns use (:func:`dvfc.analysis.multirate.local_verdict`, every check included;
        not certified where that plant has no equilibrium near the model's or saturates there); None where the
        statement does not apply."""
        assert self.case is not None and name in PLANT, "LinearCheck.of, a plant parameter"
        loop, changed = self.case.loop, with_value(self.case.loop, self.case.settings, name, value)
        return DeclaredPlant.of(changed).verdict(loop, self.case.s0[: loop.robot.n], changed.sampled, self.criterion)

    def margin(self, name: str, start: float, end: float) -> dict | None:
        """Fact 14's linear margin of a parameter searched from ``start`` to ``end``, a record ``{"value", "unit",
        "stable_at", "unstable_at", "range"}`` as :func:`dvfc.analysis.multirate.linear_margins` gives them
        (``value`` None when stable over the whole range): the record's own for :data:`LINEAR`; for :data:`PLANT`,
        by bisection of :meth:`rho` between ``start`` and ``end`` (geometric for a parameter worse downwards) in
        :data:`PLANT_STEPS` steps. None where not checked. A bisection finds one boundary between a stable and
        an unstable value: stability between is not checked value by value (each search point is)."""
        if self.margins is None or name not in LINEAR + PLANT:
            return None
        if name in LINEAR:
            return self.margins[name]
        p = PARAMETERS[name]

        def stable(value: float) -> bool:
            verdict = self.plant_verdict(name, value)
            return verdict is not None and verdict.certified

        out = {"unit": p.unit, "range": [start, end]}
        if stable(end):
            return {**out, "value": None, "stable_at": end, "unstable_at": None}
        good, bad = start, end
        for _ in range(PLANT_STEPS):
            mid = math.sqrt(good * bad) if p.worse == "down" else (good + bad) / 2
            good, bad = (mid, bad) if stable(mid) else (good, mid)
        return {**out, "value": good, "stable_at": good, "unstable_at": bad}


def _simulator(case: Case, name: str, settings: Settings) -> SampledSimulator:
    """The simulator of a search point: the process's :func:`shared_simulator` for ``settings``, but
    for a payload (a new plant: a simulator of its own, on the same compiled libraries under ``jit``)."""
    if name == "payload_mass":
        return sampled_simulator(case.loop, settings)
    return shared_simulator(case, settings.errors is not None).for_run(settings)


def unstable_text(rho: float, reason: str | None) -> str:
    """Why a run at a value where fact 14 does not certify the linearised sampled loop does not hold: its
    ``rho`` at least 1, or ``reason``, a check of its monodromy that fails (:class:`LocalVerdict`)."""
    if rho >= 1 - RHO_MARGIN:
        return f"the sampled loop linearised at rest is unstable at this value (fact 14: rho = {rho:.6g} >= 1)"
    return f"the sampled loop linearised at rest is not certified at this value (fact 14: {reason})"


def trial(
    case: Case, name: str, value: float, bound: TrackingBound, linear: LinearCheck | None = None,
    first: Trajectory | None = None,
) -> dict:  # fmt: skip
    """One search point ``name = value`` judged against ``bound`` (JSON-ready), with its wall
    time (s, setting up the simulators included).

    Where ``linear`` checks the parameter and the sampled loop linearised at rest is unstable
    at the value (``rho >= 1 - RHO_MARGIN``; for a parameter of the plant, not certified by
    :meth:`LinearCheck.plant_verdict`, every check of the monodromy included), the point does not
    hold, whatever its run. Else a
    run that holds by :func:`judge` must have reached a steady state (:func:`envelope_growth`):
    the horizon is doubled (:data:`HORIZONS`) until the envelope stops growing; growing at the
    last, the point does not hold. ``first``: the run on the scenario's horizon, when made."""
    loop = case.loop
    clock = time.perf_counter()
    changed = with_value(loop, case.settings, name, value)
    used = getattr(changed.implementation, name) if name in LINEAR else value
    rho, unstable, reason = None, False, None
    if linear is not None and linear.system is not None and name in PLANT:
        verdict = linear.plant_verdict(name, value)
        if verdict is not None:
            rho, unstable, reason = verdict.rho, not verdict.certified, verdict.reason
    elif linear is not None:
        rho = linear.rho(name, used)
        unstable = rho is not None and rho >= 1 - RHO_MARGIN
    horizons, growth, period = [], None, judged_period(loop, case.settings.duration)
    for factor in HORIZONS:
        settings = replace(changed, duration=factor * case.settings.duration)
        traj = first if factor == 1 and first is not None else _simulator(case, name, settings).run(case.s0)
        horizons.append(settings.duration)
        holds, detail = judge(traj, loop, settings, bound)
        growth = envelope_growth(traj, bound, period) if holds else None
        if unstable or not holds or (growth is not None and not growth.growing):
            break
    if unstable and rho is not None:
        holds, detail = False, f"{unstable_text(rho, reason)}; its run over {horizons[-1]:g} s: {detail}"
    elif holds and growth is None:
        holds, detail = False, (f"fewer than {PERIODS} whole periods of {period:.4g} s after the first in "
                                f"{horizons[-1]:g} s: growth not judged; {detail}")  # fmt: skip
    elif growth is not None and growth.growing:
        holds, detail = False, (f"error still growing at {horizons[-1]:g} s (the last {period:.4g} s period's "
                                f"root-mean-square {growth.ratio:.4g}x the one before it, > {growth.limit:.4g}); "
                                f"{detail}")  # fmt: skip
    linear_rho = {"rho": rho, "stable": None if rho is None else not unstable}
    return {"value": value, "holds": holds, "detail": detail, "seconds": time.perf_counter() - clock,
            "horizon": horizons[-1], "horizons": horizons, "growth": None if growth is None else growth.as_dict(),
            "linear": linear_rho}  # fmt: skip


def linear_statement(name: str, value: float | None, linear: LinearCheck | None,
                     margin: dict | None = None) -> dict:  # fmt: skip
    """A measured margin against fact 14's linear one: ``{"basis", "checked", "linear_margin", "value",
    "clipped", "statement"}``, ``value`` the margin to report (``value`` itself unless it lies beyond the
    linear margin: then the linear margin, ``clipped``), ``linear_margin`` fact 14's (None where not checked
    or stable over its whole range). ``margin``: the linear margin of a :data:`PLANT` parameter
    (:meth:`LinearCheck.margin`); a :data:`LINEAR` one's is the check's own. ``basis`` says which bounds the
    margin: ``"linear margin"`` (the schedule's), ``"linear margin of the plant as declared"`` or
    ``"measured only"``. ``value`` None: the run at the searched range's end holds (:data:`ENDS_HOLDING`)."""
    p = PARAMETERS[name]
    if name in LINEAR and linear is not None and linear.margins is not None:
        margin = linear.margins[name]
    if linear is None or margin is None:
        why = (f"fact 14 has no linear check for this parameter ({UNCHECKED[name]})" if name in UNCHECKED
               else "fact 14 not consulted" if linear is None else f"fact 14: {linear.reason}")  # fmt: skip
        return {"basis": "measured only", "checked": False, "linear_margin": None, "value": value, "clipped": False,
                "statement": f"measured only, not checked against fact 14: {why}"}  # fmt: skip
    m = margin
    basis = "linear margin" if name in LINEAR else "linear margin of the plant as declared"
    beyond = lambda v: v is None or (v > m["stable_at"] if p.worse == "up" else v < m["stable_at"])  # noqa: E731
    out = {"basis": basis, "checked": True, "linear_margin": m["value"], "value": value, "clipped": False}
    if m["value"] is None:
        return {**out, "statement": f"fact 14: the linearised loop is stable at the scenario's value and at its "
                                    f"searched range's end ({m['range'][1]:g} {p.unit}), not checked between: no "
                                    "linear margin found to clip to"}  # fmt: skip
    if beyond(value):
        measured = ("a run at the searched range's end that holds" if value is None
                    else f"the measured {value:.4g} {p.unit}")  # fmt: skip
        return {**out, "value": m["value"], "clipped": True,
                "statement": f"{measured} lies beyond fact 14's linear margin {m['value']:.4g} {p.unit} (unstable at "
                             f"{m['unstable_at']:.4g} {p.unit}): clipped to it"}  # fmt: skip
    return {**out, "statement": f"within fact 14's linear margin {m['value']:.4g} {p.unit}"}


ENDS_HOLDING = "its run at the searched range's end holds (no value between is run: the loop may break between)"
"""A search's reason when its run at the searched range's end holds: the bisection makes no other run."""


def search(case: Case, name: str, bound: TrackingBound, log: str | None = None,
           linear: LinearCheck | None = None) -> dict:  # fmt: skip
    """The bisection of one parameter (a task): the runs in ``log`` (JSON lines) are reused,
    new ones appended; each point by :func:`trial` (with ``linear``, fact 14's check). Returns
    the margin record, its value never beyond fact 14's linear margin (:func:`linear_statement`)."""
    settings = case.settings
    p = PARAMETERS[name]
    logged = [] if log is None else read_log(Path(log))
    done = {record["value"]: record for record in logged if "horizon" in record}  # older logs: runs made again

    def run(value: float) -> bool:
        if value not in done:
            done[value] = trial(case, name, value, bound, linear)
            raise_if_interrupted()  # the run may be cut short: not logged
            if log is not None:
                append_log(Path(log), done[value])
        return done[value]["holds"]

    start = base_value(name, settings)
    end = range_end(name, case.loop, settings)  # the value actually simulated
    resolution = (end / start) ** (0.5**STEPS) if p.worse == "down" else abs(end - start) * 0.5**STEPS
    margin = {"value": None, "unit": p.unit, "holds_at": None, "breaks_at": None, "range": [start, end],
              "resolution": resolution}  # fmt: skip
    if (p.worse == "down" and start <= end) or (p.worse == "up" and start >= end):
        return {**margin, "reason": "the scenario's value is already beyond the searched range"}
    plant_margin = None if linear is None or name not in PLANT else linear.margin(name, start, end)
    if run(end):
        checked = linear_statement(name, None, linear, plant_margin)
        return {**margin, "value": checked["value"], "holds_at": end, "reason": ENDS_HOLDING,
                "runs": len(done), "linear": checked, "holds_run": run_summary(done[end])}  # fmt: skip
    good, bad = start, end
    for _ in range(STEPS):
        mid = grid_value(name, math.sqrt(good * bad) if p.worse == "down" else (good + bad) / 2, settings)
        if mid in (good, bad):
            break
        if run(mid):
            good = mid
        else:
            bad = mid
    checked = linear_statement(name, good, linear, plant_margin)
    return {**margin, "value": checked["value"], "holds_at": good, "breaks_at": bad, "reason": None,
            "breaks_because": done[bad]["detail"], "runs": len(done), "linear": checked,
            "holds_run": run_summary(done[good]) if good in done else None,
            "breaks_run": run_summary(done[bad])}  # fmt: skip


def run_summary(record: dict) -> dict:
    """A search point's horizon and growth check (for the margin record)."""
    return {key: record[key] for key in ("value", "holds", "horizon", "horizons", "growth", "linear")}


def log_path(directory: Path, name: str) -> Path:
    """The log of parameter ``name``'s search in ``directory``."""
    return directory / f"{name}.jsonl"


def runs_done(directory: Path) -> int:
    """Runs recorded so far in the searches' logs (for progress)."""
    logs = (log_path(directory, n) for n in PARAMETERS)
    return sum(len(p.read_text().splitlines()) for p in logs if p.exists())


def planned_runs() -> int:
    """Runs a full search makes at most: per parameter the range end and :data:`STEPS`."""
    return len(PARAMETERS) * (1 + STEPS)


def applicable(name: str, settings: Settings, loop: ClosedLoop) -> str | None:
    """Why a parameter cannot be searched on this scenario, or None."""
    if name in ("pixel_noise", "mount_rotation", "focal_length_error") and loop.mode != "image":
        return f'{name.replace("_", " ")} acts through the image: needs e_e = "image"'
    if name == "friction_scale" and settings.sampled.integrator == "cvodes":
        return 'friction needs a fixed-step integrator ("auto", "rosenbrock" or "rk4")'
    if name == "mount_rotation" and settings.errors is not None and np.any(settings.errors.mount_rpy):
        return "the scenario's [plant] mount is already rotated: the search turns it about one axis from none"
    return None


def linear_margin_text(result: dict) -> str:
    """The linear margins of the loop as implemented (docs/math.md, fact 14) in words, or why
    the statement does not apply."""
    return implemented_text(result["linear_margins"])


@dataclass(frozen=True, kw_only=True)
class MarginsResult(Record):
    """``dvfc margins`` (docs/cli.md): each parameter's margin of the loop as implemented (measured), the
    criterion, the tracking bound, fact 14's linear margins, the scenario's own run; or (``margins``
    None) why there is none (``no_margins``); what would pass (``--what-would-pass``) and provenance,
    when made."""

    scenario: str
    margins: dict[str, dict[str, Any]] | None
    criterion: str | Absent = ABSENT
    tracking_bound: dict[str, Any] | Absent = ABSENT
    linear_margins: dict[str, Any] | Absent = ABSENT
    scenario_run: dict[str, Any] | Absent = ABSENT
    no_margins: str | Absent = ABSENT
    what_would_pass: dict[str, Any] | Absent = ABSENT
    provenance: dict[str, Any] | Absent = ABSENT


def margins(
    case: Case,
    directory: Path,
    *,
    map_tasks: Callable[[Callable, list[tuple]], Iterable],
    resume: bool = False,
    envelope: dict | None = None,
    own_run: Trajectory | None = None,
) -> MarginsResult:
    """Every margin of :data:`PARAMETERS` of the case and, beside them, the linear margins of the
    sampled loop linearised at rest (``linear_margins``: docs/math.md, fact 14,
    :func:`dvfc.analysis.multirate.implemented_record`), without provenance.
    ``map_tasks(function, argument_tuples)`` runs the searches (each task receives the case) and
    returns their results in order; ``envelope`` (the case's envelope record) and ``own_run``
    (the case run as implemented): when already computed."""
    spec, loop, s0, settings = case.scenario, case.loop, case.s0, case.settings
    if settings.implementation is None:
        raise ScenarioError("implementation: margins are of the loop as implemented; add an [implementation] section")
    bound = tracking_bound(case, envelope)
    record = implemented_record(loop, s0, settings, bound.limits)
    linear = LinearCheck.of(case, record, bound.limits)
    imp = settings.implementation
    own = trial(case, "latency", imp.latency, bound, linear, own_run)
    if not own["holds"]:
        raise MarginError(f"the scenario's own run does not hold ({own['detail']}): no margin to measure")
    names = [n for n in PARAMETERS if applicable(n, settings, loop) is None]
    logs = {n: log_path(directory, n) for n in names}
    if not resume:
        for log in logs.values():
            log.unlink(missing_ok=True)
    results = map_tasks(search, [(case, n, bound, str(logs[n]), linear) for n in names])
    found = dict(zip(names, results, strict=True))
    out = {}
    for name, p in PARAMETERS.items():
        reason = applicable(name, settings, loop)
        out[name] = found.get(name) or {"value": None, "unit": p.unit, "holds_at": None, "breaks_at": None,
                                        "reason": reason}  # fmt: skip
    unchecked = f"fact 14: {linear.reason}: the measured margins are not checked against linear ones"
    clause = LINEAR_CLAUSE if linear.margins is not None else unchecked
    period = judged_period(loop, settings.duration)
    what = ("the target's motion" if period == loop.target.motion_period
            else "a quarter of the scenario's duration: the target's motion has no period that fits")  # fmt: skip
    steady = STEADY.format(period=period, what=what, periods=PERIODS, rate=GROWTH_RATE,
                           limit=math.exp(GROWTH_RATE * period), most=HORIZONS[-1], linear=clause)  # fmt: skip
    return MarginsResult(scenario=spec.name, margins=out, criterion=CRITERION.format(bound=bound.text) + steady,
                         tracking_bound=bound.as_dict(), linear_margins=record, scenario_run=own)  # fmt: skip
