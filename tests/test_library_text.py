"""No library's own words reach the user: a search stopped by CVODES is said plainly, with
nothing on the standard streams; an H-infinity norm on marginal poles is infinite, with no
python-control warning."""

from __future__ import annotations

import math
import warnings

import pytest

from dvfc.analysis.case import Case
from dvfc.analysis.linearize import linearize
from dvfc.analysis.results import envelope_record
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.verify import SEARCH_STOPPED, adversarial_claim

from helpers import five_joints, scenario_dict


@pytest.mark.slow
def test_a_search_stopped_by_the_integrator_is_said_plainly_and_silently(capfd):
    """A torque bound of 10 kN m drives the UR5 out of every region within the first piece:
    CVODES fails there; the reason is ours and nothing reaches stdout or stderr."""
    case = Case(Scenario.model_validate(scenario_dict()), DEFAULT_SCENARIO.parent)
    env = envelope_record(case, search=False)
    env["disturbance"]["torque"] = 1e4
    capfd.readouterr()
    claim = adversarial_claim(case.loop, case.s0, env)
    captured = capfd.readouterr()
    assert claim.status == "INCONCLUSIVE" and claim.detail == f"the search could not run: {SEARCH_STOPPED}"
    assert captured.out == "" and captured.err == ""


def test_marginal_poles_give_an_infinite_norm_without_a_library_warning():
    """The 5-joint arm's loop has modes on the imaginary axis (the direction J_b cannot move)."""
    case = Case(Scenario.model_validate(scenario_dict(five_joints)), DEFAULT_SCENARIO.parent)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lin = linearize(case.loop, case.s0[:5])
    assert math.isinf(lin.hinf)
