"""The operating envelope of a design with integral action (docs/math.md, fact 23).

Scope: the ideal continuous loop (exact ``e_e``, the law's model), ``u_xi = -K_xi xi - K_I z``,
``dz/dt = xi`` from ``integral_start = T_I`` on, ``J_b`` of full row rank on a box ``R`` of
configurations. The storage is ``V_eps = V_a + eps z^T M(q) xi`` (``V_a = V + z^T K_I z / 2``,
fact 20.1), whose exact rate is (23.2). With the bounds of :mod:`dvfc.models.inertia` (the
Christoffel rows ``g_i`` and the camera levers ``d_i``, for every ``q``) and ``s_lo <=
sigma_min(J_b)`` on ``R`` (:func:`sigma_min_on_box`), the rate inequality

    dV_eps/dt <= -kappa V_eps + |V_wo|^2 / (4 s) + |tau_d|^2 / (4 s_t)

holds on ``Omega = {V_eps <= c} ∩ {q in R}`` whenever ``F0 - kappa F1 >= 0`` (fact 23.3, a
``2n + 12`` matrix). For fixed ``(eps, s, mu)`` that condition is jointly convex in ``kappa`` and the
Young multipliers ``(theta, rho, Lambda)``: :func:`best_rate` maximises ``kappa`` by one SDP, a
search over ``(eps, s, mu)`` maximises ``s kappa`` (the smallest ``c_inf``), and the rate is then
recomputed in closed form from the literal matrices at the SDP's multipliers
(``kappa = lambda_min(F1^-1/2 F0 F1^-1/2)``), shrunk by :data:`SHRINK` and re-checked.

The level ``c`` is self-consistent (``max(V_eps(T_I), c_inf) <= c <= c_max(theta_bar)``) and the
start is chained: ``z(T_I) = 0``, so ``V_eps(T_I) = V(T_I)``, bounded by the planned start's
certificate (fact 16b, 20.6). The box ``R`` is the range of the reference's inverse kinematics
over one period of the target's motion, widened by :data:`BOX_MARGIN`: that ``q`` stays in it is
an assumption (not implied by ``V_eps <= c``), checked on runs by ``verify``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import casadi as cs
import numpy as np

from dvfc.analysis.envelope import (
    SHRINK,
    THETA_GRID,
    Boxes,
    Design,
    desired_features,
    feature_boxes,
    kinetic_diagonal,
    level_bounds,
    self_consistent_level,
    visible_level,
)
from dvfc.analysis.quiet import silenced
from dvfc.models.inertia import camera_levers, christoffel_bounds
from dvfc.models.lie import SE3
from dvfc.models.robot import Robot

BOX_MARGIN = 0.05
"""Radians added on each side of the reference's inverse-kinematics range to form ``R``."""

BOX_TOLERANCE = 0.03
"""Refinement of ``s_lo``: cells are split until ``s_lo >= (1 - BOX_TOLERANCE)`` times the
smallest ``sigma_min`` found at a cell's centre (or :data:`BOX_EVALUATIONS` is spent)."""

BOX_EVALUATIONS = 200_000
"""Most ``J_b`` evaluations the refinement of ``s_lo`` spends."""

BOX_BATCH = 4096
"""Cells split per round of the refinement: those of the lowest bounds."""

PATH_SAMPLES = 96
"""Samples of one period of the target's motion at which the reference's inverse kinematics is solved."""

EPS_GRID = (0.3, 0.45, 0.6, 0.8)
MU_GRID = (0.1, 0.25, 0.5)
S_GRID = (0.55, 0.7, 0.85, 0.95)
"""The search over ``(eps, mu, s)`` (``s`` as a fraction of the largest ``s`` with ``Q_ce(s) > 0``):
a coarse grid, then coordinate refinement about its best point (:func:`best_rate`)."""

RATE_LEVELS = (0.0, 0.5, 0.9)
"""Fractions of the way from the envelope's level to ``c_max(theta_bar)`` at which the rate is sought."""

ASSUMPTIONS = (
    "ideal loop: the law uses the exact estimation error e_e (the image estimate (21) is first order)",
    "integral action u_xi = -K_xi xi - K_I z_I, dz_I/dt = xi from integral_start T_I on, z_I(T_I) = 0",
    "q stays in the box R of configurations on which sigma_min(J_b) >= s_lo (not implied by V_eps <= c; "
    "checked on runs)",
    "M(q) <= D_M, the Christoffel bounds g_i and the camera levers d_i for every configuration (docs/math.md, "
    "facts 10, 23: from the URDF, revolute joints with unit axes and positive semidefinite link inertias)",
    "target speed, target rate and joint-torque disturbance within the stated bounds at all times",
)


@dataclass(frozen=True)
class ArmBounds:
    """What fact 23 needs of the arm: the Christoffel rows ``g_i`` (B1), the camera levers ``d_i``,
    ``U = [d, 1]`` and ``jbar`` (B2), the per-joint Lipschitz constants of ``J_b`` ``L_k`` (B3.4), the
    box ``R`` (``lower``, ``upper``; ``varied``: the joints ``sigma(J_b)`` depends on) and ``s_lo``."""

    rows: np.ndarray
    whole: float
    levers: np.ndarray
    lipschitz: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    varied: np.ndarray
    s_lo: float
    s_centre: float
    cells: int

    @property
    def u(self) -> np.ndarray:
        """``U = [d, 1]`` (n, 2): ``|J_b^T J_b| <= U U^T`` entrywise."""
        return np.stack([self.levers, np.ones_like(self.levers)], axis=1)

    @property
    def jbar(self) -> float:
        """``||J_b|| <= jbar = sqrt(lambda_max(U^T U))`` for every ``q``."""
        return float(math.sqrt(np.linalg.eigvalsh(self.u.T @ self.u)[-1]))

    def contains(self, q: np.ndarray) -> np.ndarray:
        """Whether each configuration of ``q`` (..., n) lies in ``R`` (joints not varied are free)."""
        inside = (q >= self.lower - 1e-12) & (q <= self.upper + 1e-12)
        return np.all(inside | ~self.varied, axis=-1)

    def as_dict(self) -> dict:
        return {"coriolis_rows": self.rows.tolist(), "coriolis_whole": self.whole, "levers_m": self.levers.tolist(),
                "jbar": self.jbar, "lipschitz": self.lipschitz.tolist(), "box_lower": self.lower.tolist(),
                "box_upper": self.upper.tolist(), "box_joints": [int(k) for k in np.flatnonzero(self.varied)],
                "s_lo": self.s_lo, "s_centre_min": self.s_centre, "cells": self.cells,
                "box": f"the reference's inverse kinematics over one period of the target's motion, +- {BOX_MARGIN} "
                       "rad (an assumption: q stays in it, checked on runs)"}  # fmt: skip


def jacobian_lipschitz(levers: np.ndarray) -> np.ndarray:
    """``L_k`` with ``||dJ_b/dq_k|| <= L_k`` for every ``q`` (fact 23, B3): column ``i < k`` of
    ``dJ_b/dq_k`` is the bracket ``[col_i, col_k]`` (0 for ``i >= k``), of length at most
    ``sqrt((d_i + d_k)^2 + 1)``; ``L_k`` is the Frobenius norm of those bounds."""
    n = len(levers)
    return np.array([math.sqrt(sum((levers[i] + levers[k]) ** 2 + 1 for i in range(k))) for k in range(n)])


def jacobian_curvature(levers: np.ndarray) -> np.ndarray:
    """``H_kl >= ||d^2 J_b / dq_k dq_l||_F`` for every ``q`` (fact 23, B3): column ``i < k`` of
    ``d/dq_l [col_i, col_k]`` is ``[[col_i, col_l], col_k]`` (when ``i < l``) plus ``[col_i, [col_k, col_l]]``
    (when ``k < l``), each of length at most ``sqrt((d_i + d_k + d_l)^2 + 1)``; the smaller of the bounds
    for ``(k, l)`` and ``(l, k)`` (the derivative is symmetric)."""
    n = len(levers)
    h = np.zeros((n, n))
    for k in range(n):
        for ll in range(n):
            h[k, ll] = math.sqrt(sum(((i < ll) + (k < ll)) ** 2 * ((levers[i] + levers[k] + levers[ll]) ** 2 + 1)
                                     for i in range(k)))  # fmt: skip
    return np.minimum(h, h.T)


def bracket(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Lie bracket ``[a, b] = ad_a b`` of twists ``(v, w)`` (..., 6): ``(w_a x v_b - w_b x v_a, w_a x w_b)``."""
    va, wa, vb, wb = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
    return np.concatenate([np.cross(wa, vb) - np.cross(wb, va), np.cross(wa, wb)], axis=-1)


def jacobian_function(robot: Robot) -> cs.Function:
    """``q -> J_b(q)`` (6, n)."""
    return cs.Function("J_b", [robot.q], [robot.body_jacobian])


def sigma_min_on_box(jacobian: cs.Function, lower: np.ndarray, upper: np.ndarray, varied: np.ndarray,
                     levers: np.ndarray) -> tuple[float, float, int]:  # fmt: skip
    """``s_lo <= sigma_6(J_b(q))`` for every ``q`` of the box (fact 23, B3.5). On a cell of centre
    ``q_c`` and half-widths ``h``, Weyl's inequality and the mean value theorem along the segment from
    ``q_c`` give ``sigma_6(J_b(q)) >= sigma_6(J_b(q_c)) - sum_k h_k (||dJ_b/dq_k(q_c)||_F + sum_l h_l H_kl / 2)``
    (``dJ_b/dq_k`` from the brackets at the centre, ``H`` of :func:`jacobian_curvature` for every ``q``).
    Cells are split in two (along the joint with the largest ``h_k L_k``), :data:`BOX_BATCH` of the
    lowest bounds a round, until the lowest lies within :data:`BOX_TOLERANCE` of the smallest centre
    value or :data:`BOX_EVALUATIONS` are spent. Joints not ``varied`` sit at their box's middle.
    Returns ``(s_lo, smallest centre value, cells)``."""
    mid, half = (lower + upper) / 2, np.where(varied, (upper - lower) / 2, 0.0)
    lipschitz, curvature = jacobian_lipschitz(levers), jacobian_curvature(levers)
    n = len(levers)
    later = np.triu(np.ones((n, n)), 1)  # later[i, k]: column i of dJ/dq_k is [col_i, col_k] for i < k
    centres, halves = mid[None, :], half[None, :]
    spent = 0

    def evaluate(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nonlocal spent
        spent += len(points)
        j = np.asarray(jacobian.map(len(points))(points.T)).reshape(6, len(points), n).transpose(1, 2, 0)  # (K, n, 6)
        brackets = np.linalg.norm(bracket(j[:, :, None, :], j[:, None, :, :]), axis=-1)  # (K, i, k)
        slopes = np.sqrt(np.einsum("pik,ik->pk", brackets**2, later))  # ||dJ/dq_k(q_c)||_F
        return np.linalg.svd(j, compute_uv=False)[:, min(n, 6) - 1], slopes

    def lows(values, slopes, halves):
        return values - np.sum(halves * (slopes + 0.5 * halves @ curvature), axis=1)

    values, slopes = evaluate(centres)
    while True:
        bounds = lows(values, slopes, halves)
        if bounds.min() >= (1 - BOX_TOLERANCE) * values.min() or spent + 2 * BOX_BATCH > BOX_EVALUATIONS:
            return float(bounds.min()), float(values.min()), len(values)
        split = np.zeros(len(values), dtype=bool)
        split[np.argsort(bounds)[:BOX_BATCH]] = True  # the lowest bounds first
        c, h = centres[split], halves[split].copy()
        axis = np.argmax(h * lipschitz, axis=1)
        rows = np.arange(len(c))
        h[rows, axis] /= 2
        shift = np.zeros_like(c)
        shift[rows, axis] = h[rows, axis]
        fresh = np.concatenate([c - shift, c + shift])
        new_values, new_slopes = evaluate(fresh)
        centres = np.concatenate([centres[~split], fresh])
        halves = np.concatenate([halves[~split], h, h])
        values = np.concatenate([values[~split], new_values])
        slopes = np.concatenate([slopes[~split], new_slopes])


def reference_path(robot: Robot, start: np.ndarray, poses: list[np.ndarray]) -> np.ndarray:
    """The inverse kinematics of the camera goals ``poses`` (4x4 each), followed by least-norm
    Gauss-Newton steps from ``start`` through the goals in order (the branch a run from ``start``
    follows); (K, n). Raises ValueError when a goal is not reached (1e-9 m, rad)."""
    q = robot.q
    pose = robot.camera_pose.as_matrix()
    goal = cs.SX.sym("goal", 4, 4)
    residual = cs.vertcat(pose[:3, 3] - goal[:3, 3], cs.vec(pose[:3, :3] - goal[:3, :3]) / 2)
    f = cs.Function("r", [q, goal], [residual, cs.jacobian(residual, q)])
    out, current = [], np.asarray(start, dtype=float).copy()
    for g in poses:
        for _ in range(60):
            r, j = (np.asarray(v) for v in f(current, g))
            step = np.linalg.lstsq(j, -r.ravel(), rcond=None)[0]
            current = current + step
            if np.linalg.norm(step) < 1e-12:
                break
        r = np.asarray(f(current, g)[0]).ravel()
        if np.abs(r).max() > 1e-9:
            raise ValueError("the reference's inverse kinematics does not reach the camera goal "
                             f"(residual {np.abs(r).max():.2g})")
        out.append(current.copy())
    return np.array(out)


def arm_bounds(robot: Robot, q_path: np.ndarray) -> ArmBounds:
    """:class:`ArmBounds` for ``robot`` with the box ``R`` about the configurations ``q_path`` (K, n)."""
    if robot.moving != robot.joints:
        raise ValueError("the Christoffel bounds (docs/math.md, fact 23) are derived for independent joints only "
                         "(this arm has mimic joints)")
    mount = np.asarray(cs.DM(robot.mount.as_matrix()))[:3, 3]
    coriolis = christoffel_bounds(robot.urdf, robot.joints)
    levers = camera_levers(robot.urdf, robot.joints, robot.frame, mount)
    lipschitz = jacobian_lipschitz(levers)
    lower, upper = q_path.min(axis=0) - BOX_MARGIN, q_path.max(axis=0) + BOX_MARGIN
    varied = np.ones(robot.n, dtype=bool)
    varied[0] = False  # J_b does not depend on q_1 (B3.1)
    if levers[-1] == 0.0:  # the camera on the last axis: exp(-q_n xi_n) acts as diag(R, R) (B3.2)
        varied[-1] = False
    s_lo, centre, cells = sigma_min_on_box(jacobian_function(robot), lower, upper, varied, levers)
    return ArmBounds(coriolis.rows, coriolis.whole, levers, lipschitz, lower, upper, varied, s_lo, centre, cells)


@dataclass(frozen=True)
class Problem:
    """Fact 23.3's data for one design: ``k_xi``, ``k_I``, ``D = D_M(v)`` (the Perron vector of
    ``diag(k_xi)^-1 B``), ``max k_c``, ``Y0^T Y0`` (``y = Y0 e_c``, ``u_d = K_c y``), the arm's bounds
    and the pose block ``Q_ce(s) = N^T K N - s W`` of :class:`~dvfc.analysis.envelope.Design`."""

    design: Design
    k_i: np.ndarray
    kinetic: np.ndarray
    kc: float
    y0ty0: np.ndarray
    arm: ArmBounds
    torque: float

    @property
    def n(self) -> int:
        return len(self.k_i)

    @property
    def s_limit(self) -> float:
        """The largest ``s`` with ``Q_ce(s) > 0``."""
        root = np.sqrt(self.design.w)
        return float(1.0 / np.linalg.eigvalsh(root[:, None] * np.linalg.inv(self.design.nkn) * root[None, :])[-1])

    def zbar(self, eps: float, c: float) -> float:
        """``|z| <= zbar = sqrt(2c / min(k_I - eps^2 D))`` on ``{V_eps <= c}`` (23.1); inf when not positive."""
        floor = float(np.min(self.k_i - eps**2 * self.kinetic))
        return math.sqrt(2 * c / floor) if floor > 0 else math.inf


def problem_of(design: Design, k_i: np.ndarray, arm: ArmBounds, reference: SE3, torque: float) -> Problem:
    """The :class:`Problem` of ``design`` with integral gains ``k_i``."""
    kinetic = kinetic_diagonal(design.mass, design.k_xi, np.array([0.0]))[0]
    w = design.point.weights
    w_c = np.diag(np.r_[np.full(3, w.w_pc), np.full(3, w.w_rc)])
    y0 = np.asarray(cs.DM(reference.inverse().adjoint())).T @ w_c
    return Problem(design, np.asarray(k_i, float), kinetic, float(np.max(design.point.k_c)), y0.T @ y0, arm, torque)


@dataclass(frozen=True)
class Multipliers:
    """A point of fact 23.3: ``eps``, ``s``, ``mu``, ``s_t`` and the Young multipliers."""

    eps: float
    s: float
    mu: float
    s_t: float
    theta: np.ndarray
    rho: np.ndarray
    lam: np.ndarray


def matrices(p: Problem, m: Multipliers, theta_bar: float, c: float) -> tuple[np.ndarray, np.ndarray]:
    """``F0`` and ``F1`` of fact 23.3, literally (size ``2n + 12``), at level ``c``."""
    n, eps, arm = p.n, m.eps, p.arm
    zbar, d, g, k_xi = p.zbar(eps, c), p.kinetic, arm.rows, p.design.k_xi
    coriolis = eps * zbar * (g * m.theta / 2 + np.sum(g / (2 * m.theta)) + p.kc * g * m.rho / (2 * arm.s_lo))
    a0 = k_xi - m.s_t - eps * d - coriolis
    b0 = eps * (k_xi / 2 - m.s_t)
    c0 = eps * (p.k_i - eps * m.s_t - m.lam / 2)
    u = arm.u
    y_c = (eps * zbar * p.kc / (2 * arm.s_lo) * np.sum(g / m.rho)
           + eps / 2 * np.linalg.eigvalsh(u.T @ (u / m.lam[:, None]))[-1])  # fmt: skip
    pose = p.design.nkn - m.s * np.diag(p.design.w)
    pose[:6, :6] -= y_c * p.y0ty0
    f0 = np.zeros((2 * n + 12, 2 * n + 12))
    f0[:n, :n], f0[n : 2 * n, n : 2 * n] = np.diag(a0), np.diag(c0)
    f0[:n, n : 2 * n] = f0[n : 2 * n, :n] = np.diag(b0)
    f0[2 * n :, 2 * n :] = pose
    a1 = (1 + eps * m.mu) * d / 2
    c1 = p.k_i / 2 + eps * d / (2 * m.mu)
    f1 = np.diag(np.concatenate([a1, c1, p.design.d_diagonal(np.array([theta_bar]))[0]]))
    return f0, f1


def literal_rate(p: Problem, m: Multipliers, theta_bar: float, c: float) -> tuple[float, float]:
    """The largest ``kappa`` with ``F0 - kappa F1 >= 0`` at these multipliers, ``lambda_min(F1^-1/2
    F0 F1^-1/2)``, shrunk by :data:`SHRINK`, and the a posteriori margin ``lambda_min(F0 - kappa F1)``
    at it (certified when ``>= 0``); ``(-inf, -inf)`` when ``zbar`` is not finite."""
    if not math.isfinite(p.zbar(m.eps, c)):
        return -math.inf, -math.inf
    f0, f1 = matrices(p, m, theta_bar, c)
    scale = 1 / np.sqrt(np.diag(f1))
    top = float(np.linalg.eigvalsh(scale[:, None] * f0 * scale[None, :])[0])
    kappa = top * (1 - SHRINK) if top > 0 else top
    return kappa, float(np.linalg.eigvalsh(f0 - kappa * f1)[0])


class RateProgram:
    """The SDP of fact 23.3 at fixed ``(eps, s, mu, s_t)``: maximise ``kappa`` over
    ``(theta, rho, Lambda)`` subject to each joint's 2 x 2 block of ``F0 - kappa F1`` being positive
    semidefinite (``|(2 b_i, A_i - C_i)| <= A_i + C_i``), ``Y_c <= Y`` with ``lambda_max(U^T Lambda^-1 U) <= t``
    written as ``[[t I_2, U^T], [U, diag(Lambda)]] >= 0``, and ``Q_ce(s) - kappa D_ce - Y diag(Y0^T Y0, 0)
    >= 0``. Built once per problem (parameters: the numbers that change with ``eps``, ``s``, ``mu``,
    ``c`` and ``theta_bar``)."""

    def __init__(self, p: Problem) -> None:
        import cvxpy as cp

        n, arm = p.n, p.arm
        self.p = p
        self.kappa = cp.Variable()
        self.theta, self.rho, self.lam = (cp.Variable(n, pos=True) for _ in range(3))
        big_t, t, y = cp.Variable(), cp.Variable(), cp.Variable()
        self.alpha, self.beta, self.gam, self.a1 = (cp.Parameter(n) for _ in range(4))
        self.b, self.c0, self.c1 = cp.Parameter(n), cp.Parameter(n), cp.Parameter(n)
        self.ezb, self.half_eps, self.k1 = (cp.Parameter(nonneg=True) for _ in range(3))
        self.pose, self.pose_d = cp.Parameter((12, 12), symmetric=True), cp.Parameter(12, nonneg=True)
        g = arm.rows
        a = self.alpha - cp.multiply(self.beta, self.theta) - self.ezb * big_t - cp.multiply(self.gam, self.rho) \
            - self.kappa * self.a1
        cc = self.c0 - self.half_eps * self.lam - self.kappa * self.c1
        u = arm.u
        coupling = cp.bmat([[t * np.eye(2), u.T], [u, cp.diag(self.lam)]])
        weight = np.zeros((12, 12))
        weight[:6, :6] = p.y0ty0
        pose = self.pose - self.kappa * cp.diag(self.pose_d) - y * weight
        constraints = [big_t >= cp.sum(cp.multiply(g / 2, cp.inv_pos(self.theta))),
                       y >= self.k1 * cp.sum(cp.multiply(g, cp.inv_pos(self.rho))) + self.half_eps * t,
                       coupling >> 0, (pose + pose.T) / 2 >> 0, self.kappa >= 0, self.lam <= 1e6]
        constraints.append(cp.SOC(a + cc, cp.vstack([2 * self.b, a - cc]), axis=0))  # [[a, b], [b, cc]] >= 0
        self.problem = cp.Problem(cp.Maximize(self.kappa), constraints)

    def solve(self, eps: float, s: float, mu: float, s_t: float, theta_bar: float, c: float) -> Multipliers | None:
        """The multipliers maximising ``kappa`` at these values; None when infeasible or on solver trouble."""
        import cvxpy as cp

        p, arm = self.p, self.p.arm
        zbar = p.zbar(eps, c)
        if not math.isfinite(zbar):
            return None
        d, g = p.kinetic, arm.rows
        self.alpha.value = p.design.k_xi - s_t - eps * d
        self.beta.value = eps * zbar * g / 2
        self.gam.value = eps * zbar * p.kc * g / (2 * arm.s_lo)
        self.a1.value = (1 + eps * mu) * d / 2
        self.b.value = eps * (p.design.k_xi / 2 - s_t)
        self.c0.value = eps * (p.k_i - eps * s_t)
        self.c1.value = p.k_i / 2 + eps * d / (2 * mu)
        self.ezb.value, self.half_eps.value = eps * zbar, eps / 2
        self.k1.value = eps * zbar * p.kc / (2 * arm.s_lo)
        pose = p.design.nkn - s * np.diag(p.design.w)
        self.pose.value = (pose + pose.T) / 2
        self.pose_d.value = p.design.d_diagonal(np.array([theta_bar]))[0]
        try:
            with silenced():
                self.problem.solve(solver=cp.CLARABEL)
        except (cp.SolverError, ArithmeticError, ValueError):
            return None
        theta, rho, lam = self.theta.value, self.rho.value, self.lam.value
        solved = self.problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)
        if not solved or theta is None or rho is None or lam is None:
            return None
        return Multipliers(eps, s, mu, s_t, np.maximum(theta, 1e-12), np.maximum(rho, 1e-12), np.maximum(lam, 1e-12))


@dataclass(frozen=True)
class Rate:
    """A certified rate at ``(theta_bar, c)``: ``kappa`` (literal, shrunk, re-checked with ``margin``) at
    the multipliers ``m``; ``c_inf = (wbar_t^2 / (4 s) + tbar^2 / (4 s_t)) / kappa``."""

    theta_bar: float
    c: float
    kappa: float
    margin: float
    m: Multipliers
    c_inf: float


def _c_inf(m: Multipliers, kappa: float, speed2: float, torque: float) -> float:
    if kappa <= 0:
        return math.inf
    torque_part = 0.0 if torque == 0 else (torque**2 / (4 * m.s_t) if m.s_t > 0 else math.inf)
    return (speed2 / (4 * m.s) + torque_part) / kappa


def best_rate(program: RateProgram, theta_bar: float, c: float, speed2: float, start: Multipliers | None = None,
              *, fastest: bool = False) -> Rate | None:  # fmt: skip
    """The multipliers with the smallest ``c_inf`` (largest ``s kappa``) found at ``(theta_bar, c)``, or
    (``fastest``) the largest ``kappa`` among those with ``c_inf <= c``: the
    grid :data:`EPS_GRID` x :data:`MU_GRID` x :data:`S_GRID` (or only ``start``'s neighbourhood when
    given), then coordinate steps halving about the best point; each candidate's rate is the literal
    one (:func:`literal_rate`) at the SDP's multipliers. None when no candidate passes the re-check."""
    p = program.p
    s_lim = p.s_limit
    torque = p.torque
    s_ts = (0.0,) if torque == 0 else tuple(f * float(p.design.k_xi.min()) for f in (0.05, 0.15, 0.3))
    best: Rate | None = None

    def trial(eps: float, s: float, mu: float, s_t: float) -> None:
        nonlocal best
        if not (0 < s < s_lim and eps > 0 and mu > 0):
            return
        m = program.solve(eps, s, mu, s_t, theta_bar, c)
        if m is None:
            return
        kappa, margin = literal_rate(p, m, theta_bar, c)
        if kappa <= 0 or margin < 0:
            return
        c_inf = _c_inf(m, kappa, speed2, torque)
        if fastest and c_inf > c:
            return
        if best is None or (kappa > best.kappa if fastest else c_inf < best.c_inf):
            best = Rate(theta_bar, c, kappa, margin, m, c_inf)

    if start is None:
        for eps in EPS_GRID:
            for mu in MU_GRID:
                for frac in S_GRID:
                    for s_t in s_ts:
                        trial(eps, frac * s_lim, mu, s_t)
    else:
        trial(start.eps, min(start.s, 0.999 * s_lim), start.mu, start.s_t)
    if best is None:
        return None
    step = 0.25
    for _ in range(4):  # coordinate refinement: relative steps 25%, 12.5%, ...
        for _ in range(2):
            for name in ("eps", "mu", "s"):
                for sign in (-1, 1):
                    m = best.m
                    values = {"eps": m.eps, "mu": m.mu, "s": m.s, "s_t": m.s_t}
                    values[name] *= 1 + sign * step
                    trial(values["eps"], values["s"], values["mu"], values["s_t"])
        step /= 2
    return best


@dataclass(frozen=True)
class IntegralEnvelope:
    """The certified envelope with integral action at one ``theta_bar``: the rate, the level ``c``, the
    start's ``V_eps(T_I)`` bound it covers, the boxes at ``c`` and at ``c_inf``."""

    rate: Rate
    start_level: float
    boxes: Boxes | None
    ultimate_boxes: Boxes | None


def level_search(program: RateProgram, camera, desired: np.ndarray | None, start_level: float, speed2: float,
                 theta_bar: float | None) -> IntegralEnvelope | None:  # fmt: skip
    """The smallest ``theta_bar`` of the 1-degree grid (or the given one) with a self-consistent level:
    ``c`` starts at ``c_max(theta_bar)`` (``zbar`` largest) and is lowered to ``max(V_eps(T_I), c_inf(c))``
    while that falls (a lower level gives a smaller ``zbar``, so a larger rate); each level's rate is
    re-checked literally. None when no ``theta_bar`` has one."""
    design = program.p.design
    grid = np.array([theta_bar]) if theta_bar is not None else THETA_GRID
    weights = np.asarray(design.weights)
    for th in grid:
        c_max = float(self_consistent_level(weights, th))
        if c_max <= start_level:
            continue
        rate = best_rate(program, float(th), c_max, speed2)
        if rate is None or rate.c_inf > c_max:
            continue
        for _ in range(4):
            c = max(start_level, rate.c_inf) * (1 + 1e-6)
            if c >= rate.c * (1 - 1e-3):
                break
            lower = best_rate(program, float(th), c, speed2, rate.m)
            if lower is None or lower.c_inf > c:
                break
            rate = lower
        boxes = ultimate = None
        if desired is not None and camera.has_image:
            boxes = feature_boxes(design, camera, desired, rate.c)
            ultimate = feature_boxes(design, camera, desired, rate.c_inf)
        return IntegralEnvelope(rate, start_level, boxes, ultimate)
    return None


def bounds_of(p: Problem, env: IntegralEnvelope) -> dict:
    """The error bounds on ``{V_pose <= c_inf}`` (ultimately; (23.1): ``V_eps >= V_pose``), with
    ``|z_I| <= sqrt(2 c_inf / min(k_I - eps^2 D))`` and ``|xi| <= sqrt(2 c / m_lo) + eps zbar`` (on
    ``{V_eps <= c}``: ``|xi + eps z|_M^2 <= 2c``)."""
    design, rate = p.design, env.rate
    out = level_bounds(design.weights, design.mass.m_lo, True, rate.c_inf)
    zbar = p.zbar(rate.m.eps, rate.c)
    out["xi"] = math.sqrt(2 * rate.c / design.mass.m_lo) + rate.m.eps * zbar if design.mass.m_lo > 0 else math.inf
    out["z_I"] = p.zbar(rate.m.eps, rate.c_inf)
    return out


def speed_limit(program: RateProgram, camera, desired: np.ndarray, env: IntegralEnvelope,
                other2: float, speed2: float) -> tuple[float | None, Rate | None]:  # fmt: skip
    """The largest target speed with the statement kept at ``env``'s ``theta_bar``: the level raised
    to ``0.999 min(c_max, c_vis)`` (``c_vis`` the largest level whose feature boxes fit), its rate
    re-checked there, and ``speed^2 = 4 s (kappa c - tbar^2 / (4 s_t)) - other2`` (``other2``: the target's
    rate squared, the same channel; ``speed2``: the scenario's, for the search's objective). Returns
    ``(speed, rate)`` or ``(None, None)``."""
    design = program.p.design
    c_max = float(self_consistent_level(np.asarray(design.weights), env.rate.theta_bar))
    cap = 0.999 * min(c_max, visible_level(design, camera, desired))
    if cap <= env.start_level:
        return None, None
    rate = best_rate(program, env.rate.theta_bar, cap, speed2, env.rate.m)
    if rate is None:
        return None, None
    torque = program.p.torque
    torque_part = 0.0 if torque == 0 else torque**2 / (4 * rate.m.s_t)
    room = 4 * rate.m.s * (rate.kappa * cap - torque_part) - other2
    if room <= 0:
        return None, None
    return math.sqrt(room) * (1 - 1e-9), rate


def storage_symbol(loop, eps: float) -> cs.SX:
    """``V_eps = V_a + eps z_I^T M(q) xi`` (fact 23) as an expression of the loop's ``(t, s)``."""
    return loop.augmented_storage + eps * loop.z_i.T @ loop.robot.mass_matrix @ loop.xi


def storage_and_rate(loop, eps: float) -> cs.Function:
    """``(t, s) -> (V_eps, dV_eps/dt, |V_wo|^2, |tau_d|^2)`` along the loop, the rate by automatic
    differentiation of :func:`storage_symbol` (independent of (23.2))."""
    v = storage_symbol(loop, eps)
    state, rate = cs.vertcat(loop.state, loop.t), cs.vertcat(loop.state_rate, 1)
    n = loop.robot.n
    w = loop.w
    return cs.Function("V_eps", [loop.t, loop.state],
                       [v, cs.jtimes(v, state, rate), cs.sumsqr(w[n:]), cs.sumsqr(w[:n])])  # fmt: skip


def path_configurations(loop, reference: SE3, q0: np.ndarray, horizon: float) -> np.ndarray:
    """The reference's inverse kinematics (:func:`reference_path`) at :data:`PATH_SAMPLES` times of one
    period of the target's motion from ``integral_start`` (of ``horizon`` when it has no period; one
    time for a target at rest), the camera goal ``g_wo(t) g_d^-1``, from ``q0``."""
    target = loop.target
    period = target.motion_period
    moving = target.speed > 0 or target.rate > 0
    span = (period if period is not None else horizon) if moving else 0.0
    times = loop.integral_start + np.linspace(0.0, span, PATH_SAMPLES if moving else 1, endpoint=False)
    pose = cs.Function("g_wo", [loop.t], [target.pose(loop.t).as_matrix()])
    goal = np.asarray(cs.DM(reference.inverse().as_matrix()))
    return reference_path(loop.robot, q0, [np.asarray(pose(t)) @ goal for t in times])


def statement(record: dict) -> str:
    """What the envelope with integral action states, from its record."""
    if record["rate"] is None:
        return f"no envelope certified with integral action: {record['reason']}"
    fact = record["integral"]
    t_i, start = fact["T_I"], record["start"]
    when = (f"for t >= T_I = {t_i:.3g} s while q stays in the box R (ideal continuous loop with integral action, "
            f"the plant equal to the law's model, fact 23)")  # fmt: skip
    fast = fact["rate_multipliers"]
    level = (f"V_eps(t) <= c = {record['level']:.4g} and ultimately c_inf = {record['ultimate_V']:.4g} (eps = "
             f"{fact['eps']:.3g}); V_eps decays at {record['rate']:.4g} 1/s (eps = {fast['eps']:.3g}, on V_eps <= "
             f"{fast['level']:.4g})")  # fmt: skip
    if start.get("inside"):
        chained = f"from the start (facts 16b, 20.6: z_I(T_I) = 0, V_eps(T_I) = V(T_I) <= {fact['start_level']:.4g})"
    else:
        chained = "for runs with V_eps <= c at T_I (the start is not certified)"
    seen = ""
    if record["visible"] is True:
        seen = f"; every feature stays in the image, at least {record['image_margin_px']:.4g} px inside"
    elif record["visible"] is False:
        seen = "; visibility is NOT certified: a certified feature region reaches the image border or zero depth"
    return f"{when}: {level} {chained}{seen}"


def fastest_rate(program: RateProgram, rate: Rate, speed2: float) -> Rate:
    """The largest certified rate on a level between ``rate.c`` and ``c_max(theta_bar)`` (:data:`RATE_LEVELS`)
    with ``c_inf`` below it: a larger level allows a smaller ``s`` (a larger ``kappa``) at the cost of a
    larger ``zbar``. Each inequality holds on its own level set ``{V_eps' <= c'}`` (its own ``eps'``,
    ``c' >= rate.c``). Where ``z_I = 0`` every storage is ``V``, so a run with ``V(T_I) <= rate.c`` (the
    chained start, or a run the statement covers from ``T_I``) starts inside each of them. Elsewhere
    ``V_eps' - V_eps = (eps' - eps) z_I^T M xi`` takes both signs: for ``eps' != eps`` the level sets of one
    level are not nested, so ``{V_eps <= rate.c}`` need not lie in ``{V_eps' <= c'}``. It does when ``c' >=
    rho rate.c`` (sufficient, not necessary), ``rho = 1 + |eps' - eps| sqrt(beta) + 2 eps beta max(0, eps -
    eps')``, ``beta = max_i D_i / (k_I,i - eps^2 D_i)`` (``M <= D``); that is not checked here."""
    design = program.p.design
    c_max = float(self_consistent_level(np.asarray(design.weights), rate.theta_bar))
    best = rate
    for fraction in RATE_LEVELS:
        c = rate.c + fraction * (c_max - rate.c) * (1 - 1e-6)
        found = best_rate(program, rate.theta_bar, c, speed2, rate.m, fastest=True)
        if found is not None and found.kappa > best.kappa:
            best = found
    return best


def integral_envelope(loop, design: Design, disturbance, start: dict, q0: np.ndarray, horizon: float,
                      theta_bar: float | None, *, search: bool = True, start_at=None) -> dict:  # fmt: skip
    """The envelope record of fact 23 for the loop's design with integral action (the keys of
    :class:`~dvfc.analysis.envelope.Envelope`'s JSON, the fact's own numbers under ``integral``).

    ``disturbance``: the bounds on ``w``; ``start``: the start record until ``T_I`` (fact 20.6), whose
    level bounds ``V_eps(T_I) = V(T_I)``; ``q0``: where the reference's inverse kinematics starts;
    ``horizon``: the span of the reference path for a target without a period; ``search``: also the
    largest certified target speed, each candidate's start recomputed by ``start_at(disturbance)`` (the
    start's level at that disturbance, or None when not certified)."""
    t_i = loop.integral_start
    record = {"rate": None, "gamma_prime": None, "theta_bar_deg": None, "m_hi": design.mass.m_hi,
              "m_lo": design.mass.m_lo, "ultimate_V": None, "bounds": None, "level": None, "visible": None,
              "image_margin_px": None, "depth_min": None, "start": start, "max_target_speed": None,
              "max_torque": None, "wbar": disturbance.wbar, "invariant_V": None, "boxes_px": None,
              "ultimate_boxes_px": None, "recheck_margin": None, "reason": None,
              "assumptions": list(ASSUMPTIONS)}  # fmt: skip
    if design.reference is None:
        record["reason"] = "fact 23 is derived for the paper's loop, not the reduced planar one"
        record["statement"] = statement(record)
        return record
    try:
        arm = arm_bounds(loop.robot, path_configurations(loop, design.reference, q0, horizon))
    except ValueError as exc:
        record["reason"] = str(exc)
        record["statement"] = statement(record)
        return record
    p = problem_of(design, np.asarray(loop.gains.k_i, dtype=float), arm, design.reference, disturbance.torque)
    start_level = float(start["level"]) if start.get("inside") else 0.0
    speed2 = disturbance.target_speed**2 + disturbance.target_rate**2
    program = RateProgram(p)
    camera = loop.camera
    desired = desired_features(camera, design.reference)
    found = level_search(program, camera, desired, start_level, speed2, theta_bar)
    fact = {"T_I": t_i, "storage": "V_eps = V_a + eps z_I^T M(q) xi (fact 23)", "start_level": start_level,
            "arm": arm.as_dict(), "kinetic_diagonal": p.kinetic.tolist()}  # fmt: skip
    if arm.s_lo <= 0:
        record["reason"] = f"sigma_min(J_b) is not bounded away from 0 on the box R (s_lo = {arm.s_lo:.3g})"
    elif found is None:
        record["reason"] = ("no theta_bar with a self-consistent level: for every theta_bar, max(V_eps(T_I), c_inf) "
                            "exceeds c_max(theta_bar) or F0 - kappa F1 >= 0 has no positive kappa")  # fmt: skip
    if record["reason"] is not None:
        record.update(integral=fact, statement=statement({**record, "integral": fact}))
        return record
    assert found is not None
    rate = found.rate
    fastest = fastest_rate(program, rate, speed2)
    m = rate.m
    fact.update({"eps": m.eps, "s": m.s, "mu": m.mu, "s_t": m.s_t, "theta": m.theta.tolist(), "rho": m.rho.tolist(),
                 "Lambda": m.lam.tolist(), "zbar": p.zbar(m.eps, rate.c), "kappa_at_smallest_c_inf": rate.kappa,
                 "rate_multipliers": {"eps": fastest.m.eps, "s": fastest.m.s, "mu": fastest.m.mu,
                                      "level": fastest.c, "c_inf": fastest.c_inf, "recheck_margin": fastest.margin},
                 "norm_rate": fastest.kappa / 2})  # fmt: skip
    record.update({"rate": fastest.kappa, "gamma_prime": 1 / math.sqrt(2 * m.s),
                   "theta_bar_deg": math.degrees(rate.theta_bar), "ultimate_V": rate.c_inf,
                   "bounds": bounds_of(p, found), "level": rate.c,
                   "invariant_V": float(self_consistent_level(np.asarray(design.weights), rate.theta_bar)),
                   "recheck_margin": min(rate.margin, fastest.margin), "integral": fact})  # fmt: skip
    if found.boxes is not None:
        record.update({"visible": found.boxes.visible, "image_margin_px": found.boxes.margin_px,
                       "depth_min": found.boxes.depth_min, "boxes_px": found.boxes.boxes,
                       "ultimate_boxes_px": found.ultimate_boxes.boxes if found.ultimate_boxes else None})  # fmt: skip
    if search and found.boxes is not None and found.boxes.visible:
        record["max_target_speed"] = largest_speed(program, camera, desired, found, disturbance, start_at)
    record["statement"] = statement(record)
    return record


def largest_speed(program: RateProgram, camera, desired: np.ndarray, found: IntegralEnvelope, disturbance,
                  start_at) -> float | None:  # fmt: skip
    """The largest target speed of :func:`speed_limit`, re-checked a posteriori at that speed: the literal
    rate at its multipliers and level (:func:`literal_rate`) gives ``c_inf <= c``, the start recomputed
    there (``start_at``) lies below ``c`` and every feature region at ``c`` is in the image."""
    speed, rate = speed_limit(program, camera, desired, found, disturbance.target_rate**2,
                              disturbance.target_speed**2 + disturbance.target_rate**2)
    if speed is None or rate is None:
        return None
    trial = replace(disturbance, target_speed=speed)
    level = found.start_level if start_at is None else start_at(trial)
    kappa, margin = literal_rate(program.p, rate.m, rate.theta_bar, rate.c)
    c_inf = _c_inf(rate.m, kappa, speed**2 + trial.target_rate**2, program.p.torque)
    boxes = feature_boxes(program.p.design, camera, desired, rate.c)
    if level is None or level > rate.c or margin < 0 or c_inf > rate.c or not boxes.visible:
        return None
    return speed
