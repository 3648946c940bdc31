"""An independent reference for Theorem 2, written from the paper in NumPy only.

The certifier builds ``N`` from :mod:`dvfc.models.loop` (CasADi) and finds the smallest gamma by
a Schur complement (docs/math.md, fact 3). The tests judge it against this module, which shares
none of that code: the matrices are rebuilt from the paper's text and the smallest gamma
is found by a different route (bisection on the smallest eigenvalue of the whole ``P``).

- ``Ad_g = [[R, hat(p) R], [0, R]]`` (Murray, Li, Sastry), ``g^-1 = (-R^T p, R^T)``.
- Lemma 2: ``N = [[I, 0, 0], [0, -Ad_{g_d^-1}^T W_c, 0], [0, Ad_{exp(-xi theta_ec)} W_c, -W_e]]``
  with ``Ad`` of a pure rotation ``diag(R, R)``.
- (39): ``dV/dt = u^T nu + x^T G w``, ``G = [[I, 0], [0, 0], [0, W_e diag(R_ee, R_ee)]]``, so
  ``W = G G^T = diag(I, 0, W_e^2)`` (Theorem 2).
- Theorem 2: ``P(gamma) = N^T K N - W / (2 gamma^2) - I/2``.
- docs/math.md, fact 17 (the generalized plant ``z = S x``, ``w = D_w d``): ``P = N^T K N -
  G D_w^2 G^T / (2 gamma^2) - S^2/2``, with ``G`` built literally at a rotation ``R_ee``.
- docs/math.md, fact 4: ``[[alpha N^T K N - I/2, -(alpha/2) G], [-(alpha/2) G^T, (gamma^2/2) I]] >= 0``
  (``S^2/2`` and ``G D_w`` with weights).
- (P9)-(P11): the planar loop's ``N = [[I, 0, 0], [0, -w_c I2, 0], [0, w_c I2, -w_e I2]]``.

Smallest gamma. With ``A = N^T K N - I/2`` and ``s = 1/(2 gamma^2)``, ``f(s) = lambda_min(A - s W)``
is non-increasing in ``s`` (``W >= 0``), so the certifiable ``s`` form an interval ``(-inf, s*]``
and ``s*`` is found by bisection on the sign of ``f`` (a finite gamma exists iff
``f(0) = lambda_min(A) > 0``). Accuracy: 60 halvings of a bracket of width at most 2^k leave
``2^-55`` relative; the sign of ``f`` is decided to ``eigvalsh``'s backward error
``~ m eps ||A||``, so ``s*`` is accurate to ``m eps ||A|| / (v^T W v)`` (``v`` the null vector):
about 1e-11 relative for the gains the tests draw, far below the 1e-6 inflation the certifier
applies and the 1e-5 minimality step the tests check.
"""

from __future__ import annotations

import numpy as np

BISECTIONS = 60


def hat(v: np.ndarray) -> np.ndarray:
    """``hat(v) w = v x w``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation(rotvec: np.ndarray) -> np.ndarray:
    """``exp(hat(r))`` by Rodrigues' formula, batched over the leading axes of ``rotvec`` (..., 3)."""
    r = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    k = np.zeros((*r.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -r[..., 2], r[..., 1], -r[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def adjoint(p: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``Ad_g`` of ``g = (p, R)``."""
    return np.block([[r, hat(p) @ r], [np.zeros((3, 3)), r]])


def weight_matrices(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``W_c = diag(w_pc I3, w_rc I3)``, ``W_e = diag(w_pe I3, w_re I3)`` from ``(w_pc, w_rc, w_pe, w_re)``."""
    w_pc, w_rc, w_pe, w_re = w
    return np.diag([w_pc] * 3 + [w_rc] * 3), np.diag([w_pe] * 3 + [w_re] * 3)


def output_matrix(w: np.ndarray, p_d: np.ndarray, r_d: np.ndarray, r_ec: np.ndarray, n: int) -> np.ndarray:
    """``N`` of Lemma 2 at the control-error rotation ``R_ec`` (batched over ``r_ec`` (..., 3, 3))."""
    w_c, w_e = weight_matrices(w)
    ad_d_inverse = adjoint(-r_d.T @ p_d, r_d.T)
    r_ec = np.asarray(r_ec)
    batch = r_ec.shape[:-2]
    out = np.zeros((*batch, n + 12, n + 12))
    out[..., :n, :n] = np.eye(n)
    out[..., n : n + 6, n : n + 6] = -ad_d_inverse.T @ w_c
    ad_ec_t = np.zeros((*batch, 6, 6))  # Ad_{exp(-xi theta_ec)} = diag(R_ec^T, R_ec^T)
    ad_ec_t[..., :3, :3] = ad_ec_t[..., 3:, 3:] = np.swapaxes(r_ec, -1, -2)
    out[..., n + 6 :, n : n + 6] = ad_ec_t @ w_c
    out[..., n + 6 :, n + 6 :] = -w_e
    return out


def disturbance_matrix(w: np.ndarray, r_ee: np.ndarray, n: int) -> np.ndarray:
    """``G`` of (39): ``[[I, 0], [0, 0], [0, W_e diag(R_ee, R_ee)]]``."""
    _, w_e = weight_matrices(w)
    g = np.zeros((n + 12, n + 6))
    g[:n, :n] = np.eye(n)
    g[n + 6 :, n:] = w_e @ np.kron(np.eye(2), r_ee)
    return g


def disturbance_weight(w: np.ndarray, n: int) -> np.ndarray:
    """``W = diag(I_n, 0_6, W_e^2)`` of Theorem 2."""
    _, w_e = weight_matrices(w)
    return np.diag(np.r_[np.ones(n), np.zeros(6), np.diag(w_e) ** 2])


def nkn(n_matrix: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``N^T diag(k) N`` (batched over leading axes of ``n_matrix``)."""
    return np.swapaxes(n_matrix, -1, -2) @ (np.asarray(k)[:, None] * n_matrix)


def p_matrix(a: np.ndarray, w: np.ndarray, gamma: float) -> np.ndarray:
    """Theorem 2's ``P = A - W / (2 gamma^2)`` for ``A = N^T K N - I/2``."""
    return a - w / (2.0 * gamma**2)


def lambda_min(m: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of the symmetric part (batched)."""
    return np.linalg.eigvalsh((m + np.swapaxes(m, -1, -2)) / 2)[..., 0]


def round_off(m: np.ndarray) -> float:
    """Backward error of ``eigvalsh`` on a symmetric ``m`` of size up to ~24, with room for a
    congruence by a rotation: ``64 eps ||m||_F`` (``size * eps * ||m||`` with a factor 3)."""
    return 64 * np.finfo(float).eps * float(np.linalg.norm(m))


def largest_s(a: np.ndarray, w: np.ndarray, bisections: int = BISECTIONS) -> np.ndarray:
    """``s* = sup {s : A - s W >= 0}`` by bisection (batched over ``a`` (..., m, m)); ``-inf``
    where ``lambda_min(A) <= 0`` (no positive ``s``)."""
    a = np.asarray(a, dtype=float)
    feasible = lambda_min(a) > 0
    lo = np.zeros(a.shape[:-2])
    hi = np.ones(a.shape[:-2])
    for _ in range(200):  # bracket: double hi until A - hi W fails (W has a positive block)
        grow = feasible & (lambda_min(a - hi[..., None, None] * w) >= 0)
        if not grow.any():
            break
        lo, hi = np.where(grow, hi, lo), np.where(grow, 2 * hi, hi)
    for _ in range(bisections):
        mid = (lo + hi) / 2
        ok = lambda_min(a - mid[..., None, None] * w) >= 0
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return np.where(feasible, lo, -np.inf)


def gamma_of_s(s: np.ndarray) -> np.ndarray:
    """``gamma = 1 / sqrt(2 s)``, ``inf`` where ``s <= 0``."""
    s = np.asarray(s, dtype=float)
    return np.where(s > 0, 1.0 / np.sqrt(2.0 * np.where(s > 0, s, 1.0)), np.inf)


class Design:
    """One design of the paper's loop, in plain arrays: gains ``k_xi`` (n), ``k_c``, ``k_e`` (6),
    weights ``w = (w_pc, w_rc, w_pe, w_re)``, desired pose ``g_d = (p_d, R_d)``, and the
    generalized plant's diagonals ``s`` of ``S`` (n + 12) and ``dw`` of ``D_w`` (n + 6), ones by
    default; ``r_ee`` the rotation ``G`` is built at (``W`` must not depend on it)."""

    def __init__(self, k_xi, k_c, k_e, w, p_d, r_d, s=None, dw=None, r_ee=None) -> None:
        self.k_xi, self.k_c, self.k_e = (np.asarray(v, dtype=float) for v in (k_xi, k_c, k_e))
        self.w, self.p_d, self.r_d = np.asarray(w, dtype=float), np.asarray(p_d, float), np.asarray(r_d, float)
        self.n = len(self.k_xi)
        self.s = np.ones(self.n + 12) if s is None else np.asarray(s, dtype=float)
        self.dw = np.ones(self.n + 6) if dw is None else np.asarray(dw, dtype=float)
        self.r_ee = np.eye(3) if r_ee is None else np.asarray(r_ee, dtype=float)

    @property
    def k(self) -> np.ndarray:
        return np.r_[self.k_xi, self.k_c, self.k_e]

    def blockwise_minimum(self) -> Design:
        """The design with ``K_e`` replaced by its blockwise minima (docs/math.md, fact 5)."""
        k_e = np.repeat([self.k_e[:3].min(), self.k_e[3:].min()], 3)
        return Design(self.k_xi, self.k_c, k_e, self.w, self.p_d, self.r_d, self.s, self.dw, self.r_ee)

    def a(self, r_ec: np.ndarray) -> np.ndarray:
        """``A = N^T K N - S^2/2`` at ``R_ec`` (batched)."""
        return nkn(output_matrix(self.w, self.p_d, self.r_d, r_ec, self.n), self.k) - 0.5 * np.diag(self.s**2)

    @property
    def weighted_g(self) -> np.ndarray:
        """``G D_w`` at ``R_ee``."""
        return disturbance_matrix(self.w, self.r_ee, self.n) * self.dw

    @property
    def weight(self) -> np.ndarray:
        """``W = G D_w^2 G^T`` at ``R_ee`` (``diag(I, 0, W_e^2)`` at unit weights)."""
        g = self.weighted_g
        return g @ g.T

    def p_min(self, gamma: float, r_ec: np.ndarray) -> np.ndarray:
        """``lambda_min(P(gamma))`` at ``R_ec`` (batched)."""
        return lambda_min(p_matrix(self.a(r_ec), self.weight, gamma))

    def gamma(self, r_ec: np.ndarray, bisections: int = BISECTIONS) -> np.ndarray:
        """Smallest gamma with ``P(gamma) >= 0`` at ``R_ec`` (batched; ``inf`` if none)."""
        return gamma_of_s(largest_s(self.a(r_ec), self.weight, bisections))

    def tight_lmi(self, alpha: float, gamma: float, r_ec: np.ndarray, r_ee: np.ndarray) -> np.ndarray:
        """The fact-4 LMI of the storage ``alpha V`` at ``(R_ec, R_ee)``."""
        a = nkn(output_matrix(self.w, self.p_d, self.r_d, r_ec, self.n), self.k)
        g = disturbance_matrix(self.w, r_ee, self.n) * self.dw
        return tight_lmi(a, g, alpha, gamma, self.s**2)

    def tight_gamma(self, r_ec: np.ndarray) -> tuple[float, float]:
        """Smallest fact-4 gamma over ``alpha > 0`` at ``R_ec`` (``R_ee`` drops out of ``G G^T``)."""
        a = nkn(output_matrix(self.w, self.p_d, self.r_d, r_ec, self.n), self.k)
        return smallest_tight_gamma(a, self.weight, self.s**2)


def tight_lmi(a: np.ndarray, g: np.ndarray, alpha: float, gamma: float, s2: np.ndarray | None = None) -> np.ndarray:
    """``[[alpha A - S^2/2, -(alpha/2) G], [-(alpha/2) G^T, (gamma^2/2) I]]`` with ``A = N^T K N``
    (``S = I`` when ``s2``, the diagonal of ``S^2``, is None)."""
    m, k = g.shape
    half = 0.5 * (np.eye(m) if s2 is None else np.diag(s2))
    return np.block([[alpha * a - half, -alpha / 2 * g], [-alpha / 2 * g.T, gamma**2 / 2 * np.eye(k)]])


def smallest_tight_gamma(a: np.ndarray, w: np.ndarray, s2: np.ndarray | None = None) -> tuple[float, float]:
    """``min over alpha`` of the fact-4 gamma, and its ``alpha``.

    By the Schur complement on the ``(gamma^2/2) I`` block, the LMI at ``alpha`` holds iff
    ``alpha A - S^2/2 - alpha^2 W / (2 gamma^2) >= 0``: with ``s*(alpha)`` the largest ``s`` such
    that ``alpha A - S^2/2 - s W >= 0`` (bisection), ``gamma(alpha)^2 = alpha^2 / (2 s*(alpha))``.
    The LMI is jointly linear in ``(alpha, gamma^2)``, so ``gamma(alpha)^2`` is convex on the
    interval where it is finite: a dense log grid then golden-section search on it.
    """
    eye = np.eye(len(a)) if s2 is None else np.diag(s2)
    root = 1.0 / np.sqrt(np.diag(eye))
    lowest = 1.0 / (2.0 * np.linalg.eigvalsh(root[:, None] * a * root[None, :])[0])  # alpha A - S^2/2 > 0 beyond

    def gamma2(alphas: np.ndarray) -> np.ndarray:
        s = largest_s(alphas[:, None, None] * a - 0.5 * eye, w)
        return np.where(s > 0, alphas**2 / (2 * np.where(s > 0, s, 1.0)), np.inf)

    grid = lowest * np.geomspace(1 + 1e-9, 1e4, 200)
    values = gamma2(grid)
    i = int(np.argmin(values))
    lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
    ratio = (np.sqrt(5) - 1) / 2
    for _ in range(50):  # 0.618^50 ~ 4e-11 of the bracket
        c, d = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        fc, fd = gamma2(np.exp([c, d]))
        lo, hi = (lo, d) if fc <= fd else (c, hi)
    alpha = float(np.exp((lo + hi) / 2))
    return float(np.sqrt(gamma2(np.array([alpha]))[0])), alpha


def planar_output_matrix(w_c: float, w_e: float, n: int) -> np.ndarray:
    """``N`` of (P9)."""
    out = np.zeros((n + 4, n + 4))
    out[:n, :n] = np.eye(n)
    out[n : n + 2, n : n + 2] = -w_c * np.eye(2)
    out[n + 2 :, n : n + 2] = w_c * np.eye(2)
    out[n + 2 :, n + 2 :] = -w_e * np.eye(2)
    return out


def planar_matrices(k_xi, k_c, k_e, w_c: float, w_e: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A = N^T K N - I/2``, ``W = diag(I_n, 0_2, w_e^2 I_2)`` and ``G`` of (P9)-(P11)."""
    n = len(k_xi)
    a = nkn(planar_output_matrix(w_c, w_e, n), np.r_[k_xi, k_c, k_e]) - 0.5 * np.eye(n + 4)
    g = np.zeros((n + 4, n + 2))
    g[:n, :n] = np.eye(n)
    g[n + 2 :, n:] = w_e * np.eye(2)
    return a, g @ g.T, g


def random_rotations(count: int, theta_max: float, rng: np.random.Generator) -> np.ndarray:
    """Rotations with angle at most ``theta_max``: for ``theta_max >= pi`` uniform (Haar) from
    normalised Gaussian quaternions; otherwise a uniform axis and an angle uniform in
    ``[0, theta_max]``."""
    if theta_max >= np.pi:
        q = rng.normal(size=(count, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        angle = 2 * np.arccos(np.clip(np.abs(q[:, :1]), 0, 1))
        axis = q[:, 1:] / np.maximum(np.linalg.norm(q[:, 1:], axis=1, keepdims=True), 1e-300)
        return rotation(axis * angle)
    axis = rng.normal(size=(count, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return rotation(axis * rng.uniform(0, theta_max, (count, 1)))


def rotation_angle(r: np.ndarray) -> np.ndarray:
    """``|theta|`` of rotations (batched), from ``tr R = 1 + 2 cos(theta)``."""
    return np.arccos(np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1))


def worst_rotation(design: Design, theta_max: float, seed: int = 0, samples: int = 256,
                   rounds: int = 15) -> tuple[float, np.ndarray]:
    """The largest smallest-gamma over ``|theta_ec| <= theta_max`` that a search finds: uniform
    samples, then a population of the eight best perturbed by left-multiplied random small
    rotations whose spread halves whenever no member improves. A lower bound on the worst case.
    The search ranks with 24 bisections (``s*`` to ``2^-24`` of its bracket); the value returned
    is recomputed with the full :data:`BISECTIONS`."""  # fmt: skip
    rng = np.random.default_rng(seed)
    r = np.concatenate([np.eye(3)[None], random_rotations(samples, theta_max, rng)])
    g = design.gamma(r, 24)
    order = np.argsort(g)[::-1][:8]
    pop, values = r[order], g[order]
    spread = 0.3
    for _ in range(rounds):
        steps = rotation(rng.normal(scale=spread, size=(len(pop), 8, 3)))
        cand = (steps @ pop[:, None]).reshape(-1, 3, 3)
        cand = cand[rotation_angle(cand) <= theta_max]
        if len(cand) == 0:
            spread /= 2
            continue
        cg = design.gamma(cand, 24)
        merged_r, merged_g = np.concatenate([pop, cand]), np.concatenate([values, cg])
        order = np.argsort(merged_g)[::-1][: len(pop)]
        if merged_g[order[0]] <= values[0]:
            spread /= 2
        pop, values = merged_r[order], merged_g[order]
    return float(design.gamma(pop[0])), pop[0]
