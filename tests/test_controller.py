"""The controller as a discrete program (analysis/controller.py): its observer step (docs/math.md,
fact 22), the image of the capture time, the law of the sampled loop, and a finite torque for every
bad input."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import logm

import dvfc
from dvfc.analysis.controller import Status, program_loop
from dvfc.analysis.export import ExportError
from dvfc.analysis.sampled import SampledSimulator, as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.sil import software_in_the_loop
from dvfc.models.lie import SE3, quaternion_to_matrix
from dvfc.models.loop import observer_step

from loop_reference import twist_hat


@pytest.fixture(scope="module")
def case():
    return dvfc.load(DEFAULT_SCENARIO)


@pytest.fixture(scope="module")
def controller(case):
    return dvfc.controller(case)


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


def test_the_sampled_simulator_runs_the_programs_step_bit_for_bit():
    """The sampled simulator's controller is the program (docs/math.md, fact 22): along 0.1 s of its run
    of the default UR5 with ``K_I = 10 K_xi`` from 0.02 s and efforts at 0.4 % (the anti-windup acting),
    at every sample the program's step (no image; the sample's ``gbar``, ``z_I`` and a random held
    ``e_e``) returns the torque, the next ``gbar`` and the next ``z_I`` of the simulator's period at the
    same inputs, to the bit: one definition (``sample_update``), the program's design its constants. At
    each sample an image captured ``latency`` earlier (the state there, its features as the simulator
    makes them) gives the program the ``e_e`` the simulator reads from it, to the bit."""
    case = changed(DEFAULT_SCENARIO, INTEGRAL, SATURATED)
    imp = case.settings.implementation
    simulator = as_implemented(case.loop, replace(case.settings, duration=0.1, dt=imp.period))
    states = simulator.run(case.s0)["state"]
    controller = dvfc.controller(case)
    layout, n, lag, h = controller.layout, controller.n, imp.latency_steps, imp.period
    period = simulator._period_function(simulator.substeps.substeps)
    rng = np.random.default_rng(22)
    held = 0
    for k, s in enumerate(states[:-1]):
        e = 1e-3 * rng.standard_normal(6)
        after, tau, *_ = (np.asarray(v).ravel() for v in period(s, k * h, e, simulator._effort, simulator._friction,
                                                                 *simulator.design))  # fmt: skip
        x = controller.initial_state()
        x[layout.gbar], x[layout.e_e], x[layout.integral] = s[12:19], e, s[19:]
        x[layout.counter], x[layout.q_last] = k, s[:n]
        step = controller.evaluate(x, k * h, s[:n], s[n : 2 * n], None, -1)
        assert np.array_equal(step.tau, tau) and np.array_equal(step.state[layout.gbar], after[12:19]), k
        assert np.array_equal(step.state[layout.integral], after[19:]), k
        held += int(np.sum((after[19:] == s[19:]) & (k * h >= 0.02)))
        if k >= lag:
            captured = states[k - lag]
            features = np.asarray(simulator._camera((k - lag) * h, captured, np.zeros(8))[2]).ravel()
            e_read = np.asarray(simulator._read_image(captured[12:19], features)[0]).ravel()
            for j in range(layout.ring):
                x[layout.slot(j)] = captured[12:19]
            image = controller.evaluate(x, k * h, s[:n], s[n : 2 * n], features, k - lag)
            assert image.status is Status.OK and np.array_equal(image.state[layout.e_e], e_read), k
    assert held > 0  # the anti-windup held some joint at some sample


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


SEVEN_JOINTS = Path(__file__).parent / "data" / "xarm7_sampled.toml"


def changed(path: Path, gains: dict, implementation: dict | None = None):
    """The scenario at ``path`` with ``[gains]`` and ``[implementation]`` entries changed (not compiled)."""
    case = dvfc.load(path)
    data = case.scenario.model_dump()
    data["gains"].update(gains)
    data["implementation"].update(implementation or {})
    data["simulation"]["jit"] = False
    return case.with_scenario(Scenario.model_validate(data))


INTEGRAL = {"k_i_factor": 10.0, "integral_start": 0.02}
SATURATED = {"saturate": True, "torque_scale": 0.004}
"""Efforts scaled to 0.4 %: the shoulder's and elbow's gravity torques (-21 and -16 N m) always beyond their
limits (-0.6 N m), the base's (up to +0.86 N m) at times, the wrists' both ways: the anti-windup holds
``z_I,i`` at some samples and joints and not at others, on both sides."""


def law_replay(case, run):
    """Per sample of a software-in-the-loop ``run``: the program's torque and next ``z_I``, and the
    sampled simulator's law and its ``z_I`` update (:class:`SampledSimulator`) at the same
    ``(t, q, qd, gbar, z_I)`` and the same held ``e_e`` (the program's, after its image)."""
    controller = dvfc.controller(case)
    simulator = SampledSimulator(replace(case.loop, sampled=True), case.settings)
    layout, n, integral = controller.layout, controller.n, case.loop.integral
    period = simulator._period_function(1)  # z_I's update reads the sample alone, whatever the substeps
    rows = []
    for k in range(len(run.tau)):
        x = run.states[k]
        image = run.features[k] if run.captures[k] >= 0 else None
        step = controller.evaluate(x, run.t[k], run.q[k], run.qd[k], image, int(run.captures[k]))
        e_e = step.state[layout.e_e]
        s = np.concatenate([run.q[k], run.qd[k], x[:7], x[layout.integral] if integral else []])
        law, *_ = simulator._last(run.t[k], s, e_e, simulator._effort, *simulator.design)
        after = period(s, run.t[k], e_e, simulator._effort, simulator._friction, *simulator.design)[0]
        z_sim = np.asarray(after).ravel()[2 * n + 7 :]
        rows.append((step.tau, np.asarray(law).ravel(), x[layout.integral], step.state[layout.integral], z_sim))
    return [np.array(column) for column in zip(*rows, strict=True)]


@pytest.mark.slow
def test_integral_action_of_the_program_is_the_sampled_simulators_rule():
    """Facts 20-21 in the program: over 0.1 s of software in the loop (50 samples) of the default UR5
    with ``K_I = 10 K_xi`` from 0.02 s and saturated efforts, at every sample the torque equals the
    sampled simulator's law (``-K_I z_k`` included) and ``z_(k+1)`` its update (``z_k + h xi_k``, 0
    before ``integral_start``, the conditional anti-windup), bit for bit: the program reads its state
    (its ring's images, its ``z_I``) into the update the simulator runs (the rule itself is checked
    against NumPy by ``tests/test_integral.py``). ``z_I`` is held at some samples and integrates at
    others, and is 0 before 0.02 s."""
    case = changed(DEFAULT_SCENARIO, INTEGRAL, SATURATED)
    run = software_in_the_loop(case, duration=0.1)
    tau, law, z, z_next, z_sim = law_replay(case, run)
    assert np.array_equal(tau, law) and np.array_equal(z_next, z_sim)
    assert np.all(z_next[run.t[: len(tau)] < 0.02 - 1e-9] == 0.0)
    late = run.t[: len(tau)] >= 0.02
    held = (z_next == z) & late[:, None]
    assert 0 < held.sum() < late.sum() * case.loop.robot.n, held.sum()


@pytest.mark.slow
def test_friction_compensation_of_the_program_is_the_sampled_simulators_law():
    """Fact 19 in the program: the xArm 7 (its URDF's damping and friction) with ``friction_compensation =
    "urdf"``, 0.05 s of software in the loop (100 samples at 2 kHz): every torque the sampled simulator's
    law bit for bit, and the paper's law (35) plus ``fhat(qd_d) = bhat qd_d + chat tanh(qd_d / epshat)``
    evaluated in NumPy on the law's ``qd_d`` to 1e-10 relative, ``fhat`` reaching more than 0.01 N m (so
    the test sees it)."""
    case = changed(SEVEN_JOINTS, {"friction_compensation": "urdf"})
    run = software_in_the_loop(case, duration=0.05)
    tau, law, *_ = law_replay(case, run)
    assert np.array_equal(tau, law)
    loop = program_loop(case)
    n, e_e = loop.robot.n, dvfc.controller(case).layout.e_e
    paper = cs.Function("paper", [loop.t, loop.state, loop.hold], [loop.paper_torque, loop.qd_d])
    bhat, chat, eps = loop.compensation[:n], loop.compensation[n : 2 * n], loop.compensation[2 * n]
    fhat, own = [], []
    for k in range(len(run.tau) - 1):  # the e_e held at step k: the program's state after it
        hold = np.concatenate([np.zeros(n), run.states[k + 1][e_e], np.zeros(12)])
        state = np.concatenate([run.q[k], run.qd[k], run.states[k][:7]])
        torque, qd_d = (np.asarray(v).ravel() for v in paper(run.t[k], state, hold))
        fhat.append(bhat * qd_d + chat * np.tanh(qd_d / eps))
        own.append(torque + fhat[-1])
    assert np.abs(np.array(own) - tau[:-1]).max() <= 1e-10 * np.abs(tau).max()
    assert np.abs(fhat).max() > 0.01
