"""The typed results of the toolkit's jobs (:mod:`dvfc.analysis.record`: each field a key of the job's
JSON, serialised once by ``to_json``) and the records they are built of, shared by the command line
and the reports."""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.certify import (
    ASSUMPTIONS,
    NOT_APPLICABLE,
    PLANAR_ASSUMPTIONS,
    PLANAR_REGION,
    Certificate,
    GainPoint,
    TightCertificate,
    certify,
    certify_planar,
    exact_gamma,
    integral_coverage,
    region_text,
    tight_gamma,
    tight_gamma_planar,
)
from dvfc.analysis.envelope import ASSUMPTIONS as ENVELOPE_ASSUMPTIONS
from dvfc.analysis.envelope import (
    INTEGRAL_RATE,
    WITHOUT_FRICTION,
    FrictionBound,
    GridEnvelope,
    design_of,
    disturbance_bounds,
    envelope,
    friction_record,
    grid_envelope,
    said_for,
    start_storage,
    stated,
)
from dvfc.analysis.envelope import PLANAR_ASSUMPTIONS as PLANAR_ENVELOPE_ASSUMPTIONS
from dvfc.analysis.export import NO_COMPILER
from dvfc.analysis.grid import GridSpec, SweepState
from dvfc.analysis.implementation import SubstepChoice
from dvfc.analysis.linearize import MARGINAL_POLES, FromRest, from_rest
from dvfc.analysis.multirate import implemented_record
from dvfc.analysis.record import ABSENT, INTERNAL, Absent, Record
from dvfc.analysis.sampled import limit_record, robot_limits
from dvfc.analysis.scenario import Scenario
from dvfc.analysis.simulate import RunStatus, Settings, Trajectory, summary
from dvfc.analysis.start import StartStatement, for_plant, planned_start, ramp_start, until_integral
from dvfc.analysis.verify import Claim, ClaimStatus, verify
from dvfc.models.camera import Camera
from dvfc.models.errors import PlantErrors
from dvfc.models.loop import ClosedLoop, Weights


@dataclass(frozen=True, kw_only=True)
class SimulationResult(Record):
    """``dvfc simulate``: a run of the case (docs/cli.md): its summary, how the loop was implemented and
    integrated, per joint its peaks against the URDF's limits, the files written; a replayed campaign
    run's row (``campaign_row``) by the margins criterion."""

    scenario: str
    mode: str
    implementation: dict[str, Any]
    integration: dict[str, Any] | None
    summary: dict[str, Any]
    limits: dict[str, Any]
    outputs: dict[str, str]
    provenance: dict[str, Any]
    campaign_row: dict[str, Any] | Absent = ABSENT
    run: Trajectory = field(metadata=INTERNAL, repr=False, compare=False)

    @property
    def completed(self) -> bool:
        """The run reached its horizon."""
        return self.run.status is RunStatus.OK


@dataclass(frozen=True, kw_only=True)
class PoseResult(Record):
    """``dvfc pose``: where everything is at the start (:func:`dvfc.analysis.pose.initial_view`), the
    configuration solved for (``pose --solve``; None: none), the gain windows (None: none) and what a run costs
    to integrate."""

    scenario: str
    solution: dict[str, Any] | None
    camera_in_world: dict[str, list[float]]
    target_in_world: dict[str, list[float]]
    target_in_camera: dict[str, list[float]]
    image_coordinates: str
    image_size: list[float] | None
    features: list[dict[str, Any]]
    gain_windows: dict[str, Any] | None
    integration: dict[str, Any]
    """How a run of the scenario is integrated and its measured cost (:func:`dvfc.analysis.pose.integration_cost`)."""
    windows_warning: str | None = field(default=None, metadata=INTERNAL)
    """The gain windows' warning (a ``k_xi,i`` outside its window), or None."""

    @property
    def in_view(self) -> bool:
        """Every feature point in front of the camera and inside the image."""
        return all(f["in_view"] for f in self.features)


@dataclass(frozen=True, kw_only=True)
class CertificateSummary(Record):
    """How many points were certified, the smallest certified gamma, the time taken (s)."""

    points: int
    certified: int
    gamma_min: float | None
    seconds: float


@dataclass(frozen=True, kw_only=True)
class CertificateResult(Record):
    """``dvfc certify``: Theorem 2 at the case's gains, or at the named points of its ``[grid]`` (with the
    grid's axes and stored files), each point a :func:`point_record`; assembled by :meth:`of` only."""

    scenario: str
    loop: str
    region: str
    assumptions: list[str]
    gamma_required: float | None
    grid: dict[str, Any] | Absent = ABSENT
    points: list[CertificatePoint]
    points_dataset: str | Absent = ABSENT
    points_csv: str | Absent = ABSENT
    summary: CertificateSummary
    provenance: dict[str, Any]

    @property
    def certified(self) -> bool:
        """Every point certified."""
        return self.summary.certified == self.summary.points

    @classmethod
    def of(cls, spec: Scenario, points: list[CertificatePoint], summary: CertificateSummary, provenance: dict,
           **grid: Any) -> CertificateResult:  # fmt: skip
        """The certificate of ``spec``'s loop over its ``[certify]`` region: its assumptions, the gamma it
        requires, the ``points``; ``grid``: a grid's ``grid``, ``points_dataset`` and ``points_csv``."""
        planar = spec.loop == "planar"
        return cls(scenario=spec.name, loop=spec.loop,
                   region=PLANAR_REGION if planar else region_text(math.radians(spec.certify.theta_max_deg)),
                   assumptions=list(PLANAR_ASSUMPTIONS if planar else ASSUMPTIONS),
                   gamma_required=spec.certify.gamma, points=points, summary=summary, provenance=provenance,
                   **grid)  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class ClaimsSummary(Record):
    """How many claims were checked (PASS or FAIL), failed and could not be decided; the time taken (s)."""

    claims: int
    failed: int
    inconclusive: int
    seconds: float

    @classmethod
    def of(cls, claims: list[Claim], seconds: float) -> ClaimsSummary:
        """The counts of ``claims`` (:attr:`Claim.status`), checked in ``seconds``."""
        count = lambda status: sum(c.status is status for c in claims)  # noqa: E731
        return cls(claims=count(ClaimStatus.PASS) + count(ClaimStatus.FAIL), failed=count(ClaimStatus.FAIL),
                   inconclusive=count(ClaimStatus.INCONCLUSIVE), seconds=seconds)  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class VerificationResult(Record):
    """``dvfc verify``: every claim of the paper checked on simulated runs of the case, at the gamma
    certified for its gains (``gamma_certified``: whether it is)."""

    scenario: str
    gamma: float | None
    gamma_certified: bool
    claims: list[Claim]
    summary: ClaimsSummary
    provenance: dict[str, Any]

    @property
    def passed(self) -> bool:
        """No claim fails and none is inconclusive."""
        return not (self.summary.failed or self.summary.inconclusive)


class StatementStatus(StrEnum):
    """What a review's statement is: a certificate re-checked (``CERTIFIED`` or not), one whose
    assumptions fail here (``DOES NOT APPLY``), a check on simulated runs (``PASS``, ``FAIL``,
    ``INCONCLUSIVE``), a measurement (``MEASURED``)."""

    CERTIFIED = "CERTIFIED"
    NOT_CERTIFIED = "NOT CERTIFIED"
    DOES_NOT_APPLY = "DOES NOT APPLY"
    PASS = "PASS"
    FAIL = "FAIL"
    INCONCLUSIVE = "INCONCLUSIVE"
    MEASURED = "MEASURED"

    @classmethod
    def certified(cls, holds: bool) -> StatementStatus:
        return cls.CERTIFIED if holds else cls.NOT_CERTIFIED


@dataclass(frozen=True, kw_only=True)
class Statement(Record):
    """One statement of a review: what it says, the loop it is about, its status, its detail.
    ``claims``: the row summing up the paper's claims checked on runs, which the verdict counts from
    the claims themselves."""

    statement: str
    loop: str
    status: StatementStatus
    detail: str
    claims: bool = field(default=False, metadata=INTERNAL)


@dataclass(frozen=True, kw_only=True)
class Verdict(Record):
    """A review's whole verdict (:func:`verdict`)."""

    passed: bool
    headline: str
    failed: list[dict[str, Any]]
    inconclusive: list[dict[str, Any]]
    not_certified: list[Statement]


def simulation_result(case: Case, trajectory: Trajectory, outputs: dict[str, Path], provenance: dict,
                      settings: Settings | None = None) -> SimulationResult:
    """The result of a run of the case (``dvfc simulate``; ``settings``: the run's, when not the case's,
    as a campaign run replayed)."""
    loop, settings = case.loop, settings or case.settings
    integration = None if settings.implementation is None else SubstepChoice.of_run(trajectory.stats).as_dict()
    return SimulationResult(scenario=case.name, mode=loop.mode, implementation=implementation_record(settings),
                            integration=integration, summary=summary(trajectory),
                            limits=limit_record(trajectory, robot_limits(loop, settings)),
                            outputs={name: str(path) for name, path in outputs.items()}, provenance=provenance,
                            run=trajectory)  # fmt: skip


def trajectory_arrays(case: Case, trajectory: Trajectory, settings: Settings | None = None) -> dict[str, np.ndarray]:
    """What ``trajectory.npz`` holds: the time grid, every signal, the running integrals
    (``int_<name>``) and the joints' effort and velocity limits (``settings`` as in
    :func:`simulation_result`)."""
    urdf = robot_limits(case.loop, settings or case.settings)
    integrals = {f"int_{k}": v for k, v in trajectory.integrals.items()}
    limits = {"effort_limit": urdf.effort, "velocity_limit": urdf.velocity}
    return {"t": trajectory.t, **trajectory.signals, **integrals, **limits}


def implementation_record(settings: Settings) -> dict:
    """How the run was implemented: the digital controller (None: the paper's continuous
    loop), the plant's departure from the URDF (None: none)."""
    imp, plant = settings.implementation, settings.plant
    return {
        "controller": None if imp is None else asdict(imp),
        "plant": None if plant is None else {
            "payload": None if plant.payload is None else asdict(plant.payload), "mass_scale": plant.mass_scale
        },
    }  # fmt: skip


def plant_errors_record(settings: Settings, camera: Camera) -> dict:
    """What acts on the plant of the loop as implemented that the law's model leaves out
    (``[plant]``, JSON-ready; each entry None when the plant has none of it): a payload, the
    masses' scale, joint friction (viscous and Coulomb per joint, the smoothing), the camera
    mount's error, the true intrinsics where they differ from ``camera`` (the controller's), the
    feature points' errors."""
    plant, errors = settings.plant, settings.errors
    record = dict.fromkeys(("payload", "mass_scale", "friction", "mount", "intrinsics", "point_errors"))
    if plant is not None:
        record["payload"] = None if plant.payload is None else asdict(plant.payload)
        record["mass_scale"] = None if plant.mass_scale == 1.0 else plant.mass_scale
    if errors is None:
        return record
    if np.any(errors.viscous) or np.any(errors.coulomb):
        record["friction"] = {"viscous": errors.viscous.tolist(), "coulomb": errors.coulomb.tolist(),
                              "smoothing": errors.smoothing}  # fmt: skip
    if np.any(errors.mount_xyz) or np.any(errors.mount_rpy):
        record["mount"] = {"xyz": errors.mount_xyz.tolist(), "rpy": errors.mount_rpy.tolist()}
    nominal = PlantErrors.none(camera, len(errors.viscous))
    true = {"fx": errors.fx, "fy": errors.fy, "principal_point": np.asarray(errors.principal_point).tolist(),
            "distortion": np.asarray(errors.distortion).tolist()}  # fmt: skip
    if any(not np.array_equal(np.asarray(v), np.asarray(getattr(nominal, k))) for k, v in true.items()):
        record["intrinsics"] = true
    if np.any(errors.point_errors):
        record["point_errors"] = np.asarray(errors.point_errors).tolist()
    return record


@dataclass(frozen=True, kw_only=True)
class CertificatePoint(Record):
    """One point of a certificate (``points[i]`` of ``dvfc certify``'s JSON): a grid's label and index,
    the gains and weights, the generalized plant's weights, Theorem 2's certificate (closed form, SDP
    cross-check, a posteriori margin, the worst rotation found), and when computed the scaled-storage
    bound (fact 4), the lower bounds on the true gain, the operating envelope (facts 7-10), the
    coverage of integral action (facts 20-21) and the loop as implemented's local certificate (fact 14)."""

    label: str | Absent = ABSENT
    index: int | Absent = ABSENT
    gains: dict[str, list[float]]
    weights: dict[str, float]
    weights_of_plant: dict[str, Any]
    certified: bool
    gamma: float | None
    method: str
    margin: float | None
    reason: str | None
    worst_rotation: list[list[float]] | None
    gamma_worst_found: float | None
    gap: float | None
    gamma_tight: float | Absent | None = ABSENT
    alpha: float | Absent | None = ABSENT
    tight_reason: str | Absent | None = ABSENT
    gamma_lower_linear: float | Absent = ABSENT
    hinf_python_control: float | Absent = ABSENT
    hinf_note: str | Absent = ABSENT
    gamma_lower_nonlinear: float | Absent = ABSENT
    worst_disturbance: dict[str, Any] | Absent = ABSENT
    gamma_lower: float | Absent | None = ABSENT
    lower_bound_reason: str | Absent = ABSENT
    tightness: float | Absent | None = ABSENT
    tightness_tight: float | Absent | None = ABSENT
    envelope: dict[str, Any] | Absent = ABSENT
    integral: dict[str, Any] | Absent = ABSENT
    implemented: dict[str, Any] | Absent = ABSENT


def point_record(point: GainPoint, cert: Certificate, tight: TightCertificate | None = None) -> CertificatePoint:
    """One gain point of a certificate (with the fact-4 bound when computed)."""
    extra: dict[str, Any] = {} if tight is None else {"gamma_tight": tight.gamma, "alpha": tight.alpha,
                                                      "tight_reason": tight.reason}  # fmt: skip
    return CertificatePoint(
        gains={"k_xi": point.k_xi.tolist(), "k_c": point.k_c.tolist(), "k_e": point.k_e.tolist()},
        weights={k: float(v) for k, v in asdict(point.weights).items()}, weights_of_plant=plant_record(point),
        certified=cert.certified, gamma=cert.gamma, method=cert.method, margin=cert.margin, reason=cert.reason,
        worst_rotation=cert.worst_rotation, gamma_worst_found=cert.gamma_worst_found, gap=cert.gap, **extra,
    )  # fmt: skip


def plant_record(point: GainPoint) -> dict:
    """The generalized plant's weights a certificate holds for (docs/math.md, fact 17): the output
    ``z = S x`` and the disturbance ``w = D_w d``, and whether they are the paper's (all ones)."""
    p = point.plant_weights
    return {
        "output": {"xi": list(p.xi), "e_c": p.e_c, "e_e": p.e_e},
        "disturbance": {"tau_d": list(p.tau_d), "translation": p.translation, "rotation": p.rotation},
        "paper": point.plant is None,
        "gain": "from d to z = S x, w = D_w d: int |z|^2 <= gamma^2 int |d|^2 + 2 V(0)",
    }


def channels_text(point: dict, planar: bool) -> str:
    """The channels an L2 certificate bounds, in words: the paper's ``w -> x``, or with the
    ``[performance]`` weights (docs/math.md, fact 17) ``d -> z = S x`` with ``w = D_w d``."""
    target = "v_o" if planar else "V_wo"
    paper = f"from w = [tau_d; {target}] to x = [xi; e_c; e_e]"
    plant = point.get("weights_of_plant")
    if plant is None or plant["paper"]:
        return paper
    out, dist = plant["output"], plant["disturbance"]
    fmt = lambda v: "[" + ", ".join(f"{x:g}" for x in v) + "]"  # noqa: E731
    velocity = f"{dist['translation']:g}" if planar else f"{dist['translation']:g} I3, {dist['rotation']:g} I3"
    return (f"from d to z = S x, w = [tau_d; {target}] = D_w d (generalized plant: S = diag({fmt(out['xi'])}, "
            f"{out['e_c']:g} I, {out['e_e']:g} I), D_w = diag({fmt(dist['tau_d'])}, {velocity}))")


def lower_bound_record(loop: ClosedLoop, s0: np.ndarray, point: CertificatePoint,
                       rest: FromRest | None = None, jit: bool = False) -> dict[str, Any]:  # fmt: skip
    """Lower bounds on the true L2 gain and how far the certificates sit above them: the
    linearisation's peak gain and the gain of the run from rest that ``verify`` checks Theorem 2 on
    (:func:`dvfc.analysis.linearize.sharpest_from_rest`, driven to its sharpness; ``rest``: both,
    when already made by :func:`dvfc.analysis.linearize.from_rest`; compiled under ``jit``): the fields of
    ``point`` they set."""
    try:
        rest = from_rest(loop, s0[: loop.robot.n], jit) if rest is None else rest
    except ValueError as exc:
        return {"gamma_lower": None, "lower_bound_reason": str(exc)}
    nonlinear, converged = rest.gain, rest.converged
    lower = max(rest.peak_gain, nonlinear)
    ratio = lambda g: g / lower if isinstance(g, float) else None  # noqa: E731
    return {
        "gamma_lower_linear": rest.peak_gain,
        "hinf_python_control": rest.hinf,
        **({"hinf_note": MARGINAL_POLES} if math.isinf(rest.hinf) else {}),
        "gamma_lower_nonlinear": nonlinear,
        "worst_disturbance": {"signal": "the linearisation's worst sinusoid", "frequency_rad_s": rest.peak_frequency,
                              "horizon_s": float(rest.run.t[-1]), "converged": converged},
        "gamma_lower": lower,
        "tightness": ratio(point.gamma),
        "tightness_tight": ratio(point.gamma_tight),
    }


def envelope_record(case: Case, *, search: bool = True) -> dict:
    """The operating envelope of the case's design (docs/math.md, facts 7-9), with what it assumes."""
    loop, point, planar = case.loop, case.point, case.planar
    if case.theorems_do_not_apply is not None:
        return {"rate": None, "reason": NOT_APPLICABLE.format(n=loop.robot.n)}
    design = design_of(point, None if planar else case.reference, loop.robot.mass_bounds)
    section = case.scenario.envelope
    theta = None if section is None or section.theta_bar_deg is None else math.radians(section.theta_bar_deg)
    disturbance = disturbance_bounds(section, loop)
    env = envelope(design, loop.camera, disturbance, start_storage(loop, case.s0), theta, search=search)
    mass = loop.robot.mass_bounds
    if loop.plan is not None:  # docs/math.md, fact 16b: the planned reference's start decides
        env = stated(env, planned_start(design, loop.camera, disturbance, env, loop.plan))
    elif loop.ramp is not None:  # fact 16a: the ramp's bound from t = 0 decides
        env = stated(env, ramp_start(design, loop.camera, disturbance, env, loop.ramp))
    record = env.to_json()
    if (friction := plant_friction(case)) is not None and not planar:  # docs/math.md, facts 18-19
        record["friction"] = friction_record(design, loop.camera, disturbance, start_storage(loop, case.s0), env,
                                             FrictionBound.of(friction, loop.compensation))  # fmt: skip
        record["start"] = for_plant(record["start"], WITHOUT_FRICTION)
        record["statement"] = f"{said_for(WITHOUT_FRICTION, record['statement'])}; {record['friction']['statement']}"
    if loop.integral:  # docs/math.md, fact 20.4: the law without K_I has this envelope, this design none
        without = {**record, "statement": f"the same design without integral action: {record['statement']}"}
        start = until_integral(record["start"], loop.integral_start)  # fact 20.6: until z_I moves
        until = f"; {start['statement']}" if start["inside"] else ""
        record = {key: None for key in record} | {
            "rate": None, "reason": INTEGRAL_RATE, "statement": f"no envelope certified: {INTEGRAL_RATE}{until}",
            "start": start, "disturbance": record["disturbance"],
            "wbar": record["wbar"], "without_integral": without, "friction": record.get("friction"),
        }  # fmt: skip
    return {
        **record,
        "m_hi_method": mass.method_hi,
        "m_lo_method": mass.method_lo,
        "K_e": "isotropic: R_ec = I decides (fact 2)" if planar or point.isotropic
        else "anisotropic: blockwise-minimum K_min, sound for every R_ec (fact 5)",
        "assumptions": list(PLANAR_ENVELOPE_ASSUMPTIONS if planar else ENVELOPE_ASSUMPTIONS),
    }


def plant_friction(case: Case) -> np.ndarray | None:
    """The plant's joint friction ``[b; c; eps]`` of the loop as implemented (``[plant] friction``), or None
    when it has none."""
    errors = case.settings.errors
    if errors is None or not (np.any(errors.viscous) or np.any(errors.coulomb)):
        return None
    return errors.friction_vector()


def grid_envelope_for(case: Case) -> GridEnvelope | None:
    """The context of a grid's envelope columns when the scenario has an ``[envelope]``."""
    section, loop = case.scenario.envelope, case.loop
    if section is None:
        return None
    design = design_of(case.point, None if case.planar else case.reference, loop.robot.mass_bounds)
    theta = None if section.theta_bar_deg is None else math.radians(section.theta_bar_deg)
    return grid_envelope(design, loop.camera, disturbance_bounds(section, loop), theta)


def speed_theta_bar(case: Case) -> float:
    """The ``theta_bar`` (radians) at which the target-speed synthesis works: the scenario's
    ``[envelope] theta_bar_deg``, else the one giving the scenario design's largest certified
    target speed (:func:`dvfc.analysis.envelope.grid_envelope`, the gain map's rule)."""
    section, loop = case.scenario.envelope, case.loop
    if section is not None and section.theta_bar_deg is not None:
        return math.radians(section.theta_bar_deg)
    design = design_of(case.point, case.reference, loop.robot.mass_bounds)
    return grid_envelope(design, loop.camera, disturbance_bounds(section, loop), None).theta_bar


def certificate_for(spec: Scenario, point: GainPoint, *, with_sdp: bool = True, bounded: bool = True) -> Certificate:
    """Theorem 2 for the scenario's loop: the paper's over the ``[certify]`` region, or the
    reduced planar loop's; ``bounded`` applies the ``[certify]`` gamma requirement."""
    bound = spec.certify.gamma if bounded else None
    if spec.loop == "planar":
        return certify_planar(point, gamma_bound=bound, with_sdp=with_sdp)
    theta_max = math.radians(spec.certify.theta_max_deg)
    return certify(point, spec.reference.se3(), theta_max=theta_max, gamma_bound=bound, with_sdp=with_sdp)


def certificate_result(
    case: Case, provenance: dict, *, lower_bounds: bool = True, rest: FromRest | None = None
) -> CertificateResult:
    """Theorem 2 at the case's gains: the paper's gamma, the fact-4 gamma, and (optionally)
    lower bounds on the true gain (``rest``: the run from rest they take, when already made), over
    the ``[certify]`` region; the operating envelope; with an implementation, the local
    certificate of the loop as implemented (``implemented``, docs/math.md, fact 14:
    :func:`dvfc.analysis.multirate.implemented_record`)."""
    start = time.perf_counter()
    spec, point, planar = case.scenario, case.point, case.planar
    cert = certificate_for(spec, point)
    tight = tight_gamma_planar(point) if planar else tight_gamma(point, case.reference)
    record = point_record(point, cert, tight if cert.gamma is not None else None)
    if lower_bounds:
        record = replace(record, **lower_bound_record(case.loop, case.s0, record, rest, case.settings.jit))
    record = replace(record, envelope=envelope_record(case))
    if (coverage := integral_coverage(point)) is not None:
        record = replace(record, integral=coverage)
    if case.settings.implementation is not None:
        record = replace(record, implemented=implemented_record(case.loop, case.s0, case.settings, case.criterion))
    summary_ = CertificateSummary(points=1, certified=int(cert.certified), gamma_min=cert.gamma,
                                  seconds=time.perf_counter() - start)  # fmt: skip
    return CertificateResult.of(spec, [record], summary_, provenance)


def verification_result(
    case: Case,
    provenance: dict,
    envelope: dict | None = None,
    implemented_run: Trajectory | None = None,
    rest: FromRest | None = None,
    paper_run: Trajectory | None = None,
) -> VerificationResult:
    """Every claim of the paper checked on simulated runs, at the gamma certified for the gains;
    the envelope's claims against ``envelope`` (:func:`envelope_record` of the case), the limits
    on ``implemented_run`` (the case run as implemented), Theorem 2 from rest on ``rest``
    (:func:`dvfc.analysis.linearize.from_rest`), the paper's loop in its own mode on ``paper_run``
    (the case's continuous run), each computed here when not given."""
    start = time.perf_counter()
    spec, loop, point = case.scenario, case.loop, case.point
    cert = certificate_for(spec, point, with_sdp=False, bounded=False)
    gamma = cert.gamma
    if gamma is None and case.theorems_do_not_apply is not None:  # test the paper's claims as written
        gamma = exact_gamma(point, case.reference, np.eye(3))[0]
        gamma = None if not np.isfinite(gamma) else gamma
    envelope = envelope_record(case, search=False) if envelope is None else envelope
    claims = verify(loop, case.s0, case.settings, gamma, envelope, implemented_run, rest, paper_run)
    return VerificationResult(scenario=spec.name, gamma=gamma, gamma_certified=cert.certified, claims=claims,
                              summary=ClaimsSummary.of(claims, time.perf_counter() - start),
                              provenance=provenance)  # fmt: skip


def best_gamma(point: dict) -> tuple[float | None, str]:
    """The best certified L2-gain bound of a certificate point and which certificate gives it:
    the paper's ``P(gamma) >= 0`` (Theorem 2) or the scaled storage ``alpha V`` (fact 4)."""
    paper, tight = point["gamma"] if point["certified"] else None, point.get("gamma_tight")
    if tight is not None and (paper is None or tight < paper):
        return tight, f"scaled storage alpha V (docs/math.md, fact 4, alpha = {point['alpha']:.4g})"
    return paper, "the paper's P(gamma) >= 0 (Theorem 2)"


def statements(
    certificate: dict, verification: dict, margins: dict | None = None, dispersion: dict | None = None,
    controller: dict | None = None,
) -> list[Statement]:
    """Every statement a review makes, each with the loop it is about and its own status
    (:class:`StatementStatus`), from the JSON of ``certificate`` and ``verification`` (the report's
    stored stages); ``margins`` and ``dispersion`` (the report's campaign, its ``summary`` the
    campaign's ``summary.json``): when measured; ``controller``: the exported program checked against
    the simulated one (:func:`dvfc.analysis.export.running_controller`), when the scenario has one."""
    S = StatementStatus
    point = certificate["points"][0]
    gamma, which = best_gamma(point)
    integral = point.get("integral")
    out = [Statement(
        statement="L2 gain (Theorem 2)", loop="ideal continuous loop, " + certificate["region"],
        status=S.certified(gamma is not None),
        detail=f"gamma <= {gamma:.6g} by {which}, {channels_text(point, certificate['loop'] == 'planar')}"
        + ("" if integral is None else f"; with integral action: {integral['theorem_2']}")
        if gamma is not None else str(point["reason"]),
    )]  # fmt: skip
    env = point.get("envelope") or {}
    if integral is not None:
        out.append(Statement(statement="constant-torque equilibrium (fact 20.3)",
                             loop="ideal continuous loop, static target", status=S.CERTIFIED,
                             detail=integral["constant_torque"]))  # fmt: skip
    if env.get("friction") is not None:
        out.append(Statement(statement="operating envelope with the plant's friction (fact 18)",
                             loop="ideal continuous loop with the [plant] friction",
                             status=S.certified(env["friction"]["certified"]),
                             detail=env["friction"]["statement"]))  # fmt: skip
    if env.get("rate") is None:
        out.append(Statement(statement="operating envelope (facts 7-10)", loop="ideal continuous loop",
                             status=S.NOT_CERTIFIED, detail=str(env.get("reason", "not computed"))))  # fmt: skip
        if (start := env.get("start") or {}).get("until_s") is not None:  # fact 20.6
            out.append(Statement(statement="the start, until integral action engages (fact 20.6)",
                                 loop=StartStatement.of(start).about, status=S.certified(start["inside"]),
                                 detail=start["statement"] if start["inside"] else str(start.get("reason"))),
                       )  # fmt: skip
    else:
        speed, own = env.get("max_target_speed"), env["disturbance"]["target_speed"]
        out += [
            Statement(statement="decay rate and ultimate bounds (facts 7, 10)", loop="ideal continuous loop",
                      status=S.CERTIFIED, detail=f"rate {env['rate']:.4g} 1/s, ultimate V <= {env['ultimate_V']:.4g}"),
            Statement(statement="every feature in the image (fact 8)", loop="ideal continuous loop, ultimately",
                      status=S.certified(env["visible"]),
                      detail=f"{env['image_margin_px']:.4g} px from the border" if env["visible"]
                      else env["statement"]),
            Statement(statement="at the target's own speed", loop="ideal continuous loop",
                      status=S.certified(speed is not None and speed >= own),
                      detail="largest target speed with every statement certified (features in view) "
                             f"{'-' if speed is None else f'{speed:.4g}'} m/s against {own:.4g} m/s"),
            Statement(statement="the start", loop=StartStatement.of(env["start"]).about,
                      status=S.certified(env["start"]["inside"]),
                      detail=f"V(0) = {env['start']['V0']:.4g} "
                             + ("inside the certified set" if env["start"]["inside"] else
                                "outside the certified set: the statements above hold only once the run enters it")),
        ]  # fmt: skip
    implemented = point.get("implemented")
    if implemented is not None:
        status = S.DOES_NOT_APPLY if not implemented["applies"] else S.certified(implemented["certified"])
        detail = (f"rho = {implemented['rho']:.6g} over {implemented['period'] * 1e3:.4g} ms, local rate "
                  f"{implemented['rate']:.4g} 1/s" if implemented["certified"] else str(implemented["reason"]))
        out.append(Statement(statement="local stability of the loop as implemented (fact 14)",
                             loop="sampled multirate loop, linearised at rest: local", status=status, detail=detail))
    if margins is not None and "margins" in margins:
        held = [f"{name} {m['holds_at']:.4g} {m['unit']}" for name, m in margins["margins"].items()
                if m.get("holds_at") is not None]  # fmt: skip
        out.append(Statement(statement="margins of the loop as implemented", loop="sampled nonlinear loop, simulated",
                             status=S.MEASURED, detail="holds at " + ", ".join(held)))  # fmt: skip
    if dispersion is not None and "summary" in dispersion:
        campaign = dispersion["summary"]
        loop = f"sampled nonlinear loop, simulated: {campaign['runs']} runs drawn from the [dispersion]"
        out.append(Statement(statement="dispersion campaign", loop=loop, status=S.MEASURED,
                             detail=campaign["statement"]))  # fmt: skip
    if controller is not None:
        out.append(program_statement(controller))
    summary_ = verification["summary"]
    status = S.FAIL if summary_["failed"] else S.INCONCLUSIVE if summary_["inconclusive"] else S.PASS
    out.append(Statement(statement="the paper's claims and the limits, checked on runs", loop="simulated runs",
                         status=status, detail=f"{summary_['claims']} checked, {summary_['failed']} fail, "
                                               f"{summary_['inconclusive']} inconclusive", claims=True))  # fmt: skip
    return out


def program_statement(controller: dict) -> Statement:
    """The statement that the program that runs is the controller the runs simulate: the compiled C
    step replayed on the run as implemented, sample by sample, and closing the plant's loop
    (:func:`dvfc.analysis.export.check`, within its stated tolerances); ``INCONCLUSIVE`` when it
    could not be compiled, ``DOES NOT APPLY`` when the loop has no program to export."""
    statement = "the exported program is the simulated controller (dvfc export --check)"
    loop = "the compiled C step on the loop as implemented's run, sample by sample and in closed loop"
    if "check" not in controller:
        status = StatementStatus.INCONCLUSIVE if controller["reason"] == NO_COMPILER else StatementStatus.DOES_NOT_APPLY
        return Statement(statement=statement, loop=loop, status=status, detail=f"not checked: {controller['reason']}")
    check, tolerance = controller["check"], controller["tolerances"]
    detail = (f"program SHA-256 {controller['sha256'][:16]}: {check['samples']} samples, largest torque difference "
              f"{check['max_abs_torque_difference']:.3g} N m (relative {check['max_rel_torque_difference']:.3g}, "
              f"at most {tolerance['torque_relative']:.0e}); closed loop: joints within "
              f"{check['closed_loop_max_state_difference']:.3g} (at most {tolerance['closed_loop']:.0e})")
    status = StatementStatus.PASS if check["passed"] else StatementStatus.FAIL
    return Statement(statement=statement, loop=loop, status=status, detail=detail)


def verdict(certificate: dict, verification: dict, statements_: list[Statement] | None = None) -> Verdict:
    """The whole verdict of a review: the certificate AND every check behind it.

    ``passed`` only when the design is certified, no claim fails, no check is inconclusive and no
    statement of the review (:func:`statements`, when given) FAILS (the exported program's replay,
    :func:`program_statement`; the claims' own row is counted from the claims); ``failed`` and
    ``inconclusive`` list those claims with their reasons; ``not_certified`` the statements that are
    not certified or do not apply here, which the headline names too."""
    point = certificate["points"][0]
    pick = lambda status: [c for c in verification["claims"] if c["status"] == status]  # noqa: E731
    failed, inconclusive = pick(ClaimStatus.FAIL), pick(ClaimStatus.INCONCLUSIVE)
    checks = []
    if failed:
        checks.append(f"{len(failed)} of {verification['summary']['claims']} checked claims FAIL")
    if inconclusive:
        checks.append(f"{len(inconclusive)} check(s) INCONCLUSIVE")
    checks += [f"{s.statement}: FAIL" for s in statements_ or [] if s.status is StatementStatus.FAIL and not s.claims]
    if point["certified"]:
        headline = "L2 gain CERTIFIED" + (", but " + " and ".join(checks) if checks else ", and every check passes")
    else:
        headline = "L2 gain NOT CERTIFIED" + (" and " + " and ".join(checks) if checks else "")
    not_here = (StatementStatus.NOT_CERTIFIED, StatementStatus.DOES_NOT_APPLY)
    short = [s for s in statements_ or [] if s.status in not_here]
    if short:
        headline += f"; {len(short)} statement(s) not certified here or not applying (listed)"
    return Verdict(passed=bool(point["certified"]) and not checks, headline=headline, failed=failed,
                   inconclusive=inconclusive, not_certified=short)  # fmt: skip


def grid_result(spec: Scenario, grid: GridSpec, state: SweepState, files: dict[str, str], provenance: dict,
                seconds: float) -> CertificateResult:
    """The result of a grid sweep: the points worth naming, each labelled and re-certified
    alone (with the rotation search): the smallest certified gamma; with a ``[certify] gamma``
    requirement, the cheapest point meeting it (smallest ``|K| = |[k_xi; k_c; k_e]|``); the largest
    gamma (or a point not certified). ``files`` names the stored results."""  # fmt: skip
    bound = spec.certify.gamma
    named = [("smallest certified gamma", state.best)]
    if bound is not None:
        named.append((f"cheapest meeting gamma <= {bound:g} (smallest |K|)", state.cheapest))
    named.append(("largest gamma (or not certified)", state.worst))
    points = []
    for label, entry in named:
        if entry is None:
            continue
        d = grid.designs(entry[1], entry[1] + 1)
        gp = GainPoint(d["k_xi"][0], d["k_c"][0], d["k_e"][0], Weights(*d["w"][0]))
        points.append(replace(point_record(gp, certificate_for(spec, gp)), label=label, index=entry[1]))
    best = points[0] if state.best is not None else None
    summary_ = CertificateSummary(points=grid.size, certified=state.certified,
                                  gamma_min=best.gamma if best else None, seconds=seconds)  # fmt: skip
    axes = {name: v.tolist() if len(v) <= 1000 else f"{len(v)} values" for name, v in grid.axes}
    return CertificateResult.of(spec, points, summary_, provenance, grid=axes, **files)
