"""Manipulator dynamics (33) and body Jacobian (34) of the UR5 (URDF from example-robot-data)."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest
from adam.core.constants import Representations

from models.lie import SE3, vee
from models.robot import Robot, RobotModelError, builtin_urdf, chain_joints


@pytest.fixture(scope="module")
def ur5() -> Robot:
    return Robot(builtin_urdf("ur5"), "tool0", SE3.from_xyz_rpy([0.01, 0.02, 0.05], [0.0, 0.1, 0.2]))


def states(rng, count=5):
    return [(rng.uniform(-np.pi, np.pi, 6), rng.normal(size=6)) for _ in range(count)]


def test_mass_matrix_is_symmetric_positive_definite(ur5, rng):
    m_fun = ur5.function("M", ur5.mass_matrix)
    for q, qd in states(rng):
        m = np.asarray(m_fun(q, qd))
        assert np.allclose(m, m.T, atol=1e-14) and np.linalg.eigvalsh(m).min() > 0


def test_mdot_minus_2c_is_skew_symmetric(ur5, rng):
    """``Mdot - 2C`` skew (passivity of (33)); ``Mdot`` by AD, ``C`` by Christoffel symbols."""
    f = cs.Function("f", [ur5.q, ur5.qd], [ur5.mass_matrix_dot - 2 * ur5.coriolis])
    for q, qd in states(rng):
        s = np.asarray(f(q, qd))
        assert np.abs(s + s.T).max() <= 1e-12 * max(1.0, np.abs(s).max())


def test_coriolis_matches_recursive_newton_euler(ur5, rng):
    """``C(q, qd) qd + g(q)`` equals adam's bias force (RNEA), an independent algorithm."""
    bias = ur5._kindyn.bias_force(cs.SX.eye(4), ur5.q, cs.SX.zeros(6), ur5.qd)[6:]
    f = cs.Function("f", [ur5.q, ur5.qd], [ur5.coriolis @ ur5.qd + ur5.gravity - bias])
    for q, qd in states(rng):
        assert np.abs(np.asarray(f(q, qd))).max() < 1e-10


def test_gravity_is_gradient_of_potential(ur5, rng):
    """``g(q) = dU/dq`` checked by central differences (h = 1e-6; error ~1e-9 N m)."""
    g_fun = ur5.function("g", ur5.gravity)
    u_fun = cs.Function("U", [ur5.q], [ur5.potential_energy()])
    h = 1e-6
    for q, _ in states(rng):
        fd = [(float(u_fun(q + h * e)) - float(u_fun(q - h * e))) / (2 * h) for e in np.eye(6)]
        assert np.allclose(np.asarray(g_fun(q, 0)).ravel(), fd, atol=1e-7)


def test_body_jacobian_matches_forward_kinematics(ur5, rng):
    """Column i of ``J_b`` equals ``(g^-1 dg/dq_i)^vee`` by central differences (h = 1e-6)."""
    fk = cs.Function("g", [ur5.q], [ur5.camera_pose.as_matrix()])
    jb = cs.Function("J", [ur5.q], [ur5.body_jacobian])
    h = 1e-6
    for q, _ in states(rng):
        g_inv = np.linalg.inv(np.asarray(fk(q)))
        cols = [
            np.asarray(vee(g_inv @ (np.asarray(fk(q + h * e)) - np.asarray(fk(q - h * e))) / (2 * h))).ravel()
            for e in np.eye(6)
        ]
        assert np.allclose(np.asarray(jb(q)), np.array(cols).T, atol=1e-8)


def test_body_jacobian_matches_adam_body_fixed_jacobian(rng):
    """Without a mount, ``J_b`` equals adam's body-fixed Jacobian of the link."""
    robot = Robot(builtin_urdf("ur5"), "tool0")
    robot._kindyn.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)
    adam_jac = robot._kindyn.jacobian("tool0", cs.SX.eye(4), robot.q)[:, 6:]
    f = cs.Function("f", [robot.q], [robot.body_jacobian - adam_jac])
    for q, _ in states(rng):
        assert np.abs(np.asarray(f(q))).max() < 1e-12


def test_chain_joints_of_ur5():
    assert chain_joints(builtin_urdf("ur5"), "tool0") == [
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    ]


def test_missing_frame_is_an_error():
    with pytest.raises(RobotModelError, match="no link named 'camera_link'"):
        Robot(builtin_urdf("ur5"), "camera_link")


def test_unknown_builtin_is_an_error():
    with pytest.raises(RobotModelError, match="unknown robot model"):
        builtin_urdf("r2d2")
