"""The generalized plant's weights (docs/math.md, fact 17): Theorem 2 for the gain from
``d`` to ``z = S x`` with ``w = D_w d``, ``P = N^T K N - G D_w^2 G^T/(2 gamma^2) - S^2/2``.

The certificate itself is checked against the independent reference in ``test_reference.py``
(``test_weighted_*``) and the grid in ``test_grid.py``; here: the paper's plant is the default and
unchanged, the weighted certificate holds on runs of the loop by CVODES, the weights reach the
lower bounds, the gain windows and the JSON, and bad weights are refused in one line."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis.case import Case
from dvfc.analysis.certify import certify, tight_gamma
from dvfc.analysis.cli import app
from dvfc.analysis.linearize import from_rest, linearize
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.verify import theorem_2
from dvfc.analysis.windows import gain_windows

from helpers import scenario_dict

WEIGHTS = {"output": {"xi": 0.5, "e_c": 2.0, "e_e": 1.0}, "disturbance": {"tau_d": 0.5, "translation": 2.0}}
"""A light joint-velocity output and torque channel, a heavy control error and target translation."""


def case_with(performance: dict | None = None) -> Case:
    def edit(data: dict) -> None:
        if performance is not None:
            data["performance"] = performance

    return Case(Scenario.model_validate(scenario_dict(edit)), DEFAULT_SCENARIO.parent)


@pytest.fixture(scope="module")
def weighted() -> dict:
    case = case_with(WEIGHTS)
    return {"case": case, "cert": certify(case.point, case.reference), "lin": linearize(case.loop, case.s0[:6])}


def test_unit_weights_are_the_paper_and_leave_every_certificate_unchanged():
    """Writing every weight 1 is the paper's plant: the same point, the same gamma bit for bit, and
    the same fact-4 gamma."""
    paper, ones = case_with(), case_with({"output": {"xi": 1.0}, "disturbance": {"rotation": 1.0}})
    assert ones.point.plant is None and ones.loop.performance is None
    a, b = certify(paper.point, paper.reference), certify(ones.point, ones.reference)
    assert a.gamma == b.gamma and a.margin == b.margin
    assert tight_gamma(paper.point, paper.reference).gamma == tight_gamma(ones.point, ones.reference).gamma


def test_weights_change_the_certified_gamma(weighted):
    """The weights enter the certificate: another gamma than the paper's for the same gains."""
    paper = case_with()
    assert weighted["cert"].certified
    assert not math.isclose(weighted["cert"].gamma, certify(paper.point, paper.reference).gamma, rel_tol=1e-3)


def test_weighted_linearisation_is_below_the_weighted_gamma(weighted):
    """The linearisation's H-infinity norm from ``d`` to ``z`` is a lower bound on the weighted gain:
    at most the certified gamma, and not the unweighted norm (the weights reach the lower bound)."""
    paper = case_with()
    lin = weighted["lin"]
    assert lin.peak_gain <= weighted["cert"].gamma
    assert not math.isclose(lin.peak_gain, linearize(paper.loop, paper.s0[:6]).peak_gain, rel_tol=1e-3)


@pytest.mark.slow
def test_weighted_theorem_2_holds_from_rest_and_bites(weighted):
    """verify's Theorem 2 claims on CVODES runs with the weights: (43), (44) pointwise, (45) and the
    measured weighted gain pass at the certified gamma, the run attains 95% of the weighted lower
    bound, and at 0.95 of that bound the measured gain fails (the check is sharp)."""
    case, gamma = weighted["case"], weighted["cert"].gamma
    short = replace(case.settings, duration=2.0, jit=False)
    rest = from_rest(case.loop, case.s0[:6])  # the run from rest both checks read
    claims = theorem_2(case.loop, case.s0, short, gamma, rest)
    assert all(c.passed for c in claims), [c.to_json() for c in claims if not c.passed]
    assert any("|z|^2" in c.name for c in claims)
    below = theorem_2(case.loop, case.s0, short, 0.95 * weighted["lin"].peak_gain, rest)
    gain = next(c for c in below if c.name.startswith("measured gain"))
    assert gain.passed is False


def test_light_xi_weight_opens_the_gain_window():
    """Fact 17 on the xi block: a wrist gain of 0.3 is below the paper's window (1/2 + 1/(2 gamma^2))
    and inside it with ``S_xi = D_tau = 0.5`` (0.125 + 0.125/gamma^2)."""
    mass, k_xi = np.eye(6), np.full(6, 0.3)
    case = case_with(WEIGHTS)
    paper = gain_windows(mass, k_xi, None, 2.0)
    light = gain_windows(mass, k_xi, None, 2.0, case.point.plant)
    assert paper.below.all() and not light.below.any()
    assert light.lower == pytest.approx(np.full(6, 0.125 + 0.25 / 8))


@pytest.mark.slow
def test_certify_json_states_the_weights_of_the_plant(tmp_path):
    """``points[0].weights_of_plant``: the weights the certificate holds for, per channel."""
    path = tmp_path / "weighted.toml"
    path.write_text(tomli_w.dumps(scenario_dict(lambda d: d.update(performance=WEIGHTS))))
    result = CliRunner().invoke(app, ["certify", str(path), "--out", str(tmp_path / "out"), "--json", "-"])
    assert result.exit_code == 0, result.stdout
    plant = json.loads(result.stdout)["points"][0]["weights_of_plant"]
    assert plant["output"]["xi"] == [0.5] * 6 and plant["output"]["e_c"] == 2.0
    assert plant["disturbance"]["translation"] == 2.0 and plant["disturbance"]["rotation"] == 1.0
    assert plant["paper"] is False


@pytest.mark.parametrize(
    ("performance", "field"),
    [({"output": {"xi": -1.0}}, "performance.output.xi"), ({"disturbance": {"tau_d": [1.0, 2.0]}},
                                                            "performance.disturbance.tau_d"),
     ({"output": {"z": 1.0}}, "performance.output")],
)
def test_bad_weights_are_refused_in_one_line(tmp_path, performance, field):
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(scenario_dict(lambda d: d.update(performance=performance))))
    result = CliRunner().invoke(app, ["certify", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and field in result.output and len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
