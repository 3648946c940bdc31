"""A local certificate of the loop as implemented (docs/math.md, fact 14): the exact
discretisation of the sampled multirate loop, linearised at its static-target equilibrium.

The loop is :class:`dvfc.analysis.sampled.SampledSimulator`'s, the controller program's
(:mod:`dvfc.analysis.controller`): the torque computed at each control sample and held over the
period, the observer stepped at each sample by the exact flow of (12) with its inputs ``V_wc``
and ``u_e`` held (docs/math.md, fact 22), an image captured at the first control sample at or
after each camera tick and used ``latency`` later, ``e_e`` held from one image to the next. Its
exogenous inputs are set to zero: the target at rest at its start pose, no torque
disturbance, no pixel noise. Linearised at the equilibrium (``q = q_eq``, ``qd = 0``,
``gbar = g_d``, ``e = 0``, held torque ``g(q_eq)``) in ``z = [dq; dqd; dpbar; dthetabar]``
(``Rbar = Rbar* exp(dthetabar)``), with the observer's held inputs ``o = [V_k; U_k]``:

    dz/dt = A z + B_tau (tau - g(q_eq)) + B_e e + B_o o,
    tau_k = g(q_eq) + F z_k + F_e e_k,    o_k = O z_k + O_e e_k,    e_e = C z.

One control period is ``z_(k+1) = A_z z_k + A_e e_k`` with ``[Phi, G_tau, G_e, G_o]`` the first
block row of ``expm([[A, B_tau, B_e, B_o], [0, 0, 0, 0]] h)``, ``A_z = Phi + G_tau F + G_o O``,
``A_e = G_tau F_e + G_e + G_o O_e`` (exact: no integration error; the observer's rows of ``Phi`` are
those of the identity, its step the exact flow). The images in flight are extra
discrete states; over one common period of the control and camera schedules (``P`` control
periods, the control/camera ratio rational) the product of the step maps is the monodromy
``Pi``. If ``rho(Pi) < 1`` the equilibrium of the nonlinear sampled loop is locally
exponentially stable with every rate below ``-ln(rho) / (P h)``; the certificate is the
strict discrete Lyapunov inequality for ``P_L = dlyap(Pi^T, I)``, checked a posteriori.

On a redundant arm (``n > 6``) the equilibria at rest are a manifold ``E`` of dimension ``n - 6``
(the self-motion: every ``q`` with the camera at the reference, ``J_b(q_eq)`` of full row rank), so
its tangent ``T = [null(J_b(q_eq)); 0]`` is fixed by ``Pi`` and ``rho(Pi) = 1``. The statement is
then about ``Pi_T = Q^T Pi Q`` (``Q`` an orthonormal basis of ``T``'s complement: ``Pi`` is
block-triangular in ``[T, Q]``): ``rho(Pi_T) < 1`` makes ``E`` locally exponentially attracting,
every nearby run converging to one of its equilibria (:func:`transverse`; docs/math.md, fact 14).

With integral action (docs/math.md, fact 21) ``z`` ends with ``z_I``, held over the period
(no rate) and updated at each sample, ``z_I <- z_I + h (X z_k + X_e e_k)`` (``xi = X z + X_e e``
linearised), the law reading ``-K_I z_I``: ``6 + n`` more states (36 on a 6-joint arm). The
plant's viscous friction ``b qd`` is in the linearisation, ``A -> A - B_tau diag(b) S_qd``
(:meth:`HeldLinearization.with_friction`); its dry friction, whatever its model, is a torque bounded by
its Coulomb level ``c``, whose effect at rest :mod:`dvfc.analysis.dry_friction` bounds (fact 29): no
smoothing width enters a verdict.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from fractions import Fraction
from typing import Any

import casadi as cs
import numpy as np

from dvfc.analysis.dry_friction import DryFrictionCheck, dry_friction_check
from dvfc.analysis.implementation import Implementation
from dvfc.analysis.linearize import _quaternion_product, equilibrium_configuration
from dvfc.analysis.parametric import parameter_vector, symbolic
from dvfc.analysis.simulate import Settings
from dvfc.models.camera import Camera
from dvfc.models.errors import PlantErrors, controller_features, true_features
from dvfc.models.loop import ClosedLoop
from dvfc.models.planar import PlanarLoop
from dvfc.models.robot import JointLimits, Robot, spans_the_task

LYAPUNOV_MARGIN = 0.5
"""Smallest ``lambda_min(P_L - Pi^T P_L Pi)`` accepted (1 in exact arithmetic)."""

RHO_MARGIN = 1e-9
"""``rho(Pi)`` must be below ``1 - RHO_MARGIN``: a spectral radius of 1 to rounding (a
continuum of equilibria) is never certified."""

RATIO_DENOMINATOR = 10_000
"""Largest denominator of the control/camera rate ratio read as a rational number."""

RANGES = {"latency": 0.25, "camera_rate": 1.0, "control_rate": 10.0}
"""End of each margin's searched range: latency (s), camera rate (Hz), control rate (Hz)."""

UNITS = {"latency": "s", "camera_rate": "Hz", "control_rate": "Hz"}

SCOPE = (
    "local exponential stability of the equilibrium of the sampled multirate loop as implemented (torque held at "
    "the control rate, the observer stepped at each sample by the exact flow of (12) with the sampled camera "
    "velocity and u_e held, as the controller program does, images captured at the first control sample at or "
    "after each camera tick and used the latency later), "
    "linearised: the target at rest at its start pose, no torque disturbance, no pixel noise, near the "
    "equilibrium configuration q_eq (no radius is computed); for e_e exact (15) and from the image (21), whose "
    "linearisations at the equilibrium coincide (gap {gap:.2g}); every rate below -ln(rho)/period"
)

SELF_MOTION_SCOPE = (
    "; on the redundant arm, of the manifold of equilibria (the self-motion, dimension {m}: the poses near q_eq "
    "where the loop rests, checked to be equilibria at poses up to 0.05 rad along it, tangent null(J_b(q_eq)) fixed "
    "by Pi): rho is that of Pi across it, Q^T Pi Q, and a run starting near converges to one posture of the "
    "self-motion, not controlled"
)


@dataclass(frozen=True)
class HeldLinearization:
    """The sampled loop linearised at its equilibrium with the held torque ``tau`` and the
    held ``e`` as inputs (see the module's description).

    Parameters
    ----------
    a, b_tau, b_e, b_o
        ``dz/dt = a z + b_tau (tau - tau_eq) + b_e e + b_o o``, ``o = [V_k; U_k]`` the observer's held
        inputs (docs/math.md, fact 22).
    f, f_e
        The law (35), (42) evaluated with ``e``: ``tau = tau_eq + f z + f_e e``.
    o, o_e
        The observer's inputs at the sample, ``[J_b qd; u_e] = o z + o_e e``.
    c, c_image
        ``e_e`` (15) and its image estimate (21) from the true features: ``c z``, ``c_image z``.
    q_eq, tau_eq
        The equilibrium configuration and torque ``g(q_eq)``.
    xi, xi_e
        With integral action: ``xi = xi z + xi_e e`` at the sample, whose ``h`` multiple is the
        update of ``z_I``, the last ``n`` entries of ``z`` (None: no integral state).
    self_motion
        An orthonormal basis (``n x (n - 6)``) of ``null(J_b(q_eq))``: the tangent of the
        equilibria's manifold in ``dq`` (no columns on a 6-joint arm).
    state, e_eq
        The state ``[q; qd; pbar; quat; z_I]`` and the held ``e`` at the equilibrium (None: the model's,
        ``gbar = g_d``, ``e = 0``).
    self_motion_equilibria
        On a redundant arm, whether the self-motion's poses near ``q_eq`` are equilibria
        (:class:`SelfMotionCheck`); None on a 6-joint arm.
    tangent
        On a redundant arm, the tangent of the equilibria's manifold in ``z`` (its ``z_I`` and estimate move
        along it when the plant is not the model); None: ``[self_motion; 0]``.
    """

    a: np.ndarray
    b_tau: np.ndarray
    b_e: np.ndarray
    b_o: np.ndarray
    f: np.ndarray
    f_e: np.ndarray
    o: np.ndarray
    o_e: np.ndarray
    c: np.ndarray
    c_image: np.ndarray
    q_eq: np.ndarray
    tau_eq: np.ndarray
    xi: np.ndarray | None = None
    xi_e: np.ndarray | None = None
    self_motion: np.ndarray = field(default_factory=lambda: np.zeros((6, 0)))
    state: np.ndarray | None = None
    e_eq: np.ndarray | None = None
    self_motion_equilibria: SelfMotionCheck | None = None
    tangent: np.ndarray | None = None

    def flow(self, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(Phi, G_tau, G_e, G_o)``: the held flow over ``h``, the first block row of
        ``expm([[A, B_tau, B_e, B_o], [0, 0, 0, 0]] h)``."""
        import scipy.linalg  # here: a command's imports without it
        nz, nt, ne = self.a.shape[0], self.b_tau.shape[1], self.b_e.shape[1]
        inputs = np.hstack([self.b_tau, self.b_e, self.b_o])
        generator = np.zeros((nz + inputs.shape[1], nz + inputs.shape[1]))
        generator[:nz] = np.hstack([self.a, inputs])
        flow = scipy.linalg.expm(generator * h)[:nz]
        return flow[:, :nz], flow[:, nz : nz + nt], flow[:, nz + nt : nz + nt + ne], flow[:, nz + nt + ne :]

    def period_map(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """``(A_z, A_e)`` of one control period ``h``: the zero-order-hold flow with the torque and the
        observer's inputs held, exactly, and with integral action the sample's update
        ``z_I <- z_I + h xi_k`` (fact 21)."""
        nz, nt = self.a.shape[0], self.b_tau.shape[1]
        phi, g_tau, g_e, g_o = self.flow(h)
        a_z, a_e = phi + g_tau @ self.f + g_o @ self.o, g_tau @ self.f_e + g_e + g_o @ self.o_e
        if self.xi is not None:
            assert self.xi_e is not None, "xi and xi_e are given together"
            a_z[nz - nt :] += h * self.xi
            a_e[nz - nt :] += h * self.xi_e
        return a_z, a_e

    def state_at_rest(self, loop: ClosedLoop) -> np.ndarray:
        """The state at the equilibrium linearised at: :attr:`state`, or the model's (:func:`rest_state`)."""
        return rest_state(loop, self.q_eq) if self.state is None else self.state

    def steady_state(self, h: float, c: np.ndarray, tau_d: np.ndarray) -> np.ndarray:
        """The fixed point ``z`` of the sampled loop under a constant joint torque ``tau_d`` (fact 21):
        every held value is constant there (``e = c z``), so ``(I - A_z - A_e c) z = G_tau tau_d``
        exactly, the steady state of the linearised sampled loop (and of the continuous one)."""
        a_z, a_e = self.period_map(h)
        return np.linalg.solve(np.eye(len(a_z)) - a_z - a_e @ c, self.flow(h)[1] @ tau_d)

    def with_friction(self, slope: np.ndarray | None) -> HeldLinearization:
        """The same loop with a joint friction of slope ``slope`` per joint at ``qd = 0`` (the plant's viscous
        ``b``, :attr:`DeclaredPlant.friction_slope`): ``A -> A - B_tau diag(slope) S_qd`` (friction vanishes at
        rest: the equilibrium does not move; fact 21). None: no friction, ``self``."""
        if slope is None:
            return self
        n = self.b_tau.shape[1]
        a = self.a.copy()
        a[:, n : 2 * n] -= self.b_tau @ np.diag(slope)
        return replace(self, a=a)


class NotApplicableError(ValueError):
    """The statement of fact 14 does not apply to this loop (the message says why)."""


class NoEquilibriumError(NotApplicableError):
    """The plant as declared has no equilibrium near the model's: the loop does not come to rest."""


@dataclass(frozen=True)
class DeclaredPlant:
    """The plant a scenario declares where it differs from the controller's model (docs/math.md,
    fact 25: fact 14 for the plant as it is): its masses (``robot``: a payload, a mass scale; None: the
    model's) and what :class:`~dvfc.models.errors.PlantErrors` holds (camera mount, intrinsics,
    distortion, feature points, joint friction; None: none). The controller keeps its model."""

    robot: Robot | None = None
    errors: PlantErrors | None = None

    @staticmethod
    def of(settings: Settings) -> DeclaredPlant:
        """The plant of a scenario's settings (``plant`` and ``errors``; a run's masses from ``inputs``, as a
        campaign draws them)."""
        robot, inputs = settings.plant, settings.inputs
        if robot is not None and inputs is not None:
            robot = Robot(robot.urdf, robot.frame, robot.mount, robot.armature, inputs.payload, inputs.mass_scale)
        return DeclaredPlant(robot, settings.errors)

    def verdict(self, loop: ClosedLoop, q0: np.ndarray, imp: Implementation,
                criterion: tuple[float, float] | None = None) -> LocalVerdict | None:  # fmt: skip
        """Fact 14 for this plant (:func:`local_verdict`, every check included, its dry friction against
        ``criterion``; not certified, ``rho = inf``, where it has no equilibrium near the model's), None where the
        statement does not apply (:func:`applicability` is the caller's)."""
        try:
            return local_verdict(loop, q0, imp, self, criterion=criterion)
        except NoEquilibriumError as exc:
            return LocalVerdict(math.inf, False, str(exc))
        except NotApplicableError:
            return None

    def camera_errors(self, camera: Camera) -> np.ndarray | None:
        """The plant's :meth:`~dvfc.models.errors.PlantErrors.camera_vector` where it differs from the
        nominal camera's, else None."""
        if self.errors is None:
            return None
        vector = self.errors.camera_vector(camera)
        nominal = PlantErrors.none(camera, len(self.errors.viscous)).camera_vector(camera)
        return None if np.array_equal(vector, nominal) else vector

    @property
    def friction_slope(self) -> np.ndarray | None:
        """``b`` per joint, the slope of the plant's viscous friction, which the linearisation holds (None: none);
        its dry friction is a bounded torque (:attr:`coulomb`, fact 29), not a slope."""
        e = self.errors
        return None if e is None or not np.any(e.viscous) else np.asarray(e.viscous, dtype=float)

    @property
    def coulomb(self) -> np.ndarray | None:
        """``c`` per joint, the level of the plant's dry friction (None: none)."""
        e = self.errors
        return None if e is None or not np.any(e.coulomb) else np.asarray(e.coulomb, dtype=float)

    def masses_differ(self) -> bool:
        """Whether the plant's masses differ from the model's (a payload or a mass scale)."""
        r = self.robot
        return r is not None and (r.mass_scale != 1.0 or (r.payload is not None and r.payload.mass != 0.0))

    def differs(self, camera: Camera) -> bool:
        """Whether the plant differs from the controller's model in anything the linearisation sees."""
        friction = self.friction_slope is not None or self.coulomb is not None
        return self.masses_differ() or self.camera_errors(camera) is not None or friction

    def words(self, camera: Camera) -> str:
        """Which plant a statement is about, in words."""
        if not self.differs(camera):
            return "the plant equal to the controller's model"
        parts = []
        if self.masses_differ():
            assert self.robot is not None, "masses_differ"
            payload = self.robot.payload
            if payload is not None and payload.mass:
                parts.append(f"payload {payload.mass:.4g} kg")
            if self.robot.mass_scale != 1.0:
                parts.append(f"link masses x{self.robot.mass_scale:.4g}")
        if self.camera_errors(camera) is not None:
            parts.append("its camera (mount, intrinsics, distortion, feature points as declared)")
        if self.friction_slope is not None:
            parts.append("viscous joint friction b qd (in the linearisation)")
        if self.coulomb is not None:
            parts.append("dry joint friction up to c (a bounded torque, fact 29)")
        return "the plant as declared: " + ", ".join(parts)


def rest_model(loop: ClosedLoop, plant: Robot | None = None) -> ClosedLoop:
    """The sampled loop with its exogenous inputs at zero: target at rest at its start
    pose, no torque disturbance, the constant reference ``g_d`` (where a planned one ends); the
    joints moved by ``plant`` (None: the law's model)."""
    return replace(loop, target=loop.target.at_rest(), disturbances=[], sampled=True, plant=plant,
                   plan=None)  # fmt: skip


def rest_state(loop: ClosedLoop, q_eq: np.ndarray) -> np.ndarray:
    """The state ``[q; qd; pbar; quat]`` at the equilibrium: ``q = q_eq``, ``qd = 0``, ``gbar = g_d``
    (and ``z_I = 0`` with integral action)."""
    z_i = np.zeros(loop.robot.n if loop.integral else 0)
    return np.concatenate([q_eq, np.zeros(loop.robot.n), loop.reference.position_quaternion(), z_i])


EQUILIBRIUM_TOLERANCE = 1e-10
"""Largest residual ``|R|`` (rates of ``qd``, the observer, and ``xi``) accepted at an equilibrium of the plant
as it is (Newton's method stops at ``1e-13`` where it converges)."""


def _solve(residual: cs.Function, y0: np.ndarray, iterations: int = 60) -> tuple[np.ndarray, float]:
    """Newton's method with the least-norm step (``pinv`` of the Jacobian: on a manifold of solutions, a
    nearby one) on ``residual(y) = (R, dR/dy)`` from ``y0``; the point and ``|R|`` there."""
    y = np.array(y0, dtype=float)
    for _ in range(iterations):
        r, jac = (np.asarray(v) for v in residual(y))
        if not np.isfinite(r).all() or np.linalg.norm(r) < 1e-13:
            break
        y = y - np.linalg.pinv(jac) @ r.ravel()
    return y, float(np.linalg.norm(np.asarray(residual(y)[0])))


@dataclass(frozen=True)
class HeldFunctions:
    """Fact 14's linearisation of one loop structure as functions of numbers: ``held`` the rates, the law, the
    observer's inputs and their Jacobians at ``(z, tau, e, o, t, point, extra)``, ``at_rest`` the residual of the
    loop at rest and its Jacobian at ``(y, point, extra)`` (:func:`_equilibrium_residual`); ``extra`` the design
    and the plant's masses (:func:`dvfc.analysis.parametric.parameter_vector`, for a loop that takes them as
    inputs) and the true camera's :meth:`~dvfc.models.errors.PlantErrors.camera_vector` (with camera errors)."""

    held: cs.Function
    at_rest: cs.Function


HELD_CACHE = 8
"""Linearisations' functions kept (least recently used dropped): one per arm, loop structure and camera kind."""

_held: OrderedDict[tuple, tuple[ClosedLoop, HeldFunctions]] = OrderedDict()


def held_functions(rest: ClosedLoop, camera: bool) -> HeldFunctions:
    """:class:`HeldFunctions` of the loop at rest ``rest`` (:func:`rest_model`), with the true camera an input
    when ``camera``: built once per structure (:func:`dvfc.analysis.parametric.symbolic`) and shared by every
    design, payload, mass scale and camera of it, so that a campaign draw or a margin point linearises by
    evaluating them; a loop that keeps its numbers (the planar one) builds its own."""
    model = symbolic(rest)
    key = (id(model), camera)
    if model.parameters is not None and key in _held and _held[key][0] is model:
        _held.move_to_end(key)
        return _held[key][1]
    n, task = model.robot.n, model.task_dim
    tau, e, observer = model.hold[:n], model.hold[n : n + task], model.hold[n + task :]
    dq, dqd, dp, dth = cs.SX.sym("dq", n), cs.SX.sym("dqd", n), cs.SX.sym("dp", 3), cs.SX.sym("dth", 3)
    dz_i = cs.SX.sym("dz_I", n if model.integral else 0)
    z = cs.vertcat(dq, dqd, dp, dth, dz_i)
    point = cs.SX.sym("point", model.n_state)  # the state linearised at
    o = 2 * n + 3
    state = cs.vertcat(point[: 2 * n] + cs.vertcat(dq, dqd), point[2 * n : o] + dp,
                       _quaternion_product(point[o : o + 4], cs.vertcat(1, dth / 2)),
                       point[o + 4 :] + dz_i)  # fmt: skip
    held = cs.DM.zeros(dz_i.shape[0])  # z_I is held over the period
    rate = cs.vertcat(model.qd, model.qdd, model.observer_rate[0:3], model.observer_velocity[3:6], held)
    # the law and the observer's inputs at the sample read neither the held torque nor those inputs
    at_sample = cs.substitute([model.tau, cs.vertcat(model.camera_velocity, model.u[n + task : n + 2 * task])],
                              [model.hold], [cs.vertcat(cs.DM.zeros(n), e, cs.DM.zeros(2 * task))])  # fmt: skip
    extra = [] if model.parameters is None else [model.parameters]
    if not camera:
        e_image = model.e_e_image
    else:  # the true camera's image read with the nominal intrinsics (models/errors.py)
        vector = cs.SX.sym("camera", PlantErrors.none(model.camera, n).camera_vector(model.camera).size)
        pixels = true_features(model.camera, model.relative_pose, vector)[1]
        e_image = model.image_estimate(controller_features(model.camera, pixels))
        extra.append(vector)
    exprs = tuple(cs.substitute([rate, *at_sample, model.e_e, e_image, model.xi], [model.state], [state]))
    rate, law, inputs, e_exact, e_image, xi = exprs
    jac = cs.Function("held", [z, tau, e, observer, model.t, point, *extra],
                      [law, rate, cs.jacobian(rate, z), cs.jacobian(rate, tau), cs.jacobian(rate, e),
                       cs.jacobian(rate, observer), cs.jacobian(law, z), cs.jacobian(law, e), cs.jacobian(inputs, z),
                       cs.jacobian(inputs, e), cs.jacobian(e_exact, z), cs.jacobian(e_image, z), cs.jacobian(xi, z),
                       cs.jacobian(xi, e), e_exact, e_image, inputs, xi])  # fmt: skip
    functions = HeldFunctions(jac, _equilibrium_residual(model, (z, point, model.hold, model.t, extra), exprs))
    if model.parameters is not None:
        _held[key] = (model, functions)  # the model held: its id stays its own while cached
        if len(_held) > HELD_CACHE:
            _held.popitem(last=False)
    return functions


def held_linearization(loop: ClosedLoop, q0: np.ndarray, plant: DeclaredPlant | None = None) -> HeldLinearization:
    """Linearise the sampled loop at its equilibrium, by CasADi's automatic differentiation: the plant
    the controller's model (configuration by Newton from ``q0``, the camera at the reference), or
    ``plant`` as declared, its equilibrium found by Newton from the model's (a mount error or a
    payload moves it; :data:`EQUILIBRIUM_TOLERANCE`), its features those of its true camera. The functions are
    the structure's (:func:`held_functions`), evaluated at this design's and plant's numbers."""
    import scipy.linalg  # here: a command's imports without it
    plant = plant or DeclaredPlant()
    q_nom = equilibrium_configuration(loop, q0)
    n, task = loop.robot.n, loop.task_dim
    rest = rest_model(loop, plant.robot)
    camera, differs = plant.camera_errors(loop.camera), plant.differs(loop.camera)
    functions = held_functions(rest, camera is not None)
    p = parameter_vector(rest)
    extra = ([] if p is None else [p]) + ([] if camera is None else [camera])
    s_eq = rest_state(loop, q_nom)
    redundant = n > task
    y_eq = np.zeros(loop.n_state - n - 1)  # [dq; dp; dtheta; dz_I] about the model's equilibrium
    if differs or redundant:
        y = cs.MX.sym("y", y_eq.size)
        at_rest = cs.Function("equilibrium", [y], functions.at_rest.call([y, cs.DM(s_eq), *map(cs.DM, extra)]))
    if differs:
        s_eq, y_eq = _plant_equilibrium(loop, s_eq, at_rest)
    zero_z, zero_o = np.zeros(loop.n_state - 1), np.zeros(2 * task)
    jac = lambda tau, e, o: functions.held(zero_z, tau, e, o, 0.0, s_eq, *extra)  # noqa: E731
    e_used = np.zeros(task)
    if differs:  # e at the plant's equilibrium: the mode's (exact (15), or (21))
        values = jac(np.zeros(n), e_used, zero_o)
        e_used = np.asarray(values[15 if loop.mode == "image" else 14]).ravel()
    tau_eq = np.asarray(jac(np.zeros(n), e_used, zero_o)[0]).ravel()
    o_eq = np.asarray(jac(tau_eq, e_used, zero_o)[16]).ravel()
    values = [np.asarray(m) for m in jac(tau_eq, e_used, o_eq)]
    residual = max(np.abs(values[1]).max(), np.abs(values[17]).max() if loop.integral else 0.0)
    if residual > 1e-8:
        raise ValueError(f"the linearisation point is not an equilibrium (|dz/dt| = {residual:.2e})")
    a, b_tau, b_e, b_o, f, f_e, o_mat, o_e, c, c_image = values[2:12]
    integral = values[12:14] if loop.integral else [None, None]
    q_eq = s_eq[:n]
    jacobian = np.asarray(cs.Function("body_jacobian", [loop.robot.q], [loop.robot.body_jacobian])(q_eq))
    self_motion = scipy.linalg.null_space(jacobian)
    equilibria = tangent = None
    if redundant:
        equilibria = self_motion_check(at_rest, y_eq, self_motion)
        tangent = _equilibria_tangent(at_rest, y_eq, n, self_motion.shape[1])
    return HeldLinearization(a, b_tau, b_e, b_o, f, f_e, o_mat, o_e, c, c_image, q_eq=q_eq, tau_eq=tau_eq,
                             xi=integral[0], xi_e=integral[1], self_motion=self_motion, state=s_eq, e_eq=e_used,
                             self_motion_equilibria=equilibria, tangent=tangent)  # fmt: skip


def _equilibrium_residual(loop: ClosedLoop, symbols: tuple, exprs: tuple) -> cs.Function:
    """``(y, point, extra) -> (R, dR/dy)``: the rates of the sampled loop at rest (``qd = 0``; the joints'
    accelerations, the observer's rate and, with integral action, ``xi``) with the held inputs the law, the mode's
    ``e`` and the observer's inputs make there, at ``y = [dq; dp; dtheta; dz_I]`` about ``point`` (zero at an
    equilibrium; the target at rest: its radius, an entry of ``extra`` for a parametric loop, is zero, and ``t`` is
    set to 0)."""
    z, point, hold, t, extra = symbols
    rate, law, inputs, e_exact, e_image, xi = exprs
    n = loop.robot.n
    e = hold[n : n + loop.task_dim]
    e_used = e_image if loop.mode == "image" else e_exact
    law, inputs, xi = cs.substitute([law, inputs, xi], [e], [e_used])
    rate = cs.substitute(rate, hold, cs.vertcat(law, e_used, inputs))
    residual = cs.vertcat(rate[n : 2 * n + 6], xi if loop.integral else cs.DM.zeros(0))
    y = cs.vertcat(z[:n], z[2 * n :])  # at rest: dqd = 0
    at_rest = cs.substitute(residual, cs.vertcat(z[n : 2 * n], t), cs.DM.zeros(n + 1))
    return cs.Function("equilibrium", [y, point, *extra], [at_rest, cs.jacobian(at_rest, y)])


def _plant_equilibrium(loop: ClosedLoop, s_nom: np.ndarray, residual: cs.Function) -> tuple[np.ndarray, np.ndarray]:
    """The state at rest of the sampled loop with the plant as declared (``residual``:
    :func:`_equilibrium_residual` about ``s_nom``), by :func:`_solve` from the model's equilibrium ``s_nom``, and
    its ``y``; :class:`NoEquilibriumError` when none is found."""
    y_eq, size = _solve(residual, np.zeros(residual.size1_in(0)))
    if not size < EQUILIBRIUM_TOLERANCE:
        raise NoEquilibriumError(f"no equilibrium of the plant as declared found near the model's (Newton's "
                                 f"residual {size:.2e} > {EQUILIBRIUM_TOLERANCE:g})")  # fmt: skip
    n, o = loop.robot.n, 2 * loop.robot.n + 3
    dq, dp, dth, dz_i = y_eq[:n], y_eq[n : n + 3], y_eq[n + 3 : n + 6], y_eq[n + 6 :]
    quat = np.asarray(_quaternion_product(s_nom[o : o + 4], cs.DM(np.concatenate([[1.0], dth / 2])))).ravel()
    return np.concatenate([s_nom[:n] + dq, np.zeros(n), s_nom[2 * n : o] + dp, quat / np.linalg.norm(quat),
                           s_nom[o + 4 :] + dz_i]), y_eq  # fmt: skip


SELF_MOTION_STEPS = (-0.05, -0.01, 0.01, 0.05)
"""rad along each direction of the self-motion at which its poses are checked to be equilibria
(:class:`SelfMotionCheck`)."""


@dataclass(frozen=True)
class SelfMotionCheck:
    """The hypothesis of fact 14 across the self-motion, checked: the poses along it near ``q_eq`` are
    equilibria of the loop at rest (of the plant as declared). From ``q_eq`` moved by each step of
    :data:`SELF_MOTION_STEPS` along each direction of ``null(J_b(q_eq))``, Newton's least-norm iteration
    (its steps orthogonal to the equilibria's tangent) must find an equilibrium (``|R|`` below
    :data:`EQUILIBRIUM_TOLERANCE`) still moved along the direction by at least half the step: an isolated
    equilibrium (a map fixing the tangent to first order only) pulls the iteration back. ``poses`` checked,
    ``residual`` the largest ``|R|`` found, ``moved`` the smallest displacement along the direction over the
    step. A check at poses, not a proof between them."""

    poses: int
    residual: float
    moved: float

    @property
    def holds(self) -> bool:
        return self.residual < EQUILIBRIUM_TOLERANCE and self.moved >= 0.5

    def as_dict(self) -> dict:
        return {"poses": self.poses, "largest_residual": self.residual, "smallest_moved": self.moved,
                "steps_rad": list(SELF_MOTION_STEPS), "holds": self.holds}  # fmt: skip


def self_motion_check(residual: cs.Function, y_eq: np.ndarray, directions: np.ndarray) -> SelfMotionCheck:
    """:class:`SelfMotionCheck` about the equilibrium ``y_eq`` (:func:`_equilibrium_residual`) along the joint
    ``directions`` (columns, orthonormal)."""
    n = directions.shape[0]
    worst, moved = 0.0, math.inf
    for direction in directions.T:
        for step in SELF_MOTION_STEPS:
            start = y_eq.copy()
            start[:n] += step * direction
            y, r = _solve(residual, start)
            worst, moved = max(worst, r), min(moved, float(direction @ (y[:n] - y_eq[:n])) / step)
    return SelfMotionCheck(directions.shape[1] * len(SELF_MOTION_STEPS), worst, moved)


def _equilibria_tangent(residual: cs.Function, y_eq: np.ndarray, n: int, dimension: int) -> np.ndarray | None:
    """The tangent of the equilibria's manifold at ``y_eq`` in ``z = [dq; dqd; dp; dtheta; dz_I]``: the null
    space of the residual's Jacobian (:func:`_equilibrium_residual`), ``dqd = 0`` along it; None when its
    dimension is not ``dimension`` (the self-motion's)."""
    import scipy.linalg  # here: a command's imports without it
    null = scipy.linalg.null_space(np.asarray(residual(y_eq)[1]))
    if null.shape[1] != dimension:
        return None
    return np.vstack([null[:n], np.zeros((n, dimension)), null[n:]])


@dataclass(frozen=True)
class Schedule:
    """One common period of the control and camera schedules.

    Parameters
    ----------
    steps
        Control periods in the common period.
    captures
        The control samples of the common period (``0 <= k < steps``) at which images are captured.
    lag
        Control periods from the capture of an image to its use (the latency).
    pending
        The captures of earlier periods (negative samples, ``-lag <= c < 0``) whose images are in
        flight at the start of a period, in the order of their states in the monodromy.
    """

    steps: int
    captures: tuple[int, ...]
    lag: int
    pending: tuple[int, ...]


def schedule(imp: Implementation) -> Schedule:
    """The common period of ``imp``'s control and camera schedules, with the capture rule of
    :meth:`Implementation.capture_steps`; :class:`NotApplicableError` when the latency is not a
    whole number of control periods or the rate ratio is not rational (denominator at most
    :data:`RATIO_DENOMINATOR`)."""
    periods = imp.latency * imp.control_rate
    if abs(periods - round(periods)) > 1e-6:
        raise NotApplicableError(f"the latency {imp.latency:g} s is not a whole number of control periods")
    ratio = imp.control_rate / imp.camera_rate
    fraction = Fraction(ratio).limit_denominator(RATIO_DENOMINATOR)
    if abs(float(fraction) - ratio) > 1e-12 * ratio:
        raise NotApplicableError(f"the control/camera rate ratio {ratio:.17g} is not rational (denominator <= "
                            f"{RATIO_DENOMINATOR}): the schedule has no common period")  # fmt: skip
    steps, lag = fraction.numerator, round(periods)
    every = imp.capture_steps(2 * steps)
    captures = tuple(int(c) for c in every[every < steps])
    if tuple(int(c) - steps for c in every[(every >= steps) & (every < 2 * steps)]) != captures:
        raise NotApplicableError(f"the capture schedule does not repeat after {steps} control periods")
    pending = tuple(c - m * steps for m in range(1, lag // steps + 2) for c in captures if -lag <= c - m * steps)
    return Schedule(steps, captures, lag, tuple(sorted(pending)))


def monodromy(a_z: np.ndarray, a_e: np.ndarray, c: np.ndarray, sched: Schedule) -> np.ndarray:
    """The map of one common period on ``[z; e held; images in flight (sched.pending)]``.

    At each control sample ``k``: an image captured now stores ``c z_k``; an image captured
    ``lag`` samples ago replaces the held ``e``; then one control period ``z <- a_z z + a_e e``.
    The step maps are applied to the identity block by block (the images are copied, not
    multiplied)."""
    nz, ne = a_e.shape
    eye = np.eye(nz + ne * (1 + len(sched.pending)))
    z, e = eye[:nz], eye[nz : nz + ne]
    flight = {p: eye[nz + ne * (i + 1) : nz + ne * (i + 2)] for i, p in enumerate(sched.pending)}
    captures = set(sched.captures)
    for k in range(sched.steps):
        if k in captures:
            flight[k] = c @ z
        if k - sched.lag in flight:
            e = flight.pop(k - sched.lag)
        z = a_z @ z + a_e @ e
    return np.vstack([z, e, *(flight.pop(p + sched.steps) for p in sched.pending)])


@dataclass(frozen=True)
class LyapunovCheck:
    """The strict discrete Lyapunov inequality for a computed monodromy ``Pi``.

    ``P = dlyap(Pi^T, I)`` solves ``Pi^T P Pi - P = -I`` (scipy); ``margin`` is
    ``lambda_min(P - Pi^T P Pi)`` recomputed from ``P`` and ``Pi``, ``p_min`` is
    ``lambda_min(P)``. ``certified`` when ``p_min > 0`` and ``margin >= LYAPUNOV_MARGIN``.
    ``tolerance`` is how far the true monodromy may be from the computed one (spectral
    norm) with the inequality still strict: the ``eps`` with
    ``2 eps ||P|| ||Pi|| + eps^2 ||P|| = margin`` (about ``margin / (2 ||P|| ||Pi||)``)."""

    margin: float
    p_min: float
    p_norm: float
    tolerance: float
    certified: bool


def lyapunov_check(pi: np.ndarray) -> LyapunovCheck:
    """:class:`LyapunovCheck` of ``pi``."""
    import scipy.linalg  # here: a command's imports without it
    p = scipy.linalg.solve_discrete_lyapunov(pi.T, np.eye(pi.shape[0]))
    p = (p + p.T) / 2
    decrease = p - pi.T @ p @ pi
    margin = float(np.linalg.eigvalsh((decrease + decrease.T) / 2)[0])
    eig_p = np.linalg.eigvalsh(p)
    p_min, p_norm, pi_norm = float(eig_p[0]), float(np.abs(eig_p).max()), float(np.linalg.norm(pi, 2))
    tolerance = math.sqrt(pi_norm**2 + max(margin, 0.0) / p_norm) - pi_norm
    return LyapunovCheck(margin, p_min, p_norm, tolerance, bool(p_min > 0 and margin >= LYAPUNOV_MARGIN))


def spectral_radius(pi: np.ndarray) -> float:
    """``max |lambda(Pi)|``."""
    return float(np.abs(np.linalg.eigvals(pi)).max())


@dataclass(frozen=True)
class Transverse:
    """The monodromy across the self-motion (docs/math.md, fact 14, redundant arms).

    ``pi`` is ``Q^T Pi Q`` with ``Q`` an orthonormal basis of the complement of the tangent ``T``
    (``dimension`` columns, the self-motion in ``dq``, zero elsewhere); ``residual`` is
    ``||Pi T - T||_2``, how far the computed ``Pi`` is from fixing ``T``. With ``T`` fixed, ``Pi`` is
    ``[[I, *], [0, pi]]`` in ``[T, Q]``: its spectrum is ``dimension`` ones and ``pi``'s. On a 6-joint
    arm ``T`` is empty: ``pi`` is the monodromy itself and ``residual`` 0. ``equilibria``: the check that
    the self-motion's poses are equilibria (:class:`SelfMotionCheck`; None: not made)."""

    pi: np.ndarray
    dimension: int
    residual: float
    equilibria: SelfMotionCheck | None = None

    def certified(self, check: LyapunovCheck) -> bool:
        """Whether the Lyapunov ``check`` of :attr:`pi` certifies, the computed ``Pi`` fixes the tangent
        within that check's tolerance on ``Pi`` (a tangent it does not fix is not the self-motion's) and, on a
        redundant arm, the self-motion's poses were checked to be equilibria (a map fixing ``T`` to first
        order may still have an isolated fixed point: ``F(a, b) = (a + a^2 + c b, b / 2)``)."""
        manifold = self.dimension == 0 or (self.equilibria is not None and self.equilibria.holds)
        return check.certified and self.residual < check.tolerance and manifold


def transverse(pi: np.ndarray, self_motion: np.ndarray, equilibria: SelfMotionCheck | None = None) -> Transverse:
    """:class:`Transverse` of the monodromy ``pi`` across the tangent whose first rows are ``self_motion`` (the
    rest zero: :attr:`HeldLinearization.self_motion` in ``dq``, or the tangent of every state;
    ``equilibria``: the check that its poses are equilibria, :class:`SelfMotionCheck`)."""
    import scipy.linalg  # here: a command's imports without it
    m = self_motion.shape[1]
    if m == 0:
        return Transverse(pi, 0, 0.0)
    tangent = np.zeros((pi.shape[0], m))
    tangent[: self_motion.shape[0]] = self_motion
    q = scipy.linalg.null_space(tangent.T)
    return Transverse(q.T @ pi @ q, m, float(np.linalg.norm(pi @ tangent - tangent, 2)), equilibria)


@dataclass
class MultirateLoop:
    """The linearised sampled loop of one scenario and its schedules (rates and latency
    changed one at a time for the margins)."""

    lin: HeldLinearization
    implementation: Implementation
    mode: str
    _maps: dict[float, tuple[np.ndarray, np.ndarray]]

    @property
    def output(self) -> np.ndarray:
        """The ``e_e`` the law and observer use, linearised: (15), or (21) in image mode."""
        return self.lin.c_image if self.mode == "image" else self.lin.c

    def monodromy(self, imp: Implementation) -> tuple[np.ndarray, Schedule]:
        """``Pi`` and the schedule of ``imp``."""
        sched = schedule(imp)
        if imp.period not in self._maps:
            self._maps[imp.period] = self.lin.period_map(imp.period)
        return monodromy(*self._maps[imp.period], self.output, sched), sched

    def transverse(self, pi: np.ndarray) -> Transverse:
        """``pi`` across the self-motion (:func:`transverse`); ``pi`` itself on a 6-joint arm."""
        return transverse(pi, self.tangent(pi), self.lin.self_motion_equilibria)

    def tangent(self, pi: np.ndarray) -> np.ndarray:
        """The equilibria's tangent in the state of the monodromy ``pi`` (no columns on a 6-joint arm): the
        self-motion in ``dq``, zero elsewhere, or where the plant is not the model the tangent in ``z``, along
        which the held ``e`` and the images in flight move by ``c`` times it."""
        lin = self.lin
        if lin.tangent is None:
            return np.vstack([lin.self_motion, np.zeros((len(pi) - len(lin.self_motion), lin.self_motion.shape[1]))])
        copies = (len(pi) - len(lin.a)) // len(self.output)  # the held e and the images in flight
        return np.vstack([lin.tangent, *[self.output @ lin.tangent] * copies])

    def saturated(self, urdf: JointLimits) -> bool:
        """Whether saturation is active at the equilibrium: ``saturate`` on and the torque held there not
        strictly inside the efforts (of the URDF's limits ``urdf``, scaled by the implementation)."""
        imp = self.implementation
        return imp.saturate and not np.all(np.abs(self.lin.tau_eq) < imp.limits(urdf).effort)

    def rho(self, **change: Any) -> float:
        """``rho`` of the monodromy across the self-motion (:meth:`transverse`) with the
        implementation's fields changed by ``change``; ``inf`` when the product of the step maps
        overflows (never counted stable)."""
        with np.errstate(over="ignore", invalid="ignore"):
            pi = self.monodromy(replace(self.implementation, **change))[0]
        return spectral_radius(self.transverse(pi).pi) if np.isfinite(pi).all() else math.inf


def multirate_loop(loop: ClosedLoop, q0: np.ndarray, imp: Implementation,
                   plant: DeclaredPlant | None = None) -> MultirateLoop:  # fmt: skip
    """The linearised sampled loop of a scenario's loop and implementation, with the plant as declared
    (``plant``; None: the controller's model)."""
    lin = held_linearization(loop, q0, plant)
    return MultirateLoop(lin.with_friction(plant.friction_slope if plant else None), imp, loop.mode, {})


def applicability(loop: ClosedLoop, settings: Settings) -> str | None:
    """Why the statement does not apply to the scenario's loop as implemented, or None:
    it needs an equilibrium (isolated for ``n = 6``, the self-motion's manifold for ``n > 6``;
    ``n < 6`` has none with ``J_b`` invertible), which exists only with zero quantization (the
    latency and the rates are checked by :func:`schedule`, the plant's equilibrium by
    :func:`held_linearization`, saturation by :func:`implemented_record`)."""
    imp = settings.implementation
    if imp is None:
        return "the scenario has no [implementation]: the loop is the paper's continuous one"
    if isinstance(loop, PlanarLoop):
        return "the reduced planar loop: the statement is derived for the paper's loop (36)"
    if not spans_the_task(loop.robot.n):
        return f"the arm has {loop.robot.n} joints: with n < 6 J_b is not invertible (no equilibrium of the law)"
    if imp.quantization > 0:
        return f"quantization {imp.quantization:g} px: the image estimate is not 0 at the equilibrium (no fixed point)"
    return None


def _bisect(stable: Callable[[int], bool], good: int, bad: int) -> tuple[int, int | None]:
    """The last stable and first unstable integer between ``good`` (stable) and ``bad``
    (``bad`` unstable, else ``(bad, None)``), by bisection (either direction)."""
    if stable(bad):
        return bad, None
    while abs(bad - good) > 1:
        mid = (good + bad) // 2
        good, bad = (mid, bad) if stable(mid) else (good, mid)
    return good, bad


def linear_margins(system: MultirateLoop) -> dict:
    """Margins of the linearised sampled loop, each parameter alone on exact schedules,
    by bisection between the scenario's value and the end of :data:`RANGES`: the largest
    latency (whole control periods), the smallest camera rate (``control_rate / N``, an image
    every ``N`` control periods) and the smallest control rate (whole Hz; the latency held
    at the whole number of periods the sampled simulator uses). Each a record ``{"value",
    "unit", "stable_at", "unstable_at", "range"}``; ``value`` None (with ``stable_at`` the
    range end) when stable over the whole range. A bisection finds one boundary between
    a stable and an unstable schedule: stability between is not checked value by value."""
    imp = system.implementation
    r, cam = imp.control_rate, imp.camera_rate
    stable = lambda **change: system.rho(**change) < 1 - RHO_MARGIN  # noqa: E731
    lag = imp.latency_steps
    good, bad = _bisect(lambda k: stable(latency=k / r), lag, round(RANGES["latency"] * r))
    latency = (good / r, None if bad is None else bad / r)
    ratio = math.floor(r / cam + 1e-9)
    good, bad = _bisect(lambda k: stable(camera_rate=r / k), ratio, math.floor(r / RANGES["camera_rate"]))
    camera = (r / good if good > ratio else cam, None if bad is None else r / bad)
    good, bad = _bisect(lambda k: stable(control_rate=float(k), latency=round(imp.latency * k) / k),
                        math.floor(r), math.ceil(RANGES["control_rate"]))  # fmt: skip
    control = (float(good) if good < math.floor(r) else r, None if bad is None else float(bad))
    out = {}
    for name, (at, beyond) in (("latency", latency), ("camera_rate", camera), ("control_rate", control)):
        start = {"latency": imp.latency, "camera_rate": cam, "control_rate": r}[name]
        out[name] = {"value": None if beyond is None else at, "unit": UNITS[name], "stable_at": at,
                     "unstable_at": beyond, "range": [start, RANGES[name]]}  # fmt: skip
    return out


def not_applicable(reason: str) -> dict:
    """The record of a loop the statement does not apply to."""
    return {"applies": False, "certified": False, "reason": f"does not apply: {reason}", "rho": None, "rate": None,
            "period": None, "lyapunov_margin": None, "scope": None, "margins": None}  # fmt: skip


@dataclass(frozen=True)
class LocalVerdict:
    """Whether fact 14 certifies a plant's sampled loop locally (:func:`local_verdict`): ``rho`` of the
    monodromy across the self-motion (``inf`` where it overflows, saturates at the equilibrium or has no
    equilibrium), ``certified`` (``rho < 1 - RHO_MARGIN``, the Lyapunov check, the self-motion's tangent
    residual and its poses' equilibrium check: :meth:`Transverse.certified`), ``reason`` when it is not;
    and what was computed (None where it stopped short): the monodromy, its schedule's steps, the part
    across the self-motion, the Lyapunov check and, for a plant with dry friction whose monodromy is
    certified, the tracking error that friction can hold at rest (``friction``, fact 29)."""

    rho: float
    certified: bool
    reason: str | None
    pi: np.ndarray | None = None
    steps: int = 0
    across: Transverse | None = None
    check: LyapunovCheck | None = None
    saturated: bool = False
    friction: DryFrictionCheck | None = None


SATURATED = "saturation is active at the equilibrium (|tau_eq| not strictly inside the efforts)"


def local_verdict(loop: ClosedLoop, q0: np.ndarray, imp: Implementation, plant: DeclaredPlant,
                  system: MultirateLoop | None = None, criterion: tuple[float, float] | None = None,
                  tight: bool = False) -> LocalVerdict:  # fmt: skip
    """The one answer to "does fact 14 certify this plant's loop as implemented" (docs/math.md, facts 14,
    25 and 29), for ``certify``, ``margins`` and campaigns alike (``system``: the plant's linearised loop
    when already built): with dry friction, also the tracking error it can hold at rest (fact 29) within
    ``criterion`` (position m, angle deg; None: computed, not judged), its bound summed until it settles the
    criterion or, ``tight``, until it converges (:func:`dry_friction_check`). Raises :class:`NotApplicableError`
    (:class:`NoEquilibriumError` where the plant has no equilibrium near the model's)."""
    system = multirate_loop(loop, q0, imp, plant) if system is None else system
    if system.saturated(loop.robot.limits):
        return LocalVerdict(math.inf, False, SATURATED, saturated=True)
    with np.errstate(over="ignore", invalid="ignore"):
        pi, sched = system.monodromy(imp)
    if not np.isfinite(pi).all():
        return LocalVerdict(math.inf, False, "the period map overflows: far from stable", pi, sched.steps)
    across = system.transverse(pi)
    rho, check = spectral_radius(across.pi), lyapunov_check(across.pi)
    certified = rho < 1 - RHO_MARGIN and across.certified(check)
    reason = (f"rho = {rho:.6g}, the Lyapunov check (margin {check.margin:.3g}), the self-motion's residual "
              f"({across.residual:.2g}) or the check that its poses are equilibria fails")  # fmt: skip
    friction = None
    if certified and plant.coulomb is not None:
        state, rest = system.lin.state_at_rest(loop), rest_model(loop, plant.robot)
        mount = None if plant.errors is None else plant.errors.camera_vector(loop.camera)[:6]
        friction = dry_friction_check(system, rest, state, plant.coulomb, mount, criterion, tight)
        if friction.within is False:
            certified, reason = False, friction.words()
    return LocalVerdict(rho, certified, None if certified else reason, pi, sched.steps, across, check,
                        friction=friction)  # fmt: skip


def implemented_record(loop: ClosedLoop, s0: np.ndarray, settings: Settings,
                       criterion: tuple[float, float] | None = None, *, program: bool = True) -> dict:  # fmt: skip
    """Fact 14 for the scenario's loop as implemented and its plant as declared (JSON-ready,
    :class:`DeclaredPlant`: ``plant`` names it): the monodromy's spectral radius, the certified
    local rate, the common period, the Lyapunov check, the scope, the declared effects it does not
    cover and the linear margins, and with dry friction the tracking error it can hold at rest (fact 29,
    judged against ``criterion``: position m, angle deg, where given); or why the statement does not apply.
    Without ``program``, not the exported program's loop (fact 22: :func:`with_program_record` adds it)."""
    start = time.perf_counter()
    plant = DeclaredPlant.of(settings)
    words = {"plant": plant.words(loop.camera)}
    reason = applicability(loop, settings)
    if reason is not None:
        return {**not_applicable(reason), **words}
    imp = settings.implementation
    assert imp is not None, "applicability: the loop as implemented"
    try:
        frictionless = held_linearization(loop, s0[: loop.robot.n], plant)
        system = MultirateLoop(frictionless.with_friction(plant.friction_slope), imp, loop.mode, {})
        verdict = local_verdict(loop, s0[: loop.robot.n], imp, plant, system, criterion, tight=True)
    except ValueError as exc:  # NotApplicableError, no equilibrium configuration, or none of the plant
        return {**not_applicable(str(exc)), **words}
    lin = system.lin
    if verdict.saturated:
        return {**not_applicable(SATURATED), **words}
    if verdict.across is None or verdict.check is None or verdict.pi is None:
        return {**not_applicable(""), **words, "applies": True, "reason": verdict.reason}
    pi, across, check, rho, certified = verdict.pi, verdict.across, verdict.check, verdict.rho, verdict.certified
    period = verdict.steps * imp.period
    gap = float(np.abs(lin.c_image - lin.c).max())
    return {
        "integral_state": loop.integral,
        **_friction_record(plant, MultirateLoop(frictionless, imp, loop.mode, {})),
        **({} if verdict.friction is None else {"dry_friction": verdict.friction.as_dict()}),
        **words,
        "applies": True,
        "certified": certified,
        "reason": verdict.reason,
        "rho": rho,
        "rate": -math.log(rho) / period if rho < 1 else None,
        "period": period,
        "steps": verdict.steps,
        "states": pi.shape[0],
        "self_motion": self_motion_record(across),
        "lyapunov_margin": check.margin,
        "lyapunov_p_min": check.p_min,
        "lyapunov_p_norm": check.p_norm,
        "pi_error_tolerance": check.tolerance,
        "floating_point": (
            "P certifies the computed Pi; it certifies the true monodromy if ||Pi_true - Pi||_2 < pi_error_tolerance "
            "(about lyapunov_margin / (2 ||P|| ||Pi||))"
        ),
        "image_linearisation_gap": gap,
        "q_eq": lin.q_eq.tolist(),
        "scope": SCOPE.format(gap=gap) + (SELF_MOTION_SCOPE.format(m=across.dimension) if across.dimension else ""),
        "not_covered": not_covered(settings, system),
        "margins": linear_margins(system),
        **(program_record(loop, s0, imp, plant) if program else {}),
        "seconds": time.perf_counter() - start,
    }


def with_program_record(record: dict, loop: ClosedLoop, s0: np.ndarray, settings: Settings) -> dict:
    """``record``, of :func:`implemented_record` without ``program``, with the exported program's loop (its
    :func:`program_record`) where :func:`implemented_record` gives it: a synthesis checks its candidates without
    it (about 1 s each) and states it for the design it keeps."""
    if "lyapunov_margin" not in record or "program_rho" in record:
        return record
    assert settings.implementation is not None, "a record that applies: the loop as implemented"
    return {**record, **program_record(loop, s0, settings.implementation, DeclaredPlant.of(settings))}


def self_motion_record(across: Transverse) -> dict | None:
    """The record's ``self_motion`` (None on a 6-joint arm): the manifold's dimension, the tangent's
    residual ``||Pi T - T||_2``, the size of the monodromy across it and the check that its poses are
    equilibria (:class:`SelfMotionCheck`)."""
    if not across.dimension:
        return None
    equilibria = None if across.equilibria is None else across.equilibria.as_dict()
    return {"dimension": across.dimension, "tangent_residual": across.residual, "states": across.pi.shape[0],
            "equilibria": equilibria, "statement": SELF_MOTION_SCOPE.format(m=across.dimension).removeprefix("; ")}


def _friction_record(plant: DeclaredPlant, frictionless: MultirateLoop) -> dict:
    """The record's ``friction_slope`` when the plant has viscous friction (fact 21): its slope ``b``, which the
    headline ``rho`` includes, and ``rho`` of the same plant without friction."""
    slope = plant.friction_slope
    if slope is None:
        return {}
    return {"friction_slope": {
        "slope": slope.tolist(),
        "rho_without_friction": frictionless.rho(),
        "scope": ("the plant's viscous friction b qd in the linearisation; its dry friction is a torque bounded "
                  "by its Coulomb level (dry_friction, fact 29), not a slope; local, target at rest"),
    }}  # fmt: skip


def not_covered(settings: Settings, system: MultirateLoop) -> list[str]:
    """The effects the scenario declares that the monodromy leaves out, each in words (the latency
    jitter with ``rho`` at each fixed latency it allows: switching among them is not certified)."""
    imp = settings.sampled
    out = []
    if imp.latency_jitter:
        lags = range(imp.latency_steps, imp.latency_steps + imp.latency_jitter + 1)
        worst = max(system.rho(latency=k / imp.control_rate) for k in lags)
        out.append(f"latency jitter of up to {imp.latency_jitter} control periods (each fixed latency of "
                   f"{lags[0]}-{lags[-1]} periods: rho <= {worst:.6g}; switching among them is not certified)")
    if imp.frame_drop:
        out.append(f"frame drops (probability {imp.frame_drop:g})")
    if imp.outlier_probability:
        out.append(f"outlier detections (probability {imp.outlier_probability:g})")
    if imp.pixel_noise and system.mode == "image":
        out.append(f"pixel noise ({imp.pixel_noise:g} px)")
    return out


def margin_text(label: str, margin: dict, sign: str, scale: float, unit: str) -> str:
    """One linear margin in words: ``label sign value unit``, or, when stable at the searched range's end
    (the bisection then checks no value between), that and the range's end."""
    if margin["value"] is None:
        way = "up" if sign == "<=" else "down"
        return f"{label} stable at the searched range's end {way} to {margin['range'][1] * scale:.4g} {unit}"
    return f"{label} {sign} {margin['value'] * scale:.4g} {unit}"


def implemented_text(record: dict) -> str:
    """Fact 14's record in one line of words."""
    if record["rho"] is None:  # does not apply, or the period map overflows
        plant = f", for {record['plant']}" if "plant" in record else ""
        return f"local certificate of the loop as implemented (fact 14{plant}): {record['reason']}"
    m = record["margins"]
    margins = ", ".join(margin_text(label, m[name], sign, scale, unit) for name, label, sign, scale, unit in (
        ("latency", "latency", "<=", 1e3, "ms"), ("camera_rate", "camera", ">=", 1.0, "Hz"),
        ("control_rate", "control", ">=", 1.0, "Hz")))  # fmt: skip
    verdict = "CERTIFIED" if record["certified"] else f"NOT CERTIFIED ({record['reason']})"
    rate = "-" if record["rate"] is None else f"{record['rate']:.4g}"
    friction = record.get("friction_slope")
    without = "" if friction is None else f" (without friction: rho = {friction['rho_without_friction']:.6g})"
    dry = record.get("dry_friction")
    held = "" if dry is None else f"; {dry['statement']}"
    left = record.get("not_covered")
    uncovered = f"; not covered: {'; '.join(left)}" if left else ""
    return (f"loop as implemented, linearised at rest (fact 14, local): {verdict} for {record['plant']}: rho = "
            f"{record['rho']:.6g} over {record['period'] * 1e3:.4g} ms{without}, rate {rate} 1/s, Lyapunov margin "
            f"{record['lyapunov_margin']:.3g}; linear margins {margins}{held}{uncovered}")  # fmt: skip


@dataclass(frozen=True)
class ProgramMonodromy:
    """Fact 14 for the loop the controller program closes (docs/math.md, fact 22): the plant's held
    flow between samples (``[dq; dqd]``, exact) and the program's step (``dvfc_program``) linearised
    at the static-target equilibrium by CasADi's Jacobian, its observer a discrete state.

    ``pi`` acts on ``[dq; dqd; dpbar; dthetabar; e held; z_I (with integral action); the ring's
    estimates by age 1..B (6 each); the features of the images in flight (schedule.pending, 2m each)]``
    over one common period of the schedules; ``rho`` its spectral radius (across the self-motion on a
    redundant arm: :func:`transverse`, whose ``dq`` are the first ``n`` coordinates here too)."""

    pi: np.ndarray
    rho: float
    schedule: Schedule
    ring: int


def _tangent(quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(embed, project)`` between ``[dp; dtheta]`` (6) and ``[dp; dquat]`` (7) at ``quat``
    (``Rbar = Rbar* exp(dtheta)``: ``dquat = quat (x) [0; dtheta/2]``, and back
    ``dtheta = 2 vec(quat^* (x) dquat)``)."""
    w, v = quat[0], quat[1:]
    cross = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    left = np.block([[w, -v[None, :]], [v[:, None], w * np.eye(3) + cross]])  # quat (x) .
    embed, project = np.zeros((7, 6)), np.zeros((6, 7))
    embed[:3, :3] = project[:3, :3] = np.eye(3)
    embed[3:, 3:] = left[:, 1:] / 2
    project[3:, 3:] = 2 * left.T[1:, :]  # the conjugate's product, its vector part
    return embed, project


def program_monodromy(loop: ClosedLoop, q0: np.ndarray, imp: Implementation,
                      as_declared: DeclaredPlant | None = None) -> ProgramMonodromy:  # fmt: skip
    """:class:`ProgramMonodromy` of a scenario's loop and implementation (fact 14's applicability and
    :func:`schedule`; the plant's period map from :func:`held_linearization`, with the plant as declared,
    ``as_declared``: its equilibrium, friction slope and true camera)."""
    from dvfc.analysis.controller import Layout, program_function  # the program needs the loop's models

    declared = as_declared or DeclaredPlant()
    lin = held_linearization(loop, q0, declared).with_friction(declared.friction_slope)
    sched = schedule(imp)
    n, m, h = loop.robot.n, loop.camera.m, imp.period
    ring = imp.latency_steps + imp.latency_jitter + 1
    program = program_function(replace(loop, sampled=True, plant=None), imp, ring)
    layout = Layout(n, ring)
    t, q, qd, f, c, x = (cs.SX.sym(name, *program.size_in(i)) for i, name in enumerate(program.name_in()))
    tau, x_next, _ = program(t, q, qd, f, c, x)
    jacobian = cs.Function("program_jacobian", [t, q, qd, f, c, x],
                           [tau, x_next, cs.jacobian(cs.vertcat(tau, x_next), cs.vertcat(q, qd, f, x))])  # fmt: skip
    rest = rest_model(loop)
    seen, errors = rest.features, declared.camera_errors(loop.camera)
    if errors is not None:  # the true camera's pixels read with the nominal intrinsics (models/errors.py)
        seen = controller_features(loop.camera, true_features(loop.camera, rest.relative_pose, cs.DM(errors))[1])
    seen = cs.substitute(seen, rest.t, 0)
    features = cs.Function("features", [rest.q], [seen, cs.jacobian(seen, rest.q)])
    f_eq, f_q = (np.asarray(v) for v in features(lin.q_eq))
    at = lin.state_at_rest(loop)
    gbar_eq = at[2 * n : 2 * n + 7]
    embed, project = _tangent(gbar_eq[3:])
    late = 1e3  # s: past the planned reference, the ramp and integral_start
    first = ring * (sched.lag + 1)  # a counter (a multiple of the ring) with every capture >= 0
    x_eq = np.zeros(layout.size)
    x_eq[layout.gbar] = gbar_eq
    for j in range(ring):
        x_eq[layout.slot(j)] = gbar_eq
    x_eq[layout.q_last] = lin.q_eq
    if loop.integral:
        x_eq[layout.integral] = at[loop.integral_slice]
    if lin.e_eq is not None:
        x_eq[layout.e_e] = lin.e_eq
    phi, g_tau, *_ = lin.flow(h)
    phi, g_tau = phi[: 2 * n, : 2 * n], g_tau[: 2 * n]
    z_i = n if loop.integral else 0
    controller = 12 + z_i + 6 * ring
    size = 2 * n + controller + 2 * m * len(sched.pending)
    eye = np.eye(size)
    plant, state = eye[: 2 * n], eye[2 * n : 2 * n + controller]
    flight = {p: eye[2 * n + controller + 2 * m * i : 2 * n + controller + 2 * m * (i + 1)]
              for i, p in enumerate(sched.pending)}  # fmt: skip

    def embedding(k: int) -> np.ndarray:
        """The program's ``dx`` from the reduced controller coordinates before the step at counter ``k``
        (the ring's age ``a`` in slot ``(k - a) mod B``)."""
        e = np.zeros((layout.size, controller))
        e[layout.gbar, :6] = embed
        e[layout.e_e, 6:12] = np.eye(6)
        e[layout.integral.start : layout.integral.start + z_i, 12 : 12 + z_i] = np.eye(z_i)
        for a in range(1, ring + 1):
            e[layout.slot((k - a) % ring), 12 + z_i + 6 * (a - 1) : 12 + z_i + 6 * a] = embed
        return e

    def projection(k: int) -> np.ndarray:
        """The reduced controller coordinates from the program's ``dx`` after the step, counter ``k``."""
        r = np.zeros((controller, layout.size))
        r[:6, layout.gbar] = project
        r[6:12, layout.e_e] = np.eye(6)
        r[12 : 12 + z_i, layout.integral.start : layout.integral.start + z_i] = np.eye(z_i)
        for a in range(1, ring + 1):
            r[12 + z_i + 6 * (a - 1) : 12 + z_i + 6 * a, layout.slot((k - a) % ring)] = project
        return r

    captures = set(sched.captures)
    for k in range(sched.steps):
        if k in captures:
            flight[k] = f_q @ plant[:n]
        arriving = k - sched.lag in flight
        image = flight.pop(k - sched.lag) if arriving else np.zeros((2 * m, size))
        x_eq[layout.counter] = first + k
        capture = first + k - sched.lag if arriving else -1.0
        tau, x_next, jac = (np.asarray(v) for v in jacobian(late, lin.q_eq, np.zeros(n), f_eq, capture, x_eq))
        tau, x_next = tau.ravel(), x_next.ravel()
        moved = np.abs(np.concatenate([tau - lin.tau_eq, x_next[: layout.counter] - x_eq[: layout.counter]])).max()
        if not (moved < 1e-8 and np.isfinite(jac).all()):
            raise ValueError(f"the program's equilibrium is not a fixed point of its step (moved {moved:.2e})")
        out = jac @ np.vstack([plant, image, embedding(first + k) @ state])
        state = projection(first + k + 1) @ out[n:]
        plant = phi @ plant + g_tau @ out[:n]
    pi = np.vstack([plant, state, *(flight.pop(p + sched.steps) for p in sched.pending)])
    return ProgramMonodromy(pi, spectral_radius(transverse(pi, lin.self_motion).pi), sched, ring)


PROGRAM_LOOP = (
    "the same loop linearised through the controller program's step (dvfc export's dvfc_program, its Jacobian by "
    "CasADi; its ring of estimates and the features in flight as states, docs/math.md fact 22) at the same "
    "equilibrium over the same common period: a check that rho is the program's (equal to rounding)"
)


def program_record(loop: ClosedLoop, s0: np.ndarray, imp: Implementation, plant: DeclaredPlant) -> dict:
    """``program_rho`` (the spectral radius of :func:`program_monodromy`) and ``program_loop`` (what it
    is), for :func:`implemented_record`; None with the reason when its linearisation fails."""
    try:
        rho = program_monodromy(loop, s0[: loop.robot.n], imp, plant).rho
        return {"program_rho": rho, "program_loop": PROGRAM_LOOP}
    except ValueError as exc:
        return {"program_rho": None, "program_loop": f"not computed: {exc}"}
