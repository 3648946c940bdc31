"""A campaign's drawn latency is run as the nearest whole number of control periods: images are used
at control samples, so a drawn latency between two samples is taken to the nearer of them (never
always the earlier one, which would make every run's latency shorter than drawn by up to a period)."""

from __future__ import annotations

import copy
import math
import tomllib

import numpy as np
import pytest

from dvfc.analysis.campaign import CampaignSpec
from dvfc.analysis.case import Case
from dvfc.analysis.margins import TrackingBound
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario

BASE = tomllib.loads(DEFAULT_SCENARIO.read_text())
BOUND = TrackingBound(1.0, 180.0, "scenario", "")

RATES = (500.0, 1000.0, 300.0)
"""Control rates (Hz): the default example's, one whose period is a power-of-ten fraction of a second, and
one whose period (1/300 s) is not a binary fraction, so that ``k / rate * rate`` falls just below ``k`` for
some whole ``k`` (55, 79, 97, ...): a latency that is already whole must not lose a period there."""


def latency_campaign(control_rate: float) -> CampaignSpec:
    """The default example at ``control_rate`` (its 20 ms latency a whole number of periods at each of
    :data:`RATES`) with its latency dispersed: the campaign every test here draws from."""
    data = copy.deepcopy(BASE)
    data["implementation"]["control_rate"] = control_rate
    data["implementation"]["camera_rate"] = 60.0
    data["dispersion"] = {"implementation.latency": {"dist": "uniform", "low": -0.02, "high": 0.02}}
    case = Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent)
    return CampaignSpec.of(case, BOUND)


@pytest.fixture(scope="module", params=RATES, ids=lambda rate: f"{rate:g}Hz")
def spec(request) -> CampaignSpec:
    return latency_campaign(request.param)


def run_latency(spec: CampaignSpec, drawn: float) -> tuple[float, int]:
    """The latency (s) and latency in control periods a campaign run uses when ``drawn`` s is drawn."""
    settings, _ = spec.run_settings(0, {"implementation.latency": np.array([drawn])})
    imp = settings.implementation
    assert imp is not None
    return imp.latency, imp.latency_steps


@pytest.mark.parametrize(
    ("periods", "nearest"),
    [(0.0, 0), (0.2, 0), (0.49, 0), (0.51, 1), (0.99, 1), (1.0, 1), (1.01, 1), (1.49, 1), (1.51, 2), (2.0, 2),
     (2.49, 2), (2.51, 3), (9.6, 10), (10.4, 10)],
)  # fmt: skip
def test_a_drawn_latency_rounds_to_the_nearest_control_period(spec, periods, nearest):
    """A latency drawn ``periods`` control periods long is run as ``nearest`` whole periods: a draw just
    above half a period past a sample (0.51, 1.51, 2.51) goes up to the next, one just below (0.49, 1.49,
    2.49) down to the previous; whole numbers stay. The run's latency in seconds is that whole number of
    periods to round-off (1e-12 relative), and the simulator's own count of periods is the same number."""
    rate = spec.case.settings.sampled.control_rate
    latency, steps = run_latency(spec, periods / rate)
    assert steps == nearest
    assert latency == pytest.approx(nearest / rate, rel=1e-12, abs=1e-15)


def test_a_drawn_latency_that_is_a_whole_number_of_periods_is_kept(spec):
    """Every whole number of periods from 0 to 200 is run as drawn, not one period less: the drawn seconds
    ``k / rate`` times the rate may fall a unit of round-off below ``k`` (at 300 Hz for 55, 79, 97, ...),
    and that must not cost a period."""
    rate = spec.case.settings.sampled.control_rate
    for k in range(201):
        latency, steps = run_latency(spec, k / rate)
        assert steps == k and latency == pytest.approx(k / rate, rel=1e-12, abs=1e-15), k


def test_a_drawn_latency_in_seconds_goes_to_the_nearer_sample(spec):
    """In seconds at the scenario's control rate: a draw 1 microsecond short of half a period past the
    20 ms latency stays at 20 ms, one 1 microsecond beyond it goes to 20 ms plus one period; a draw 1
    microsecond either side of 20 ms is 20 ms. (1 microsecond is at least 0.1% of each rate's period.)"""
    rate = spec.case.settings.sampled.control_rate
    period = 1 / rate
    for drawn, expected in [(0.02 + period / 2 - 1e-6, 0.02), (0.02 + period / 2 + 1e-6, 0.02 + period),
                            (0.02 - period / 2 + 1e-6, 0.02), (0.02 - period / 2 - 1e-6, 0.02 - period),
                            (0.02 - 1e-6, 0.02), (0.02 + 1e-6, 0.02)]:  # fmt: skip
        latency, steps = run_latency(spec, drawn)
        assert steps == round(expected * rate) and latency == pytest.approx(expected, rel=1e-12), drawn


def test_every_drawn_latency_is_run_within_half_a_period_of_the_draw(spec):
    """The campaign's own draws (uniform within 20 ms of the 20 ms latency, 300 runs): each run's latency is
    a whole number of periods (1e-9 of a period) no more than half a period from its draw (plus 1e-9 of a
    period for round-off), and the draws are spread over many periods, so that every fraction of a period
    is met (the fractions of the draws above one half are about half of them: rounding goes up for those)."""
    rate = spec.case.settings.sampled.control_rate
    fractions = []
    for run in range(300):
        values = spec.values(run)
        drawn = float(values["implementation.latency"][0])
        settings, _ = spec.run_settings(run, values)
        assert settings.implementation is not None
        periods = settings.implementation.latency * rate
        assert abs(periods - round(periods)) <= 1e-9
        assert abs(periods - drawn * rate) <= 0.5 + 1e-9, (run, drawn)
        assert settings.implementation.latency_steps == round(periods)
        fractions.append(drawn * rate - math.floor(drawn * rate))
    above = np.mean(np.asarray(fractions) > 0.5)
    assert 0.35 < above < 0.65
