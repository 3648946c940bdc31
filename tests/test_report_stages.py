"""The report's kept stages: each is made again exactly when something it reads changes."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest

from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, design_before
from dvfc.reports.stages import IGNORES, StageCache

CELL = Path(__file__).parent.parent / "examples" / "ur5_cell.toml"
BOUND = {"position": 0.05, "angle_deg": 6.0}
"""A stand-in for the criterion's tracking bound, which the campaign before the synthesis takes."""
STAGES = [name for name in IGNORES if name != "dispersions_before"]
"""The stages of a scenario without a design before a synthesis (the default's)."""

ENVELOPE = {"rate": 0.5, "level": 1.0}
"""A stand-in for the certificate's envelope, which later stages take."""


def case_of(data: dict, base: Path) -> SimpleNamespace:
    """What a stage's key reads of a case: its validated scenario, its folder and its ``e_e`` override."""
    return SimpleNamespace(scenario=Scenario.model_validate(data), base=base, mode=None)


def made(directory: Path, case, *, resume: bool = True, envelope: dict = ENVELOPE) -> list[str]:
    """The stages made (not reused) by one report of ``case`` kept in ``directory``, in order."""
    cache, computed = StageCache(directory, "0.1.0", resume), []

    def stage(name: str, uses: tuple = ()) -> None:
        cache(name, case, lambda: computed.append(name) or name, uses)

    for name in ("implemented", "simulation", "from_rest"):
        stage(name)
    stage("certificate", ("rest",))
    stage("verification", (envelope, "run", "rest"))
    stage("margins", (envelope, "run"))
    stage("controller")
    stage("dispersions", (envelope,))
    if (before := design_before(case.scenario)) is not None:  # the report's Case.before()
        cache("dispersions_before", case_of(before.model_dump(), case.base),
              lambda: computed.append("dispersions_before") or "dispersions_before", (BOUND,))  # fmt: skip
    assert {name for name, (_, reused) in cache.timings.items() if not reused} == set(computed)
    return computed


@pytest.fixture
def default() -> dict:
    return tomllib.loads(DEFAULT_SCENARIO.read_text())


def edited(data: dict, path: str, value) -> dict:
    out = copy.deepcopy(data)
    *parents, last = path.split(".")
    node = out
    for name in parents:
        node = node.setdefault(name, {})
    node[last] = value
    return out


def test_every_stage_is_kept_when_nothing_it_reads_changes(tmp_path, default):
    """A second report of the same scenario (with ``--resume``) makes no stage again, nor after an
    edit of a display field (the name) or of the gain map's quantity, which no kept stage reads."""
    assert len(made(tmp_path, case_of(default, tmp_path))) == len(STAGES)
    assert made(tmp_path, case_of(default, tmp_path)) == []
    assert made(tmp_path, case_of(edited(default, "name", "renamed"), tmp_path)) == []
    assert made(tmp_path, case_of(edited(default, "synthesize.k_c", [0.5, 5.0]), tmp_path)) == []


@pytest.mark.parametrize(
    ("path", "value", "remade"),
    [
        ("report.campaign_runs", 7, ["dispersions"]),
        ("dispersion", {"plant.mount.rpy": {"dist": "normal", "sigma": 0.01}}, ["dispersions"]),
        ("certify.gamma", 50.0, ["certificate"]),
        ("certify.theta_max_deg", 90.0, ["certificate", "verification"]),
        ("gains.k_e", 11.0, STAGES),
        ("simulation.duration", 5.0, [name for name in STAGES if name != "from_rest"]),
    ],
)
def test_an_edit_remakes_exactly_the_stages_that_read_it(tmp_path, default, path, value, remade):
    """An edited field remakes the stages that read it and keeps the others (their results
    unchanged: the envelope later stages take is the same)."""
    made(tmp_path, case_of(default, tmp_path))
    assert made(tmp_path, case_of(edited(default, path, value), tmp_path)) == remade


@pytest.mark.parametrize(
    ("path", "value", "remade"),
    [
        ("synthesized_from.gains.k_c", 4.0, ["dispersions_before"]),
        ("synthesized_from.name", "renamed", []),
        ("gains.k_e", 11.0, STAGES),
        ("report.campaign_runs", 7, ["dispersions", "dispersions_before"]),
    ],
)
def test_the_campaign_before_the_synthesis_is_remade_exactly_when_its_design_changes(tmp_path, path, value, remade):
    """The cell's campaign of the design it was synthesised from reads that design (``[synthesized_from]``
    gains) and the campaign's settings, not the synthesised ``[gains]``; the other stages never read the
    table."""
    cell = tomllib.loads(CELL.read_text())
    assert len(made(tmp_path, case_of(cell, tmp_path))) == len(IGNORES)
    assert made(tmp_path, case_of(edited(cell, path, value), tmp_path)) == remade


def test_a_changed_result_remakes_the_stages_that_take_it(tmp_path, default):
    """The verification, the margins and the campaign take the certificate's envelope: another
    envelope remakes them, not the runs or the certificate."""
    made(tmp_path, case_of(default, tmp_path))
    again = made(tmp_path, case_of(default, tmp_path), envelope={**ENVELOPE, "rate": 0.25})
    assert again == ["verification", "margins", "dispersions"]


def test_a_changed_calibration_file_remakes_every_stage(tmp_path, default):
    """The calibration file the scenario names is read by every stage: an edit of its content
    (the scenario file unchanged) remakes them all."""
    (tmp_path / "camera.yaml").write_text("image_width: 1280\n")
    camera = {"calibration": "camera.yaml"}
    made(tmp_path, case_of(edited(default, "camera", camera), tmp_path))
    assert made(tmp_path, case_of(edited(default, "camera", camera), tmp_path)) == []
    (tmp_path / "camera.yaml").write_text("image_width: 640\n")
    assert made(tmp_path, case_of(edited(default, "camera", camera), tmp_path)) == STAGES


def test_without_resume_every_stage_is_made(tmp_path, default):
    made(tmp_path, case_of(default, tmp_path))
    assert made(tmp_path, case_of(default, tmp_path), resume=False) == STAGES
