"""The campaign's drivers: a moment-independent sensitivity (PAWN) beside the rank
correlation, against a floor (an input independent of the loop)."""

from __future__ import annotations

import copy
import tomllib

import numpy as np
import pytest
from scipy import stats

from dvfc.analysis import campaign as campaign_module
from dvfc.analysis.campaign import CampaignSpec, read_runs, run_campaign
from dvfc.analysis.case import Case
from dvfc.analysis.margins import tracking_bound
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.sensitivity import above_floor, moment_independent, outcome

BASE = tomllib.loads(DEFAULT_SCENARIO.read_text())


def u_shaped(runs: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Three inputs uniform on [-1, 1]; the outcome ``x0^2`` plus a little noise: x0 fails the loop
    both ways, x1 and x2 are harmless."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (runs, 3))
    return x, x[:, 0] ** 2 + 0.05 * rng.normal(size=runs)


def test_a_driver_that_fails_both_ways_is_first_by_pawn_though_its_rank_correlation_is_near_zero():
    """The symmetric driver's Spearman correlation is within sampling noise of 0 (|rho| below the
    two-sided 5% critical value ~ 2 / sqrt(N)), yet its PAWN score clears the floor and the
    harmless inputs' scores by far."""
    x, y = u_shaped(200)
    rho = stats.spearmanr(x[:, 0], y).statistic
    assert abs(rho) < 2 / np.sqrt(200)
    scores, floor = moment_independent(x, y)
    assert above_floor(scores[0], floor)
    assert scores[0].pawn > 2 * max(scores[1].pawn, scores[2].pawn)


def test_harmless_inputs_do_not_clear_the_floor():
    """An outcome independent of every input: no input is told apart from the reference."""
    rng = np.random.default_rng(3)
    x, y = rng.uniform(size=(200, 3)), rng.normal(size=200)
    scores, floor = moment_independent(x, y)
    assert not any(above_floor(s, floor) for s in scores)


@pytest.mark.parametrize("runs", [10, 25, 60, 64, 90, 99, 150, 299])
def test_every_campaign_size_is_scored(runs):
    """Every number of runs from 10 gets scores (SALib's slicing fails for some slice counts)."""
    x, y = u_shaped(runs)
    scores, floor = moment_independent(x, y)
    assert all(s is not None for s in scores) and floor.pawn is not None


def test_runs_that_did_not_complete_stand_in_above_every_finite_run_and_the_earlier_the_higher():
    closeness = np.array([0.5, 1.7, np.inf, np.inf])
    y = outcome(closeness, np.array([10.0, 10.0, 2.0, 8.0]), 10.0)
    assert np.all(np.isfinite(y))
    assert y[2] > y[3] > y[1] > y[0]
    assert y[0] == 0.5 and y[1] == 1.7


def test_too_few_runs_or_a_constant_outcome_score_nothing_and_say_why():
    x, y = u_shaped(8)
    scores, floor = moment_independent(x, y)
    assert scores == [None] * 3 and "too few" in floor.note
    x, _ = u_shaped(40)
    scores, floor = moment_independent(x, np.ones(40))
    assert scores == [None] * 3 and "same in every run" in floor.note


@pytest.mark.slow
def test_when_most_runs_fail_the_mount_rotation_failing_both_ways_ranks_above_a_harmless_observer_error(tmp_path):
    """A mount rotation uniform in +-1.2 rad about the optical axis's normal fails most runs
    (either sign); a small error of the observer's initial estimate changes nothing that matters.
    The drivers rank the mount first, above the floor; the observer error does not clear it,
    though on these runs its rank correlation is the larger (what ranked it first before)."""
    data = copy.deepcopy(BASE)
    data["simulation"]["duration"] = 3.0  # past the default's 2 s planned start
    data["dispersion"] = {
        "plant.mount.rpy": {"dist": "uniform", "low": [-1.2, 0.0, 0.0], "high": [1.2, 0.0, 0.0]},
        "observer.error_xyz": {"dist": "normal", "sigma": 0.002},
    }
    case = Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent)
    spec = CampaignSpec.of(case, tracking_bound(case))
    run_campaign(spec, tmp_path, 30, batch_size=15)
    summary = campaign_module.summarize(spec, read_runs(tmp_path), 0.95, 0.01, 0.9)
    assert summary["failures"] >= 20
    first = summary["sensitivity"][0]
    assert first["quantity"] == "plant.mount.rpy" and first["column"] == "plant.mount.rpy[0]"
    assert first["above_floor"]
    observer = next(e for e in summary["sensitivity"] if e["quantity"] == "observer.error_xyz")
    assert not any(e["above_floor"] for e in observer["entries"])
    assert abs(observer["spearman"]) > abs(first["spearman"])
