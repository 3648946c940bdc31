"""The toolkit's jobs as ``dvfc`` runs them; :mod:`dvfc.analysis.cli` parses, shows progress and prints.

Each job takes a :class:`~dvfc.analysis.case.Case` and its arguments, checks them before any work (a bad
one raises :class:`~dvfc.analysis.scenario.ScenarioError` naming the scenario's field, or
:class:`ValueError` ``"argument: why"`` naming the job's argument), creates its output folder, reports
progress through callbacks, writes its files (never its JSON: that is the caller's, from the result's
``to_json``) and returns its typed result (:mod:`dvfc.analysis.record`).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from dvfc.analysis.campaign import CONFIDENCE, P_FAIL, QUANTILE, CampaignResult, CampaignSpec, shared_simulator
from dvfc.analysis.campaign import campaign as run_campaign
from dvfc.analysis.campaign import row as campaign_row
from dvfc.analysis.case import Case
from dvfc.analysis.cell import Design, Search, design_text, synthesize_for_campaign
from dvfc.analysis.cell import record as cell_record
from dvfc.analysis.defaults import MAX_GRID_BYTES, MAX_GRID_POINTS
from dvfc.analysis.export import ExportResult, export_controller, exportable
from dvfc.analysis.grid import BYTES_PER_POINT, POINTS, GridSpec, export_csv, run_sweep
from dvfc.analysis.hardware import what_would_pass
from dvfc.analysis.margins import PARAMETERS, MarginError, MarginsResult, TrackingBound, log_path, tracking_bound
from dvfc.analysis.margins import margins as measure_margins
from dvfc.analysis.output import atomic_write
from dvfc.analysis.pose import initial_view, integration_cost, solution_record
from dvfc.analysis.record import ABSENT, Absent, Record
from dvfc.analysis.results import (
    CertificateResult,
    PoseResult,
    SimulationResult,
    grid_envelope_for,
    grid_result,
    simulation_result,
    trajectory_arrays,
)
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import Scenario, ScenarioError, auto_q0
from dvfc.analysis.synthesize import refuse_unless_synthesisable
from dvfc.analysis.tasks import run_tasks
from dvfc.analysis.windows import case_windows

Say = Callable[[str], None]
"""Progress in words: what the job does now."""


def simulate(case: Case, directory: Path, provenance: dict, *, campaign_run: int | None = None,
             campaign_values: Path | None = None, campaign_seed: int = 0,
             progress: Callable[[float], None] | None = None) -> SimulationResult:  # fmt: skip
    """A run of the case's loop as implemented (``dvfc simulate``), its arrays written to
    ``directory/trajectory.npz``; or run ``campaign_run`` of the case's campaign of seed
    ``campaign_seed``, or the values of a worst-case file ``campaign_values``, replayed on the
    campaign's simulator, with its row by the margins criterion. ``progress`` gets the time reached."""
    replayed, values, settings, s0 = None, None, case.settings, case.s0
    if campaign_run is not None or campaign_values is not None:
        if campaign_run is not None and campaign_values is not None:
            raise ValueError("campaign_run: give a campaign run or campaign_values, not both")
        replayed = CampaignSpec.of(case, tracking_bound(case), campaign_seed)
        values = None if campaign_values is None else replayed_values(replayed, campaign_values)
        settings, s0 = replayed.run_settings(campaign_run or 0, values)
    directory.mkdir(parents=True, exist_ok=True)
    simulator = as_implemented(case.loop, settings) if replayed is None else shared_simulator(case).for_run(settings)
    trajectory = simulator.run(s0, progress=progress)
    outputs = {"trajectory": directory / "trajectory.npz", "summary": directory / "summary.json"}
    result = simulation_result(case, trajectory, outputs, provenance, settings)
    if replayed is not None:
        drawn = replayed.values(campaign_run or 0) if values is None else values
        result = replace(result, campaign_row=campaign_row(replayed, campaign_run or 0, trajectory, settings, drawn))
    arrays: dict[str, Any] = trajectory_arrays(case, trajectory, settings)
    atomic_write(outputs["trajectory"], lambda h: np.savez_compressed(h, **arrays))
    return result


def replayed_values(spec: CampaignSpec, path: Path) -> dict[str, np.ndarray]:
    """The values of a worst-case file of ``dvfc campaign`` (``campaign_values``)."""
    try:
        data = json.loads(path.read_text())["values"]
        values = {k: np.asarray(v, dtype=float) for k, v in data.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"campaign_values: cannot read {path}: {exc}") from exc
    if set(values) != set(spec.dispersion.keys):
        raise ValueError(f"campaign_values: {path} has other quantities than the scenario's [dispersion]")
    return values


def pose(case: Case, *, solve: bool = False) -> PoseResult:
    """Where everything is at the start (``dvfc pose``); with ``solve``, from the configuration solved for
    the camera at the reference pose (:func:`dvfc.analysis.scenario.auto_q0`, ``ScenarioError`` when
    none is found)."""
    solution = None
    if solve:
        config = auto_q0(case.scenario, case.loop.robot, "pose --solve")
        data = case.scenario.model_dump()
        data["robot"]["q0"] = config.q.tolist()
        solution = solution_record(config, case.loop.robot.limits)
        case = case.with_scenario(Scenario.model_validate(data))
    windows = case_windows(case)
    return PoseResult(scenario=case.name, solution=solution, **initial_view(case.loop, case.s0),
                      gain_windows=None if windows is None else windows.as_dict(),
                      integration=integration_cost(case.loop, case.s0, case.settings),
                      windows_warning=None if windows is None else windows.warning())  # fmt: skip


def grid_points(case: Case) -> int:
    """The number of points of the case's ``[grid]``."""
    assert case.scenario.grid is not None
    return int(np.prod([len(v) for _, v in case.scenario.grid.axes()], dtype=np.int64))


def grid_size(case: Case, *, csv: bool = False, large: bool = False) -> str:
    """The case's ``[grid]`` in words (points, bytes on disk), after checking that it is allowed: more
    than :data:`MAX_GRID_POINTS` points or :data:`MAX_GRID_BYTES` bytes need ``large``."""
    size = grid_points(case)
    expected = size * BYTES_PER_POINT
    if (size > MAX_GRID_POINTS or expected > MAX_GRID_BYTES) and not large:
        raise ValueError(f"large: the grid has {size:,} points, about {expected / 1e6:,.0f} MB on disk, over "
                         f"{MAX_GRID_POINTS:.0e} points or {MAX_GRID_BYTES / 1e6:,.0f} MB; set it to confirm")
    return (f"grid: {size:,} points, about {expected / 1e6:,.3g} MB on disk (Parquet, ~{BYTES_PER_POINT} bytes "
            f"a point{'; plus CSV, about 4x more' if csv else ''})")  # fmt: skip


def certify_grid(case: Case, directory: Path, provenance: dict, *, workers: int = 1, scheduler: str | None = None,
                 resume: bool = False, batch_size: int = 20000, csv: bool = False, large: bool = False,
                 progress: Callable[[int], None] | None = None) -> CertificateResult:  # fmt: skip
    """Theorem 2 at every point of the case's ``[grid]`` (``dvfc certify`` of a grid), stored in ``directory``
    batch by batch (``resume`` continues an interrupted sweep), also as CSV with ``csv``; ``progress``
    gets the points done."""
    start = time.perf_counter()
    spec = case.scenario
    grid_size(case, csv=csv, large=large)
    assert spec.grid is not None
    grid = GridSpec.around(case.point, spec.reference.se3(), spec.grid.axes(), spec.certify.gamma,
                           grid_envelope_for(case))  # fmt: skip
    if resume and not (directory / "sweep.json").exists():
        raise ValueError(f"resume: no sweep to resume in {directory}")
    directory.mkdir(parents=True, exist_ok=True)
    state = run_sweep(grid, directory, batch_size=batch_size, workers=workers, scheduler=scheduler, resume=resume,
                      progress=progress, scenario_sha256=case.provenance([])["scenario_sha256"])  # fmt: skip
    files = {"points_dataset": str(directory / POINTS)}
    if csv:
        export_csv(directory, directory / "points.csv")
        files["points_csv"] = str(directory / "points.csv")
    return grid_result(spec, grid, state, files, provenance, time.perf_counter() - start)


def require_theorems(case: Case, command: str) -> None:
    """Refuse ``command`` (a ``ScenarioError`` naming the loop) when it rests on Theorems 1-2 and they do
    not apply (:attr:`Case.theorems_do_not_apply`)."""
    if (why := case.theorems_do_not_apply) is not None:
        raise ScenarioError(f"loop: dvfc {command} needs the paper's equilibrium and Theorems 1-2; {why}")


def campaign_bound(case: Case, purpose: str) -> TrackingBound:
    """The criterion of ``case``'s campaign, for the ``purpose`` that needs one (a ``ScenarioError``
    unless it can run: a ``[dispersion]``, an ``[implementation]``, the paper's loop)."""
    if not case.scenario.dispersion:
        raise ScenarioError(f"dispersion: {purpose} needs a [dispersion] section")
    if case.planar or case.settings.implementation is None:
        raise ScenarioError(f"implementation: {purpose} designs the loop as implemented; add an [implementation]")
    bound = tracking_bound(case)
    CampaignSpec.of(case, bound)
    return bound


def hardware_search(case: Case, log: Path, *, p_fail: float, confidence: float, workers: int, resume: bool,
                    say: Say | None = None) -> dict[str, Any]:  # fmt: skip
    """What would pass (:func:`dvfc.analysis.hardware.what_would_pass`) at the full budget, its
    evaluations in ``log`` (continued with ``resume``)."""
    if resume and not log.exists():
        raise ValueError(f"resume: no what-would-pass search to resume ({log} not found)")
    return what_would_pass(case, p_fail=p_fail, confidence=confidence, search=Search(workers=workers), log=log,
                           resume=resume, progress=say)  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class CampaignDesignResult(Record):
    """``dvfc synthesize --for-campaign`` (docs/cli.md): whether a design holds on the campaign, the design,
    its checks, the search and its surrogate, the confirming campaign, the criterion, what limits it
    otherwise (:func:`dvfc.analysis.cell.record`); the scenario written (None: none); what would pass,
    when searched."""

    scenario: str
    holds: bool
    design: dict[str, Any] | None
    checks: dict[str, Any] | None
    surrogate: float | None
    search: dict[str, Any]
    confirmation: dict[str, Any] | None
    tracking_bound: dict[str, Any]
    limits: str | None
    scenario_file: str | None
    what_would_pass: dict[str, Any] | Absent = ABSENT
    seconds: float
    provenance: dict[str, Any]


def synthesize_for_campaign_job(case: Case, target: Path, provenance: dict, *, p_fail: float = P_FAIL,
                                confidence: float = CONFIDENCE, workers: int = 1, what: bool = False,
                                resume: bool = False, say: Say | None = None) -> CampaignDesignResult:  # fmt: skip
    """Gains and integral action that hold on the case's campaign (``dvfc synthesize --for-campaign``,
    :mod:`dvfc.analysis.cell`), written as a scenario at ``target`` when one holds; with ``what``, that
    synthesis is the first check of what would pass (:mod:`dvfc.analysis.hardware`), its log beside
    ``target`` (continued with ``resume``)."""
    start = time.perf_counter()
    for name, value in (("p_fail", p_fail), ("confidence", confidence)):
        if not 0 < value < 1:
            raise ValueError(f"{name}: {value:g} is not in (0, 1)")
    refuse_unless_synthesisable(case)
    bound = campaign_bound(case, "the synthesis for the campaign")
    target.parent.mkdir(parents=True, exist_ok=True)
    found: dict[str, Any] | Absent = ABSENT
    if what:
        log = target.with_name(target.name + ".what_would_pass.jsonl")
        found = hardware_search(case, log, p_fail=p_fail, confidence=confidence, workers=workers, resume=resume,
                                say=say)  # fmt: skip
        synthesis = found["today"]["synthesis"]  # the synthesis at the scenario's own hardware
        design = Design.of(synthesis["design"]) if synthesis["holds"] else None
    else:
        result = synthesize_for_campaign(case, p_fail=p_fail, confidence=confidence, search=Search(workers=workers),
                                         progress=say)  # fmt: skip
        synthesis, design = cell_record(result), result.design if result.holds else None
    written = None
    if design is not None:
        assert case.path is not None
        text = design_text(case.path.read_text(), case, design, bound, name=f"{case.name}-synthesized",
                           source=case.path, target=target)  # fmt: skip
        atomic_write(target, lambda h: h.write(text.encode()))
        written = str(target)
    return CampaignDesignResult(scenario=case.name, **synthesis, scenario_file=written, what_would_pass=found,
                                seconds=time.perf_counter() - start, provenance=provenance)  # fmt: skip


def margins(case: Case, directory: Path, provenance: dict, *, workers: int = 1, scheduler: str | None = None,
            resume: bool = False, what: bool = False, poll: Callable[[], None] | None = None,
            say: Say | None = None) -> MarginsResult:  # fmt: skip
    """The measured margins of the case's loop as implemented (``dvfc margins``,
    :func:`dvfc.analysis.margins.margins`), each search in one of ``workers`` processes, its runs logged
    in ``directory`` (continued with ``resume``); ``poll`` called as runs finish. With ``what``, what would
    pass (its log in ``directory`` too). The scenario's own run failing is a result without margins."""
    if case.settings.implementation is None:
        raise ScenarioError("implementation: margins are of the loop as implemented; add an [implementation] section")
    require_theorems(case, "margins")
    if what:
        campaign_bound(case, "what would pass")
    log = directory / "what_would_pass.jsonl"
    logged = [log_path(directory, n) for n in PARAMETERS] + ([log] if what else [])
    if resume and not any(p.exists() for p in logged):
        raise ValueError(f"resume: no margin search to resume in {directory}")
    directory.mkdir(parents=True, exist_ok=True)
    try:
        result = measure_margins(case, directory, map_tasks=lambda f, a: run_tasks(f, a, workers, scheduler, poll),
                                 resume=resume)  # fmt: skip
    except MarginError as exc:
        result = MarginsResult(scenario=case.name, margins=None, no_margins=str(exc))
    if what:
        found = hardware_search(case, log, p_fail=P_FAIL, confidence=CONFIDENCE, workers=workers,
                                resume=resume and log.exists(), say=say)  # fmt: skip
        result = replace(result, what_would_pass=found)
    return replace(result, provenance=provenance)


def campaign(case: Case, directory: Path, provenance: dict, runs: int = 100, *, seed: int = 0,
             confidence: float = CONFIDENCE, p_fail: float = P_FAIL, quantile: float = QUANTILE, search: int = 0,
             batch_size: int = 25, workers: int = 1, scheduler: str | None = None, resume: bool = False,
             what: bool = False, progress: Callable[[int], None] | None = None,
             say: Say | None = None) -> CampaignResult:  # fmt: skip
    """The case's ``[dispersion]`` as a campaign (``dvfc campaign``, :func:`dvfc.analysis.campaign.campaign`);
    with ``what`` and a failing run, what would pass (None when no run fails)."""
    result = run_campaign(case, directory, runs, seed=seed, confidence=confidence, p_fail=p_fail, quantile=quantile,
                          search=search, batch_size=batch_size, workers=workers, scheduler=scheduler, resume=resume,
                          progress=progress)  # fmt: skip
    result = replace(result, provenance=provenance)
    if what:
        log = directory / "what_would_pass.jsonl"
        found = hardware_search(case, log, p_fail=p_fail, confidence=confidence, workers=workers,
                                resume=resume and log.exists(), say=say) if result.failures else None  # fmt: skip
        result = replace(result, what_would_pass=found)
    return result


def export(case: Case, directory: Path, *, check: bool = False) -> ExportResult:
    """The case's controller exported as C to ``directory`` (``dvfc export``); with ``check``, compiled,
    replayed on a simulated run and timed (:func:`dvfc.analysis.export.export_controller`)."""
    exportable(case)
    directory.mkdir(parents=True, exist_ok=True)
    return export_controller(case, directory, checked=check)

