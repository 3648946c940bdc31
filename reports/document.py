"""The design-review report of a scenario: one self-contained HTML file and its PDF.

:func:`assemble` runs the jobs a review signs off on (simulation of (36), the
Theorem 2 certificate with its lower bounds, the verification of every claim, the margins
of the loop as implemented, the campaign of its ``[dispersion]``, the gain map); :func:`render`
turns them into HTML (figures inline as SVG, CSS inline, nothing fetched); :func:`write` saves ``report.html`` and
``report.pdf`` (WeasyPrint) atomically.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from jinja2 import Environment, PackageLoader, StrictUndefined

from dvfc.analysis.campaign import (
    CONFIDENCE,
    P_FAIL,
    QUANTILE,
    CampaignSpec,
    read_runs,
    run_campaign,
    simulate_run,
    true_pixels,
)
from dvfc.analysis.campaign import summarize as summarize_campaign
from dvfc.analysis.case import Case
from dvfc.analysis.export import running_controller
from dvfc.analysis.grid import GainMap, GridSpec, axis_value, certify_batch, gain_map
from dvfc.analysis.implementation import SubstepChoice
from dvfc.analysis.linearize import FromRest, from_rest
from dvfc.analysis.margins import MarginError, TrackingBound, linear_margin_text, margins, tracking_bound
from dvfc.analysis.output import atomic_write
from dvfc.analysis.pose import xyz_rpy
from dvfc.analysis.record import Record
from dvfc.analysis.results import (
    Verdict,
    best_gamma,
    certificate_result,
    channels_text,
    grid_envelope_for,
    implementation_record,
    plant_errors_record,
    statements,
    verdict,
    verification_result,
)
from dvfc.analysis.sampled import as_implemented, limit_record, robot_limits
from dvfc.analysis.scenario import Scenario, ScenarioError, gain_point
from dvfc.analysis.simulate import RunStatus, Simulator, Trajectory, identity_residuals, summary
from dvfc.analysis.tasks import run_tasks
from dvfc.models.camera import Camera
from dvfc.models.loop import ClosedLoop
from dvfc.reports import figures
from dvfc.reports.stages import StageCache

STEPS = ("simulation", "certificate and lower bounds", "verification", "margins", "controller", "dispersions",
         "gain map", "figures")  # fmt: skip
"""The stages of :func:`assemble`, in order (reported to ``progress``)."""


@dataclass
class ReportData:
    """Everything the report shows."""

    spec: Scenario
    loop: ClosedLoop
    trajectory: Trajectory
    summary: dict
    certificate: dict
    verification: dict
    gain_map: GainMap | None
    design: dict[str, float]
    figures: dict[str, str | None]
    provenance: dict
    implemented: dict
    """The run as implemented (:func:`dvfc.analysis.sampled.as_implemented`): how, its summary, and
    per joint its peak torque and speed against the URDF's limits."""
    controller: dict | None
    """The controller that runs (:func:`dvfc.analysis.export.running_controller`): the export's digest,
    its replay and its step times, or ``{"reason": ...}``; None without an ``[implementation]``."""
    margins: dict | None
    """The margins of the loop as implemented (:func:`dvfc.analysis.margins.margins`), or
    ``{"reason": ...}`` when there are none to measure; None without an ``[implementation]``."""
    dispersion: dict | None
    """The campaign of the scenario's ``[dispersion]`` (:func:`measure_campaign`), or
    ``{"reason": ...}`` when it cannot run; None without a ``[dispersion]``."""
    q0: np.ndarray
    """The start configuration run (the scenario's, or the one solved for ``q0 = "auto"``)."""
    plant_errors: dict
    """What acts on the plant that the law's model leaves out
    (:func:`dvfc.analysis.results.plant_errors_record`)."""


MARGIN_WORKERS = min(2, os.cpu_count() or 1)
"""Local processes the report's margin searches run in (one search a task): the two cores a
report is made for, the searches of the payload (in CasADi's virtual machine) beside the others."""


def measure_margins(case: Case, cache: StageCache, envelope: dict, own_run: Trajectory) -> dict:
    """The margins of the case (:func:`dvfc.analysis.margins.margins`, given its envelope and
    its run as implemented), measured in :data:`MARGIN_WORKERS` local processes; the runs are
    logged in the cache's scratch directory so that a resumed report continues an interrupted
    search. ``{"reason": ...}`` when the scenario's own run does not hold."""
    scratch = cache.scratch("margins", case, (envelope, own_run))
    tasks = lambda function, arguments: run_tasks(function, arguments, MARGIN_WORKERS)  # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        try:
            return margins(case, scratch or Path(tmp), map_tasks=tasks,
                           resume=scratch is not None, envelope=envelope, own_run=own_run).to_json()  # fmt: skip
        except MarginError as exc:
            return {"reason": str(exc)}


CONTROLLER_CALLS = 10_000
"""Calls of the compiled step the report times (``benchmarks/controller_step.py`` times 1e5)."""


def measure_controller(case: Case) -> dict:
    """The controller that runs (:func:`dvfc.analysis.export.running_controller`), exported to a
    temporary folder and timed over :data:`CONTROLLER_CALLS` calls."""
    with tempfile.TemporaryDirectory() as tmp:
        return running_controller(case, Path(tmp), CONTROLLER_CALLS)


def _campaign(case: Case, cache: StageCache, name: str, bound: TrackingBound, uses: tuple) -> tuple[CampaignSpec, dict]:
    """``[report] campaign_runs`` runs of the case's campaign judged against ``bound``, with the
    default confidence, in this process, the batches kept in the scratch directory of stage ``name``
    (taking ``uses``) so that a resumed report continues an interrupted campaign: its spec and
    ``{"summary": summary.json without provenance, "runs": the dataset as columns}``
    (:class:`ScenarioError` when the scenario cannot run a campaign)."""
    spec = CampaignSpec.of(case, bound)
    scratch = cache.scratch(name, case, uses)
    with tempfile.TemporaryDirectory() as tmp:
        directory = scratch or Path(tmp)
        run_campaign(spec, directory, case.scenario.report.campaign_runs, resume=scratch is not None,
                     key=cache.key(name, case, uses))  # fmt: skip
        table = read_runs(directory)
    return spec, {"summary": summarize_campaign(spec, table, CONFIDENCE, P_FAIL, QUANTILE), "runs": table.to_pydict()}


def measure_campaign(case: Case, cache: StageCache, envelope: dict) -> dict:
    """The campaign of the case's ``[dispersion]`` (:mod:`dvfc.analysis.campaign`, :func:`_campaign`),
    judged by the margins criterion (the tracking bound of ``envelope``, ``bound``); then the worst run
    made again for its features: ``worst`` its trajectory, ``worst_pixels`` the features its plant's
    camera saw (:func:`true_pixels`); ``{"reason": ...}`` when the scenario cannot run a campaign."""
    try:
        bound = tracking_bound(case, envelope)
        spec, campaign = _campaign(case, cache, "dispersions", bound, (envelope,))
    except ScenarioError as exc:
        return {"reason": str(exc)}
    run = campaign["summary"]["worst"][0]["run"]
    worst = simulate_run(spec, run)[1]
    errors = spec.run_settings(run)[0].errors
    assert errors is not None  # every campaign run has its plant errors (campaign_settings)
    pixels = true_pixels(case.loop, worst, errors)
    return {**campaign, "bound": bound, "worst": worst, "worst_pixels": pixels}


def measure_before(before: Case, cache: StageCache, bound: TrackingBound) -> dict:
    """The same campaign (the same runs and seeds: common random numbers) of the design the scenario
    was synthesised from (``before``, :meth:`Case.before`), judged against the same ``bound`` as the
    scenario's own design: ``summary`` and ``runs`` as :func:`measure_campaign`'s; ``{"reason": ...}``
    when it cannot run."""
    try:
        return _campaign(before, cache, "dispersions_before", bound, (bound,))[1]
    except ScenarioError as exc:
        return {"reason": str(exc)}


def assemble(
    case: Case,
    provenance: dict,
    progress: Callable[[str], None] = lambda step: None,
    cache: StageCache | None = None,
) -> ReportData:
    """Run every job of the review on the case, each once: the simulation of the paper's loop
    and of the loop as implemented (one run when they are the same loop), the run from rest
    under the linearisation's worst sinusoid, the certificate with its envelope and lower bounds
    (on that run), the verification (on both simulations and that run), the margins of the loop
    as implemented (without an ``[implementation]``, none), the campaign, the gain map;
    ``progress`` is told each step of :data:`STEPS`; every stage but the gain map and the
    figures goes through ``cache`` (:class:`dvfc.reports.stages.StageCache`)."""
    spec, loop, s0, settings = case.scenario, case.loop, case.s0, case.settings
    stage = cache or StageCache(None, "", False)
    progress(STEPS[0])
    implemented = stage("implemented", case, lambda: as_implemented(loop, settings).run(s0))
    # the paper's loop is the one implemented when there is no [implementation] and no [plant]: the same
    # run, unless it stopped where a feature left the image (the paper's run goes on there)
    same = settings.implementation is None and settings.plant is None and implemented.status is RunStatus.OK
    trajectory = implemented if same else stage("simulation", case, lambda: Simulator(loop, settings).run(s0))
    progress(STEPS[1])
    rest = stage("from_rest", case, lambda: _from_rest(case))  # shared by the lower bound and Theorem 2's checks
    rest = rest if isinstance(rest, FromRest) else None  # no equilibrium: both say why
    certificate = _current(stage("certificate", case, lambda: certificate_result(case, provenance, rest=rest).to_json(),
                                 (rest,)), spec, provenance)  # fmt: skip
    envelope = certificate["points"][0]["envelope"]
    progress(STEPS[2])
    verification = _current(stage("verification", case, lambda: verification_result(case, provenance, envelope,
                                  implemented, rest, trajectory).to_json(), (envelope, implemented, rest, trajectory)),
                            spec, provenance)  # fmt: skip
    progress(STEPS[3])
    measured = None
    if settings.implementation is not None:
        measured = stage("margins", case, lambda: measure_margins(case, stage, envelope, implemented),
                         (envelope, implemented))  # fmt: skip
    progress(STEPS[4])
    controller = None
    if settings.implementation is not None:
        controller = stage("controller", case, lambda: measure_controller(case))
    progress(STEPS[5])
    dispersion = None
    if spec.dispersion:
        dispersion = stage("dispersions", case, lambda: measure_campaign(case, stage, envelope), (envelope,))
        if (before := case.before()) is not None and "summary" in dispersion:
            bound = dispersion.get("bound") or tracking_bound(case, envelope)  # a stage kept before it had one
            dispersion = {**dispersion, "before": stage("dispersions_before", before,
                                                        lambda: measure_before(before, stage, bound), (bound,))}
    progress(STEPS[6])
    point = case.point
    axes = spec.grid.axes() if spec.grid is not None else None
    gamma_certified = certificate["points"][0]["gamma"]
    gmap, design = None, {"gamma": gamma_certified}
    if gamma_certified is not None:  # no map where Theorem 2 does not apply (the paper's loop with n < 6)
        quantity = spec.report.map
        context = grid_envelope_for(case) if quantity != "gamma" else None
        gmap = gain_map(point, spec.reference.se3(), axes, spec.certify.gamma, envelope=context, quantity=quantity)
        if context is not None:  # the design's own value on the map, by the same batched route
            itself = [("w_pc", np.array([point.weights.w_pc]))]  # a one-point grid: the design exactly
            own = GridSpec.around(point, spec.reference.se3(), itself, None, context)
            design[quantity] = float(certify_batch(own, 0, 1)[quantity][0])
        design |= {name: axis_value(point, name) for name in (gmap.x_axis, gmap.y_axis) if name is not None}
    progress(STEPS[7])
    gamma = verification["gamma"]
    drawn = {
        "paths": figures.paths(trajectory),
        "image": figures.image_plane(trajectory, loop.camera.focal_length),
        "errors": figures.errors(trajectory),
        "storage": figures.storage(trajectory),
        "torques": figures.torques(trajectory),
        "supply": figures.supply(trajectory),
        "l2": figures.l2_inequality(trajectory, gamma) if gamma is not None else None,
        "map": figures.gain_map(gmap, design) if gmap is not None else None,
        "envelope": _envelope_figure(trajectory, loop, certificate["points"][0].get("envelope")),
        "implemented": figures.implemented_image(implemented, loop.camera.centre,
                                                 loop.camera.size) if loop.camera.has_image else None,
    } | _dispersion_figures(dispersion, loop)  # fmt: skip
    as_built = {
        "implementation": implementation_record(settings),
        "integration": None if settings.implementation is None else SubstepChoice.of_run(implemented.stats).as_dict(),
        "summary": summary(implemented),
        "limits": limit_record(implemented, robot_limits(loop, settings)),
    }
    return ReportData(
        spec, loop, trajectory, summary(trajectory), certificate, verification, gmap, design, drawn, provenance,
        as_built, controller, measured, dispersion, s0[: loop.robot.n].copy(),
        plant_errors_record(settings, loop.camera),
    )  # fmt: skip


def _from_rest(case: Case) -> FromRest | str:
    """The case's run from rest (:func:`dvfc.analysis.linearize.from_rest`), or why there is none."""
    try:
        return from_rest(case.loop, case.s0[: case.loop.robot.n], case.settings.jit)
    except ValueError as exc:
        return str(exc)


def _current(result: dict, spec: Scenario, provenance: dict) -> dict:
    """A kept stage's JSON result with this report's scenario name and provenance (a stage is
    kept across edits of fields it does not read, the name among them)."""
    return {**result, "scenario": spec.name, "provenance": provenance}


def _dispersion_figures(dispersion: dict | None, loop: ClosedLoop) -> dict[str, str | None]:
    """The campaign's figures (:func:`figures.campaign_ecdf`, :func:`figures.sensitivity_bars`,
    :func:`figures.drivers_scatter`, the worst run's features in the image), None each when
    there is no campaign."""
    names = ("campaign_ecdf", "campaign_sensitivity", "campaign_drivers", "campaign_worst", "campaign_before")
    if dispersion is None or "summary" not in dispersion:
        return dict.fromkeys(names)
    summary_, runs, camera = dispersion["summary"], dispersion["runs"], loop.camera
    worst = summary_["worst"][0]
    before = dispersion.get("before") or {}
    return dict(zip(names, (
        figures.campaign_ecdf(runs, summary_["tolerance"]),
        figures.sensitivity_bars(summary_["sensitivity"], summary_["sensitivity_floor"]["pawn"]),
        figures.drivers_scatter(runs, summary_["sensitivity"]),
        figures.implemented_image(dispersion["worst"], camera.centre, camera.size,
                                  f"Features of run {worst['run']} (the worst) in the true image",
                                  dispersion["worst_pixels"])
        if camera.has_image else None,
        figures.campaigns_ecdf({"before synthesis": before["runs"], "this design": runs}) if "runs" in before else None,
    ), strict=True))  # fmt: skip


def supply_facts(traj: Trajectory) -> dict[str, float | bool]:
    """What Lemma 2 says about the run shown: with ``w``, ``V(t) - V(0) = int u^T nu +
    int x^T G w`` (its residual, :func:`dvfc.analysis.simulate.identity_residuals`) and the
    smallest values of both supplies against ``-V(0)``; ``int u^T nu >= -V(0)`` is stated
    for ``w = 0`` only."""
    i = traj.integrals
    return {
        "with_w": bool(np.abs(traj["w"]).max() > 0),
        "V0": float(traj["V"][0, 0]),
        "min_u_nu": float(i["supply_u_nu"].min()),
        "min_total": float((i["supply_u_nu"] + i["supply_x_G_w"]).min()),
        "residual": identity_residuals(traj)["passivity"],
    }


def _envelope_figure(trajectory: Trajectory, loop: ClosedLoop, envelope: dict | None) -> str | None:
    """The image with the certified feature regions, when there is an image and a region."""
    camera = loop.camera
    if not envelope or envelope.get("boxes_px") is None or not camera.has_image:
        return None
    return figures.envelope_image(trajectory, camera.centre, camera.size, envelope)


def _number(value: float | str | None, digits: int = 6) -> str:
    """A number for the page: ``-`` when absent, ``digits`` significant figures; anything else
    (a string) as it is."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, str | bool) or not isinstance(value, int | float | np.number):
        return str(value)
    return f"{value:.{digits}g}"


def _vector(values, digits: int = 4) -> str:
    """A vector for the page, its entries by :func:`_number`; a string (``"auto"``) or None as :func:`_number`."""
    if values is None or isinstance(values, str):
        return _number(values)
    return "[" + ", ".join(_number(float(v), digits) for v in values) + "]"


def camera_facts(camera: Camera, calibration: str | None) -> dict:
    """The controller's camera as the page states it: ``fx``, ``fy`` (px), the principal point
    (px from the top-left corner; None without an image size), the distortion coefficients
    (None: none), the image size (None: not given) and the calibration file they came from."""
    distortion = [float(k) for k in camera.distortion]
    return {
        "fx": float(camera.focal_length),
        "fy": float(camera.focal_length * camera.aspect),
        "principal_point": camera.centre.tolist() if camera.has_image else None,
        "distortion": distortion if any(distortion) else None,
        "size": (camera.width, camera.height) if camera.has_image else None,
        "calibration": calibration,
    }


def plant_text(record: dict) -> list[str]:
    """Each entry of a :func:`dvfc.analysis.results.plant_errors_record` in words."""
    parts = []
    if (f := record["friction"]) is not None:
        parts.append(f"joint friction b qd + c tanh(qd / {_number(f['smoothing'], 3)} rad/s): viscous b = "
                     f"{_vector(f['viscous'])} N m s/rad, Coulomb c = {_vector(f['coulomb'])} N m")  # fmt: skip
    if (payload := record["payload"]) is not None:
        parts.append(f"a payload of {_number(payload['mass'], 4)} kg on the camera link (centre of mass "
                     f"{_vector(payload['com'])} m)")  # fmt: skip
    if record["mass_scale"] is not None:
        parts.append(f"masses and inertias {_number(record['mass_scale'], 4)}x the URDF's")
    if (mount := record["mount"]) is not None:
        parts.append(f"a camera mount error xyz {_vector(mount['xyz'])} m, rpy {_vector(mount['rpy'])} rad")
    if (true := record["intrinsics"]) is not None:
        parts.append(f"true intrinsics fx = {_number(true['fx'])} px, fy = {_number(true['fy'])} px, principal point "
                     f"{_vector(true['principal_point'])} px, distortion {_vector(true['distortion'], 6)}")  # fmt: skip
    if (points := record["point_errors"]) is not None:
        largest = float(np.linalg.norm(np.asarray(points), axis=1).max())
        parts.append(f"feature point errors up to {_number(largest, 3)} m")
    return parts


def disturbances_text(spec: Scenario, record: dict) -> list[str]:
    """What disturbs the loop, in words: the target's motion, the joint-torque disturbances
    ``tau_d`` and what acts on the plant that the law leaves out (:func:`plant_text`)."""
    moving = [f"the target's motion ({spec.target.motion.kind})"] if spec.target.motion.kind != "static" else []
    kinds = ", ".join(d.kind for d in spec.disturbance.torque)
    torques = [f"{kinds} joint torques tau_d"] if kinds else []
    acting = plant_text(record)
    plant = ["acting on the plant of the loop as implemented, unknown to the law ([plant]): " + "; ".join(acting)]
    return [*moving, *torques, *(plant if acting else [])]


def render(data: ReportData) -> str:
    """The report as one HTML document."""
    env = Environment(loader=PackageLoader("dvfc.reports"), autoescape=True, undefined=StrictUndefined)
    env.filters["num"] = _number
    env.filters["vec"] = _vector
    spec = data.spec
    point = data.certificate["points"][0]
    review = statements(data.certificate, data.verification, data.margins, data.dispersion, data.controller)
    return env.get_template("report.html.j2").render(
        spec=spec,
        robot=data.loop.robot,
        n=data.loop.robot.n,
        point=point,
        certificate=data.certificate,
        region=data.certificate["region"],
        assumptions=data.certificate["assumptions"],
        verification=data.verification,
        verdict=verdict(data.certificate, data.verification, review),
        statements=review,
        best_gamma=best_gamma(point),
        channels=channels_text(point, spec.loop == "planar"),
        target_start=xyz_rpy(np.asarray(data.loop.target.start.as_matrix())),
        envelope=point.get("envelope"),
        envelope_claims=[c for c in data.verification["claims"] if c["paper"] in ("fact 7", "fact 8")],
        summary=data.summary,
        map=data.gain_map,
        design=data.design,
        best=data.gain_map.best() if data.gain_map is not None and data.gain_map.certified.any() else None,
        figures=data.figures,
        lemma2=supply_facts(data.trajectory),
        implemented=data.implemented,
        margins=data.margins,
        controller=data.controller,
        dispersion=data.dispersion,
        linear_margin=linear_margin_text(data.margins) if data.margins and "margins" in data.margins else None,
        mode=data.loop.mode,
        camera_size=(data.loop.camera.width, data.loop.camera.height),
        camera=camera_facts(data.loop.camera, spec.camera.calibration),
        q0=data.q0,
        disturbances=disturbances_text(spec, data.plant_errors),
        plant_acting=plant_text(data.plant_errors),
        provenance=data.provenance,
        gains=data.loop.gains,
        before_gains=None if (origin := spec.synthesized_from) is None else gain_point(
            spec, data.loop.robot.n, origin.gains, "synthesized_from.gains"),
    )  # fmt: skip


def write(data: ReportData, directory: Path) -> tuple[Path, Path]:
    """Write ``report.html`` and ``report.pdf`` into ``directory`` (each atomically)."""
    from weasyprint import HTML  # imported here: loading pango takes a second

    html = render(data)
    html_path, pdf_path = directory / "report.html", directory / "report.pdf"
    pdf = HTML(string=html, base_url=str(directory)).write_pdf()
    atomic_write(html_path, lambda h: h.write(html.encode()))
    atomic_write(pdf_path, lambda h: h.write(pdf))
    return html_path, pdf_path


@dataclass(frozen=True, kw_only=True)
class ReportResult(Record):
    """``dvfc report``: the files written and the review's verdict (:func:`dvfc.analysis.results.verdict`)."""

    html: Path
    pdf: Path
    verdict: Verdict


def report(case: Case, directory: Path, provenance: dict, *, progress: Callable[[str], None] = lambda step: None,
           cache: StageCache | None = None) -> ReportResult:  # fmt: skip
    """The design-review report of the case (:func:`assemble`, each stage through ``cache``), written to
    ``directory/report.html`` and ``report.pdf`` (:func:`write`), with its verdict."""
    directory.mkdir(parents=True, exist_ok=True)
    data = assemble(case, provenance, progress=progress, cache=cache)
    progress("HTML and PDF")
    html, pdf = write(data, directory)
    review = statements(data.certificate, data.verification, data.margins, data.dispersion, data.controller)
    return ReportResult(html=html, pdf=pdf, verdict=verdict(data.certificate, data.verification, review))
