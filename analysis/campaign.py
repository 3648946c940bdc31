"""Dispersion campaigns: independent runs of the loop as implemented with the scenario's
``[dispersion]`` drawn anew for each, judged by the margins criterion, and what the runs say
with a stated confidence.

Run ``K`` draws its values from ``numpy.random.SeedSequence(seed, spawn_key=(K,))``: the dataset
does not depend on the workers or the batch sizes, and any run replays alone
(``dvfc simulate SCENARIO --campaign-run K``). The runs are written one Parquet file per batch
in ``DIR/runs`` with a state file (``campaign.json``) saved after each: an interrupted campaign
resumes with the batches already written (the grid's pattern, :mod:`dvfc.analysis.grid`).

The statistics are of simulated runs of the loop as implemented (measurements, not
certificates): the binomial bound speaks of the runs' distribution as drawn, under the model
of the plant and its errors, nothing beyond it.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import casadi as cs
import numpy as np

from dvfc.analysis import sensitivity
from dvfc.analysis.batches import BatchRun
from dvfc.analysis.case import Case
from dvfc.analysis.defaults import CONFIDENCE, P_FAIL, QUANTILE
from dvfc.analysis.dispersion import INPUTS, MASSES, Dispersion, base_values, with_values
from dvfc.analysis.margins import CRITERION, TrackingBound, judge, tracking_bound, tracking_error
from dvfc.analysis.multirate import DeclaredPlant, LocalVerdict, applicability
from dvfc.analysis.output import write_json
from dvfc.analysis.parametric import parametrised
from dvfc.analysis.record import ABSENT, Absent, Record
from dvfc.analysis.sampled import SampledSimulator, limit_record, robot_limits, sampled_simulator
from dvfc.analysis.scenario import ScenarioError
from dvfc.analysis.simulate import RunStatus, Settings, Trajectory
from dvfc.models.errors import PlantErrors, camera_size, true_features
from dvfc.models.loop import ClosedLoop

if TYPE_CHECKING:
    import pyarrow as pa

RUNS = "runs"
"""Folder of a campaign's dataset in its output directory: one Parquet file per batch."""

BOUND = "clopper-pearson, one-sided"

LOCAL = (
    "; and, where fact 14 applies, the draw's plant linearised at rest (docs/math.md, fact 25: its masses, camera "
    "and friction, at the scenario's latency and rates) has rho < 1: a draw with rho >= 1 fails whatever its run"
)
"""Added to the campaign's criterion: a run judged on its horizon cannot show a slow local instability."""


@dataclass(frozen=True)
class CampaignSpec:
    """What every run of a campaign shares: the case (its ``errors`` set, so that every run uses
    the same compiled functions), the dispersion, the tracking bound of the criterion, the seed."""

    case: Case
    dispersion: Dispersion
    bound: TrackingBound
    seed: int = 0

    @staticmethod
    def of(case: Case, bound: TrackingBound, seed: int = 0) -> CampaignSpec:
        """The campaign of a case's ``[dispersion]`` (:class:`ScenarioError` where it cannot run)."""
        settings = case.settings
        if settings.implementation is None:
            raise ScenarioError("implementation: a campaign runs the loop as implemented; add an [implementation]")
        image = [k for k in case.scenario.dispersion if k.startswith(("plant.camera", "plant.mount", "plant.target"))]
        if image and case.loop.mode != "image":
            raise ScenarioError(f'dispersion."{image[0]}": acts through the image; needs e_e = "image"')
        if any(k.startswith("plant.friction") for k in case.scenario.dispersion) and (
            settings.implementation.integrator == "cvodes"
        ):
            raise ScenarioError('dispersion: friction needs a fixed-step integrator ("auto", "rosenbrock" or "rk4")')
        inputs = [k for k in case.scenario.dispersion if k in INPUTS]
        if inputs and not parametrised(case.loop):
            raise ScenarioError(f'dispersion."{inputs[0]}": an input of the paper\'s loop only, not the planar one')
        if "target.motion.radius" in case.scenario.dispersion and case.scenario.target.motion.kind == "static":
            raise ScenarioError('dispersion."target.motion.radius": a static target has no radius; give a circle')
        base = base_values(case.scenario, campaign_settings(case), case.s0, case.loop.robot.n)
        return CampaignSpec(case, Dispersion(dict(case.scenario.dispersion), base), bound, seed)

    def values(self, run: int) -> dict[str, np.ndarray]:
        """Run ``run``'s drawn values."""
        return self.dispersion.draw(np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(run,))))

    def run_settings(self, run: int, values: dict[str, np.ndarray] | None = None) -> tuple[Settings, np.ndarray]:
        """The settings and start of run ``run`` (with ``values``, else its drawn ones); its
        pixel noise and faults seeded from the run's own seed sequence."""
        values = self.values(run) if values is None else values
        settings, s0 = with_values(campaign_settings(self.case), self.case.s0, self.case.loop, self.case.scenario,
                                   values)  # fmt: skip
        noise_seed = int(np.random.SeedSequence(self.seed, spawn_key=(run, 1)).generate_state(1, np.uint64)[0])
        return replace(settings, implementation=replace(settings.sampled, seed=noise_seed)), s0

    def replay(self, run: int | None = None, values: Path | None = None) -> str:
        """The command that replays run ``run``, or run 0's noise with the values in the file ``values``."""
        path = self.case.path or "SCENARIO"
        which = f"--campaign-run {run}" if values is None else f"--campaign-values {values}"
        return f"dvfc simulate {path} {which}" + (f" --campaign-seed {self.seed}" if self.seed else "")


def campaign_settings(case: Case) -> Settings:
    """The case's settings with plant errors (none when the scenario gives none) and, when the
    dispersion draws the plant's masses, a plant (the URDF's arm when the scenario gives none):
    the code path of every campaign run."""
    settings = case.settings
    if settings.errors is None:
        settings = replace(settings, errors=PlantErrors.none(case.loop.camera, case.loop.robot.n))
    if settings.plant is None and any(key in MASSES for key in case.scenario.dispersion):
        settings = replace(settings, plant=case.loop.robot)
    return settings


def row(spec: CampaignSpec, run: int, traj: Trajectory, settings: Settings, values: dict[str, np.ndarray]) -> dict:
    """One run's dataset row: outcome, tracking error, peak ratios, drawn values, wall time."""
    loop = spec.case.loop
    holds, reason = judge(traj, loop, settings, spec.bound)
    verdict = local_verdict_of(spec.case, settings, spec.bound.limits)
    if verdict is not None and not verdict.certified:  # a failure whatever its run shows
        reason = (f"fact 14 for this draw's plant: not certified locally at rest ({verdict.reason}); "
                  + ("its run held: the horizon is too short to show it" if holds else reason))  # fmt: skip
        holds = False
    position, angle = tracking_error(traj)
    completed = traj.status is RunStatus.OK
    ratio = max(position / spec.bound.position, angle / spec.bound.angle_deg) if completed else math.inf
    record = limit_record(traj, robot_limits(loop, settings))
    limits = [max(record["speed_ratio"]), max(record["position_ratio"])]
    if not settings.sampled.saturate:
        limits.append(max(record["torque_commanded_ratio"]))
    out = {
        "run": run, "holds": holds, "reason": reason, "status": traj.status,
        "tracking_position": position, "tracking_angle_deg": angle, "tracking_ratio": ratio,
        "peak_torque_ratio": max(record["torque_commanded_ratio"]), "peak_speed_ratio": max(record["speed_ratio"]),
        "position_ratio": max(record["position_ratio"]), "closeness": max(ratio, *limits),
        "end_time": float(traj.t[-1]), "wall_time": traj.wall_time,
        "local_error_q": traj.stats.get("local_error_q"),  # None (null) for a run by RK4
        "local_rho": None if verdict is None else verdict.rho,
        "local_certified": None if verdict is None else verdict.certified,
        "friction_position": None if verdict is None or verdict.friction is None else verdict.friction.position,
        "friction_angle_deg": None if verdict is None or verdict.friction is None else verdict.friction.angle_deg,
    }  # fmt: skip
    for key in spec.dispersion.keys:
        columns = spec.dispersion.columns_of(key)
        out.update(zip(columns, map(float, values[key]), strict=True))
    return out


def local_verdict_of(
    case: Case, settings: Settings, criterion: tuple[float, float] | None = None
) -> LocalVerdict | None:
    """Fact 14 for one run's plant as drawn (its masses, camera, friction; at the scenario's latency and
    rates: docs/math.md, fact 25), its dry friction's tracking error at rest judged against ``criterion``
    (fact 29), by the one function ``certify`` and ``margins`` use too
    (:func:`dvfc.analysis.multirate.local_verdict`: every check, the self-motion's included); None where
    the statement does not apply to the loop."""
    if applicability(case.loop, settings) is not None:
        return None
    return DeclaredPlant.of(settings).verdict(case.loop, case.s0[: case.loop.robot.n], settings.sampled, criterion)


def has_dry_friction(spec: CampaignSpec) -> bool:
    """Whether the campaign's plants have dry friction (declared or drawn)."""
    errors = spec.case.settings.errors
    drawn = "plant.friction.coulomb" in spec.case.scenario.dispersion
    return errors is not None and (drawn or errors.has_dry_friction)


def local_summary(data: dict, dry_friction: bool = False) -> dict:
    """How many runs' plants fact 14 certifies locally (``local_certified``), the largest ``rho`` and the
    runs it does not certify (failures whatever their runs show); ``dry_friction``: whether the plants have
    dry friction, whose tracking error at rest (fact 29) the verdict holds to the criterion."""
    checked = [(int(run), rho, certified) for run, rho, certified in zip(data["run"], data["local_rho"],
                                                                         data["local_certified"], strict=True)
               if certified is not None]  # fmt: skip
    unstable = [run for run, _, certified in checked if not certified]
    largest = max((rho for _, rho, _ in checked), default=None)
    return {"computed": len(checked), "certified": len(checked) - len(unstable), "largest_rho": largest,
            "unstable_runs": unstable,
            "statement": (f"{len(checked) - len(unstable)} of {len(data['run'])} draws locally certified (fact 14 "
                          f"for each draw's plant, linearised at rest, at the scenario's latency and rates: rho < 1 "
                          f"with every check of the monodromy), largest rho "
                          f"{'-' if largest is None else f'{largest:.6g}'}"
                          + ("" if not dry_friction else
                             "; the joints' dry friction is a torque bounded by its Coulomb level (fact 29, no "
                             "smoothing), and the tracking error it can hold at rest must be within the "
                             "criterion"))}  # fmt: skip


def simulate_run(spec: CampaignSpec, run: int, simulator: SampledSimulator | None = None) -> tuple[dict, Trajectory]:
    """Run ``run`` of the campaign on ``simulator``'s compiled functions (default: the process's
    :func:`shared_simulator`, so that a replayed run integrates as the campaign did): its row
    and trajectory."""
    values = spec.values(run)
    settings, s0 = spec.run_settings(run, values)
    sim = (shared_simulator(spec.case) if simulator is None else simulator).for_run(settings)
    traj = sim.run(s0)
    return row(spec, run, traj, settings, values), traj


def true_pixels(loop: ClosedLoop, traj: Trajectory, errors: PlantErrors) -> np.ndarray:
    """The features the plant's camera sees along a run, without noise: ``(T, m, 2)`` pixels from
    the image's top-left corner, by the true mount, intrinsics, distortion and points of
    ``errors`` (:func:`dvfc.models.errors.true_features`) at each output sample."""
    parameters = cs.SX.sym("errors", camera_size(loop.camera.m))
    true = true_features(loop.camera, loop.relative_pose, parameters)[0]
    function = cs.Function("true_pixels", [loop.t, loop.state, parameters], [true]).map(len(traj.t))
    vector = np.repeat(errors.camera_vector(loop.camera)[:, None], len(traj.t), axis=1)
    f = np.asarray(function(traj.t, traj["state"].T, vector)).T
    return f.reshape(len(traj.t), -1, 2) + np.asarray(errors.principal_point, dtype=float)


SIMULATORS = 4
"""Compiled campaign simulators kept per process (least recently used dropped)."""

_simulators: OrderedDict[int, tuple[Case, SampledSimulator]] = OrderedDict()


def shared_simulator(case: Case) -> SampledSimulator:
    """The simulator every run of ``case``'s campaigns runs on (:meth:`SampledSimulator.for_run`),
    built once per process and case: a worker builds it for its first batch and reuses it for
    every later one (a worker receives each batch's case as the same object,
    :func:`dvfc.analysis.case._unpickled`)."""
    key = id(case)
    if key in _simulators:
        _simulators.move_to_end(key)
        return _simulators[key][1]
    simulator = sampled_simulator(case.loop, campaign_settings(case)).settle(case.s0)  # substeps: the case's start
    _simulators[key] = (case, simulator)  # the case held: its id stays its own while cached
    if len(_simulators) > SIMULATORS:
        _simulators.popitem(last=False)
    return simulator


def campaign_batch(spec: CampaignSpec, start: int, stop: int) -> dict[str, list]:
    """Runs ``start .. stop - 1`` (a task) on the process's :func:`shared_simulator`: their rows
    as columns."""
    simulator = shared_simulator(spec.case)
    rows = [simulate_run(spec, k, simulator)[0] for k in range(start, stop)]
    return {key: [r[key] for r in rows] for key in rows[0]}


def batch_table(columns: dict[str, list]) -> pa.Table:
    """A batch's rows as a table, a column with no value in the batch (every entry None: ``local_error_q`` of runs
    that stopped at their start, say) typed ``float64`` as the other batches' are, so that the batches read as one
    dataset."""
    import pyarrow as pa  # here: a command's imports without it

    table = pa.table(columns)
    fields = [pa.field(f.name, pa.float64()) if pa.types.is_null(f.type) else f for f in table.schema]
    return table.cast(pa.schema(fields))


def read_runs(directory: Path) -> pa.Table:
    """Every run of a campaign in ``directory``, in run order."""
    import pyarrow.parquet as pq

    return pq.read_table(directory / RUNS).sort_by("run")


def run_campaign(
    spec: CampaignSpec,
    directory: Path,
    runs: int,
    *,
    batch_size: int = 25,
    workers: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[int], None] | None = None,
    key: str = "",
) -> int:
    """Make runs ``0 .. runs - 1``, one Parquet file per batch in ``directory / runs``, saving
    ``campaign.json`` (runs done) after each; with ``resume``, from the runs done of the campaign of the
    same ``key`` (the scenario's SHA-256, or a report stage's key), seed and runs
    (:class:`dvfc.analysis.batches.BatchRun`). Returns the runs done."""
    identity = {"key": key, "seed": spec.seed, "runs": runs}
    run = BatchRun(directory, RUNS, "campaign.json", identity,
                   "the campaign in this directory has another scenario, seed or number of runs")  # fmt: skip
    return int(run.run(runs, batch_size, campaign_batch, spec, batch_table, resume=resume, workers=workers,
                       scheduler=scheduler, progress=progress)["done"])  # fmt: skip


def clopper_pearson_upper(failures: int, runs: int, confidence: float) -> float:
    """The one-sided Clopper-Pearson upper bound on P(fail) from ``failures`` of ``runs``:
    ``Beta.ppf(confidence, k + 1, n - k)`` (1 when every run fails)."""
    from scipy import stats

    if failures >= runs:
        return 1.0
    return float(stats.beta.ppf(confidence, failures + 1, runs - failures))


def zero_failure_runs(p: float, confidence: float) -> int:
    """The fewest runs that, all holding, bound P(fail) by ``p`` at ``confidence``:
    ``N >= ln(1 - c) / ln(1 - p)``."""
    return math.ceil(math.log(1 - confidence) / math.log(1 - p) - 1e-12)


def tolerance_rank(runs: int, quantile: float, confidence: float) -> int | None:
    """The smallest rank ``r`` (1-based, ascending) whose order statistic bounds the ``quantile``
    of the distribution from above with ``confidence``: ``P(Binomial(n, q) <= r - 1) >= c``;
    None when ``runs`` are too few."""
    from scipy import stats

    ranks = np.arange(1, runs + 1)
    ok = stats.binom.cdf(ranks - 1, runs, quantile) >= confidence
    return int(ranks[ok][0]) if ok.any() else None


def summarize(spec: CampaignSpec, table: pa.Table, confidence: float, p: float, quantile: float) -> dict:
    """The campaign's statement and statistics (JSON-ready; see the module's description)."""
    data = table.to_pydict()
    n = len(data["run"])
    holds = np.asarray(data["holds"], dtype=bool)
    k = int((~holds).sum())
    upper = clopper_pearson_upper(k, n, confidence)
    criterion = CRITERION.format(bound=spec.bound.text) + LOCAL
    ratio = np.asarray(data["tracking_ratio"], dtype=float)
    tolerance = {"quantile": quantile, "confidence": confidence, "rank": None, "tracking_position": None,
                 "tracking_angle_deg": None, "tracking_ratio": None,
                 "note": "runs that did not complete count as an infinite tracking error"}  # fmt: skip
    if (rank := tolerance_rank(n, quantile, confidence)) is not None:
        tolerance["rank"] = rank
        for name in ("tracking_position", "tracking_angle_deg", "tracking_ratio"):
            values = np.where(np.asarray(data["status"]) == "ok", np.asarray(data[name], dtype=float), math.inf)
            tolerance[name] = float(np.sort(values)[rank - 1])
        tolerance["statement"] = (
            f"with {confidence:.0%} confidence at least {quantile:.0%} of runs drawn like these have a tracking error "
            f"at most the order statistic of rank {rank} of {n} (distribution-free)"
        )
    else:
        tolerance["statement"] = f"{n} runs are too few to bound the {quantile:.0%} quantile at {confidence:.0%}"
    drivers, floor = sensitivities(spec, data, ratio, holds)
    closeness = np.nan_to_num(np.asarray(data["closeness"], dtype=float), posinf=np.finfo(float).max)
    order = np.lexsort((np.asarray(data["run"]), -closeness, holds))  # failures first, then the closest to failing
    worst = [{"run": int(data["run"][i]), "holds": bool(holds[i]), "reason": data["reason"][i],
              "tracking_ratio": float(ratio[i]), "closeness": float(data["closeness"][i]),
              "replay": spec.replay(int(data["run"][i]))} for i in order[:5]]  # fmt: skip
    statement = (
        f"{k} failures in {n} runs: P(fail) <= {upper:.3g} at {confidence:.0%} confidence ({BOUND}), for runs drawn "
        "from the stated dispersion of the loop as implemented, simulated (a measurement on the model, not a "
        "certificate; it says nothing about errors outside the dispersion)"
    )
    return {
        "runs": n, "failures": k, "confidence": confidence, "p_fail_upper": upper, "bound": BOUND,
        "statement": statement, "criterion": criterion, "tracking_bound": spec.bound.as_dict(),
        "zero_failure": {"p": p, "runs": zero_failure_runs(p, confidence),
                         "statement": f"{zero_failure_runs(p, confidence)} runs without a failure bound P(fail) by "
                                      f"{p:g} at {confidence:.0%} confidence"},
        "tolerance": tolerance, "sensitivity": drivers, "sensitivity_floor": floor, "worst": worst,
        "local": local_summary(data, has_dry_friction(spec)),
        "seed": spec.seed,
        "wall_time_per_run": float(np.mean(data["wall_time"])) if n else None,
        "local_error_q": largest_local_error(data),
    }  # fmt: skip


def largest_local_error(data: dict) -> dict[str, Any] | None:
    """The largest of the runs' local error estimates of the joint angles a period (ROS34PW2's, docs/math.md fact
    28.4) and its run; None where the runs have none (RK4, or a dataset written without the column)."""
    errors = np.asarray(data.get("local_error_q", []), dtype=float)
    if not np.isfinite(errors).any():
        return None
    i = int(np.nanargmax(errors))
    return {"value": float(errors[i]), "run": int(data["run"][i]),
            "statement": f"every run's local error of q a period at most {errors[i]:.2g} rad (ROS34PW2's embedded "
                         f"estimate, largest on run {int(data['run'][i])})"}  # fmt: skip


BINS = 4
"""Quantile bins of each drawn quantity for its failure rate."""


def sensitivities(spec: CampaignSpec, data: dict, ratio: np.ndarray, holds: np.ndarray) -> tuple[list[dict], dict]:
    """Per drawn quantity, its entries' Spearman rank correlation with the tracking ratio (tracking
    error over its bound, infinite for a run that did not complete), their moment-independent
    scores for the closeness to failing (:mod:`dvfc.analysis.sensitivity`: PAWN, against the
    floor of an independent input) and the failure rate per quantile bin; the quantity's
    strongest entry (by PAWN, else by the rank correlation) stated, strongest quantity first.
    Also the floor and what it means."""
    from scipy import stats

    columns = [c for key in spec.dispersion.keys for c in spec.dispersion.columns_of(key)]
    x = np.column_stack([np.asarray(data[c], dtype=float) for c in columns])
    horizon = spec.case.settings.duration
    y = sensitivity.outcome(np.asarray(data["closeness"], dtype=float), np.asarray(data["end_time"]), horizon)
    scores, floor = sensitivity.moment_independent(x, y, seed=spec.seed)
    by_column = dict(zip(columns, scores, strict=True))
    out = []
    for key in spec.dispersion.keys:
        entries = []
        for column in spec.dispersion.columns_of(key):
            x = np.asarray(data[column], dtype=float)
            rho = float(stats.spearmanr(x, ratio).statistic) if np.ptp(x) > 0 and np.ptp(ratio) > 0 else math.nan
            edges = np.quantile(x, np.linspace(0, 1, BINS + 1))
            which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, BINS - 1)
            rates = [float((~holds[which == b]).mean()) if np.any(which == b) else None for b in range(BINS)]
            s = by_column[column]
            entries.append({"column": column, "spearman": None if math.isnan(rho) else rho,
                            "pawn": None if s is None else s.pawn,
                            "above_floor": sensitivity.above_floor(s, floor),
                            "bin_edges": edges.tolist(), "failure_rate": rates})  # fmt: skip
        strongest = max(entries, key=_strength)
        out.append({"quantity": key, **{k: strongest[k] for k in (
            "spearman", "pawn", "above_floor", "column", "failure_rate", "bin_edges")},
                    "entries": entries})  # fmt: skip
    floor_record = {"pawn": floor.pawn, "references": sensitivity.REFERENCES, "note": floor.note}
    return sorted(out, key=lambda e: tuple(-v for v in _strength(e))), floor_record


def _strength(entry: dict) -> tuple[float, float]:
    """An entry's order of strength: its PAWN score (0 without), then its rank correlation's magnitude."""
    return (entry["pawn"] or 0.0, abs(entry["spearman"] or 0.0))


def worst_case(spec: CampaignSpec, budget: int, progress: Callable[[int], None] | None = None) -> dict:
    """A bounded search over the dispersion's box (:meth:`Dispersion.box`) for the run closest to
    failing (the largest of the tracking ratio and the peak limit ratios; a run that stops
    scores above any that completes): scipy's differential evolution within ``budget`` runs (the pixel noise and
    faults of run 0's seed). The worst found is a lower bound on the worst case in the box, not
    the worst case."""
    from scipy.optimize import differential_evolution

    box = spec.dispersion.box()
    simulator = shared_simulator(spec.case)
    best: dict = {"ratio": -math.inf}
    evaluations = 0

    def objective(x: np.ndarray) -> float:
        nonlocal evaluations
        values = spec.dispersion.split(x)
        settings, s0 = spec.run_settings(0, values)
        traj = simulator.for_run(settings).run(s0)
        r = row(spec, 0, traj, settings, values)
        # a run that stops: worse the earlier it stops (so the search climbs toward failure)
        score = r["closeness"] if traj.status is RunStatus.OK else 1e3 * (2 - traj.t[-1] / settings.duration)
        evaluations += 1
        if score > best["ratio"]:
            best.update(ratio=score, values={k: v.tolist() for k, v in values.items()}, holds=r["holds"],
                        reason=r["reason"])  # fmt: skip
        if progress is not None:
            progress(evaluations)
        return -score

    fixed = [i for i, (lo, hi) in enumerate(box) if lo == hi]
    start = time.perf_counter()
    popsize = max(2, math.ceil(min(15, budget / max(1, len(box)) / 2)))
    maxiter = max(0, budget // (popsize * len(box)) - 1)
    bounds = [(lo, hi if hi > lo else lo + 1e-12) for lo, hi in box]
    differential_evolution(objective, bounds, maxiter=maxiter, popsize=popsize, seed=spec.seed, polish=False,
                           tol=0, init="latinhypercube")  # fmt: skip
    return {
        "method": f"scipy differential_evolution, popsize {popsize}, {maxiter} generations, no polish",
        "budget": budget, "evaluations": evaluations, "seconds": time.perf_counter() - start,
        "worst_closeness": best["ratio"], "holds": best["holds"], "reason": best["reason"], "values": best["values"],
        "fixed_columns": len(fixed),
        "statement": "the worst combination found: a lower bound on the worst case over the box, not the worst case",
    }  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class CampaignResult(Record):
    """``dvfc campaign`` (docs/cli.md): the campaign's statistics (:func:`summarize`: the failure
    probability's bound at its confidence, the zero-failure count, the tracking error's tolerance bound,
    the drivers, the worst runs, the draws fact 14 certifies locally), its dataset; the worst case found (with
    ``search``), what would pass
    (``--what-would-pass``; None: no run fails) and provenance, when made."""

    scenario: str
    runs: int
    failures: int
    confidence: float
    p_fail_upper: float
    bound: str
    statement: str
    criterion: str
    tracking_bound: dict[str, Any]
    zero_failure: dict[str, Any]
    tolerance: dict[str, Any]
    sensitivity: list[dict[str, Any]]
    sensitivity_floor: dict[str, Any]
    worst: list[dict[str, Any]]
    seed: int
    wall_time_per_run: float | None
    local_error_q: dict[str, Any] | None
    local: dict[str, Any]
    dataset: str
    worst_case_search: dict[str, Any] | Absent = ABSENT
    what_would_pass: dict[str, Any] | Absent | None = ABSENT
    provenance: dict[str, Any] | Absent = ABSENT


def campaign(
    case: Case,
    directory: Path,
    runs: int = 100,
    *,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    p_fail: float = P_FAIL,
    quantile: float = QUANTILE,
    search: int = 0,
    batch_size: int = 25,
    workers: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[int], None] | None = None,
) -> CampaignResult:
    """The case's ``[dispersion]`` as a campaign of ``runs`` independent runs of the loop as implemented,
    each judged by the margins criterion, stored batch by batch in ``directory`` (``resume`` continues
    an interrupted one); its statistics (:func:`summarize`) at ``confidence``, the zero-failure count
    for ``p_fail``, the tracking error's ``quantile``; with ``search`` runs, the worst case found
    (:func:`worst_case`, also written to ``directory / "worst_case.json"``). ``progress`` gets the runs
    done. Bad arguments raise :class:`ValueError` naming the argument (:class:`ScenarioError` the field)."""
    if runs < 1:
        raise ValueError(f"runs: {runs}; give at least 1")
    for name, value in (("confidence", confidence), ("p_fail", p_fail), ("quantile", quantile)):
        if not 0 < value < 1:
            raise ValueError(f"{name}: {value:g} is not in (0, 1)")
    if not case.scenario.dispersion:
        raise ScenarioError("dispersion: the scenario has no [dispersion] section")
    spec = CampaignSpec.of(case, tracking_bound(case), seed)
    if resume and not (directory / "campaign.json").exists():
        raise ValueError(f"resume: no campaign to resume in {directory}")
    directory.mkdir(parents=True, exist_ok=True)
    run_campaign(spec, directory, runs, batch_size=batch_size, workers=workers, scheduler=scheduler, resume=resume,
                 progress=progress, key=case.provenance([])["scenario_sha256"])  # fmt: skip
    result = CampaignResult(**summarize(spec, read_runs(directory), confidence, p_fail, quantile), scenario=case.name,
                            dataset=str(directory / RUNS))  # fmt: skip
    if search:
        found = worst_case(spec, search)
        write_json(directory / "worst_case.json", found)
        replay = spec.replay(values=directory / "worst_case.json")
        result = replace(result, worst_case_search=found | {"replay": replay})
    return result
