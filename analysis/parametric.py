"""The loop with its design as an input: gains, weights and reference as a parameter vector,
with the target's circle radius and, for a loop with a plant, the plant's masses.

The simulators build their functions (compiled to C under ``jit``) from the loop with
symbolic gains, weights, reference, target radius and plant (:func:`symbolic`), once per arm
and loop structure, and pass a design's numbers (:func:`parameter_vector`) at run time::

    p = [k_xi (n); k_c (6); k_e (6); w_pc; w_rc; w_pe; w_re; p_d (3); vec(R_d) (9, column-major);
         radius; (mass_scale; payload mass; payload com (3); payload inertia (6)) with a plant;
         (k_i (n); integral_start) with integral action;
         (ReferencePlan.vector (20): the planned start's pose, path, duration and hold) with a plan;
         (cos part (n + 6); sin part (n + 6); omega) driven by a sinusoid]

so that the generated code, and the compiled library cached by the hash of its source, does
not depend on the design: another design of the same arm, another target radius, another
payload or mass scale of the plant, another planned start (its start pose, duration and hold: the
latency sets the hold) or another time integral action starts from runs the same code. The
plant's masses are inputs because rigid-body dynamics are linear in the inertial parameters
(:class:`InertialPlant`). The loop with numbers stays the one every analysis (certificates,
linearisation) uses.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import casadi as cs
import numpy as np

from dvfc.models.driven import DrivenTargetLoop, Sinusoid
from dvfc.models.lie import SE3, SO3, Matrix, hat, vee
from dvfc.models.loop import ClosedLoop, Gains, ReferencePlan, Weights
from dvfc.models.robot import Payload, Robot
from dvfc.models.target import TargetMotion

CACHE_SIZE = 8
"""Symbolic loops kept (least recently used dropped): one per arm and loop structure in use."""

_symbolic: OrderedDict[tuple, tuple[tuple, ClosedLoop]] = OrderedDict()


def parametrised(loop: ClosedLoop) -> bool:
    """Whether the loop's design enters its functions as :func:`parameter_vector`: the paper's
    loop, and the paper's loop driven by a :class:`~dvfc.models.driven.Sinusoid` (the run from rest), whose
    numbers enter too (the reduced planar loop keeps its numbers in its expressions)."""
    return type(loop) is ClosedLoop or (type(loop) is DrivenTargetLoop and _drive(loop) is not None)


def _drive(loop: ClosedLoop) -> Sinusoid | None:
    """The sinusoid driving the paper's loop, whose numbers are entries of ``p``; None: none."""
    return loop.drive if isinstance(loop, DrivenTargetLoop) else None


def _drive_size(loop: ClosedLoop) -> int:
    """Entries of ``p`` for the loop's sinusoid: ``2 (n + 6) + 1`` when driven by one, else none."""
    return 0 if _drive(loop) is None else 2 * (loop.robot.n + loop.task_dim) + 1


PLANT_ENTRIES = 11
"""Entries of ``p`` for a loop with a plant: its mass scale and its payload's mass, centre of
mass and inertia."""

GRAVITY = (0.0, 0.0, -9.80665)
"""The world's gravity (m/s^2), adam-robotics' default that :class:`Robot`'s ``g(q)`` has."""


@dataclass(frozen=True)
class Inputs:
    """The loop's quantities that enter ``p`` besides the design: the target's circle radius
    and, for a loop with a plant, the plant's mass scale and payload (None: none). A run with
    other values runs the same compiled code."""

    radius: float
    mass_scale: float = 1.0
    payload: Payload | None = None

    @staticmethod
    def of(target: TargetMotion, plant: Robot | None) -> Inputs:
        """A numeric loop's own: its ``target``'s radius, its ``plant``'s masses."""
        if plant is None:
            return Inputs(float(target.radius))
        return Inputs(float(target.radius), plant.mass_scale, plant.payload)

    def vector(self, plant: bool) -> np.ndarray:
        """The entries of ``p`` after the design: ``[radius]``, then with a ``plant`` its
        :data:`PLANT_ENTRIES`."""
        if not plant:
            if self.mass_scale != 1.0 or self.payload is not None:
                raise ValueError("a mass scale or payload needs a loop with a plant")
            return np.array([self.radius])
        body = self.payload or Payload(0.0)
        return np.array([self.radius, self.mass_scale, body.mass, *body.com, *body.inertia], dtype=float)


def parameter_count(n: int, plant: bool = False, integral: bool = False) -> int:
    """Entries of the parameter vector of an arm with ``n`` joints (with a ``plant``: its masses
    too; with ``integral`` action: ``K_I`` and the time it starts from)."""
    return n + 2 * ClosedLoop.task_dim + 4 + 3 + 9 + 1 + (PLANT_ENTRIES if plant else 0) + (n + 1 if integral else 0)


def _plan_size(loop: ClosedLoop) -> int:
    """Entries of ``p`` for the loop's planned reference: :data:`ReferencePlan.ENTRIES` with one, else none."""
    return 0 if loop.plan is None else ReferencePlan.ENTRIES


def parameter_vector(loop: ClosedLoop, inputs: Inputs | None = None) -> np.ndarray | None:
    """``p`` of the module's description for the numeric ``loop``, with ``inputs`` in place of
    the loop's own (:meth:`Inputs.of` its target and plant); None when the loop is not :func:`parametrised`."""
    if not parametrised(loop):
        return None
    g, r = loop.gains, loop.reference
    translation = np.asarray(cs.DM(r.translation), dtype=float).ravel()
    rotation = np.asarray(cs.DM(r.rotation.matrix), dtype=float).ravel(order="F")
    extra = (inputs or Inputs.of(loop.target, loop.plant)).vector(loop.plant is not None)
    k_i = [] if g.k_i is None else [g.k_i, [loop.integral_start]]
    plan = [] if loop.plan is None else [loop.plan.vector()]
    drive = [] if (sinusoid := _drive(loop)) is None else [sinusoid.vector()]
    return np.concatenate(
        [g.k_xi, g.k_c, g.k_e, loop.weights.as_array(), translation, rotation, extra, *k_i, *plan, *drive]
    ).astype(float)


@dataclass(frozen=True)
class InertialPlant:
    """The arm ``robot`` as the plant is, as expressions of symbolic masses ``masses``
    (:data:`PLANT_ENTRIES`: mass scale ``s``, payload mass ``m``, centre of mass ``c`` in the
    link frame, inertia about it ``[ixx, ixy, ixz, iyy, iyz, izz]``): the URDF's links scaled
    by ``s`` and the payload fixed to the camera link (:func:`dvfc.models.robot.perturbed_urdf`).

    Rigid-body dynamics are linear in the links' masses and inertias, so the links contribute
    ``s M_links(q)`` and ``s (C qd + g)_links`` (the armature is not scaled); the payload adds
    ``M_b = m J_c^T J_c + J_w^T I_c J_w`` (``J_c`` the Jacobian of its centre of mass in the
    world, ``J_w`` of the link's body angular velocity ``w``), the Newton-Euler ``C_b = m J_c^T
    dJ_c/dt + J_w^T (I_c dJ_w/dt + hat(w) I_c J_w)`` (its ``C_b qd`` the Christoffel one's, at a
    directional derivative's cost) and ``g_b = -m J_c^T g_world``."""

    robot: Robot
    masses: cs.SX

    @property
    def q(self) -> cs.SX:
        return self.robot.q

    @property
    def qd(self) -> cs.SX:
        return self.robot.qd

    @cached_property
    def _payload(self) -> tuple[Matrix, Matrix, Matrix]:
        """``(M_b, C_b, g_b)`` of the payload."""
        r, m, com = self.robot, self.masses[1], self.masses[2:5]
        xx, xy, xz, yy, yz, zz = (self.masses[5 + i] for i in range(6))
        inertia = cs.vertcat(cs.horzcat(xx, xy, xz), cs.horzcat(xy, yy, yz), cs.horzcat(xz, yz, zz))
        rotation = r.link_pose.rotation.matrix
        j_c = cs.jacobian(r.link_pose.translation + rotation @ com, r.q)
        spin = (rotation.T @ cs.reshape(cs.jacobian(cs.vec(rotation), r.q[i]), 3, 3) for i in range(r.n))
        j_w = cs.horzcat(*map(vee, spin))
        rate = lambda j: cs.reshape(cs.jtimes(cs.vec(j), r.q, r.qd), 3, r.n)  # noqa: E731 (dJ/dt)
        coriolis = m * (j_c.T @ rate(j_c)) + j_w.T @ (inertia @ rate(j_w) + hat(j_w @ r.qd) @ inertia @ j_w)
        return m * (j_c.T @ j_c) + j_w.T @ inertia @ j_w, coriolis, -m * (j_c.T @ cs.DM(GRAVITY))

    @cached_property
    def mass_matrix(self) -> Matrix:
        r = self.robot
        armature = cs.diag(cs.DM(r.armature)) if r.armature else cs.DM.zeros(r.n, r.n)
        return self.masses[0] * r.rigid_mass_matrix + armature + self._payload[0]

    @cached_property
    def bias(self) -> Matrix:
        """``C qd + g``: the links' scaled, the payload's added."""
        return self.masses[0] * self.robot.bias + self._payload[1] @ self.qd + self._payload[2]


def _structure(loop: ClosedLoop) -> tuple:
    """What a loop's functions depend on besides its design: the objects (held by identity:
    ``dataclasses.replace`` of a loop keeps them) and the flags. The target and the plant enter by value: a
    target at rest is made anew for every run from rest and every linearisation, a plant for every draw of its
    masses (which are entries of ``p``: the plant's arm is what counts); of a planned reference only whether
    there is one (its numbers are entries of ``p``)."""
    objects = (loop.robot, loop.camera, loop.inputs, *loop.disturbances)
    flags: tuple = (type(loop), loop.mode, loop.sampled, loop.ramp, len(loop.disturbances), loop.performance,
                    _target_key(loop.target), None if loop.plant is None else _arm_key(loop.plant),
                    loop.plan is not None)  # fmt: skip
    if loop.integral or loop.friction is not None or loop.compensation is not None:
        numbers = (None if v is None else tuple(map(float, v)) for v in (loop.friction, loop.compensation))
        flags = (*flags, loop.integral, *numbers)
    return objects, flags


def _target_key(target: TargetMotion) -> tuple:
    """The target's motion but its radius (an entry of ``p``), by value."""
    start = tuple(np.asarray(cs.DM(target.start.as_matrix())).ravel())
    return start, float(target.period), tuple(target.normal), tuple(target.spin_axis), float(target.spin_rate)


def _arm_key(robot: Robot) -> tuple:
    """A plant's arm as :func:`_same_arm` compares it: its URDF, link and armature (its masses are in ``p``)."""
    return robot.urdf, robot.frame, tuple(robot.armature)


def symbolic(loop: ClosedLoop) -> ClosedLoop:
    """``loop`` with its gains, weights and reference the entries of a symbol ``p``
    (:attr:`~dvfc.models.loop.ClosedLoop.parameters`), built once per arm and structure and
    shared by every design of it; ``loop`` itself when it is not :func:`parametrised`."""
    if not parametrised(loop):
        return loop
    objects, flags = _structure(loop)
    key = (tuple(map(id, objects)), flags)
    if key in _symbolic:
        _symbolic.move_to_end(key)
        return _symbolic[key][1]
    n, task = loop.robot.n, loop.task_dim
    plant = loop.plant is not None
    driving, planning = _drive_size(loop), _plan_size(loop)
    p = cs.SX.sym("p", parameter_count(n, plant, loop.integral) + planning + driving)
    k_xi, k_c, k_e = p[:n], p[n : n + task], p[n + task : n + 2 * task]
    w = p[n + 2 * task : n + 2 * task + 4]
    position = p[n + 2 * task + 4 : n + 2 * task + 7]
    end = n + 2 * task + 16
    rotation = cs.reshape(p[n + 2 * task + 7 : end], 3, 3)
    changes: dict[str, Any] = {"drive": Sinusoid.of(p[p.shape[0] - driving :], n + task)} if driving else {}
    reference = SE3(position, SO3(rotation))
    if planning:
        changes["plan"] = ReferencePlan.of(p[p.shape[0] - driving - planning : p.shape[0] - driving], reference)
    after_k_i = p.shape[0] - driving - planning - 1
    k_i = p[after_k_i - n : after_k_i] if loop.integral else None
    if loop.integral:
        changes["integral_start"] = p[after_k_i]
    model = replace(
        loop,
        **changes,
        gains=Gains(k_xi, k_c, k_e, k_i),
        weights=Weights(w[0], w[1], w[2], w[3]),
        reference=reference,
        target=replace(loop.target, radius=p[end]),
        plant=None if not plant else InertialPlant(_same_arm(loop), p[end + 1 : end + 1 + PLANT_ENTRIES]),  # type: ignore[arg-type]
        parameters=p,
    )
    _symbolic[key] = (objects, model)  # the objects held: their ids stay theirs while cached
    if len(_symbolic) > CACHE_SIZE:
        _symbolic.popitem(last=False)
    return model


def _same_arm(loop: ClosedLoop) -> Robot:
    """The law's arm, whose URDF, link and armature the plant shares (ValueError otherwise): the
    plant differs only by its masses."""
    r, plant = loop.robot, loop.plant
    assert plant is not None, "called for a loop with a plant"
    if (plant.urdf, plant.frame, plant.armature) != (r.urdf, r.frame, r.armature):
        raise ValueError("the plant must be the law's arm with other masses (its URDF, link and armature)")
    return r
