"""Every example arm through ``simulate``, ``certify`` and ``verify``; where the paper's
guarantees hold (n = 6, n = 7) and where they stop (n = 2), measured."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.models.loop import pseudo_inverse
from dvfc.models.robot import Robot, builtin_urdf
from dvfc.reports.cli import app

EXAMPLES = Path(__file__).parent.parent / "examples"
runner = CliRunner()


def short(name: str, tmp_path: Path, duration: float = 10.0, **edits) -> Path:
    """The example ``name`` with the horizon ``duration``, compiled as the example is."""
    data = tomllib.loads((EXAMPLES / f"{name}.toml").read_text())
    data["simulation"].update(duration=duration)
    for section, values in edits.items():
        data.setdefault(section, {}).update(values)
    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def run(*args: str) -> tuple[int, dict]:
    result = runner.invoke(app, [*args, "--json", "-"])
    return result.exit_code, json.loads(result.stdout) if result.stdout.strip() else {}


@pytest.mark.parametrize("name", ["ur5_paper_ideal", "panda_circle", "puma560_circle", "planar2dd_reduced"])
def test_simulate_runs_and_keeps_the_identities(name, tmp_path):
    """Each arm tracks its target; Lemma 2's identity holds to integration accuracy."""
    code, result = run("simulate", str(short(name, tmp_path, 3.0)), "--out", str(tmp_path / "out"))
    s = result["summary"]
    assert code == 0 and s["status"] == "ok"
    assert s["identity_residuals"]["passivity"] < 1e-6 and s["identity_residuals"]["dissipation"] < 1e-6
    assert s["min_sigma_arm_jacobian"] > 1e-3


def test_paper_law_on_two_joints_simulates_without_its_identity(tmp_path):
    """n = 2: the run completes, but V(t) - V(0) = int (u^T nu + x^T G w) is off by far more
    than the integration error."""
    code, result = run("simulate", str(short("planar2dd_paper", tmp_path, 3.0)), "--out", str(tmp_path / "out"))
    s = result["summary"]
    assert code == 0 and s["status"] == "ok" and s["identity_residuals"]["passivity"] > 1e-3


@pytest.mark.parametrize("name", ["panda_circle", "puma560_circle", "planar2dd_reduced"])
def test_certify_each_arm(name, tmp_path):
    """Theorem 2 (P11 for the planar loop) is certified with the SDP cross-check."""
    code, result = run("certify", str(short(name, tmp_path)), "--no-lower-bounds")
    point = result["points"][0]
    assert code == 0 and point["certified"] and "cross-checked" in point["method"]
    assert point["margin"] >= 0 and point["gamma_tight"] <= point["gamma"]


LIMIT_CLAIMS = ("as implemented", "URDF <limit effort>", "URDF <limit velocity>")


@pytest.mark.parametrize("name", ["panda_circle", "puma560_circle", "planar2dd_reduced"])
@pytest.mark.slow
def test_verify_every_claim_of_the_paper_holds(name, tmp_path):
    """n = 7 (J_b pinv(J_b) = I_6 since J_b has full row rank), n = 6, and the reduced planar
    loop: every claim of the paper passes on simulation. Whether the run stays within the
    arm's limits is measured beside them and decides the exit status (the Panda and Puma
    examples' laws ask for more torque than their URDFs allow)."""
    code, result = run("verify", str(short(name, tmp_path)))
    paper = [c for c in result["claims"] if c["paper"] not in LIMIT_CLAIMS]
    limits = [c for c in result["claims"] if c["paper"] in LIMIT_CLAIMS]
    assert not [c for c in paper if c["status"] == "FAIL"]
    assert len(limits) == 3 and code == int(any(c["status"] == "FAIL" for c in limits))


@pytest.mark.slow
def test_default_example_is_a_loop_a_ur5_can_run(tmp_path):
    """The default example runs sampled (500 Hz torques, 60 Hz images 20 ms late, noisy
    pixels) within the UR5's effort and velocity limits for its whole run, every feature in
    its 1280 x 1024 image, and verify passes (the identity claims on the paper's loop, the
    limits on the run as implemented)."""
    data = tomllib.loads((EXAMPLES / "ur5_circle.toml").read_text())
    imp = data["implementation"]
    assert (imp["control_rate"], imp["camera_rate"], imp["latency"]) == (500.0, 60.0, 0.02)
    path = tmp_path / "ur5_circle.toml"
    path.write_text(tomli_w.dumps(data))
    code, result = run("simulate", str(path), "--out", str(tmp_path / "out"))
    assert code == 0 and result["summary"]["status"] == "ok"
    assert result["limits"]["within_effort"] and result["limits"]["within_velocity"]
    trajectory = np.load(tmp_path / "out" / "trajectory.npz")
    pixels = trajectory["f"].reshape(len(trajectory["t"]), -1, 2) + np.array([640.0, 512.0])
    assert np.all((pixels >= 0) & (pixels <= [1280.0, 1024.0]))
    code, result = run("verify", str(path))
    assert code == 0 and all(c["status"] in ("PASS", "MEASURED") for c in result["claims"])


@pytest.mark.slow
def test_redundant_arm_self_motion_is_bounded_by_xi(tmp_path):
    """n = 7: the null-space motion, invisible in x, is measured and stays below int |xi| dt."""
    _, result = run("verify", str(short("panda_circle", tmp_path, 5.0)))
    claim = next(c for c in result["claims"] if c["claim"].startswith("self-motion"))
    assert claim["status"] == "PASS" and claim["value"] > 0


def test_planar_certificates_sit_above_the_lower_bounds(tmp_path):
    """The planar loop's certified gammas (paper's P and scaled storage) are upper bounds on
    its L2 gain: both lie above the linearisation's peak gain and the gain of the
    nonlinear loop from rest. python-control's H-infinity norm (Hamiltonian bisection, stopped at
    1e-6 relative) agrees with the attained peak of the frequency sweep (exact here: the peak is
    at omega = 0, a grid point) to 1e-5 relative."""
    _, result = run("certify", str(short("planar2dd_reduced", tmp_path)))
    p = result["points"][0]
    assert p["gamma_lower_linear"] == pytest.approx(p["hinf_python_control"], rel=1e-5)
    assert p["gamma_lower_nonlinear"] <= p["gamma_lower"] == p["gamma_lower_linear"]
    assert p["gamma_lower"] <= p["gamma_tight"] <= p["gamma"]


def test_planar_image_estimate_is_exact(tmp_path):
    """(P12): with the camera's orientation known and every feature at a constant depth,
    ``pinv(A)(f - fbar)`` equals ``e_e`` to round-off, so the image loop is the ideal one."""
    _, result = run("verify", str(short("planar2dd_reduced", tmp_path)))
    gap = next(c for c in result["claims"] if c["paper"] == "(P12)" and "pinv(A)" in c["claim"])
    assert gap["status"] == "PASS" and gap["value"] < 1e-12


@pytest.mark.parametrize(
    ("name", "frame", "identity"), [("panda", "panda_link8", True), ("planar2dd", "camera_link", False)]
)
def test_pinv_of_the_body_jacobian_is_a_right_inverse_only_for_n_at_least_6(name, frame, identity, rng):
    """``J_b pinv(J_b) = I_6`` for the 7-joint Panda (full row rank): Lemma 2's cancellation
    holds. For the 2-joint testbed it is a rank-2 projector, not the identity."""
    arm = Robot(builtin_urdf(name), frame)
    f = cs.Function("f", [arm.q], [arm.body_jacobian @ pseudo_inverse(arm.body_jacobian)])
    for q in rng.uniform(-2.5, 2.5, (5, arm.n)):
        product = np.asarray(f(q))
        assert np.allclose(product, product @ product, rtol=0, atol=1e-10)  # a projector either way
        assert (np.abs(product - np.eye(6)).max() < 1e-10) == identity
        assert round(np.trace(product)) == min(arm.n, 6)


def test_paper_law_on_two_joints_is_not_certified(tmp_path):
    """n = 2: the certifier refuses (Lemma 2 does not hold), exit status 1, with the reason."""
    code, result = run("certify", str(short("planar2dd_paper", tmp_path)), "--no-lower-bounds")
    point = result["points"][0]
    assert code == 1 and not point["certified"] and point["gamma"] is None
    assert "n = 2 < 6" in point["reason"]


@pytest.mark.slow
def test_paper_law_on_two_joints_fails_its_identities(tmp_path):
    """n = 2: ``J_b pinv(J_b) != I``, so Lemma 2's identity and (43) fail by far more than the
    integration error (residuals above 1e-3, over a thousand times the 1e-6 the identities meet
    when they hold); the kinematic claims, which do not involve the arm, still hold."""
    code, result = run("verify", str(short("planar2dd_paper", tmp_path)))
    claims = {(c["paper"], c["claim"]): c for c in result["claims"]}
    assert code == 1
    for paper in ("Lemma 2, (40)-(41)", "Theorem 1, (43)", "(43) with w"):
        claim = next(c for (p, _), c in claims.items() if p == paper and c["claim"].startswith("V("))
        assert claim["status"] == "FAIL" and claim["value"] > 1e-3, claim
    assert all(c["status"] == "PASS" for (p, _), c in claims.items() if p.startswith(("remark", "Lemma 1")))


def test_planar_loop_rejects_a_rotating_target(tmp_path):
    path = short("planar2dd_reduced", tmp_path)
    text = path.read_text().replace('kind = "circle"', 'kind = "circle_spin"\nspin_rate = 0.5')
    path.write_text(text)
    result = runner.invoke(app, ["simulate", str(path)])
    assert result.exit_code == 2 and result.stderr.startswith("error: target.motion.kind: the planar loop")


def test_planar_grid_rejects_rotational_axes(tmp_path):
    data = tomllib.loads(short("planar2dd_reduced", tmp_path).read_text())
    data["grid"] = {"k_c": [1.0, 2.0], "k_e_r": [1.0, 2.0]}
    path = tmp_path / "grid.toml"
    path.write_text(tomli_w.dumps(data))
    result = runner.invoke(app, ["certify", str(path), "--out", str(tmp_path / "g")])
    assert result.exit_code == 2 and "grid.k_e_r: the planar loop" in result.stderr


def test_planar_grid_point_equals_single_certificate(tmp_path):
    """The planar grid's closed form gives the single-point certificate's gamma."""
    data = tomllib.loads(short("planar2dd_reduced", tmp_path).read_text())
    data["grid"] = {"k_c": [3.0], "k_e": [10.0]}
    path = tmp_path / "grid.toml"
    path.write_text(tomli_w.dumps(data))
    code, grid = run("certify", str(path), "--out", str(tmp_path / "g"))
    _, single = run("certify", str(short("planar2dd_reduced", tmp_path)), "--no-lower-bounds")
    assert code == 0 and grid["summary"]["gamma_min"] == pytest.approx(single["points"][0]["gamma"], rel=1e-12)


def test_user_urdf_by_path(tmp_path):
    """Any URDF works by path with the camera frame named; a missing frame is one line."""
    path = short("planar2dd_reduced", tmp_path, 1.0)
    data = tomllib.loads(path.read_text())
    data["robot"] = {"urdf": str(builtin_urdf("planar2dd")), "camera_frame": "camera_link", "q0": [0.3, 1.2]}
    path.write_text(tomli_w.dumps(data))
    code, result = run("simulate", str(path), "--out", str(tmp_path / "o"))
    assert code == 0 and result["summary"]["status"] == "ok"
    data["robot"]["camera_frame"] = "lens"
    path.write_text(tomli_w.dumps(data))
    result = runner.invoke(app, ["simulate", str(path)])
    assert result.exit_code == 2 and result.stderr.startswith("error: robot.camera_frame:")
    assert "'lens'" in result.stderr
