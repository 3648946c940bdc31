"""Fact 23 (docs/math.md): the bounds of the envelope with integral action, and its rate program."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import casadi as cs
import cvxpy as cp
import numpy as np
import pytest
import scipy.linalg

from dvfc.analysis import integral_envelope as ie
from dvfc.analysis.case import Case
from dvfc.analysis.envelope import (
    design_of,
    desired_features,
    disturbance_bounds,
    feature_boxes,
    self_consistent_level,
    visible_level,
)
from dvfc.analysis.results import envelope_record
from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.analysis.simulate import RunStatus, Simulator
from dvfc.models.inertia import camera_levers, christoffel_bounds
from dvfc.models.robot import BUILTIN_CAMERA_FRAME, Robot, builtin_urdf

ARMS = ("ur5", "panda", "xarm7", "puma560")


def arm(name: str) -> Robot:
    return Robot(builtin_urdf(name), BUILTIN_CAMERA_FRAME[name])


@pytest.mark.parametrize("name", ARMS)
def test_the_christoffel_rows_bound_the_coriolis_torque_at_random_states(name):
    """(B1): ``|(C(q, qd) b)_i| <= g_i |qd| |b|`` at 300 random states (a bound, so no tolerance but round-off)."""
    robot = arm(name)
    rows = christoffel_bounds(robot.urdf, robot.joints).rows
    c = robot.function("C", robot.coriolis)
    rng = np.random.default_rng(1)
    for _ in range(300):
        q, qd, b = rng.uniform(-np.pi, np.pi, robot.n), rng.normal(size=robot.n), rng.normal(size=robot.n)
        torque = np.asarray(c(q, qd)) @ b
        assert np.all(np.abs(torque.ravel()) <= rows * np.linalg.norm(qd) * np.linalg.norm(b) * (1 + 1e-12) + 1e-15)


@pytest.mark.parametrize("name", ARMS)
def test_the_camera_levers_bound_the_body_jacobian_columns(name):
    """(B2): the linear part of column ``i`` of ``J_b`` is at most ``d_i`` long at random configurations."""
    robot = arm(name)
    levers = camera_levers(robot.urdf, robot.joints, robot.frame, np.zeros(3))
    jacobian = ie.jacobian_function(robot)
    rng = np.random.default_rng(2)
    for _ in range(200):
        j = np.asarray(jacobian(rng.uniform(-np.pi, np.pi, robot.n)))
        assert np.all(np.linalg.norm(j[:3], axis=0) <= levers * (1 + 1e-12) + 1e-15)


@pytest.mark.parametrize("name", ARMS)
def test_a_body_jacobian_column_moves_by_its_bracket_with_a_later_column(name):
    """(B3.3): ``|d col_i / dq_k| = |[col_i, col_k]|`` for ``i < k`` and 0 otherwise (AD, to 1e-12)."""
    robot = arm(name)
    n = robot.n
    derivative = cs.Function("dJ", [robot.q], [cs.jacobian(cs.vec(robot.body_jacobian), robot.q)])
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, n)
    j = np.asarray(ie.jacobian_function(robot)(q))
    d = np.asarray(derivative(q)).reshape(n, 6, n).transpose(1, 0, 2)  # d[:, i, k] = d col_i / dq_k
    for i in range(n):
        for k in range(n):
            expected = np.linalg.norm(ie.bracket(j[:, i], j[:, k])) if i < k else 0.0
            assert np.linalg.norm(d[:, i, k]) == pytest.approx(expected, abs=1e-12)


def test_the_ur5_bounds_are_those_of_the_derivation():
    """(B1, B2) on the UR5: the rows and levers of docs/math.md, fact 23.3, to their printed digits."""
    robot = arm("ur5")
    rows = christoffel_bounds(robot.urdf, robot.joints).rows
    levers = camera_levers(robot.urdf, robot.joints, "tool0", np.zeros(3))
    assert rows == pytest.approx([12.79, 13.17, 7.35, 1.495, 0.914, 0.148], abs=6e-3)
    assert levers == pytest.approx([1.2396, 1.0872, 0.6622, 0.1770, 0.0823, 0.0], abs=6e-5)


BOX_LOWER = np.array([0.0, -1.75, 1.43, -1.63, -1.63, 0.0])
BOX_UPPER = np.array([0.0, -1.43, 1.74, -1.50, -1.51, 0.0])
"""A box about the default's run after ``T_I``: ``q2..q5`` vary (``J_b`` does not depend on ``q1``; the camera on
the last axis, ``sigma(J_b)`` not on ``q6``)."""


def box_sigma(count: int, seed: int) -> tuple[float, float]:
    """``(s_lo, the smallest sigma_min(J_b) at count random configurations)`` on the UR5's box."""
    robot = arm("ur5")
    varied = np.array([False, True, True, True, True, False])
    levers = camera_levers(robot.urdf, robot.joints, "tool0", np.zeros(3))
    s_lo, _, _ = ie.sigma_min_on_box(ie.jacobian_function(robot), BOX_LOWER, BOX_UPPER, varied, levers)
    q = np.random.default_rng(seed).uniform(BOX_LOWER, BOX_UPPER, (count, 6))
    j = np.asarray(ie.jacobian_function(robot).map(count)(q.T)).reshape(6, count, 6).transpose(1, 0, 2)
    return s_lo, float(np.linalg.svd(j, compute_uv=False)[:, 5].min())


def test_sigma_min_on_a_box_is_below_every_sampled_value():
    """(B3.5): ``s_lo`` lies below ``sigma_min(J_b)`` at 2000 random configurations of the box, and within
    20% of it (the refinement is not vacuous)."""
    s_lo, sampled = box_sigma(2000, 4)
    assert 0.8 * sampled <= s_lo <= sampled


def test_sigma_min_on_coarse_cells_is_below_every_sampled_value(monkeypatch):
    """(B3.5) with the refinement cut short (200 evaluations, no tolerance): the cells are large, so the
    Weyl correction decides, and ``s_lo`` must still lie below ``sigma_min(J_b)`` at 20,000 random
    configurations of the box."""
    monkeypatch.setattr(ie, "BOX_BATCH", 16)
    monkeypatch.setattr(ie, "BOX_EVALUATIONS", 200)
    monkeypatch.setattr(ie, "BOX_TOLERANCE", 0.0)
    s_lo, sampled = box_sigma(20000, 5)
    assert s_lo <= sampled


# --- the rate program, the level, the speed, the statement and the storage along a run (23.2, 23.5-23.6) -------

THETA_4 = math.radians(4.0)
REFERENCE_POINT = {"s_lo": 0.1723, "eps": 0.55, "s": 0.85, "mu": 0.25, "c": 0.0023}
"""Fact 23.5's reference point (``theta_bar = 4`` deg, no torque: ``s_t = 0``), whose SDP rate 0.80235 the fact
derives independently."""


def least(matrix: np.ndarray) -> float:
    """``lambda_min`` of a symmetric matrix."""
    return float(np.linalg.eigvalsh(matrix)[0])


@pytest.fixture(scope="module")
def default() -> SimpleNamespace:
    """The default example's ideal loop (the law with the exact ``e_e``, continuous: the loop fact 23 is about, built
    as ``verify`` builds it from the image-mode loop the scenario's ``[implementation]`` gives), its design, the
    disturbance bounds, the camera and the desired image."""
    case = Case.load(DEFAULT_SCENARIO)
    loop = replace(case.loop, mode="ideal")
    assert case.loop.mode == "image" and loop.integral and loop.integral_start > 0
    design = design_of(case.point, case.reference, loop.robot.mass_bounds)
    disturbance = disturbance_bounds(case.scenario.envelope, loop)
    return SimpleNamespace(case=case, loop=loop, design=design, disturbance=disturbance, camera=loop.camera,
                           desired=desired_features(loop.camera, design.reference),
                           speed2=disturbance.target_speed**2 + disturbance.target_rate**2,
                           k_i=np.asarray(loop.gains.k_i, dtype=float))  # fmt: skip


@pytest.fixture(scope="module")
def reference(default) -> SimpleNamespace:
    """The default design's rate program with the reference point's ``s_lo = 0.1723`` (given, no box: the UR5's
    Christoffel rows and camera levers), solved at the reference point."""
    robot = default.loop.robot
    n = robot.n
    coriolis = christoffel_bounds(robot.urdf, robot.joints)
    levers = camera_levers(robot.urdf, robot.joints, robot.frame, np.asarray(cs.DM(robot.mount.as_matrix()))[:3, 3])
    arm_ = ie.ArmBounds(coriolis.rows, coriolis.whole, levers, ie.jacobian_lipschitz(levers), np.full(n, -np.pi),
                        np.full(n, np.pi), np.ones(n, dtype=bool), REFERENCE_POINT["s_lo"], math.nan, 0)  # fmt: skip
    p = ie.problem_of(default.design, default.k_i, arm_, default.design.reference, 0.0)
    program = ie.RateProgram(p)
    point = REFERENCE_POINT
    m = program.solve(point["eps"], point["s"], point["mu"], 0.0, THETA_4, point["c"])
    assert m is not None
    return SimpleNamespace(p=p, program=program, m=m, sdp_kappa=float(program.kappa.value), c=point["c"])


def test_the_literal_rate_is_the_largest_kappa_keeping_f0_minus_kappa_f1_semidefinite(reference):
    """(23.5) ``literal_rate`` at the reference point's multipliers is the least generalized eigenvalue of the pencil
    ``(F0, F1)`` (scipy's ``eigh``, independent of the scaling ``literal_rate`` uses) shrunk by ``SHRINK``, to 1e-9
    relative (a 24 x 24 pencil, ``F1`` diagonal and positive: round-off ~1e-15, 4e-16 measured); its margin is
    ``lambda_min(F0 - kappa F1) >= 0``, and ``F0 - kappa F1`` is indefinite 1e-5 above the unshrunk rate (ten times
    ``SHRINK``): no larger ``kappa`` passes."""
    p, m, c = reference.p, reference.m, reference.c
    f0, f1 = ie.matrices(p, m, THETA_4, c)
    assert f0.shape == f1.shape == (2 * p.n + 12, 2 * p.n + 12)
    assert np.array_equal(f0, f0.T) and np.array_equal(f1, np.diag(np.diag(f1))) and np.diag(f1).min() > 0
    top = float(scipy.linalg.eigh(f0, f1, eigvals_only=True)[0])
    kappa, margin = ie.literal_rate(p, m, THETA_4, c)
    assert top > 0
    assert kappa == pytest.approx(top * (1 - ie.SHRINK), rel=1e-9)
    assert margin == least(f0 - kappa * f1) and margin >= 0
    assert least(f0 - top * (1 + 1e-5) * f1) < 0


def test_the_literal_rate_falls_when_a_bound_it_uses_is_made_worse(reference):
    """(23.3)-(23.5) At fixed multipliers each bound enters ``F0`` (or ``F1``) monotonically: a Christoffel row 10%
    larger (each of the six in turn), the camera levers (so ``jbar``) 10% longer, ``s_lo`` 10% smaller, ``max k_c``
    10% larger, the level ``c`` 10% higher (a larger ``zbar``) or ``theta_bar`` 10% larger (a larger ``D_ce``) each
    lower the literal rate by more than 1e-6 (the eigenvalue's round-off is ~1e-15; the smallest drop measured,
    ``theta_bar``'s, is 1.9e-4)."""
    p, m, c = reference.p, reference.m, reference.c
    arm_ = p.arm
    kappa = ie.literal_rate(p, m, THETA_4, c)[0]
    worse = {f"row {i + 1}": replace(p, arm=replace(arm_, rows=arm_.rows * np.where(np.arange(p.n) == i, 1.1, 1.0)))
             for i in range(p.n)}  # fmt: skip
    worse |= {"levers": replace(p, arm=replace(arm_, levers=arm_.levers * 1.1)),
              "s_lo": replace(p, arm=replace(arm_, s_lo=arm_.s_lo * 0.9)),
              "k_c": replace(p, kc=p.kc * 1.1)}  # fmt: skip
    assert worse["levers"].arm.jbar > arm_.jbar
    drops = {name: kappa - ie.literal_rate(q, m, THETA_4, c)[0] for name, q in worse.items()}
    drops["c"] = kappa - ie.literal_rate(p, m, THETA_4, 1.1 * c)[0]
    drops["theta_bar"] = kappa - ie.literal_rate(p, m, 1.1 * THETA_4, c)[0]
    assert all(drop > 1e-6 for drop in drops.values()), drops


def test_the_rate_program_gives_the_facts_reference_rate_and_the_literal_matrices_agree(reference):
    """(23.5) At the fact's reference point the SDP's ``kappa`` is 0.80235, the value derived independently (to its
    printed digits), and the literal matrices at the SDP's multipliers give that rate shrunk by ``SHRINK``, to 1e-7
    relative (the solver's tolerance; 2e-10 measured): a term of ``F0`` or ``F1`` that only one of them has and that
    tightens the condition shows here (one that loosens a block shows as room in it, the next test)."""
    assert reference.sdp_kappa == pytest.approx(0.80235, abs=5e-6)
    kappa, margin = ie.literal_rate(reference.p, reference.m, THETA_4, reference.c)
    assert kappa == pytest.approx(reference.sdp_kappa * (1 - ie.SHRINK), rel=1e-7)
    assert margin >= 0


def test_at_the_programs_optimum_every_block_of_the_literal_matrices_limits_the_rate(reference):
    """(23.5) The SDP and ``matrices`` state one condition block by block: at the reference point's optimum each
    joint's 2 x 2 block of the literal ``(F0, F1)`` (``(xi_i, z_i)``) and the pose block, taken alone, allow a rate
    (their least generalized eigenvalue, scipy's ``eigh``) within 1e-6 relative of the whole matrix's (at most 1.1e-9
    measured: the solver's tolerance). The multipliers couple the blocks (``sum g / (2 theta)`` in every joint's,
    ``rho`` and ``Lambda`` in ``Y_c``), so room left in one block would raise ``kappa``: a term of a block that only
    ``matrices`` or only the program has shows as room in it."""
    p, m, c = reference.p, reference.m, reference.c
    n = p.n
    f0, f1 = ie.matrices(p, m, THETA_4, c)
    top = float(scipy.linalg.eigh(f0, f1, eigvals_only=True)[0])
    for rows in [[i, n + i] for i in range(n)] + [list(range(2 * n, 2 * n + 12))]:
        block = np.ix_(rows, rows)
        own = float(scipy.linalg.eigh(f0[block], f1[block], eigvals_only=True)[0])
        assert top * (1 - 1e-12) <= own <= top * (1 + 1e-6)


def test_a_certified_rate_is_the_literal_one_rechecked_with_its_margin(reference, default):
    """(23.5) ``best_rate`` about the reference point: its ``kappa`` and margin are those of ``literal_rate`` at its own
    multipliers (exactly: the literal rate, not the solver's), the margin is ``lambda_min(F0 - kappa F1)`` and at least
    half of ``SHRINK kappa lambda_min(F1)`` (the shrink's guarantee when ``F0 - kappa_0 F1 >= 0``; the half absorbs the
    eigenvalues' round-off, ~1e-13 against the 4e-7 measured), and ``c_inf = |V_wo|^2 / (4 s kappa)`` (no torque) to
    1e-12 relative."""
    rate = ie.best_rate(reference.program, THETA_4, reference.c, default.speed2, reference.m)
    assert rate is not None
    f0, f1 = ie.matrices(reference.p, rate.m, THETA_4, reference.c)
    kappa, margin = ie.literal_rate(reference.p, rate.m, THETA_4, reference.c)
    assert (rate.kappa, rate.margin) == (kappa, margin) and kappa > 0
    assert margin == least(f0 - kappa * f1)
    assert margin >= 0.5 * ie.SHRINK * kappa * np.diag(f1).min()
    assert rate.c_inf == pytest.approx(default.speed2 / (4 * rate.m.s * kappa), rel=1e-12)


def test_a_failed_or_infeasible_solve_gives_no_rate(reference, default, monkeypatch):
    """A pose block ``Q_ce(s)`` that is not positive (``s`` above its limit) makes the SDP infeasible: no multipliers.
    A solver that fails (raises) gives no multipliers, no rate at the reference point's ``(theta_bar, c)``, no level
    on a ``theta_bar`` grid (4, 30, 90 deg), and a record with no rate, its reason and a statement saying nothing is
    certified."""
    p, program = reference.p, reference.program
    point = REFERENCE_POINT
    assert program.solve(point["eps"], 1.2 * p.s_limit, point["mu"], 0.0, THETA_4, point["c"]) is None
    assert program.problem.status == cp.INFEASIBLE

    def fail(*args, **kwargs):
        raise cp.SolverError("the solver failed")

    monkeypatch.setattr(cp.Problem, "solve", fail)
    monkeypatch.setattr(ie, "THETA_GRID", np.radians([4.0, 30.0, 90.0]))  # a short grid: each solve fails at once
    assert program.solve(point["eps"], point["s"], point["mu"], 0.0, THETA_4, point["c"]) is None
    assert ie.best_rate(program, THETA_4, point["c"], default.speed2) is None
    assert ie.level_search(program, default.camera, default.desired, 0.0, default.speed2, None) is None
    monkeypatch.setattr(ie, "arm_bounds", lambda robot, q_path: p.arm)  # the box's s_lo is not the point here
    case, loop = default.case, default.loop
    record = ie.integral_envelope(loop, default.design, default.disturbance, {"inside": True, "level": 1e-3},
                                  case.s0[: loop.robot.n], case.settings.duration, THETA_4)  # fmt: skip
    assert record["rate"] is None and record["level"] is None and record["max_target_speed"] is None
    assert "no theta_bar with a self-consistent level" in record["reason"]
    assert record["statement"] == f"no envelope certified with integral action: {record['reason']}"


def test_multipliers_the_literal_matrices_do_not_certify_give_no_rate(reference, default, monkeypatch):
    """Whatever the solver returns, the rate is the literal one: multipliers at which ``F0 - kappa F1 >= 0`` has no
    positive ``kappa`` (``theta = 1e-6``: the Coriolis rows' ``g / (2 theta)`` swamps ``K_xi``) give no rate and no
    level, though the solve "succeeded"."""
    p, program, m = reference.p, reference.program, reference.m
    n = p.n
    bogus = ie.Multipliers(m.eps, m.s, m.mu, m.s_t, np.full(n, 1e-6), m.rho, m.lam)
    assert ie.literal_rate(p, bogus, THETA_4, reference.c)[0] <= 0
    monkeypatch.setattr(program, "solve", lambda eps, s, mu, s_t, theta_bar, c: replace(bogus, eps=eps, s=s, mu=mu))
    assert ie.best_rate(program, THETA_4, reference.c, default.speed2) is None
    assert ie.best_rate(program, THETA_4, reference.c, default.speed2, m, fastest=True) is None
    assert ie.level_search(program, default.camera, default.desired, 0.0, default.speed2, THETA_4) is None


@pytest.fixture(scope="module")
def envelope(default) -> SimpleNamespace:
    """Fact 23 for the default example piece by piece, as ``integral_envelope`` computes it: the box ``R`` and the
    arm's bounds, the rate program, the start's level (the planned start until ``T_I``, facts 16b, 20.6), the level
    search and the fastest storage."""
    case, loop, design = default.case, default.loop, default.design
    n = loop.robot.n
    q_path = ie.path_configurations(loop, design.reference, case.s0[:n], case.settings.duration)
    arm_ = ie.arm_bounds(loop.robot, q_path)
    p = ie.problem_of(design, default.k_i, arm_, design.reference, default.disturbance.torque)
    program = ie.RateProgram(p)
    start = envelope_record(case, search=False)["start"]
    assert start["inside"] and start["until_s"] == loop.integral_start
    found = ie.level_search(program, default.camera, default.desired, start["level"], default.speed2, None)
    assert found is not None
    fastest = ie.fastest_rate(program, found.rate, default.speed2)
    return SimpleNamespace(arm=arm_, p=p, program=program, start=start, found=found, rate=found.rate, fastest=fastest)


@pytest.mark.slow
def test_the_level_covers_the_chained_start_and_the_ultimate_bounds_follow_from_c_inf(default, envelope):
    """(23.6) The default's level: the planned start's bound on ``V_eps(T_I) = V(T_I)`` (0.001405) ``<= c <=
    c_max(theta_bar)`` at ``theta_bar = 4`` deg, ``c_inf <= c``, the rate the literal one at its multipliers with
    ``c_inf = |V_wo|^2 / (4 s kappa)`` (1e-12 relative: the same arithmetic); ``c = 0.001921``, ``c_inf = 0.001920``
    to their printed digits. The ultimate bounds of ``V_pose <= c_inf`` ((23.1): ``V_eps >= V_pose``) recomputed as the
    fact states them, to 1e-12 relative: ``|p_ec| <= sqrt(2 c_inf / w_pc)`` (31.0 mm), ``theta_ec <= arccos(1 -
    c_inf / w_rc)`` (3.55 deg), ``|z_I| <= sqrt(2 c_inf / min(k_I - eps^2 D))``; the feature boxes at ``c_inf`` lie
    within those at ``c``."""
    p, found, rate, start = envelope.p, envelope.found, envelope.rate, envelope.start
    c_max = float(self_consistent_level(np.asarray(default.design.weights), rate.theta_bar))
    assert rate.theta_bar == pytest.approx(THETA_4, abs=1e-15)
    assert found.start_level == start["level"] == pytest.approx(0.001405, abs=5e-7)
    assert start["level"] <= rate.c <= c_max and rate.c_inf <= rate.c
    assert rate.c == pytest.approx(0.001921, abs=5e-7) and rate.c_inf == pytest.approx(0.001920, abs=5e-7)
    kappa, margin = ie.literal_rate(p, rate.m, rate.theta_bar, rate.c)
    assert (rate.kappa, rate.margin) == (kappa, margin) and margin >= 0
    assert rate.c_inf == pytest.approx(default.speed2 / (4 * rate.m.s * kappa), rel=1e-12)
    w_pc, w_rc, _, _ = default.design.weights
    bounds = ie.bounds_of(p, found)
    assert bounds["p_ec"] == pytest.approx(math.sqrt(2 * rate.c_inf / w_pc), rel=1e-12)
    assert bounds["p_ec"] == pytest.approx(0.0310, abs=5e-5)
    assert bounds["theta_ec_deg"] == pytest.approx(math.degrees(math.acos(1 - rate.c_inf / w_rc)), rel=1e-12)
    assert bounds["theta_ec_deg"] == pytest.approx(3.55, abs=5e-3)
    floor = float(np.min(default.k_i - rate.m.eps**2 * p.kinetic))
    assert bounds["z_I"] == pytest.approx(math.sqrt(2 * rate.c_inf / floor), rel=1e-12)
    assert found.boxes is not None and found.ultimate_boxes is not None and found.boxes.visible
    inner, outer = np.asarray(found.ultimate_boxes.boxes), np.asarray(found.boxes.boxes)
    assert np.all(inner[:, :2] >= outer[:, :2]) and np.all(inner[:, 2:] <= outer[:, 2:])


@pytest.mark.slow
def test_a_start_above_c_inf_raises_the_level_to_it_and_one_above_c_max_raises_theta_bar(default, envelope):
    """(23.6) The level is chained to the start: a start level of 0.0021 (above the default's ``c_inf`` 0.00192,
    below ``c_max(4 deg)`` 0.002436) gives a level of at least 0.0021 at 4 deg; one of 0.003 (above ``c_max(4 deg)``)
    moves to the first ``theta_bar`` of the grid whose ``c_max`` exceeds it, 5 deg, with ``c >= 0.003``. Each with
    ``c_inf <= c <= c_max`` and its rate re-checked literally (``margin >= 0``)."""
    weights = np.asarray(default.design.weights)
    assert envelope.rate.c_inf < 0.0021 < float(self_consistent_level(weights, THETA_4)) < 0.003
    for level, degrees in ((0.0021, 4.0), (0.003, 5.0)):
        found = ie.level_search(envelope.program, default.camera, default.desired, level, default.speed2, None)
        assert found is not None
        rate = found.rate
        assert math.degrees(rate.theta_bar) == pytest.approx(degrees, abs=1e-12)
        assert level <= rate.c <= float(self_consistent_level(weights, rate.theta_bar)) and rate.c_inf <= rate.c
        kappa, margin = ie.literal_rate(envelope.p, rate.m, rate.theta_bar, rate.c)
        assert (rate.kappa, rate.margin) == (kappa, margin) and kappa > 0 and margin >= 0


@pytest.mark.slow
def test_the_largest_speed_is_rechecked_at_that_speed_and_not_certified_just_above_it(default, envelope):
    """(23.6) The default's largest certified target speed is 0.0872 m/s (printed digits). At it, from the literal
    matrices at the speed's multipliers, by scipy's generalized eigenvalues (independent of ``literal_rate``): the rate
    is positive with ``F0 - kappa F1 >= 0``, ``c_inf = speed^2 / (4 s kappa) <= c`` (the speed is shrunk by 1e-9, so
    to 1e-8 relative), ``c`` lies below ``c_max(4 deg)`` and the visible level, every feature region at ``c`` is in
    the image and the start's level below ``c``. 0.1% faster ``c_inf > c``, and the level search at 4 deg certifies
    nothing at that speed."""
    program, found, p = envelope.program, envelope.found, envelope.p
    speed = ie.largest_speed(program, default.camera, default.desired, found, default.disturbance, None)
    assert speed == pytest.approx(0.0872, abs=5e-5)
    again, rate = ie.speed_limit(program, default.camera, default.desired, found, 0.0, default.speed2)
    assert again == speed and rate is not None
    f0, f1 = ie.matrices(p, rate.m, rate.theta_bar, rate.c)
    kappa = float(scipy.linalg.eigh(f0, f1, eigvals_only=True)[0]) * (1 - ie.SHRINK)
    assert kappa > 0 and least(f0 - kappa * f1) >= 0
    c_max = float(self_consistent_level(np.asarray(default.design.weights), rate.theta_bar))
    assert rate.c <= c_max and rate.c <= visible_level(default.design, default.camera, default.desired)
    assert feature_boxes(default.design, default.camera, default.desired, rate.c).visible
    assert envelope.start["level"] <= rate.c
    assert speed**2 / (4 * rate.m.s * kappa) <= rate.c * (1 + 1e-8)
    faster = 1.001 * speed
    assert faster**2 / (4 * rate.m.s * kappa) > rate.c
    assert ie.level_search(program, default.camera, default.desired, envelope.start["level"], faster**2,
                           rate.theta_bar) is None  # fmt: skip


@pytest.mark.slow
def test_the_largest_speed_shrinks_as_a_bound_grows_or_theta_bar_falls(default, envelope):
    """(23.6) The certified speed never grows with what it must absorb: the target's rate takes its share exactly
    (``speed^2 + rate^2`` constant, to 1e-8 relative: the rate is the same channel); a start whose level lies above the
    speed's ``c`` leaves no speed (and one below it the same speed); a joint-torque bound (0.02 N m), a 10% smaller
    ``s_lo`` each give a smaller speed (0.0812 and 0.0861 against 0.0872 measured); ``theta_bar = 3`` deg
    (``c_max`` below the start's level) gives no envelope, and 4 deg a smaller speed than 6 deg (0.1237 measured)."""
    program, found, p = envelope.program, envelope.found, envelope.p
    camera, desired, disturbance = default.camera, default.desired, default.disturbance
    speed = ie.largest_speed(program, camera, desired, found, disturbance, None)
    assert speed is not None
    for rate in (0.02, 0.05):
        slower = ie.largest_speed(program, camera, desired, found, replace(disturbance, target_rate=rate), None)
        assert slower is not None and slower**2 + rate**2 == pytest.approx(speed**2, rel=1e-8)
    _, rate_ = ie.speed_limit(program, camera, desired, found, 0.0, default.speed2)
    assert rate_ is not None
    assert ie.largest_speed(program, camera, desired, found, disturbance, lambda d: rate_.c * 1.001) is None
    assert ie.largest_speed(program, camera, desired, found, disturbance, lambda d: rate_.c * 0.999) == speed

    def certified(problem, torque: float, theta_bar: float | None) -> float | None:
        rates = ie.RateProgram(problem)
        trial = replace(disturbance, torque=torque)
        env = ie.level_search(rates, camera, desired, found.start_level, default.speed2 + torque**2, theta_bar)
        return None if env is None else ie.largest_speed(rates, camera, desired, env, trial, None)

    torque = ie.problem_of(default.design, default.k_i, p.arm, default.design.reference, 0.02)
    worse = replace(p, arm=replace(p.arm, s_lo=0.9 * p.arm.s_lo))
    assert certified(torque, 0.02, None) < speed
    assert certified(worse, 0.0, None) < speed
    assert ie.level_search(program, camera, desired, found.start_level, default.speed2, math.radians(3.0)) is None
    assert speed < certified(p, 0.0, math.radians(6.0))


@pytest.fixture(scope="module")
def record(default, envelope) -> dict:
    """``integral_envelope``'s record of the default example (the arm's bounds on the box reused from
    :func:`envelope`, the same box), with the largest speed."""
    case, loop = default.case, default.loop
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(ie, "arm_bounds", lambda robot, q_path: envelope.arm)
        return ie.integral_envelope(loop, default.design, default.disturbance, envelope.start,
                                    case.s0[: loop.robot.n], case.settings.duration, None)  # fmt: skip


@pytest.mark.slow
def test_the_statement_names_the_loop_the_plant_the_region_and_what_it_assumes(record, envelope):
    """The sentence says of which loop (the ideal continuous loop with integral action) and which plant (the law's
    model) it speaks, over which region (``t >= T_I`` while ``q`` stays in the box ``R``), from which start
    (``z_I(T_I) = 0``, ``V_eps(T_I) = V(T_I)`` below the planned start's level), with its level, rates and image
    margin; the record lists what it assumes (the exact ``e_e``, the integral law from ``T_I``, the box, the arm's
    bounds, the disturbance bounds). A start not certified claims nothing from the start; no rate says why."""
    text, fact = record["statement"], record["integral"]
    assert record["rate"] == envelope.fastest.kappa and record["level"] == envelope.rate.c
    assert "ideal continuous loop with integral action" in text
    assert "the plant equal to the law's model" in text
    assert f"for t >= T_I = {fact['T_I']:.3g} s while q stays in the box R" in text
    assert f"z_I(T_I) = 0, V_eps(T_I) = V(T_I) <= {envelope.start['level']:.4g}" in text
    assert f"V_eps(t) <= c = {record['level']:.4g}" in text and f"c_inf = {record['ultimate_V']:.4g}" in text
    assert f"decays at {record['rate']:.4g} 1/s" in text and "every feature stays in the image" in text
    assumed = " | ".join(record["assumptions"])
    for words in ("exact estimation error e_e", "dz_I/dt = xi from integral_start T_I on, z_I(T_I) = 0",
                  "q stays in the box R", "the Christoffel bounds g_i and the camera levers d_i",
                  "target speed, target rate and joint-torque disturbance within the stated bounds"):  # fmt: skip
        assert words in assumed
    uncertified = ie.statement({**record, "start": {**record["start"], "inside": False}})
    assert "for runs with V_eps <= c at T_I (the start is not certified)" in uncertified
    assert "from the start" not in uncertified and "the plant equal to the law's model" in uncertified
    assert ie.statement({**record, "rate": None, "reason": "why"}) == "no envelope certified with integral action: why"


@pytest.fixture(scope="module")
def run(default) -> SimpleNamespace:
    """A CVODES run (rtol = atol = 1e-10, the virtual machine) of the default's ideal loop from its start to
    ``T_I + 1.5`` s, sampled every millisecond; the samples from ``T_I`` on."""
    case, loop = default.case, default.loop
    settings = replace(case.settings, implementation=None, plant=None, view=False, jit=False, dt=1e-3,
                       duration=loop.integral_start + 1.5)  # fmt: skip
    traj = Simulator(loop, settings).run(case.s0)
    assert traj.status is RunStatus.OK
    after = np.flatnonzero(traj.t >= loop.integral_start - 1e-12)
    assert traj.t[after[0]] == pytest.approx(loop.integral_start, abs=1e-12)
    return SimpleNamespace(traj=traj, t=traj.t, states=traj["state"], after=after)


def along(loop, run: SimpleNamespace, eps: float) -> tuple[np.ndarray, ...]:
    """``storage_and_rate`` at every sample of the run: ``V_eps``, ``dV_eps/dt``, ``|V_wo|^2``, ``|tau_d|^2``."""
    out = ie.storage_and_rate(loop, eps).map(len(run.t))(run.t, run.states.T)
    return tuple(np.asarray(v).ravel() for v in out)


def rate_23_2(loop, eps: float) -> cs.Function:
    """(23.2) term by term: ``-nu^T K nu + x^T G w + eps [xi^T M xi + xi^T C(q, qd) z + z^T J_b^T y - z^T K_xi xi -
    z^T K_I z + z^T tau_d]``, ``y = Ad_{g_d^-1}^T W_c e_c``, as a function of ``(t, s)``."""
    robot, n = loop.robot, loop.robot.n
    xi, z, m = loop.xi, loop.z_i, robot.mass_matrix
    y = loop.desired.inverse().adjoint().T @ loop.weights.control @ loop.e_c
    k_xi, k_i = (cs.diag(cs.DM(np.asarray(k, dtype=float))) for k in (loop.gains.k_xi, loop.gains.k_i))
    supply = -loop.nu.T @ loop.gain_matrix @ loop.nu + loop.x.T @ loop.disturbance_matrix @ loop.w
    cross = (xi.T @ m @ xi + xi.T @ robot.coriolis @ z + z.T @ robot.body_jacobian.T @ y - z.T @ k_xi @ xi
             - z.T @ k_i @ z + z.T @ loop.w[:n])  # fmt: skip
    return cs.Function("rate_23_2", [loop.t, loop.state], [supply + eps * cross])


@pytest.mark.slow
def test_storage_and_rate_gives_the_time_derivative_of_v_eps_and_23_2_along_a_run(default, envelope, run):
    """(23.2) Along the run after ``T_I``, for both stated storages (``eps`` = 0.459 and 0.550), ``storage_and_rate``'s
    rate is (i) the central difference of its own ``V_eps`` over 1 ms, to 1e-4 of the largest rate (the difference's
    ``h^2 V''' / 6`` and the solver's interpolation: 1.0e-9 measured against rates up to 2.4e-5), a tolerance that
    resolves the ``eps z_I^T M xi`` term's share of the rate (3e-7, over 100 times it); and (ii) (23.2)'s formula
    evaluated term by term, to 1e-10 of the largest rate (round-off: 3.6e-17 measured, 1.5e-12 of it)."""
    loop = default.loop
    k = run.after[2:-1]  # central differences inside [T_I, end]: z_I's rate switches on at T_I
    h = run.t[1] - run.t[0]
    a_dot = run.traj["V_a_dot"][:, 0]
    for eps in (envelope.rate.m.eps, envelope.fastest.m.eps):
        v, v_dot, _, _ = along(loop, run, eps)
        scale = np.abs(v_dot[k]).max()
        difference = (v[k + 1] - v[k - 1]) / (2 * h)
        assert np.abs(difference - v_dot[k]).max() <= 1e-4 * scale
        assert np.abs(v_dot[k] - a_dot[k]).max() >= 100 * 1e-4 * scale  # the eps term is seen
        formula = np.asarray(rate_23_2(loop, eps).map(len(run.t))(run.t, run.states.T)).ravel()
        assert np.abs(formula[run.after] - v_dot[run.after]).max() <= 1e-10 * scale


@pytest.mark.slow
def test_the_rate_inequality_holds_along_a_run_from_t_i_while_q_stays_in_the_box(default, envelope, run):
    """(23.5)-(23.6) On the same run, from ``T_I``: ``V_eps(T_I) = V(T_I)`` (``z_I(T_I) = 0`` but for the solver's
    interpolation, 1e-9: to 1e-9 relative) lies below the planned start's level; ``q`` stays in the box ``R`` and
    ``V_eps <= c`` at every sample (so every sample is in ``Omega`` and the check is not vacuous); and for both stated
    storages ``dV_eps/dt <= -kappa V_eps + |V_wo|^2 / (4 s)`` (no torque disturbance on this run), round-off of 1e-12
    allowed; the least slack measured is 1.2e-3, most of the input term (fact 23.7: the bound is conservative)."""
    loop, arm_ = default.loop, envelope.arm
    n, first = loop.robot.n, run.after[0]
    v_pose = run.traj["V"][:, 0]
    assert np.all(arm_.contains(run.states[run.after, :n]))
    for rate in (envelope.rate, envelope.fastest):
        v, v_dot, wo2, td2 = along(loop, run, rate.m.eps)
        assert v[first] == pytest.approx(v_pose[first], rel=1e-9) and v[first] <= envelope.start["level"]
        assert np.all(td2 == 0) and v[run.after].max() <= rate.c
        slack = wo2 / (4 * rate.m.s) - rate.kappa * v - v_dot
        assert slack[run.after].min() >= -1e-12


@pytest.mark.slow
def test_the_fastest_storage_covers_the_chained_start_and_contains_the_envelopes_level_set_only_with_room(
    default, envelope, run
):
    """(23.6) The storages of the two stated rates (``eps`` = 0.459 on ``c``, ``eps'`` = 0.550 on ``c'``) are one where
    ``z_I = 0``: at ``T_I`` on the run they agree to 1e-9 relative (the solver's ``z_I(T_I)``), so a run with ``V(T_I)
    <= c`` starts in both level sets (``c' >= c``). Elsewhere they differ by ``(eps' - eps) z_I^T M xi``: at 200
    configurations of the box the direction of ``(xi, z_I)`` with the largest ``V_eps' / V_eps`` (a generalized
    eigenvalue) has it above 1, so ``{V_eps <= c}`` is not inside ``{V_eps' <= c}``; it stays below ``rho = 1 + |eps'
    - eps| sqrt(beta) + 2 eps beta max(0, eps - eps')``, ``beta = max_i D_i / (k_I,i - eps^2 D_i)`` (from ``M <= D``,
    checked there), and ``rho c <= c'``: the envelope's level set lies in the fastest storage's because ``c'`` leaves
    that room (1.023 needed, 1.241 given)."""
    loop, p, rate, fast = default.loop, envelope.p, envelope.rate, envelope.fastest
    eps, eps_f = rate.m.eps, fast.m.eps
    assert eps_f != eps and fast.c >= rate.c and fast.c_inf <= fast.c and fast.kappa >= rate.kappa
    assert (fast.kappa, fast.margin) == ie.literal_rate(p, fast.m, fast.theta_bar, fast.c) and fast.margin >= 0
    first = run.after[0]
    v, v_f = along(loop, run, eps)[0], along(loop, run, eps_f)[0]
    assert v_f[first] == pytest.approx(v[first], rel=1e-9) and v[first] <= rate.c <= fast.c
    d, k_i = p.kinetic, default.k_i
    beta = float(np.max(d / (k_i - eps**2 * d)))
    rho = 1 + abs(eps_f - eps) * math.sqrt(beta) + 2 * eps * beta * max(0.0, eps - eps_f)
    assert rho * rate.c <= fast.c
    mass = cs.Function("M", [loop.robot.q], [loop.robot.mass_matrix])
    configurations = np.random.default_rng(6).uniform(envelope.arm.lower, envelope.arm.upper, (200, p.n))
    ratios = []
    for q in configurations:
        m = np.asarray(mass(q))
        assert least(np.diag(d) - m) >= -1e-12
        quadratic = [np.block([[m, e * m], [e * m, np.diag(k_i)]]) / 2 for e in (eps, eps_f)]
        ratios.append(float(scipy.linalg.eigh(quadratic[1], quadratic[0], eigvals_only=True)[-1]))
    assert min(ratios) > 1 and max(ratios) <= rho
