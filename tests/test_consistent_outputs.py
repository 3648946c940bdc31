"""The report's figures and verify's claims never contradict themselves: certified feature
regions beyond the image are drawn clipped, with a note saying so; fact 8 on boxes that are not
certified visible, or on a run with no step inside the certified level, is vacuous, never PASS."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dvfc.analysis.scenario import Scenario, load
from dvfc.analysis.simulate import Trajectory
from dvfc.analysis.verify import ClaimStatus, feature_region_claim
from dvfc.reports.figures import envelope_image

CENTRE = np.array([640.0, 512.0])
SIZE = (1280.0, 1024.0)
SQUARE = np.array([[50.0, 50.0], [-50.0, 50.0], [-50.0, -50.0], [50.0, -50.0]])  # about the principal point


def still_run(v: float) -> Trajectory:
    """Ten steps with the four features still at ``SQUARE`` and the storage at ``v``."""
    t = np.linspace(0.0, 1.0, 10)
    return Trajectory(t, {"f": np.tile(SQUARE.ravel(), (10, 1)), "V": np.full((10, 1), v)}, {})


def envelope(boxes: list[list[float]], visible: bool, margin: float) -> dict:
    return {"boxes_px": boxes, "ultimate_boxes_px": None, "level": 1.0, "visible": visible,
            "image_margin_px": margin}  # fmt: skip


HUGE = [[-2000.0, -2000.0, 3300.0, 3000.0]] * 4  # every box holds the whole image
TIGHT = [[c[0] - 20, c[1] - 20, c[0] + 20, c[1] + 20] for c in SQUARE + CENTRE]


def test_fact_8_is_vacuous_on_boxes_not_certified_visible():
    claim = feature_region_claim(still_run(0.5), CENTRE, envelope(HUGE, False, -2000.0))
    assert claim.status is ClaimStatus.MEASURED and claim.detail.startswith("vacuous: ")
    assert "-2000 px" in claim.detail


def test_fact_8_is_vacuous_when_no_step_is_within_the_level():
    claim = feature_region_claim(still_run(2.0), CENTRE, envelope(TIGHT, True, 100.0))
    assert claim.status is ClaimStatus.MEASURED and claim.detail.startswith("vacuous: 0 of 10 steps")


def test_fact_8_passes_on_visible_boxes_it_checks():
    claim = feature_region_claim(still_run(0.5), CENTRE, envelope(TIGHT, True, 100.0))
    assert claim.status is ClaimStatus.PASS and claim.value == -20.0


def test_regions_beyond_the_image_are_drawn_clipped_and_said_so():
    svg = envelope_image(still_run(0.5), CENTRE, SIZE, envelope(HUGE, False, -2000.0))
    assert "certified region (V &lt;= c)" in svg or "certified region (V <= c)" in svg
    assert "drawn clipped to it" in svg and "image margin -2000 px: visibility not certified" in svg


def test_regions_wholly_outside_the_view_are_said_so():
    outside = [[5000.0, 5000.0, 5100.0, 5100.0]] * 4
    svg = envelope_image(still_run(0.5), CENTRE, SIZE, envelope(outside, False, -3820.0))
    assert "4 of 4 certified regions lie wholly outside the view" in svg


def test_regions_inside_the_image_carry_no_note():
    svg = envelope_image(still_run(0.5), CENTRE, SIZE, envelope(TIGHT, True, 100.0))
    assert "outside the view" not in svg and "clipped" not in svg


def test_a_target_placed_relative_to_the_camera_survives_its_own_dump():
    """The validated scenario a worker or ``with_gains`` rebuilds from (its JSON dump, with the
    defaults written out) is accepted again when the target is placed ``relative_to_camera``."""
    scenario, _ = load(Path(__file__).parents[1] / "examples" / "xarm7_circle.toml")
    again = Scenario.model_validate_json(scenario.model_dump_json())
    assert again.target.relative_to_camera == scenario.target.relative_to_camera
    assert Scenario.model_validate(scenario.model_dump()).target.xyz is None
