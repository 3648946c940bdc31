"""A campaign run that stopped before its horizon (diverged, lost the target, ran out of time: any status
but ``ok``) is a failure, and in the tolerance bound on the tracking error it counts as an infinite error
at every quantile and for every statistic (position, angle, ratio): the error it reached before it
stopped is of a shorter run and says nothing of the error it would have reached, so it must never make
the bound look smaller."""

from __future__ import annotations

import copy
import math
import tomllib

import numpy as np
import pyarrow as pa
import pytest

from dvfc.analysis.campaign import CampaignSpec, row, shared_simulator, summarize, tolerance_rank
from dvfc.analysis.case import Case
from dvfc.analysis.dispersion import Dispersion
from dvfc.analysis.margins import TrackingBound
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.schema import DistributionSection
from dvfc.analysis.simulate import RunStatus

BOUND = TrackingBound(0.01, 1.0, "scenario", "")
WIDE = TrackingBound(1.0, 180.0, "scenario", "")
"""A bound every start of the default example is within."""
STATISTICS = ("tracking_position", "tracking_angle_deg", "tracking_ratio")
STOPS = [s.value for s in RunStatus if s is not RunStatus.OK]
KEY = "implementation.pixel_noise"
RUNS = 20
LEVELS = [(q, c) for q in (0.05, 0.1, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95) for c in (0.5, 0.75, 0.9, 0.95)]
"""(quantile, confidence) pairs: with 20 runs their ranks run from 1 to 20, and some have none (too few
runs for the 95% quantile at 90% confidence)."""
BY_RANK = list({tolerance_rank(RUNS, q, c): (q, c) for q, c in reversed(LEVELS) if tolerance_rank(RUNS, q, c)}.values())
"""One (quantile, confidence) pair of :data:`LEVELS` for each rank they reach."""


@pytest.fixture(scope="module")
def spec() -> CampaignSpec:
    """A campaign of the default example with one drawn quantity: what the statistics read of it (its
    columns, horizon and replay command) and nothing it would run."""
    d = Dispersion({KEY: DistributionSection(dist="uniform", low=-0.1, high=0.1)}, {KEY: np.array([0.5])})
    return CampaignSpec(Case.load(), d, BOUND)


def records(stopped: list[int], partial: float, seed: int = 4) -> dict[str, list]:
    """``RUNS`` run records: the runs in ``stopped`` stopped (each with another of the stop statuses) with
    the tracking error ``partial`` in every statistic (below every completed run's when small, NaN when
    the run had diverged); the others completed with distinct errors between 0.1 and 1 of the bound."""
    rng = np.random.default_rng(seed)
    position, angle = BOUND.position * rng.uniform(0.1, 1, RUNS), BOUND.angle_deg * rng.uniform(0.1, 1, RUNS)
    ratio = np.maximum(position / BOUND.position, angle / BOUND.angle_deg)
    status = ["ok"] * RUNS
    for i, run in enumerate(stopped):
        status[run] = STOPS[i % len(STOPS)]
        position[run] = angle[run] = ratio[run] = partial
    return {
        "run": list(range(RUNS)), "holds": [s == "ok" for s in status], "reason": [""] * RUNS, "status": status,
        "tracking_position": position.tolist(), "tracking_angle_deg": angle.tolist(), "tracking_ratio": ratio.tolist(),
        "closeness": ratio.tolist(), "end_time": [2.0 if s == "ok" else 1.0 for s in status],
        "wall_time": [0.1] * RUNS, "local_rho": [None] * RUNS,
        "local_certified": [None] * RUNS, KEY: rng.uniform(0.4, 0.6, RUNS).tolist(),
    }  # fmt: skip


def tolerance(spec: CampaignSpec, data: dict, quantile: float, confidence: float) -> dict:
    return summarize(spec, pa.table(data), confidence, 0.01, quantile)["tolerance"]


def order_statistic(data: dict, name: str, rank: int) -> float:
    """The ``rank``-th smallest of the statistic ``name`` with every stopped run's taken as infinite."""
    values = [v if s == "ok" else math.inf for v, s in zip(data[name], data["status"], strict=True)]
    return sorted(values)[rank - 1]


@pytest.mark.parametrize("stopped", [[], [3], [0, 7, 12], list(range(0, RUNS, 2)), list(range(RUNS))],
                         ids=["none", "one", "three", "half", "all"])  # fmt: skip
def test_a_stopped_run_counts_as_an_infinite_tracking_error_at_every_quantile(spec, stopped):
    """Stopped runs with a partial error of 1e-9 (below every completed run's): at every quantile and
    confidence the bound of each statistic is the order statistic of its rank with the stopped runs'
    errors taken as infinite (exactly: the same float), so infinite exactly where the rank reaches into the
    stopped runs (rank > completed runs), and never below the bound of the completed runs alone."""
    data = records(stopped, 1e-9)
    completed = RUNS - len(stopped)
    ranked = 0
    for quantile, confidence in LEVELS:
        rank = tolerance_rank(RUNS, quantile, confidence)
        out = tolerance(spec, data, quantile, confidence)
        assert out["rank"] == rank
        if rank is None:
            assert all(out[name] is None for name in STATISTICS)
            continue
        ranked += 1
        for name in STATISTICS:
            assert out[name] == order_statistic(data, name, rank), (quantile, confidence, name)
            assert math.isinf(out[name]) == (rank > completed), (quantile, confidence, name)
            ok = sorted(v for v, s in zip(data[name], data["status"], strict=True) if s == "ok")
            assert out[name] >= max(ok[:rank], default=0.0)
    assert ranked >= 20


@pytest.mark.parametrize("partial", [0.0, 1e-12, 0.5, 1e6, math.nan, math.inf])
def test_the_bound_does_not_depend_on_the_error_a_stopped_run_reached(spec, partial):
    """The bound is the same whatever the tracking error recorded for the stopped runs (none, tiny, within
    the bound, far beyond it, NaN from a diverged state, infinite), at a quantile and confidence of each
    rank: it is not the stopped run's to give."""
    stopped = [1, 5, 9, 13]
    reference = records(stopped, math.inf)
    data = records(stopped, partial)
    assert len(BY_RANK) >= 10
    for quantile, confidence in BY_RANK:
        expected, out = tolerance(spec, reference, quantile, confidence), tolerance(spec, data, quantile, confidence)
        assert {k: out[k] for k in STATISTICS} == {k: expected[k] for k in STATISTICS}, (quantile, confidence)


@pytest.mark.parametrize("status", STOPS)
def test_every_kind_of_stop_counts_as_an_infinite_error_and_a_failure(spec, status):
    """A single stopped run of each status, with zero partial error: the bound at the largest rank (the 95%
    quantile at 50% confidence, rank 20 of 20) is infinite in each statistic, one rank lower it is the
    largest completed run's, and the run is counted among the failures."""
    data = records([6], 0.0)
    data["status"][6] = status
    assert tolerance_rank(RUNS, 0.95, 0.5) == RUNS
    out = tolerance(spec, data, 0.95, 0.5)
    for name in STATISTICS:
        assert out[name] == math.inf, name
    below = next((q, c) for q, c in LEVELS if tolerance_rank(RUNS, q, c) == RUNS - 1)
    out = tolerance(spec, data, *below)
    for name in STATISTICS:
        assert out[name] == max(v for i, v in enumerate(data[name]) if i != 6), name
    assert summarize(spec, pa.table(data), 0.95, 0.01, 0.9)["failures"] == 1


@pytest.fixture(scope="module")
def stopping_campaign() -> CampaignSpec:
    """The default example as implemented, stopping a run at a joint speed beyond the URDF's limit, with
    its initial joint speeds dispersed."""
    data = copy.deepcopy(tomllib.loads(DEFAULT_SCENARIO.read_text()))
    data["implementation"]["velocity_limits"] = "stop"
    data["dispersion"] = {"robot.qd0": {"dist": "normal", "sigma": 0.01}}
    case = Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent)
    return CampaignSpec.of(case, WIDE)


def test_a_run_that_stopped_is_a_failure_with_an_infinite_tracking_ratio(stopping_campaign):
    """A run started at 10 rad/s on every joint (beyond the UR5's 3.15 rad/s) stops at its first sample
    with its tracking error finite and within the bound (the start's); its dataset row says it does not
    hold, names the stop, and records its tracking ratio and closeness to failing as infinite."""
    spec = stopping_campaign
    n = spec.case.loop.robot.n
    values = spec.values(0) | {"robot.qd0": np.full(n, 10.0)}
    settings, s0 = spec.run_settings(0, values)
    traj = shared_simulator(spec.case).for_run(settings).run(s0)
    assert traj.status is RunStatus.VELOCITY_LIMIT, traj.message
    out = row(spec, 0, traj, settings, values)
    assert out["tracking_position"] < WIDE.position and out["tracking_angle_deg"] < WIDE.angle_deg
    assert out["holds"] is False and out["reason"].startswith("velocity_limit")
    assert out["tracking_ratio"] == math.inf and out["closeness"] == math.inf
