"""A user's own arm: strict JSON outputs, joint position limits, a readable verify table,
arms with fewer than six joints, and consistent figures of runs that stop."""

from __future__ import annotations

import json
import math
import re
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from typer.testing import CliRunner

from dvfc.analysis.calibration import read_calibration
from dvfc.analysis.cli import app
from dvfc.analysis.margins import TrackingBound, judge
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import Scenario, build
from dvfc.analysis.verify import implemented
from dvfc.models.robot import Robot, RobotModelError, builtin_urdf

from helpers import Q0, as_a_ur5_runs_it, five_joints, on_urdf, setter, write

runner = CliRunner()


def strict_load(path: Path) -> object:
    """``path`` parsed by a strict JSON parser: NaN and infinities are errors."""

    def refuse(constant: str) -> None:
        raise ValueError(f"{path.name}: {constant} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.mark.parametrize(
    "command", ["simulate", *(pytest.param(c, marks=pytest.mark.slow) for c in ("certify", "verify"))]
)
def test_every_output_file_is_strict_json(command, tmp_path):
    """An uncertified design (k_xi <= 1/2): its claims without a number are null, not NaN."""
    out = tmp_path / "out"
    scenario = write(tmp_path, setter("gains.k_xi", 0.5))
    result = runner.invoke(app, [command, str(scenario), "--out", str(out), "--json", str(tmp_path / "o.json")])
    assert result.exit_code in (0, 1), result.output
    files = [tmp_path / "o.json", *out.glob("*.json")]
    assert len(files) > 1
    for path in files:
        strict_load(path)


def ur5_with_limits(tmp_path: Path, joint: str, **limit: float) -> Path:
    """The UR5's URDF with some attributes of one joint's ``<limit>`` changed."""
    root = ET.parse(builtin_urdf("ur5")).getroot()
    element = next(j for j in root.iter("joint") if j.get("name") == joint).find("limit")
    for key, value in limit.items():
        element.set(key, repr(value))
    path = tmp_path / f"ur5_{joint}.urdf"
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


def test_q0_outside_its_position_limits_is_one_line_exit_2(tmp_path):
    urdf = ur5_with_limits(tmp_path, "shoulder_lift_joint", lower=-1.0, upper=1.0)
    out = tmp_path / "out"
    for command in ("pose", "simulate", "verify", "certify"):
        result = runner.invoke(app, [command, str(write(tmp_path, on_urdf(urdf))),
                                     *(["--out", str(out)] if command != "pose" else [])])  # fmt: skip
        assert result.exit_code == 2, (command, result.output)
        assert result.stderr.strip() == (
            f"error: robot.q0[1]: {Q0[1]:g} is outside the limits [-1, 1] of joint 2 (shoulder_lift_joint) in the URDF"
        ), (command, result.stderr)
        assert not out.exists()


def test_a_run_records_its_joint_range_against_the_position_limits(tmp_path):
    """The elbow may move 1 mrad from q0: the run leaves that range, summary.json says by how
    much (the ratio of the range's reach to the limits' half-width), verify's claim FAILs."""
    urdf = ur5_with_limits(tmp_path, "elbow_joint", lower=Q0[2] - 1e-3, upper=Q0[2] + 1e-3)
    out = tmp_path / "out"
    scenario = write(tmp_path, on_urdf(urdf))
    result = runner.invoke(app, ["simulate", str(scenario), "--out", str(out)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    limits = strict_load(out / "summary.json")["limits"]
    low, high = limits["position_range"][2]
    assert limits["position_limit"][2] == pytest.approx([Q0[2] - 1e-3, Q0[2] + 1e-3])
    assert limits["position_limit"][0] == pytest.approx([-2 * math.pi, 2 * math.pi])
    assert limits["position_ratio"][2] == pytest.approx(max(high - Q0[2], Q0[2] - low) / 1e-3)
    assert limits["position_ratio"][2] > 1 and not limits["within_position"]
    assert "joint range / position limits" in result.stdout and "joint 3, EXCEEDS" in result.stdout
    loop, s0, settings = build(Scenario.model_validate(tomllib.loads(scenario.read_text())), tmp_path)
    claim = next(c for c in implemented(loop, s0, settings) if c.name == "joint position limits")
    assert claim.status == "FAIL" and claim.value == pytest.approx(limits["position_ratio"][2])
    assert claim.detail.startswith("joint 3: range [")


@pytest.mark.parametrize(("limit", "reason"), [
    ({"velocity": 0.01}, "peak joint speed"),
    ({"lower": Q0[2] - 1e-3, "upper": Q0[2] + 1e-3}, "joint range"),
])  # fmt: skip
def test_a_margins_run_over_a_velocity_or_position_limit_does_not_hold(limit, reason, tmp_path):
    urdf = ur5_with_limits(tmp_path, "elbow_joint", **limit)
    scenario = write(tmp_path, lambda data: (on_urdf(urdf)(data), as_a_ur5_runs_it(data)))
    loop, s0, settings = build(Scenario.model_validate(tomllib.loads(scenario.read_text())), tmp_path)
    traj = as_implemented(loop, settings).run(s0)
    assert traj.status == "ok", traj.message
    holds, detail = judge(traj, loop, settings, TrackingBound(math.inf, 180.0, "continuous", ""))
    assert not holds and detail.startswith(reason), detail


WHY = "n = 5 < 6 joints: J_b pinv(J_b) != I, so Theorems 1-2 do not apply to the paper's loop on this arm"


@pytest.mark.parametrize(("command", "status", "says"), [
    ("pose", 0, f"warning: {WHY}"),
    ("simulate", 0, f"warning: {WHY}"),
    pytest.param("certify", 1, None, marks=pytest.mark.slow),
    pytest.param("verify", 1, f"warning: {WHY}", marks=pytest.mark.slow),
    ("synthesize", 2, "error: loop: gain synthesis is for the paper's loop with n >= 6 joints (this is paper, n = 5)"),
    ("margins", 2, f"error: loop: dvfc margins needs the paper's equilibrium and Theorems 1-2; {WHY}"),
    ("report", 2, f"error: loop: dvfc report needs the paper's equilibrium and Theorems 1-2; {WHY}"),
])  # fmt: skip
def test_every_command_on_a_five_joint_arm_works_or_says_why_not(command, status, says, tmp_path):
    """Theorems 1-2 need n >= 6: ``pose``, ``simulate`` and ``verify`` warn in one line before
    the work, ``certify`` says what is not certified, and the commands that rest on them refuse
    in one line before any work (nothing written)."""
    from dvfc.reports.cli import app as full

    out = tmp_path / "out"
    target = out / "s.toml" if command == "synthesize" else out
    options = [] if command == "pose" else ["--out", str(target)]
    result = runner.invoke(full, [command, str(write(tmp_path, five_joints)), *options])
    assert result.exit_code == status, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    if says is not None:
        assert result.stderr.strip().splitlines()[0] == says, result.stderr
    if status == 2:
        assert len(result.stderr.strip().splitlines()) == 1 and not out.exists()
    else:
        assert "n = 5 < 6" in result.output, result.output


def test_a_diverged_run_reports_figures_up_to_its_stop(tmp_path):
    """A wrist gain far above the sampled loop's stable range diverges within milliseconds: the
    table's max |tau| and summary.json's per-joint peaks come from the same samples, and the
    final errors are labelled as those of the last sample before the stop."""
    def diverging(data: dict) -> None:
        as_a_ur5_runs_it(data)
        data["gains"]["k_xi"] = 200.0

    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(write(tmp_path, diverging)), "--out", str(out)],
                           env={"COLUMNS": "200"})  # fmt: skip
    assert result.exit_code == 1 and "run stopped: non-finite state" in result.stderr, result.output
    record = strict_load(out / "summary.json")
    s = record["summary"]
    assert s["max_torque"] == max(record["limits"]["peak_torque"])
    assert s["stopped"] and s["final_at"] == s["t_final"] < s["stopped_at"]
    assert f"max |tau| applied {s['max_torque']:.4g} N m" in " ".join(result.stdout.replace("│", " ").split())
    assert f"final (at {s['final_at']:.4g} s, the last sample before the stop)" in result.stdout


Z1 = Path(__file__).parent / "data" / "z1_bracket.urdf"


def on_own_urdf(tmp_path: Path, text: str, name: str = "arm.urdf"):
    """An edit running the scenario on the URDF ``text`` (written to ``tmp_path``), a Z1-like arm
    with its camera on ``camera_link``, the target 0.35 m ahead of the camera."""
    (tmp_path / name).write_text(text)

    def edit(data: dict) -> None:
        data["robot"] = {"urdf": str(tmp_path / name), "camera_frame": "camera_link",
                         "q0": [0.5, 1.0, -2.0, 1.0, 0.3, 0.5]}  # fmt: skip
        for key in ("xyz", "rpy"):
            data["target"].pop(key)
        data["target"]["relative_to_camera"] = {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}

    return edit


def refused(tmp_path: Path, edit, command: str = "simulate") -> str:
    """The one line of ``command`` refusing the scenario of ``edit`` (exit 2, nothing written)."""
    out = tmp_path / "out"
    options = [] if command == "pose" else ["--out", str(out)]
    result = runner.invoke(app, [command, str(write(tmp_path, edit)), *options])
    assert result.exit_code == 2, result.output
    assert not out.exists() and "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


@pytest.mark.parametrize(("old", "new", "says"), [
    ('effort="60"', 'effort="0"', "effort limit 0 must be a positive number (N m)"),
    ('effort="60"', 'effort="-40"', "effort limit -40 must be a positive number (N m)"),
    ('lower="0.0" upper="2.967" effort="60" velocity="3.1415"', 'lower="0.0" upper="2.967" effort="60" velocity="0"',
     "velocity limit 0 must be a positive number (rad/s)"),
    ('upper="2.967" effort="60" velocity="3.1415"', 'upper="2.967" effort="60"', "no velocity limit"),
])  # fmt: skip
def test_a_zero_negative_or_missing_effort_or_velocity_limit_is_refused_naming_the_joint(old, new, says, tmp_path):
    """A URDF has no "unlimited" effort or velocity: 0 would make every run's torque ratio 0 ("within
    the limit") while the arm applies tens of N m. Refused in one line naming the joint and field."""
    text = Z1.read_text()
    assert text.count(old) == 1
    line = refused(tmp_path, on_own_urdf(tmp_path, text.replace(old, new)))
    assert line.startswith(f"error: robot.urdf: joint 'joint2' of arm.urdf: {says}"), line


def test_a_continuous_joint_has_no_position_limits_and_may_give_no_effort_or_velocity(tmp_path):
    """The URDF ignores a continuous joint's lower/upper (the example-robot-data Jaco2 gives +-2 pi
    there): no position limit; and no effort or velocity limit when it gives no ``<limit>`` (a
    ``<limit>`` without them is refused, as the URDF requires them)."""
    text = Z1.read_text().replace('"joint1" type="revolute"', '"joint1" type="continuous"')
    first, second = ('<limit lower="-2.618" upper="2.618" effort="30" velocity="3.1415"/>',
                     '<limit lower="-2.618" upper="2.618"/>')  # fmt: skip
    for name, limit in (("given.urdf", first), ("none.urdf", "")):
        (tmp_path / name).write_text(text.replace(first, limit))
        limits = Robot(tmp_path / name, "camera_link").limits
        assert (limits.lower[0], limits.upper[0]) == (-math.inf, math.inf)
        assert (limits.effort[0], limits.velocity[0]) == ((30.0, 3.1415) if limit else (math.inf, math.inf))
        assert (limits.effort[1], limits.lower[1], limits.upper[1]) == (60.0, 0.0, 2.967)
    (tmp_path / "partial.urdf").write_text(text.replace(first, second))
    with pytest.raises(RobotModelError, match=r"^joint 'joint1' of partial.urdf: no effort limit \(<limit effort="):
        Robot(tmp_path / "partial.urdf", "camera_link")


def test_moving_links_without_inertial_data_are_refused_naming_them(tmp_path):
    """Joints 5 and 6 move nothing with mass (link05; link06 and everything fixed to it have no
    ``<inertial>``): ``M(q)`` is singular (a link without one carrying a body with mass is fine).
    One line naming those links, exit 2, for every command that builds the arm (before, a run
    stopped at t = 0 and certify certified it)."""
    text = Z1.read_text()
    carried, count = re.subn(r'(<link name="link06">)<inertial>.*?</inertial>', r"\1", text)
    (tmp_path / "carried.urdf").write_text(carried)
    assert count == 1 and Robot(tmp_path / "carried.urdf", "camera_link").n == 6  # the gripper fixed to it has mass
    for link in ("link05", "link06", "gripperStator", "gripperMover", "camera_bracket", "camera_link"):
        text, count = re.subn(rf'(<link name="{link}">)<inertial>.*?</inertial>', r"\1", text)
        assert count == 1
    for command in ("pose", "simulate", "certify"):
        line = refused(tmp_path, on_own_urdf(tmp_path, text), command)
        assert line == (
            "error: robot.urdf: arm.urdf: link(s) 'link05', 'link06' carry no <inertial> mass or inertia, nor does "
            "anything fixed to them: M(q) would be singular; give each moving link its inertial data"
        ), (command, line)


REALSENSE = """image_width: 1280
image_height: 720
camera_name: color
camera_matrix:
  rows: 3
  cols: 3
  data: [908.3, 0.0, 641.1, 0.0, 907.9, 362.4, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.0, 0.0, 0.0, 0.0, 0.0]
"""
"""A RealSense-like colour camera's ROS ``camera_info`` YAML (5 coefficients, plumb_bob)."""


def calibrated(tmp_path: Path, text: str):
    """An edit giving the scenario's camera the calibration file ``text`` (written beside it)."""
    (tmp_path / "cam.yaml").write_text(text)

    def edit(data: dict) -> None:
        data["camera"] = {"calibration": "cam.yaml"}

    return edit


@pytest.mark.parametrize(("text", "says"), [
    (REALSENSE.replace("image_height: 720\n", ""),
     "missing field image_height (or height): the image height in pixels"),
    (REALSENSE.replace("362.4, 0.0, 0.0, 1.0]", "362.4, 0.0, 0.0]"),
     "camera_matrix: expected 9 entries (a 3x3 matrix, row by row), got 8"),
    (REALSENSE.replace("data: [0.0, 0.0, 0.0, 0.0, 0.0]", "data: [0.1, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0]"),
     "distortion_coefficients: 8 coefficients with nonzero entries past the fifth (a rational, thin-prism or tilted "
     "model) are not supported (supported: plumb_bob, OpenCV's 5 coefficients [k1, k2, p1, p2, k3], and "
     "rational_polynomial with k4 = k5 = k6 = 0)"),
    (REALSENSE.replace("plumb_bob", "equidistant"), "distortion_model: 'equidistant' is not supported (supported:"),
    (REALSENSE.replace("  cols: 3\n", "  cols: 3\n data: ["), "not valid YAML: line 7, column 2: "),
    (REALSENSE.replace("908.3, 0.0", "908.3, 1.5"), "camera_matrix: expected a pinhole matrix [fx, 0, cx, 0, fy, cy, "
     "0, 0, 1] (no skew), got [908.3, 1.5, 641.1, 0, 907.9, 362.4, 0, 0, 1]"),
    (REALSENSE.replace("image_width: 1280", "image_width: 1280.5"),
     "image_width: expected a positive whole number of pixels, got 1280.5"),
])  # fmt: skip
def test_a_bad_calibration_file_is_one_line_naming_the_file_and_the_field(text, says, tmp_path):
    line = refused(tmp_path, calibrated(tmp_path, text), "pose")
    assert line.startswith(f"error: camera.calibration: {tmp_path / 'cam.yaml'}: {says}"), line


def test_a_camera_info_message_as_ros2_topic_echo_prints_it_reads(tmp_path):
    """``sensor_msgs/CameraInfo`` as ``ros2 topic echo --once`` prints it: ``height``, ``width``,
    ``k``, ``d``, then ``---``; the same intrinsics as the calibration file's."""
    echoed = ("header:\n  stamp:\n    sec: 0\n    nanosec: 0\n  frame_id: camera_color_optical_frame\nheight: 720\n"
              "width: 1280\ndistortion_model: plumb_bob\nd:\n- 0.0\n- 0.0\n- 0.0\n- 0.0\n- 0.0\nk:\n- 908.3\n- 0.0\n"
              "- 641.1\n- 0.0\n- 907.9\n- 362.4\n- 0.0\n- 0.0\n- 1.0\n---\n")  # fmt: skip
    (tmp_path / "echo.yaml").write_text(echoed)
    (tmp_path / "file.yaml").write_text(REALSENSE)
    echo, file = read_calibration(tmp_path / "echo.yaml"), read_calibration(tmp_path / "file.yaml")
    assert echo == file and (echo.fx, echo.fy, echo.principal_point) == (908.3, 907.9, (641.1, 362.4))
    assert (echo.width, echo.height, echo.distortion) == (1280, 720, (0.0,) * 5)


@pytest.mark.parametrize(("edit", "says"), [
    (setter("robot.mount", {"xyz": [0.0, 0.0, 55.7], "rpy": [0.0, 0.0, 0.0]}),
     "robot.mount.xyz[2]: 55.7 m is not a plausible length in a robot cell (|x| <= 10 m); lengths are in metres "
     "(55.7 mm = 0.0557 m)"),
    (setter("robot.mount", {"xyz": [0.0, 0.0, 0.0], "rpy": [180.0, 0.0, 0.0]}),
     "robot.mount.rpy[0]: 180 rad is beyond 2 pi in magnitude: angles are in radians (180 deg = 3.142 rad)"),
    (setter("reference.rpy", [0.0, -90.0, 0.0]), "reference.rpy[1]: -90 rad is beyond 2 pi in magnitude"),
    (setter("target.xyz", [487.0, 109.0, 82.0]), "target.xyz[0]: 487 m is not a plausible length"),
    (setter("target.points", [[50.0, 50.0, 0.0], [-50.0, 50.0, 0.0], [-50.0, -50.0, 0.0], [50.0, -50.0, 0.0]]),
     "target.points[0][0]: 50 m is not a plausible length"),
    (setter("robot.q0", [8.6, -83.1, 83.1, -97.4, -83.1, 11.5]), "robot.q0[0]: 8.6 rad is beyond 2 pi in magnitude"),
    (setter("observer.error_rpy", [0.0, 0.0, 7.0]), "observer.error_rpy[2]: 7 rad is beyond 2 pi in magnitude"),
    (setter("implementation", {"control_rate": 500.0, "latency": 40.0}),
     "implementation.latency: 40 s is more than 1 s: times are in seconds (40 ms = 0.04 s)"),
])  # fmt: skip
def test_a_length_in_mm_or_an_angle_in_degrees_or_a_latency_in_ms_is_flagged_naming_the_field(edit, says, tmp_path):
    """A robot cell is within 10 m, an angle within 2 pi, a camera's latency within a second: beyond,
    the value is taken for a unit mistake (before, a mount in mm surfaced as an inverse-kinematics
    failure "55.7 m or rad away", and rpy = [180, 0, 0] or latency = 40 ran)."""
    line = refused(tmp_path, edit)
    assert line.startswith(f"error: {says}"), line
