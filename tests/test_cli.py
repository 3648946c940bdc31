"""``dvfc simulate``: outputs, and one clear line with exit status 2 for bad input."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
import tomli_w
import typer
from typer.testing import CliRunner

import dvfc.analysis.console as console_module
from dvfc.analysis.cli import app
from dvfc.analysis.output import interrupt_aware, interrupted
from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.models.robot import Robot, builtin_urdf

from helpers import scenario_dict, setter, write

runner = CliRunner()
EXAMPLES = Path(__file__).parent.parent / "examples"
DEFAULT_SCENARIO_TEXT = (Path(__file__).parent.parent / "analysis" / "scenarios" / "ur5_circle.toml").read_text()


def remover(path: str):
    def edit(data):
        *parents, key = path.split(".")
        node = data
        for p in parents:
            node = node[p]
        del node[key]

    return edit


BAD_SCENARIOS = {
    "unknown key": (setter("gains.k_z", 1.0), "gains.k_z: unknown key"),
    "unknown section": (setter("controller.k", 1.0), "controller: unknown section 'controller' (expected one of"),
    "missing gains": (remover("gains"), "gains: required key missing"),
    "negative gain": (setter("gains.k_xi", -1.0), "gains.k_xi"),
    "zero gain": (setter("gains.k_e", 0.0), "gains.k_e"),
    "five-entry k_c": (setter("gains.k_c", [1.0] * 5), "gains.k_c: expected 6 entries, got 5"),
    "nan gain": (setter("gains.k_c", float("nan")), "gains.k_c"),
    "inf weight": (setter("weights.w_pc", float("inf")), "weights.w_pc"),
    "string weight": (setter("weights.w_re", "heavy"), "weights.w_re"),
    "three points": (
        setter("target.points", [[0.05, 0.05, 0.0], [-0.05, 0.05, 0.0], [0.0, -0.05, 0.0]]),
        "target.points",
    ),
    "collinear points": (setter("target.points", [[x, 0.0, 0.0] for x in (-0.1, 0.0, 0.05, 0.1)]), "collinear"),
    "points behind camera": (setter("target.xyz", [0.487, 0.109, 0.9]), "target.points"),
    "unknown robot": (setter("robot.model", "r2d2"), "robot.model: unknown robot model"),
    "missing camera frame": (setter("robot.camera_frame", "no_such_link"), "robot.camera_frame"),
    "missing urdf": (
        lambda d: (d["robot"].pop("model"), d["robot"].update(urdf="nope.urdf")),
        "robot.urdf: no such file",
    ),
    "wrong q0 length": (setter("robot.q0", [0.0] * 5), "robot.q0: expected 6 entries, got 5"),
    "reference at pi": (setter("reference.rpy", [3.141592653589793, 0.0, 0.0]), "reference.rpy"),
    "bad motion kind": (setter("target.motion.kind", "zigzag"), "target.motion.kind"),
    "static with radius": (setter("target.motion", {"kind": "static", "radius": 0.1}), "target.motion"),
    "step without amplitude": (setter("disturbance.torque", [{"kind": "step"}]), "disturbance.torque[0]"),
    "bad mode": (setter("simulation.mode", "psychic"), "simulation.mode"),
    "negative duration": (setter("simulation.duration", -1.0), "simulation.duration"),
    "zero focal length": (setter("camera.focal_length", 0.0), "camera.focal_length"),
}


def camera_position_at_q0() -> list[float]:
    robot = Robot(builtin_urdf("ur5"), "tool0")
    q0 = scenario_dict()["robot"]["q0"]
    return np.asarray(cs.Function("p", [robot.q], [robot.camera_pose.translation])(q0)).ravel().tolist()


def garbage_urdf(data):
    data["robot"].pop("model")
    data["robot"]["urdf"] = "broken.urdf"
    data["robot"]["camera_frame"] = "tool0"


BAD_SCENARIOS.update({
    "target at the camera centre": (lambda d: d["target"].update(xyz=camera_position_at_q0()), "target.points"),
    "unparsable URDF": (garbage_urdf, "robot.urdf"),
    "qd0 wrong length": (setter("robot.qd0", [0.0] * 7), "robot.qd0: expected 6 entries, got 7"),
    "NaN in observer error": (setter("observer.error_rpy", [0.0, float("nan"), 0.0]), "observer.error_rpy"),
    "dt above duration": (setter("simulation.dt", 5.0), "simulation"),
    "unknown start reference": (setter("start.reference", "ramp"), "start.reference"),
    "zero plan duration": (setter("start.duration", 0.0), "start.duration"),
    "unknown start observer": (setter("start.observer", "pnp"), "start.observer"),
    "negative ramp": (setter("start.ramp", -1.0), "start.ramp"),
    "ramp with a planned reference": (lambda d: d.update(start={"reference": "planned", "ramp": 1.0}), "start: ramp"),
    "missing weight": (remover("weights.w_re"), "weights.w_re: required key missing"),
    "disturbance of wrong length": (
        setter("disturbance.torque", [{"kind": "sine", "amplitude": [1.0, 2.0], "frequency": 1.0}]),
        "disturbance.torque[0].amplitude",
    ),
    "empty grid": (setter("grid", {}), "grid"),
    "unknown grid axis": (setter("grid", {"k_z": [1.0]}), "unknown axis 'k_z'"),
    "negative grid value": (setter("grid", {"k_c": [1.0, -2.0]}), "grid.k_c"),
    "grid range of zero points": (setter("grid", {"k_c": {"start": 1.0, "stop": 2.0, "num": 0}}), "grid.k_c"),
    "reversed synthesis bounds": (setter("synthesize.k_c", [5.0, 1.0]), "synthesize"),
    "unknown synthesis objective": (setter("synthesize.objective", "speed"), "synthesize.objective"),
    "string respect_limits": (setter("synthesize.respect_limits", "yes"), "synthesize.respect_limits"),
    "respect_limits with a gamma target": (
        setter("synthesize", {"respect_limits": True, "gamma": 0.5}), "respect_limits: not available with a gamma"
    ),
    "gamma target for the target speed": (
        setter("synthesize", {"objective": "target_speed", "gamma": 0.5}), "a gamma target applies to objective"
    ),
    "negative gamma requirement": (setter("certify.gamma", -1.0), "certify.gamma"),
    "negative envelope speed": (setter("envelope.target_speed", -0.1), "envelope.target_speed"),
    "rate map without an envelope": (setter("report.map", "rate"), "needs an [envelope] section"),
    "theta_bar at 180 degrees": (setter("envelope.theta_bar_deg", 180.0), "envelope.theta_bar_deg"),
    "width without height": (remover("camera.height"), "camera: give both width and height"),
    "principal point off the image": (
        lambda d: d["camera"].update(width=640, height=480, principal_point=[700.0, 240.0]),
        "camera: principal_point must lie inside the image",
    ),
    "string gain": (setter("gains.k_xi", "20"), "gains.k_xi: expected a number or a list of numbers, got the string"),
    "string gain entries": (setter("gains.k_c", ["3"] * 6), "gains.k_c[0]: expected a number, got the string '3'"),
    "boolean gain": (setter("gains.k_xi", True), "gains.k_xi: expected a number or a list of numbers, got the boolean"),
    "boolean switch as number": (setter("simulation.jit", 1), "simulation.jit: expected true or false, got 1"),
    "negative gain entry": (setter("gains.k_e", [1, 2, -1, 4, 5, 6]), "gains.k_e[2]: must be > 0, got -1"),
    "typo in a required key": (
        lambda d: d["camera"].update(focal_lenght=d["camera"].pop("focal_length")),
        "camera.focal_lenght: unknown key 'focal_lenght' (did you mean 'focal_length'?)",
    ),
    "typo in a section": (lambda d: d.update(gain=d.pop("gains")), "unknown section 'gain' (did you mean 'gains'?)"),
    "typo in a nested key": (
        setter("disturbance.torque", [{"kind": "sine", "amplitude": 1.0, "frequencyy": 1.0}]),
        "disturbance.torque[0].frequencyy: unknown key 'frequencyy' (did you mean 'frequency'?)",
    ),
    "typo in a grid range": (
        setter("grid", {"k_c": {"strat": 1.0, "stop": 2.0, "num": 3}}),
        "grid.k_c.strat: unknown key 'strat' (did you mean 'start'?)",
    ),
    "typo in a grid axis": (setter("grid", {"k_cc": [1.0]}), "unknown axis 'k_cc'; did you mean 'k_c'?"),
    "camera frame misspelt": (setter("robot.camera_frame", "tool_0"), "no link named 'tool_0'; closest: 'tool0'"),
    "feature outside the image at the start": (
        lambda d: d["camera"].update(width=160, height=120),
        "target.points: feature point 0 is at pixel",
    ),
    "zero control rate": (setter("implementation", {"control_rate": 0.0}), "implementation.control_rate"),
    "negative camera rate": (
        setter("implementation", {"control_rate": 500.0, "camera_rate": -60.0}), "implementation.camera_rate"
    ),
    "camera faster than control": (
        setter("implementation", {"control_rate": 500.0, "camera_rate": 1000.0}),
        "implementation: camera_rate 1000 Hz exceeds control_rate 500 Hz",
    ),
    "negative latency": (setter("implementation", {"control_rate": 500.0, "latency": -0.02}), "implementation.latency"),
    "negative pixel noise": (
        setter("implementation", {"control_rate": 500.0, "pixel_noise": -1.0, "e_e": "image"}),
        "implementation.pixel_noise",
    ),
    "latency between control samples": (
        setter("implementation", {"control_rate": 500.0, "latency": 0.021}),
        "implementation: latency 0.021 s is not a whole number of control periods (0.002 s)",
    ),
    "pixel noise on the ideal e_e": (
        setter("implementation", {"control_rate": 500.0, "pixel_noise": 0.5, "e_e": "ideal"}),
        "implementation.pixel_noise: needs e_e = \"image\"",
    ),
    "output step between control samples": (
        setter("implementation", {"control_rate": 250.0}), "simulation.dt: 0.01 s is not a whole number"
    ),
    "payload without mass": (setter("plant.payload", {"com": [0.0, 0.0, 0.05]}), "plant.payload.mass"),
    "negative payload mass": (setter("plant.payload", {"mass": -1.0}), "plant.payload.mass"),
    "reference behind the camera": (setter("reference.xyz", [0.0, 0.0, -0.35]), "reference: feature point 0"),
    "reference outside the image": (
        setter("reference.xyz", [0.5, 0.0, 0.35]), "reference: feature point 0 is at pixel"
    ),
})  # fmt: skip

COMMANDS = ("simulate", "certify", "verify", "synthesize")


def invoke(command: str, scenario: Path, out: Path):
    target = out / "s.toml" if command == "synthesize" else out
    return runner.invoke(app, [command, str(scenario), "--out", str(target)])


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", BAD_SCENARIOS)
def test_bad_scenario_is_one_line_exit_2(case, command, tmp_path):
    edit, expected = BAD_SCENARIOS[case]
    (tmp_path / "broken.urdf").write_text("<robot name='x'><link name=")
    out = tmp_path / "out"
    result = invoke(command, write(tmp_path, edit), out)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], result.stderr
    assert "Traceback" not in result.output and not out.exists()


def test_huge_grid_needs_confirmation(tmp_path):
    axis = {"start": 1.0, "stop": 2.0, "num": 1000}
    scenario = write(tmp_path, setter("grid", {"k_c_p": axis, "k_c_r": axis, "k_e": axis}))
    result = runner.invoke(app, ["certify", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "--large" in result.stderr and not (tmp_path / "out").exists()


def test_resume_without_sweep_is_exit_2(tmp_path):
    scenario = write(tmp_path, setter("grid", {"k_c": [1.0, 2.0]}))
    result = runner.invoke(app, ["certify", str(scenario), "--out", str(tmp_path / "o"), "--resume"])
    assert result.exit_code == 2 and "--resume" in result.stderr


def test_missing_file_is_exit_2(tmp_path):
    result = runner.invoke(app, ["simulate", str(tmp_path / "absent.toml")])
    assert result.exit_code == 2 and "cannot read scenario file" in result.stderr


def test_not_toml_is_exit_2(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[robot\nmodel = ")
    result = runner.invoke(app, ["simulate", str(path)])
    assert result.exit_code == 2 and "not valid TOML" in result.stderr


def test_unwritable_out_is_exit_2(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    result = runner.invoke(app, ["simulate", str(write(tmp_path)), "--out", str(blocker)])
    assert result.exit_code == 2 and "--out" in result.stderr


def test_simulate_writes_trajectory_and_summary(tmp_path):
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(write(tmp_path)), "--out", str(out), "--json", "-"])
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)
    on_disk = json.loads((out / "summary.json").read_text())
    assert printed["summary"] == on_disk["summary"]
    assert on_disk["provenance"]["scenario_sha256"]
    with np.load(out / "trajectory.npz") as data:
        for name in ("t", "q", "qd", "tau", "g", "gbar", "f", "fbar", "e_c", "e_e", "xi", "u", "nu", "V", "w"):
            assert name in data.files
        assert data["t"][-1] == pytest.approx(0.2)
    assert on_disk["summary"]["identity_residuals"]["dissipation"] < 1e-6


@pytest.mark.slow
def test_cli_process_exit_status_and_message(tmp_path):
    """A real process: bad input gives status 2 and a single line, no traceback."""
    path = write(tmp_path, setter("gains.k_c", [1.0] * 5))
    proc = subprocess.run([sys.executable, "-m", "dvfc.analysis", "simulate", str(path)], capture_output=True,
                          text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip() == "error: gains.k_c: expected 6 entries, got 5"


@pytest.mark.slow
def test_certify_default_scenario_json(tmp_path):
    result = runner.invoke(app, ["certify", str(write(tmp_path)), "--json", "-"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    point = data["points"][0]
    assert point["certified"] and point["gamma"] > 0 and point["margin"] >= 0
    assert set(point) >= {"gains", "weights", "certified", "gamma", "method", "margin", "reason"}
    assert data["summary"] == {**data["summary"], "points": 1, "certified": 1, "gamma_min": point["gamma"]}
    assert "SO(3)" in data["region"]


@pytest.mark.slow
def test_certify_uncertified_point_exits_1(tmp_path):
    result = runner.invoke(app, ["certify", str(write(tmp_path, setter("gains.k_xi", 0.5)))])
    assert result.exit_code == 1 and "k_xi <= S_xi^2/2" in result.stdout


@pytest.mark.slow
def test_certify_required_gamma_exits_1(tmp_path):
    result = runner.invoke(app, ["certify", str(write(tmp_path, setter("certify.gamma", 0.1))), "--json", "-"])
    assert result.exit_code == 1 and "exceeds the required bound" in json.loads(result.stdout)["points"][0]["reason"]


def test_certify_bad_region_is_exit_2(tmp_path):
    result = runner.invoke(app, ["certify", str(write(tmp_path, setter("certify.theta_max_deg", 270.0)))])
    assert result.exit_code == 2 and result.stderr.startswith("error: certify.theta_max_deg")


@pytest.mark.slow
def test_synthesize_writes_a_scenario_that_certifies(tmp_path):
    """Within bounds whose optimum the UR5 can run (a design exceeding a limit is refused), the
    file written certifies at the gamma synthesised, and its run is stated against the limits."""
    target = tmp_path / "syn.toml"
    bounds = {"k_xi": [1.0, 5.0], "k_c": [0.1, 2.0], "k_e": [0.1, 10.0]}
    result = runner.invoke(app, ["synthesize", str(write(tmp_path, setter("synthesize", bounds))), "--out",
                                 str(target), "--json", "-"])  # fmt: skip
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    limits = record["limits"]
    assert limits["within_effort"] and all(r <= 1 for r in limits["torque_ratio"]) and len(limits["effort_limit"]) == 6
    check = runner.invoke(app, ["certify", str(target), "--json", "-"])
    assert check.exit_code == 0
    assert json.loads(check.stdout)["points"][0]["gamma"] == pytest.approx(record["point"]["gamma"], rel=1e-9)


@pytest.mark.slow
def test_target_speed_synthesis_reports_the_written_designs_certified_speed(tmp_path):
    """``objective = "target_speed"``: the speed reported is the envelope that ``certify``
    computes for the file written (the ordinary route), not the synthesis' own value."""
    bounds = {"objective": "target_speed", "k_xi": [1.0, 5.0], "k_c": [0.1, 2.0], "k_e": [0.1, 10.0]}
    target = tmp_path / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(write(tmp_path, setter("synthesize", bounds))), "--out",
                                 str(target), "--json", "-"])  # fmt: skip
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    check = runner.invoke(app, ["certify", str(target), "--json", "-"])
    assert check.exit_code == 0
    speed = json.loads(check.stdout)["points"][0]["envelope"]["max_target_speed"]
    assert record["max_target_speed"] is not None and record["max_target_speed"] == speed


@pytest.mark.slow
def test_verify_passes_and_writes_json(tmp_path):
    """The default example (the loop as a UR5 runs it) over 4 s: every claim holds."""
    out = tmp_path / "v"
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["simulation"]["duration"] = 4.0
    scenario = tmp_path / "default.toml"
    scenario.write_text(tomli_w.dumps(data))
    result = runner.invoke(app, ["verify", str(scenario), "--out", str(out), "--json", "-"])
    assert result.exit_code == 0, result.output
    data = json.loads((out / "verification.json").read_text())
    assert data["summary"]["failed"] == 0 and all(c["status"] in ("PASS", "MEASURED") for c in data["claims"])


@pytest.mark.slow
def test_verify_short_horizon_fails_convergence(tmp_path):
    """0.2 s is too short for x -> 0: verify says FAIL and exits 1; the idealised law's torque
    exceeds the UR5's wrist effort limit, also a FAIL. At 80 columns the human table fits, every
    status whole; each FAIL's reason follows it in full, and the verdict line counts them."""
    out = tmp_path / "v"
    result = runner.invoke(app, ["verify", str(write(tmp_path)), "--out", str(out)], env={"COLUMNS": "80"})
    assert result.exit_code == 1
    claims = json.loads((out / "verification.json").read_text())["claims"]
    assert [c["claim"] for c in claims if c["status"] == "FAIL"] == ["x -> 0", "torques within effort limits"]
    lines = result.stdout.splitlines()
    assert max(len(line) for line in lines) <= 80 and "\u2026" not in result.stdout, result.stdout
    statuses = [s for line in lines for s in re.findall(r"\u2502 (\w+) +\u2502", line) if s.isupper()]
    assert len(statuses) == len(claims) and set(statuses) <= {"PASS", "FAIL", "INCONCLUSIVE", "MEASURED"}, statuses
    reason = next(c["detail"] for c in claims if c["claim"] == "x -> 0")
    assert f"FAIL x -> 0: {reason}" in lines, lines
    assert "2 claim(s) FAIL" in result.stdout


def test_ctrl_c_inside_a_c_extension_counts_as_an_interrupt():
    """Native code reports Ctrl-C its own way (CasADi: a SystemError caused by it; Clarabel:
    InterruptedError): both are interrupts (exit 130 and how to resume); other errors are not."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as cause:
            raise SystemError("returned a result with an exception set") from cause
    except SystemError as wrapped:
        assert interrupted(wrapped)
    assert interrupted(InterruptedError("Clarabel's way"))
    assert not interrupted(SystemError("other")) and not interrupted(ValueError("bad"))


def test_ctrl_c_swallowed_by_native_code_is_remembered():
    """CVODES inside CasADi turns Ctrl-C into a failed right-hand side (a RuntimeError): within
    interrupt_aware the signal itself is remembered, so that error counts as an interrupt."""
    failure = RuntimeError("CV_RHSFUNC_FAIL")
    with interrupt_aware():
        assert not interrupted(failure)
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
        assert interrupted(failure)
    assert not interrupted(failure)


def test_simulate_shows_the_true_tracking_error_first(tmp_path):
    """The summary leads with the true tracking error g_d^-1 g (position and angle, from the
    relative pose g, not the estimate gbar), then e_c and e_e, each labelled."""
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(write(tmp_path)), "--out", str(out)])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stdout.splitlines() if "error" in line]
    assert "tracking error g_d^-1 g" in lines[0] and "e_c" in lines[1] and "e_e" in lines[2], lines
    final = json.loads((out / "summary.json").read_text())["summary"]["final"]
    with np.load(out / "trajectory.npz") as data:
        g = data["g"][-1].reshape(4, 4, order="F")
    g_d = np.eye(4)
    g_d[:3, 3] = scenario_dict()["reference"]["xyz"]  # reference rpy = 0
    error = np.linalg.solve(g_d, g)
    angle = np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1, 1)))
    assert final["tracking_position"] == pytest.approx(np.linalg.norm(error[:3, 3]), rel=1e-9)
    assert final["tracking_angle_deg"] == pytest.approx(angle, rel=1e-9, abs=1e-9)


@pytest.mark.slow
def test_native_solver_text_never_reaches_the_user(tmp_path):
    """A run whose step size collapses (the planar arm stretched into its elbow singularity with
    the singularity stop off): SUNDIALS' own lines ("At t = ..., the error test failed ...")
    stay out of stderr; the user reads one line of ours."""
    data = tomllib.loads((EXAMPLES / "planar2dd_reduced.toml").read_text())
    data["simulation"].update(jit=False, sigma_min=0.0, duration=1.0)
    data["camera"] = {"focal_length": data["camera"]["focal_length"]}
    data["target"].update(xyz=[0.72, 0.20, -0.45], motion={"kind": "static"})
    path = tmp_path / "reach.toml"
    path.write_text(tomli_w.dumps(data))
    proc = subprocess.run([sys.executable, "-m", "dvfc.analysis", "simulate", str(path), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True)  # fmt: skip
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith("run stopped: CVODES stopped"), lines


def test_urdf_with_control_tags_builds_silently(tmp_path, capfd):
    """A URDF with ros2_control, transmission and gazebo elements: the parser prints nothing."""
    text = (Path(__file__).parent / "data" / "light_wrist6.urdf").read_text()
    extra = """<ros2_control name="arm" type="system"><hardware><plugin>mock</plugin></hardware></ros2_control>
      <transmission name="t"><type>transmission_interface/SimpleTransmission</type></transmission>
      <gazebo reference="tool0"><material>Gazebo/Grey</material></gazebo></robot>"""
    urdf = tmp_path / "tagged.urdf"
    urdf.write_text(text.replace("</robot>", extra))
    assert Robot(urdf, "tool0").n == 6
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""


def on_the_axis(data):
    """The target placed 0.35 m straight ahead of the camera at q0, facing it."""
    for key in ("xyz", "rpy"):
        data["target"].pop(key)
    data["target"]["relative_to_camera"] = {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}


def test_target_placed_relative_to_the_camera(tmp_path):
    """``relative_to_camera`` gives g(0) itself: ``dvfc pose`` prints the camera pose at q0 and
    the square of side 0.1 m at depth 0.35 m centred in the 1280 x 1024 image, 800 * 0.05 / 0.35
    px from the centre on each axis."""
    result = runner.invoke(app, ["pose", str(write(tmp_path, on_the_axis)), "--json", "-"])
    assert result.exit_code == 0, result.output
    view = json.loads(result.stdout)
    assert np.allclose(view["target_in_camera"]["xyz"], [0.0, 0.0, 0.35], atol=1e-12)
    assert np.allclose(view["target_in_camera"]["rpy"], 0.0, atol=1e-12)
    offset = 800 * 0.05 / 0.35
    expected = np.array([[640 + offset, 512 + offset], [640 - offset, 512 + offset], [640 - offset, 512 - offset],
                         [640 + offset, 512 - offset]])  # fmt: skip
    assert np.allclose([f["image"] for f in view["features"]], expected, atol=1e-9)
    robot = Robot(builtin_urdf("ur5"), "tool0")
    g_wc = np.asarray(cs.Function("g", [robot.q], [robot.camera_pose.as_matrix()])(scenario_dict()["robot"]["q0"]))
    assert np.allclose(view["camera_in_world"]["xyz"], g_wc[:3, 3], atol=1e-12)


def test_pose_shows_a_target_out_of_view(tmp_path):
    """A target 0.5 m to the camera's side is bad input for a run, but ``pose`` shows where its
    points land (exit 1, the points marked out of view)."""
    def aside(data):
        on_the_axis(data)
        data["target"]["relative_to_camera"]["xyz"] = [0.5, 0.0, 0.35]

    path = write(tmp_path, aside)
    refused = runner.invoke(app, ["simulate", str(path)])
    assert refused.exit_code == 2 and "dvfc pose shows where every point lands" in refused.stderr
    result = runner.invoke(app, ["pose", str(path)], env={"COLUMNS": "200"})
    assert result.exit_code == 1 and "NO" in result.stdout and "u [px]" in result.stdout, result.output


def test_target_placed_twice_is_refused(tmp_path):
    result = runner.invoke(app, ["pose", str(write(tmp_path, setter("target.relative_to_camera.xyz", [0, 0, 0.3])))])
    assert result.exit_code == 2 and "give either xyz/rpy (world frame) or relative_to_camera" in result.stderr


def test_help_texts_print_every_bracketed_word():
    """Every command's help prints its text as written: no ``[grid]``, ``[certify]`` or other
    bracketed word swallowed as markup, and flags not shown as ``<bool>``."""
    from dvfc.reports.cli import app as full_app

    commands = typer.main.get_command(full_app).commands
    assert {"simulate", "certify", "verify", "synthesize", "report", "pose"} <= set(commands)
    for name, command in commands.items():
        result = runner.invoke(full_app, [name, "--help"], env={"COLUMNS": "100"})
        assert result.exit_code == 0, result.output
        printed = " ".join(result.stdout.split())
        texts = [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]
        words = {w for text in texts for w in re.findall(r"\[[A-Za-z_.]+\]", text)}
        assert all(w in printed for w in words), (name, words - {w for w in words if w in printed})
        assert "<bool>" not in printed, name
    assert "[grid]" in " ".join(runner.invoke(full_app, ["certify", "--help"]).stdout.split())


@pytest.mark.slow
def test_synthesize_keeps_the_users_file_and_certifies_the_rounded_gains(tmp_path):
    """The written scenario is the user's file, comments and layout kept, with only the name and
    the gains changed (one line each, 3-8 significant figures, no ``19.99999997``); the gamma
    reported is the certificate of exactly those rounded values. (The bounds keep the design
    within the arm's limits and certified as implemented, so that it is written at all.)"""
    bounds = "\n[synthesize]\nk_xi = [1.0, 5.0]\nk_c = [0.1, 2.0]\nk_e = [0.1, 10.0]\n"
    original = DEFAULT_SCENARIO_TEXT + bounds
    scenario = tmp_path / "commented.toml"
    scenario.write_text(original)
    target = tmp_path / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(scenario), "--out", str(target), "--json", "-"])
    assert result.exit_code == 0, result.output
    before, after = original.splitlines(), target.read_text().splitlines()
    changed = [(a, b) for a, b in zip(before, after, strict=True) if a != b]
    assert [b.split(" = ")[0] for _, b in changed] == ["name", "k_xi", "k_c", "k_e"], changed
    gains = tomllib.loads(target.read_text())["gains"]
    written = {key: gains[key] for key in ("k_xi", "k_c", "k_e")}
    assert gains["k_i_factor"] == 10.0  # the integral action kept: K_I = 10 K_xi at the written K_xi
    assert all(float(f"{v:.8g}") == v and len(repr(v)) <= 10 for key in written for v in written[key])
    record = json.loads(result.stdout)
    assert record["point"]["gains"] == written
    again = json.loads(runner.invoke(app, ["certify", str(target), "--no-lower-bounds", "--json", "-"]).stdout)
    assert again["points"][0]["gamma"] == record["point"]["gamma"]


def test_simulate_progress_lines_without_a_terminal(tmp_path, monkeypatch):
    """Standard error not a terminal: plain progress lines of simulated time (here at every
    chunk), ending at the horizon, and no bar's control characters."""
    monkeypatch.setattr(console_module, "PROGRESS_EVERY", 0.0)
    result = runner.invoke(app, ["simulate", str(write(tmp_path)), "--out", str(tmp_path / "o")])
    assert result.exit_code == 0, result.output
    lines = result.stderr.splitlines()
    assert lines and all(line.startswith("simulate ") for line in lines), lines
    assert "0.2 / 0.2 s (100%)" in lines[-1] and "\x1b" not in result.stderr
