"""``[robot] q0 = "auto"``: the camera at the reference pose relative to the target, within the
URDF's position limits, on every built-in arm, with no IPOPT text on the standard streams."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dvfc.analysis.ik import LIMIT_MARGIN
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build
from dvfc.models.robot import BUILTIN_CAMERA_FRAME, Robot, builtin_urdf

from conftest import scenario_dict

START = {
    "ur5": [0.15, -1.45, 1.45, -1.70, -1.45, 0.20],
    "panda": [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785],
    "puma560": [0.0, 0.5, -0.5, 0.0, 0.6, 0.0],
}


def automatic_on(name: str):
    """An edit running the default scenario on ``name`` with ``q0 = "auto"`` and the target
    0.35 m ahead of where the camera is at the arm's usual start (a reachable goal)."""
    robot = Robot(builtin_urdf(name), BUILTIN_CAMERA_FRAME[name])
    camera = np.asarray(cs.Function("g", [robot.q], [robot.camera_pose.as_matrix()])(START[name]))
    target = camera[:3, 3] + 0.35 * camera[:3, 2]

    def edit(data: dict) -> None:
        data["robot"] = {"model": name, "q0": "auto"}
        data["target"]["xyz"] = target.tolist()
        data["target"]["rpy"] = Rotation.from_matrix(camera[:3, :3]).as_euler("xyz").tolist()

    return edit


@pytest.mark.parametrize("name", sorted(START))
def test_auto_q0_reaches_the_reference_within_the_limits(name, capfd):
    loop, s0, _ = build(Scenario.model_validate(scenario_dict(automatic_on(name))), DEFAULT_SCENARIO.parent)
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""
    q = s0[: loop.robot.n]
    limits = loop.robot.limits
    assert np.all(q >= limits.lower + LIMIT_MARGIN - 1e-12) and np.all(q <= limits.upper - LIMIT_MARGIN + 1e-12)
    relative = np.asarray(cs.Function("g", [loop.t, loop.state], [loop.relative_pose.as_matrix()])(0.0, s0))
    reference = np.asarray(cs.DM(loop.reference.as_matrix()))
    assert np.linalg.norm(relative[:3, 3] - reference[:3, 3]) < 1e-6
    assert np.linalg.norm(relative[:3, :3] - reference[:3, :3]) < 1e-6
