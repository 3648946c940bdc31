"""Mimic joints follow their master as the URDF says; a prismatic joint on the way to the
camera is refused in one line by every command."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dvfc.models.robot import Robot, builtin_urdf
from dvfc.reports.cli import app

from helpers import scenario_dict, write

runner = CliRunner()
Q0 = scenario_dict()["robot"]["q0"]
MULTIPLIER, OFFSET = 0.5, 0.1


def mimic_urdf(tmp_path: Path, mimic: bool = True) -> Path:
    """The UR5 with a camera bracket on ``tool0`` turning with the last wrist joint
    (``q_bracket = 0.5 q_6 + 0.1``), or, without ``mimic``, turning on its own."""
    root = ET.parse(builtin_urdf("ur5")).getroot()
    inertial = ET.SubElement(ET.SubElement(root, "link", name="bracket"), "inertial")
    ET.SubElement(inertial, "mass", value="0.3")
    ET.SubElement(inertial, "origin", xyz="0 0.02 0.03")
    ET.SubElement(inertial, "inertia", ixx="4e-4", iyy="5e-4", izz="6e-4", ixy="0", ixz="0", iyz="0")
    joint = ET.SubElement(root, "joint", name="bracket_joint", type="revolute")
    ET.SubElement(joint, "parent", link="tool0")
    ET.SubElement(joint, "child", link="bracket")
    ET.SubElement(joint, "origin", xyz="0 0.05 0.02", rpy="0 0 0")
    ET.SubElement(joint, "axis", xyz="1 0 0")
    ET.SubElement(joint, "limit", lower="-3", upper="3", effort="10", velocity="3")
    if mimic:
        ET.SubElement(joint, "mimic", joint="wrist_3_joint", multiplier=repr(MULTIPLIER), offset=repr(OFFSET))
    path = tmp_path / ("mimic.urdf" if mimic else "free.urdf")
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


def test_a_mimic_joint_follows_its_master(tmp_path):
    """Six independent joints; the camera pose, ``M`` and ``g`` are those of the free 7-joint arm
    at ``q_7 = 0.5 q_6 + 0.1`` (``M = T^T M_7 T``, ``g = T^T g_7``); the bracket's limits
    narrow the wrist's (``-3 <= 0.5 q_6 + 0.1 <= 3``, ``|0.5 qd_6| <= 3``); the bounds hold."""
    coupled, free = Robot(mimic_urdf(tmp_path), "bracket"), Robot(mimic_urdf(tmp_path, False), "bracket")
    assert coupled.n == 6 and free.n == 7
    t = np.vstack([np.eye(6), MULTIPLIER * np.eye(6)[5]])
    q = np.array([0.1, -1.2, 1.3, -1.7, -1.5, 0.4])
    q7 = t @ q + np.r_[np.zeros(6), OFFSET]
    pose, pose7 = (r.function("g", r.camera_pose.as_matrix()) for r in (coupled, free))
    np.testing.assert_allclose(pose(q, 0), pose7(q7, 0), atol=1e-12)
    mass, mass7 = (np.array(r.function("M", r.mass_matrix)(x, 0)) for r, x in ((coupled, q), (free, q7)))
    np.testing.assert_allclose(mass, t.T @ mass7 @ t, atol=1e-12)
    gravity, gravity7 = (np.array(r.function("g", r.gravity)(x, 0)) for r, x in ((coupled, q), (free, q7)))
    np.testing.assert_allclose(gravity, t.T @ gravity7, atol=1e-12)
    limits = coupled.limits
    assert (limits.lower[5], limits.upper[5], limits.velocity[5]) == pytest.approx((-6.2, 5.8, 3.2))
    bounds = coupled.mass_bounds
    assert np.all(np.abs(mass) <= bounds.upper) and np.all(np.diag(mass) >= bounds.diagonal_lower)


def on_bracket(urdf: Path):
    """An edit running the default scenario with the camera on the bracket of ``urdf``."""

    def edit(data: dict) -> None:
        data["robot"].pop("model")
        data["robot"].update(urdf=str(urdf), camera_frame="bracket")
        for key in ("xyz", "rpy"):
            data["target"].pop(key)
        data["target"]["relative_to_camera"] = {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}

    return edit


@pytest.mark.parametrize("command", ["pose", "simulate"])
def test_a_camera_on_a_mimic_joint_runs(command, tmp_path):
    options = [] if command == "pose" else ["--out", str(tmp_path / "out")]
    result = runner.invoke(app, [command, str(write(tmp_path, on_bracket(mimic_urdf(tmp_path)))), *options])
    assert result.exit_code == 0, result.output
    assert result.exception is None and "error" not in result.stderr and "warning" not in result.stderr, result.stderr


def on_the_finger(data: dict) -> None:
    """An edit putting the camera on the Panda's left finger (a prismatic joint)."""
    data["robot"].update(model="panda", camera_frame="panda_leftfinger")
    data["robot"]["q0"] = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]


FINGER = (
    "error: robot.camera_frame: joint 'panda_finger_joint1' is prismatic, on the chain from the root of panda.urdf "
    "to 'panda_leftfinger': only revolute and continuous joints are supported; mount the camera on a link above it"
)


@pytest.mark.parametrize("command", ["pose", "simulate", "verify", "certify", "margins", "report", "synthesize"])
def test_a_prismatic_joint_to_the_camera_is_one_line_before_any_work(command, tmp_path):
    out = tmp_path / "out"
    options = [] if command == "pose" else ["--out", str(out / "s.toml" if command == "synthesize" else out)]
    result = runner.invoke(app, [command, str(write(tmp_path, on_the_finger)), *options])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == FINGER
    assert not out.exists()
