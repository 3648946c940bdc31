"""Singularities: the run stops with the time, the matrix and its value instead of
producing NaNs; ``verify`` reports it; a singular start is bad input."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from dvfc.analysis.case import Case
from dvfc.analysis.results import verification_result
from dvfc.analysis.scenario import ScenarioError, build, load
from dvfc.analysis.simulate import Simulator, conditioning_of

from helpers import build_loop

EXAMPLE = Path(__file__).parent.parent / "examples" / "planar2dd_reduced.toml"


def planar(tmp_path: Path, **robot_or_target) -> Path:
    """The planar testbed with the target (or arm) moved, without JIT."""
    data = tomllib.loads(EXAMPLE.read_text())
    data["simulation"]["jit"] = False
    for section, values in robot_or_target.items():
        data[section].update(values)
    path = tmp_path / "planar.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def out_of_reach(tmp_path: Path) -> Case:
    """Target at rest 0.75 m from the shoulder, beyond the arm's 0.70 m reach, in view from the
    start (q0 = [-0.15, 1.0], tip 0.62 m out): the law stretches the arm into its elbow
    singularity. The arm crosses from sigma_min = 0.025 to singular within one 10 ms output
    step, so the stop threshold is raised to 0.05 to catch it at an output step."""
    return Case.load(planar(tmp_path, robot={"q0": [-0.15, 1.0]}, simulation={"sigma_min": 0.05},
                            target={"xyz": [0.72, 0.20, -0.45], "motion": {"kind": "static"}}))  # fmt: skip


def test_run_stops_at_the_singularity(tmp_path):
    case = out_of_reach(tmp_path)
    settings = case.settings
    traj = Simulator(case.loop, settings).run(case.s0)
    sigma = traj["sigma_min_arm_jacobian"][:, 0]
    assert traj.status == "singular" and traj.t[-1] < settings.duration
    assert "J_p is near-singular" in traj.message and f"t = {traj.t[-1]:.4g} s" in traj.message
    assert sigma[-1] < settings.sigma_min <= sigma[:-1].min()
    assert all(np.all(np.isfinite(v)) for v in traj.signals.values())


def test_verify_reports_the_singularity(tmp_path):
    result = verification_result(out_of_reach(tmp_path), {})
    claim = next(c for c in result.claims if c.name.startswith("no singularity"))
    assert claim.status == "FAIL" and "near-singular" in claim.detail


def test_wrist_singularity_of_the_ur5_is_detected():
    """At ``q_5 = 0`` the UR5's wrist axes 4 and 6 align: ``sigma_min(J_b)`` vanishes (below
    1e-12: the SVD resolves it to ``eps sigma_max(J_b)`` ~ 1e-16, ``sigma_max`` ~ 1)."""
    loop, s0, settings = build_loop()
    simulator = Simulator(loop, settings)
    singular = s0.copy()
    singular[4] = 0.0
    sigma, _ = simulator.conditioning(np.zeros(2), np.stack([s0, singular], axis=1))
    assert sigma[0] > 0.1 and sigma[1] < 1e-12


def test_singular_start_is_bad_input(tmp_path):
    spec, base = load(planar(tmp_path, robot={"q0": [0.3, 0.0]}, target={"xyz": [0.67, 0.21, -0.45]}))  # in view
    with pytest.raises(ScenarioError, match=r"^robot.q0: J_p is near-singular at q0 \(sigma_min = "):
        build(spec, base)


def test_conditioning_of_a_diverged_sample_is_nan_not_a_crash():
    """A diverged run's last samples can hold infinite Jacobians: their conditioning is NaN and the
    finite samples keep their singular values (to the SVD's round-off, a few eps)."""
    arm, image = np.diag([3.0, 2.0]), np.diag([4.0, 1.0, 2.0])[:, :2]
    row = np.concatenate([arm.ravel(order="F"), image.ravel(order="F")])
    flat = np.stack([row, np.full_like(row, np.inf)])
    sigma, cond = conditioning_of(flat, ((2, 2), (3, 2)))
    assert sigma[0] == pytest.approx(2.0, rel=1e-14) and cond[0] == pytest.approx(4.0, rel=1e-14)
    assert np.isnan(sigma[1]) and np.isnan(cond[1])
