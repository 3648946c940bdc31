"""``[robot] q0 = "auto"``: the camera at the reference pose relative to the target, within the
URDF's position limits, on every built-in arm, with no IPOPT text on the standard streams."""

from __future__ import annotations

from types import SimpleNamespace

import casadi as cs
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dvfc.analysis import ik
from dvfc.analysis.ik import LIMIT_MARGIN, NoConfigurationError, _bounds, solve_configuration
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build
from dvfc.models.robot import BUILTIN_CAMERA_FRAME, Robot, builtin_urdf

from helpers import JACO2_CAMERA, Q_STAR, camera_at, limited_jaco2, scenario_dict

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


@pytest.mark.parametrize("offset", [0.0, pytest.param(0.03, marks=pytest.mark.slow)])
def test_auto_q0_finds_a_configuration_within_tight_limits(offset, tmp_path):
    """The goal is the camera's pose at ``Q_STAR`` (or 3 cm from it along the camera's x axis): a
    configuration within the limits attains it, and the search finds one (the 12 starts around
    the middle of the limits it replaced stopped 0.0129 m or rad away, 0.0149 with the offset):
    the pose error recomputed from its forward kinematics is below 1e-9 m and 1e-9 rad."""
    robot = Robot(limited_jaco2(tmp_path), JACO2_CAMERA)
    goal = camera_at(robot, Q_STAR)
    goal[:3, 3] += offset * goal[:3, 0]
    config = solve_configuration(robot, goal)
    limits = robot.limits
    assert np.all(config.q >= limits.lower + LIMIT_MARGIN - 1e-12) and np.all(config.q <= limits.upper - LIMIT_MARGIN)
    reached = camera_at(robot, config.q)
    assert np.linalg.norm(reached[:3, 3] - goal[:3, 3]) < 1e-9
    assert Rotation.from_matrix(goal[:3, :3].T @ reached[:3, :3]).magnitude() < 1e-9


@pytest.mark.slow
def test_the_global_search_finds_a_configuration_the_local_starts_miss(monkeypatch, tmp_path):
    """With two local starts (the middle of the limits and one Sobol point) none reaches this goal;
    the global search's screened starts do (and without them the search fails)."""
    robot = Robot(limited_jaco2(tmp_path), JACO2_CAMERA)
    goal = camera_at(robot, np.array([-2.893, 2.907, 1.189, -2.75, 3.876, 2.216]))
    monkeypatch.setattr(ik, "STARTS", 2)
    reached = camera_at(robot, solve_configuration(robot, goal).q)
    assert np.linalg.norm(reached[:3, 3] - goal[:3, 3]) < 1e-9
    monkeypatch.setattr(ik, "GLOBAL_STARTS", 0)
    with pytest.raises(NoConfigurationError):
        solve_configuration(robot, goal)


def test_an_unreachable_goal_reports_the_closest_configuration_found(monkeypatch, tmp_path):
    """3 m above the arm's reach: one line with the position (m) and rotation (rad) errors of the
    closest configuration found, and that configuration, whose pose is that far from the goal."""
    robot = Robot(limited_jaco2(tmp_path), JACO2_CAMERA)
    goal = camera_at(robot, Q_STAR)
    goal[2, 3] += 3.0
    monkeypatch.setattr(ik, "STARTS", 5)
    monkeypatch.setattr(ik, "GLOBAL_STARTS", 4)
    with pytest.raises(NoConfigurationError) as caught:
        solve_configuration(robot, goal)
    closest = caught.value.closest
    pose = camera_at(robot, closest.q)
    position = np.linalg.norm(pose[:3, 3] - goal[:3, 3])
    rotation = Rotation.from_matrix(goal[:3, :3].T @ pose[:3, :3]).magnitude()
    assert 2.0 < position < 3.0 and closest.position_error == pytest.approx(position, rel=1e-9)
    assert closest.rotation_error == pytest.approx(rotation, rel=1e-9, abs=1e-12)
    q = ", ".join(f"{v:.4g}" for v in closest.q)
    assert str(caught.value) == (
        "no configuration within the position limits puts the camera at the reference pose relative to the target: "
        f"the closest found (5 starts, then 4 of 4096 screened) is {position:.3g} m and {rotation:.3g} rad away, "
        f"at q = [{q}]"
    )


def test_a_solution_whose_conditioning_loses_the_goal_is_kept_as_least_squares_found_it(monkeypatch):
    """IPOPT's conditioning returning a point off the goal (here: every solve returns its start moved
    by 0.1 rad) does not lose the solution bounded least squares reached: that one is returned."""
    robot = Robot(builtin_urdf("ur5"), BUILTIN_CAMERA_FRAME["ur5"])
    goal = camera_at(robot, np.asarray(START["ur5"]))
    monkeypatch.setattr(cs, "nlpsol", lambda *args, **kwargs: lambda **given: {"x": cs.DM(given["x0"]) + 0.1})
    config = solve_configuration(robot, goal)
    reached = camera_at(robot, config.q)
    assert np.linalg.norm(reached[:3, 3] - goal[:3, 3]) < 1e-9
    assert config.position_error <= ik.REACHED and config.rotation_error <= ik.REACHED


def test_the_search_box_keeps_every_limit_and_a_full_turn_where_there_is_none():
    """Both limits: narrowed by the margin; one: the margin on its side, a full turn from it on
    the other; none (a continuous joint): ``[-pi, pi]``, every angle, without a margin."""
    inf, pi = np.inf, np.pi
    limits = SimpleNamespace(lower=np.array([-inf, 0.0, -inf, -1.0]), upper=np.array([inf, inf, 1.0, 1.0]))
    lower, upper = _bounds(SimpleNamespace(limits=limits))
    m = LIMIT_MARGIN
    assert np.allclose(lower, [-pi, m, 1 - 2 * pi, -1 + m], rtol=0, atol=1e-15)
    assert np.allclose(upper, [pi, 2 * pi, 1 - m, 1 - m], rtol=0, atol=1e-15)


def test_a_solved_start_is_the_turn_of_each_angle_nearest_the_middle_of_its_range():
    """Whole turns change no pose of a revolute arm: each angle moves to the value congruent to it
    modulo 2 pi that lies within its limits nearest their middle (0 where a side is unlimited), and
    stays where no other turn fits."""
    from dvfc.analysis.ik import nearest_turn

    lower = np.array([-2 * np.pi, -2 * np.pi, 0.0, -1.0, -np.inf, 1.0])
    upper = np.array([2 * np.pi, 2 * np.pi, 1.0, 6.0, np.inf, np.inf])
    q = np.array([-5.430, 3.641, 0.5, 5.5, 9.0, 7.0])
    moved = nearest_turn(q, lower, upper)
    turns = (moved - q) / (2 * np.pi)
    assert np.allclose(turns, np.round(turns), atol=1e-12)
    assert np.all((moved >= lower) & (moved <= upper))
    middle = np.array([0.0, 0.0, 0.5, 2.5, 0.0, 0.0])
    for k, value in enumerate(moved):  # no other turn within the limits is nearer the middle
        for other in (value - 2 * np.pi, value + 2 * np.pi):
            assert not (lower[k] <= other <= upper[k]) or abs(other - middle[k]) >= abs(value - middle[k])
    # 5.5 is nearer 2.5 than -0.78; a turn down from 7.0 (0.72) is nearer 0 but below the limit 1
    assert np.allclose(moved, [-5.430 + 2 * np.pi, 3.641 - 2 * np.pi, 0.5, 5.5, 9.0 - 2 * np.pi, 7.0])
