"""``dvfc pose --solve``: q0 solved as ``[robot] q0 = "auto"`` would, printed as a line to
paste with its conditioning, pose error and position limits; pasted, it puts the camera at
the reference pose relative to the target."""

from __future__ import annotations

import json
import re
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from dvfc.analysis.cli import app
from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.models.lie import SE3
from dvfc.models.robot import Robot

from helpers import JACO2_CAMERA, Q_STAR, camera_at, limited_jaco2, write

runner = CliRunner()
PANDA = Path(__file__).parents[1] / "examples" / "panda_circle.toml"


def pasted(source: Path, line: str, folder: Path) -> Path:
    """``source`` with its ``q0 = ...`` line replaced by ``line``, written to ``folder``."""
    text, count = re.subn(r"^q0 = .*$", line, source.read_text(), count=1, flags=re.M)
    assert count == 1
    path = folder / source.name
    path.write_text(text)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("source", [DEFAULT_SCENARIO, PANDA], ids=["default", "panda"])
def test_pose_solve_prints_a_configuration_to_paste(source, tmp_path):
    result = runner.invoke(app, ["pose", str(source), "--solve", "--json", "-"])
    assert result.exit_code == 0, result.stderr
    solution = json.loads(result.stdout)["solution"]
    assert solution["within_position_limits"] and all(solution["joints_within_limits"])
    assert solution["position_error_m"] < 1e-9 and solution["rotation_error_rad"] < 1e-9
    assert solution["sigma_min_body_jacobian"] > 0 and solution["condition_number"] >= 1
    human = runner.invoke(app, ["pose", str(source), "--solve"], env={"COLUMNS": "200"})
    assert human.exit_code == 0 and solution["q0_toml"] in human.stdout
    assert "sigma_min(J_b)" in human.stdout and "within its position limits" in human.stdout
    again = runner.invoke(app, ["pose", str(pasted(source, solution["q0_toml"], tmp_path)), "--json", "-"])
    assert again.exit_code == 0, again.stderr
    relative = json.loads(again.stdout)["target_in_camera"]
    assert np.allclose(relative["xyz"], [0.0, 0.0, 0.35], atol=1e-9)
    assert np.allclose(relative["rpy"], [0.0, 0.0, 0.0], atol=1e-9)


def test_pose_solve_needs_the_target_in_the_world(tmp_path):
    text = DEFAULT_SCENARIO.read_text()
    text = re.sub(r"^xyz = \[0\.487.*\nrpy = .*$", "relative_to_camera = { xyz = [0.0, 0.0, 0.35] }", text, flags=re.M)
    path = tmp_path / "relative.toml"
    path.write_text(text)
    result = runner.invoke(app, ["pose", str(path), "--solve"])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [
        "error: pose --solve needs the target placed in the world (target.xyz, target.rpy); "
        "target.relative_to_camera follows the camera wherever q0 puts it"
    ]


@pytest.mark.slow
def test_auto_q0_on_a_jaco2_with_tight_limits_puts_the_camera_at_the_reference(tmp_path):
    """A user's Jaco2 (joints 2 and 3 limited to 0.3 rad), the target placed where ``Q_STAR`` (within
    the limits) puts the camera at the reference pose: ``dvfc pose`` with ``q0 = "auto"`` finds a
    configuration there (the search it replaced exited 2, "closest of 12 starts: 0.0129 m or rad away")."""
    urdf = limited_jaco2(tmp_path)
    reference = SE3.from_xyz_rpy([0.0, 0.0, 0.35], [0.0, 0.0, 0.0])
    target = np.asarray(cs.DM((SE3.from_matrix(camera_at(Robot(urdf, JACO2_CAMERA), Q_STAR)) @ reference).as_matrix()))

    def edit(data: dict) -> None:
        data["robot"] = {"urdf": str(urdf), "camera_frame": JACO2_CAMERA, "q0": "auto"}
        data["reference"] = {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}
        data["target"]["xyz"] = target[:3, 3].tolist()
        data["target"]["rpy"] = Rotation.from_matrix(target[:3, :3]).as_euler("xyz").tolist()

    result = runner.invoke(app, ["pose", str(write(tmp_path, edit)), "--json", "-"])
    assert result.exit_code == 0, result.output
    relative = json.loads(result.stdout)["target_in_camera"]
    assert np.allclose(relative["xyz"], [0.0, 0.0, 0.35], atol=1e-9)
    assert np.allclose(relative["rpy"], [0.0, 0.0, 0.0], atol=1e-9)
