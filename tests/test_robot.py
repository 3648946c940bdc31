"""Manipulator dynamics (33) and body Jacobian (34) of every built-in arm: the UR5 and the
Franka Panda (example-robot-data), the Puma 560 and the planar direct-drive testbed (URDFs
shipped with the package).

Tolerances are absolute with ``rtol=0``. Comparisons of two exact algorithms in double
precision (symmetry, Christoffel vs RNEA, our URDF vs the Robotics Toolbox's DH model, our
``J_b`` vs adam's) allow 1e-14 to 1e-10: round-off of O(100-1000) flops on entries up to
O(10) (inertias in kg m^2, torques in N m). Central differences state their truncation
(``h^2``) and round-off (``eps / h``) bounds in their docstrings.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import casadi as cs
import numpy as np
import pytest
from adam.core.constants import Representations

from dvfc.models.lie import SE3, vee
from dvfc.models.robot import (
    BUILTIN_ARMATURE,
    BUILTIN_CAMERA_FRAME,
    BUILTIN_URDF,
    Robot,
    RobotModelError,
    builtin_urdf,
    chain_joints,
)

MOUNT = SE3.from_xyz_rpy([0.01, 0.02, 0.05], [0.0, 0.1, 0.2])


@pytest.fixture(scope="module", params=sorted(BUILTIN_URDF))
def arm(request) -> Robot:
    """Each built-in arm with a camera mounted off its flange."""
    return Robot(builtin_urdf(request.param), BUILTIN_CAMERA_FRAME[request.param], MOUNT)


def states(rng, n, count=5):
    return [(rng.uniform(-np.pi, np.pi, n), rng.normal(size=n)) for _ in range(count)]


def test_mass_matrix_is_symmetric_positive_definite(arm, rng):
    m_fun = arm.function("M", arm.mass_matrix)
    for q, qd in states(rng, arm.n):
        m = np.asarray(m_fun(q, qd))
        assert np.allclose(m, m.T, rtol=0, atol=1e-14) and np.linalg.eigvalsh(m).min() > 0


def test_mdot_minus_2c_is_skew_symmetric(arm, rng):
    """``Mdot - 2C`` skew (passivity of (33)); ``Mdot`` by AD, ``C`` by Christoffel symbols."""
    f = cs.Function("f", [arm.q, arm.qd], [arm.mass_matrix_dot - 2 * arm.coriolis])
    for q, qd in states(rng, arm.n):
        s = np.asarray(f(q, qd))
        assert np.abs(s + s.T).max() <= 1e-12 * max(1.0, np.abs(s).max())


def test_coriolis_matches_recursive_newton_euler(arm, rng):
    """``C(q, qd) qd + g(q)`` with the Christoffel ``C`` equals :attr:`Robot.bias`, the loop's, by adam's bias force
    (RNEA), an independent algorithm (docs/math.md, fact 27, (27.1))."""
    f = cs.Function("f", [arm.q, arm.qd], [arm.coriolis @ arm.qd + arm.gravity - arm.bias])
    for q, qd in states(rng, arm.n):
        assert np.abs(np.asarray(f(q, qd))).max() < 1e-10


def test_the_laws_coriolis_product_is_the_christoffel_one(arm, rng):
    """``C(q, qd) v`` as the law computes it (half the derivative of the recursive Newton-Euler bias along ``v``,
    docs/math.md, fact 27) equals the Christoffel ``C`` times ``v`` for ``v`` other than ``qd``, and
    ``v^T (Mdot - 2C) v = 0`` (the skew property of (33) for the product), to 1e-12 relative (round-off)."""
    v = cs.SX.sym("v", arm.n)
    f = cs.Function("f", [arm.q, arm.qd, v], [arm.coriolis_times(v), arm.coriolis @ v,
                                              v.T @ (arm.mass_matrix_dot @ v - 2 * arm.coriolis_times(v))])  # fmt: skip
    for q, qd in states(rng, arm.n):
        product, christoffel, quadratic = (np.asarray(x) for x in f(q, qd, rng.normal(size=arm.n)))
        assert np.abs(product - christoffel).max() <= 1e-12 * max(1.0, np.abs(christoffel).max())
        assert abs(quadratic.item()) <= 1e-12 * max(1.0, np.abs(christoffel).max())


def test_gravity_is_gradient_of_potential(arm, rng):
    """``g(q) = dU/dq`` checked by central differences (h = 1e-6; error ~1e-9 N m)."""
    g_fun = arm.function("g", arm.gravity)
    u_fun = cs.Function("U", [arm.q], [arm.potential_energy()])
    h = 1e-6
    for q, _ in states(rng, arm.n):
        fd = [(float(u_fun(q + h * e)) - float(u_fun(q - h * e))) / (2 * h) for e in np.eye(arm.n)]
        assert np.allclose(np.asarray(g_fun(q, 0)).ravel(), fd, rtol=0, atol=1e-7)


def test_body_jacobian_matches_forward_kinematics(arm, rng):
    """Column i of ``J_b`` equals ``(g^-1 dg/dq_i)^vee`` by central differences (h = 1e-6)."""
    fk = cs.Function("g", [arm.q], [arm.camera_pose.as_matrix()])
    jb = cs.Function("J", [arm.q], [arm.body_jacobian])
    h = 1e-6
    for q, _ in states(rng, arm.n):
        g_inv = np.linalg.inv(np.asarray(fk(q)))
        cols = [
            np.asarray(vee(g_inv @ (np.asarray(fk(q + h * e)) - np.asarray(fk(q - h * e))) / (2 * h))).ravel()
            for e in np.eye(arm.n)
        ]
        assert np.allclose(np.asarray(jb(q)), np.array(cols).T, rtol=0, atol=1e-8)


def test_planar_testbed_moves_in_a_horizontal_plane(rng):
    """The testbed's joint axes are vertical: no gravity torque, the camera keeps its height
    and looks straight down (optical axis -z of the world) in every configuration."""
    arm = Robot(builtin_urdf("planar2dd"), "camera_link")
    g = arm.function("g", arm.gravity)
    fk = cs.Function("g", [arm.q], [arm.camera_pose.as_matrix()])
    for q, _ in states(rng, 2):
        pose = np.asarray(fk(q))
        assert np.abs(np.asarray(g(q, 0))).max() == 0.0
        assert pose[2, 3] == pytest.approx(-0.05, abs=1e-15)
        assert np.allclose(pose[:3, 2], [0.0, 0.0, -1.0], rtol=0, atol=1e-15)


def test_puma560_matches_the_robotics_toolbox(rng):
    """The shipped Puma 560 URDF with its reflected motor inertias reproduces the Robotics
    Toolbox's DH model of the same published parameters (friction removed; gravity 9.80665 here
    and 9.81 there, so its gravity load is rescaled): mass matrix, gravity, and the flange pose
    up to the 0.672 m pedestal the toolbox puts into d_1."""
    import roboticstoolbox as rtb
    puma = rtb.models.DH.Puma560().nofriction(coulomb=True, viscous=True)
    arm = Robot(builtin_urdf("puma560"), "link6", armature=BUILTIN_ARMATURE["puma560"])
    m, g = arm.function("M", arm.mass_matrix), arm.function("g", arm.gravity)
    fk = cs.Function("g", [arm.q], [arm.camera_pose.as_matrix()])
    pedestal = np.zeros((4, 4))
    pedestal[2, 3] = puma.links[0].d
    for q, _ in states(rng, 6):
        assert np.allclose(np.asarray(m(q, 0)), puma.inertia(q), rtol=0, atol=1e-12)
        assert np.allclose(np.asarray(g(q, 0)).ravel(), puma.gravload(q) * 9.80665 / 9.81, rtol=0, atol=1e-10)
        assert np.allclose(np.asarray(fk(q)) + pedestal, puma.fkine(q).A, rtol=0, atol=1e-12)


def test_body_jacobian_matches_adam_body_fixed_jacobian(rng):
    """Without a mount, ``J_b`` equals adam's body-fixed Jacobian of the link."""
    robot = Robot(builtin_urdf("ur5"), "tool0")
    robot._kindyn.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)
    adam_jac = robot._kindyn.jacobian("tool0", cs.SX.eye(4), robot.q)[:, 6:]
    f = cs.Function("f", [robot.q], [robot.body_jacobian - adam_jac])
    for q, _ in states(rng, 6):
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


def test_joints_outside_the_camera_chain_are_frozen():
    """The Panda's fingers are not in the chain to the flange: the arm has 7 joints and the
    hand and fingers ride on it as rigid loads: the model's mass is every link's of the URDF."""
    urdf = builtin_urdf("panda")
    arm = Robot(urdf, "panda_link8")
    assert arm.joints == [f"panda_joint{i}" for i in range(1, 8)]
    masses = [float(m.get("value")) for m in ET.parse(urdf).getroot().iter("mass")]
    assert float(arm._kindyn.get_total_mass()) == pytest.approx(sum(masses), rel=1e-12)


def test_unparsable_urdf_is_an_error(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(RobotModelError, match="cannot read URDF"):
        Robot(bad, "a")


ORIGINLESS = """<?xml version="1.0"?>
<robot name="two">
  <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material>
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>{identity}<axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <link name="l1">
    <visual><geometry><box size="0.1 0.1 0.1"/></geometry>
      <material name="red"><color rgba="1 0 0 1"/><specular rgb="1 1 1"/></material></visual>
    <collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
    <inertial>{identity}<mass value="1.0"/><inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.03" iyz="0" izz="0.01"/>
    </inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.3 0 0.1" rpy="0.2 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <link name="l2"><inertial>{identity}<mass value="0.5"/>
    <inertia ixx="0.01" ixy="0" ixz="0.002" iyy="0.01" iyz="0" izz="0.005"/></inertial></link>
</robot>
"""


def test_an_inertial_or_joint_without_origin_is_the_identity_and_geometry_is_not_read(tmp_path, capfd):
    """The URDF format reads an ``<inertial>`` or a joint without ``<origin>`` as the identity: such an arm has
    the mass matrix, bias and camera pose of the same arm with the identity written out (to round-off), and a
    link's visual and collision elements and the materials are not read (nothing printed about them: the
    parser would say ``Unknown tag "specular"`` of the visual's material, an extension of Gazebo's)."""
    arms = []
    for name, identity in (("written", '<origin xyz="0 0 0" rpy="0 0 0"/>'), ("implied", "")):
        path = tmp_path / f"{name}.urdf"
        path.write_text(ORIGINLESS.format(identity=identity))
        arms.append(Robot(path, "l2"))
    q, qd = np.array([0.3, -0.4]), np.array([0.2, -0.1])
    written, implied = (cs.Function("f", [a.q, a.qd], [a.mass_matrix, a.bias, a.camera_pose.as_matrix()])(q, qd)
                        for a in arms)  # fmt: skip
    for a, b in zip(written, implied, strict=True):
        assert np.allclose(np.asarray(a), np.asarray(b), rtol=0.0, atol=1e-14)
    assert np.asarray(written[0])[0, 1] != 0.0  # the test's arm couples its joints
    out, err = capfd.readouterr()
    assert out == "" and err == ""
