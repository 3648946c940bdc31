"""Where the loop as implemented stops working: measured margins of the nonlinear loop.

For each parameter of :data:`PARAMETERS` (the others at the scenario's values) the run of
:func:`dvfc.analysis.sampled.as_implemented` is repeated by bisection between the scenario's
value and the end of a stated range, and each run is judged by :func:`judge`: the loop
*holds* when the run completes (no divergence, singularity or stop, every feature in the
image), the joints stay within their position and velocity limits and, when ``saturate``
is off, the torques within the effort limits, and the
tracking error over the last half of the run stays within the operating envelope's
certified ultimate bound (docs/math.md, fact 7; twice the continuous loop's error where the design
has no certified envelope) (:data:`CRITERION`). These are measurements on simulated runs,
not certificates.

Each parameter's search is one task (local processes or a Dask cluster); every run is
appended to ``DIR/<parameter>.jsonl`` as it finishes, so an interrupted search resumes
with the runs already made.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.multirate import implemented_record, implemented_text
from dvfc.analysis.output import append_log, raise_if_interrupted, read_log
from dvfc.analysis.results import envelope_record
from dvfc.analysis.sampled import as_implemented, limit_record, robot_limits
from dvfc.analysis.scenario import ScenarioError
from dvfc.analysis.simulate import Settings, Trajectory, rotation_angle
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


class MarginError(RuntimeError):
    """The scenario's own run does not hold: there is no margin to measure."""


@dataclass(frozen=True)
class Parameter:
    """A searched parameter: its unit, whether larger values are worse (``"up"``) or smaller
    (``"down"``, searched geometrically), and the end of the searched range."""

    name: str
    unit: str
    worse: str
    end: float


PARAMETERS = {
    "latency": Parameter("latency", "s", "up", 0.25),
    "camera_rate": Parameter("camera_rate", "Hz", "down", 1.0),
    "payload_mass": Parameter("payload_mass", "kg", "up", 20.0),
    "pixel_noise": Parameter("pixel_noise", "px", "up", 50.0),
    "torque_scale": Parameter("torque_scale", "x URDF effort", "down", 0.05),
    "mount_rotation": Parameter("mount_rotation", "deg", "up", 45.0),
    "focal_length_error": Parameter("focal_length_error", "relative", "up", 1.0),
    "friction_scale": Parameter("friction_scale", "x reference friction", "up", 20.0),
    "frame_drop": Parameter("frame_drop", "probability", "up", 0.95),
}
"""The searched parameters. ``mount_rotation``: the true camera mount turned about the nominal
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


def with_value(loop: ClosedLoop, settings: Settings, name: str, value: float) -> Settings:
    """The settings with one parameter changed (latency rounded to whole control periods).

    A payload changes the plant's equations, so each mass is a new right-hand side: its runs
    are made in CasADi's virtual machine (``jit = False``) rather than compiling C code for
    every mass (see ``benchmarks/margins.py``). The other parameters are inputs of the
    compiled code, or act between its calls; the plant-error parameters replace one entry of
    the settings' ``errors`` (none: :meth:`PlantErrors.none`), keeping the others."""
    imp = settings.implementation
    if name == "payload_mass":
        plant = settings.plant
        r = loop.robot
        old = plant.payload if plant is not None and plant.payload is not None else Payload(0.0)
        scale = 1.0 if plant is None else plant.mass_scale
        payload = Robot(r.urdf, r.frame, r.mount, r.armature, replace(old, mass=value), scale)
        return replace(settings, plant=payload, jit=False)
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
    if name == "latency":
        value = round(value * imp.control_rate) / imp.control_rate
    return replace(settings, implementation=replace(imp, **{name: value}))


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


def tracking_error(traj: Trajectory) -> tuple[float, float]:
    """The largest position ``|p|`` (m) and rotation angle (deg) of the true tracking error
    ``g_d^-1 g`` over the last half of the run (angle by :func:`rotation_angle`)."""
    err = traj["g_tracking"][len(traj.t) // 2 :].reshape(-1, 4, 4).transpose(0, 2, 1)  # CasADi vec: columns
    angle = rotation_angle(err[:, :3, :3])
    return float(np.linalg.norm(err[:, :3, 3], axis=1).max()), float(np.degrees(angle.max()))


def judge(traj: Trajectory, loop: ClosedLoop, settings: Settings, bound: TrackingBound) -> tuple[bool, str]:
    """Whether a run holds by :data:`CRITERION`, with the reason when it does not."""
    if traj.status != "ok":
        return False, f"{traj.status}: {traj.message}"
    record = limit_record(traj, robot_limits(loop, settings))
    ratio = max(record["torque_commanded_ratio"])
    if ratio > 1 and not settings.implementation.saturate:
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
    if traj.status != "ok":
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


def trial(case: Case, name: str, value: float, bound: TrackingBound) -> dict:
    """One run at ``name = value`` judged against ``bound``, with its wall time (s, setting
    up the simulator included)."""
    loop = case.loop
    start = time.perf_counter()
    changed = with_value(loop, case.settings, name, value)
    traj = as_implemented(loop, changed).run(case.s0)
    holds, detail = judge(traj, loop, changed, bound)
    return {"value": value, "holds": holds, "detail": detail, "seconds": time.perf_counter() - start}


def search(case: Case, name: str, bound: TrackingBound, log: str | None = None) -> dict:
    """The bisection of one parameter (a task): the runs in ``log`` (JSON lines) are reused,
    new ones appended. Returns the margin record."""
    settings = case.settings
    p = PARAMETERS[name]
    done = {} if log is None else {record["value"]: record for record in read_log(Path(log))}

    def run(value: float) -> bool:
        if value not in done:
            done[value] = trial(case, name, value, bound)
            raise_if_interrupted()  # the run may be cut short: not logged
            if log is not None:
                append_log(Path(log), done[value])
        return done[value]["holds"]

    start = base_value(name, settings)
    period = 1.0 / settings.implementation.control_rate
    end = round(p.end / period) * period if name == "latency" else p.end  # the latency actually simulated
    margin = {"value": None, "unit": p.unit, "holds_at": None, "breaks_at": None, "range": [start, end]}
    if (p.worse == "down" and start <= end) or (p.worse == "up" and start >= end):
        return {**margin, "reason": "the scenario's value is already beyond the searched range"}
    if run(end):
        return {**margin, "holds_at": end, "reason": "holds over the whole searched range", "runs": len(done)}
    good, bad = start, end
    for _ in range(STEPS):
        mid = math.sqrt(good * bad) if p.worse == "down" else (good + bad) / 2
        if name == "latency":
            mid = round(mid / period) * period
            if mid in (good, bad):
                break
        if run(mid):
            good = mid
        else:
            bad = mid
    return {**margin, "value": good, "holds_at": good, "breaks_at": bad, "reason": None,
            "breaks_because": done[bad]["detail"], "runs": len(done)}  # fmt: skip


def runs_done(directory: Path) -> int:
    """Runs recorded so far in the searches' logs (for progress)."""
    return sum(len(p.read_text().splitlines()) for p in directory.glob("*.jsonl"))


def planned_runs() -> int:
    """Runs a full search makes at most: per parameter the range end and :data:`STEPS`."""
    return len(PARAMETERS) * (1 + STEPS)


def applicable(name: str, settings: Settings, loop: ClosedLoop) -> str | None:
    """Why a parameter cannot be searched on this scenario, or None."""
    if name in ("pixel_noise", "mount_rotation", "focal_length_error") and loop.mode != "image":
        return f'{name.replace("_", " ")} acts through the image: needs e_e = "image"'
    if name == "friction_scale" and settings.implementation.integrator != "rk4":
        return 'friction needs integrator = "rk4"'
    if name == "mount_rotation" and settings.errors is not None and np.any(settings.errors.mount_rpy):
        return "the scenario's [plant] mount is already rotated: the search turns it about one axis from none"
    return None


def linear_margin_text(result: dict) -> str:
    """The linear margins of the loop as implemented (docs/math.md, fact 14) in words, or why
    the statement does not apply."""
    return implemented_text(result["linear_margins"])


def margins(
    case: Case,
    directory: Path,
    *,
    map_tasks: Callable[[Callable, list[tuple]], list],
    resume: bool = False,
    envelope: dict | None = None,
    own_run: Trajectory | None = None,
) -> dict:
    """Every margin of :data:`PARAMETERS` of the case and, beside them, the linear margins of the
    sampled loop linearised at rest (``linear_margins``: docs/math.md, fact 14,
    :func:`dvfc.analysis.multirate.implemented_record`) (JSON-ready, without provenance).
    ``map_tasks(function, argument_tuples)`` runs the searches (each task receives the case) and
    returns their results in order; ``envelope`` (the case's envelope record) and ``own_run``
    (the case run as implemented): when already computed."""
    spec, loop, s0, settings = case.scenario, case.loop, case.s0, case.settings
    if settings.implementation is None:
        raise ScenarioError("implementation: margins are of the loop as implemented; add an [implementation] section")
    bound = tracking_bound(case, envelope)
    if own_run is None:
        own = trial(case, "latency", settings.implementation.latency, bound)
    else:
        holds, detail = judge(own_run, loop, settings, bound)
        own = {"value": settings.implementation.latency, "holds": holds, "detail": detail,
               "seconds": own_run.wall_time}  # fmt: skip
    if not own["holds"]:
        raise MarginError(f"the scenario's own run does not hold ({own['detail']}): no margin to measure")
    names = [n for n in PARAMETERS if applicable(n, settings, loop) is None]
    logs = {n: directory / f"{n}.jsonl" for n in names}
    if not resume:
        for log in logs.values():
            log.unlink(missing_ok=True)
    results = map_tasks(search, [(case, n, bound, str(logs[n])) for n in names])
    found = dict(zip(names, results, strict=True))
    out = {}
    for name, p in PARAMETERS.items():
        reason = applicable(name, settings, loop)
        out[name] = found.get(name) or {"value": None, "unit": p.unit, "holds_at": None, "breaks_at": None,
                                        "reason": reason}  # fmt: skip
    return {
        "scenario": spec.name,
        "margins": out,
        "criterion": CRITERION.format(bound=bound.text),
        "tracking_bound": bound.as_dict(),
        "linear_margins": implemented_record(loop, s0, settings),
        "scenario_run": own,
    }
