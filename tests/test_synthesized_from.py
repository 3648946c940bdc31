"""``[synthesized_from]``: the design a synthesised scenario started from, written by ``synthesize
--for-campaign``, validated like ``[gains]`` and loaded as a case of its own (the report's campaign
before the synthesis)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dvfc.analysis import cell
from dvfc.analysis.case import Case
from dvfc.analysis.margins import tracking_bound
from dvfc.analysis.scenario import Scenario, design_before
from dvfc.reports.cli import app

CELL = Path(__file__).parent.parent / "examples" / "ur5_cell.toml"
BEFORE = "k_xi = [20.0, 20.0, 20.0, 5.0, 5.0, 1.5]\nk_c = 3.0\nk_e = 10.0\nk_i_factor = 10.0"
"""The shipped cell's ``[synthesized_from.gains]`` as written in the file."""


@pytest.fixture(scope="module")
def shipped() -> Case:
    return Case.load(CELL)


def test_the_shipped_cell_names_the_design_of_its_comments(shipped):
    """``examples/ur5_cell.toml`` was synthesised from ``ur5_circle.toml``'s gains with ``k_i_factor =
    10`` (its comments): the table says so, and the design before is that scenario's design."""
    assert BEFORE in CELL.read_text()
    before = shipped.before()
    assert before.point.k_xi.tolist() == [20.0, 20.0, 20.0, 5.0, 5.0, 1.5]
    assert before.point.k_c.tolist() == [3.0] * 6 and before.point.k_e.tolist() == [10.0] * 6
    assert np.array_equal(before.point.k_i, 10.0 * before.point.k_xi)


def test_the_design_before_changes_the_gains_alone(shipped):
    """:func:`design_before` is the same scenario with the table's ``[gains]`` and no table."""
    scenario = shipped.scenario
    before = design_before(scenario)
    assert before.gains == scenario.synthesized_from.gains and before.synthesized_from is None
    ignored = {"gains", "synthesized_from"}
    assert {k: v for k, v in before.model_dump().items() if k not in ignored} == {
        k: v for k, v in scenario.model_dump().items() if k not in ignored
    }
    assert design_before(before) is None


def test_the_written_design_records_the_design_it_started_from(shipped):
    """``synthesize --for-campaign`` writes the input scenario's name and ``[gains]`` into the output's
    ``[synthesized_from]``: loaded again, the design before is the input's, the ``[gains]`` the new one."""
    design = cell.Design(np.array([30.0, 30, 30, 6, 6, 2]), np.full(6, 3.5), np.full(6, 12.0), 15.0)
    text = cell.design_text(CELL.read_text(), shipped, design, tracking_bound(shipped), name="cell-x",
                            source=CELL, target=CELL)  # fmt: skip
    written = Scenario.model_validate(tomllib.loads(text))
    assert written.gains.k_xi == design.k_xi.tolist() and written.gains.k_i_factor == 15.0
    assert written.synthesized_from.name == shipped.name
    assert written.synthesized_from.gains == shipped.scenario.gains


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("k_c = 3.0\n", "k_c = -3.0\n"), "error: synthesized_from.gains.k_c: must be > 0, got -3.0"),
        (("[20.0, 20.0, 20.0, 5.0, 5.0, 1.5]", "[20.0, 20.0, 5.0, 5.0, 1.5]"),
         "error: synthesized_from.gains.k_xi: expected 6 entries, got 5"),
        (("k_i_factor = 10.0", "k_i_fact = 10.0"),
         "error: synthesized_from.gains.k_i_fact: unknown key 'k_i_fact' (did you mean 'k_i_factor'?)"),
    ],
)
def test_a_bad_design_before_is_one_line_naming_the_field_exit_2(tmp_path, edit, message):
    """A bad value in ``[synthesized_from]`` is refused when the scenario is loaded, before any work:
    one line naming the field, status 2, no report written."""
    old, new = edit
    text = CELL.read_text()
    assert BEFORE in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(BEFORE, BEFORE.replace(old, new)))
    result = CliRunner().invoke(app, ["report", str(bad), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [message]
    assert not (tmp_path / "out" / "report.html").exists()
