"""docs/math.md, fact 28: the control period of a plant with dry friction, integrated by ROS34PW2 linearly implicit
in the friction (:mod:`dvfc.analysis.rosenbrock`), against an independent integrator (scipy's Radau), and the UR5
cell's wrist released from rest with one step a period against sixteen RK4 steps."""

from __future__ import annotations

from dataclasses import replace

import casadi as cs
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from dvfc.analysis.case import Case
from dvfc.analysis.implementation import Implementation
from dvfc.analysis.linearize import equilibrium_configuration
from dvfc.analysis.multirate import rest_model, rest_state
from dvfc.analysis.rosenbrock import ALPHA, COUPLING, EMBEDDED, GAMMA, WEIGHTS, w_step
from dvfc.analysis.sampled import SampledSimulator

from helpers import CELL

MASS, STIFFNESS = 0.02, 3.0
"""The toy joint: ``m qdd = tau(t) - d qd - k q`` with a third state ``z' = q + sin t`` outside ``W``."""


def toy_rate(t, s, damping):
    q, qd, _ = s[0], s[1], s[2]
    return [cs.vertcat(qd, (cs.sin(5 * t) - damping * qd - STIFFNESS * q) / MASS, q + cs.sin(t)), q * q]


def toy_steps(damping: float, slope: float, steps: int, horizon: float) -> np.ndarray:
    """The toy from ``[0.01, 0, 0]`` over ``horizon`` in ``steps`` ROS34PW2 steps whose ``W`` has the friction
    slope ``slope`` (the exact Jacobian's is ``damping``), and the quadrature of ``q^2``."""
    s0, t = cs.MX.sym("s", 3), cs.MX.sym("t")
    h = horizon / steps
    after, quad, _ = w_step(lambda time, state: toy_rate(time, state, damping), t, s0, h, 1, cs.MX(MASS), cs.MX(slope))
    step = cs.Function("step", [t, s0], [after, quad])
    s, total = np.array([0.01, 0.0, 0.0]), 0.0
    for i in range(steps):
        after, quad = step(i * h, s)
        s, total = np.asarray(after).ravel(), total + float(quad)
    return np.append(s, total)


def toy_numbers(t: float, y: np.ndarray, damping: float) -> list[float]:
    """:func:`toy_rate` in NumPy, for scipy: the three states' rates, then the quadrature's when ``y`` has it."""
    q, qd = y[0], y[1]
    rates = [qd, (np.sin(5 * t) - damping * qd - STIFFNESS * q) / MASS, q + np.sin(t)]
    return [*rates, q * q] if len(y) > 3 else rates


def toy_reference(damping: float, horizon: float) -> np.ndarray:
    """The same by scipy's Radau IIA at 1e-13 (the quadrature as a fourth state)."""
    return solve_ivp(toy_numbers, (0, horizon), [0.01, 0, 0, 0], method="Radau", rtol=1e-13, atol=1e-15,
                     args=(damping,)).y[:, -1]  # fmt: skip


@pytest.mark.parametrize("slope_factor", [1.0, 0.0, 3.0])
def test_fact_28_1_ros34pw2_is_of_order_3_whatever_its_w(slope_factor):
    """A W-method keeps its order whatever ``W`` approximates the Jacobian: on the non-stiff toy (damping 0.1,
    ``|lambda| h`` at most 0.16) the error against Radau falls 8-fold (``2^3``) when the step halves, with ``W``'s
    slope the exact one, none, or three times it (measured 7.2 to 8.4 from 40 to 80 and 80 to 160 steps)."""
    damping, horizon = 0.1, 0.5
    reference = toy_reference(damping, horizon)
    errors = [np.abs(toy_steps(damping, slope_factor * damping, k, horizon) - reference).max() for k in (40, 80, 160)]
    ratios = [errors[i] / errors[i + 1] for i in range(2)]
    assert all(6.5 < r < 10 for r in ratios), (errors, ratios)


def test_fact_28_2_one_step_is_stable_and_accurate_at_any_friction_slope():
    """With the friction slope over the inertia ``d / m`` from 200 to 2e7 1/s, one to 1e5 times the reach of a
    5 ms step (a smoothing width down to a ten-thousandth of the cell's), ten steps end within 2e-5 of the
    solution's size from Radau's (measured at most 3.4e-6, the error not growing with the slope: the joint
    stuck where the torque balances the friction), and halving the step brings them closer."""
    horizon = 0.05
    for damping in (4.0 * 10**k for k in range(0, 6)):
        reference = toy_reference(damping, horizon)[:3]
        errors = [np.abs(toy_steps(damping, damping, k, horizon)[:3] - reference).max() for k in (10, 20)]
        assert errors[0] < 2e-5 * np.abs(reference).max() and errors[1] < errors[0], (damping, errors)


def test_fact_28_3_the_tableau_is_l_stable_and_its_weights_consistent():
    """ROS34PW2's stability function ``R(z) = 1 + z b^T (I - z B)^-1 1`` (``B = alpha + Gamma``) is at most 1 in
    modulus on the closed left half-plane (sampled on rays and the imaginary axis) and vanishes at infinity
    (L-stable: a stiff mode is damped in one step); the weights and the embedded ones sum to 1."""
    b = np.array(WEIGHTS)
    full = np.zeros((4, 4))
    for i in range(4):
        full[i, :i] = np.array(ALPHA[i]) + np.array(COUPLING[i])
        full[i, i] = GAMMA
    stability = lambda z: 1 + z * b @ np.linalg.solve(np.eye(4) - z * full, np.ones(4))  # noqa: E731
    radii = np.logspace(-3, 8, 400)
    for angle in np.linspace(np.pi / 2, np.pi, 13):
        assert max(abs(stability(r * np.exp(1j * angle))) for r in radii) <= 1 + 1e-12, angle
    assert abs(stability(-1e12)) < 1e-9
    assert sum(WEIGHTS) == pytest.approx(1, abs=1e-15) and sum(EMBEDDED) == pytest.approx(1, abs=1e-15)


@pytest.mark.parametrize("damping", [0.1, 400.0])
def test_fact_28_4_the_embedded_estimate_measures_the_local_error(damping):
    """From states along the toy's path, one step's estimate ``sum (b_i - bhat_i) k_i`` is the embedded step's
    true local error (against Radau from the same state) to within a factor 3 (measured 0.94 to 0.97 on the
    non-stiff toy, 0.92 to 2.07 with a slope 100 times the step's reach), and at least the step's own (measured
    17 to 32 times it, and 1.9 to 17 times on the stiff one): a run's largest estimate bounds what one period
    adds to its error."""
    h = 0.005
    s0, t = cs.MX.sym("s", 3), cs.MX.sym("t")
    after, _, error = w_step(lambda time, state: toy_rate(time, state, damping), t, s0, h, 1, cs.MX(MASS),
                             cs.MX(damping))  # fmt: skip
    step = cs.Function("step", [t, s0], [after, error])

    def exact(t0, y0):
        return solve_ivp(toy_numbers, (t0, t0 + h), y0, method="Radau", rtol=1e-13, atol=1e-16,
                         args=(damping,)).y[:, -1]  # fmt: skip

    y = np.array([0.01, 0.0, 0.0])
    for k in range(6):
        got, estimate = (np.asarray(v).ravel() for v in step(k * h, y))
        truth = exact(k * h, y)
        embedded = np.abs(got - estimate - truth).max()
        assert embedded / 3 <= np.abs(estimate).max() <= 3 * embedded, (k, estimate, embedded)
        assert np.abs(got - truth).max() <= np.abs(estimate).max(), k
        y = got


def test_auto_integrates_dry_friction_by_ros34pw2_and_no_friction_by_rk4():
    """``integrator = "auto"`` (the default) takes ROS34PW2 for a plant with dry friction and RK4 otherwise;
    an explicit choice is kept; CVODES has no fixed steps."""
    imp = Implementation(control_rate=500.0, camera_rate=60.0)
    assert imp.integrator == "auto" and (imp.method(True), imp.method(False)) == ("rosenbrock", "rk4")
    for chosen in ("rk4", "rosenbrock"):
        assert replace(imp, integrator=chosen).method(True) == replace(imp, integrator=chosen).method(False) == chosen
    assert replace(imp, integrator="cvodes").method(True) is None


@pytest.fixture(scope="module")
def wrist_release():
    """The UR5 cell at rest with the target still, no pixel noise and no timing fault, wrist 3 released 1 mrad
    from ``q_eq`` with the cell's friction (Coulomb 0.56 N m on the wrists, eps 0.05 rad/s) and wrist 3's Coulomb
    ``c``: the joint's angle over 3 s and the run's ``stats``, run with the given integrator and substeps."""
    case = Case.load(CELL)
    loop, settings = case.loop, case.settings
    imp = replace(settings.implementation, pixel_noise=0.0, latency_jitter=0, frame_drop=0.0, outlier_probability=0.0)
    q_eq = equilibrium_configuration(loop, case.s0[: loop.robot.n])
    s0 = rest_state(loop, q_eq)
    s0[5] += 1e-3
    rest = rest_model(loop, loop.robot)

    def run(coulomb: float, integrator: str, substeps: int) -> tuple[np.ndarray, dict]:
        friction = np.array(settings.errors.coulomb, dtype=float)
        friction[5] = coulomb
        st = replace(settings, implementation=replace(imp, integrator=integrator, substeps=substeps), duration=3.0,
                     dt=0.002, errors=replace(settings.errors, coulomb=friction))  # fmt: skip
        traj = SampledSimulator(rest, st).run(s0)
        return traj["q"][:, 5] - q_eq[5], traj.stats

    return run


@pytest.mark.parametrize("coulomb", [1.251, 1.6])
def test_wrist_3_released_from_rest_with_one_step_a_period_matches_sixteen(wrist_release, coulomb):
    """Wrist 3 with 1.251 N m (draw 39 of the seed-0 cell campaign) and 1.6 N m of Coulomb friction, released
    1 mrad from rest: its smoothed slope over its inertia, 1500 and 1920 1/s, puts one RK4 step of 2 ms past
    RK4's stability limit (2.785), and RK4 with one step a period invents a limit cycle of several mrad (measured
    5.7 and 13.3 mrad from the reference); ROS34PW2 with one step (the default for a plant with dry friction)
    stays within 1e-6 rad of RK4 in sixteen steps (measured 2.9e-8 and 3.6e-8 rad) over 3 s, and states its
    largest local error of a period (measured 9e-10 rad), which is below that difference."""
    reference, _ = wrist_release(coulomb, "rk4", 16)
    assert np.abs(reference[-500:]).max() < 3e-4  # the joint settles (the integral action learns the friction)
    implicit, stats = wrist_release(coulomb, "auto", 1)
    assert np.abs(implicit - reference).max() < 1e-6 and stats["rosenbrock"] == 1
    assert 0 < stats["local_error_q"] < np.abs(implicit - reference).max()
    assert np.abs(wrist_release(coulomb, "rk4", 1)[0] - reference).max() > 1e-3
