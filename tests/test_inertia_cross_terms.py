"""Fact 10.1's off-diagonal terms: on a spherical wrist every link's centre of mass lies on every
axis, so ``M(q) = sum_L Jw_L^T S_L Jw_L`` has no translational part and its off-diagonal entries
are exactly the rotational cross terms ``a_i^T S_L a_j`` that the bound covers by
``|S_L a_c|`` (one index the carrier) and ``lambda_max(I_L)`` (neither). The mass matrix is the
dynamics library's (adam-robotics through :class:`dvfc.models.robot.Robot`), evaluated on a dense
grid of the two angles it depends on: a brute-force maximum of ``|M_ij(q)|``."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from dvfc.models.robot import Robot

SPHERICAL_WRIST = """<robot name="wrist">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit effort="1" velocity="1"/></joint>
  <link name="l1"><inertial><mass value="0.1"/><origin xyz="0 0 0"/>
    <inertia ixx="1e-4" ixy="0" ixz="0" iyy="2e-4" iyz="0" izz="1.5e-4"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0" rpy="0 0.4 0"/><axis xyz="1 0 0"/><limit effort="1" velocity="1"/></joint>
  <link name="l2"><inertial><mass value="0.1"/><origin xyz="0 0 0" rpy="0.2 0 0.5"/>
    <inertia ixx="2e-4" ixy="5e-5" ixz="0" iyy="1e-4" iyz="2e-5" izz="3e-4"/></inertial></link>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0 0 0" rpy="0.3 0 0"/><axis xyz="0 0 1"/><limit effort="1" velocity="1"/></joint>
  <link name="l3"><inertial><mass value="1.0"/><origin xyz="0 0 0" rpy="0.1 -0.6 0.2"/>
    <inertia ixx="0.01" ixy="0.02" ixz="0.01" iyy="0.05" iyz="0.005" izz="0.04"/></inertial></link>
  <joint name="tool" type="fixed"><parent link="l3"/><child link="tip"/><origin xyz="0 0 0.05"/></joint>
  <link name="tip"/>
</robot>
"""
"""Three revolute joints through one point, tilted fixed rotations between them, rotated inertial
frames with products of inertia, and a heavy last link: its cross terms with joints 1 and 2 (neither
index its carrier) and with joint 3 (its carrier) are most of ``M``'s off-diagonal entries."""


@pytest.fixture(scope="module")
def wrist(tmp_path_factory) -> tuple[Robot, np.ndarray]:
    """The wrist and ``|M(q)|`` on a 241 x 241 grid of ``(q2, q3)`` in ``[-pi, pi]^2`` (``M`` does not
    depend on ``q1``), its entrywise maximum (3, 3)."""
    path = tmp_path_factory.mktemp("wrist") / "wrist.urdf"
    path.write_text(SPHERICAL_WRIST)
    robot = Robot(path, "tip")
    angles = np.linspace(-np.pi, np.pi, 241)
    q2, q3 = np.meshgrid(angles, angles)
    q = np.vstack([np.zeros(q2.size), q2.ravel(), q3.ravel()])
    m = np.asarray(cs.Function("M", [robot.q], [robot.mass_matrix]).map(q.shape[1])(q))
    return robot, np.abs(m.reshape(3, -1, 3)).max(axis=1)


def test_inertia_bound_dominates_mass_matrix_entrywise_with_cross_terms(wrist):
    """(10.1) ``|M_ij(q)| <= B_ij`` on the grid for every entry, off the diagonal in particular
    (tolerance 1e-12 relative: rounding; the carrier entry ``M_33 = a_3^T S_3 a_3`` is attained
    exactly, ``B_33`` to 1e-12). The off-diagonal entries the bound must cover are not small:
    ``max |M_12|``, ``max |M_13|`` and ``max |M_23|`` (0.041, 0.046, 0.019 kg m^2) are each above a
    quarter of the carrier entry ``B_33`` (0.042), so a bound without its rotational cross terms
    (0.0003 for ``B_12``) or with ``a_c^T S a_c`` (0.042) in place of ``|S a_c|`` (0.046, attained by
    ``M_13``) falls below them."""
    robot, worst = wrist
    b = robot.mass_bounds.upper
    assert np.all(worst <= b * (1 + 1e-12)), worst / b
    assert worst[2, 2] == pytest.approx(b[2, 2], rel=1e-12)
    off = worst[np.triu_indices(3, 1)]
    assert np.all(off > b[2, 2] / 4), off
