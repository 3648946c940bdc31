"""Fact 23 (docs/math.md): the bounds of the envelope with integral action, and its rate program."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis import integral_envelope as ie
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
