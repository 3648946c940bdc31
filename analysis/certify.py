"""Theorem 2 certificates: the smallest gamma with ``P(gamma) = N^T K N - W/(2 gamma^2) - S^2/2 >= 0``.

``N`` comes from :func:`dvfc.models.loop.output_matrix`, the expression the simulator uses;
``W = G D_w^2 G^T`` and ``S`` are the generalized plant's weights (docs/math.md, fact 17;
:class:`~dvfc.models.loop.PlantWeights`, the paper's ``W`` and ``I`` at unit weights).
``P`` does not depend on the robot (docs/math.md, fact 1): the ``xi`` block of ``N`` is the
identity, so that block decouples and needs ``k_xi,i >= S_xi,i^2/2 + D_tau,i^2/(2 gamma^2)``
(``1/2 + 1/(2 gamma^2)`` at unit weights). The rest, over ``(e_c, e_e)``, depends on
``K_c, K_e, W_c, W_e, g_d``, the weights and on the rotation ``R_ec`` of the state.

Two routes to the smallest gamma:

- exact (docs/math.md, facts 3 and 17): with ``A = N^T K N - S^2/2`` and ``s = 1/(2 gamma^2)``, the
  largest ``s`` with ``A - s W >= 0`` is
  ``min(min_i (k_xi,i - S_xi,i^2/2)/D_tau,i^2, lambda_min(D^-1/2 Sc D^-1/2))``, ``Sc`` the Schur
  complement of the ``e_c`` block ``A_cc`` (where ``W`` vanishes) and ``D = W_e^2 D_v^2``; it
  requires ``A_cc > 0``. Batched over many gain points.
- SDP: ``maximize s  s.t.  A - s W >= 0`` with cvxpy and Clarabel (SCS as fallback).

Every answer is re-checked a posteriori on the literal ``P`` of Theorem 2: the reported
gamma is the computed one inflated by :data:`INFLATION`, and it is certified only when
``lambda_min(P(gamma)) >= 0`` there (the margin reported).

Region: for block-isotropic ``K_e`` (``k_e1 = k_e2 = k_e3``, ``k_e4 = k_e5 = k_e6``)
``P(R_ec)`` is congruent to ``P(I)`` (docs/math.md, fact 2), so ``R_ec = I`` decides for every
rotation. Otherwise the isotropic gains ``K_min`` (blockwise minima of ``K_e``) give a
sound bound for every ``R_ec`` (docs/math.md, fact 5); a search over rotations reports the worst
case it finds and the gap.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from enum import IntEnum
from functools import cache
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from dvfc.analysis.output import interrupted
from dvfc.models.lie import SE3, SO3
from dvfc.models.loop import PlantWeights, Weights, disturbance_matrix, disturbance_weight, output_matrix
from dvfc.models.planar import planar_disturbance_matrix, planar_output_matrix
from dvfc.models.robot import spans_the_task

if TYPE_CHECKING:
    import cvxpy as cp

INFLATION = 1e-6
"""Relative inflation of a computed gamma before the a posteriori check: at the exact
optimum ``P`` is singular; at ``gamma (1 + 1e-6)`` its smallest eigenvalue is positive
by a margin far above the eigenvalue solver's error (~1e-14 ||P||)."""

ASSUMPTIONS = (
    "exact estimation error e_e (ideal loop; the image estimate (21) is first order)",
    "n = 6 with J_b invertible, or n > 6 with J_b of full row rank",
    "rotation errors with |theta| < pi (e_R identifies R = I only there)",
    "feature points in front of the camera and J(gbar) of full column rank",
)


INTEGRAL_COVERAGE = {
    "lemma_2": "exact with V_a = V + z_I^T K_I z_I / 2: dV_a/dt = u'^T nu + x^T G w with u'_xi = u_xi + K_I z_I, and "
    "dV_a/dt = -nu^T K nu + x^T G w under the law (docs/math.md, fact 20.1)",
    "theorem_2": "the same P(gamma), so the same gamma, from w to x (not to z_I): int |x|^2 <= gamma^2 int |w|^2 + "
    "2 V_a(0), V_a(0) = V(0) with z_I(0) = 0 (fact 20.2)",
    "constant_torque": "under any constant joint torque and a static target the equilibrium has xi = 0, e_c = 0, e_e = "
    "0 and K_I z_I = tau_d (fact 20.3, exact)",
    "rate": "not certified: fact 7's exponential rate is lost; fact 20.4's V_eps rate needs sampled constants (fact "
    "20.4)",
    "implemented": "fact 14 with z_I in the monodromy (fact 21: n more states), local",
}
"""What the certificates cover for a design with integral action ``K_I``."""


def integral_coverage(point: GainPoint) -> dict | None:
    """:data:`INTEGRAL_COVERAGE` with the design's ``k_i`` (JSON-ready), or None without integral action."""
    if point.k_i is None:
        return None
    return {"k_i": np.asarray(point.k_i, dtype=float).tolist(), **INTEGRAL_COVERAGE}


@dataclass(frozen=True)
class GainPoint:
    """One design: the gains of (42), the weights of (35), the generalized plant's weights
    (``plant``, docs/math.md, fact 17; None: the paper's, every weight 1) and the integral gain
    ``k_i`` (fact 20; None: none). ``P(gamma)`` does not depend on ``k_i`` (fact 20.2)."""

    k_xi: np.ndarray
    k_c: np.ndarray
    k_e: np.ndarray
    weights: Weights
    plant: PlantWeights | None = None
    k_i: np.ndarray | None = None

    @property
    def plant_weights(self) -> PlantWeights:
        """The generalized plant's weights (unit when ``plant`` is None)."""
        return self.plant if self.plant is not None else PlantWeights.unit(len(self.k_xi))

    @property
    def output_squared(self) -> np.ndarray:
        """The diagonal of ``S^2`` (``n + 2 t`` entries, ``t`` the task's)."""
        return self.plant_weights.output(len(self.k_c)) ** 2

    @property
    def disturbance_weights(self) -> np.ndarray:
        """The diagonal of ``D_w`` (``n + t`` entries)."""
        return self.plant_weights.disturbance(len(self.k_c))

    @property
    def xi_limit(self) -> float:
        """The largest ``s = 1/(2 gamma^2)`` the ``xi`` block of ``P`` allows (docs/math.md, fact 17)."""
        return float(xi_limits(self.k_xi[None], self.plant_weights)[0])

    @property
    def isotropic(self) -> bool:
        """Block-isotropic ``K_e`` (the exact reduction of docs/math.md, fact 2 applies)."""
        return bool(np.ptp(self.k_e[:3]) == 0 and np.ptp(self.k_e[3:]) == 0)

    def with_k_e(self, k_e: np.ndarray) -> GainPoint:
        return GainPoint(self.k_xi, self.k_c, np.asarray(k_e, dtype=float), self.weights, self.plant, self.k_i)


def xi_limits(k_xi: np.ndarray, plant: PlantWeights) -> np.ndarray:
    """``min_i (k_xi,i - S_xi,i^2/2) / D_tau,i^2`` for a batch ``k_xi`` (B, n) and the generalized
    plant's weights: the ``xi`` block of ``P`` is ``diag(k_xi - S_xi^2/2 - s D_tau^2)`` (docs/math.md,
    fact 17), ``min k_xi - 1/2`` exactly at unit weights."""
    return ((k_xi - 0.5 * np.square(plant.xi)) / np.square(plant.tau_d)).min(axis=1)


def estimation_scale(weights: Weights, plant: PlantWeights, task: int = 6) -> np.ndarray:
    """The diagonal of ``W_e D_v`` (``task`` entries), whose square is ``W`` on ``e_e``: ``W_e`` at
    unit plant weights."""
    w_e = np.repeat([weights.w_pe, weights.w_re], 3) if task == 6 else np.full(task, float(weights.w_pe))
    return w_e * plant.disturbance(task)[len(plant.tau_d) :]


def sound_k_e(k_e: np.ndarray) -> np.ndarray:
    """The blockwise-minimum gains ``K_min = diag(min(k_e1..3) I3, min(k_e4..6) I3)`` (fact 5), for
    one ``K_e`` (6,) or a batch (B, 6): ``Q`` grows with ``K_e``, so a bound certified with
    ``K_min`` at ``R_ec = I`` holds for every ``R_ec`` (equal to ``K_e`` when block-isotropic)."""
    k_e = np.asarray(k_e, dtype=float)
    return np.repeat(np.stack([k_e[..., :3].min(axis=-1), k_e[..., 3:].min(axis=-1)], axis=-1), 3, axis=-1)


@dataclass
class Certificate:
    """What was certified, at which gamma, over which region, and why not if not."""

    certified: bool
    gamma: float | None
    method: str
    margin: float | None
    reason: str | None
    region: str
    gamma_worst_found: float | None = None
    worst_rotation: list[list[float]] | None = None
    gap: float | None = None


@cache
def _ce_block_function() -> cs.Function:
    """``N`` restricted to ``(e_c, e_e)`` (12 x 12) as a CasADi function of the weights,
    ``g_d`` and ``R_ec``: the simulator's expression with ``n = 0``."""
    w = cs.SX.sym("w", 4)
    p_d, r_d, r_ec = cs.SX.sym("p_d", 3), cs.SX.sym("R_d", 3, 3), cs.SX.sym("R_ec", 3, 3)
    n = output_matrix(Weights(w[0], w[1], w[2], w[3]), SE3(p_d, SO3(r_d)), r_ec, 0)
    return cs.Function("N_ce", [w, p_d, r_d, r_ec], [n])


@cache
def _mapped_ce_block_function(batch: int) -> cs.Function:
    return _ce_block_function().map(batch)


def output_blocks(weights: np.ndarray, reference: SE3, rotations: np.ndarray) -> np.ndarray:
    """``N_ce`` for a batch: ``weights`` (B, 4) as (w_pc, w_rc, w_pe, w_re), ``rotations``
    (B, 3, 3) values of ``R_ec``; returns (B, 12, 12)."""
    b = weights.shape[0]
    f = _mapped_ce_block_function(b)
    p_d = np.asarray(cs.DM(reference.translation))
    r_d = np.asarray(cs.DM(reference.rotation.matrix))
    r_ec = np.transpose(rotations, (1, 0, 2)).reshape(3, 3 * b)  # CasADi's map stacks inputs side by side
    out = np.asarray(f(weights.T, p_d, r_d, r_ec))
    return out.reshape(12, b, 12).transpose(1, 0, 2)


def exact_s(n_ce: np.ndarray, xi_limit: np.ndarray, k_c: np.ndarray, k_e: np.ndarray, w_e: np.ndarray,
            output_squared: np.ndarray | None = None):
    """Largest ``s = 1/(2 gamma^2)`` with ``A - s W >= 0`` (docs/math.md, facts 3 and 17), batched.

    Parameters are batches, for a task of ``t`` entries (6 for the paper's loop, 2 for the
    planar one): ``n_ce`` (B, 2t, 2t), ``xi_limit`` (B,) the ``xi`` block's largest ``s``
    (:func:`xi_limits`), ``k_c``, ``k_e`` (B, t), ``w_e`` (B, t) the diagonal of ``W_e D_v``
    (:func:`estimation_scale`), ``output_squared`` (2t,) the diagonal of ``S^2`` on
    ``(e_c, e_e)`` (None: ones). Returns ``(s, reason, A)``: ``s`` (B,) with ``-inf`` where
    ``A_cc`` is not positive definite, a :class:`Reason` per point (``CERTIFIED``, ``K_XI`` the
    ``xi`` block, ``E_C_BLOCK`` ``A_cc`` not positive definite, ``SCHUR``), and
    ``A = N^T K N - S^2/2`` on ``(e_c, e_e)`` (B, 2t, 2t).
    """
    t = n_ce.shape[1] // 2
    half = 0.5 * (np.eye(2 * t) if output_squared is None else np.diag(output_squared))
    a = nkn(n_ce, np.concatenate([k_c, k_e], axis=1)) - half
    a_cc, a_ce, a_ee = a[:, :t, :t], a[:, :t, t:], a[:, t:, t:]
    cc_min = np.linalg.eigvalsh(a_cc)[:, 0]
    ok = cc_min > 0
    s = np.full(len(a), -np.inf)
    if ok.any():
        schur = a_ee[ok] - np.einsum("bji,bjk->bik", a_ce[ok], np.linalg.solve(a_cc[ok], a_ce[ok]))
        d = 1.0 / w_e[ok]  # D^-1/2 = W_e^-1
        s[ok] = np.linalg.eigvalsh(d[:, :, None] * schur * d[:, None, :])[:, 0]
    s = np.minimum(s, xi_limit)
    reason = np.where(xi_limit <= 0, Reason.K_XI,
                      np.where(~ok, Reason.E_C_BLOCK, np.where(s <= 0, Reason.SCHUR, Reason.CERTIFIED)))  # fmt: skip
    return s, reason, a


def nkn(n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Batched ``N^T diag(k) N``."""
    return n.transpose(0, 2, 1) @ (k[:, :, None] * n)


class Reason(IntEnum):
    """Why a point is not certified: the codes of a grid's ``reason`` column (0: certified)."""

    CERTIFIED = 0
    K_XI = 1
    E_C_BLOCK = 2
    SCHUR = 3
    RECHECK = 4
    ABOVE_BOUND = 5


REASONS = {
    Reason.K_XI: "k_xi <= S_xi^2/2 (1/2 at unit weights): the xi block of P needs k_xi,i > S_xi,i^2/2",
    Reason.E_C_BLOCK: "the e_c block of N^T K N - S^2/2 is not positive definite (raise k_c or the weights W_c)",
    Reason.SCHUR: "the Schur complement of the e_c block is not positive definite: no gamma satisfies Theorem 2",
    Reason.RECHECK: "a posteriori check failed",
    Reason.ABOVE_BOUND: "gamma exceeds the required bound",
}
"""Each reason in words."""


def gamma_of(s: np.ndarray) -> np.ndarray:
    """``gamma = 1 / sqrt(2 s)`` (infinite where ``s <= 0``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(s > 0, 1.0 / np.sqrt(2.0 * np.maximum(s, 1e-300)), np.inf)


def theorem2_matrices(point: GainPoint, reference: SE3, r_ec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A = N^T K N - S^2/2`` and ``W = G D_w^2 G^T`` of Theorem 2 (docs/math.md, fact 17),
    literally, with ``N`` of size ``n + 12``."""
    n = len(point.k_xi)
    nmat = np.asarray(cs.DM(output_matrix(point.weights, reference, cs.DM(r_ec), n)))
    k = np.concatenate([point.k_xi, point.k_c, point.k_e])
    a = nmat.T @ (k[:, None] * nmat) - 0.5 * np.diag(point.output_squared)
    return (a + a.T) / 2, np.asarray(cs.DM(disturbance_weight(point.weights, n, point.plant)))


def p_min_eigenvalue(point: GainPoint, reference: SE3, r_ec: np.ndarray, gamma: float) -> float:
    """``lambda_min(P(gamma))`` of Theorem 2: the independent a posteriori check."""
    a, w = theorem2_matrices(point, reference, r_ec)
    return float(np.linalg.eigvalsh(a - w / (2 * gamma**2))[0])


def exact_gamma(point: GainPoint, reference: SE3, r_ec: np.ndarray) -> tuple[float, Reason]:
    """Smallest gamma at one rotation by the closed form, and its :class:`Reason`."""
    s, reason, _ = exact_s(
        output_blocks(point.weights.as_array()[None], reference, np.asarray(r_ec)[None]),
        np.array([point.xi_limit]),
        point.k_c[None],
        point.k_e[None],
        estimation_scale(point.weights, point.plant_weights, len(point.k_c))[None],
        point.output_squared[len(point.k_xi) :],
    )
    return float(gamma_of(s)[0]), Reason(reason[0])


SOLVERS = ("CLARABEL", "SCS")
"""Conic solvers in the order tried: Clarabel (interior point, accurate), then SCS."""


def solve(problem: cp.Problem, solver_options: dict | None = None) -> tuple[str | None, list[str]]:
    """Solve with each of :data:`SOLVERS` until one reports a clean optimum.

    Returns that solver's name (the problem then holds its solution) or None, and what
    went wrong with the others. Inexact statuses (``optimal_inaccurate``, iteration
    limits) count as failures: a certificate never rests on them.
    """
    failures = []
    for solver in SOLVERS:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                problem.solve(solver=solver, **(solver_options or {}).get(solver, {}))
        except Exception as exc:
            if interrupted(exc):  # Ctrl-C inside a solver: not a solver failure
                raise KeyboardInterrupt from exc
            failures.append(f"{solver}: {type(exc).__name__}: {exc}".splitlines()[0])
            continue
        if problem.status == "optimal":
            return solver, failures
        failures.append(f"{solver}: status {problem.status}")
    return None, failures


def sdp_gamma(point: GainPoint, reference: SE3, r_ec: np.ndarray, solver_options: dict | None = None):
    """Smallest gamma by the SDP ``maximize s s.t. A - s W >= 0`` (Clarabel, then SCS).

    Returns ``(gamma or None, method, reason or None)``: anything but a clean optimum of
    one of the solvers is "uncertified" with the solver's status as reason.
    """
    return sdp_gamma_of(*theorem2_matrices(point, reference, r_ec), solver_options)


def sdp_gamma_of(a: np.ndarray, w: np.ndarray, solver_options: dict | None = None):
    """:func:`sdp_gamma` for given ``A = N^T K N - I/2`` and ``W``."""
    import cvxpy as cp

    s = cp.Variable()
    problem = cp.Problem(cp.Maximize(s), [a - s * w >> 0])
    solver, failures = solve(problem, solver_options)
    if solver is None or s.value is None:
        return None, "sdp", "solver trouble: " + "; ".join(failures)
    if s.value <= 0:
        return None, f"sdp-{solver.lower()}", "the SDP optimum has s <= 0: no gamma satisfies Theorem 2"
    return float(1.0 / math.sqrt(2.0 * s.value)), f"sdp-{solver.lower()}", None


@dataclass
class TightCertificate:
    """Fact 4: the smallest gamma certified by a scaled storage ``alpha V``."""

    gamma: float | None
    alpha: float | None
    margin: float | None
    method: str
    reason: str | None


def tight_lmi(point: GainPoint, reference: SE3, alpha: float, gamma: float) -> np.ndarray:
    """The dissipation LMI of the storage ``alpha V`` (docs/math.md, facts 4 and 17), at
    ``R_ec = R_ee = I``::

        [[alpha N^T K N - S^2/2, -(alpha/2) G D_w], [-(alpha/2) D_w G^T, (gamma^2/2) I]] >= 0

    It gives ``d(alpha V)/dt + |z|^2/2 - gamma^2 |d|^2/2 <= 0`` (``z = S x``, ``w = D_w d``) and so
    ``int |z|^2 <= gamma^2 int |d|^2 + 2 alpha V(0)``; ``alpha = 1`` is Theorem 2's ``P``.
    """
    nkn_, g, s2 = _tight_blocks(point, reference)
    return tight_lmi_of(nkn_, g, alpha, gamma, s2)


def tight_lmi_of(a: np.ndarray, g: np.ndarray, alpha: float, gamma: float,
                 output_squared: np.ndarray | None = None) -> np.ndarray:
    """:func:`tight_lmi` for given ``N^T K N``, ``G D_w`` and diagonal of ``S^2`` (None: ones)."""  # fmt: skip
    half = 0.5 * _diagonal(output_squared, a.shape[0])
    return np.block([[alpha * a - half, -alpha / 2 * g], [-alpha / 2 * g.T, gamma**2 / 2 * np.eye(g.shape[1])]])


def _diagonal(entries: np.ndarray | None, size: int) -> np.ndarray:
    return np.eye(size) if entries is None else np.diag(entries)


def _tight_blocks(point: GainPoint, reference: SE3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``N^T K N``, ``G D_w`` and the diagonal of ``S^2`` at the identity rotations."""
    a, _ = theorem2_matrices(point, reference, np.eye(3))
    n = len(point.k_xi)
    g = np.asarray(cs.DM(disturbance_matrix(point.weights, cs.DM.eye(3), n))) * point.disturbance_weights
    return a + 0.5 * np.diag(point.output_squared), g, point.output_squared


def gamma_for_alpha(
    a: np.ndarray, g: np.ndarray, alpha: float, output_squared: np.ndarray | None = None
) -> float | None:
    """Smallest gamma of the fact-4 LMI at a fixed ``alpha`` (Schur complement):
    ``gamma^2 = (alpha^2 / 2) lambda_max(G^T (alpha A - S^2/2)^-1 G)``, None unless
    ``alpha A - S^2/2 > 0``. The solver supplies ``alpha``; gamma is then computed exactly."""
    m = alpha * a - 0.5 * _diagonal(output_squared, a.shape[0])
    if np.linalg.eigvalsh(m)[0] <= 0:
        return None
    return math.sqrt(alpha**2 / 2 * np.linalg.eigvalsh(g.T @ np.linalg.solve(m, g))[-1])


def alpha_by_search(a: np.ndarray, g: np.ndarray, output_squared: np.ndarray | None = None) -> float:
    """The ``alpha`` minimising :func:`gamma_for_alpha` without a conic solver: the LMI is jointly
    linear in ``(alpha, gamma^2)``, so ``gamma(alpha)^2`` is convex on
    ``alpha > 1/(2 lambda_min(S^-1 A S^-1))`` and a bounded scalar search on ``log alpha`` (Brent)
    finds its minimum."""
    from scipy.optimize import minimize_scalar

    s_inv = 1.0 / np.sqrt(np.ones(a.shape[0]) if output_squared is None else output_squared)
    lowest = 1.0 / (2.0 * np.linalg.eigvalsh(s_inv[:, None] * a * s_inv[None, :])[0])

    def gamma2(t: float) -> float:
        gamma = gamma_for_alpha(a, g, lowest * math.exp(t), output_squared)
        return math.inf if gamma is None else gamma**2

    found = minimize_scalar(gamma2, bounds=(1e-9, math.log(1e6)), method="bounded", options={"xatol": 1e-10})
    return lowest * math.exp(found.x)


def tight_gamma(point: GainPoint, reference: SE3, solver_options: dict | None = None) -> TightCertificate:
    """Minimise gamma^2 over ``alpha > 0`` subject to the LMI of :func:`tight_lmi` (jointly
    linear in ``alpha`` and ``gamma^2``), re-checked a posteriori like every certificate.

    The rotations drop out as for Theorem 2: the change of variables ``e_e -> Ad_{R_ec} e_e``
    and ``w -> diag(I, Ad_{R_ec} Ad_{R_ee}) w`` (orthogonal) maps the LMI at any rotation
    to the one at ``I`` for block-isotropic ``K_e``; otherwise the blockwise-minimum
    ``K_e`` gives a bound sound for every rotation (the LMI is monotone in ``K``).
    """
    sound = point.with_k_e(sound_k_e(point.k_e))
    nkn_, g, s2 = _tight_blocks(sound, reference)
    return tight_gamma_of(nkn_, g, solver_options, s2)


def tight_gamma_of(a: np.ndarray, g: np.ndarray, solver_options: dict | None = None,
                   output_squared: np.ndarray | None = None) -> TightCertificate:
    """:func:`tight_gamma` for given ``N^T K N``, ``G D_w`` and diagonal of ``S^2`` (None: ones).
    When neither solver returns a clean optimum, ``alpha`` comes from :func:`alpha_by_search`
    (the method says so): the certificate never rests on the solver, only on the exact gamma at
    ``alpha`` and its a posteriori check."""  # fmt: skip
    import cvxpy as cp

    nx, nw = g.shape
    alpha, g2 = cp.Variable(nonneg=True), cp.Variable(nonneg=True)
    half = 0.5 * _diagonal(output_squared, nx)
    lmi = cp.bmat([[alpha * a - half, -alpha / 2 * g], [-alpha / 2 * g.T, g2 / 2 * np.eye(nw)]])
    problem = cp.Problem(cp.Minimize(g2), [(lmi + lmi.T) / 2 >> 0])
    solver, failures = solve(problem, solver_options)
    if solver is None or alpha.value is None:
        # the solver only proposes alpha; gamma is computed exactly at it and re-checked below
        method = "scaled storage alpha V (fact 4), 1-D search over alpha (" + "; ".join(failures) + ")"
        a_alpha = alpha_by_search(a, g, output_squared)
    else:
        method = f"scaled storage alpha V (fact 4), {solver.lower()}"
        a_alpha = float(alpha.value)
    gamma = gamma_for_alpha(a, g, a_alpha, output_squared)
    if gamma is None:
        return TightCertificate(
            None, a_alpha, None, method, "alpha A - S^2/2 is not positive definite at the solver's alpha"
        )
    gamma *= 1 + INFLATION
    margin = float(np.linalg.eigvalsh(tight_lmi_of(a, g, a_alpha, gamma, output_squared))[0])
    if margin < 0:
        return TightCertificate(None, a_alpha, margin, method, "a posteriori check failed")
    return TightCertificate(gamma, a_alpha, margin, method, None)


def random_rotations(count: int, theta_max: float, rng: np.random.Generator) -> np.ndarray:
    """Rotations with angle at most ``theta_max``: uniform axis, angle uniform in [0, theta_max]."""
    from scipy.spatial.transform import Rotation

    axes = rng.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0.0, theta_max, size=(count, 1))
    return Rotation.from_rotvec(axes * angles).as_matrix()


def gammas_over_rotations(point: GainPoint, reference: SE3, rotations: np.ndarray) -> np.ndarray:
    """Smallest gamma of ``point`` at each rotation ``R_ec`` of a batch (B, 3, 3)."""
    b = len(rotations)
    s, _, _ = exact_s(
        output_blocks(np.tile(point.weights.as_array(), (b, 1)), reference, rotations),
        np.full(b, point.xi_limit),
        np.tile(point.k_c, (b, 1)),
        np.tile(point.k_e, (b, 1)),
        np.tile(estimation_scale(point.weights, point.plant_weights, len(point.k_c)), (b, 1)),
        point.output_squared[len(point.k_xi) :],
    )
    return gamma_of(s)


def _clip(rotvecs: np.ndarray, theta_max: float) -> np.ndarray:
    angle = np.linalg.norm(rotvecs, axis=1, keepdims=True)
    return rotvecs * np.minimum(1.0, theta_max / np.maximum(angle, 1e-300))


def worst_rotation(
    point: GainPoint, reference: SE3, theta_max: float, samples: int = 512, rounds: int = 15, seed: int = 0
) -> tuple[float, np.ndarray]:
    """The largest smallest-gamma over ``|theta_ec| <= theta_max`` found by batched random
    sampling, then batched local refinement around the best rotation with a shrinking
    radius. A lower bound on the worst case, never a certificate."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    rotvecs = np.concatenate(
        [np.zeros((1, 3)), Rotation.from_matrix(random_rotations(samples, theta_max, rng)).as_rotvec()]
    )
    values = gammas_over_rotations(point, reference, Rotation.from_rotvec(rotvecs).as_matrix())
    best = int(np.argmax(values))
    best_vec, best_value = rotvecs[best], values[best]
    radius = 0.5
    for _ in range(rounds):
        steps = rng.normal(scale=radius, size=(64, 3))
        candidates = _clip((Rotation.from_rotvec(best_vec) * Rotation.from_rotvec(steps)).as_rotvec(), theta_max)
        values = gammas_over_rotations(point, reference, Rotation.from_rotvec(candidates).as_matrix())
        i = int(np.argmax(values))
        if values[i] > best_value:
            best_vec, best_value = candidates[i], values[i]
        else:
            radius *= 0.5
    rotation = Rotation.from_rotvec(best_vec).as_matrix()
    return float(gammas_over_rotations(point, reference, rotation[None])[0]), rotation


def region_text(theta_max: float) -> str:
    if theta_max >= math.pi:
        return "every rotation R_ec in SO(3) with |theta_ec| < pi"
    return f"every rotation R_ec with |theta_ec| <= {math.degrees(theta_max):.6g} deg"


NOT_APPLICABLE = (
    "n = {n} < 6: J_b pinv(J_b) != I, so Lemma 2's cancellation fails and Theorem 2 does not apply to "
    "this arm (use the reduced planar loop, loop = \"planar\")"
)

PLANAR_REGION = (
    "every state of the reduced planar loop where J_p has full row rank (away from the arm's singularities; "
    "N is constant: no rotation enters)"
)

PLANAR_ASSUMPTIONS = (
    "planar arm in a horizontal plane, camera looking straight down, target moving without rotating "
    "in a parallel plane (dvfc.models.planar)",
    "exact estimation error e_e: from the image it is exact when every feature keeps its depth (P12)",
    "J_p of full row rank (away from the arm's singularities)",
    "feature points in front of the camera",
)


def planar_blocks(point: GainPoint) -> tuple[np.ndarray, np.ndarray]:
    """``N^T K N`` and ``G D_w`` of the reduced planar loop (P9)-(P11)."""
    w, n = point.weights, len(point.k_xi)
    nmat = planar_output_matrix(w.w_pc, w.w_pe, n)
    k = np.concatenate([point.k_xi, point.k_c, point.k_e])
    return nmat.T @ (k[:, None] * nmat), planar_disturbance_matrix(w.w_pe, n) * point.disturbance_weights


def certify_planar(
    point: GainPoint, *, gamma_bound: float | None = None, with_sdp: bool = True, solver_options: dict | None = None
) -> Certificate:
    """Theorem 2 for the reduced planar loop (P11): the same closed form (fact 3, with a task
    of 2 entries), SDP cross-check and a posteriori check as :func:`certify`."""
    w = point.weights
    s, code, _ = exact_s(
        planar_output_matrix(w.w_pc, w.w_pe, 0)[None],
        np.array([point.xi_limit]),
        point.k_c[None],
        point.k_e[None],
        estimation_scale(point.weights, point.plant_weights, len(point.k_c))[None],
        point.output_squared[len(point.k_xi) :],
    )
    result = Certificate(False, None, "exact (planar loop, fact 3)", None, None, PLANAR_REGION)
    if (reason := Reason(code[0])) is not Reason.CERTIFIED:
        result.reason = REASONS[reason]
        return result
    nkn_, g = planar_blocks(point)
    a = nkn_ - 0.5 * np.diag(point.output_squared)
    return _confirm(result, float(gamma_of(s)[0]), a, g @ g.T, gamma_bound, with_sdp, solver_options)


def tight_gamma_planar(point: GainPoint, solver_options: dict | None = None) -> TightCertificate:
    """Fact 4 for the reduced planar loop."""
    return tight_gamma_of(*planar_blocks(point), solver_options, point.output_squared)


def certify(
    point: GainPoint,
    reference: SE3,
    *,
    theta_max: float = math.pi,
    gamma_bound: float | None = None,
    with_sdp: bool = True,
    solver_options: dict | None = None,
) -> Certificate:
    """Certify Theorem 2 for one gain point over the rotations ``|theta_ec| <= theta_max``.

    ``gamma`` in the result is the smallest gamma certified over the whole region
    (inflated by :data:`INFLATION` and re-checked); certified means it exists, passes
    the re-check and, when ``gamma_bound`` is given, is at most ``gamma_bound``.
    """
    region = region_text(theta_max)
    identity = np.eye(3)
    if not spans_the_task(len(point.k_xi)):
        return Certificate(False, None, "not applicable", None, NOT_APPLICABLE.format(n=len(point.k_xi)), region)
    if point.isotropic:
        sound_point, method = point, "exact (isotropic K_e: R_ec = I decides, fact 2)"
    else:
        sound_point = point.with_k_e(sound_k_e(point.k_e))
        method = "exact (anisotropic K_e: blockwise-minimum bound, fact 5)"
    gamma_exact, code = exact_gamma(sound_point, reference, identity)
    if code is not Reason.CERTIFIED:
        return Certificate(False, None, method, None, REASONS[code], region)
    result = Certificate(False, None, method, None, None, region)
    if not point.isotropic:
        found, rotation = worst_rotation(point, reference, theta_max)
        result.gamma_worst_found = found
        result.worst_rotation = rotation.tolist()
        result.gap = gamma_exact / found - 1.0
    a, w = theorem2_matrices(sound_point, reference, identity)
    return _confirm(result, gamma_exact, a, w, gamma_bound, with_sdp, solver_options)


def _confirm(result: Certificate, gamma_exact: float, a: np.ndarray, w: np.ndarray, gamma_bound: float | None,
             with_sdp: bool, solver_options: dict | None) -> Certificate:
    """Cross-check the closed-form gamma with the SDP, inflate it, re-check ``P >= 0`` on the
    literal ``A - W/(2 gamma^2)`` and compare with the required bound."""  # fmt: skip
    if with_sdp:
        gamma_sdp, sdp_method, trouble = sdp_gamma_of(a, w, solver_options)
        if trouble is not None:
            result.reason = trouble
            result.method = f"{result.method}; {sdp_method}"
            return result
        if abs(gamma_sdp - gamma_exact) > 1e-5 * gamma_exact:
            result.reason = f"exact ({gamma_exact:.9g}) and SDP ({gamma_sdp:.9g}) disagree"
            return result
        result.method = f"{result.method}; cross-checked by {sdp_method}"
    gamma = gamma_exact * (1 + INFLATION)
    margin = float(np.linalg.eigvalsh(a - w / (2 * gamma**2))[0])
    result.margin = margin
    if margin < 0:
        result.reason = f"a posteriori check failed: lambda_min(P) = {margin:.3g} < 0"
        return result
    result.gamma = gamma
    if gamma_bound is not None and gamma > gamma_bound:
        result.reason = f"gamma = {gamma:.6g} exceeds the required bound {gamma_bound:.6g}"
        return result
    result.certified = True
    return result
