"""Target motions: the object's pose ``g_wo(t)`` and body velocity ``V_wo(t)`` (5).

Each motion is a closed-form function of time; ``V_wo = (g_wo^-1 dg_wo/dt)^vee`` is
obtained by automatic differentiation of that closed form, so it is exact.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as cs
import numpy as np

from dvfc.models.lie import SE3, SO3, Matrix, vee


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two orthonormal vectors spanning the plane with the given normal."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    a = np.cross(n, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(n, a)


@dataclass(frozen=True)
class TargetMotion:
    """Rigid motion of the target in the world frame.

    Parameters
    ----------
    start
        ``g_wo(0)``.
    radius, period, normal
        Circular translation of the origin, starting at ``start``, in the plane with
        the given world normal (``radius = 0``: no translation).
    spin_axis, spin_rate
        Rotation about an axis fixed in the object frame at ``spin_rate`` rad/s.
    """

    start: SE3
    radius: float = 0.0
    period: float = 1.0
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    spin_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    spin_rate: float = 0.0

    def pose(self, t: Matrix) -> SE3:
        """``g_wo(t)``."""
        a, b = plane_basis(np.array(self.normal))
        omega = 2 * np.pi / self.period
        offset = self.radius * ((cs.cos(omega * t) - 1) * cs.DM(a) + cs.sin(omega * t) * cs.DM(b))
        axis = np.asarray(self.spin_axis, dtype=float)
        spin = SO3.exp(cs.DM(axis / np.linalg.norm(axis)) * (self.spin_rate * t))
        return SE3(self.start.translation + offset, self.start.rotation @ spin)

    def at_rest(self) -> TargetMotion:
        """The same target held at ``start``: no radius, no spin (the motion's other numbers kept, so that a
        loop with it runs the moving target's compiled functions, whose radius is an input)."""
        return replace(self, radius=0.0, spin_rate=0.0)

    @property
    def speed(self) -> float:
        """``|v|`` of ``V_wo = [v; w]``: the origin's speed on its circle, ``2 pi radius / period``
        (the body frame rotates the world velocity, keeping its length)."""
        return 2 * np.pi * self.radius / self.period

    @property
    def rate(self) -> float:
        """``|w|`` of ``V_wo``: the spin rate."""
        return abs(self.spin_rate)

    @property
    def motion_period(self) -> float | None:
        """The period of ``g_wo(t)``: the circle's, or the spin's ``2 pi / |spin_rate|``; None when the
        target is at rest, or circles and spins (no common period is sought)."""
        circles, spins = self.radius != 0, self.spin_rate != 0
        if circles == spins:
            return None
        return self.period if circles else 2 * np.pi / abs(self.spin_rate)

    def velocity(self, t: cs.SX) -> Matrix:
        """``V_wo(t) = (g_wo^-1 dg_wo/dt)^vee`` (5), exact by automatic differentiation."""
        g = self.pose(t)
        gdot = cs.reshape(cs.jacobian(cs.vec(g.as_matrix()), t), 4, 4)
        return vee(g.inverse().as_matrix() @ gdot)
