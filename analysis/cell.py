"""A design that holds on a cell: gains chosen for the scenario's dispersion campaign.

The search (``dvfc synthesize SCENARIO --for-campaign``) chooses ``K_xi`` (one scale for the
large joints 1-3, one for the wrists 4-6, on the scenario's values), ``K_c`` and ``K_e`` (one
scale each) and the integral gain ``K_I = k_i_factor K_xi`` (docs/math.md, fact 20) so that

- every ``k_xi,i`` lies inside its gain window (:mod:`dvfc.analysis.windows`, with the windows'
  hold margin) and Theorem 2 certifies the gains (the ideal continuous loop; fact 20.2: the
  integral state leaves gamma unchanged);
- the loop as implemented is certified locally with the integral state (facts 14, 21):
  ``rho(Pi) <= RHO_MAX`` (on a redundant arm across the self-motion) and fact 14's one verdict
  (:func:`dvfc.analysis.multirate.local_verdict`: the a posteriori Lyapunov check, the self-motion's checks, no
  saturation at rest);
- the campaign holds: CMA-ES (the ``cma`` package, within a box of the log-scales) minimises a
  surrogate of the campaign, the mean of the largest quarter of the runs' closeness to failing
  by what the gains move (the largest of the tracking ratio, the peak torque and the peak joint
  speed over their limits; the joint-range ratio, which the gains hardly move, is left to the
  confirmation) over a fixed set of runs (common random numbers: campaign runs ``0 .. runs - 1`` of
  the scenario's seed for every candidate, on a shortened horizon), with a penalty above any
  completed run's value outside the windows or fact 14;

then confirms the best design found on a campaign with fresh seeds (campaign seed
:data:`CONFIRM_SEED`: runs independent of the search's) of ``zero_failure_runs(p_fail, confidence)`` runs on the
full horizon, judged by the scenario's criterion (:func:`dvfc.analysis.margins.tracking_bound`
of the scenario as given, pinned in the written design's ``[criterion]``). The search's value
and the confirmation are measurements on simulated runs, not certificates; the confirmation's
P(fail) bound is the campaign's Clopper-Pearson bound.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit

from dvfc.analysis.batches import batches
from dvfc.analysis.campaign import CampaignSpec, campaign_batch, clopper_pearson_upper, zero_failure_runs
from dvfc.analysis.case import Case
from dvfc.analysis.certify import GainPoint, certify
from dvfc.analysis.console import remaining
from dvfc.analysis.margins import TrackingBound, tracking_bound
from dvfc.analysis.multirate import DeclaredPlant
from dvfc.analysis.synthesize import scenario_text
from dvfc.analysis.tasks import run_tasks
from dvfc.analysis.windows import case_windows
from dvfc.models.loop import Gains

RHO_MAX = 0.99
"""Fact 14's monodromy radius a design must stay at or below (with the integral state): every
rate below ``-ln(0.99) / T_P`` (0.2 1/s over the cell's 50 ms period) is certified locally."""

SCALE_BOX = (0.25, 4.0)
"""The box of each gain scale searched (on the scenario's gains)."""
K_I_BOX = (1.0, 60.0)
"""The box of ``k_i_factor`` searched: ``K_I = k_i_factor K_xi``, an integral time of 1 to 1/60 s
(fact 21 measured the cell well damped up to ``60 K_xi``)."""

SEARCH_SEED, CONFIRM_SEED = 0, 1
"""The campaign seeds of the search's runs (``dvfc campaign``'s default: its runs ``0 .. runs - 1``)
and of the confirmation's (independent of them)."""

TAIL = 0.25
"""The surrogate is the mean of this largest fraction of the runs' closeness to failing."""
PENALTY = 10.0
"""The surrogate of a design outside the windows or fact 14 (plus how far outside): above every
run that completes within ten times its criterion."""
CAP = 5.0
"""A run's closeness to failing is capped here in the surrogate (a run that stops counts as CAP)."""
CLOSENESS = ("tracking_ratio", "peak_torque_ratio", "peak_speed_ratio")
"""The campaign row's ratios the surrogate takes the largest of, run by run."""


@dataclass(frozen=True)
class Search:
    """How the search runs: ``runs`` common-random-number campaign runs per candidate, each over
    ``horizon`` seconds, CMA-ES with ``population`` candidates a generation for ``generations``
    generations (its own ``seed``), on ``workers`` local processes."""

    runs: int = 12
    horizon: float = 6.0
    population: int = 8
    generations: int = 5
    seed: int = 1
    workers: int = 1


@dataclass(frozen=True)
class Design:
    """A candidate: the gains of (42) and the integral factor ``K_I = k_i_factor K_xi``."""

    k_xi: np.ndarray
    k_c: np.ndarray
    k_e: np.ndarray
    k_i_factor: float

    def as_dict(self) -> dict:
        return {"k_xi": self.k_xi.tolist(), "k_c": self.k_c.tolist(), "k_e": self.k_e.tolist(),
                "k_i_factor": self.k_i_factor}  # fmt: skip

    @staticmethod
    def of(data: dict) -> Design:
        """The design of its :meth:`as_dict`."""
        k_xi, k_c, k_e = (np.asarray(data[k], dtype=float) for k in ("k_xi", "k_c", "k_e"))
        return Design(k_xi, k_c, k_e, float(data["k_i_factor"]))


@dataclass(frozen=True)
class Checks:
    """A design's certificates: its gain windows (what breaks them, empty inside), Theorem 2's gamma
    (None: not certified), fact 14's ``rho`` and Lyapunov margin with the integral state (None: the
    statement does not apply) and its verdict (``local_certified``: :func:`dvfc.analysis.multirate.local_verdict`,
    every check of the monodromy and saturation at rest), and whether all pass."""

    outside: tuple[str, ...]
    gamma: float | None
    rho: float | None
    lyapunov_margin: float | None
    local_certified: bool

    @property
    def passes(self) -> bool:
        return (not self.outside and self.gamma is not None and self.rho is not None and self.rho <= RHO_MAX
                and self.local_certified)  # fmt: skip

    def violation(self) -> float:
        """How far outside: 0 when the design passes, else at least 1."""
        if self.passes:
            return 0.0
        rho = 0.0 if self.rho is None else max(0.0, self.rho - RHO_MAX)
        return 1.0 + len(self.outside) + (self.gamma is None) + min(rho, 1e3) * 100

    def as_dict(self) -> dict:
        return {"windows_outside": list(self.outside), "gamma": self.gamma, "rho": self.rho, "rho_max": RHO_MAX,
                "lyapunov_margin": self.lyapunov_margin, "local_certified": self.local_certified,
                "passes": self.passes}  # fmt: skip


@dataclass(frozen=True)
class Confirmation:
    """The confirming campaign: its seed, runs, failures, P(fail) bound at ``confidence``, the largest
    tracking angle over the last half (deg) and position (m), and the first failures' reasons."""

    seed: int
    runs: int
    failures: int
    confidence: float
    p_fail_upper: float
    max_tracking_angle_deg: float
    max_tracking_position: float
    reasons: tuple[str, ...]

    def as_dict(self) -> dict:
        return {"seed": self.seed, "runs": self.runs, "failures": self.failures, "confidence": self.confidence,
                "p_fail_upper": self.p_fail_upper, "max_tracking_angle_deg": self.max_tracking_angle_deg,
                "max_tracking_position": self.max_tracking_position, "reasons": list(self.reasons)}  # fmt: skip


@dataclass(frozen=True)
class CellSynthesis:
    """The result: ``design`` (None: refused, ``limits`` says what limits it), its checks, its
    surrogate value, the confirming campaign, the criterion, the candidates evaluated and the wall
    time (s) of the search and of the confirmation."""

    design: Design | None
    checks: Checks | None
    surrogate: float | None
    confirmation: Confirmation | None
    bound: TrackingBound
    evaluations: int
    search: Search
    limits: str | None
    search_seconds: float
    confirm_seconds: float

    @property
    def holds(self) -> bool:
        return self.design is not None and self.confirmation is not None and self.confirmation.failures == 0


def candidate_case(case: Case, design: Design, *, horizon: float | None = None) -> Case:
    """``case`` with ``design``'s gains (and ``horizon`` seconds, when given), built anew."""
    data = case.scenario.model_dump()
    data["gains"].update(k_xi=design.k_xi.tolist(), k_c=design.k_c.tolist(), k_e=design.k_e.tolist(),
                         k_i=None, k_i_factor=design.k_i_factor)  # fmt: skip
    if horizon is not None:
        data["simulation"]["duration"] = horizon
    return case.with_scenario(type(case.scenario).model_validate(data))


def checks(case: Case, design: Design) -> Checks:
    """The windows, Theorem 2 and fact 14 (with the integral state, for the case's plant as declared) of
    ``design`` on ``case``."""
    windows = case_windows(replace_gains(case, design))
    outside = tuple(windows.breaks()) if windows is not None else ()
    point = GainPoint(design.k_xi, design.k_c, design.k_e, case.point.weights, case.point.plant)
    cert = certify(point, case.reference, theta_max=math.radians(case.scenario.certify.theta_max_deg),
                   gamma_bound=case.scenario.certify.gamma)  # fmt: skip
    gamma = cert.gamma if cert.certified else None
    if outside:  # the hold breaks: fact 14 is not worth computing
        return Checks(outside, gamma, None, None, False)
    loop = replace(case.loop, gains=Gains(design.k_xi, design.k_c, design.k_e, design.k_i_factor * design.k_xi))
    try:
        verdict = DeclaredPlant.of(case.settings).verdict(loop, case.s0[: loop.robot.n], case.settings.sampled,
                                                          case.criterion)  # fmt: skip
    except ValueError:  # no linearisation at rest
        verdict = None
    if verdict is None:  # the statement does not apply
        return Checks(outside, gamma, None, None, False)
    margin = None if verdict.check is None else verdict.check.margin
    return Checks(outside, gamma, verdict.rho, margin, verdict.certified)


def replace_gains(case: Case, design: Design) -> Case:
    """``case`` whose ``point`` carries ``design``'s ``K_xi`` (for the windows at these gains)."""
    return case.with_gains(k_xi=design.k_xi.tolist(), k_c=design.k_c.tolist(), k_e=design.k_e.tolist())


def design_of(case: Case, x: np.ndarray) -> Design:
    """The design of the search variables ``x = ln [scale_big, scale_wrist, scale_c, scale_e,
    k_i_factor]`` (joints 1-3 are the large joints of a 6-joint arm; on another ``n`` the first
    half)."""
    p, n = case.point, case.loop.robot.n
    big = np.arange(n) < n // 2
    scale = np.exp(np.asarray(x, dtype=float))
    k_xi = p.k_xi * np.where(big, scale[0], scale[1])
    return Design(_rounded(k_xi), _rounded(p.k_c * scale[2]), _rounded(p.k_e * scale[3]), float(_rounded(scale[4:])[0]))


def _rounded(values: np.ndarray) -> np.ndarray:
    """To 4 significant figures (the file shows what was evaluated)."""
    return np.array([float(f"{v:.4g}") for v in np.atleast_1d(values)])


def surrogate(rows: dict[str, list]) -> float:
    """The mean of the largest :data:`TAIL` of the runs' closeness (the largest of
    :data:`CLOSENESS`), each capped at :data:`CAP` (a run that stops: ``CAP``)."""
    ratios = np.column_stack([np.asarray(rows[k], dtype=float) for k in CLOSENESS])
    closeness = np.where(np.asarray(rows["status"]) == "ok", ratios.max(axis=1), math.inf)
    c = np.sort(np.minimum(np.nan_to_num(closeness, nan=CAP, posinf=CAP), CAP))
    tail = max(1, math.ceil(TAIL * len(c)))
    return float(c[-tail:].mean())


def run_rows(specs: list[CampaignSpec], runs: int, workers: int,
             progress: Callable[[int, int], None] | None = None) -> list[dict[str, list]]:  # fmt: skip
    """Runs ``0 .. runs - 1`` of each spec (split in ``workers`` batches a spec), their rows as columns;
    ``progress(done, total)`` is told the runs made so far of all of them after each batch."""
    size = max(1, math.ceil(runs / max(1, workers)))
    tasks = [(spec, a, b) for spec in specs for a, b in batches(0, runs, size)]
    columns: list[dict[str, list]] = [{} for _ in specs]
    done = 0
    for (spec, a, b), result in zip(tasks, run_tasks(campaign_batch, tasks, workers), strict=True):
        target = columns[specs.index(spec)]
        for key, values in result.items():
            target.setdefault(key, []).extend(values)
        done += b - a
        if progress is not None:
            progress(done, runs * len(specs))
    return columns


def synthesize_for_campaign(
    case: Case,
    *,
    p_fail: float = 0.01,
    confidence: float = 0.95,
    search: Search = Search(),
    progress: Callable[[str], None] | None = None,
) -> CellSynthesis:
    """The design of the module's description for ``case`` (a scenario with an ``[implementation]``
    and a ``[dispersion]``; :class:`~dvfc.analysis.scenario.ScenarioError` where a campaign cannot
    run)."""
    import cma

    say = progress or (lambda _: None)
    bound = tracking_bound(case)
    CampaignSpec.of(case, bound)  # refuses what cannot run, before any work
    start = time.perf_counter()
    evaluated: dict[tuple, tuple[float, Design, Checks]] = {}

    def evaluate(xs: list[np.ndarray], generation: int) -> list[float]:
        designs = [design_of(case, x) for x in xs]
        values: list[Any] = []  # None until its campaign's runs are made
        specs, where = [], []
        for i, d in enumerate(designs):
            key = tuple(np.r_[d.k_xi, d.k_c, d.k_e, d.k_i_factor])
            if key in evaluated:
                values.append(evaluated[key][0])
                continue
            c = checks(case, d)
            if not c.passes:
                evaluated[key] = (PENALTY + c.violation(), d, c)
                values.append(evaluated[key][0])
                continue
            values.append(None)
            specs.append(CampaignSpec.of(candidate_case(case, d, horizon=search.horizon), bound, SEARCH_SEED))
            where.append((i, key, d, c))
        started = time.perf_counter()

        def told(done: int, total: int) -> None:
            elapsed = time.perf_counter() - started
            say(f"generation {generation} of {search.generations}: {done} of {total} runs of its "
                f"{len(specs)} campaigns, {remaining(done, total, elapsed)}")  # fmt: skip

        told(0, search.runs * len(specs))
        for (i, key, d, c), rows in zip(where, run_rows(specs, search.runs, search.workers, told), strict=True):
            evaluated[key] = (surrogate(rows), d, c)
            values[i] = evaluated[key][0]
        return [float(v) for v in values]

    lo, hi = np.log([SCALE_BOX[0]] * 4 + [K_I_BOX[0]]), np.log([SCALE_BOX[1]] * 4 + [K_I_BOX[1]])
    x0 = np.r_[np.zeros(4), np.log(10.0)]  # the scenario's gains, K_I = 10 K_xi (fact 21's measured choice)
    options = {"bounds": [lo.tolist(), hi.tolist()], "popsize": search.population, "seed": search.seed,
               "maxiter": search.generations, "verbose": -9}  # fmt: skip
    es = cma.CMAEvolutionStrategy(x0, 0.5, options)
    es.inject([x0])  # the first generation holds the scenario's own design
    for g in range(search.generations):
        xs = es.ask()
        es.tell(xs, evaluate(xs, g + 1))
        say(f"generation {g + 1} of {search.generations}: best {min(v[0] for v in evaluated.values()):.4g}")
    value, best, best_checks = min(evaluated.values(), key=lambda v: v[0])
    search_seconds = time.perf_counter() - start
    if not best_checks.passes:
        return CellSynthesis(None, best_checks, None, None, bound, len(evaluated), search,
                             refusal(best_checks, None, case), search_seconds, 0.0)  # fmt: skip
    say(f"confirming on {zero_failure_runs(p_fail, confidence)} runs with fresh seeds")
    start = time.perf_counter()
    confirmation = confirm(candidate_case(case, best), bound, zero_failure_runs(p_fail, confidence), confidence,
                           CONFIRM_SEED, search.workers)  # fmt: skip
    limits = None if confirmation.failures == 0 else refusal(best_checks, confirmation, case)
    return CellSynthesis(best, best_checks, value, confirmation, bound, len(evaluated), search, limits,
                         search_seconds, time.perf_counter() - start)  # fmt: skip


def confirm(case: Case, bound: TrackingBound, runs: int, confidence: float, seed: int, workers: int) -> Confirmation:
    """The campaign of ``case`` with ``seed`` over ``runs`` runs, judged against ``bound``."""
    rows = run_rows([CampaignSpec.of(case, bound, seed)], runs, workers)[0]
    holds = np.asarray(rows["holds"], dtype=bool)
    ok = np.asarray(rows["status"]) == "ok"
    angle = np.where(ok, np.asarray(rows["tracking_angle_deg"], dtype=float), math.inf)
    position = np.where(ok, np.asarray(rows["tracking_position"], dtype=float), math.inf)
    k = int((~holds).sum())
    reasons = tuple(f"run {r}: {why}" for r, h, why in zip(rows["run"], holds, rows["reason"], strict=True) if not h)
    return Confirmation(seed, runs, k, confidence, clopper_pearson_upper(k, runs, confidence), float(angle.max()),
                        float(position.max()), reasons[:5])  # fmt: skip


def refusal(found: Checks, confirmation: Confirmation | None, case: Case) -> str:
    """What limits the best design found, in one line: the control rate (the hold limits of the
    windows), the camera latency and rates (fact 14's rho), the effort limits or the tracking error
    (the confirming campaign's failures)."""
    imp = case.settings.sampled
    if confirmation is None:
        if found.outside:
            why = f"the control rate ({imp.control_rate:g} Hz): {found.outside[0]}"
        elif found.gamma is None:
            why = "Theorem 2 certifies no gains searched"
        else:
            why = (f"the camera's latency ({imp.latency * 1e3:g} ms) and rate ({imp.camera_rate:g} Hz) at "
                   f"{imp.control_rate:g} Hz control: fact 14's rho {found.rho:.4g} > {RHO_MAX:g}")  # fmt: skip
        return f"no design inside the gain windows passes: {why}"
    effort = [r for r in confirmation.reasons if "torque" in r]
    what = "the effort limits" if effort else "the tracking error (wrist friction against the gains the windows allow)"
    return (f"no design found holds on the campaign: {confirmation.failures} of {confirmation.runs} confirming runs "
            f"fail, limited by {what}; first: {confirmation.reasons[0]}")  # fmt: skip


def design_text(original: str, case: Case, design: Design, bound: TrackingBound, *, name: str,
                source: Path, target: Path) -> str:
    """The scenario file with ``design`` written (:func:`dvfc.analysis.synthesize.scenario_text`,
    comments kept), ``k_i_factor`` set (``k_i`` removed), the criterion pinned in ``[criterion]`` and
    the design it started from (``case``'s name and ``[gains]``) in ``[synthesized_from]``."""  # fmt: skip
    point = GainPoint(design.k_xi, design.k_c, design.k_e, case.point.weights, case.point.plant)
    doc = tomlkit.parse(scenario_text(original, point, name=name, weights=False, source=source, target=target))
    gains = doc["gains"]
    if "k_i" in gains:
        del gains["k_i"]
    gains["k_i_factor"] = design.k_i_factor
    criterion = doc.setdefault("criterion", tomlkit.table())
    criterion["position"] = float(bound.position)
    criterion["angle_deg"] = float(bound.angle_deg)
    origin = tomlkit.table()
    origin.add(tomlkit.comment("the design the [gains] above were synthesised from (dvfc synthesize --for-campaign)"))
    origin["name"] = case.name
    origin["gains"] = case.scenario.gains.model_dump(mode="json", exclude_none=True, exclude_defaults=True)
    doc["synthesized_from"] = origin
    return tomlkit.dumps(doc)


def record(result: CellSynthesis) -> dict:
    """JSON-ready (docs/cli.md, ``synthesize --for-campaign``)."""
    d, s = result.design, result.search
    return {
        "holds": result.holds,
        "design": None if d is None else d.as_dict(),
        "checks": None if result.checks is None else result.checks.as_dict(),
        "surrogate": result.surrogate,
        "search": {"method": f"CMA-ES (cma), population {s.population}, {s.generations} generations, seed {s.seed}",
                   "runs": s.runs, "horizon": s.horizon, "candidates": result.evaluations,
                   "surrogate": f"mean of the largest {TAIL:.0%} of max({', '.join(CLOSENESS)}) over campaign runs "
                                f"0 .. {s.runs - 1} (common random numbers), {s.horizon:g} s horizon",
                   "seconds": result.search_seconds},
        "confirmation": None if result.confirmation is None else {
            **result.confirmation.as_dict(), "seconds": result.confirm_seconds,
            "statement": (f"{result.confirmation.failures} failures in {result.confirmation.runs} runs with fresh "
                          f"seeds: P(fail) <= {result.confirmation.p_fail_upper:.3g} at "
                          f"{result.confirmation.confidence:.0%} confidence (clopper-pearson, one-sided; simulated "
                          "runs of the loop as implemented, a measurement, not a certificate)")},
        "tracking_bound": result.bound.as_dict(),
        "limits": result.limits,
    }  # fmt: skip
