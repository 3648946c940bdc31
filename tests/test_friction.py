"""Joint friction in the certificates (docs/math.md, facts 18-19): the friction supply of the law with
compensation on ``qd_d`` on CVODES runs, the compensation never a velocity feedback, and the operating
envelope with the plant's friction (vacuous on the cell with the law unchanged, the frictionless one
recovered with an exact model)."""

from __future__ import annotations

from dataclasses import replace

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis.case import Case
from dvfc.analysis.results import envelope_record, statements

from helpers import build_loop, cell_with_default_design, run

NOMINAL = np.concatenate([[1.0, 1.0, 1.0, 0.1, 0.1, 0.1], [3.0, 3.0, 3.0, 0.56, 0.56, 0.56], [0.05]])
"""``[b; c; eps]`` of ``examples/ur5_cell.toml``'s plant."""
TWO_SIGMA = NOMINAL.copy()
TWO_SIGMA[11] = 0.56 * np.exp(0.6)  # wrist 3's Coulomb friction at +2 sigma


def friction_supply(plant: np.ndarray, model: np.ndarray):
    """The ideal continuous loop (CVODES, the target circling) with the plant's friction ``plant`` and the
    law's compensation ``model`` on ``qd_d``, 1 s: the run and the friction's supply ``xi^T (fhat(qd_d) -
    f(qd))`` (``w``'s torque, fact 19.2) at every output step."""
    loop, s0, settings = build_loop()
    loop = replace(loop, friction=plant, compensation=model)
    traj = run(loop, s0, settings, duration=1.0)
    assert traj.status == "ok", traj.message
    return traj, np.einsum("ti,ti->t", traj["xi"], traj["w"][:, : loop.robot.n])


@pytest.mark.slow
def test_fact_19_2a_exact_compensation_on_qd_d_makes_the_friction_dissipative():
    """(19.2a) With the exact model fed forward on ``qd_d`` the residual ``r = f(qd) - fhat(qd_d)`` has
    ``-xi^T r <= 0`` at every output step (by monotonicity of ``b v + c tanh(v/eps)``), and (43) holds with
    ``w``'s torque ``-r`` to 1e-8 relative. With the nominal model against the plant's +2 sigma wrist 3
    the same supply turns positive (+0.0098 W within 1 s): the sign is the model's, not the run's."""
    exact, supply = friction_supply(NOMINAL, NOMINAL)
    assert supply.max() <= 1e-12 and supply.min() < -1e-3
    v, i = exact["V"][:, 0], exact.integrals
    scale = max(v[0], np.abs(i["supply_x_G_w"]).max())
    assert np.abs(v - v[0] + i["dissipation_nu_K_nu"] - i["supply_x_G_w"]).max() <= 1e-8 * scale
    _, mismatched = friction_supply(TWO_SIGMA, NOMINAL)
    assert mismatched.max() > 1e-3


def test_compensation_reads_the_law_s_qd_d_never_the_measured_qd():
    """(19.2, 19.4) The compensation ``fhat(qd_d)`` does not depend on the measured ``qd`` (its Jacobian in
    ``qd`` is structurally zero: no velocity feedback, so no loss of fact 14 at rest) and equals
    ``bhat qd_d + chat tanh(qd_d/epshat)`` at a random state."""
    loop, s0, _ = build_loop()
    loop = replace(loop, compensation=NOMINAL)
    assert cs.jacobian(loop.compensation_torque, loop.qd).nnz() == 0
    rng = np.random.default_rng(19)
    s = s0 + 0.01 * rng.standard_normal(s0.shape)
    s[loop.quaternions[0]] /= np.linalg.norm(s[loop.quaternions[0]])
    comp, qd_d = cs.Function("c", [loop.t, loop.state], [loop.compensation_torque, loop.qd_d])(0.3, s)
    qd_d = np.asarray(qd_d).ravel()
    expected = NOMINAL[:6] * qd_d + NOMINAL[6:12] * np.tanh(qd_d / NOMINAL[12])
    assert np.allclose(np.asarray(comp).ravel(), expected, rtol=1e-14, atol=1e-15)


@pytest.fixture(scope="module")
def cell():
    return Case(*cell_with_default_design())


def test_fact_18_5_the_envelope_with_the_plant_s_friction_is_vacuous_on_the_cell(cell):
    """(18.5, unweighted) The cell's law without compensation: with ``|tau_d| <= |F_c| = 5.286`` N m the
    envelope is not self-consistent, ``c_inf = 6.087 > c_max = 0.00137`` at the frictionless envelope's
    ``theta_bar = 3`` deg; at fixed ``theta_bar`` ``c_inf`` is the frictionless one scaled by
    ``wbar^2`` (``c_inf = wbar^2 / (4 s kappa)``), which checks the number from the frictionless record.
    The statement says so, in the envelope record and in the statements table (NOT CERTIFIED)."""
    env = envelope_record(cell, search=False)
    f = env["friction"]
    assert not f["certified"] and f["torque_bound"] == pytest.approx(np.linalg.norm(NOMINAL[6:12]), rel=1e-12)
    assert f["c_inf"] == pytest.approx(env["ultimate_V"] * f["wbar"] ** 2 / env["wbar"] ** 2, rel=1e-9)
    assert f["c_inf"] == pytest.approx(6.087, abs=1e-3) and f["c_inf"] > f["c_max_sup"] > f["c_max"]
    assert "vacuous: c_inf = 6.087 > c_max = 0.00137" in env["statement"]
    rows = statements({"points": [{"certified": False, "reason": "-", "envelope": env}], "region": "-",
                       "loop": "paper"}, {"summary": {"failed": 0, "inconclusive": 0, "claims": 0}})  # fmt: skip
    row = next(r for r in rows if "friction" in r.statement)
    assert row.status == "NOT CERTIFIED" and "vacuous" in row.detail


@pytest.mark.slow
def test_fact_19_2a_an_exact_compensation_recovers_the_frictionless_envelope(cell):
    """(19.2a) With ``[gains] friction_compensation`` the plant's own model (viscous and Coulomb exact,
    the same smoothing) the residual's bound is 0 and no cross term is left: the friction record is
    CERTIFIED with the frictionless envelope's ``c_inf`` and bounds exactly. With the model's smoothing
    changed (0.06 rad/s) the residual's Coulomb bound is ``chat`` itself and it is vacuous again."""
    spec, base = cell_with_default_design()
    data = spec.model_dump()
    data["gains"]["friction_compensation"] = dict(data["plant"]["friction"])
    exact = envelope_record(Case(type(spec).model_validate(data), base), search=False)
    assert exact["friction"]["certified"] and exact["friction"]["bounds"] == exact["bounds"]
    assert exact["friction"]["c_inf"] == pytest.approx(exact["ultimate_V"], rel=1e-12)
    data["gains"]["friction_compensation"]["smoothing"] = 0.06
    blurred = envelope_record(Case(type(spec).model_validate(data), base), search=False)
    assert not blurred["friction"]["certified"] and blurred["friction"]["coulomb_bound"] == NOMINAL[6:12].tolist()
