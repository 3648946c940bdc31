"""One answer to "does fact 14 certify this plant's loop as implemented" (docs/math.md, facts 14 and 25):
``certify`` (:func:`implemented_record`), the margins' plant points (:meth:`LinearCheck.plant_verdict`) and a
campaign's draws (:func:`local_verdict_of`) all read :func:`local_verdict`, with every check of the
monodromy, not its spectral radius alone."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from dvfc.analysis import campaign
from dvfc.analysis.case import Case
from dvfc.analysis.margins import LinearCheck
from dvfc.analysis.multirate import implemented_record
from dvfc.analysis.scenario import Scenario

CELL = Path(__file__).parents[1] / "examples" / "xarm7_cell.toml"


def without_integral(payload: float | None) -> Case:
    """The xArm 7 cell with the paper's law (no integral action), with a payload of ``payload`` kg."""
    data = tomllib.loads(CELL.read_text())
    data["gains"].pop("k_i_factor", None)
    if payload is not None:
        data["plant"]["payload"] = {"mass": payload}
    return Case.load(CELL).with_scenario(Scenario.model_validate(data))


@pytest.fixture(scope="module")
def payload_case() -> Case:
    return without_integral(0.3)


@pytest.mark.slow
def test_a_payload_that_moves_the_self_motion_is_certified_nowhere(payload_case):
    """Without integral action a 0.3 kg payload on the xArm 7 moves the manifold of equilibria: the
    monodromy's spectral radius across the tangent is 0.975, but the computed monodromy does not fix
    that tangent (residual 0.018, against a tolerance of about 5e-5) and the self-motion's poses are not
    equilibria: not certified, by ``certify``'s record, by the campaign's verdict of that draw and by the
    margins' verdict of that payload, each with the same rho and reason."""
    record = implemented_record(payload_case.loop, payload_case.s0, payload_case.settings)
    assert record["applies"] and not record["certified"] and record["rho"] < 1
    assert record["self_motion"]["tangent_residual"] > 1e-3
    drawn = campaign.local_verdict_of(payload_case, campaign.campaign_settings(payload_case))
    assert drawn is not None and not drawn.certified
    assert drawn.rho == pytest.approx(record["rho"], rel=1e-9) and drawn.reason == record["reason"]
    nominal = without_integral(None)
    check = LinearCheck.of(nominal, implemented_record(nominal.loop, nominal.s0, nominal.settings))
    margin = check.plant_verdict("payload_mass", 0.3)
    assert margin is not None and not margin.certified and margin.rho == pytest.approx(record["rho"], rel=1e-9)


@pytest.mark.slow
def test_the_shipped_cell_is_certified_by_each_of_them():
    """The other side: the shipped xArm 7 cell (integral action, no payload) is certified by the record and
    by the campaign's verdict of its own plant, with the same rho."""
    case = Case.load(CELL)
    record = implemented_record(case.loop, case.s0, case.settings)
    drawn = campaign.local_verdict_of(case, campaign.campaign_settings(case))
    assert record["certified"] and drawn is not None and drawn.certified and drawn.reason is None
    assert drawn.rho == pytest.approx(record["rho"], rel=1e-9)
