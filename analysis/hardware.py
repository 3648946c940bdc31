"""What to change when nothing passes: the least change of the hardware at which the synthesis for
the campaign succeeds, measured.

For each parameter of the ``[implementation]`` separately (:data:`UNITS`: the control rate up, the
camera rate up, the latency down), the other two held, a bisection over the parameter's grid
(:func:`grid`) finds the least change at which ``dvfc synthesize --for-campaign``
(:func:`dvfc.analysis.cell.synthesize_for_campaign`) writes a design. The inner check is that
synthesis itself: during the bisection with a reduced budget (:data:`SCREEN_SEARCH`, a confirming
campaign bounding P(fail) by :data:`SCREEN_P_FAIL`), which only chooses where to look; every value the
answer states is checked with the full budget (the command's search and its ``p_fail`` and
``confidence``): the scenario's value, the value found (failing there, the bisection continues above
it), the value below it (passing there, the bisection continues below it at the full size) and, when
nothing passes, the range's end. The bracket reported fails at its lower end and passes at its upper
end, both at the full size.

Held while one parameter moves: the others' values in seconds and hertz, the dispersion and the
criterion (the scenario's :func:`~dvfc.analysis.margins.tracking_bound`, pinned). What the scenario
gives in control periods is held in seconds when the control rate moves, to the nearest whole period
(:func:`with_hardware`: ``latency_jitter`` and its dispersion's values; the RK4 ``substeps``, so that
the integration step never grows).

The bisection assumes that a change that passes keeps passing further along the parameter: a
measurement on simulated runs, not a proof (the synthesis is a search, and its confirmation a
campaign). Every finished evaluation is appended to a JSON-lines log keyed by the evaluated scenario
and budget, so an interrupted search resumes with nothing lost or repeated.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from fractions import Fraction
from pathlib import Path

from dvfc.analysis.campaign import zero_failure_runs
from dvfc.analysis.case import Case
from dvfc.analysis.cell import Search, synthesize_for_campaign
from dvfc.analysis.cell import record as cell_record
from dvfc.analysis.margins import TrackingBound, tracking_bound
from dvfc.analysis.output import append_log, raise_if_interrupted, read_log
from dvfc.analysis.scenario import Scenario, ScenarioError

UNITS = {"control_rate": "Hz", "camera_rate": "Hz", "latency": "s"}
"""The parameters searched (each separately, in this order: the control and camera rates up, the
latency down) and their units."""

CONTROL_FACTOR = 4.0
"""The control rate is searched up to this times the scenario's."""

SCREEN_SEARCH = Search(runs=8, population=6, generations=3)
"""The synthesis's search during the bisection: 18 candidates on 8 common-random-number runs
(the full search: 40 on 12)."""
SCREEN_P_FAIL = 0.1
"""The P(fail) the bisection's confirmations bound (29 runs at 95%); every value stated is checked at
the command's (299 runs for 1% at 95%)."""

FULL_SEARCH = Search()
"""The full search: the synthesis's own (40 candidates on 12 runs)."""

SCREEN, FULL = "screen", "full"
"""The two levels of the inner check."""


@dataclass(frozen=True)
class Budget:
    """One level of the inner check: the synthesis's ``search`` and the P(fail) ``p_fail`` its
    confirming campaign bounds at ``confidence``."""

    search: Search
    p_fail: float
    confidence: float

    @property
    def runs(self) -> int:
        """The confirming campaign's runs: :func:`~dvfc.analysis.campaign.zero_failure_runs`."""
        return zero_failure_runs(self.p_fail, self.confidence)

    def as_dict(self) -> dict:
        """JSON-ready; the workers left out (they do not change a result)."""
        search = {k: v for k, v in asdict(self.search).items() if k != "workers"}
        return {"search": search, "p_fail": self.p_fail, "confidence": self.confidence, "confirmation_runs": self.runs}

    def screen(self) -> Budget:
        """The reduced budget of the bisection: :data:`SCREEN_SEARCH` (on this budget's horizon and
        workers), its confirmation bounding the larger of :data:`SCREEN_P_FAIL` and ``p_fail``."""
        search = replace(SCREEN_SEARCH, horizon=self.search.horizon, workers=self.search.workers)
        return Budget(search, max(SCREEN_P_FAIL, self.p_fail), self.confidence)


@dataclass(frozen=True)
class Evaluation:
    """One inner check: the synthesis's record (:func:`dvfc.analysis.cell.record`: whether it holds,
    what limits it otherwise, the design, its certificates and its confirming campaign) and its wall
    time (s)."""

    synthesis: dict
    seconds: float

    @property
    def holds(self) -> bool:
        return bool(self.synthesis["holds"])


Evaluate = Callable[[Case, Scenario, Budget, Callable[[str], None]], Evaluation]
"""An inner check: the case searched, its scenario at a hardware point (:func:`with_hardware`), the
budget, a progress callback."""


def synthesis_check(case: Case, scenario: Scenario, budget: Budget, progress: Callable[[str], None]) -> Evaluation:
    """The inner check: :func:`~dvfc.analysis.cell.synthesize_for_campaign` with ``budget`` on
    ``case`` with ``scenario`` (built anew)."""
    start = time.perf_counter()
    result = synthesize_for_campaign(case.with_scenario(scenario), p_fail=budget.p_fail, confidence=budget.confidence,
                                     search=budget.search, progress=progress)  # fmt: skip
    return Evaluation(cell_record(result), time.perf_counter() - start)


def hardware(scenario: Scenario) -> dict[str, float]:
    """The scenario's control rate and camera rate (Hz; every control sample when not given) and latency (s)."""
    if scenario.implementation is None:
        raise ScenarioError("implementation: what would pass changes the loop as implemented; add an [implementation]")
    imp = scenario.implementation.implementation()
    return {"control_rate": imp.control_rate, "camera_rate": imp.camera_rate, "latency": imp.latency}


def control_step(case: Case) -> Fraction:
    """The smallest control rate (Hz) at which the output step ``dt`` and the latency (when not zero)
    are whole numbers of control periods: the least common multiple of their inverses (as fractions)."""
    latency = hardware(case.scenario)["latency"]
    step = 1 / Fraction(case.scenario.simulation.dt).limit_denominator(10**6)
    for p in [latency] if latency > 0 else []:
        f = 1 / Fraction(p).limit_denominator(10**6)
        step = Fraction(math.lcm(step.numerator, f.numerator), math.gcd(step.denominator, f.denominator))
    return step


def grid(case: Case, name: str) -> list[float]:
    """The values searched for ``name``, the scenario's first, then toward the better end:

    - ``control_rate``: the whole multiples of the smallest rate at which the output step ``dt``
      and the latency are whole numbers of control periods (100 Hz for 10 ms and 20 ms), above the
      scenario's, up to :data:`CONTROL_FACTOR` times it;
    - ``camera_rate``: an image every whole number ``N`` of control periods (``control_rate / N``,
      fact 14's exact schedules), above the scenario's, up to one at every control sample;
    - ``latency``: whole numbers of control periods below the scenario's, down to none."""
    today = hardware(case.scenario)
    rate = today["control_rate"]
    if name == "control_rate":
        step = control_step(case)
        first = math.floor(Fraction(rate).limit_denominator(10**6) / step) + 1
        last = math.floor(Fraction(CONTROL_FACTOR * rate).limit_denominator(10**6) / step)
        return [rate] + [float(k * step) for k in range(first, last + 1)]
    if name == "camera_rate":
        most = math.ceil(rate / today["camera_rate"] - 1e-9) - 1
        return [today["camera_rate"]] + [rate / n for n in range(most, 0, -1)]
    periods = round(today["latency"] * rate)
    return [today["latency"]] + [k / rate for k in range(periods - 1, -1, -1)]


def grid_text(case: Case, name: str) -> str:
    """The grid of :func:`grid` in words."""
    if name == "control_rate":
        return (f"whole multiples of {float(control_step(case)):g} Hz (the output step and the latency whole numbers "
                f"of control periods), up to {CONTROL_FACTOR:g}x the scenario's")  # fmt: skip
    if name == "camera_rate":
        return "an image every N control periods (control_rate / N, fact 14's exact schedules), up to N = 1"
    return "whole numbers of control periods, down to none"


def with_hardware(scenario: Scenario, name: str, value: float, bound: TrackingBound) -> Scenario:
    """``scenario`` with ``name = value`` (the others held; the criterion ``bound`` pinned),
    validated. A new control rate holds in seconds what the scenario gives in control periods, to the
    nearest whole period: ``latency_jitter`` and the values of its dispersion; and holds the RK4
    step at most the scenario's (``substeps`` rounded up)."""
    data = scenario.model_dump()
    imp = data["implementation"]
    if value != hardware(scenario)[name]:  # the scenario's own value stays as written (a camera_rate left out)
        if name == "control_rate":
            ratio = value / imp["control_rate"]
            imp["latency_jitter"] = round(imp["latency_jitter"] * ratio)
            if (jitter := data["dispersion"].get("implementation.latency_jitter")) is not None:
                jitter["values"] = [float(round(v * ratio)) for v in jitter["values"]]
            if isinstance(imp["substeps"], int):
                imp["substeps"] = max(1, math.ceil(imp["substeps"] / ratio - 1e-9))
        imp[name] = value
    data["criterion"] = {"position": bound.position, "angle_deg": bound.angle_deg}
    return Scenario.model_validate(data)


def fingerprint(scenario: Scenario, budget: Budget) -> str:
    """What identifies an evaluation in the log: the SHA-256 of the evaluated scenario and the budget."""
    text = json.dumps({"scenario": scenario.model_dump(mode="json"), "budget": budget.as_dict()},
                      sort_keys=True)  # fmt: skip
    return hashlib.sha256(text.encode()).hexdigest()


class Evaluations:
    """The inner checks made, by :func:`fingerprint`, kept in a JSON-lines ``log`` (None: in memory):
    a check found there is not made again."""

    def __init__(self, evaluate: Evaluate, log: Path | None, progress: Callable[[str], None]) -> None:
        self.evaluate, self.log, self.say = evaluate, log, progress
        self.done = {e["fingerprint"]: e for e in ([] if log is None else read_log(log)) if "holds" in e}
        self.used: set[str] = set()
        self.made = 0

    def at(self, case: Case, name: str, value: float, level: str, budget: Budget, bound: TrackingBound) -> dict:
        """The check of ``name = value`` at ``level`` with ``budget``: from the log, or made and logged."""
        scenario = with_hardware(case.scenario, name, value, bound)
        key = fingerprint(scenario, budget)
        self.used.add(key)
        if key in self.done:
            return self.done[key]
        same = value == hardware(case.scenario)[name]
        label = f"{'as it is' if same else f'{name} = {value_text(value, UNITS[name])}'} ({level})"
        self.say(f"{label}: synthesising ({_size(budget)})")
        result = self.evaluate(case, scenario, budget, lambda text: self.say(f"{label}: {text}"))
        raise_if_interrupted()  # the synthesis may be cut short: not logged
        self.made += 1
        self.say(f"{label}: {'passes' if result.holds else 'refused'} ({result.seconds:.0f} s)")
        entry = {"fingerprint": key, "parameter": name, "value": value, "level": level, "hardware": hardware(scenario),
                 "holds": result.holds, "limits": result.synthesis["limits"], "synthesis": result.synthesis,
                 "seconds": result.seconds}  # fmt: skip
        self.done[key] = entry
        if self.log is not None:
            append_log(self.log, entry)
        return entry


def bisect(case: Case, name: str, bound: TrackingBound, screen: Budget, full: Budget, checks: Evaluations) -> dict:
    """The least change of ``name`` at which the synthesis passes (the module's description): the
    record of :func:`what_would_pass`'s ``parameters`` entries. The reduced check only chooses where
    to look: both ends of the bracket reported (and the range end when nothing passes) are checked
    at the full size."""
    unit, values = UNITS[name], grid(case, name)
    budgets = {SCREEN: screen, FULL: full}
    full_fail: dict[int, dict] = {}  # index: its failing full-size check
    passes: set[int] = set()  # indices a check (either) passes

    def check(i: int, level: str) -> bool:
        entry = checks.at(case, name, values[i], level, budgets[level], bound)
        if entry["holds"]:
            passes.add(i)
        elif level == FULL:
            full_fail[i] = entry
        return entry["holds"]

    def entry(i: int) -> dict:
        return checks.at(case, name, values[i], FULL, full, bound)

    record = {"parameter": name, "unit": unit, "today": values[0], "needed": None,
              "range": [values[0], values[-1]], "grid": grid_text(case, name), "fails_at": None,
              "fails_because": None, "passes_at": None, "confirmation": None, "design": None}  # fmt: skip
    if check(0, FULL):
        return {**record, **_passing(entry(0)), "needed": values[0], "passes_at": values[0],
                "statement": "passes as it is: no change needed"}  # fmt: skip
    lo, hi = 0, len(values) - 1

    def nothing(i: int) -> dict:
        return {**record, "fails_at": values[i], "fails_because": full_fail[i]["limits"],
                "statement": f"no value to {value_text(values[i], unit)} passes (the full-size synthesis)"}  # fmt: skip

    if hi == 0:
        return {**nothing(0), "statement": f"already at the end of the searched range ({value_text(values[0], unit)})"}
    if not check(hi, SCREEN) and not check(hi, FULL):
        return nothing(hi)
    while True:
        while hi - lo > 1:  # the reduced check's bracket
            mid = (lo + hi) // 2
            if check(mid, SCREEN):
                hi = mid
            else:
                lo = mid
        if not check(hi, FULL):  # fails at the full size: look above it
            lo = hi
            above = [i for i in passes if i > lo]
            if not above:
                return nothing(lo)
            hi = min(above)
            continue
        if lo in full_fail or not check(lo, FULL):
            break
        hi, lo = lo, max(i for i in full_fail if i < lo)  # the reduced check failed where the full passes
        while hi - lo > 1:  # bisect at the full size
            mid = (lo + hi) // 2
            if check(mid, FULL):
                hi = mid
            else:
                lo = mid
        break
    passed = _passing(entry(hi))
    return {**record, **passed, "needed": values[hi], "fails_at": values[lo], "fails_because": full_fail[lo]["limits"],
            "passes_at": values[hi],
            "statement": (f"passes at {value_text(values[hi], unit)} (full size: "
                          f"{passed['confirmation']['statement']}); fails at {value_text(values[lo], unit)} "
                          "(full size)")}  # fmt: skip


def _passing(entry: dict) -> dict:
    """The confirmation and the design of a passing check."""
    return {"confirmation": entry["synthesis"]["confirmation"], "design": entry["synthesis"]["design"]}


def _size(budget: Budget) -> str:
    """A budget in words."""
    s = budget.search
    return (f"CMA-ES {s.population} x {s.generations} candidates on {s.runs} runs of {s.horizon:g} s, "
            f"{budget.runs}-run confirmation")  # fmt: skip


def value_text(value: float | None, unit: str) -> str:
    """A value with its unit (a latency in ms; ``-`` for none)."""
    if value is None:
        return "-"
    return f"{value * 1e3:.4g} ms" if unit == "s" else f"{value:.5g} {unit}"


def what_would_pass(
    case: Case,
    *,
    p_fail: float = 0.01,
    confidence: float = 0.95,
    search: Search = FULL_SEARCH,
    screen: Budget | None = None,
    names: tuple[str, ...] = tuple(UNITS),
    log: Path | None = None,
    resume: bool = False,
    evaluate: Evaluate = synthesis_check,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """For each of ``names`` (of :data:`UNITS`), the least change at which the synthesis for the
    campaign passes (the module's description; JSON-ready, docs/cli.md). ``search``, ``p_fail`` and
    ``confidence``: the full budget; ``screen``: the bisection's (default :meth:`Budget.screen`);
    ``log``: the finished evaluations (kept with ``resume``, else started afresh); ``evaluate``: the inner
    check (:func:`synthesis_check`). ``today`` holds the full synthesis at the scenario's own
    hardware (its record, ``synthesis``: the answer of ``dvfc synthesize --for-campaign``);
    ``evaluations`` counts the checks the answer rests on, ``made`` those made by this call (the
    others were in the log)."""
    say = progress or (lambda _: None)
    start = time.perf_counter()
    bound = tracking_bound(case)
    full = Budget(search, p_fail, confidence)
    screen = full.screen() if screen is None else screen
    if log is not None and not resume:
        log.unlink(missing_ok=True)
    checks = Evaluations(evaluate, log, say)
    as_it_is = hardware(case.scenario)
    first = checks.at(case, "latency", as_it_is["latency"], FULL, full, bound)
    found = {name: bisect(case, name, bound, screen, full, checks) for name in names}
    return {
        "scenario": case.name,
        "today": {"hardware": as_it_is, "holds": first["holds"], "limits": first["limits"],
                  "synthesis": first["synthesis"]},
        "parameters": found,
        "screen": screen.as_dict(),
        "full": full.as_dict(),
        "criterion": bound.as_dict(),
        "held": ("each parameter moved alone, the others held; what the scenario gives in control periods held in "
                 "seconds to the nearest whole period when the control rate moves (latency_jitter and its "
                 "dispersion; the RK4 step at most the scenario's); the dispersion and the criterion held"),
        "method": (f"bisection on each parameter's grid with the synthesis for the campaign as the check, reduced "
                   f"while searching ({_size(screen)}); every value stated checked at the full size ({_size(full)}): "
                   "the scenario's, the bracket's two ends, the range's end when nothing passes"),
        "assumption": ("a change that passes keeps passing further along its parameter: measured on simulated runs, "
                       "not proven (the synthesis is a search, its confirmation a campaign)"),
        "evaluations": len(checks.used),
        "made": checks.made,
        "seconds": time.perf_counter() - start,
    }  # fmt: skip
