"""What a campaign's statistics say of its runs: the failures counted and their one-sided bound, the
worst runs listed failures first and then the closest to failing, and each drawn quantity's failure rate
per quantile bin of its values. Checked on run records made here, so that each property is seen on runs
whose answer is known."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest
from scipy import stats

from dvfc.analysis.campaign import CampaignSpec, summarize
from dvfc.analysis.case import Case
from dvfc.analysis.dispersion import Dispersion
from dvfc.analysis.margins import TrackingBound
from dvfc.analysis.schema import DistributionSection

KEY = "implementation.pixel_noise"
BOUND = TrackingBound(0.01, 1.0, "scenario", "")


@pytest.fixture(scope="module")
def spec() -> CampaignSpec:
    """A campaign of the default example drawing its pixel noise: what the statistics read of it."""
    d = Dispersion({KEY: DistributionSection(dist="uniform", low=-0.1, high=0.1)}, {KEY: np.array([0.5])})
    return CampaignSpec(Case.load(), d, BOUND)


def records(closeness: list[float], holds: list[bool], drawn: list[float] | None = None) -> pa.Table:
    """Completed runs with the given closeness to failing (also their tracking ratio) and outcomes."""
    runs = len(closeness)
    ratio = np.asarray(closeness, dtype=float)
    return pa.table({
        "run": list(range(runs)), "holds": holds, "reason": ["" if h else "fails" for h in holds],
        "status": ["ok"] * runs, "tracking_position": (ratio * BOUND.position).tolist(),
        "tracking_angle_deg": (ratio * BOUND.angle_deg).tolist(), "tracking_ratio": ratio.tolist(),
        "closeness": ratio.tolist(), "end_time": [2.0] * runs, "wall_time": [0.1] * runs, "local_rho": [None] * runs,
        "local_certified": [None] * runs,
        KEY: drawn if drawn is not None else np.linspace(0.4, 0.6, runs).tolist(),
    })  # fmt: skip


@pytest.mark.parametrize("failures", [0, 1, 3, 12])
def test_the_failures_are_the_runs_that_do_not_hold_and_bound_p_fail_one_sided(spec, failures):
    """``k`` runs of 12 that do not hold: the summary counts ``k`` and bounds ``P(fail)`` by the one-sided
    Clopper-Pearson bound ``beta.ppf(c, k + 1, n - k)`` at each confidence (``1 - (1 - c)^(1/n)`` without a
    failure, 1 when every run fails), to 1e-12; the bound grows with the failures and with the confidence."""
    holds = [i >= failures for i in range(12)]
    table = records([0.5] * 12, holds)
    bounds = []
    for confidence in (0.5, 0.9, 0.95, 0.99):
        out = summarize(spec, table, confidence, 0.01, 0.9)
        assert out["runs"] == 12 and out["failures"] == failures
        if failures == 12:
            expected = 1.0
        elif failures == 0:
            expected = 1 - (1 - confidence) ** (1 / 12)
        else:
            expected = stats.beta.ppf(confidence, failures + 1, 12 - failures)
        assert out["p_fail_upper"] == pytest.approx(expected, abs=1e-12)
        assert f"{failures} failures in 12 runs" in out["statement"]
        bounds.append(out["p_fail_upper"])
    assert bounds == sorted(bounds)


def test_the_worst_runs_are_the_failures_first_then_the_closest_to_failing(spec):
    """Five runs are listed: every failure first (the closest to failing first among them, an infinite
    closeness before any finite one; a failure with a small closeness, as when the drawn plant is locally
    unstable, before any holding run), then the holding runs from the closest to failing down; equal
    closeness in run order (run 2 before run 6). Each names its run and the command that replays it."""
    closeness = [0.2, math.inf, 0.9, 1.7, 0.95, 0.3, 0.9, 0.6, 0.1]  # run 7 fails below a holding run's closeness
    holds = [True, False, True, False, True, True, True, False, True]
    out = summarize(spec, records(closeness, holds), 0.95, 0.01, 0.9)
    assert [w["run"] for w in out["worst"]] == [1, 3, 7, 4, 2]
    assert [w["holds"] for w in out["worst"]] == [False, False, False, True, True]
    for w in out["worst"]:
        assert w["replay"].endswith(f"--campaign-run {w['run']}")
        assert w["closeness"] == closeness[w["run"]]


def test_a_quantitys_failure_rate_is_per_quarter_of_its_drawn_values(spec):
    """20 runs whose drawn pixel noise is 0.40, 0.41, ... 0.59, failing exactly when it is above 0.545 (its
    top quarter) and closer to failing the larger it is: the failure rate per quartile bin of the drawn
    values is 0, 0, 0, 1, the bins' edges are the values' quartiles, and the rank correlation with the
    tracking ratio is 1."""
    drawn = [0.40 + 0.01 * i for i in range(20)]
    closeness = [0.5 + 0.05 * i for i in range(20)]
    holds = [i < 15 for i in range(20)]
    out = summarize(spec, records(closeness, holds, drawn), 0.95, 0.01, 0.9)
    (entry,) = out["sensitivity"]
    assert entry["quantity"] == KEY and entry["failure_rate"] == [0.0, 0.0, 0.0, 1.0]
    np.testing.assert_allclose(entry["bin_edges"], np.quantile(drawn, [0, 0.25, 0.5, 0.75, 1]), rtol=1e-12)
    assert entry["spearman"] == pytest.approx(1.0, abs=1e-12)
