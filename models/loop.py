"""The dynamic visual feedback system (36) under the passivity-based law (35), (42).

Symbols (paper numbering):

- relative pose ``g = g_wc^-1 g_wo`` (3), moving by (9);
- observer ``gbar`` (12), estimation error ``g_ee = gbar^-1 g`` (15), ``e_e = e(g_ee)``;
- control error ``g_ec = g_d^-1 gbar`` (24), ``e_c = e(g_ec)``;
- ``qd_d = pinv(J_b) u_d``, ``xi = qd - qd_d``; torque law (35);
- error state ``x = [xi; e_c; e_e]``, input ``u = [u_xi; u_d; u_e]``,
  disturbance ``w = [tau_d; V_wo]``, passive output ``nu = N x`` (Lemma 2);
- storage ``V`` (38); feedback ``u = -K N x`` (42).

Along (36), ``dV/dt = u^T nu + x^T G w`` exactly (n = 6 and ``J_b`` invertible, or
``n > 6`` with ``J_b`` of full row rank): with (42), ``dV/dt = -nu^T K nu + x^T G w``
(43), the basis of Theorems 1 and 2.

The simulation state is ``s = [q; qd; pbar; quat]`` with ``Rbar`` carried by a unit
quaternion ``[qw, qx, qy, qz]``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import casadi as cs
import numpy as np

from dvfc.models.camera import Camera
from dvfc.models.disturbance import Disturbance, torque
from dvfc.models.errors import friction_torque
from dvfc.models.lie import (
    SE3,
    SO3,
    Matrix,
    quaternion_exp,
    quaternion_product,
    quaternion_rate,
    quaternion_to_matrix,
)
from dvfc.models.robot import Robot
from dvfc.models.target import TargetMotion

Mode = Literal["ideal", "image"]

QUADRATURES = (
    "supply_u_nu",
    "supply_x_G_w",
    "dissipation_nu_K_nu",
    "z_squared",
    "d_squared",
    "unmodelled_supply",
    "observer_supply",
)
"""Integrals accumulated by the integrator: ``u^T nu``, ``x^T G w``, ``nu^T K nu``,
``|z|^2 = |S x|^2``, ``|d|^2 = |D_w^-1 w|^2`` (the generalized plant's performance output and
disturbance, :class:`PlantWeights`; ``|x|^2`` and ``|w|^2`` at unit weights), ``xi^T delta``
(:attr:`ClosedLoop.unmodelled_torque`) and the observer's hold ``o`` (:attr:`ClosedLoop.observer_supply`:
0 but in the sampled loop)."""


@dataclass(frozen=True)
class PlantWeights:
    """Weights of the generalized plant (docs/math.md, fact 17): the performance output
    ``z = S x`` with ``S = diag(S_xi, s_c I, s_e I)`` and the disturbance ``w = D_w d`` with
    ``D_w = diag(D_tau, d_t I3, d_r I3)`` (``d_t I2`` for the planar loop's target velocity).
    Theorem 2 then bounds the gain from ``d`` to ``z``, with
    ``P = N^T K N - G D_w^2 G^T / (2 gamma^2) - S^2 / 2``; unit weights are the paper's ``P``.

    ``xi`` and ``tau_d`` have one entry per joint; every weight is positive."""

    xi: tuple[float, ...]
    tau_d: tuple[float, ...]
    e_c: float = 1.0
    e_e: float = 1.0
    translation: float = 1.0
    rotation: float = 1.0

    @classmethod
    def unit(cls, n: int) -> PlantWeights:
        """The paper's generalized plant (every weight 1) for ``n`` joints."""
        return cls((1.0,) * n, (1.0,) * n)

    @property
    def is_unit(self) -> bool:
        return self == PlantWeights.unit(len(self.xi))

    def output(self, task: int = 6) -> np.ndarray:
        """The diagonal of ``S`` (``n + 2 task`` entries)."""
        return np.concatenate([self.xi, np.full(task, self.e_c), np.full(task, self.e_e)]).astype(float)

    def disturbance(self, task: int = 6) -> np.ndarray:
        """The diagonal of ``D_w`` (``n + task`` entries): the target's translational velocity, then
        (the paper's loop) its rotational velocity."""
        target = [self.translation] * 3 + [self.rotation] * 3 if task == 6 else [self.translation] * task
        return np.concatenate([self.tau_d, target]).astype(float)


@dataclass(frozen=True)
class Weights:
    """Block-isotropic weights ``W_c = diag(w_pc I3, w_rc I3)``, ``W_e = diag(w_pe I3, w_re I3)``
    (Section V-A); the cancellations behind Lemma 2 need the isotropy."""

    w_pc: float | cs.SX
    w_rc: float | cs.SX
    w_pe: float | cs.SX
    w_re: float | cs.SX

    @property
    def control(self) -> Matrix:
        """``W_c`` (numeric, or symbolic when the weights are CasADi symbols)."""
        return cs.diag(cs.vertcat(*[self.w_pc] * 3, *[self.w_rc] * 3))

    @property
    def estimation(self) -> Matrix:
        """``W_e``."""
        return cs.diag(cs.vertcat(*[self.w_pe] * 3, *[self.w_re] * 3))

    def as_array(self) -> np.ndarray:
        """``[w_pc, w_rc, w_pe, w_re]`` (numeric weights), the order of every batched certificate."""
        return np.array([self.w_pc, self.w_rc, self.w_pe, self.w_re], dtype=float)


@dataclass(frozen=True)
class Gains:
    """Diagonal gains of (42): ``K_xi`` (n entries), ``K_c`` and ``K_e`` (6 entries each), as
    numbers or as CasADi symbols (columns), and the integral gain ``K_I`` (n entries) of
    ``u_xi = -K_xi xi - K_I z_I`` (docs/math.md, fact 20; None: no integral action, the paper's law)."""

    k_xi: np.ndarray | cs.SX
    k_c: np.ndarray | cs.SX
    k_e: np.ndarray | cs.SX
    k_i: np.ndarray | cs.SX | None = None

    @property
    def matrix(self) -> Matrix:
        """``K = diag(K_xi, K_c, K_e)`` (42)."""
        return cs.diag(cs.vertcat(*map(gain_column, (self.k_xi, self.k_c, self.k_e))))


def gain_column(entries: np.ndarray | cs.SX) -> Matrix:
    """Diagonal gains as a CasADi column: numbers as constants, symbols as they are."""
    return entries if isinstance(entries, cs.SX) else cs.DM(entries)


def output_matrix(weights: Weights, reference: SE3, r_ec: Matrix, n: int) -> Matrix:
    """``N`` of Lemma 2 (``nu = N x``) at the control-error rotation ``R_ec``::

    N = [[I_n, 0,                    0   ],
         [0,  -Ad_{g_d^-1}^T W_c,    0   ],
         [0,   Ad_{R_ec}^T W_c,     -W_e ]]
    """
    w_c, w_e = weights.control, weights.estimation
    ad_d = reference.inverse().adjoint()
    ad_ec = SO3(r_ec).adjoint()
    zero = cs.DM.zeros
    return cs.vertcat(
        cs.horzcat(cs.DM.eye(n), zero(n, 6), zero(n, 6)),
        cs.horzcat(zero(6, n), -ad_d.T @ w_c, zero(6, 6)),
        cs.horzcat(zero(6, n), ad_ec.T @ w_c, -w_e),
    )


def disturbance_matrix(weights: Weights, r_ee: Matrix, n: int) -> Matrix:
    """``G`` with ``dV/dt = u^T nu + x^T G w``: ``G = [[I, 0], [0, 0], [0, W_e Ad_{R_ee}]]``,
    so that ``G G^T = W = diag(I_n, 0_6, W_e^2)`` of Theorem 2."""
    zero = cs.DM.zeros
    return cs.vertcat(
        cs.horzcat(cs.DM.eye(n), zero(n, 6)),
        zero(6, n + 6),
        cs.horzcat(zero(6, n), weights.estimation @ SO3(r_ee).adjoint()),
    )


def disturbance_weight(weights: Weights, n: int, plant: PlantWeights | None = None) -> Matrix:
    """``W = G D_w^2 G^T = diag(D_tau^2, 0_6, W_e^2 D_v^2)`` of Theorem 2 (``diag(I_n, 0_6, W_e^2)``
    at unit weights): ``Ad_{R_ee}`` is block-diagonal in rotations and commutes with the
    block-isotropic ``W_e D_v``, so ``W`` is the same for every ``R_ee`` (docs/math.md, fact 17)."""
    w_e = weights.estimation
    if plant is None:
        return cs.diagcat(cs.DM.eye(n), cs.DM.zeros(6, 6), w_e @ w_e)
    d = cs.DM(plant.disturbance())
    d_v = cs.diag(d[n:])
    return cs.diagcat(cs.diag(d[:n] ** 2), cs.DM.zeros(6, 6), w_e @ d_v @ d_v @ w_e)


def observer_step(pbar: Matrix, quat: Matrix, v_wc: Matrix, u_e: Matrix, h: Matrix | float) -> Matrix:
    """``[pbar; quat]`` after the exact flow of (12) over ``h`` with ``V_wc`` and ``u_e`` constant:
    ``gbar(h) = exp(-h hat(V_wc)) gbar exp(h hat(u_e))`` (docs/math.md, fact 22, (22.1)), the quaternion
    ``q(-h w_V) (x) quat (x) q(h w_U)`` renormalised, the translation that of the ``SE(3)`` product."""
    before, after = SE3.exp(-h * v_wc), SE3.exp(h * u_e)
    gbar = SE3(pbar, SO3(quaternion_to_matrix(quat)))
    p = (before @ gbar @ after).translation
    turned = quaternion_product(quaternion_product(quaternion_exp(-h * v_wc[3:6]), quat), quaternion_exp(h * u_e[3:6]))
    return cs.vertcat(p, turned / cs.norm_2(turned))


def pseudo_inverse(j: Matrix) -> Matrix:
    """``pinv(J)`` for a matrix of full rank: ``J^-1`` (square), ``J^T (J J^T)^-1``
    (wide, full row rank) or ``(J^T J)^-1 J^T`` (tall, full column rank)."""
    rows, cols = j.shape
    if rows == cols:
        return cs.inv(j)
    if rows < cols:
        return j.T @ cs.inv(j @ j.T)
    return cs.inv(j.T @ j) @ j.T


def quintic(u: Matrix | np.ndarray | float) -> Matrix | np.ndarray | float:
    """The quintic time law ``10 u^3 - 15 u^4 + 6 u^5`` of a planned reference (C^2, at rest at
    ``u = 0`` and ``u = 1``), for CasADi or NumPy ``u`` in ``[0, 1]``."""
    return 10 * u**3 - 15 * u**4 + 6 * u**5


def smoothstep(u: Matrix | np.ndarray | float) -> Matrix | np.ndarray | float:
    """The ramp's ``sigma = 3 u^2 - 2 u^3`` (C^1, nondecreasing from 0 to 1), for CasADi or NumPy
    ``u`` in ``[0, 1]``."""
    return 3 * u**2 - 2 * u**3


@dataclass(frozen=True)
class ReferencePlan:
    """A planned reference ``g_d(t)`` (docs/math.md, fact 16): from ``start`` (the controller's own
    estimate ``gbar(0)``) to ``goal`` (the scenario's ``g_d``) in ``duration`` seconds, by the
    decoupled interpolation ``p_d = p_0 + tau(t) dp``, ``R_d = R_0 exp(tau(t) omega)``
    (``dp = p_goal - p_0``, ``omega = log(R_0^T R_goal)``) with the quintic time law
    ``tau = 10 u^3 - 15 u^4 + 6 u^5``, ``u = min(max(t - hold, 0) / duration, 1)``: C^2, at rest at
    both ends, and ``g_d = goal`` from ``hold + duration`` on. ``hold``: seconds ``g_d`` stays at
    ``start`` first (the arm held until the first image arrives: the law then commands no motion,
    ``e_c = 0`` and ``qd_d = 0``). Numbers, or (:meth:`of`) entries of the parametric loop's symbol,
    whose ``covered`` then gives ``(dp, omega)``: a plan with another start, duration or hold (another
    latency) runs the same compiled code."""

    start: SE3
    goal: SE3
    duration: Matrix
    hold: Matrix = 0.0
    covered: tuple[Matrix, Matrix] | None = None
    """``(dp, omega)`` as given (the symbolic plan of :meth:`of`); None: from ``start`` and ``goal``."""

    ENTRIES = 20
    """Entries of :meth:`vector`: ``[p_0 (3); vec(R_0) (9, column-major); dp (3); omega (3); duration; hold]``."""

    def vector(self) -> np.ndarray:
        """The plan's numbers as the parametric loop takes them (:data:`ENTRIES`)."""
        dp, omega = self.step
        p0 = np.asarray(cs.DM(self.start.translation), dtype=float).ravel()
        r0 = np.asarray(cs.DM(self.start.rotation.matrix), dtype=float).ravel(order="F")
        return np.concatenate([p0, r0, dp, omega, [self.duration, self.hold]]).astype(float)

    @staticmethod
    def of(vector: Matrix, goal: SE3) -> ReferencePlan:
        """The plan whose :meth:`vector` is ``vector``, ending at ``goal`` (the loop's reference)."""
        start = SE3(vector[0:3], SO3(cs.reshape(vector[3:12], 3, 3)))
        return ReferencePlan(start, goal, vector[18], vector[19], (vector[12:15], vector[15:18]))

    def fraction(self, t: Matrix | np.ndarray) -> Matrix | np.ndarray:
        """``u(t) = min(max(t - hold, 0) / duration, 1)``, for CasADi or NumPy ``t``."""
        if isinstance(t, cs.SX | cs.MX | cs.DM):
            return cs.fmin(cs.fmax((t - self.hold) / self.duration, 0), 1)
        return np.clip((np.asarray(t, dtype=float) - self.hold) / self.duration, 0.0, 1.0)

    @cached_property
    def step(self) -> tuple[Matrix, Matrix]:
        """``(dp, omega)``: the translation and the rotation vector the plan covers (numbers for a
        numeric plan)."""
        if self.covered is not None:
            return self.covered
        p0, p1 = (np.asarray(cs.DM(g.translation)).ravel() for g in (self.start, self.goal))
        turn = (self.start.rotation.inverse() @ self.goal.rotation).log()
        return p1 - p0, np.asarray(cs.DM(turn)).ravel()

    @property
    def _step_matrices(self) -> tuple[Matrix, Matrix]:
        return tuple(cs.DM(v) if isinstance(v, np.ndarray) else v for v in self.step)  # type: ignore[return-value]

    def progress(self, t: Matrix) -> tuple[Matrix, Matrix]:
        """``(tau(t), dtau/dt)`` of the quintic time law."""
        u = self.fraction(t)
        return quintic(u), 30 * u**2 * (1 - u) ** 2 / self.duration

    def pose(self, t: Matrix) -> SE3:
        """``g_d(t)``."""
        dp, omega = self._step_matrices
        tau, _ = self.progress(t)
        return SE3(self.start.translation + tau * dp, self.start.rotation @ SO3.exp(tau * omega))

    def velocity(self, t: Matrix) -> Matrix:
        """The body velocity ``V_d = vee(g_d^-1 dg_d/dt) = tau' [R_d^T dp; omega]``."""
        dp, omega = self._step_matrices
        _, rate = self.progress(t)
        return rate * cs.vertcat(self.pose(t).rotation.matrix.T @ dp, omega)


@dataclass
class ClosedLoop:
    """The dynamic visual feedback system of one scenario, as CasADi expressions.

    Parameters
    ----------
    robot, camera, target
        The arm, the camera with the object's feature points, the target motion.
    reference
        Desired relative pose ``g_d`` (the goal of ``plan``, when one is given).
    plan
        A planned reference ``g_d(t)`` ending at ``reference`` (docs/math.md, fact 16): the law uses
        ``g_d(t)`` everywhere and adds the feedforward ``-Ad_(g_d) V_d`` to the camera-velocity
        command; None: the paper's constant ``g_d``.
    performance
        The generalized plant's weights (:class:`PlantWeights`) the quadratures ``|z|^2`` and
        ``|d|^2`` use; None: the paper's (unit).
    ramp
        Seconds of the ramp ``u_d = -sigma(t) K_c nu_c`` (docs/math.md, fact 16a; :attr:`ramp_level`);
        None: no ramp.
    weights, gains
        ``W_c, W_e`` and ``K`` of (35), (42).
    mode
        ``"ideal"``: the law uses the exact ``e_e``; ``"image"``: the law uses the
        first-order estimate ``pinv(J)(f - fbar)`` (21) from the image.
    disturbances
        Joint-torque disturbance components, summed into ``tau_d(t)``.
    inputs
        When given, the open loop (36) driven by ``u(t)`` (a function of the time
        symbol returning ``n + 12`` entries) instead of the feedback (42).
    plant
        The arm as it really is (a payload, other masses), when it differs from ``robot``:
        the law keeps ``robot``'s model, the joints move by ``plant``'s (33).
    friction
        The plant's joint friction ``[b; c; eps]`` (:func:`dvfc.models.errors.friction_torque`) in
        the continuous loop: the joints receive ``tau - f(qd)``, and ``-f(qd)`` is part of the torque
        disturbance of ``w`` (docs/math.md, fact 18.1). None: none. (The sampled loop takes the
        plant's friction as an input of its control period instead.)
    compensation
        The controller's friction model ``[bhat; chat; epshat]``, fed forward on the law's own
        ``qd_d``: the law (35) plus ``fhat(qd_d)`` (docs/math.md, fact 19.2); the residual
        ``fhat(qd_d) - f(qd)`` is the torque disturbance of ``w``. None: no compensation.
    integral_start
        With integral action (``gains.k_i``), the time from which ``z_I`` integrates (held at 0
        before: the start's transient, docs/math.md, fact 20).
    sampled
        The loop as a digital controller runs it: the torque applied, the ``e_e`` the law uses and
        the observer's inputs ``V_wc``, ``u_e`` are held inputs (:attr:`hold`), set at the samples by
        :class:`dvfc.analysis.sampled.SampledSimulator`, instead of (35), (15)/(21) and (34), (42)
        evaluated continuously: between samples the observer follows (12) with its inputs held, whose
        flow over a period is the program's step (docs/math.md, fact 22).
    parameters
        The symbols ``reference``, ``weights`` and ``gains`` are expressions of, when they are
        symbolic (:func:`dvfc.analysis.parametric.symbolic`): the last argument of every
        function of the loop. None: they are numbers.
    """

    robot: Robot
    camera: Camera
    target: TargetMotion
    reference: SE3
    weights: Weights
    gains: Gains
    mode: Mode = "ideal"
    disturbances: list[Disturbance] = field(default_factory=list)
    inputs: Callable[[cs.SX], Matrix] | None = None
    plant: Robot | None = None
    sampled: bool = False
    parameters: cs.SX | None = None
    plan: ReferencePlan | None = None
    ramp: float | None = None
    performance: PlantWeights | None = None
    friction: np.ndarray | None = None
    compensation: np.ndarray | None = None
    integral_start: Matrix = 0.0

    task_dim = 6
    """Entries of ``e_c``, ``e_e``, ``u_d`` and ``u_e``."""
    _arm_matrix, _image_matrix = "J_b", "J(gbar)"
    """Keys of :attr:`conditioning`: the arm's Jacobian and the image Jacobian the law inverts."""

    def __post_init__(self) -> None:
        n = self.robot.n
        self.t = cs.SX.sym("t")
        self.q, self.qd = self.robot.q, self.robot.qd
        self.pbar = cs.SX.sym("pbar", 3)
        self.quat = cs.SX.sym("quat", 4)
        self.state = cs.vertcat(self.q, self.qd, self.pbar, self.quat)
        self.n_state = 2 * n + 7
        self.quaternions = [slice(2 * n + 3, 2 * n + 7)]
        """Where the state holds unit quaternions (renormalised between integration chunks)."""
        self.z_i = cs.SX.sym("z_I", n) if self.integral else cs.SX(0, 1)
        """The integral state ``z_I`` (fact 20), the state's last ``n`` entries with integral action."""
        if self.integral:
            self.state = cs.vertcat(self.state, self.z_i)
            self.n_state += n

    @property
    def integral(self) -> bool:
        """Whether the law has integral action (``gains.k_i`` given)."""
        return self.gains.k_i is not None

    @property
    def integral_slice(self) -> slice:
        """Where the state holds ``z_I`` (empty without integral action)."""
        start = 2 * self.robot.n + 7
        return slice(start, start + (self.robot.n if self.integral else 0))

    @property
    def estimate_slice(self) -> slice:
        """Where the state holds the observer's estimate (``[pbar; quat]``; ``pbar`` in the planar loop)."""
        n = self.robot.n
        return slice(2 * n, self.n_state - (n if self.integral else 0))

    # --- poses and errors -------------------------------------------------------
    @cached_property
    def relative_pose(self) -> SE3:
        """``g = g_wc^-1 g_wo`` (3)."""
        return self.robot.camera_pose.inverse() @ self.target.pose(self.t)

    @cached_property
    def estimate(self) -> SE3:
        """``gbar = (pbar, Rbar)``, the observer's state (12)."""
        return SE3(self.pbar, SO3(quaternion_to_matrix(self.quat)))

    @cached_property
    def estimation_pose_error(self) -> SE3:
        """``g_ee = gbar^-1 g`` (15)."""
        return self.estimate.inverse() @ self.relative_pose

    @cached_property
    def desired(self) -> SE3:
        """``g_d`` the law uses: the plan's ``g_d(t)``, or the constant :attr:`reference`."""
        return self.reference if self.plan is None else self.plan.pose(self.t)

    @cached_property
    def desired_velocity(self) -> Matrix:
        """``V_d``, the body velocity of :attr:`desired` (zero without a plan)."""
        return cs.DM.zeros(6) if self.plan is None else self.plan.velocity(self.t)

    @cached_property
    def tracking_error(self) -> SE3:
        """The true tracking error against the goal, ``g_d^-1 g`` with the scenario's ``g_d``
        (the identity when the camera holds that pose; ``e_c`` measures the estimate's against
        :attr:`desired`)."""
        return self.reference.inverse() @ self.relative_pose

    @cached_property
    def control_pose_error(self) -> SE3:
        """``g_ec = g_d^-1 gbar`` (24), with ``g_d(t)`` when planned."""
        return self.desired.inverse() @ self.estimate

    @cached_property
    def e_c(self) -> Matrix:
        return self.control_pose_error.error_vector()

    @cached_property
    def e_e(self) -> Matrix:
        return self.estimation_pose_error.error_vector()

    @cached_property
    def features(self) -> Matrix:
        """``f`` (11), the measured image."""
        return self.camera.project(self.relative_pose)

    @cached_property
    def estimated_features(self) -> Matrix:
        """``fbar`` (14)."""
        return self.camera.project(self.estimate)

    @cached_property
    def e_e_image(self) -> Matrix:
        """``pinv(J(gbar)) (f - fbar)`` (21)."""
        return self.image_estimate(self.features)

    def image_estimate(self, f: Matrix) -> Matrix:
        """``e_e`` the observer computes from a measured image ``f`` (21)."""
        return self.camera.estimation_error(f, self.estimate)

    # --- passivity structure ----------------------------------------------------
    @cached_property
    def output_matrix(self) -> Matrix:
        """``N`` of Lemma 2 at the current ``R_ec``."""
        return output_matrix(self.weights, self.desired, self.control_pose_error.rotation.matrix, self.robot.n)

    @cached_property
    def disturbance_matrix(self) -> Matrix:
        """``G`` at the current ``R_ee``."""
        return disturbance_matrix(self.weights, self.estimation_pose_error.rotation.matrix, self.robot.n)

    # --- the law --------------------------------------------------------------
    @cached_property
    def _camera_inputs(self) -> tuple[Matrix, Matrix]:
        """``(u_d, u_e)``: from (42) with the mode's ``e_e``, or from :attr:`inputs`."""
        n = self.robot.n
        if self.inputs is not None:
            u = self.inputs(self.t)
            return u[n : n + 6], u[n + 6 : n + 12]
        nu_ce = self.output_matrix[n:, n:] @ cs.vertcat(self.e_c, self.e_e_law)
        return -self.ramp_level * gain_column(self.gains.k_c) * nu_ce[0:6], -gain_column(self.gains.k_e) * nu_ce[6:12]

    @cached_property
    def ramp_level(self) -> Matrix:
        """``sigma(t)`` of the ramp (docs/math.md, fact 16a): the smoothstep ``3u^2 - 2u^3``,
        ``u = min(t / ramp, 1)``, C^1, so the command ``u_d = -sigma K_c nu_c`` starts at rest;
        1 without a ramp."""
        if self.ramp is None:
            return cs.DM(1.0)
        return smoothstep(cs.fmin(cs.fmax(self.t / self.ramp, 0), 1))

    @cached_property
    def gain_matrix(self) -> Matrix:
        """``K(sigma(t)) = diag(K_xi, sigma K_c, K_e)``: the feedback (42) with the ramp's ``sigma``."""
        k = self.gains
        return cs.diag(cs.vertcat(gain_column(k.k_xi), self.ramp_level * gain_column(k.k_c), gain_column(k.k_e)))

    @cached_property
    def hold(self) -> cs.SX:
        """Inputs held between samples in the sampled loop: ``[tau applied; e_e measured; V_k; U_k]``,
        ``V_k = V_wc(t_k)`` and ``U_k = u_e(t_k)`` the observer's inputs at the sample (docs/math.md,
        fact 22)."""
        return cs.SX.sym("hold", self.robot.n + 3 * self.task_dim)

    @cached_property
    def e_e_law(self) -> Matrix:
        """The ``e_e`` the law and the observer use: exact (15), from the image (21), or the
        latest measurement held (sampled loop)."""
        if self.sampled:
            return self.hold[self.robot.n : self.robot.n + self.task_dim]
        return self.e_e if self.mode == "ideal" else self.e_e_image

    @cached_property
    def observer_hold(self) -> tuple[Matrix, Matrix]:
        """``(V_k, U_k)``: the observer's inputs held over the period in the sampled loop."""
        n, task = self.robot.n, self.task_dim
        return self.hold[n + task : n + 2 * task], self.hold[n + 2 * task :]

    def held_estimate(self, v_wc: Matrix, u_e: Matrix, h: Matrix | float) -> Matrix:
        """The estimate ``[pbar; quat]`` after ``h`` of (12) from the state's with ``V_wc = v_wc`` and
        ``u_e`` held: (22.1), the program's observer step (:func:`observer_step`)."""
        return observer_step(self.pbar, self.quat, v_wc, u_e, h)

    @cached_property
    def camera_velocity(self) -> Matrix:
        """``V_wc = J_b(q) qd`` (34)."""
        return self.robot.body_jacobian @ self.qd

    @cached_property
    def estimate_velocity(self) -> Matrix:
        """``Vbar = -Ad_{gbar^-1} V_wc + u_e`` (12)."""
        return -self.estimate.inverse().adjoint() @ self.camera_velocity + self._camera_inputs[1]

    @cached_property
    def estimate_rate(self) -> Matrix:
        """``[dpbar/dt; dquat/dt]`` from ``d gbar/dt = gbar hat(Vbar)``."""
        return self._estimate_rate(self.estimate_velocity)

    def _estimate_rate(self, v: Matrix) -> Matrix:
        """``[dpbar/dt; dquat/dt]`` of ``d gbar/dt = gbar hat(v)``."""
        return cs.vertcat(self.estimate.rotation.matrix @ v[0:3], quaternion_rate(self.quat, v[3:6]))

    @cached_property
    def observer_velocity(self) -> Matrix:
        """The body velocity the observer moves with: ``Vbar`` of (12), or in the sampled loop (12)
        with its inputs held, ``-Ad_{gbar^-1} V_k + U_k`` (docs/math.md, fact 22)."""
        if not self.sampled:
            return self.estimate_velocity
        v, u = self.observer_hold
        return -self.estimate.inverse().adjoint() @ v + u

    @cached_property
    def observer_rate(self) -> Matrix:
        """``[dpbar/dt; dquat/dt]`` of the observer as it runs: :attr:`estimate_rate`, or with its inputs
        held (sampled loop)."""
        return self._estimate_rate(self.observer_velocity) if self.sampled else self.estimate_rate

    @cached_property
    def observer_input_error(self) -> Matrix:
        """``D``: the observer's velocity less (12)'s at the state, ``-Ad_{gbar^-1} (V_k - V_wc) + U_k - u_e``
        (docs/math.md, fact 11): ``O(h)`` in the sampled loop, 0 in the continuous one."""
        return self.observer_velocity - self.estimate_velocity

    @cached_property
    def qd_d(self) -> Matrix:
        """Reference joint velocity ``qd_d = pinv(J_b) u_d`` (Section V-A); with a plan,
        ``pinv(J_b) (u_d - Ad_(g_d) V_d)`` (docs/math.md, fact 16: the feedforward makes
        ``V_ec`` the constant-reference one, ``-Ad_(gbar^-1)(J_b xi + u_d) + u_e``)."""
        command = self._camera_inputs[0]
        if self.plan is not None:
            command = command - self.desired.adjoint() @ self.desired_velocity
        return pseudo_inverse(self.robot.body_jacobian) @ command

    @cached_property
    def qdd_d(self) -> Matrix:
        """``d qd_d/dt`` by automatic differentiation along ``(qd, 1, dgbar/dt)``, the explicit
        time derivative included (the target's in the ideal ``e_e``, the plan's ``g_d(t)``):
        needs no target information beyond what ``u_e`` already uses. ``dgbar/dt`` is (12)'s: the
        law's (at a sample, the held observer's too)."""
        return self.reference_acceleration(self.estimate_rate)

    def reference_acceleration(self, estimate_rate: Matrix) -> Matrix:
        """``d qd_d/dt`` along ``(qd, 1, estimate_rate)``."""
        args = cs.vertcat(self.q, self.t, self.pbar, self.quat)
        rates = cs.vertcat(self.qd, 1, estimate_rate)
        return cs.jtimes(self.qd_d, args, rates)

    @cached_property
    def xi(self) -> Matrix:
        """``xi = qd - qd_d``."""
        return self.qd - self.qd_d

    @cached_property
    def x(self) -> Matrix:
        """Error state ``x = [xi; e_c; e_e]`` (36), with the exact ``e_e``."""
        return cs.vertcat(self.xi, self.e_c, self.e_e)

    @cached_property
    def u(self) -> Matrix:
        """Input ``u = [u_xi; u_d; u_e]``; ``u_xi = -K_xi xi`` under (42), ``-K_xi xi - K_I z_I`` with
        integral action (fact 20)."""
        u_d, u_e = self._camera_inputs
        feedback = self.inputs is None
        u_xi = -gain_column(self.gains.k_xi) * self.xi if self.inputs is None else self.inputs(self.t)[0 : self.robot.n]
        if self.integral and feedback:
            u_xi = u_xi - gain_column(self.gains.k_i) * self.z_i
        return cs.vertcat(u_xi, u_d, u_e)

    @cached_property
    def integrand(self) -> Matrix:
        """``dz_I/dt = xi`` from :attr:`integral_start` on, 0 before (fact 20, variant i): the rate of
        ``z_I`` in the continuous loop; the sampled loop adds ``h`` times it at each sample (its
        anti-windup in :class:`dvfc.analysis.sampled.SampledSimulator`)."""
        return cs.if_else(self.t >= self.integral_start, self.xi, cs.DM.zeros(self.robot.n))

    @cached_property
    def augmented_storage(self) -> Matrix:
        """``V_a = V + z_I^T K_I z_I / 2`` (fact 20.1): ``dV_a/dt = -nu^T K nu + x^T G w`` under the law
        with integral action; ``V`` (38) without it."""
        if not self.integral:
            return self.storage
        return self.storage + self.z_i.T @ (gain_column(self.gains.k_i) * self.z_i) / 2

    @cached_property
    def z(self) -> Matrix:
        """The performance output ``z = S x`` of the generalized plant (:class:`PlantWeights`)."""
        if self.performance is None:
            return self.x
        return cs.DM(self.performance.output(self.task_dim)) * self.x

    @cached_property
    def d(self) -> Matrix:
        """The normalised disturbance ``d = D_w^-1 w`` of the generalized plant."""
        if self.performance is None:
            return self.w
        return self.w / cs.DM(self.performance.disturbance(self.task_dim))

    @cached_property
    def tau_d(self) -> Matrix:
        return torque(self.disturbances, self.t, self.robot.n)

    @cached_property
    def plant_friction(self) -> Matrix:
        """The continuous loop's joint friction ``f(qd) = b qd + c tanh(qd/eps)`` (:attr:`friction`;
        0 without)."""
        if self.friction is None:
            return cs.DM.zeros(self.robot.n)
        return friction_torque(self.qd, cs.DM(self.friction), self.robot.n)

    @cached_property
    def compensation_torque(self) -> Matrix:
        """``fhat(qd_d)``, the law's friction compensation (:attr:`compensation`; 0 without)."""
        if self.compensation is None:
            return cs.DM.zeros(self.robot.n)
        return friction_torque(self.qd_d, cs.DM(self.compensation), self.robot.n)

    @cached_property
    def matched_disturbance(self) -> Matrix:
        """The torque disturbance of (36) relative to the law (35): ``tau_d - f(qd) + fhat(qd_d)``
        (docs/math.md, facts 18.1 and 19.2); ``tau_d`` without friction or compensation."""
        if self.friction is None and self.compensation is None:
            return self.tau_d
        return self.tau_d - self.plant_friction + self.compensation_torque

    @cached_property
    def w(self) -> Matrix:
        """Disturbance ``w = [tau_d; V_wo]`` (36), ``tau_d`` the :attr:`matched_disturbance`."""
        return cs.vertcat(self.matched_disturbance, self.target.velocity(self.t))

    @cached_property
    def tau(self) -> Matrix:
        """Torque law (35): ``M qdd_d + C qd_d + g + J_b^T Ad_{g_d^-1}^T W_c e_c + u_xi`` (``g_d(t)``
        when planned), plus the friction compensation ``fhat(qd_d)`` when the law has one."""
        law = self.paper_torque
        return law if self.compensation is None else law + self.compensation_torque

    @cached_property
    def paper_torque(self) -> Matrix:
        """(35) alone, without the friction compensation."""
        r = self.robot
        ad_d = self.desired.inverse().adjoint()
        feedforward = r.mass_matrix @ self.qdd_d + r.coriolis_times(self.qd_d) + r.gravity
        return feedforward + r.body_jacobian.T @ ad_d.T @ self.weights.control @ self.e_c + self.u[0 : r.n]

    @cached_property
    def applied_torque(self) -> Matrix:
        """The torque the joints receive: (35), or the value held since the last sample."""
        return self.hold[: self.robot.n] if self.sampled else self.tau

    @cached_property
    def plant_dynamics(self) -> tuple[Matrix, Matrix]:
        """``(M, C qd + g)`` of (33) for the arm as it is (:attr:`plant`, else :attr:`robot`)."""
        p = self.plant or self.robot
        m, bias = p.mass_matrix, p.bias
        if p is self.robot:
            return m, bias
        return tuple(cs.substitute([m, bias], [p.q, p.qd], [self.q, self.qd]))

    @cached_property
    def qdd(self) -> Matrix:
        """Joint acceleration from (33): ``M qdd = tau + tau_d - C qd - g``, with the plant's
        ``M``, ``C``, ``g`` and the applied torque."""
        m, bias = self.plant_dynamics
        if self.friction is not None:
            bias = bias + self.plant_friction
        return cs.solve(m, self.applied_torque + self.tau_d - bias)

    @cached_property
    def unmodelled_torque(self) -> Matrix:
        """``delta = M qdd + C qd + g - tau - tau_d`` with the law's model (``robot``) along the
        actual motion and the law's torque (35): zero for the paper's loop. Otherwise the
        derivation of Lemma 2 gains one term, ``dV/dt = u^T nu + x^T G w + xi^T delta``:
        sampling, saturation and model error enter the storage only through ``delta``."""
        if self.plant is None and not self.sampled:
            return cs.DM.zeros(self.robot.n)
        r = self.robot
        if self.friction is None and self.compensation is None:
            return r.mass_matrix @ self.qdd + r.bias - self.tau - self.tau_d
        model = r.mass_matrix @ self.qdd + r.bias
        return model - self.paper_torque - self.matched_disturbance

    @cached_property
    def observer_supply(self) -> Matrix:
        """``o = nu_e^T D + xi^T M (qdd_d - qdd_d^o)`` (docs/math.md, fact 11, (11.2)): what the observer's
        hold adds to ``dV/dt``, ``nu_e`` the ``u_e`` block of ``nu``, ``D`` the :attr:`observer_input_error`,
        ``qdd_d^o`` the rate of ``qd_d`` along the observer as it runs (the law's ``qdd_d`` follows (12));
        0 in the continuous loop."""
        if not self.sampled:
            return cs.DM(0.0)
        n, task = self.robot.n, self.task_dim
        along = self.reference_acceleration(self.observer_rate)
        nu_e = self.nu[n + task : n + 2 * task]
        return nu_e.T @ self.observer_input_error + self.xi.T @ self.robot.mass_matrix @ (self.qdd_d - along)

    @cached_property
    def state_rate(self) -> Matrix:
        """``ds/dt`` for ``s = [q; qd; pbar; quat]`` (and ``z_I``: :attr:`integrand` in the continuous
        loop, held between samples in the sampled one); the observer as it runs (:attr:`observer_rate`)."""
        if not self.integral:
            return cs.vertcat(self.qd, self.qdd, self.observer_rate)
        rate = cs.DM.zeros(self.robot.n) if self.sampled else self.integrand
        return cs.vertcat(self.qd, self.qdd, self.observer_rate, rate)

    @cached_property
    def conditioning(self) -> dict[str, Matrix]:
        """Matrices the law inverts: ``J_b`` (``pinv(J_b)``, Section V-A) and, in image mode,
        ``J(gbar)`` (21)."""
        return {"J_b": self.robot.body_jacobian, "J(gbar)": self.camera.jacobian(self.estimate)}

    # --- storage and supply -----------------------------------------------------
    @cached_property
    def nu(self) -> Matrix:
        """Passive output ``nu = N x`` (Lemma 2)."""
        return self.output_matrix @ self.x

    @cached_property
    def storage(self) -> Matrix:
        """Storage function (38)."""
        w = self.weights
        ec = self.control_pose_error.error_function()
        ee = self.estimation_pose_error.error_function()
        kinetic = self.xi.T @ self.robot.mass_matrix @ self.xi / 2
        return kinetic + w.w_pc * ec[0] + w.w_rc * ec[1] + w.w_pe * ee[0] + w.w_re * ee[1]

    @cached_property
    def storage_rate(self) -> Matrix:
        """``dV/dt`` along the loop, by automatic differentiation of (38)."""
        return cs.jtimes(self.storage, cs.vertcat(self.state, self.t), cs.vertcat(self.state_rate, 1))

    @cached_property
    def augmented_storage_rate(self) -> Matrix:
        """``dV_a/dt`` along the loop, by automatic differentiation of :attr:`augmented_storage`."""
        state, rate = cs.vertcat(self.state, self.t), cs.vertcat(self.state_rate, 1)
        return cs.jtimes(self.augmented_storage, state, rate)

    @cached_property
    def quadratures(self) -> Matrix:
        """Integrands of :data:`QUADRATURES`."""
        nu, x, w = self.nu, self.x, self.w
        k = self.gain_matrix
        return cs.vertcat(
            self.u.T @ nu,
            x.T @ self.disturbance_matrix @ w,
            nu.T @ k @ nu,
            self.z.T @ self.z,
            self.d.T @ self.d,
            self.xi.T @ self.unmodelled_torque,
            self.observer_supply,
        )

    @cached_property
    def signals(self) -> dict[str, Matrix]:
        """Every signal of the loop as an expression of ``(t, s)``."""
        r = self.robot
        return {
            "q": self.q,
            "qd": self.qd,
            "tau": self.tau,
            "tau_applied": self.applied_torque,
            "tau_d": self.tau_d,
            "g": cs.vec(self.relative_pose.as_matrix()),
            "g_tracking": cs.vec(self.tracking_error.as_matrix()),
            "gbar": cs.vec(self.estimate.as_matrix()),
            "g_wc": cs.vec(r.camera_pose.as_matrix()),
            "g_wo": cs.vec(self.target.pose(self.t).as_matrix()),
            "f": self.features,
            "fbar": self.estimated_features,
            "e_c": self.e_c,
            "e_e": self.e_e,
            "e_e_image": self.e_e_image,
            "xi": self.xi,
            "u": self.u,
            "nu": self.nu,
            "w": self.w,
            "V": self.storage,
            "Vdot": self.storage_rate,
            "depth": self.camera.depths(self.relative_pose),
            "depth_bar": self.camera.depths(self.estimate),
            "image_jacobian": cs.vec(self.conditioning[self._image_matrix]),
            "body_jacobian": cs.vec(self.conditioning[self._arm_matrix]),
            **self._integral_signals,
        }

    @property
    def _integral_signals(self) -> dict[str, Matrix]:
        """With integral action: ``z_I``, ``V_a`` and ``dV_a/dt`` (fact 20.1); none without."""
        if not self.integral:
            return {}
        return {"z_I": self.z_i, "V_a": self.augmented_storage, "V_a_dot": self.augmented_storage_rate}

    @property
    def arguments(self) -> tuple[list[cs.SX], list[str]]:
        """The symbols every expression of the loop depends on: ``(t, s)``, :attr:`hold` for the
        sampled loop, then :attr:`parameters` when given."""
        symbols, names = [self.t, self.state], ["t", "s"]
        if self.sampled:
            symbols, names = [*symbols, self.hold], [*names, "hold"]
        if self.parameters is not None:
            symbols, names = [*symbols, self.parameters], [*names, "p"]
        return symbols, names

    def rhs_function(self) -> cs.Function:
        """``(t, s[, hold][, p]) -> (ds/dt, quadrature integrands)``."""
        symbols, names = self.arguments
        return cs.Function("rhs", symbols, [self.state_rate, self.quadratures], names, ["ode", "quad"])

    def signals_function(self) -> cs.Function:
        """``(t, s[, hold][, p]) -> signals``: one output per entry of :attr:`signals`."""
        names = list(self.signals)
        values = [cs.densify(v) for v in self.signals.values()]  # dense: structural zeros stored too
        symbols, arguments = self.arguments
        return cs.Function("signals", symbols, values, arguments, names)

    def initial_state(self, q0: np.ndarray, qd0: np.ndarray, estimation_error: SE3) -> np.ndarray:
        """``s(0)`` with ``gbar(0) = g(0) g_ee(0)^-1`` for a given initial estimation error."""
        pose = cs.Function("g0", [self.q, self.t], [self.relative_pose.as_matrix()])
        g0 = SE3.from_matrix(pose(q0, 0.0))
        z_i = np.zeros(self.robot.n if self.integral else 0)
        return np.concatenate([q0, qd0, (g0 @ estimation_error.inverse()).position_quaternion(), z_i])
