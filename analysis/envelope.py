"""The certified operating envelope of one design (docs/math.md, facts 7-9; the rate of fact 10).

The L2 gain of Theorem 2 says nothing uniform in time about a target that keeps moving
(its energy is infinite). This module answers the review's questions instead, from the
same storage ``V`` (38):

- Rate (fact 7 with docs/math.md, fact 10; the ideal continuous loop). With
  ``s = 1/(2 gamma'^2)``, ``Q(s) = N^T K N - s W`` and ``V <= x^T D x`` while
  ``|theta_ec|, |theta_ee| <= theta_bar``, ``D = diag(D_M/2, D_ce)``,
  ``D_ce = diag(w_pc/2 I3, w_rc/(1+cos theta_bar) I3, w_pe/2 I3, w_re/(1+cos theta_bar) I3)`` and
  ``D_M = diag(B v / v) >= M(q)`` for every ``q`` (``B`` the entrywise bound of
  :mod:`dvfc.models.inertia`), ``kappa = lambda_min(D^-1/2 Q D^-1/2)`` gives
  ``dV/dt <= -kappa V + |w|^2 / (4 s)``. The ``xi`` block decouples; with ``v`` the Perron vector of
  ``diag(k_xi - s)^-1 B`` (the best ``v``, Collatz-Wielandt) it gives
  ``kappa = min(2 / rho(diag(k_xi - s)^-1 B), lambda_min(D_ce^-1/2 Q_ce D_ce^-1/2))`` (10.4),
  still concave in ``s``. ``Q`` is taken at ``R_ec = I``:
  exact for block-isotropic ``K_e`` (``D`` is block-isotropic, so fact 2's congruence
  leaves it alone), and with the blockwise-minimum gains ``K_min`` otherwise (fact 5:
  ``Q`` grows with ``K_e``), sound for every ``R_ec``.
- Ultimate bound. ``V(t) <= exp(-kappa t) V(0) + c_inf``, ``c_inf = wbar^2 / (4 s kappa)``,
  ``wbar^2 = torque^2 + speed^2 + rate^2 >= |w|^2``; ``s`` maximises ``s kappa(s)`` (a
  concave function times ``s``: ``log`` of it is concave, so a golden-section search finds it).
- Self-consistency (first exit). ``{V <= c}`` keeps ``theta <= theta_bar`` when
  ``c <= c_max = min(w_rc, w_re) (1 - cos theta_bar)``. If ``c_inf <= c`` and ``V(0) <= c``,
  ``V(t) <= c`` for all ``t >= 0``. ``theta_bar`` (unless given) is the one, on a 1-degree
  grid, with the smallest ``c_inf`` that is self-consistent and, when possible, covers the
  start (``V(0) <= c_max``).
- Error bounds from ``V <= c``: ``|p_ec| <= sqrt(2c/w_pc)``, ``theta_ec <= arccos(1 - c/w_rc)``,
  the same for ``e_e``, ``|xi| <= sqrt(2c/m_lo)`` (``m_lo I <= M(q)``, the lower bound of fact 10).
- Visibility (fact 8 with the regions of docs/math.md, fact 16.0). ``p_ci - g_d p_oi =
  R_d [(R_ec R_ee - I) p_oi + R_ec p_ee + p_ec]`` has length at most the joint radius
  ``rho_i = sqrt(2 c S_i)``, ``S_i = 1/w_pc + 1/w_pe + |p_oi|^2 (1/w_rc + 1/w_re)``, on ``{V <= c}``;
  each feature lies in the image box ``lambda [tan(phi - beta), tan(phi + beta)]`` per image axis
  (``phi = atan2(x_i, z_i)``, ``beta = asin(rho_i / sqrt(x_i^2 + z_i^2))``, the same with ``y_i``),
  the exact range of the ball ``B(g_d p_oi, rho_i)``, when ``z_i - rho_i > 0``.
- The largest certified target speed and torque: ``c_inf`` grows as ``wbar^2`` and the
  boxes grow with the level, so the largest ``wbar^2`` keeping the statement is
  ``max over theta_bar of min(c_max, c_vis) / rho(theta_bar)`` (``c_vis`` the largest level
  whose boxes fit, by bisection); the answer is re-checked by recomputing the envelope there.

Every rate is re-checked a posteriori: the reported ``kappa`` is the computed one shrunk by
:data:`SHRINK`, certified only when ``lambda_min(Q - kappa D) >= 0`` on the literal ``Q``
and ``D`` (with ``D_M`` built from the Perron vector) of size ``n + 12``.

Where this stops (fact 9): the ideal loop (exact ``e_e``); ``J_b`` and ``J(gbar)`` away from
singular (not implied by ``V <= c``); the inertia bounds over every configuration, for a chain
of revolute joints with unit axes and positive semidefinite link inertias (others are refused
by :mod:`dvfc.models.inertia`); ``|theta| < pi``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import casadi as cs
import numpy as np

from dvfc.analysis.certify import GainPoint, sound_k_e, theorem2_matrices
from dvfc.analysis.record import Record
from dvfc.models.camera import Camera
from dvfc.models.disturbance import torque_bound
from dvfc.models.inertia import MassBounds
from dvfc.models.lie import SE3
from dvfc.models.planar import planar_output_matrix

SHRINK = 1e-6
"""Relative shrink of a computed rate before the a posteriori check ``Q - kappa D >= 0``: at
the computed ``kappa`` that matrix is singular; shrunk, its smallest eigenvalue is positive
by far more than the eigenvalue solver's error (~1e-14 ||Q||)."""

PERRON_FLOOR = 1e-12
"""Smallest entry of the Perron vector, relative to its largest, used for ``D_M(v)`` (only a
reducible inertia bound ``B`` has smaller ones: ``D_M(v)`` is a bound for every ``v > 0``)."""

THETA_GRID = np.radians(np.arange(1.0, 180.0, 1.0))
"""Candidates for ``theta_bar`` when the scenario does not fix it (1-degree steps)."""

GOLDEN_STEPS = 24
"""Golden-section steps over ``[s_lim/2, s_lim]``: the bracket shrinks to ~1e-5 of ``s_lim``;
``s kappa(s)`` is flat at its maximum, so ``c_inf`` is then within ~1e-10 of its minimum (the
optimum only affects tightness, never soundness)."""

ASSUMPTIONS = (
    "ideal loop: the law uses the exact estimation error e_e (the image estimate (21) is first order)",
    "J_b of full row rank and J(gbar) of full column rank along the run (not implied by V <= c)",
    "m_lo I <= M(q) <= D_M for every configuration (docs/math.md, fact 10: from the URDF, revolute joints with "
    "unit axes and positive semidefinite link inertias)",
    "target speed, target rate and joint-torque disturbance within the stated bounds at all times",
)

PLANAR_ASSUMPTIONS = (
    "the reduced planar loop (dvfc.models.planar): horizontal motion, camera looking straight down, "
    "target not rotating, every feature at a constant depth",
    "J_p of full row rank along the run (not implied by V <= c)",
    "m_lo I <= M(q) <= D_M for every configuration (docs/math.md, fact 10: from the URDF, revolute joints with "
    "unit axes and positive semidefinite link inertias)",
    "target speed and joint-torque disturbance within the stated bounds at all times",
)


@dataclass(frozen=True)
class DisturbanceBounds:
    """Bounds on the disturbance ``w = [tau_d; V_wo]`` and how each was obtained."""

    target_speed: float
    target_rate: float
    torque: float
    derivation: dict[str, str] = field(default_factory=dict)

    @property
    def wbar(self) -> float:
        """``wbar >= sup |w|``: ``|w|^2 = |tau_d|^2 + |v_wo|^2 + |w_wo|^2``."""
        return math.sqrt(self.torque**2 + self.target_speed**2 + self.target_rate**2)


@dataclass(frozen=True)
class Design:
    """What the envelope of one design needs: ``N^T K N`` on ``(e_c, e_e)`` (at ``R_ec = I``,
    with ``K_min`` for anisotropic ``K_e``), the diagonal of ``W`` there, ``k_xi``, the
    mass bounds and the weights; ``rotational`` is False for the planar loop."""

    nkn: np.ndarray
    w: np.ndarray
    k_xi: np.ndarray
    mass: MassBounds
    weights: tuple[float, float, float, float]  # w_pc, w_rc, w_pe, w_re (w_rc, w_re unused when planar)
    rotational: bool
    point: GainPoint
    reference: SE3 | None
    full: tuple[np.ndarray, np.ndarray]
    """``N^T K N`` of size ``n + 2t`` and the diagonal of ``W``, literally (for the a posteriori check)."""

    @property
    def task(self) -> int:
        return self.nkn.shape[0] // 2

    @property
    def k_xi_min(self) -> float:
        """The smallest ``k_xi``: the ``xi`` block has a positive rate only for ``s < k_xi_min``."""
        return float(self.k_xi.min())

    def d_diagonal(self, theta_bar: np.ndarray) -> np.ndarray:
        """``D_ce``, ``D`` on ``(e_c, e_e)``, for each ``theta_bar`` (B,): (B, 2t)."""
        return pose_diagonal(np.asarray(self.weights), theta_bar, self.rotational, self.task)

    def c_max(self, theta_bar: np.ndarray) -> np.ndarray:
        """Largest self-consistent level (:func:`self_consistent_level`; infinite for the planar
        loop: no rotation to keep below pi)."""
        if not self.rotational:
            return np.full(np.shape(theta_bar), np.inf)
        return self_consistent_level(np.asarray(self.weights), theta_bar)


def pose_diagonal(weights: np.ndarray, theta_bar: np.ndarray | float, rotational: bool, task: int) -> np.ndarray:
    """The pose part ``D_ce`` of fact 7's ``D`` (``V <= x^T D x`` while ``|theta| <= theta_bar``):
    ``diag(w_pc/2 I3, w_rc/(1+cos theta_bar) I3, w_pe/2 I3, w_re/(1+cos theta_bar) I3)``, or
    ``diag(w_pc/2 I_t, w_pe/2 I_t)`` for the planar loop (P13; ``task`` = ``t``). ``weights``
    (4,) or (B, 4) as ``w_pc, w_rc, w_pe, w_re``; ``theta_bar`` scalar or (B,). Returns (B, 2 task)."""
    theta = np.atleast_1d(np.asarray(theta_bar, dtype=float))
    w = np.atleast_2d(weights)
    rows = max(len(theta), len(w))
    if not rotational:
        return np.broadcast_to(np.repeat(w[:, [0, 2]] / 2, task, axis=1), (rows, 2 * task)).copy()
    rot = 1.0 / (1.0 + np.cos(theta))
    half = np.full_like(rot, 0.5)
    return np.repeat(w * np.stack([half, rot, half, rot], axis=1), task // 2, axis=1)


def self_consistent_level(weights: np.ndarray, theta_bar: np.ndarray | float) -> np.ndarray:
    """The largest level ``c`` whose set ``{V <= c}`` keeps both rotation errors within
    ``theta_bar`` (``w_r phi(R) <= V``, ``phi = 1 - cos theta``): ``min(w_rc, w_re) (1 - cos theta_bar)``,
    the smaller weight (the rotation it weighs the less can turn the further). ``weights`` (4,)
    or (B, 4)."""
    return np.minimum(weights[..., 1], weights[..., 3]) * (1.0 - np.cos(theta_bar))


def _xi_scale(k_xi: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(K_xi - s)^-1/2`` (S, n) for ``k_xi`` (n,) or (S, n) and ``s`` (S,), and where it exists
    (``s < min k_xi``; elsewhere the scale is that of ``K_xi - s`` replaced by ``I``)."""
    slack = np.asarray(k_xi, dtype=float) - np.asarray(s, dtype=float)[:, None]
    ok = np.all(slack > 0, axis=1)
    return 1.0 / np.sqrt(np.where(ok[:, None], slack, 1.0)), ok


def xi_rates(mass: MassBounds, k_xi: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The ``xi``-block rate ``2 / rho(diag(k_xi - s)^-1 B)`` of (10.4) (docs/math.md, fact 10),
    ``rho`` the spectral radius, computed as ``lambda_max`` of the symmetric
    ``(K_xi - s)^-1/2 B (K_xi - s)^-1/2``; 0 where ``s >= min k_xi`` (no positive rate). Batched:
    ``k_xi`` (n,) or (S, n), ``s`` (S,)."""
    scale, ok = _xi_scale(k_xi, s)
    rho = np.linalg.eigvalsh(scale[:, :, None] * mass.upper * scale[:, None, :])[:, -1]
    return np.where(ok, 2.0 / rho, 0.0)


def kinetic_diagonal(mass: MassBounds, k_xi: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``D_M(v) = diag(B v / v) >= M(q)`` (10.2) at the Perron vector ``v`` of
    ``diag(k_xi - s)^-1 B``, ``v = (K_xi - s)^-1/2 u`` with ``u`` the top eigenvector of
    ``(K_xi - s)^-1/2 B (K_xi - s)^-1/2``: then ``D_M = rho (K_xi - s)`` and the ``xi`` rate is
    :func:`xi_rates`. Batched as :func:`xi_rates`, for ``s < min k_xi``: (S, n). A reducible ``B``
    (say diagonal) has a Perron vector with zeros: they are raised to :data:`PERRON_FLOOR` of its
    largest entry (every ``v > 0`` gives a bound; the a posteriori check decides the rate)."""
    scale, _ = _xi_scale(k_xi, s)
    top = np.abs(np.linalg.eigh(scale[:, :, None] * mass.upper * scale[:, None, :])[1][:, :, -1])
    return mass.upper_diagonal(scale * np.maximum(top, PERRON_FLOOR * top.max(axis=1, keepdims=True)))


def storage_diagonal(design: Design, s: float, theta_bar: float) -> np.ndarray:
    """The diagonal of ``D = diag(D_M/2, D_ce)`` (``V <= x^T D x`` while ``|theta| <= theta_bar``),
    ``D_M`` at the Perron vector for ``s`` (:func:`kinetic_diagonal`): (n + 2t,)."""
    d_m = kinetic_diagonal(design.mass, design.k_xi, np.array([s]))[0]
    return np.concatenate([d_m / 2, design.d_diagonal(np.array([theta_bar]))[0]])


def rate_margin(nkn: np.ndarray, w: np.ndarray, d: np.ndarray, s: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """The a posteriori check of a rate: ``lambda_min(N^T K N - s W - kappa D)`` with ``W``, ``D``
    diagonal; batched: ``nkn`` (B, m, m), ``w``, ``d`` (B, m), ``s``, ``kappa`` (B,)."""
    eye = np.eye(nkn.shape[1])
    return np.linalg.eigvalsh(nkn - s[:, None, None] * (w[:, :, None] * eye)
                              - kappa[:, None, None] * (d[:, :, None] * eye))[:, 0]  # fmt: skip


def design_of(point: GainPoint, reference: SE3 | None, mass: MassBounds) -> Design:
    """The :class:`Design` of a gain point: the paper's loop when ``reference`` is given, the
    reduced planar loop (P9), with ``N`` constant and ``D`` of (P13), when it is None. The envelope
    bounds ``V`` by the disturbance ``w`` itself: the generalized plant's weights (fact 17) do not
    enter it."""
    point = replace(point, plant=None)
    w, n = point.weights, len(point.k_xi)
    if reference is None:
        nmat = planar_output_matrix(w.w_pc, w.w_pe, n)
        k = np.concatenate([point.k_xi, point.k_c, point.k_e])
        nkn = nmat.T @ (k[:, None] * nmat)
        wdiag = np.concatenate([np.ones(n), np.zeros(len(point.k_c)), np.full(len(point.k_e), w.w_pe**2)])
        sound, weights, rotational = point, (w.w_pc, 0.0, w.w_pe, 0.0), False
    else:
        sound = point.with_k_e(sound_k_e(point.k_e))
        a, wmat = theorem2_matrices(sound, reference, np.eye(3))
        nkn, wdiag = a + 0.5 * np.eye(len(a)), np.diag(wmat).copy()
        weights, rotational = tuple(w.as_array()), True
    return Design(nkn[n:, n:], wdiag[n:], np.asarray(point.k_xi, dtype=float), mass, weights, rotational, sound,
                  reference, (nkn, wdiag))  # fmt: skip


def rates(design: Design, s: np.ndarray, theta_bar: np.ndarray) -> np.ndarray:
    """``kappa(s, theta_bar) = min(2 / rho(diag(k_xi - s)^-1 B), lambda_min(D_ce^-1/2 Q_ce(s) D_ce^-1/2))``
    (10.4, docs/math.md, fact 10) for batches ``s``, ``theta_bar`` (B,)."""
    return _rates(design, _scaled(design, theta_bar), np.atleast_1d(s))


def _scaled(design: Design, theta_bar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``D^-1/2 N^T K N D^-1/2`` and the diagonal of ``D^-1/2 W D^-1/2`` per ``theta_bar``."""
    inv = 1.0 / np.sqrt(design.d_diagonal(theta_bar))
    return inv[:, :, None] * design.nkn[None] * inv[:, None, :], design.w[None] * inv**2


def _rates(design: Design, scaled: tuple[np.ndarray, np.ndarray], s: np.ndarray) -> np.ndarray:
    a, w = scaled
    ce = np.linalg.eigvalsh(a - s[:, None, None] * (w[:, :, None] * np.eye(a.shape[1])))[:, 0]
    return np.minimum(xi_rates(design.mass, design.k_xi, s), ce)


def s_limit(design: Design) -> float:
    """The largest ``s`` with ``Q(s) > 0``: ``min(k_xi_min, 1 / lambda_max(W^1/2 (N^T K N)^-1 W^1/2))``."""
    root = np.sqrt(design.w)
    inverse = np.linalg.inv(design.nkn)
    return float(min(design.k_xi_min, 1.0 / np.linalg.eigvalsh(root[:, None] * inverse * root[None, :])[-1]))


def best_s(design: Design, theta_bar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each ``theta_bar``: the ``s`` maximising ``s kappa(s)`` (smallest ``c_inf``), by a
    batched golden-section search; returns ``(s, kappa)``.

    ``kappa`` is concave in ``s`` (a smallest eigenvalue of a matrix affine in ``s``, and an
    affine function) and vanishes at ``s_lim`` (:func:`s_limit`), so ``log(s kappa)`` is
    concave (one maximum; the ``xi`` rate of fact 10, ``1/rho`` a minimum of functions affine in
    ``s``, is concave too) and, by the tangent inequality ``-kappa'/kappa <= 1/(s_lim - s)``,
    increasing below ``s_lim / 2``: the maximum lies in ``[s_lim/2, s_lim]``.
    """
    theta_bar = np.atleast_1d(theta_bar)
    top = s_limit(design)
    scaled = _scaled(design, theta_bar)
    s = golden_max(lambda x: x * _rates(design, scaled, x), np.full(len(theta_bar), top), GOLDEN_STEPS)
    return s, _rates(design, scaled, s)


def golden_max(value: Callable[[np.ndarray], np.ndarray], top: np.ndarray, steps: int) -> np.ndarray:
    """Batched golden-section search for the maximiser of ``value`` (elementwise, log-concave)
    on ``[top/2, top]`` (where the maximum of ``s kappa(s)`` lies, :func:`best_s`): the bracket
    shrinks by 0.618 per step; returns its midpoint (B,)."""
    ratio = (math.sqrt(5) - 1) / 2
    lo, hi = np.asarray(top, dtype=float) / 2, np.asarray(top, dtype=float).copy()
    c, d = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fc, fd = value(c), value(d)
    for _ in range(steps):
        left = fc >= fd  # the maximum lies in [lo, d]: d becomes the upper end, c the new d
        hi, lo = np.where(left, d, hi), np.where(left, lo, c)
        fresh = np.where(left, hi - ratio * (hi - lo), lo + ratio * (hi - lo))
        f_fresh = value(fresh)
        c, d, fc, fd = (np.where(left, fresh, d), np.where(left, c, fresh),
                        np.where(left, f_fresh, fd), np.where(left, fc, f_fresh))  # fmt: skip
    return (lo + hi) / 2


def recheck(design: Design, s: float, theta_bar: float, kappa: float) -> float:
    """``lambda_min(Q(s) - kappa D)`` on the literal matrices of size ``n + 2t``, ``D`` of
    :func:`storage_diagonal`: the a posteriori check of a rate."""
    nkn, w = design.full
    d = storage_diagonal(design, s, theta_bar)
    return float(rate_margin(nkn[None], w[None], d[None], np.array([s]), np.array([kappa]))[0])


@dataclass(frozen=True)
class Decay:
    """The rate certified at one ``theta_bar``: ``s``, ``kappa`` (shrunk and re-checked),
    ``rho = c_inf / wbar^2 = 1/(4 s kappa)`` and the self-consistent level ``c_max``."""

    theta_bar: float
    s: float
    kappa: float
    rho: float
    c_max: float

    @property
    def gamma_prime(self) -> float:
        return 1.0 / math.sqrt(2.0 * self.s)


def decays(design: Design, theta_bars: np.ndarray) -> list[Decay]:
    """:class:`Decay` at each candidate ``theta_bar`` with a positive rate (shrunk by
    :data:`SHRINK`; the one used is re-checked by :func:`recheck`)."""
    s, kappa = best_s(design, theta_bars)
    c_max = design.c_max(theta_bars)
    return [
        Decay(float(th), float(si), float(ki * (1 - SHRINK)), float(1.0 / (4 * si * ki * (1 - SHRINK))), float(cm))
        for th, si, ki, cm in zip(theta_bars, s, kappa, c_max, strict=True)
        if ki > 0
    ]


def error_bounds(design: Design, c: float) -> dict:
    """Bounds on every error for the states with ``V <= c`` (fact 7): metres, degrees, rad/s."""
    return level_bounds(design.weights, design.mass.m_lo, design.rotational, c)


def level_bounds(weights: tuple[float, float, float, float], m_lo: float, rotational: bool, c: float) -> dict:
    """From ``V <= c``: ``|p_ec| <= sqrt(2c/w_pc)``, ``theta_ec <= arccos(1 - c/w_rc)`` (degrees; None
    for the planar loop), the same for ``e_e``, ``|xi| <= sqrt(2c/m_lo)``."""
    w_pc, w_rc, w_pe, w_re = weights

    def angle(weight: float) -> float | None:
        return math.degrees(math.acos(max(-1.0, 1.0 - c / weight))) if rotational else None

    return {
        "p_ec": math.sqrt(2 * c / w_pc),
        "theta_ec_deg": angle(w_rc),
        "p_ee": math.sqrt(2 * c / w_pe),
        "theta_ee_deg": angle(w_re),
        "xi": math.sqrt(2 * c / m_lo) if m_lo > 0 else (0.0 if c == 0 else math.inf),
    }


@dataclass(frozen=True)
class Boxes:
    """Certified feature regions at a level ``c``: per feature ``[u_lo, v_lo, u_hi, v_hi]`` in
    pixels (None without an image size or when a depth can reach zero), the smallest depth,
    the smallest distance to the image border (negative when a box crosses it)."""

    level: float
    boxes: list[list[float]] | None
    depth_min: float
    margin_px: float | None

    @property
    def visible(self) -> bool | None:
        if self.margin_px is None:
            return None if self.depth_min > 0 else False
        return self.depth_min > 0 and self.margin_px >= 0


def joint_radius(weights: tuple[float, float, float, float], rotational: bool, points: np.ndarray,
                 c: float) -> np.ndarray:
    """docs/math.md, fact 16 (16.0.1): every state with ``V <= c`` has
    ``|p_ci - g_d p_oi| <= rho_i = sqrt(2 c S_i)``, ``S_i = 1/w_pc + 1/w_pe + |p_oi|^2 (1/w_rc + 1/w_re)``
    (the rotational term absent for the planar loop). ``points`` (m, 3): the features ``p_oi`` in
    the object frame; returns ``rho_i`` (m,).

    By fact 8, ``p_ci - g_d p_oi = R_d [(R_ec R_ee - I) p_oi + R_ec p_ee + p_ec]``; with the spectral
    norm ``||R - I||_2 = 2 sin(theta/2)``, ``phi(R) = ||R - I||_2^2 / 2``, so ``V <= c`` bounds the
    weighted squares of ``|p_ec|``, ``|p_ee|``, ``||R_ec - I||_2``, ``||R_ee - I||_2`` by ``2c`` in sum,
    and Cauchy-Schwarz gives the radius (asymptotically attained as ``c -> 0``)."""
    w_pc, w_rc, w_pe, w_re = weights
    spread = 1.0 / w_pc + 1.0 / w_pe
    if rotational:
        spread = spread + np.sum(np.asarray(points) ** 2, axis=1) * (1.0 / w_rc + 1.0 / w_re)
    return np.sqrt(2.0 * c * np.broadcast_to(spread, (len(points),)))


def cone_interval(centres: np.ndarray, axis: int, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """docs/math.md, fact 16 (16.0.2): the exact range ``[tan(phi - beta), tan(phi + beta)]`` of
    ``x/z`` (``axis`` 0) or ``y/z`` (``axis`` 1) over the balls of ``radius`` (...) about ``centres``
    (..., 3): ``phi = atan2(x, z)``, ``beta = asin(radius / d)`` with the distance
    ``d = sqrt(x^2 + z^2)`` in the plane of that axis and the optical axis (the ball's projection
    onto it is a disk of the same radius; ``x/z`` is the tangent of the angle seen from the optical
    centre). Valid where the depth exceeds the radius (then ``|phi| + beta < pi/2``)."""
    lateral, depth = centres[..., axis], centres[..., 2]
    distance = np.hypot(lateral, depth)
    phi = np.arctan2(lateral, depth)
    beta = np.arcsin(np.minimum(1.0, radius / distance))
    return np.tan(phi - beta), np.tan(phi + beta)


def feature_boxes(design: Design, camera: Camera, desired: np.ndarray, c: float, extra: float | np.ndarray = 0.0
                  ) -> Boxes:  # fmt: skip
    """The certified feature regions at level ``c`` (docs/math.md, fact 16.0: fact 8 with the joint
    radius :func:`joint_radius` and the exact cone :func:`cone_interval`). ``desired`` (m, 3) or
    (K, m, 3): the features' camera-frame positions at the reference, ``g_d p_oi`` (at ``K``
    references along a path, the regions covering them all); ``extra``: a length added to every
    radius (how far a centre may move between two references of a path)."""
    centres = np.asarray(desired, dtype=float).reshape(-1, len(camera.points), 3)
    radius = joint_radius(design.weights, design.rotational, camera.points, c) + extra
    radius = np.broadcast_to(radius, centres.shape[:2])
    depth_min = float(np.min(centres[..., 2] - radius))
    if not camera.has_image or depth_min <= 0:
        return Boxes(c, None, depth_min, None)
    ends = [cone_interval(centres, axis, radius) for axis in (0, 1)]
    lo = camera.focal_length * np.stack([ends[0][0], ends[1][0]], axis=-1).min(axis=0) + camera.centre
    hi = camera.focal_length * np.stack([ends[0][1], ends[1][1]], axis=-1).max(axis=0) + camera.centre
    size = np.array([camera.width, camera.height])
    margin = float(np.min(np.concatenate([lo, size - hi], axis=1)))
    return Boxes(c, np.concatenate([lo, hi], axis=1).tolist(), depth_min, margin)


def desired_features(camera: Camera, reference: SE3) -> np.ndarray:
    """``g_d p_oi`` for every feature (m, 3)."""
    matrix = np.asarray(cs.DM(reference.as_matrix()))
    return camera.points @ matrix[:3, :3].T + matrix[:3, 3]


def visible_level(design: Design, camera: Camera, desired: np.ndarray, steps: int = 60) -> float:
    """The largest level ``c`` whose feature boxes all fit the image (boxes grow with ``c``):
    bisection; 0 when even ``c = 0`` does not fit, ``inf`` without an image size."""
    if not camera.has_image:
        return math.inf
    if not feature_boxes(design, camera, desired, 0.0).visible:
        return 0.0
    hi = 2 * min(w for w in design.weights if w > 0) if design.rotational else 1.0
    while design.rotational is False and feature_boxes(design, camera, desired, hi).visible:
        hi *= 2
    lo = 0.0
    if feature_boxes(design, camera, desired, hi).visible:
        return hi
    for _ in range(steps):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if feature_boxes(design, camera, desired, mid).visible else (lo, mid)
    return lo


@dataclass
class Envelope(Record):
    """The operating envelope of one design (see the module text for every field); its fields are the
    keys of ``points[0].envelope`` in ``dvfc certify``'s JSON."""

    rate: float | None
    gamma_prime: float | None
    theta_bar_deg: float | None
    m_hi: float
    m_lo: float
    ultimate_V: float | None  # noqa: N815 (the paper's V)
    bounds: dict | None
    level: float | None
    visible: bool | None
    image_margin_px: float | None
    depth_min: float | None
    start: dict
    max_target_speed: float | None
    max_torque: float | None
    wbar: float
    disturbance: DisturbanceBounds
    invariant_V: float | None = None  # noqa: N815
    boxes_px: list[list[float]] | None = None
    ultimate_boxes_px: list[list[float]] | None = None
    recheck_margin: float | None = None
    statement: str = ""
    reason: str | None = None
    inertia: dict | None = None
    """The inertia matrices the rate was computed with (docs/math.md, fact 10): ``upper`` ``diag(D_M)``
    at the optimum (None without a rate), ``lower`` the lower bound with ``P = I`` (``m_lo`` its
    smallest entry, used by the ``|xi|`` bound)."""


def _smallest(design: Design, grid: np.ndarray, wbar2: float, v0: float, cover: bool):
    """The smallest ``theta_bar`` of ``grid`` whose rate passes the a posteriori check and
    whose ``c_inf`` is self-consistent (``c_inf <= c_max``) and, with ``cover``, whose
    ``c_max`` covers the start. ``kappa`` falls and ``c_inf`` grows with ``theta_bar`` (``D``
    grows), so the smallest also has the smallest ``c_inf``. Returns ``(decay, cover, margin)``."""
    if cover and design.rotational:
        grid = grid[design.c_max(grid) >= v0]
    lo, size = 0, 1
    while lo < len(grid):  # chunks of 1, 2, 4, ... candidates: usually the first one is it
        chunk, lo, size = grid[lo : lo + size], lo + size, 2 * size
        for d in decays(design, chunk):
            if d.rho * wbar2 <= d.c_max and (not cover or v0 <= d.c_max):
                margin = recheck(design, d.s, d.theta_bar, d.kappa)
                if margin >= 0:
                    return d, cover, margin
    return None, False, None


def envelope(
    design: Design,
    camera: Camera,
    disturbance: DisturbanceBounds,
    start: dict,
    theta_bar: float | None = None,
    *,
    search: bool = True,
) -> Envelope:
    """The envelope of ``design`` under ``disturbance`` from a start whose storage is
    ``start["V0"]`` (:func:`start_storage`); ``theta_bar`` (radians) fixed, or chosen (module
    text). ``search``: also the largest certified target speed and torque."""
    v0 = start["V0"]
    grid = np.array([theta_bar]) if theta_bar is not None else THETA_GRID
    if not design.rotational:
        grid = np.array([0.0])  # no rotation: D does not depend on theta_bar
    wbar2 = disturbance.wbar**2
    mass = design.mass
    empty = Envelope(None, None, None, mass.m_hi, mass.m_lo, None, None, None, None, None, None,
                     {**start, "inside": False}, None, None, disturbance.wbar, disturbance,
                     inertia=inertia_record(mass, None))  # fmt: skip
    if s_limit(design) <= 0:
        empty.reason = "no positive decay rate: Q(gamma') = N^T K N - W/(2 gamma'^2) is not positive definite"
        return empty
    chosen, inside, margin = _smallest(design, grid, wbar2, v0, cover=True)
    if chosen is None:
        chosen, inside, margin = _smallest(design, grid, wbar2, v0, cover=False)
    if chosen is None:
        empty.reason = (
            "not self-consistent: for every theta_bar the ultimate level c_inf exceeds min(w_rc, w_re)(1 - cos "
            "theta_bar), so the rotation errors are not kept below theta_bar (reduce the disturbance bounds)"
        )
        return empty
    env = _build(design, camera, disturbance, start, chosen, inside, margin)
    if inside and env.visible is False:  # covering the start costs visibility: try the ultimate statement
        ultimate = _build(design, camera, disturbance, start, *_smallest(design, grid, wbar2, v0, cover=False))
        if ultimate.visible:
            ultimate.start["reason"] = (
                f"V(0) = {v0:.3g} lies in a self-consistent set (theta_bar = {env.theta_bar_deg:.3g} deg) whose "
                "feature regions are not certified inside the image; the statement is the ultimate one")
            env = ultimate
    if search and env.visible is not None:
        assert design.reference is not None, "a visibility statement is of the paper's loop"
        _largest_bounds(env, design, camera, desired_features(camera, design.reference), decays(design, grid),
                        theta_bar)  # fmt: skip
    env.statement = statement(env)
    return env


def stated(env: Envelope, start: dict) -> Envelope:
    """The envelope with ``start`` as its start record, the one that decides whether the start is
    inside the certified set, and its statement re-derived from that decision.

    With a planned reference (docs/math.md, fact 16b) or a ramp of ``u_d`` (fact 16a) the loop from
    ``t = 0`` is not the fixed-reference loop whose set ``V <= c_max`` the envelope's own test
    ``V(0) <= c_max`` is about: the start's record (:mod:`dvfc.analysis.start`) decides, and the
    envelope's statement, table and figure read it. When it certifies the start, its statement
    (from ``t = 0``, along the whole run) and its regions are the envelope's."""
    env = replace(env, start=start)
    if start.get("method", "constant") != "constant" and start["inside"]:
        env.statement = start["statement"]
        if start.get("boxes_px") is not None:  # the figure's regions: those of the whole run
            env.boxes_px = start["boxes_px"]
        return env
    env.statement = statement(env)
    return env


def _build(design: Design, camera: Camera, disturbance: DisturbanceBounds, start: dict, chosen: Decay,
           inside: bool, margin: float) -> Envelope:
    """The envelope at the chosen ``theta_bar``: bounds, level, boxes (without the searches)."""  # fmt: skip
    wbar2 = disturbance.wbar**2
    mass = design.mass
    v0 = start["V0"]
    c_inf = chosen.rho * wbar2
    level = max(c_inf, v0) if inside else c_inf
    desired = desired_features(camera, design.reference) if design.reference is not None else None
    env = Envelope(
        rate=chosen.kappa,
        gamma_prime=chosen.gamma_prime,
        theta_bar_deg=math.degrees(chosen.theta_bar) if design.rotational else None,
        m_hi=mass.m_hi,
        m_lo=mass.m_lo,
        ultimate_V=c_inf,
        bounds=error_bounds(design, c_inf),
        level=level,
        visible=None,
        image_margin_px=None,
        depth_min=None,
        start={**start, "inside": inside, "level": level if inside else None},
        max_target_speed=None,
        max_torque=None,
        wbar=disturbance.wbar,
        disturbance=disturbance,
        recheck_margin=margin,
        invariant_V=chosen.c_max,
        inertia=inertia_record(mass, kinetic_diagonal(mass, design.k_xi, np.array([chosen.s]))[0]),
    )
    if desired is not None:
        boxes = feature_boxes(design, camera, desired, level)
        env.visible, env.image_margin_px, env.depth_min, env.boxes_px = (
            boxes.visible, boxes.margin_px, boxes.depth_min, boxes.boxes)  # fmt: skip
        env.ultimate_boxes_px = feature_boxes(design, camera, desired, c_inf).boxes
    return env


def inertia_record(mass: MassBounds, d_m: np.ndarray | None) -> dict:
    """``{"upper": diag(D_M) or None, "lower": L_M, "method": ...}`` (n x n lists; docs/math.md, fact 10)."""
    return {"upper": None if d_m is None else np.diag(d_m).tolist(), "lower": mass.lower().tolist(),
            "method": f"upper: {mass.method_hi}, at the Perron vector of diag(k_xi - s)^-1 B; "
                      f"lower (P = I): {mass.method_lo}"}  # fmt: skip


def _largest_bounds(env: Envelope, design: Design, camera: Camera, desired: np.ndarray,
                    candidates: list[Decay], theta_bar: float | None) -> None:
    """The largest target speed and torque with the same statement still certified (from
    t = 0 when the start is covered, else ultimately), each with the other bounds held;
    re-checked by recomputing the envelope there."""  # fmt: skip
    if not camera.has_image:
        return
    cap = visible_level(design, camera, desired)
    start = {k: env.start[k] for k in ("V0", "kinetic", "pose") if k in env.start}
    v0, inside = start["V0"], env.start["inside"]
    best = 0.0
    for d in candidates:
        top = min(d.c_max, cap)
        if inside and v0 > top:
            continue
        best = max(best, top / d.rho)
    dist = env.disturbance
    for name, others in (("target_speed", dist.torque**2 + dist.target_rate**2),
                         ("torque", dist.target_speed**2 + dist.target_rate**2)):  # fmt: skip
        room = best - others
        if room < 0:
            continue
        value = math.sqrt(room) * (1 - 1e-9)
        trial = DisturbanceBounds(**{**_fields(dist), name: value})
        check = envelope(design, camera, trial, start, theta_bar, search=False)
        if check.visible and (check.start["inside"] or not inside):
            setattr(env, "max_target_speed" if name == "target_speed" else "max_torque", value)


def _fields(d: DisturbanceBounds) -> dict:
    return {"target_speed": d.target_speed, "target_rate": d.target_rate, "torque": d.torque,
            "derivation": d.derivation}  # fmt: skip


def statement(env: Envelope) -> str:
    """One sentence saying what is certified and from when, from the decision of ``env.start``
    (``inside``): a start not certified says why when its record does (``reason``)."""
    if env.rate is None:
        return "no envelope certified"
    start = env.start
    when = f"for all t >= 0 (the start V(0) = {start['V0']:.3g} is inside the certified set V <= {env.level:.3g})"
    if not start["inside"]:
        why = f"not certified: {start['reason']}" if start.get("reason") else "outside it"
        when = (f"ultimately, for runs that enter the certified set V <= {env.invariant_V:.3g} "
                f"(the start V(0) = {start['V0']:.3g} is {why})")  # fmt: skip
    if env.visible is True:
        return f"every feature stays in the image {when}"
    if env.visible is False:
        return "visibility is NOT certified: a certified feature region reaches the image border or zero depth"
    assert env.bounds is not None, "an envelope with a rate has its bounds"
    why = ("the planar loop's feature regions are not derived (the camera's yaw is not a task)"
           if env.bounds["theta_ec_deg"] is None else "no image size given")  # fmt: skip
    return f"errors bounded {when}; no visibility statement: {why}"


def disturbance_bounds(section, loop) -> DisturbanceBounds:
    """The envelope's disturbance bounds: those of the scenario's ``[envelope]`` section
    (``section``, possibly None), each missing one derived from the loop's own target motion
    and torque disturbances (saying how)."""
    given = {} if section is None else section.model_dump(exclude_none=True)
    derived = {
        "target_speed": (loop.target.speed, "the target's circle: 2 pi radius / period"),
        "target_rate": (loop.target.rate, "the target's spin rate"),
        "torque": (torque_bound(loop.disturbances), "sum of the torque components' sup-norm bounds "
                   "(step, sine: |amplitude|; noise: |rms| sqrt(2 tones))"),
    }  # fmt: skip
    values, how = {}, {}
    for name, (value, text) in derived.items():
        values[name] = float(given.get(name, value))
        how[name] = "[envelope] " + name if name in given else text
    return DisturbanceBounds(**values, derivation=how)


def start_storage(loop, s0: np.ndarray) -> dict:
    """``V(0)`` (38) at the initial state and its parts: the kinetic term ``xi^T M xi / 2``
    (large when ``qd0`` differs from ``qd_d(0) = pinv(J_b) u_d(0)``) and the pose errors; and how
    the run starts (``"constant"``, ``"planned"``: docs/math.md, fact 16b, or ``"ramp"``: fact 16a)."""
    kinetic = loop.xi.T @ loop.robot.mass_matrix @ loop.xi / 2
    values = cs.Function("V0", [loop.t, loop.state], [loop.storage, kinetic])(0.0, s0)
    total, kin = (float(v) for v in values)
    method = "planned" if loop.plan is not None else ("ramp" if loop.ramp is not None else "constant")
    return {"V0": total, "kinetic": kin, "pose": total - kin, "method": method}


GRID_GOLDEN_STEPS = 8
"""Golden-section steps per grid point (the bracket shrinks to 2% of ``s_lim / 2``; ``s kappa``
is flat at its maximum, so ``c_inf`` is within a few 1e-4 of its minimum: a tightness loss only)."""


@dataclass(frozen=True)
class GridEnvelope:
    """What the envelope columns of a grid need besides each point's gains and weights (plain,
    picklable data): the ``theta_bar`` used for every point, the mass bounds, the camera and
    the features at the reference (None for the planar loop), and ``torque^2 + rate^2``."""

    theta_bar: float
    mass: MassBounds
    camera: Camera
    desired: np.ndarray | None
    other2: float


def grid_envelope(
    design: Design, camera: Camera, disturbance: DisturbanceBounds, theta_bar: float | None
) -> GridEnvelope:
    """The grid context of a scenario: ``theta_bar`` given, or the one giving the design's largest
    certified target speed (with an image; else the smallest self-consistent one), used for
    every point of the grid."""
    desired = desired_features(camera, design.reference) if design.reference is not None else None
    if theta_bar is None and desired is not None:
        candidates = decays(design, THETA_GRID)
        cap = visible_level(design, camera, desired)
        wbar2 = disturbance.wbar**2
        if camera.has_image and candidates:
            theta_bar = max(candidates, key=lambda d: min(d.c_max, cap) / d.rho).theta_bar
        else:
            consistent = [d for d in candidates if d.rho * wbar2 <= d.c_max]
            theta_bar = consistent[0].theta_bar if consistent else math.radians(30.0)
    return GridEnvelope(theta_bar or 0.0, design.mass, camera, desired,
                        disturbance.torque**2 + disturbance.target_rate**2)  # fmt: skip


def envelope_columns(ctx: GridEnvelope, nkn: np.ndarray, wdiag: np.ndarray, k_xi: np.ndarray,
                     weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched fact 7-8 for grid points at ``ctx.theta_bar``: the certified rate (NaN where none,
    re-checked a posteriori on ``Q - kappa D``) and the largest target speed keeping every
    feature in view ultimately (NaN without an image or a visible level). ``nkn`` (B, 2t, 2t)
    is ``N^T K N`` on ``(e_c, e_e)`` (sound ``K_e``), ``wdiag`` (B, 2t) the diagonal of ``W``
    there, ``k_xi`` (B, n), ``weights`` (B, 4). The rate is (10.4) (docs/math.md, fact 10), re-checked
    on ``Q(s) - kappa diag(D_M/2, D_ce)`` of size ``n + 2t`` with ``D_M`` from the Perron vector."""  # fmt: skip
    b, t2 = nkn.shape[:2]
    n = k_xi.shape[1]
    rotational = ctx.desired is not None
    d = pose_diagonal(weights, ctx.theta_bar, rotational, t2 // 2)
    inv = 1.0 / np.sqrt(d)
    a = inv[:, :, None] * nkn * inv[:, None, :]
    w = wdiag * inv**2
    eye = np.eye(t2)
    root = np.sqrt(wdiag)
    lim = 1.0 / np.linalg.eigvalsh(root[:, :, None] * np.linalg.inv(nkn) * root[:, None, :])[:, -1]
    lim = np.minimum(lim, k_xi.min(axis=1))

    def value(s: np.ndarray) -> np.ndarray:
        ce = np.linalg.eigvalsh(a - s[:, None, None] * (w[:, :, None] * eye))[:, 0]
        return np.minimum(xi_rates(ctx.mass, k_xi, s), ce)

    s = golden_max(lambda x: x * value(x), lim, GRID_GOLDEN_STEPS)
    kappa = value(s) * (1 - SHRINK)
    full = np.zeros((b, n + t2, n + t2))
    full[:, :n, :n] = k_xi[:, :, None] * np.eye(n)
    full[:, n:, n:] = nkn
    ok = (kappa > 0) & (lim > 0)
    d_m = kinetic_diagonal(ctx.mass, k_xi, np.where(ok, s, 0.0))
    check = rate_margin(full, np.concatenate([np.ones((b, n)), wdiag], axis=1),
                        np.concatenate([d_m / 2, d], axis=1), s, kappa)  # fmt: skip
    ok &= check >= 0
    rate = np.where(ok, kappa, np.nan)
    speed = np.full(b, np.nan)
    if rotational and ctx.camera.has_image:
        c_max = self_consistent_level(weights, ctx.theta_bar)
        unique, which = np.unique(weights, axis=0, return_inverse=True)
        c_vis = np.array([_visible_level_of(ctx, row) for row in unique])[which.ravel()]
        with np.errstate(divide="ignore", invalid="ignore"):
            wbar2 = np.minimum(c_max, c_vis) * 4 * s * kappa
            speed = np.where(ok & (wbar2 >= ctx.other2), np.sqrt(np.maximum(wbar2 - ctx.other2, 0.0)), np.nan)
    return rate, speed


def _visible_level_of(ctx: GridEnvelope, weights: np.ndarray) -> float:
    """:func:`visible_level` for one row of weights (boxes depend on the weights, not the gains)."""
    w_pc, w_rc, w_pe, w_re = map(float, weights)
    stub = Design(np.zeros((12, 12)), np.zeros(12), np.zeros(0), ctx.mass, (w_pc, w_rc, w_pe, w_re), True,
                  None, None, (np.zeros((1, 1)), np.zeros(1)))  # type: ignore[arg-type]  # fmt: skip (a stub: no point)
    assert ctx.desired is not None, "called for the paper's loop only"
    return visible_level(stub, ctx.camera, ctx.desired)


INTEGRAL_RATE = (
    "not certified for a law with integral action (docs/math.md, fact 20.4): fact 7's exponential rate is lost (at "
    "x = 0 with z_I != 0, dV_a/dt = 0 while V_a > 0), and fact 20.4's local V_eps rate needs constants (the bounds "
    "c_C on C(q, qd) and jbar on J_b) that are sampled, not rigorous"
)
"""The envelope's statement for a design with ``K_I``."""


@dataclass(frozen=True)
class FrictionBound:
    """The plant's joint friction as the envelope sees it (docs/math.md, facts 18, 19.2): per joint, the
    Coulomb bound on the torque the law leaves (``F_c``, or ``|d_i| <= |F_i - Fhat_i| + Fhat_i
    sup_v |tanh(v/eps) - tanh(v/epshat)|`` with compensation on ``qd_d``, the ``sup`` bounded by 1 when the
    smoothings differ), and the viscous coefficient of the cross term ``-xi^T (B_v - Bhat) J_b^-1 Y e_c``
    (fact 18.3), which this route does not bound."""

    coulomb: np.ndarray
    cross: np.ndarray
    compensated: bool

    @staticmethod
    def of(friction: np.ndarray, compensation: np.ndarray | None) -> FrictionBound:
        """From the plant's ``[b; c; eps]`` and the law's ``[bhat; chat; epshat]`` (None: no compensation)."""
        n = (len(friction) - 1) // 2
        b, c, eps = friction[:n], friction[n : 2 * n], friction[2 * n]
        if compensation is None:
            return FrictionBound(np.asarray(c, float), np.asarray(b, float), False)
        bh, ch, eh = compensation[:n], compensation[n : 2 * n], compensation[2 * n]
        shape = 0.0 if eh == eps else 1.0
        return FrictionBound(np.abs(c - ch) + ch * shape, np.abs(b - bh), True)


WITHOUT_FRICTION = "the plant without friction"
"""The plant of the ideal continuous loop's statements when the scenario's has friction (facts 18-19)."""


def said_for(plant: str | None, text: str) -> str:
    """``text`` said for ``plant`` (None: the law's model, said by the loop alone)."""
    return text if plant is None else f"for {plant}: {text}"


def friction_record(design: Design, camera: Camera, disturbance: DisturbanceBounds, start: dict,
                    frictionless: Envelope, bound: FrictionBound) -> dict:
    """The envelope of the plant with friction, the law's as it is (docs/math.md, fact 18.5 unweighted:
    ``|tau_d| <= |tau_e| + |F|`` with ``F`` the Coulomb bound of ``bound``, one ``s`` for every channel):
    CERTIFIED only when the envelope with that torque bound is certified and no viscous cross term is
    left (exact viscous compensation); otherwise the numbers that show why, ``c_inf`` against ``c_max``
    at the frictionless envelope's ``theta_bar`` (``c_inf`` grows with ``theta_bar`` while ``c_max <
    2 min(w_rc, w_re)``)."""  # fmt: skip
    torque = disturbance.torque + float(np.linalg.norm(bound.coulomb))
    how = ("|tau_e| + |F_c|: the plant's Coulomb friction, law unchanged (fact 18.4)" if not bound.compensated else
           "|tau_e| + |d|: the residual of the law's friction compensation on qd_d (fact 19.2)")  # fmt: skip
    trial = DisturbanceBounds(**{**_fields(disturbance), "torque": torque,
                                 "derivation": {**disturbance.derivation, "torque": how}})  # fmt: skip
    env = envelope(design, camera, trial, start, search=False)
    theta = frictionless.theta_bar_deg if frictionless.theta_bar_deg is not None else 1.0
    d = decays(design, np.radians([theta]))
    c_inf, c_max = (d[0].rho * trial.wbar**2, d[0].c_max) if d else (math.inf, 0.0)
    cap = 2 * float(min(design.weights[1], design.weights[3]))
    record = {"torque_bound": torque, "wbar": trial.wbar, "theta_bar_deg": theta, "c_inf": c_inf, "c_max": c_max,
              "c_max_sup": cap, "coulomb_bound": bound.coulomb.tolist(), "viscous_cross": bound.cross.tolist(),
              "compensated": bound.compensated, "rate": env.rate, "bounds": env.bounds}  # fmt: skip
    law = "with the law's friction compensation on qd_d" if bound.compensated else "with the law unchanged"
    if env.rate is None:
        record["certified"] = False
        record["statement"] = (f"with the plant's friction ({law}) the envelope is vacuous: c_inf = {c_inf:.4g} > "
                               f"c_max = {c_max:.4g} at theta_bar = {theta:.3g} deg (fact 18.5, unweighted; c_inf "
                               f"grows with theta_bar, c_max < 2 min(w_rc, w_re) = {cap:.3g}): no certificate; the "
                               "dispersion campaign is the evidence")  # fmt: skip
    elif np.any(bound.cross > 0):
        record["certified"] = False
        record["statement"] = (f"with the plant's friction ({law}) not certified: the Coulomb part alone gives "
                               f"c_inf = {env.ultimate_V:.4g} <= c_max = {env.invariant_V:.4g}, but the viscous cross "
                               "term -xi^T (B_v - Bhat) J_b^-1 Y e_c (fact 18.3) is not bounded by this route")
    else:
        record["certified"] = True
        record["statement"] = (f"with the plant's friction ({law}; viscous friction cancelled exactly, fact 19.2): "
                               f"{env.statement} (c_inf = {env.ultimate_V:.4g})")  # fmt: skip
    return record
