"""What the report's scenario table says of the camera and the plant, and its number formats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dvfc.analysis.export import CLOSED_LOOP_TOLERANCE, NO_COMPILER, TORQUE_TOLERANCE, Check
from dvfc.analysis.results import program_statement, verdict
from dvfc.models.camera import Camera
from dvfc.reports.document import _number, _vector, camera_facts, plant_text

POINTS = np.array([[0.05, 0.05, 0], [-0.05, 0.05, 0], [-0.05, -0.05, 0], [0.05, -0.05, 0]])


def test_a_string_or_none_is_shown_not_formatted_as_a_number():
    """A field that may be a string (``q0 = "auto"``) or absent never breaks the page: it reads
    as itself, or ``-``; numbers keep their significant figures."""
    assert _vector("auto") == "auto" and _number("auto") == "auto"
    assert _vector(None) == "-" and _number(None) == "-" and _number(float("nan")) == "-"
    assert _vector([0.15, -1.4512345, 2]) == "[0.15, -1.451, 2]" and _number(np.float64(812.5)) == "812.5"


def test_camera_facts_give_both_focal_lengths_the_principal_point_and_the_distortion():
    """``fy = aspect fx``; the principal point given, or the image centre; zero distortion is none."""
    calibrated = Camera(805.0, POINTS, 1280, 1024, (642.5, 510.25), 801.0 / 805.0, (-0.05, 0.01, 0.0005, -0.0003, 0))
    facts = camera_facts(calibrated, "camera.yaml")
    assert facts["fx"] == 805.0 and abs(facts["fy"] - 801.0) < 1e-12
    assert facts["principal_point"] == [642.5, 510.25] and facts["size"] == (1280, 1024)
    assert facts["distortion"] == [-0.05, 0.01, 0.0005, -0.0003, 0.0] and facts["calibration"] == "camera.yaml"
    plain = camera_facts(Camera(800.0, POINTS, 1280, 1024), None)
    assert plain["principal_point"] == [640.0, 512.0] and plain["distortion"] is None and plain["fy"] == 800.0
    unsized = camera_facts(Camera(800.0, POINTS), None)
    assert unsized["principal_point"] is None and unsized["size"] is None


def test_plant_text_names_each_error_with_its_values():
    """Friction, a payload, a mass scale, a mount error, true intrinsics and point errors each
    read as one entry with their values; a plant without errors reads as nothing."""
    record = {
        "friction": {"viscous": [0.3, 0.2], "coulomb": [0.1, 0.1], "smoothing": 0.05},
        "payload": {"mass": 0.5, "com": [0, 0, 0.05], "inertia": [0] * 6},
        "mass_scale": 1.1,
        "mount": {"xyz": [0.001, 0, 0], "rpy": [0, 0.01, 0]},
        "intrinsics": {"fx": 830.0, "fy": 830.0, "principal_point": [650, 500], "distortion": [-0.1, 0, 0, 0, 0]},
        "point_errors": [[0.0003, 0.0004, 0], [0, 0, 0]],
    }
    parts = plant_text(record)
    assert parts[0] == ("joint friction b qd + c tanh(qd / 0.05 rad/s): viscous b = [0.3, 0.2] N m s/rad, "
                        "Coulomb c = [0.1, 0.1] N m")  # fmt: skip
    assert parts[1:] == [
        "a payload of 0.5 kg on the camera link (centre of mass [0, 0, 0.05] m)",
        "masses and inertias 1.1x the URDF's",
        "a camera mount error xyz [0.001, 0, 0] m, rpy [0, 0.01, 0] rad",
        "true intrinsics fx = 830 px, fy = 830 px, principal point [650, 500] px, distortion [-0.1, 0, 0, 0, 0]",
        "feature point errors up to 0.0005 m",
    ]
    assert plant_text(dict.fromkeys(record)) == []


def test_the_verdict_names_every_statement_not_certified_or_not_applying():
    """A certified design whose claims all pass, with two statements of the review not certified
    and one not applying: the verdict passes (the design's exit 0), and its headline counts the
    three and lists them; the certified and measured statements are not listed."""
    from dvfc.analysis.results import Statement, StatementStatus

    certificate = {"points": [{"certified": True}]}
    verification = {"claims": [{"status": "PASS"}], "summary": {"claims": 1}}
    statuses = {"L2 gain": "CERTIFIED", "every feature": "NOT CERTIFIED", "own speed": "NOT CERTIFIED",
                "fact 14": "DOES NOT APPLY", "margins": "MEASURED"}  # fmt: skip
    review = [Statement(statement=name, loop="-", status=StatementStatus(status), detail="-")
              for name, status in statuses.items()]  # fmt: skip
    outcome = verdict(certificate, verification, review)
    assert outcome.passed
    assert [s.statement for s in outcome.not_certified] == ["every feature", "own speed", "fact 14"]
    assert "3 statement(s) not certified" in outcome.headline
    assert verdict(certificate, verification).headline == "L2 gain CERTIFIED, and every check passes"


CHECK = {"samples": 5000, "max_abs_torque_difference": 0.0, "max_rel_torque_difference": 0.0,
         "closed_loop_max_state_difference": 0.0, "passed": True}
"""A replay of the exported step identical to the Python step's (``dvfc export --check``'s record)."""


@pytest.mark.parametrize(("record", "status"), [
    ({"check": CHECK}, "PASS"),
    ({"check": CHECK | {"max_rel_torque_difference": 1e-9, "passed": False}}, "FAIL"),
    ({"reason": NO_COMPILER}, "INCONCLUSIVE"),
    ({"reason": "loop: the reduced planar loop cannot be exported; export the paper's loop"}, "DOES NOT APPLY"),
])  # fmt: skip
def test_the_programs_statement_is_the_replays_outcome(record, status):
    """Page 1's statement on the program that runs: PASS exactly when the replay of the compiled step
    stayed within its tolerances, FAIL otherwise, INCONCLUSIVE without a C compiler, DOES NOT APPLY
    when the loop has no program; a failed replay fails the verdict (the report's exit status)."""
    record = record | {"sha256": "0" * 64, "tolerances": {"torque_relative": 1e-12, "closed_loop": 1e-9}}
    row = program_statement(record)
    assert row.statement.startswith("the exported program") and row.status == status
    certificate = {"points": [{"certified": True}]}
    verification = {"claims": [{"status": "PASS"}], "summary": {"claims": 1}}
    assert verdict(certificate, verification, [row]).passed == (status != "FAIL")


@pytest.mark.parametrize(("torque", "closed_loop", "status"), [
    (0.0, 0.0, "PASS"),
    (1e-9, 0.0, "FAIL"),
    (0.0, 2e-9, "FAIL"),
    (0.0, float("inf"), "FAIL"),
], ids=["both agree", "a torque off 1e-9", "the closed loop off 2e-9", "the closed loop stopped early"])  # fmt: skip
def test_the_programs_statement_needs_both_the_replay_and_the_closed_loop(torque, closed_loop, status):
    """Page 1's "the exported program is the simulated controller" stands on both halves of ``dvfc export
    --check`` (:class:`~dvfc.analysis.export.Check`): every torque of the replay within 1e-12 of the
    Python step's, relative, AND the loop the compiled step closes within 1e-9 of the Python step's.
    The replay alone agreeing is not enough: a closed loop off by 2e-9, or stopped early, FAILS the
    statement and the verdict."""
    check = Check(Path("sil_inputs.csv"), 5000, torque * 30.0, torque, closed_loop)
    record = {"sha256": "0" * 64, "check": check.as_dict(),
              "tolerances": {"torque_relative": TORQUE_TOLERANCE, "closed_loop": CLOSED_LOOP_TOLERANCE}}  # fmt: skip
    row = program_statement(record)
    assert row.status == status, row.detail
    certificate = {"points": [{"certified": True}]}
    verification = {"claims": [{"status": "PASS"}], "summary": {"claims": 1}}
    outcome = verdict(certificate, verification, [row])
    assert outcome.passed is (status == "PASS")
    assert ("every check passes" in outcome.headline) is (status == "PASS")
