"""The campaign's statements (analysis/campaign.py, analysis/dispersion.py) against scipy.stats and
brute force: the zero-failure run count, the order-statistic rank of the tolerance bound and the
draws of a truncated or clipped dispersion. Each claims a probability; an optimistic error of one
run, one rank or one side of a truncation makes the statement false."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from dvfc.analysis import campaign
from dvfc.analysis.campaign import (
    CampaignSpec,
    has_dry_friction,
    local_summary,
    tolerance_rank,
    zero_failure_runs,
)
from dvfc.analysis.case import Case
from dvfc.analysis.dispersion import Dispersion
from dvfc.analysis.margins import TrackingBound
from dvfc.analysis.multirate import DeclaredPlant, LocalVerdict
from dvfc.analysis.scenario import Scenario
from dvfc.analysis.schema import DistributionSection

CELL = Path(__file__).resolve().parent.parent / "examples" / "ur5_cell.toml"

LEVELS = [(p, c) for p in (0.5, 0.2, 0.1, 0.05, 0.01, 0.001) for c in (0.5, 0.75, 0.9, 0.95, 0.99)]
"""(p, confidence) pairs, among them exact cases: ``(1 - 0.5)^2 = 1 - 0.75`` and ``0.5^1 = 1 - 0.5``."""


@pytest.mark.parametrize(("p", "confidence"), LEVELS)
def test_zero_failure_run_count_is_the_fewest_runs_whose_clopper_pearson_bound_is_p(p, confidence):
    """``N`` runs without a failure bound ``P(fail) <= p`` at ``confidence`` iff the probability of
    ``N`` successes at ``P(fail) = p`` is at most ``1 - c`` (``binom.pmf(0, N, p)``; equivalently the
    one-sided Clopper-Pearson bound ``beta.ppf(c, 1, N) <= p``), and ``N - 1`` runs do not. Checked
    by scipy.stats, with a relative slack of 1e-12 on the probabilities (their rounding) so that the
    exact cases (``0.5^2 = 0.25``) count as bounded."""
    runs = zero_failure_runs(p, confidence)
    assert stats.binom.pmf(0, runs, p) <= (1 - confidence) * (1 + 1e-12)
    assert stats.beta.ppf(confidence, 1, runs) <= p * (1 + 1e-12)
    assert stats.binom.pmf(0, runs - 1, p) > (1 - confidence) * (1 + 1e-12)


def test_zero_failure_run_count_of_one_percent_at_95_percent_is_299():
    """The textbook case (the rule of three's exact form): 299 runs, ``0.99^299 = 0.0495``."""
    assert zero_failure_runs(0.01, 0.95) == 299


@pytest.mark.parametrize("runs", [1, 5, 22, 29, 45, 59, 100, 300])
@pytest.mark.parametrize(("quantile", "confidence"), [(0.9, 0.9), (0.9, 0.95), (0.95, 0.95), (0.5, 0.99)])
def test_tolerance_rank_is_the_smallest_order_statistic_above_the_quantile_with_confidence(runs, quantile, confidence):
    """The ``r``-th smallest of ``n`` i.i.d. uniforms is ``Beta(r, n - r + 1)`` (the distribution-free
    order statistic), so ``X_(r)`` exceeds the ``q`` quantile of any continuous distribution with
    probability ``beta.sf(q, r, n - r + 1)``: the rank is the smallest ``r`` with that at least
    ``c``, and None when even ``r = n`` falls short (59 runs are the fewest for 95% / 95%, 22 for
    90% / 90%). Tolerance 1e-12 absolute on the probabilities (their rounding)."""
    rank = tolerance_rank(runs, quantile, confidence)
    coverage = lambda r: stats.beta.sf(quantile, r, runs - r + 1)  # noqa: E731
    if rank is None:
        assert coverage(runs) < confidence + 1e-12
        return
    assert coverage(rank) >= confidence - 1e-12
    assert rank == 1 or coverage(rank - 1) < confidence - 1e-12


def test_tolerance_rank_covers_the_quantile_in_a_monte_carlo_of_exponential_runs():
    """A measurement of the statement itself: 20,000 campaigns of 59 exponential draws each (rank 59,
    the largest); its order statistic lies above the true 95% quantile ``ln 20`` in at least 95% of
    them (measured 95.27%, exact ``1 - 0.95^59 = 95.15%``; a 4-sigma binomial allowance of 0.6%),
    and one rank lower it does not (measured 80.1%)."""
    rng = np.random.default_rng(12)
    runs, quantile = 59, 0.95
    rank = tolerance_rank(runs, quantile, 0.95)
    order = np.sort(rng.exponential(size=(20_000, runs)), axis=1)
    true = -np.log(1 - quantile)
    allowance = 4 * np.sqrt(0.95 * 0.05 / 20_000)
    assert np.mean(order[:, rank - 1] >= true) >= 0.95 - allowance
    if rank > 1:
        assert np.mean(order[:, rank - 2] >= true) < 0.95 - allowance


def dispersion(key: str, base: float, **distribution) -> Dispersion:
    """One field's dispersion about ``base``."""
    return Dispersion({key: DistributionSection(**distribution)}, {key: np.array([base])})


def draws(d: Dispersion, key: str, count: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.array([d.draw(rng)[key][0] for _ in range(count)])


def test_a_clipped_normal_latency_is_a_truncated_normal_on_both_sides():
    """``clip = 1.5`` sigmas: every drawn latency lies within ``base +- 1.5 sigma`` and the 4000 draws
    follow scipy's ``truncnorm(-1.5, 1.5)`` (Kolmogorov-Smirnov p-value above 1e-3; a one-sided
    truncation leaves a tail below ``-1.5 sigma``, p-value ~ 0)."""
    base, sigma = 0.1, 0.02
    values = draws(dispersion("implementation.latency", base, dist="normal", sigma=sigma, clip=1.5),
                   "implementation.latency", 4000)  # fmt: skip
    assert np.all(np.abs(values - base) <= 1.5 * sigma * (1 + 1e-12))
    assert stats.kstest((values - base) / sigma, stats.truncnorm(-1.5, 1.5).cdf).pvalue > 1e-3


def test_a_latency_drawn_negative_is_clipped_to_zero_and_no_further():
    """A latency cannot be negative (the image cannot arrive before it is captured): a normal of
    ``sigma = base`` draws ``P(N < -1) = 15.9%`` below zero, and exactly those are set to 0 (the
    fraction at 0 within 4 binomial sigmas of ``norm.cdf(-1)``); the rest are untouched, and follow
    the normal restricted to ``(0, inf)`` (Kolmogorov-Smirnov p-value above 1e-3)."""
    base = 0.02
    values = draws(dispersion("implementation.latency", base, dist="normal", sigma=base), "implementation.latency",
                   4000)  # fmt: skip
    assert values.min() == 0.0
    zero = np.mean(values == 0.0)
    expected = stats.norm.cdf(-1.0)
    assert abs(zero - expected) <= 4 * np.sqrt(expected * (1 - expected) / len(values))
    positive = (values[values > 0] - base) / base
    assert stats.kstest(positive, stats.truncnorm(-1.0, np.inf).cdf).pvalue > 1e-3


def test_a_probability_drawn_beyond_one_is_clipped_to_one():
    """A frame-drop probability drawn uniform in ``base + [-0.5, 0.5]`` about 0.8 lies in ``[0, 1]``
    and is exactly 1 for the draws above 1 (30% of them, within 4 binomial sigmas)."""
    values = draws(dispersion("implementation.frame_drop", 0.8, dist="uniform", low=-0.5, high=0.5),
                   "implementation.frame_drop", 4000)  # fmt: skip
    assert values.min() >= 0.3 - 1e-12 and values.max() == 1.0
    assert abs(np.mean(values == 1.0) - 0.3) <= 4 * np.sqrt(0.3 * 0.7 / len(values))


def test_the_local_summary_counts_the_draws_fact_14_certifies_and_names_the_unstable_ones():
    """Of the runs whose plant fact 14 checked (``local_certified`` not None), those it certifies count;
    the largest rho is reported and the runs it does not certify named (failures whatever their runs show),
    a run with ``rho < 1`` whose other checks fail among them."""
    data = {"run": [0, 1, 2, 3, 4], "local_rho": [0.9, None, 1.0002, 0.95, 0.975],
            "local_certified": [True, None, False, True, False]}  # fmt: skip
    local = local_summary(data)
    assert local["computed"] == 4 and local["certified"] == 2 and local["unstable_runs"] == [2, 4]
    assert local["largest_rho"] == 1.0002 and "2 of 5 draws locally certified" in local["statement"]
    assert "eps" not in local["statement"]


def test_a_local_verdict_on_dry_friction_names_its_bounded_torque_and_no_smoothing():
    """The plants' dry friction enters fact 14 as a torque bounded by its Coulomb level (fact 29), not as the
    smoothed model's slope: the campaign's local statement for the ``ur5_cell`` draws (Coulomb friction declared
    and drawn) says so and names no smoothing width, as do the words of a declared plant with friction; a
    campaign without dry friction says nothing of it."""
    bound = TrackingBound(1.0, 180.0, "envelope", "")
    data = tomllib.loads(CELL.read_text())
    case = Case.load(CELL)
    runs = {"run": [0], "local_rho": [0.9], "local_certified": [True]}
    statement = local_summary(runs, has_dry_friction(CampaignSpec.of(case, bound)))["statement"]
    assert "a torque bounded by its Coulomb level (fact 29, no smoothing)" in statement and "eps" not in statement
    words = DeclaredPlant(None, case.settings.errors).words(case.loop.camera)
    assert "dry joint friction up to c (a bounded torque, fact 29)" in words and "eps" not in words
    data["plant"]["friction"]["coulomb"] = [0.0] * 6
    del data["dispersion"]["plant.friction.coulomb"]
    without = case.with_scenario(Scenario.model_validate(data))
    assert not has_dry_friction(CampaignSpec.of(without, bound))
    assert "Coulomb" not in local_summary(runs, has_dry_friction(CampaignSpec.of(without, bound)))["statement"]


@pytest.mark.slow
def test_a_draw_whose_plant_is_locally_unstable_fails_whatever_its_run(monkeypatch):
    """A campaign run that holds on its horizon but whose drawn plant fact 25 does not certify (rho >= 1, or
    another check of its monodromy fails, or its dry friction can hold the error beyond the criterion) is a
    failure, the reason saying the horizon was too short to show it; the same run with rho < 1 holds and records
    its rho. (Run 0 of ``examples/ur5_cell.toml`` over 2 s, its verdict stood in for; draw 67's plant, joint 3's
    Coulomb friction 8.07 N m, has rho 0.905765 with its viscous friction, and is certified against a loose
    criterion.)"""
    data = tomllib.loads(CELL.read_text())
    data["simulation"]["duration"] = 2.0
    case = Case.load(CELL).with_scenario(Scenario.model_validate(data))
    spec = CampaignSpec.of(case, TrackingBound(1.0, 180.0, "scenario", ""), 0)
    drawn, _ = spec.run_settings(67)  # joint 3's Coulomb friction drawn at 8.07 N m: it hunts at rest
    verdict = campaign.local_verdict_of(case, drawn, spec.bound.limits)
    assert verdict.rho == pytest.approx(0.905765, abs=1e-5) and verdict.certified and drawn.errors is not None
    values = spec.values(0)
    settings, s0 = spec.run_settings(0, values)
    traj = campaign.shared_simulator(spec.case).for_run(settings).run(s0)
    for rho, certified in ((0.9, True), (1.01, False), (0.95, False)):
        stand_in = LocalVerdict(rho, certified, None if certified else f"rho = {rho}, a check fails")
        monkeypatch.setattr(campaign, "local_verdict_of", lambda case, settings, criterion, v=stand_in: v)
        out = campaign.row(spec, 0, traj, settings, values)
        assert out["holds"] is certified and out["local_rho"] == rho and out["local_certified"] is certified
        if not certified:
            assert f"rho = {rho}, a check fails" in out["reason"], out["reason"]
            assert "the horizon is too short to show it" in out["reason"]
