"""The window each joint's gain ``k_xi,i`` must lie in (docs/math.md, "Gain windows").

Below, the certificate's requirement on the ``xi`` block of the ideal continuous loop:
Theorem 2's L2 certificate at ``gamma`` needs ``K_xi - S_xi^2/2 - s D_tau^2 >= 0`` with
``s = 1/(2 gamma^2)`` and the generalized plant's weights (docs/math.md, fact 17); the window asks
``k_xi,i > S_xi,i^2/2 + D_tau,i^2/(2 gamma^2)`` at the scenario's required gamma (``[certify] gamma``),
``k_xi,i > S_xi,i^2/2`` for any finite gamma (``1/2 + 1/(2 gamma^2)`` and ``1/2`` at unit weights,
the paper's); the envelope's rate needs
``k_xi,i > s`` for its own ``s``, which it meets by choosing ``s < min_i k_xi,i``.

Above, the hold limit of the sampled loop at the control rate: the torque ``-K_xi xi`` held
over ``h`` on ``M(q0) xi' = tau`` (the joint-velocity loop alone, linear, at ``q0``, the
model's inertia) is exactly ``xi_(k+1) = (I - h M^-1 K_xi) xi_k``. Its eigenvalues ``1 - h
lambda`` (``lambda`` those of ``M^-1 K_xi``, real and positive) lie in ``(-(1 - HOLD_MARGIN),
1)`` iff ``h lambda_max(M^-1 K_xi) <= 2 - HOLD_MARGIN``. Each joint's limit is found exactly,
by bisection on its gain with the other gains fixed at their values; where the others break
the limit already, the joint's limit alone (the others at zero: the diagonal term
``(2 - HOLD_MARGIN) / (h (M^-1)_ii)``, necessary whatever the others are) is used instead, and
gains that break the limit together, none above its own, are reported together. This is a
necessary condition for the sampled loop, local, at ``q0``: fact 14
(:mod:`dvfc.analysis.multirate`) is the certificate of the whole sampled loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from dvfc.models.loop import PlantWeights

if TYPE_CHECKING:
    from dvfc.analysis.case import Case

HOLD_MARGIN = 0.05
"""The held map's eigenvalues must lie in ``(-(1 - HOLD_MARGIN), 1)``: at the hold limit the
joint's velocity error, sampled, still shrinks by 5% a period in its fastest mode."""

UPPER_FRACTION = 0.8
"""A synthesised design keeps ``K_xi <= UPPER_FRACTION (2 - HOLD_MARGIN)/h M(q0)``: every joint's gain
at most this fraction of its window's upper end, the hold limit at ``UPPER_FRACTION`` of the control
rate (the limit scales with ``1/h``), the control-rate margin the synthesis asks of fact 14."""

LOWER_FACTOR = 1.1
"""A synthesised design keeps every ``k_xi,i`` at least this factor times its window's lower end."""

BISECTION_STEPS = 60
"""Bisection steps on each gain between 0 and its diagonal limit (to ``2^-60`` of it)."""


def certificate_lower(gamma: float | None, plant: PlantWeights) -> np.ndarray:
    """Per joint, the bound ``k_xi,i`` must exceed for the ``xi`` block of Theorem 2's certificate:
    ``S_xi,i^2/2 + D_tau,i^2/(2 gamma^2)`` at a required ``gamma``; ``S_xi,i^2/2`` for any finite gamma."""
    n = len(plant.xi)
    s2, d2 = plant.output()[:n] ** 2, plant.disturbance()[:n] ** 2
    return 0.5 * s2 if gamma is None else 0.5 * s2 + d2 / (2.0 * gamma**2)


def held_eigenvalues(m_inv: np.ndarray, k_xi: np.ndarray, h: float) -> np.ndarray:
    """The eigenvalues of ``h M^-1 K_xi`` in ascending order, from the symmetric
    ``h K^1/2 M^-1 K^1/2``: the held map ``I - h M^-1 K_xi`` has the eigenvalues ``1 -`` these."""
    root = np.sqrt(k_xi)
    return h * np.linalg.eigvalsh(root[:, None] * m_inv * root[None, :])


def hold_limits(
    m_inv: np.ndarray, k_xi: np.ndarray, h: float, margin: float = HOLD_MARGIN
) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, the largest ``k_xi,i`` with ``h lambda_max(M^-1 K_xi) <= 2 - margin``, the
    other gains fixed at their values, by bisection between 0 and the joint's limit alone (the
    others at zero), the diagonal term ``(2 - margin) / (h (M^-1)_ii)`` (``lambda_max >= k_i
    (M^-1)_ii``: a gain above it breaks the limit whatever the others are). Where the other
    gains break the limit already, no gain of this joint meets it, and its limit alone is
    returned; ``alone`` says where."""
    diagonal = (2.0 - margin) / (h * np.diag(m_inv))
    limits, alone = diagonal.copy(), np.ones(len(k_xi), bool)
    for i in range(len(k_xi)):
        joint = np.arange(len(k_xi)) == i
        stable = lambda k: held_eigenvalues(m_inv, np.where(joint, k, k_xi), h)[-1] <= 2 - margin  # noqa: B023, E731
        lo, hi = 0.0, float(diagonal[i])
        if not stable(lo):
            continue
        alone[i] = False
        for _ in range(BISECTION_STEPS):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if stable(mid) else (lo, mid)
        limits[i] = lo
    return limits, alone


@dataclass(frozen=True)
class GainWindows:
    """The windows of the joints' gains ``k_xi`` (see the module's description).

    ``lower``: the certificate's requirement (exclusive when ``gamma`` is None); ``upper``: the
    hold limits at ``control_rate`` (None: the ideal continuous loop, no hold), ``alone`` where a
    joint's is its limit alone (:func:`hold_limits`); ``held``: ``h lambda_max(M(q0)^-1 K_xi)`` at the
    given gains, at most ``2 - margin`` within the hold limit (None without a hold);
    ``map_radius``: the spectral radius of ``I - h M(q0)^-1 K_xi`` (None without a hold)."""

    k_xi: np.ndarray
    lower: np.ndarray
    gamma: float | None
    upper: np.ndarray | None
    alone: np.ndarray | None
    control_rate: float | None
    held: float | None
    map_radius: float | None
    margin: float = HOLD_MARGIN

    @property
    def below(self) -> np.ndarray:
        """Per joint, whether the gain breaks the certificate's requirement ``k_xi,i > lower``."""
        return self.k_xi <= self.lower

    @property
    def above(self) -> np.ndarray:
        """Per joint, whether the gain exceeds its hold limit (never without a hold)."""
        return np.zeros(len(self.k_xi), bool) if self.upper is None else self.k_xi > self.upper

    @property
    def hold_broken(self) -> bool:
        """Whether the gains together break the hold limit ``h lambda_max <= 2 - margin``."""
        return self.held is not None and self.held > 2 - self.margin

    def breaks(self) -> list[str]:
        """Each gain outside its window, with the limit it breaks, in words; and the gains
        together when they break the hold limit with no single joint's gain above its own."""
        at = f" (gamma = {self.gamma:g})" if self.gamma else ""
        found = []
        for i, k in enumerate(self.k_xi):
            if self.below[i]:
                found.append(f"joint {i + 1} k_xi = {k:.4g} not above the L2 certificate's {self.lower[i]:.4g}{at}")
            if self.above[i]:
                assert self.upper is not None, "above only with a hold"
                found.append(f"joint {i + 1} k_xi = {k:.4g} above its hold limit {self.upper[i]:.4g}")
        if self.hold_broken and not self.above.any():
            found.append("the gains together break the hold limit (no single joint's gain is above its own)")
        return found

    def outside_margins(self) -> list[str]:
        """Each gain not inside its window with the synthesis' margins (at least :data:`LOWER_FACTOR`
        times the lower end, at most :data:`UPPER_FRACTION` of the upper end), and the gains together
        when ``h lambda_max(M^-1 K_xi)`` exceeds ``UPPER_FRACTION (2 - margin)``, in words."""
        found = [f"joint {i + 1} k_xi = {k:.4g} below {LOWER_FACTOR:g} x its window's lower end {low:.4g}"
                 for i, (k, low) in enumerate(zip(self.k_xi, self.lower, strict=True)) if k < LOWER_FACTOR * low]
        if self.upper is not None:
            found += [f"joint {i + 1} k_xi = {k:.4g} above {UPPER_FRACTION:g} x its hold limit {up:.4g}"
                      for i, (k, up) in enumerate(zip(self.k_xi, self.upper, strict=True)) if k > UPPER_FRACTION * up]
            assert self.held is not None, "held with a hold (upper)"
            if self.held > UPPER_FRACTION * (2 - self.margin) and not found:
                found.append(f"the gains together: h lambda_max(M^-1 K_xi) = {self.held:.4g} above "
                             f"{UPPER_FRACTION:g} x {2 - self.margin:g}")  # fmt: skip
        return found

    def warning(self) -> str | None:
        """One line naming the gains outside their windows, or None when all lie inside."""
        found = self.breaks()
        if not found:
            return None
        held = ""
        if self.held is not None:
            verdict = "unstable" if self.held >= 2 else "stable"
            held = (f"; held torque at {self.control_rate:g} Hz: most negative eigenvalue of I - h M(q0)^-1 K_xi "
                    f"{1 - self.held:.4g} ({verdict}, required >= {self.margin - 1:g})")  # fmt: skip
        return f"gain outside its window: {'; '.join(found)}{held}"

    def as_dict(self) -> dict:
        """JSON-ready: per joint ``[lower, upper]`` (upper None without a hold) and what each limit is."""
        upper = [None] * len(self.k_xi) if self.upper is None else self.upper.tolist()
        block = "ideal continuous loop, Theorem 2's xi block: k_xi > S_xi^2/2"
        return {
            "k_xi": [float(k) for k in self.k_xi],
            "windows": [[float(low), u] for low, u in zip(self.lower, upper, strict=True)],
            "inside": (~(self.below | self.above)).tolist(),
            "hold_broken": self.hold_broken,
            "upper_alone": None if self.alone is None else self.alone.tolist(),
            "lower": f"{block} + D_tau^2/(2 gamma^2) at gamma = {self.gamma:g}" if self.gamma
            else f"{block}, any gamma",
            "envelope": "k_xi > s, met by the envelope's choice of s below min k_xi",
            "upper": None if self.upper is None else (
                f"sampled loop, local at q0: the torque -K_xi xi held over h = 1/{self.control_rate:g} s on "
                f"M(q0) xi' = tau, map I - h M^-1 K_xi with eigenvalues in (-(1 - {self.margin:g}), 1); per joint by "
                "bisection on its gain, the others fixed (upper_alone: the others break it already, the joint's "
                "limit with the others at zero)"),
            "map_radius": self.map_radius,
            "outside": self.breaks(),
        }  # fmt: skip


@dataclass(frozen=True)
class WindowSpec:
    """What the windows of ``k_xi`` depend on besides the gains: the inertia ``mass = M(q0)``, the
    control rate (None: the ideal continuous loop), the required gamma (None: any finite gamma) and
    the generalized plant's weights (None: the paper's)."""

    mass: np.ndarray
    control_rate: float | None
    gamma: float | None
    plant: PlantWeights | None = None

    def of(self, k_xi: np.ndarray) -> GainWindows:
        """The windows of the gains ``k_xi``."""
        return gain_windows(self.mass, k_xi, self.control_rate, self.gamma, self.plant)

    def synthesis_lower(self) -> np.ndarray:
        """Per joint, the least gain a synthesis may choose: :data:`LOWER_FACTOR` times the lower end."""
        plant = self.plant if self.plant is not None else PlantWeights.unit(len(self.mass))
        return LOWER_FACTOR * certificate_lower(self.gamma, plant)

    def synthesis_hold(self) -> np.ndarray | None:
        """``H = UPPER_FRACTION (2 - HOLD_MARGIN) M(q0) / h`` (None without a hold): for diagonal
        ``K_xi >= 0``, ``K_xi <= H`` (an LMI, linear in the gains) iff ``h lambda_max(M^-1 K_xi) <=
        UPPER_FRACTION (2 - HOLD_MARGIN)``, and then every gain is at most ``UPPER_FRACTION`` of its
        upper end: raising one gain of ``K_xi`` by ``1/UPPER_FRACTION`` stays below ``K_xi /
        UPPER_FRACTION``, whose held eigenvalue is ``2 - HOLD_MARGIN``."""
        if self.control_rate is None:
            return None
        mass = (self.mass + self.mass.T) / 2
        return UPPER_FRACTION * (2.0 - HOLD_MARGIN) * self.control_rate * mass

    def empty(self, box: tuple[np.ndarray | float, np.ndarray | float]) -> list[str]:
        """Each joint whose gain box ``box`` (lower, upper per joint) leaves no gain inside its
        window with the synthesis' margins, in words: at least :meth:`synthesis_lower` and at most
        ``1 / (H^-1)_ii`` (``H`` :meth:`synthesis_hold`: the largest ``k_xi,i`` with ``k_xi,i e_i
        e_i^T <= H``, the other gains at zero: :data:`UPPER_FRACTION` of the joint's hold limit alone)."""
        lower, (box_lo, box_hi) = self.synthesis_lower(), np.broadcast_arrays(*box)
        hold = self.synthesis_hold()
        alone = np.full(len(lower), np.inf) if hold is None else 1.0 / np.diag(np.linalg.inv(hold))
        found = []
        for i in np.flatnonzero(np.maximum(box_lo, lower) > np.minimum(box_hi, alone)):
            found.append(f"joint {i + 1}: no k_xi in [{box_lo[i]:.4g}, {box_hi[i]:.4g}] is at least {LOWER_FACTOR:g} x "
                         f"the certificate's {lower[i] / LOWER_FACTOR:.4g} and at most {UPPER_FRACTION:g} x its hold "
                         f"limit alone {alone[i] / UPPER_FRACTION:.4g}")  # fmt: skip
        return found


def gain_windows(mass: np.ndarray, k_xi: np.ndarray, control_rate: float | None, gamma: float | None,
                 plant: PlantWeights | None = None) -> GainWindows:
    """The windows of ``k_xi`` for the inertia ``mass = M(q0)``, the control rate (None: the
    ideal continuous loop), the required gamma (None: any finite gamma) and the generalized
    plant's weights (None: the paper's)."""  # fmt: skip
    k_xi = np.asarray(k_xi, dtype=float)
    lower = certificate_lower(gamma, plant if plant is not None else PlantWeights.unit(len(k_xi)))
    if control_rate is None:
        return GainWindows(k_xi, lower, gamma, None, None, None, None, None)
    h = 1.0 / control_rate
    m_inv = np.linalg.inv(mass)
    m_inv = (m_inv + m_inv.T) / 2
    eigenvalues = held_eigenvalues(m_inv, k_xi, h)
    return GainWindows(k_xi, lower, gamma, *hold_limits(m_inv, k_xi, h), control_rate,
                       float(eigenvalues[-1]), float(np.abs(1.0 - eigenvalues).max()))  # fmt: skip


def case_window_spec(case: Case) -> WindowSpec | None:
    """What the case's windows depend on: its ``q0`` (the model's ``M(q0)``), control rate,
    ``[certify] gamma`` and generalized plant; None for the reduced planar loop (no joint-space inertia)."""
    if case.planar:
        return None
    robot, imp = case.loop.robot, case.settings.implementation
    mass = np.asarray(robot.function("M", robot.mass_matrix)(case.s0[: robot.n], 0))
    rate = None if imp is None else imp.control_rate
    return WindowSpec(mass, rate, case.scenario.certify.gamma, case.point.plant)


def case_windows(case: Case) -> GainWindows | None:
    """The windows of the case's gains (:func:`case_window_spec`); None for the reduced planar loop."""
    spec = case_window_spec(case)
    return None if spec is None else spec.of(case.point.k_xi)
