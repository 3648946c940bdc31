"""The constant bounds on the mass matrix ``M(q)`` (docs/math.md, fact 10), from the URDF: the
entrywise bound ``B``, the matrix upper bound ``D_M(v)``, the lower bounds, the rate they give
and the files they refuse. These bounds hold for every ``q``; the tests sample ``q`` uniformly
in ``[-pi, pi]^n`` (every configuration of a revolute arm), the mass matrices batched with
CasADi ``map``."""

from __future__ import annotations

import math
import re
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis.envelope import kinetic_diagonal, xi_rates
from dvfc.models.inertia import InertiaModelError, mass_matrix_bounds
from dvfc.models.robot import BUILTIN_ARMATURE, BUILTIN_CAMERA_FRAME, BUILTIN_URDF, Robot, RobotModelError, builtin_urdf

DATA = Path(__file__).parent / "data"
COUNT = 10_000

OFFSET_ARM = """<robot name="offset_arm">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/><limit effort="1" velocity="1"/></joint>
  <link name="l1"><inertial><mass value="0.5"/><origin xyz="0.05 0 0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.015"/></inertial></link>
  <joint name="f1" type="fixed"><parent link="l1"/><child link="l1b"/>
    <origin xyz="0 0 0.3" rpy="1.5707963267948966 0 0"/></joint>
  <link name="l1b"><inertial><mass value="0.2"/><origin xyz="0 0.1 0" rpy="0.3 0.2 0.1"/>
    <inertia ixx="0.002" ixy="0.0005" ixz="0" iyy="0.003" iyz="0" izz="0.001"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1b"/><child link="l2"/>
    <origin xyz="0 0 0.4" rpy="0 0.4 0"/><axis xyz="1 0 0"/><limit effort="1" velocity="1"/></joint>
  <link name="l2"><inertial><mass value="2.0"/><origin xyz="0.3 0 0" rpy="0 0 0.7"/>
    <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.05" iyz="0" izz="0.04"/></inertial></link>
  <joint name="f2" type="fixed"><parent link="l2"/><child link="l2b"/>
    <origin xyz="0.1 0.2 0" rpy="0 -0.5 1.0"/></joint>
  <link name="l2b"><inertial><mass value="0.7"/><origin xyz="0 0 0.15"/>
    <inertia ixx="0.004" ixy="0" ixz="0.001" iyy="0.004" iyz="0" izz="0.002"/></inertial></link>
  <joint name="j3" type="continuous"><parent link="l2b"/><child link="l3"/>
    <origin xyz="0 0.25 0" rpy="0.2 0 0"/><axis xyz="0 0.6 0.8"/></joint>
  <link name="l3"><inertial><mass value="0.4"/><origin xyz="0.02 0.05 0.1"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.0015"/></inertial></link>
  <joint name="tool" type="fixed"><parent link="l3"/><child link="tip"/><origin xyz="0 0 0.1"/></joint>
  <link name="tip"/>
</robot>
"""
"""A three-joint arm with rotated fixed joints between its revolute joints, rotated inertial
frames, products of inertia and a tilted axis: the offsets ``o_i'^(i)`` are composed through
the fixed joints' rotations (a bound that forgot one would be exceeded here)."""


ARMS = [*sorted(BUILTIN_URDF), "light_wrist6", "offset_arm"]


def robot_named(name: str, tmp: Path) -> Robot:
    """A built-in arm, the light-wrist UR5 (``tests/data``) or the offset arm (written to ``tmp``)."""
    if name in BUILTIN_URDF:
        return Robot(builtin_urdf(name), BUILTIN_CAMERA_FRAME[name], armature=BUILTIN_ARMATURE.get(name, ()))
    if name == "light_wrist6":
        return Robot(DATA / "light_wrist6.urdf", "tool0")
    path = tmp / "offset_arm.urdf"
    path.write_text(OFFSET_ARM)
    return Robot(path, "tip")


@pytest.fixture(scope="module", params=ARMS)
def arm(request, tmp_path_factory) -> tuple[Robot, np.ndarray]:
    """An arm and ``M(q)`` at :data:`COUNT` random configurations (COUNT, n, n), seeded by the
    arm's name (evaluated once for every test of the module)."""
    robot = robot_named(request.param, tmp_path_factory.mktemp(request.param))
    rng = np.random.default_rng(sum(map(ord, request.param)))
    q = rng.uniform(-math.pi, math.pi, (robot.n, COUNT))
    m = np.asarray(cs.Function("M", [robot.q], [robot.mass_matrix]).map(COUNT)(q))
    return robot, m.reshape(robot.n, COUNT, robot.n).transpose(1, 0, 2)


def test_d_m_minus_m_is_positive_semidefinite(arm, rng):
    """(10.2): ``D_M(v) - M(q) >= 0`` at every sampled ``q`` for ``v`` the Perron vector of
    ``diag(k_xi - s)^-1 B`` (random gains and ``s``), for ``v = 1`` and for a random ``v > 0``.
    Tolerance 1e-12 ``||M||``: the eigenvalue solver's error; the smallest gap is attained by
    no entry of ``D_M`` (its rows are sums of ``B``)."""
    robot, m = arm
    bounds = robot.mass_bounds
    k_xi = rng.uniform(1.0, 30.0, robot.n)
    perron = kinetic_diagonal(bounds, k_xi, np.array([0.3]))[0]
    for d_m in (perron, bounds.upper_diagonal(np.ones(robot.n)), bounds.upper_diagonal(rng.uniform(0.1, 10, robot.n))):
        gap = np.linalg.eigvalsh(np.diag(d_m)[None] - m)[:, 0]
        assert gap.min() >= -1e-12 * np.abs(m).max()


def test_m_minus_lower_bound_is_positive_semidefinite(arm, rng):
    """(10.3): ``M(q) - P / lambda_max(mu^-1/2 Delta^T P Delta mu^-1/2) >= 0`` (plus armature) at
    every sampled ``q`` for ``P = I`` (``m_lo``) and for a random diagonal ``P >= 0``; the lower
    diagonal bounds ``M_ii(q) >= d_i`` too. A zero principal inertia gives the rigid part 0 (no
    division by zero). Tolerance 1e-12 ``||M||`` (eigenvalue solver; ``d`` is attained exactly
    on the carrier terms)."""
    robot, m = arm
    bounds = robot.mass_bounds
    scale = 1e-12 * np.abs(m).max()
    for p in (None, rng.uniform(0.0, 50.0, robot.n)):
        lower = bounds.lower(p)
        assert np.all(np.isfinite(lower)) and np.all(np.diag(lower) >= 0)
        assert np.linalg.eigvalsh(m - lower[None])[:, 0].min() >= -scale
    assert bounds.m_lo == pytest.approx(np.linalg.eigvalsh(bounds.lower())[0], rel=1e-15)
    assert np.all(np.diagonal(m, axis1=1, axis2=2) >= bounds.diagonal_lower - scale)
    if np.any(bounds.mu == 0):
        assert np.allclose(np.diag(bounds.lower()), bounds.armature)


def test_entries_are_bounded_and_the_carrier_entries_attained(arm):
    """(10.1): ``|M_ij(q)| <= B_ij`` at every sampled ``q``, with a relative tolerance 1e-12 since
    entries are attained exactly: the last joint carries every link it moves, so ``M_nn(q) =
    B_nn`` for every ``q`` (exact carrier terms), and on every arm some entry reaches its bound
    to rounding (``|M_55| / B_55 = 1 + 2e-16`` on the Puma)."""
    robot, m = arm
    b = robot.mass_bounds.upper
    assert np.allclose(b, b.T) and np.all(b >= 0)
    ratio = np.abs(m).max(axis=0) / b
    assert ratio.max() <= 1 + 1e-12
    assert ratio[-1, -1] == pytest.approx(1.0, rel=1e-12)
    assert np.abs(m[:, -1, -1] - b[-1, -1]).max() <= 1e-12 * b[-1, -1]


def test_ur5_entrywise_bound_is_the_derived_one():
    """(10.1) on the UR5 against the derivation's table (kg m^2, 4 decimals: the table's rounding),
    and its scalar bound ``lambda_max(B) = 11.83`` (the earlier full-length bound was 12.01)."""
    urdf = builtin_urdf("ur5")
    robot = Robot(urdf, BUILTIN_CAMERA_FRAME["ur5"])
    b = robot.mass_bounds.upper
    assert b[:3, :3] == pytest.approx(np.array([[6.5387, 5.3604, 2.2110], [5.3604, 4.4575, 1.9447],
                                                [2.2110, 1.9447, 1.2021]]), abs=5e-5)  # fmt: skip
    assert np.diag(b)[3:] == pytest.approx([0.3661, 0.2532, 0.0171], abs=5e-5)
    assert robot.mass_bounds.m_hi == pytest.approx(11.83, abs=5e-3)


def test_perron_rate_is_never_below_the_scalar_rate(rng):
    """(10.4): the ``xi`` rate ``2 / rho(diag(k_xi - s)^-1 B)`` is at least the scalar route's
    ``2 (min k_xi - s) / lambda_max(B)`` of the same ``B`` and at least ``min_i 2 (k_i - s) / D_M(v)_i``
    for every sampled ``v > 0``; at the Perron vector every ratio is equal (``D_M = rho (K_xi - s)``)
    and gives the rate. Random gains and ``s`` on the UR5 and the Panda; 1e-12 relative covers
    the eigen-solvers."""
    for name in ("ur5", "panda"):
        bounds = Robot(builtin_urdf(name), BUILTIN_CAMERA_FRAME[name]).mass_bounds
        n = len(bounds.mu)
        for _ in range(200):
            k_xi = rng.uniform(0.5, 30.0, n)
            s = rng.uniform(0.0, 0.99) * k_xi.min()
            rate = xi_rates(bounds, k_xi, np.array([s]))[0]
            assert rate >= 2 * (k_xi.min() - s) / bounds.m_hi * (1 - 1e-12)
            d_m = kinetic_diagonal(bounds, k_xi, np.array([s]))[0]
            assert 2 * (k_xi - s) / d_m == pytest.approx(np.full(n, rate), rel=1e-9)
            other = bounds.upper_diagonal(rng.uniform(0.01, 1.0, n))
            assert rate >= np.min(2 * (k_xi - s) / other) * (1 - 1e-12)


ONE_JOINT = """<robot name="one">
  <link name="base"/>
  <joint name="j1" type="{kind}"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1"/><axis xyz="{axis}"/><limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
  <link name="l1"><inertial><mass value="1.0"/><origin xyz="0.2 0 0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="{izz}"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="tip"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 0 1"/><limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
  <link name="tip"><inertial><mass value="0.5"/><origin xyz="0.1 0 0"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
</robot>
"""


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"axis": "0 0 2"}, "axis 0 0 2 has length 2, not 1"),
        ({"izz": "-0.1"}, "principal inertia -0.1 kg m^2 < 0"),
        ({"kind": "prismatic"}, "joint 'j1' is prismatic"),
    ],
    ids=["non-unit axis", "negative inertia", "prismatic joint"],
)
def test_files_outside_the_assumptions_are_refused_in_one_line(tmp_path, change, words):
    """A non-unit joint axis (the dynamics would not be a rigid arm's), a negative principal
    inertia on a moved link, a prismatic joint in the chain: the arm is refused with one line
    saying which (a scenario shows it as ``robot.urdf: ...``); the unchanged file is accepted."""
    values = {"kind": "revolute", "axis": "0 0 1", "izz": "0.02"}
    good = tmp_path / "good.urdf"
    good.write_text(ONE_JOINT.format(**values))
    assert Robot(good, "tip").mass_bounds.m_hi > 0
    bad = tmp_path / "bad.urdf"
    bad.write_text(ONE_JOINT.format(**{**values, **change}))
    with pytest.raises(RobotModelError) as error:
        Robot(bad, "tip")
    message = str(error.value)
    assert words in message and "\n" not in message
    with pytest.raises(InertiaModelError, match=re.escape(words)):
        mass_matrix_bounds(bad, ["j1", "j2"])
