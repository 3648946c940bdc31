"""The controller as a discrete program (analysis/controller.py): its observer step (docs/math.md,
fact 22), the image of the capture time, the law of the sampled loop, and a finite torque for every
bad input."""

from __future__ import annotations

from dataclasses import replace

import casadi as cs
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import logm

import dvfc
from dvfc.analysis.controller import Status, observer_step
from dvfc.analysis.export import ExportError
from dvfc.analysis.sampled import SampledSimulator
from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.models.lie import SE3, quaternion_to_matrix


@pytest.fixture(scope="module")
def case():
    return dvfc.load(DEFAULT_SCENARIO)


@pytest.fixture(scope="module")
def controller(case):
    return dvfc.controller(case)


def twist_hat(v: np.ndarray) -> np.ndarray:
    w = v[3:]
    return np.array([[0, -w[2], w[1], v[0]], [w[2], 0, -w[0], v[1]], [-w[1], w[0], 0, v[2]], [0, 0, 0, 0.0]])


def matrix_of(state: np.ndarray) -> np.ndarray:
    """The homogeneous matrix of ``[pbar; quat]``."""
    g = np.eye(4)
    g[:3, :3] = np.asarray(cs.DM(quaternion_to_matrix(state[3:7])))
    g[:3, 3] = state[:3]
    return g


STEP = None


def stepped(state: np.ndarray, v_wc: np.ndarray, u_e: np.ndarray, h: float) -> np.ndarray:
    """:func:`observer_step` as a numeric function."""
    global STEP
    if STEP is None:
        p, q, v, u, period = (cs.SX.sym(name, k) for name, k in (("p", 3), ("q", 4), ("v", 6), ("u", 6), ("h", 1)))
        STEP = cs.Function("step", [p, q, v, u, period], [observer_step(p, q, v, u, period)])
    return np.asarray(STEP(state[:3], state[3:], v_wc, u_e, h)).ravel()


def exact_flow(g0: np.ndarray, v_wc, u_e, h: float) -> np.ndarray:
    """(12) integrated by an ODE solver: ``dg/dt = -hat(V_wc(t)) g + g hat(u_e(t))`` (matrix form)."""

    def rate(t, y):
        g = y.reshape(4, 4)
        return (-twist_hat(v_wc(t)) @ g + g @ twist_hat(u_e(t))).ravel()

    return solve_ivp(rate, (0.0, h), g0.ravel(), method="DOP853", rtol=1e-13, atol=1e-15).y[:, -1].reshape(4, 4)


def pose_distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(logm(np.linalg.solve(a, b))).max())


START = np.array([0.01, -0.02, 0.35, *SE3.from_xyz_rpy([0, 0, 0], [0.1, -0.2, 0.3]).position_quaternion()[3:]])


def test_observer_step_is_the_exact_flow_of_12_for_held_velocities():
    """With ``V_wc`` and ``u_e`` constant, ``exp(-h hat(V_wc)) gbar exp(h hat(u_e))`` solves (12):
    against DOP853 at 1e-13, within 1e-11 over a 0.1 s period (1 rad/s, 0.5 m/s); the quaternion
    stays unit to 1e-15."""
    v, u = np.array([0.3, -0.5, 0.2, 1.0, -0.4, 0.6]), np.array([0.05, 0.02, -0.03, 0.2, 0.1, -0.3])
    exact = exact_flow(matrix_of(START), lambda t: v, lambda t: u, 0.1)
    out = stepped(START, v, u, 0.1)
    assert np.abs(matrix_of(out) - exact).max() < 1e-11
    assert abs(np.linalg.norm(out[3:]) - 1) < 1e-15


def test_observer_step_local_error_is_second_order_in_h():
    """docs/math.md, fact 22: with ``V_wc(t)``, ``u_e(t)`` varying, one step with their values at
    ``t_k`` is off the exact flow by ``O(h^2)``: halving ``h`` divides the error by 4 (order in
    [1.9, 2.1] measured over h = 8, 4, 2 ms)."""
    v0, v1 = np.array([0.3, -0.5, 0.2, 1.0, -0.4, 0.6]), np.array([2.0, 1.0, -1.5, 3.0, 2.0, -1.0])
    u0, u1 = np.array([0.05, 0.02, -0.03, 0.2, 0.1, -0.3]), np.array([0.5, -0.2, 0.1, -1.0, 0.4, 0.8])
    errors = []
    for h in (0.008, 0.004, 0.002):
        exact = exact_flow(matrix_of(START), lambda t: v0 + v1 * t + np.sin(t) * v1, lambda t: u0 + u1 * t, h)
        errors.append(pose_distance(exact, matrix_of(stepped(START, v0, u0, h))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 1.9) & (orders < 2.1)), orders


def test_image_is_read_with_the_estimate_of_its_capture_time(case, controller):
    """(21) with ``gbar`` of the capture sample: the exact features of the estimate at sample 3,
    handed over at sample 8, give ``e_e = 0`` (to 1e-12), though the estimate has moved since."""
    n, x = controller.n, controller.initial_state()
    q, qd = case.s0[:n], case.s0[n : 2 * n] + 0.2
    project = cs.Function("f", [case.loop.pbar, case.loop.quat], [case.loop.camera.project(case.loop.estimate)])
    for k in range(8):
        if k == 3:
            captured = np.asarray(project(x[:3], x[3:7])).ravel()
            at_capture = x[:7].copy()
        _, x = controller.step(x, k * controller.period, q, qd, None, -1)
    assert np.abs(x[:7] - at_capture).max() > 1e-4  # the estimate has moved
    result = controller.evaluate(x, 8 * controller.period, q, qd, captured, 3)
    assert result.status is Status.OK
    assert np.abs(result.state[controller.layout.e_e]).max() < 1e-12


def test_torque_is_the_sampled_loops_law_at_the_sample(case, controller):
    """The program's torque is the law (35), (42) of the sampled simulator (its parametric model,
    another graph) at the same ``(t, q, qd, gbar, e_e)``, to 1e-10 relative."""
    n, rng = controller.n, np.random.default_rng(1)
    simulator = SampledSimulator(replace(case.loop, sampled=True), case.settings)
    x = controller.initial_state()
    x[controller.layout.e_e] = 1e-3 * rng.standard_normal(6)
    q, qd, t = case.s0[:n] + 0.01 * rng.standard_normal(n), 0.1 * rng.standard_normal(n), 0.7
    tau, _ = controller.step(x, t, q, qd, None, -1)
    s = np.concatenate([q, qd, x[:7]])
    law, _ = simulator._last(t, s, x[controller.layout.e_e], np.full(n, np.inf), *simulator.design)
    assert np.abs(tau - law.ravel()).max() < 1e-10 * np.abs(tau).max()


def gravity(case, q: np.ndarray) -> np.ndarray:
    robot = case.loop.robot
    return np.asarray(cs.Function("g", [robot.q], [robot.gravity])(q)).ravel()


@pytest.mark.parametrize("bad", ["q", "qd"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_joints_give_gravity_compensation_at_the_last_finite_q(case, controller, bad, value):
    """Status 2: a NaN or infinite ``q`` or ``qd`` gives ``g(q)`` at the last finite ``q`` (the one of
    this sample when only ``qd`` is bad) and holds the estimate; the state stays finite."""
    n = controller.n
    x = controller.initial_state()
    q, qd = case.s0[:n] + 0.01, np.full(n, 0.05)
    _, x = controller.step(x, 0.0, q, qd, None, -1)
    broken = {"q": q + 0.02, "qd": qd.copy()}
    broken[bad][2] = value
    result = controller.evaluate(x, controller.period, broken["q"], broken["qd"], None, -1)
    assert result.status is Status.BAD_JOINTS
    expected = gravity(case, q if bad == "q" else broken["q"])
    assert np.array_equal(result.tau, expected)
    assert np.isfinite(result.state).all()
    assert np.array_equal(result.state[:13], x[:13])


def test_a_non_finite_estimate_gives_gravity_compensation_at_q(case, controller):
    """Status 3: the law not finite at finite joints (here an estimate whose quaternion is zero)
    gives ``g(q_k)``."""
    n = controller.n
    x = controller.initial_state()
    x[3:7] = 0.0
    q = case.s0[:n]
    result = controller.evaluate(x, 0.0, q, np.zeros(n), None, -1)
    assert result.status is Status.NOT_FINITE
    assert np.array_equal(result.tau, gravity(case, q))


def reference_features(case, controller, x):
    project = cs.Function("f", [case.loop.pbar, case.loop.quat], [case.loop.camera.project(case.loop.estimate)])
    return np.asarray(project(x[:3], x[3:7])).ravel()


@pytest.mark.parametrize("change", ["nan", "inf", "overflow", "far", "too_old", "future"])
def test_a_bad_image_is_dropped_like_a_lost_frame(case, controller, change):
    """Status 1: features not finite, features whose estimate (21) overflows (1e300 px) or is no
    possible estimation error (every point 1000 px off), or a capture sample outside the ring: the
    step is the one without an image, exactly; the good image is used."""
    n, ring = controller.n, controller.layout.ring
    x = controller.initial_state()
    q, qd = case.s0[:n], np.full(n, 0.05)
    for k in range(ring + 2):
        _, x = controller.step(x, k * controller.period, q, qd, None, -1)
    k = ring + 2
    features, capture = reference_features(case, controller, x) + 3.0, k - 1
    if change in ("nan", "inf"):
        features[5] = np.nan if change == "nan" else np.inf
    elif change == "overflow":
        features[:] = 1e300
    elif change == "far":  # 1000 px off: an estimate (21) of 0.44 m, beyond the 0.35 m standoff
        features[::2] += 1000.0
    elif change == "too_old":
        capture = k - ring
    elif change == "future":
        capture = k + 1
    result = controller.evaluate(x, k * controller.period, q, qd, features, capture)
    without = controller.evaluate(x, k * controller.period, q, qd, None, -1)
    assert result.status is Status.IMAGE_REJECTED
    assert np.array_equal(result.tau, without.tau) and np.array_equal(result.state, without.state)
    good = controller.evaluate(x, k * controller.period, q, qd, reference_features(case, controller, x) + 3.0, k - 1)
    assert good.status is Status.OK and not np.array_equal(good.state, without.state)


def test_controller_needs_an_implementation():
    """``dvfc.controller`` of a scenario without ``[implementation]``: one line naming the section."""
    with pytest.raises(ExportError, match=r"^implementation: "):
        dvfc.controller(dvfc.load(DEFAULT_SCENARIO.parent / "ur5_paper_ideal.toml"))
