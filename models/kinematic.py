"""The visual feedback system (26) alone: relative motion (9) and observer (12), driven
directly by the camera velocity ``V_wc`` and the estimation input ``u_e`` (Lemma 1).

State: the relative pose ``g = (p, R)`` and the estimate ``gbar = (pbar, Rbar)``, rotations
as unit quaternions. Storages:

- ``V_r = |p|^2/2 + phi(R)`` (remark after (9)): ``dV_r/dt = V_wc^T (-e_r)`` when ``V_wo = 0``;
- ``V_e = |p_ee|^2/2 + phi(R_ee)`` (remark after (23)): ``dV_e/dt = u_e^T (-e_e)``;
- ``V_ce`` (29): ``dV_ce/dt = u_ce^T nu_ce`` (31), ``nu_ce`` of (28), Lemma 1.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import casadi as cs

from dvfc.models.lie import SE3, SO3, Matrix, quaternion_rate, quaternion_to_matrix


@dataclass
class VisualFeedbackSystem:
    """(26) with inputs ``V_wc(t)``, ``u_e(t)`` and a static target (``V_wo = 0``)."""

    reference: SE3
    camera_velocity: Callable[[cs.SX], Matrix]
    estimation_input: Callable[[cs.SX], Matrix]

    def __post_init__(self) -> None:
        self.t = cs.SX.sym("t")
        self.p, self.quat = cs.SX.sym("p", 3), cs.SX.sym("quat", 4)
        self.pbar, self.quatbar = cs.SX.sym("pbar", 3), cs.SX.sym("quatbar", 4)
        self.state = cs.vertcat(self.p, self.quat, self.pbar, self.quatbar)
        self.v_wc = self.camera_velocity(self.t)
        self.u_e = self.estimation_input(self.t)

    @cached_property
    def pose(self) -> SE3:
        return SE3(self.p, SO3(quaternion_to_matrix(self.quat)))

    @cached_property
    def estimate(self) -> SE3:
        return SE3(self.pbar, SO3(quaternion_to_matrix(self.quatbar)))

    @staticmethod
    def _rate(g: SE3, quat: Matrix, twist: Matrix) -> Matrix:
        return cs.vertcat(g.rotation.matrix @ twist[0:3], quaternion_rate(quat, twist[3:6]))

    @cached_property
    def state_rate(self) -> Matrix:
        """(9) with ``V_wo = 0`` and (12): ``V = -Ad_{g^-1} V_wc``, ``Vbar = -Ad_{gbar^-1} V_wc + u_e``."""
        v = -self.pose.inverse().adjoint() @ self.v_wc
        vbar = -self.estimate.inverse().adjoint() @ self.v_wc + self.u_e
        return cs.vertcat(self._rate(self.pose, self.quat, v), self._rate(self.estimate, self.quatbar, vbar))

    @cached_property
    def errors(self) -> tuple[SE3, SE3]:
        """``(g_ec, g_ee)`` of (24) and (15)."""
        return self.reference.inverse() @ self.estimate, self.estimate.inverse() @ self.pose

    @cached_property
    def storages(self) -> Matrix:
        """``[V_r, V_e, V_ce]``."""
        g_ec, g_ee = self.errors
        total = lambda g: cs.sum1(g.error_function())  # noqa: E731  |p|^2/2 + phi(R)
        return cs.vertcat(total(self.pose), total(g_ee), total(g_ec) + total(g_ee))

    @cached_property
    def supplies(self) -> Matrix:
        """``[V_wc^T (-e_r), u_e^T (-e_e), u_ce^T nu_ce]`` with ``nu_ce`` of (28)."""
        g_ec, g_ee = self.errors
        e_c, e_e, e_r = g_ec.error_vector(), g_ee.error_vector(), self.pose.error_vector()
        ad_d = self.reference.inverse().adjoint()
        nu_c = -ad_d.T @ e_c
        nu_e = g_ec.rotation.adjoint().T @ e_c - e_e
        u_ce = cs.vertcat(self.v_wc, self.u_e)
        return cs.vertcat(-self.v_wc.T @ e_r, -self.u_e.T @ e_e, u_ce.T @ cs.vertcat(nu_c, nu_e))
