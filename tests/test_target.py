"""Target motion: ``V_wo = (g_wo^-1 dg_wo/dt)^vee`` (5) checked by finite differences."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from dvfc.models.lie import SE3, vee
from dvfc.models.target import TargetMotion

START = SE3.from_xyz_rpy([0.4, 0.1, 0.1], [np.pi, 0.0, -np.pi / 2])
MOTIONS = {
    "static": TargetMotion(START),
    "circle": TargetMotion(START, radius=0.05, period=4.0, normal=(0.0, 0.3, 1.0)),
    "circle_spin": TargetMotion(START, radius=0.05, period=4.0, spin_axis=(0.0, 0.0, 1.0), spin_rate=0.5),
}


@pytest.mark.parametrize("kind", MOTIONS)
def test_body_velocity_matches_finite_differences(kind):
    """Central differences, h = 1e-6: truncation ~1e-12, round-off ~1e-10."""
    motion = MOTIONS[kind]
    t = cs.SX.sym("t")
    pose = cs.Function("g", [t], [motion.pose(t).as_matrix()])
    velocity = cs.Function("V", [t], [motion.velocity(t)])
    h = 1e-6
    for time in (0.0, 0.7, 3.1):
        g = np.asarray(pose(time))
        fd = vee(np.linalg.inv(g) @ (np.asarray(pose(time + h)) - np.asarray(pose(time - h))) / (2 * h))
        assert np.allclose(np.asarray(velocity(time)), np.asarray(fd), rtol=0, atol=1e-8)


def test_circle_starts_at_start_and_has_radius():
    """The circle starts at the start pose (exactly: the offset is ``radius (cos 0 - 1) = 0``, so
    1e-15 is round-off of O(1) coordinates) with the stated radius (half the chord over half a
    period; 1e-12 is round-off of sines and cosines of O(1) arguments)."""
    motion = MOTIONS["circle"]
    t = cs.SX.sym("t")
    p = cs.Function("p", [t], [motion.pose(t).translation])
    p0 = np.asarray(p(0.0)).ravel()
    assert np.allclose(p0, np.asarray(START.translation).ravel(), rtol=0, atol=1e-15)
    radii = [np.linalg.norm(np.asarray(p(s)).ravel() - np.asarray(p(s + 2.0)).ravel()) / 2 for s in (0.0, 0.5, 1.3)]
    assert np.allclose(radii, 0.05, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", MOTIONS)
def test_a_target_at_rest_stays_at_its_start(kind):
    """:meth:`TargetMotion.at_rest`: ``g_wo(t) = g_wo(0)`` and ``V_wo = 0`` at every time (exactly: zero radius
    and spin rate multiply every term of the motion), the motion's period and axes kept."""
    motion = MOTIONS[kind].at_rest()
    t = cs.SX.sym("t")
    pose = cs.Function("g", [t], [motion.pose(t).as_matrix()])
    velocity = cs.Function("V", [t], [motion.velocity(t)])
    for time in (0.0, 0.7, 3.1):
        assert np.array_equal(np.asarray(pose(time)), np.asarray(START.as_matrix()))
        assert not np.asarray(velocity(time)).any()
    assert (motion.period, motion.normal, motion.spin_axis) == (MOTIONS[kind].period, MOTIONS[kind].normal,
                                                                MOTIONS[kind].spin_axis)  # fmt: skip
