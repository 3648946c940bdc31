"""The reduced visual feedback problem that holds for an arm with fewer than six joints.

The paper's law needs ``J_b pinv(J_b) = I_6`` ((40)-(41)); an arm with ``n < 6`` joints,
like the planar two-link testbed of Fig. 3, cannot produce every camera velocity, so that
cancellation fails (docs/math.md, "Where the guarantees stop"). This module restates the problem
in the directions the arm does control and re-derives each step for them. Equation labels
``(P1)``... are this derivation's; the paper's equation each one mirrors is in brackets.

Setting. The arm moves in a horizontal plane, the camera at its tip looks straight down
(optical axis ``-z`` of the world), the target moves in a parallel plane without rotating.
The camera's height and orientation are then known from the joint angles; only the
horizontal position is a task. Write ``c(q)`` for the camera's horizontal position in the
world (the first two entries of ``p_wc``), ``J_p(q) = dc/dq`` (``2 x n``, full row rank
away from the arm's singularities), ``o(t)`` for the target's horizontal position and
``v_o = do/dt`` its velocity (unknown to the controller: a disturbance).

- (P1) [(3), (9)] relative position in a frame aligned with the world:
  ``p = o - c(q)``, so ``dp/dt = -J_p qd + v_o``.
- (P2) [(12)] observer: ``dpbar/dt = -J_p qd + u_e``.
- (P3) [(15), (23)] estimation error ``e_e = p - pbar``: ``de_e/dt = v_o - u_e``.
- (P4) [(24), (25)] control error ``e_c = pbar - p_d`` (``p_d`` the desired offset):
  ``de_c/dt = -J_p qd + u_e``.
- (P5) [(34), Section V-A] ``qd_d = pinv(J_p) u_d``, ``xi = qd - qd_d``. Because ``J_p``
  has full row rank, ``J_p pinv(J_p) = I_2`` exactly, so ``-J_p qd = -J_p xi - u_d`` and
  ``de_c/dt = -J_p xi - u_d + u_e``. (This is the step that fails for the paper's 6-D
  task: ``J_b pinv(J_b) != I_6`` when ``n < 6``.)
- (P6) [(35)] torque law ``tau = M qdd_d + C qd_d + g + J_p^T w_c e_c + u_xi``;
  ``qdd_d`` by automatic differentiation along ``(qd, dpbar/dt)``: no target data.
- (P7) [(33)] with ``M qdd + C qd + g = tau + tau_d``:
  ``M dxi/dt = -C xi + J_p^T w_c e_c + u_xi + tau_d``.
- (P8) [(38)] storage ``V = xi^T M xi / 2 + w_c |e_c|^2 / 2 + w_e |e_e|^2 / 2``.
- (P9) [(40)-(41), Lemma 2] with ``Mdot - 2C`` skew,
  ``dV/dt = xi^T (J_p^T w_c e_c + u_xi + tau_d) + w_c e_c^T (-J_p xi - u_d + u_e)
  + w_e e_e^T (v_o - u_e)``; the ``J_p`` terms cancel, leaving
  ``dV/dt = u^T nu + x^T G w`` with ``x = [xi; e_c; e_e]``, ``u = [u_xi; u_d; u_e]``,
  ``w = [tau_d; v_o]`` and

      N = [[I_n, 0,       0      ],        G = [[I_n, 0     ],
           [0,  -w_c I_2, 0      ],             [0,   0     ],
           [0,   w_c I_2, -w_e I_2]],           [0,   w_e I_2]].

  This is the paper's ``N`` and ``G`` with ``Ad_{g_d^-1} = I`` and ``R_ec = R_ee = I``,
  restricted to the translational rows: ``N`` is constant, so a certificate has no
  rotation to range over.
- (P10) [(42), (43), Theorem 1] ``u = -K N x``: ``dV/dt = -x^T N^T K N x + x^T G w``.
- (P11) [(44)-(45), Theorem 2] ``P = N^T K N - W / (2 gamma^2) - I/2 >= 0`` with
  ``W = G G^T = diag(I_n, 0_2, w_e^2 I_2)`` gives the L2 gain ``<= gamma`` from ``w`` to ``x``.
- (P12) [(16)-(21)] the image: with the camera's orientation known and every feature at a
  constant depth, the features are affine in the relative position, so
  ``f - fbar = A (p - pbar)`` exactly, ``A = dfbar/dpbar`` (``2m x 2``), and
  ``e_e = pinv(A) (f - fbar)`` holds exactly, not to first order as (21).
- (P13) [docs/math.md, fact 7] the operating envelope. (P8) is exactly quadratic in ``e_c, e_e``
  (no rotation error function), so ``V <= x^T D x`` with
  ``D = diag(D_M/2, w_c/2 I_2, w_e/2 I_2)``, ``D_M >= M(q)`` for every ``q`` (the matrix bound of
  docs/math.md, fact 10, at the Perron vector of ``diag(k_xi - s)^-1 B``), for every state: no
  ``theta_bar`` and no self-consistency condition. Completing the square in (P10),
  ``x^T G w <= s x^T W x + |w|^2 / (4 s)`` for any ``s > 0``, so
  ``dV/dt <= -x^T Q x + |w|^2 / (4 s)``, ``Q = N^T K N - s W``, and with
  ``kappa = lambda_min(D^-1/2 Q D^-1/2) > 0``: ``dV/dt <= -kappa V + |w|^2 / (4 s)``,
  ``V(t) <= exp(-kappa t) V(0) + wbar^2 / (4 s kappa)`` with ``wbar^2 = |tau_d|^2 + |v_o|^2``
  (the target does not rotate). Every sublevel set ``{V <= c}`` with ``c >= wbar^2/(4 s kappa)``
  is invariant, so the start is always covered; from ``V <= c``: ``|e_c| <= sqrt(2c/w_c)``,
  ``|e_e| <= sqrt(2c/w_e)``, ``|xi| <= sqrt(2c/m_lo)``.

What the reduced problem leaves out: the camera's yaw (``q_1 + q_2``, not a task) and its
height (fixed by the arm). The simulation state is ``s = [q; qd; pbar]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as cs
import numpy as np

from dvfc.models.lie import SE3, SO3, Matrix
from dvfc.models.loop import ClosedLoop, pseudo_inverse

TASK = 2
"""Dimension of the reduced task (horizontal position)."""


def planar_output_matrix(w_c: float, w_e: float, n: int) -> np.ndarray:
    """``N`` of (P9)."""
    eye, zero = np.eye(TASK), np.zeros((TASK, TASK))
    return np.block([
        [np.eye(n), np.zeros((n, 2 * TASK))],
        [np.zeros((TASK, n)), -w_c * eye, zero],
        [np.zeros((TASK, n)), w_c * eye, -w_e * eye],
    ])  # fmt: skip


def planar_disturbance_matrix(w_e: float, n: int) -> np.ndarray:
    """``G`` of (P9)."""
    g = np.zeros((n + 2 * TASK, n + TASK))
    g[:n, :n] = np.eye(n)
    g[n + TASK :, n:] = w_e * np.eye(TASK)
    return g


@dataclass
class PlanarLoop(ClosedLoop):
    """The reduced loop (P1)-(P12) for a planar arm with a downward-looking camera.

    Same parameters as :class:`dvfc.models.loop.ClosedLoop`; ``reference`` gives the desired
    offset ``p_d`` (its first two coordinates, world-aligned); the weights used are
    ``w_pc`` (``w_c``) and ``w_pe`` (``w_e``); ``gains.k_c`` and ``gains.k_e`` have two entries.
    """

    task_dim = TASK
    _arm_matrix, _image_matrix = "J_p", "A"

    def __post_init__(self) -> None:
        self.t = cs.SX.sym("t")
        self.q, self.qd = self.robot.q, self.robot.qd
        self.pbar = cs.SX.sym("pbar", TASK)
        self.state = cs.vertcat(self.q, self.qd, self.pbar)
        self.n_state = 2 * self.robot.n + TASK
        self.quaternions = []

    # --- positions and errors (P1)-(P4) ---------------------------------------------
    @cached_property
    def camera_position(self) -> Matrix:
        """``c(q)``: the camera's horizontal position in the world."""
        return self.robot.camera_pose.translation[:TASK]

    @cached_property
    def task_jacobian(self) -> Matrix:
        """``J_p(q) = dc/dq``."""
        return cs.jacobian(self.camera_position, self.q)

    @cached_property
    def target_position(self) -> Matrix:
        """``o(t)``."""
        return self.target.pose(self.t).translation[:TASK]

    @cached_property
    def relative_position(self) -> Matrix:
        """``p = o - c(q)`` (P1)."""
        return self.target_position - self.camera_position

    @cached_property
    def estimate(self) -> SE3:
        """``gbar``: the target placed at ``c + pbar`` at its known height and orientation,
        seen from the camera."""
        start = self.target.start
        position = cs.vertcat(self.camera_position + self.pbar, start.translation[TASK])
        return self.robot.camera_pose.inverse() @ SE3(position, SO3(start.rotation.matrix))

    @cached_property
    def e_e(self) -> Matrix:
        """``e_e = p - pbar`` (P3)."""
        return self.relative_position - self.pbar

    @cached_property
    def tracking_error(self) -> SE3:
        """The true tracking error ``p - p_d = e_e + e_c`` (P3)-(P4), horizontal and
        world-aligned, as a pose without rotation."""
        return SE3(cs.vertcat(self.e_e + self.e_c, 0), SO3(cs.DM.eye(3)))

    @cached_property
    def e_c(self) -> Matrix:
        """``e_c = pbar - p_d`` (P4)."""
        return self.pbar - cs.DM(np.asarray(cs.DM(self.reference.translation)).ravel()[:TASK])

    @cached_property
    def image_map(self) -> Matrix:
        """``A = dfbar/dpbar`` (P12)."""
        return cs.jacobian(self.estimated_features, self.pbar)

    def image_estimate(self, f: Matrix) -> Matrix:
        """``pinv(A) (f - fbar)`` (P12): exact when every feature keeps its depth."""
        return pseudo_inverse(self.image_map) @ (f - self.estimated_features)

    # --- passivity structure (P9) ----------------------------------------------------
    @cached_property
    def output_matrix(self) -> Matrix:
        return cs.DM(planar_output_matrix(self.weights.w_pc, self.weights.w_pe, self.robot.n))

    @cached_property
    def disturbance_matrix(self) -> Matrix:
        return cs.DM(planar_disturbance_matrix(self.weights.w_pe, self.robot.n))

    # --- the law (P5), (P6), (P10) ---------------------------------------------------
    @cached_property
    def _camera_inputs(self) -> tuple[Matrix, Matrix]:
        n = self.robot.n
        if self.inputs is not None:
            u = self.inputs(self.t)
            return u[n : n + TASK], u[n + TASK : n + 2 * TASK]
        nu_ce = self.output_matrix[n:, n:] @ cs.vertcat(self.e_c, self.e_e_law)
        return -cs.DM(self.gains.k_c) * nu_ce[:TASK], -cs.DM(self.gains.k_e) * nu_ce[TASK:]

    @cached_property
    def camera_velocity(self) -> Matrix:
        """``dc/dt = J_p qd``."""
        return self.task_jacobian @ self.qd

    @cached_property
    def estimate_rate(self) -> Matrix:
        """``dpbar/dt = -J_p qd + u_e`` (P2)."""
        return -self.camera_velocity + self._camera_inputs[1]

    def held_estimate(self, v_wc: Matrix, u_e: Matrix, h: Matrix | float) -> Matrix:
        """``pbar + h (u_e - v_wc)``: (P2) over ``h`` with ``J_p qd = v_wc`` and ``u_e`` held, exactly."""
        return self.pbar + h * (u_e - v_wc)

    @cached_property
    def observer_velocity(self) -> Matrix:
        """``dpbar/dt`` as the observer runs: (P2), or with its inputs held, ``-V_k + U_k`` (sampled loop)."""
        if not self.sampled:
            return self.estimate_rate
        v, u = self.observer_hold
        return -v + u

    @cached_property
    def observer_rate(self) -> Matrix:
        return self.observer_velocity

    @cached_property
    def observer_input_error(self) -> Matrix:
        """``D = -(V_k - J_p qd) + U_k - u_e``: the observer's rate less (P2)'s."""
        return self.observer_velocity - self.estimate_rate

    @cached_property
    def qd_d(self) -> Matrix:
        """``qd_d = pinv(J_p) u_d`` (P5)."""
        return pseudo_inverse(self.task_jacobian) @ self._camera_inputs[0]

    def reference_acceleration(self, estimate_rate: Matrix) -> Matrix:
        """``d qd_d/dt`` along ``(qd, 1, estimate_rate)`` (P6: :attr:`qdd_d` along (P2))."""
        args = cs.vertcat(self.q, self.t, self.pbar)
        return cs.jtimes(self.qd_d, args, cs.vertcat(self.qd, 1, estimate_rate))

    @cached_property
    def w(self) -> Matrix:
        """``w = [tau_d; v_o]`` (P9)."""
        return cs.vertcat(self.tau_d, cs.jacobian(self.target_position, self.t))

    @cached_property
    def tau(self) -> Matrix:
        """Torque law (P6)."""
        r = self.robot
        feedforward = r.mass_matrix @ self.qdd_d + r.coriolis_times(self.qd_d) + r.gravity
        return feedforward + self.task_jacobian.T @ (self.weights.w_pc * self.e_c) + self.u[0 : r.n]

    @cached_property
    def storage(self) -> Matrix:
        """Storage function (P8)."""
        w = self.weights
        kinetic = self.xi.T @ self.robot.mass_matrix @ self.xi / 2
        return kinetic + w.w_pc * cs.sumsqr(self.e_c) / 2 + w.w_pe * cs.sumsqr(self.e_e) / 2

    @cached_property
    def conditioning(self) -> dict[str, Matrix]:
        """Matrices the law inverts: ``J_p`` (P5) and, in image mode, ``A`` (P12)."""
        return {"J_p": self.task_jacobian, "A": self.image_map}

    def initial_state(self, q0: np.ndarray, qd0: np.ndarray, estimation_error: SE3) -> np.ndarray:
        """``s(0)`` with ``e_e(0)`` the first two coordinates of the estimation error's translation."""
        p0 = np.asarray(cs.Function("p0", [self.q, self.t], [self.relative_position])(q0, 0.0)).ravel()
        error = np.asarray(cs.DM(estimation_error.translation)).ravel()[:TASK]
        return np.concatenate([q0, qd0, p0 - error])
