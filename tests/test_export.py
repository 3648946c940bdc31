"""``dvfc export``: the C controller generated from the program's CasADi graph, equal to the Python
step bit for bit (replayed and in closed loop), safe on bad input, and the command's outputs."""

from __future__ import annotations

import hashlib
import json
import math
import re
import shutil
import subprocess
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

import dvfc
from dvfc.analysis.cli import app
from dvfc.analysis.controller import Controller
from dvfc.analysis.export import (
    CLOSED_LOOP_TOLERANCE,
    NO_COMPILER,
    TORQUE_TOLERANCE,
    Check,
    build,
    check,
    compiled_controller,
    generate,
    program_digest,
    replay,
    running_controller,
)
from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.analysis.sil import SilRun, software_in_the_loop
from dvfc.analysis.simulate import RunStatus
from dvfc.models.robot import builtin_urdf

runner = CliRunner()
EXAMPLES = Path(__file__).parent.parent / "examples"


@pytest.fixture(scope="module")
def case():
    return dvfc.load(DEFAULT_SCENARIO)


@pytest.fixture(scope="module")
def exported(case, tmp_path_factory):
    return generate(case, tmp_path_factory.mktemp("ur5"))


SEVEN_JOINTS = Path(__file__).parent / "data" / "xarm7_sampled.toml"
"""The xArm 7 as implemented at 2 kHz (the file says why)."""


def user_arm_scenario(folder: Path) -> Path:
    """:data:`SEVEN_JOINTS` with its arm read from a user's URDF file (the xArm 7's, copied into
    ``folder``)."""
    data = tomllib.loads(SEVEN_JOINTS.read_text())
    shutil.copy(builtin_urdf("xarm7"), folder / "my_arm.urdf")
    del data["robot"]["model"]
    data["robot"]["urdf"] = "my_arm.urdf"
    path = folder / "xarm7.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_export_writes_the_documented_files_with_nothing_beyond_libm(exported, case):
    """The folder holds the API, the generated step, the Makefile, README, replay and the ROS 2
    example; the step's sources include only math.h (and the API's own headers), allocate nothing
    and do no I/O; the header states the sizes."""
    names = {f.name for f in exported.files}
    assert names == {"dvfc_controller.h", "dvfc_controller.c", "dvfc_program.c", "dvfc_program.h", "Makefile",
                     "README.md", "dvfc_timing.c", "replay.c", "ros2_control_example.cpp"}  # fmt: skip
    assert all(f.is_file() for f in exported.files)
    for name in ("dvfc_controller.c", "dvfc_program.c"):
        text = (exported.directory / name).read_text()
        includes = set(re.findall(r"#include\s+[<\"]([^>\"]+)[>\"]", text))
        assert includes <= {"math.h", "dvfc_controller.h", "dvfc_program.h"}, includes
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf|fprintf|fopen|pthread_\w+)\s*\(", text)
    header = exported.api.read_text()
    assert f"#define DVFC_STATE_SIZE {exported.state_size}" in header
    assert "#define DVFC_N_JOINTS 6" in header and "#define DVFC_N_FEATURES 8" in header


@pytest.mark.slow
def test_compiled_step_equals_the_python_step_on_random_inputs_near_the_operating_point(case, exported, rng):
    """``dvfc.controller(case).step`` and the C step from the same state: the same torque and state
    bits over 200 random steps (joints 0.05 rad and 0.2 rad/s about the start, an image of the start
    with 2 px noise every third step)."""
    python = dvfc.controller(case)
    compiled = compiled_controller(case, exported)
    n = python.n
    x = python.initial_state()
    assert np.array_equal(x, compiled.initial_state())
    features = reference_features(case)
    for k in range(200):
        q, qd = case.s0[:n] + 0.05 * rng.standard_normal(n), 0.2 * rng.standard_normal(n)
        image = features + 2 * rng.standard_normal(8) if k % 3 == 0 else None
        tau_p, x_p = python.step(x, k * python.period, q, qd, image, k)
        tau_c, x_c = compiled.step(x, k * python.period, q, qd, image, k)
        assert np.array_equal(tau_p, tau_c) and np.array_equal(x_p, x_c), k
        x = x_p


def reference_features(case) -> np.ndarray:
    import casadi as cs

    loop = case.loop
    return np.asarray(cs.Function("f", [loop.t, loop.state], [loop.features])(0.0, case.s0)).ravel()


@pytest.mark.slow
@pytest.mark.parametrize("bad", ["nan_q", "inf_qd", "null_q", "nan_features", "far_capture"])
def test_compiled_step_returns_a_finite_safe_torque_and_a_code_on_bad_input(case, exported, bad):
    """In C as in Python: a NaN ``q``, an infinite ``qd`` or a NULL ``q`` give code 2 and gravity
    compensation; NaN features or a capture outside the ring give code 1 and the law's torque; never
    a non-finite torque."""
    python, compiled = Controller(case), compiled_controller(case, exported)
    n, x = python.n, python.initial_state()
    q, qd, features, capture = case.s0[:n].copy(), np.full(n, 0.05), reference_features(case), 0
    if bad == "nan_q":
        q[0] = np.nan
    elif bad == "inf_qd":
        qd[3] = np.inf
    elif bad == "nan_features":
        features[1] = np.nan
    elif bad == "far_capture":
        capture = 500
    if bad == "null_q":
        tau = np.zeros(n)
        ptr = compiled._p
        state = x.copy()
        code = compiled.lib.dvfc_step(ptr(state), 0.0, None, ptr(qd), ptr(features), capture, ptr(tau))
        expected = python.evaluate(x, 0.0, np.full(n, np.nan), qd, features, capture)
    else:
        tau, _ = compiled.step(x, 0.0, q, qd, features, capture)
        code = compiled.last_status
        expected = python.evaluate(x, 0.0, q, qd, features, capture)
    assert code == int(expected.status) == (2 if bad in ("nan_q", "inf_qd", "null_q") else 1)
    assert np.isfinite(tau).all() and np.array_equal(tau, expected.tau)


LIBM = {"sin", "cos", "sincos", "tan", "sqrt", "fmod", "fmin", "fmax", "fabs", "floor", "ceil", "exp", "log",
        "atan2", "asin", "acos", "atan", "pow", "tanh", "sinh", "cosh"}  # fmt: skip


@pytest.mark.slow
def test_the_compiled_library_needs_nothing_beyond_libm(exported):
    """The built library's undefined symbols (``nm -u``, weak ones aside) are libm functions only:
    no allocator, no I/O, no locks (the timing file's ``clock_gettime`` aside)."""
    if shutil.which("nm") is None:
        pytest.skip("nm needed")
    listing = subprocess.run(["nm", "-u", str(build(exported))], check=True, capture_output=True, text=True).stdout
    needed = {line.split()[-1].split("@")[0] for line in listing.splitlines() if line.split()[0] != "w"}
    assert needed - {"clock_gettime"} <= LIBM, needed


@pytest.mark.slow
def test_a_null_state_or_torque_is_refused(case, exported):
    """``dvfc_step`` with a NULL state or torque returns -1 and writes nothing."""
    compiled = compiled_controller(case, exported)
    n = compiled.n
    q, qd, tau = (np.zeros(n) for _ in range(3))
    p = compiled._p
    assert compiled.lib.dvfc_step(None, 0.0, p(q), p(qd), None, -1, p(tau)) == -1
    state = compiled.initial_state()
    assert compiled.lib.dvfc_step(p(state), 0.0, p(q), p(qd), None, -1, None) == -1
    assert np.array_equal(state, compiled.initial_state())


def assert_check(case, exported, duration: float) -> None:
    result, reference = check(case, exported, duration)
    assert reference.status == "ok"
    assert result.samples == round(duration * case.settings.implementation.control_rate)
    assert result.max_rel_torque_difference <= TORQUE_TOLERANCE
    assert result.closed_loop_max_state_difference <= CLOSED_LOOP_TOLERANCE
    assert result.passed


def sil_run(samples: int, tau: np.ndarray, status: RunStatus = RunStatus.OK) -> SilRun:
    """A stand-in software-in-the-loop run of two joints at 500 Hz: ``samples`` control samples with
    the torques ``tau`` (``samples x 2``), smooth joints at every sample ``k <= samples`` (one more when
    it completes), no image."""
    t = np.arange(samples + (status is RunStatus.OK)) / 500.0
    q = np.column_stack([np.sin(t), 0.5 * np.cos(2 * t)])
    return SilRun(t=t, q=q, qd=np.gradient(q, t, axis=0), tau=tau[:samples], captures=np.full(samples, -1),
                  features=np.zeros((samples, 8)), states=np.zeros((samples, 3)), status=status,
                  message="" if status is RunStatus.OK else "stopped")  # fmt: skip


STAND_IN_TORQUES = np.column_stack([100.0 * np.cos(np.arange(50) / 10), 0.01 + 0.005 * np.sin(np.arange(50) / 7)])
"""50 samples of two joints' torques: one of up to 100 N m, one of 0.005 to 0.015 N m (1e-4 of the peak)."""


@pytest.mark.parametrize(("off", "passes"), [(3e-13, True), (1e-11, False)], ids=["3e-13", "1e-11"])
def test_each_torque_is_compared_relative_to_itself(off, passes):
    """The replay's statistic (``dvfc export --check``): a compiled step whose torque on the small joint is
    off by ``off`` of that torque, the loop it closes the same. 3e-13 of each torque (a thousand ulps)
    is within the tolerance; 1e-11 is not, though it is 1e-15 of the run's peak torque: a small
    torque is the program's as much as a large one."""
    reference = sil_run(50, STAND_IN_TORQUES)
    compiled = STAND_IN_TORQUES * [1.0, 1.0 + off]
    check = Check.of(Path("inputs.csv"), reference, compiled, reference)
    assert check.max_rel_torque_difference == pytest.approx(off, rel=1e-3)
    assert check.max_abs_torque_difference == pytest.approx(off * np.abs(STAND_IN_TORQUES[:, 1]).max(), rel=1e-3)
    assert check.samples == 50 and check.closed_loop_max_state_difference == 0.0
    assert check.passed is passes and (check.max_rel_torque_difference <= TORQUE_TOLERANCE) is passes


@pytest.mark.parametrize(
    ("stopped", "shift", "difference"),
    [("closed", (0.0, 0.0), math.inf), ("reference", (0.0, 0.0), math.inf), (None, (0.0, 2e-9), 2e-9),
     (None, (5e-10, 0.0), 5e-10)],
    ids=["the compiled step's loop stops early", "the Python step's loop stops early", "speeds off 2e-9",
         "positions off 5e-10"],
)  # fmt: skip
def test_the_closed_loop_is_the_same_only_when_both_runs_complete_alike(stopped, shift, difference):
    """The closed loop's statistic: the largest difference of the joint positions and speeds between the
    loop the compiled step closes and the Python step's, with the torques replayed identical. A loop
    that stopped early (a feature out of view) where the other went on is not the same loop: its
    difference is infinite, never the 0 of the samples both have; a difference in the speeds alone
    counts as one in the positions, against :data:`CLOSED_LOOP_TOLERANCE` (1e-9)."""
    complete = sil_run(50, STAND_IN_TORQUES)
    early = sil_run(40, STAND_IN_TORQUES, RunStatus.OUT_OF_VIEW)
    reference = early if stopped == "reference" else complete
    closed = early if stopped == "closed" else replace(complete, q=complete.q + shift[0], qd=complete.qd + shift[1])
    check = Check.of(Path("inputs.csv"), reference, reference.tau, closed)
    assert check.max_rel_torque_difference == 0.0
    assert check.closed_loop_max_state_difference == pytest.approx(difference, rel=1e-6)
    assert check.passed is (difference <= CLOSED_LOOP_TOLERANCE)


@pytest.mark.slow
def test_check_replays_a_short_sil_run_through_the_compiled_step(case, exported):
    """``--check`` on the default UR5 over 0.1 s (50 samples, the first image among them): every
    torque of the C step within 1e-12 relative of the Python step's, and the loop it closes equal."""
    assert_check(case, exported, 0.1)


@pytest.mark.slow
def test_check_over_ten_seconds_on_the_default_ur5(case, exported):
    """The same over the scenario's 10 s (5000 samples, 600 images)."""
    assert_check(case, exported, 10.0)


@pytest.mark.slow
def test_check_over_two_seconds_on_a_seven_joint_arm_from_a_urdf_file(tmp_path):
    """The same on a 7-joint arm read from the user's URDF file over 2 s (2 kHz, 4000 samples: the long run's
    error growth is the UR5's 10 s test's to show; this one, that the arm's own code replays)."""
    user = dvfc.load(user_arm_scenario(tmp_path))
    assert_check(user, generate(user, tmp_path / "export"), 2.0)


@pytest.mark.slow
def test_replay_program_prints_the_python_torques(case, exported, tmp_path):
    """``make`` in the export folder builds ``replay``; on a recorded input file it prints the
    Python step's torques (17 significant digits: the doubles exactly) and the return codes."""
    if shutil.which("make") is None or shutil.which("cc") is None:
        pytest.skip("make and cc needed")
    run = software_in_the_loop(case, duration=0.1)
    from dvfc.analysis.export import write_inputs

    inputs = tmp_path / "inputs.csv"
    write_inputs(run, inputs)
    subprocess.run(["make", "-C", str(exported.directory), "replay"], check=True, capture_output=True)
    printed = subprocess.run([str(exported.directory / "replay"), str(inputs)], check=True, capture_output=True,
                             text=True).stdout  # fmt: skip
    rows = np.array([[float(v) for v in line.split(",")] for line in printed.splitlines()])
    python_taus, _ = replay(Controller(case).step, run, Controller(case).initial_state())
    assert np.array_equal(rows[:, 2:], python_taus) and np.all(rows[:, 1] == 0)


def test_export_json_lists_the_files_api_and_state(tmp_path):
    """``dvfc export --json -``: the files, the API header, the state size; no check asked, none run."""
    result = runner.invoke(app, ["export", str(DEFAULT_SCENARIO), "--out", str(tmp_path / "c"), "--json", "-"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    assert record["api"] == str(tmp_path / "c" / "dvfc_controller.h")
    assert len(record["files"]) == 9 and all(Path(f).is_file() for f in record["files"])
    assert record["state_size"] == Controller(dvfc.load(DEFAULT_SCENARIO)).layout.size
    assert record["check"] is None and record["timing"] is None
    assert record["sha256"] == program_digest(generate(dvfc.load(DEFAULT_SCENARIO), tmp_path / "again"))


@pytest.mark.parametrize(
    ("arguments", "field"),
    [
        (["export", "no/such.toml"], "no/such.toml"),
        (["export", str(EXAMPLES / "ur5_paper_ideal.toml")], "implementation"),
    ],
)
def test_export_bad_input_is_one_line_and_exit_2(tmp_path, arguments, field):
    """A missing scenario file, or one without ``[implementation]``: one line naming it, exit 2,
    nothing written."""
    result = runner.invoke(app, [*arguments, "--out", str(tmp_path / "c")])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0] and "Traceback" not in result.output
    assert not (tmp_path / "c").exists()


@pytest.mark.slow
def test_export_check_json_reports_the_check_and_the_timing(tmp_path):
    """``dvfc export --check --json -`` on the default scenario cut to 0.2 s: the check's samples and
    zero differences, the timing of 1e5 calls, the README saying what the check found."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["simulation"]["duration"] = 0.2
    scenario = tmp_path / "short.toml"
    scenario.write_text(tomli_w.dumps(data))
    result = runner.invoke(app, ["export", str(scenario), "--out", str(tmp_path / "c"), "--check", "--json", "-"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    assert record["check"]["samples"] == 100 and record["check"]["passed"]
    assert record["check"]["max_abs_torque_difference"] == 0.0
    assert record["check"]["closed_loop_max_state_difference"] == 0.0
    timing = record["timing"]
    assert timing["calls"] == 100_000 and 0 < timing["min_us"] <= timing["median_us"] <= timing["p999_us"]
    assert "100 samples, largest torque difference 0 N m" in (tmp_path / "c" / "README.md").read_text()
    assert (tmp_path / "c" / "sil_inputs.csv").is_file()


@pytest.mark.slow
def test_check_replays_the_integral_and_friction_compensated_program_bit_for_bit(tmp_path):
    """``--check`` on the default UR5 with ``K_I = 10 K_xi`` from 0.02 s, saturated efforts (the
    anti-windup acting) and a friction compensation, over 0.1 s: every torque of the C step equal to
    the Python step's, bit for bit, and the loop it closes equal."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["gains"].update(k_i_factor=10.0, integral_start=0.02,
                         friction_compensation={"viscous": 1.0, "coulomb": 0.5, "smoothing": 0.05})  # fmt: skip
    data["implementation"].update(saturate=True, torque_scale=0.004)
    data["simulation"]["jit"] = False
    path = tmp_path / "integral.toml"
    path.write_text(tomli_w.dumps(data))
    integral = dvfc.load(path)
    result, _ = check(integral, generate(integral, tmp_path / "c"), 0.1)
    assert result.samples == 50 and result.max_abs_torque_difference == 0.0
    assert result.closed_loop_max_state_difference == 0.0


def test_the_program_digest_names_the_program_and_nothing_beside_it(case, exported, tmp_path):
    """:func:`program_digest`: the SHA-256 of the program's four files (name, NUL, bytes); the same
    scenario exported again gives the same digest, other gains or one byte of the step another, the
    README not part of it."""
    expected = hashlib.sha256()
    for name in ("dvfc_controller.h", "dvfc_controller.c", "dvfc_program.h", "dvfc_program.c"):
        expected.update(name.encode() + b"\0" + (exported.directory / name).read_bytes())
    assert program_digest(exported) == expected.hexdigest()
    again = generate(case, tmp_path / "again")
    assert program_digest(again) == program_digest(exported)
    (again.directory / "README.md").write_text("edited")
    assert program_digest(again) == program_digest(exported)
    step = again.directory / "dvfc_program.c"
    step.write_bytes(step.read_bytes() + b"\n")
    assert program_digest(again) != program_digest(exported)
    other = generate(case.with_gains(k_c=2.0), tmp_path / "other")
    assert program_digest(other) != program_digest(exported)


def test_the_running_controller_says_why_when_there_is_no_compiler_or_no_program(case, tmp_path, monkeypatch):
    """:func:`running_controller` (the report's section) states a reason instead of a result: no C
    compiler on the PATH, or a scenario without ``[implementation]``; nothing is written."""
    without = dvfc.load(EXAMPLES / "ur5_paper_ideal.toml")
    assert running_controller(without, tmp_path / "a")["reason"].startswith("implementation:")
    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert running_controller(case, tmp_path / "b") == {"reason": NO_COMPILER}
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
