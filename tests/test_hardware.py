"""What would pass (``--what-would-pass``, :mod:`dvfc.analysis.hardware`): the bisection over the
control rate, the camera rate and the latency with the synthesis for the campaign as its check; the
bracket it ends on, the full-size confirmation, the grids, what is held, the log and its resume,
and the command line's bad flags."""

from __future__ import annotations

import json
import math
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dvfc.analysis import cell
from dvfc.analysis import hardware as hw
from dvfc.analysis.case import Case
from dvfc.analysis.margins import tracking_bound
from dvfc.analysis.output import read_log
from dvfc.analysis.scenario import Scenario
from dvfc.reports.cli import app

CELL = Path(__file__).parent.parent / "examples" / "ur5_cell.toml"
runner = CliRunner()


@pytest.fixture(scope="module")
def shipped() -> Case:
    """The shipped cell (500 Hz control, 60 Hz camera, 20 ms latency, 10 ms output step), loaded once."""
    return Case.load(CELL)


class Threshold:
    """A stand-in for the synthesis: it passes where the control rate reaches ``screen`` (the
    bisection's budget) or ``full`` (the full size) Hz, and counts what it is asked."""

    def __init__(self, screen: float, full: float | None = None) -> None:
        self.limits = {"screen": screen, "full": screen if full is None else full}
        self.asked: list[tuple[float, str]] = []

    def __call__(self, case, scenario, budget, progress) -> hw.Evaluation:
        rate = scenario.implementation.control_rate
        level = "screen" if budget.runs < 299 else "full"
        self.asked.append((rate, level))
        holds = rate >= self.limits[level]
        confirmation = {"runs": budget.runs, "failures": 0 if holds else 3, "confidence": budget.confidence,
                        "p_fail_upper": 0.00997 if holds else 0.03, "statement": f"{budget.runs} runs"}  # fmt: skip
        synthesis = {"holds": holds, "limits": None if holds else f"too slow at {rate:g} Hz",
                     "design": {"k_xi": [1.0] * 6} if holds else None, "confirmation": confirmation,
                     "checks": None, "surrogate": None, "search": {"method": "a threshold on the control rate"},
                     "tracking_bound": {}}  # every key of dvfc.analysis.cell.record  # fmt: skip
        return hw.Evaluation(synthesis, 1.0)


def search(case: Case, evaluate, **options) -> dict:
    return hw.what_would_pass(case, evaluate=evaluate, names=("control_rate",), **options)


def test_the_needed_control_rate_is_the_least_grid_value_passing_and_the_one_below_it_fails(shipped):
    check = Threshold(730.0)
    found = search(shipped, check)["parameters"]["control_rate"]
    grid = hw.grid(shipped, "control_rate")
    assert found["needed"] == found["passes_at"] == 800.0
    assert found["fails_at"] == 700.0 and grid.index(found["fails_at"]) == grid.index(found["passes_at"]) - 1
    assert (700.0, "full") in check.asked and (800.0, "full") in check.asked  # both ends at the full size
    assert found["fails_because"] == "too slow at 700 Hz"
    assert found["confirmation"]["runs"] == 299  # the value needed is confirmed at the full size


def test_the_search_is_a_bisection_log2_reduced_checks_and_three_at_the_full_size(shipped):
    check = Threshold(730.0)
    search(shipped, check)
    grid = hw.grid(shipped, "control_rate")  # 16 values: the range's end, then 4 halvings of 15 intervals
    screens = [rate for rate, level in check.asked if level == "screen"]
    assert len(screens) <= 1 + math.ceil(math.log2(len(grid) - 1))
    assert [rate for rate, level in check.asked if level == "full"] == [500.0, 800.0, 700.0]  # as it is, the two ends


def test_a_value_that_fails_at_the_full_size_is_not_reported_needed_the_bisection_continues_above(shipped):
    check = Threshold(730.0, full=930.0)  # the reduced check passes from 800 Hz, the full one from 1000 Hz
    found = search(shipped, check)["parameters"]["control_rate"]
    assert found["needed"] == 1000.0 and (1000.0, "full") in check.asked
    assert found["fails_at"] == 900.0 and (900.0, "full") in check.asked
    assert found["confirmation"]["runs"] == 299


def test_where_the_reduced_check_fails_but_the_full_size_passes_the_bisection_goes_down_at_the_full_size(shipped):
    check = Threshold(930.0, full=730.0)  # the reduced check passes from 1000 Hz, the full one from 800 Hz
    found = search(shipped, check)["parameters"]["control_rate"]
    assert (found["needed"], found["fails_at"]) == (800.0, 700.0)
    assert {(800.0, "full"), (700.0, "full")} <= set(check.asked)


def test_nothing_in_the_range_passes_says_so_with_the_end_that_failed(shipped):
    check = Threshold(5000.0)
    found = search(shipped, check)["parameters"]["control_rate"]
    assert found["needed"] is None and found["passes_at"] is None
    assert found["fails_at"] == 2000.0 and (2000.0, "full") in check.asked  # 4x the scenario's 500 Hz, full size
    assert "no value to 2000 Hz passes" in found["statement"]


def test_a_cell_that_passes_as_it_is_needs_no_change_and_one_synthesis(shipped):
    check = Threshold(100.0)
    result = hw.what_would_pass(shipped, evaluate=check)
    assert result["today"]["holds"] and check.asked == [(500.0, "full")]
    assert all(p["needed"] == p["today"] for p in result["parameters"].values())


def test_the_grids_keep_the_latency_and_the_output_step_whole_periods_and_the_camera_exact(shipped):
    bound = tracking_bound(shipped)
    rates = hw.grid(shipped, "control_rate")
    assert rates[0] == 500.0 and rates[1:] == [600.0 + 100 * k for k in range(15)]  # dt 10 ms, latency 20 ms
    for rate in rates[1:]:
        imp = hw.with_hardware(shipped.scenario, "control_rate", rate, bound).implementation  # validated
        assert abs(imp.latency * rate - round(imp.latency * rate)) < 1e-9 and imp.latency == 0.02
    assert hw.grid(shipped, "camera_rate") == [60.0] + [500.0 / n for n in range(8, 0, -1)]
    assert hw.grid(shipped, "latency") == [0.02] + [k / 500.0 for k in range(9, -1, -1)]
    late = shipped.with_scenario(hw.with_hardware(shipped.scenario, "latency", 0.016, bound))  # 8 periods
    assert hw.grid(late, "control_rate") == [500.0, 1000.0, 1500.0, 2000.0]  # 16 and 10 ms: 500 Hz


def test_a_new_control_rate_holds_in_seconds_what_the_scenario_gives_in_control_periods(shipped):
    bound = tracking_bound(shipped)
    moved = hw.with_hardware(shipped.scenario, "control_rate", 1000.0, bound)
    imp, before = moved.implementation, shipped.scenario.implementation
    assert imp.latency_jitter * 1e-3 == before.latency_jitter * 2e-3  # 2 periods of 2 ms: 4 of 1 ms
    jitter = moved.dispersion["implementation.latency_jitter"].values
    assert jitter == [2 * v for v in shipped.scenario.dispersion["implementation.latency_jitter"].values]
    assert (imp.latency, imp.camera_rate, imp.substeps) == (before.latency, before.camera_rate, 1)
    assert (moved.criterion.position, moved.criterion.angle_deg) == (bound.position, bound.angle_deg)


def test_an_interrupted_search_resumes_with_the_same_answer_and_no_evaluation_made_twice(shipped, tmp_path):
    log = tmp_path / "what_would_pass.jsonl"
    whole = search(shipped, Threshold(730.0), log=tmp_path / "whole.jsonl")

    class Interrupted(Threshold):
        def __call__(self, *args):
            if len(self.asked) == 3:
                raise KeyboardInterrupt
            return super().__call__(*args)

    with pytest.raises(KeyboardInterrupt):
        search(shipped, Interrupted(730.0), log=log)
    logged = {(e["value"], e["level"]) for e in read_log(log)}
    assert len(logged) == 3
    again = Threshold(730.0)
    resumed = search(shipped, again, log=log, resume=True)
    assert not logged & set(again.asked)  # nothing logged was made again
    assert len(again.asked) + len(logged) == whole["evaluations"] == resumed["evaluations"]
    assert resumed["made"] == len(again.asked)
    strip = lambda r: json.dumps(r["parameters"], sort_keys=True)  # noqa: E731
    assert strip(resumed) == strip(whole)


def test_what_would_pass_without_for_campaign_is_one_line_exit_2(tmp_path):
    result = runner.invoke(app, ["synthesize", str(CELL), "--what-would-pass", "--out", str(tmp_path / "x.toml")])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        "error: --what-would-pass: searches the hardware for the synthesis --for-campaign; give --for-campaign"
    ]


def test_what_would_pass_on_margins_without_a_dispersion_is_one_line_exit_2(tmp_path):
    text = CELL.read_text()
    (tmp_path / "plain.toml").write_text(text[: text.index("[dispersion]")])
    result = runner.invoke(app, ["margins", str(tmp_path / "plain.toml"), "--what-would-pass",
                                 "--out", str(tmp_path / "m")])  # fmt: skip
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == ["error: dispersion: what would pass needs a [dispersion] section"]


def test_resuming_a_search_that_was_never_started_is_one_line_exit_2(tmp_path):
    target = tmp_path / "x.toml"
    result = runner.invoke(app, ["synthesize", str(CELL), "--for-campaign", "--what-would-pass", "--resume",
                                 "--out", str(target)])  # fmt: skip
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        f"error: --resume: no what-would-pass search to resume ({target}.what_would_pass.jsonl not found)"
    ]
    assert not target.exists()


def test_the_refusing_synthesis_prints_and_jsons_what_would_pass(tmp_path, monkeypatch):
    monkeypatch.setattr("dvfc.analysis.jobs.what_would_pass",
                        partial(hw.what_would_pass, evaluate=Threshold(730.0), names=("control_rate",)))  # fmt: skip
    target, saved = tmp_path / "x.toml", tmp_path / "x.json"
    result = runner.invoke(app, ["synthesize", str(CELL), "--for-campaign", "--what-would-pass", "--out", str(target),
                                 "--json", str(saved)], env={"COLUMNS": "400"})  # fmt: skip
    assert result.exit_code == 1 and not target.exists()  # refused as it is: nothing written
    found = json.loads(saved.read_text(), parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    rate = found["what_would_pass"]["parameters"]["control_rate"]
    assert (rate["today"], rate["needed"], rate["fails_at"]) == (500.0, 800.0, 700.0)
    row = next(line for line in result.stdout.splitlines() if line.lstrip("│ ").startswith("control_rate"))
    assert "fails at 700 Hz, passes at 800 Hz" in row and "0 of 299 fail" in row
    assert (tmp_path / "x.toml.what_would_pass.jsonl").exists()


def slow_cell() -> Case:
    """The shipped cell at a 50 Hz control rate: a 50 Hz camera (at most the control rate), the latency
    20 ms (one period), the output step 20 ms, the RK4 step 2 ms as at 500 Hz, no jitter (its 2 ms
    periods round to none at 50 Hz), over 4 s (the planned start's 2 s and 2 s after it). Wrist 3's
    hold limit at 50 Hz (1.65) lies below every gain the synthesis reaches: it refuses."""
    case = Case.load(CELL)
    data = case.scenario.model_dump()
    data["implementation"].update(control_rate=50.0, camera_rate=50.0, latency=0.02, substeps=10, latency_jitter=0)
    data["dispersion"]["implementation.latency_jitter"]["values"] = [0.0]
    data["simulation"].update(dt=0.02, duration=4.0)
    return case.with_scenario(Scenario.model_validate(data))


@pytest.mark.slow
def test_a_cell_too_slow_at_50_hz_passes_at_the_rate_found_and_the_synthesis_refuses_below_it():
    case = slow_cell()
    full = cell.Search(runs=2, horizon=4.0, population=4, generations=2)
    screen = hw.Budget(cell.Search(runs=2, horizon=4.0, population=4, generations=1), 0.5, 0.75)
    found = hw.what_would_pass(case, p_fail=0.5, confidence=0.75, search=full, screen=screen, names=("control_rate",))
    rate = found["parameters"]["control_rate"]
    assert not found["today"]["holds"] and "the control rate (50 Hz)" in found["today"]["limits"]
    assert rate["needed"] == rate["passes_at"] > 50.0
    grid = hw.grid(case, "control_rate")
    assert grid.index(rate["fails_at"]) == grid.index(rate["passes_at"]) - 1  # adjacent on the grid

    def synthesis(value: float, search: cell.Search, p_fail: float) -> cell.CellSynthesis:
        """The synthesis itself at ``value`` Hz, the case built here by hand (latency and camera held)."""
        data = case.scenario.model_dump()
        data["implementation"].update(control_rate=value, substeps=int(np.ceil(10 * 50.0 / value)))
        return cell.synthesize_for_campaign(case.with_scenario(Scenario.model_validate(data)), p_fail=p_fail,
                                            confidence=0.75, search=search)  # fmt: skip

    assert not synthesis(rate["fails_at"], full, 0.5).holds  # fails below, at the full size
    passing = synthesis(rate["passes_at"], full, 0.5)  # passes at
    assert passing.holds and passing.confirmation.failures == 0
