"""The loop driven by a disturbance signal: its whole ``w = [tau_d; target velocity]`` an input, the
target's pose a state moved by it (what the lower bounds on the L2 gain and Theorem 2 from rest run).

``w`` is either an expression of ``t`` (``disturbance_input``: a symbol, for the linearisation) or a
:class:`Sinusoid` whose numbers are data (``drive``): the parametric loop
(:mod:`dvfc.analysis.parametric`) then takes them as entries of its parameter vector, so that every
design and every worst input of an arm runs one compiled structure.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import casadi as cs
import numpy as np

from dvfc.models.lie import SE3, SO3, Matrix, quaternion_rate, quaternion_to_matrix
from dvfc.models.loop import ClosedLoop
from dvfc.models.planar import TASK, PlanarLoop


@dataclass(frozen=True)
class Sinusoid:
    """``w(t) = cos_part cos(omega t) + sin_part sin(omega t)`` (a constant when ``omega = 0`` and
    ``sin_part = 0``): numbers, or entries of the parametric loop's symbol."""

    cos_part: Matrix
    sin_part: Matrix
    omega: Matrix

    def __call__(self, t: cs.SX) -> cs.SX:
        return self.cos_part * cs.cos(self.omega * t) + self.sin_part * cs.sin(self.omega * t)

    def vector(self) -> np.ndarray:
        """``[cos_part; sin_part; omega]``: the entries of the parameter vector (numbers only)."""
        return np.concatenate([np.ravel(self.cos_part), np.ravel(self.sin_part), [self.omega]]).astype(float)

    @staticmethod
    def of(vector: Matrix, size: int) -> Sinusoid:
        """The sinusoid of ``size`` inputs whose :meth:`vector` is ``vector``."""
        return Sinusoid(vector[:size], vector[size : 2 * size], vector[2 * size])


@dataclass
class DisturbanceDriven(ClosedLoop):
    """Mixin for a loop whose whole disturbance ``w = [tau_d; target velocity]`` is the signal
    ``drive(t)``, or ``disturbance_input(t)`` without one (the target's motion then becomes a state)."""

    disturbance_input: Callable[[cs.SX], cs.SX] | None = None
    drive: Sinusoid | None = None

    @cached_property
    def w(self):
        signal = self.drive or self.disturbance_input
        assert signal is not None, "a driven loop is given its disturbance"
        return signal(self.t)

    @cached_property
    def tau_d(self):
        return self.w[: self.robot.n]


@dataclass
class DrivenTargetLoop(DisturbanceDriven, ClosedLoop):
    """The loop driven by a disturbance signal ``w(t) = [tau_d; V_wo]``: the target's pose
    is a state ``(p_o, quat_o)`` moved by ``V_wo`` (5), so any ``w`` can be applied."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.p_o, self.quat_o = cs.SX.sym("p_o", 3), cs.SX.sym("quat_o", 4)
        self.quaternions = [*self.quaternions, slice(self.n_state + 3, self.n_state + 7)]
        self.state = cs.vertcat(self.state, self.p_o, self.quat_o)
        self.n_state += 7

    @cached_property
    def target_pose(self) -> SE3:
        return SE3(self.p_o, SO3(quaternion_to_matrix(self.quat_o)))

    @cached_property
    def relative_pose(self) -> SE3:
        return self.robot.camera_pose.inverse() @ self.target_pose

    @cached_property
    def state_rate(self):
        v = self.w[self.robot.n :]
        target = cs.vertcat(self.target_pose.rotation.matrix @ v[0:3], quaternion_rate(self.quat_o, v[3:6]))
        return cs.vertcat(super().state_rate, target)


@dataclass
class DrivenPlanarLoop(DisturbanceDriven, PlanarLoop):
    """The reduced planar loop driven by ``w(t) = [tau_d; v_o]``: the target's horizontal
    position ``o`` is a state moved by ``v_o``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.o = cs.SX.sym("o", TASK)
        self.state = cs.vertcat(self.state, self.o)
        self.n_state += TASK

    @cached_property
    def target_position(self):
        return self.o

    @cached_property
    def state_rate(self):
        return cs.vertcat(super().state_rate, self.w[self.robot.n :])
