"""The gain windows' limits (docs/math.md, "Gain windows") against independent computations: the
lower limit against the ``xi`` block of the reference ``P(gamma)`` (tests/reference.py, fact 17's
weights), the hold limits and the joint hold check against the eigenvalues of the held map
``I - h M^-1 K_xi`` computed as a general (non-symmetric) matrix by ``numpy.linalg.eigvals``."""

from __future__ import annotations

import numpy as np
import pytest

from dvfc.analysis.windows import HOLD_MARGIN, gain_windows
from dvfc.models.loop import PlantWeights

import reference as ref

N = 6


def reference_xi_block(k_xi: np.ndarray, plant: PlantWeights, gamma: float) -> np.ndarray:
    """The ``xi`` block of the reference ``P(gamma) = N^T K N - G D_w^2 G^T / (2 gamma^2) - S^2/2``
    (tests/reference.py, built literally from Lemma 2 and fact 17; ``K_c``, ``K_e``, the weights and
    ``g_d`` arbitrary: the block does not depend on them, fact 1)."""
    design = ref.Design(k_xi, np.full(6, 2.0), np.full(6, 3.0), (1.0, 1.0, 1.0, 1.0), np.array([0.1, 0.0, 0.4]),
                        np.eye(3), s=plant.output(), dw=plant.disturbance())  # fmt: skip
    p = ref.p_matrix(design.a(np.eye(3)), design.weight, gamma)
    return p[:N, :N]


def held_map_eigenvalues(mass: np.ndarray, k_xi: np.ndarray, h: float) -> np.ndarray:
    """The eigenvalues of ``I - h M^-1 K_xi``, as a general matrix (real parts; they are real)."""
    return np.linalg.eigvals(np.eye(len(k_xi)) - h * np.linalg.solve(mass, np.diag(k_xi))).real


def random_mass(rng: np.random.Generator, n: int = N) -> np.ndarray:
    """A symmetric positive definite inertia with strong coupling and a wide spread of scales."""
    a = rng.normal(size=(n, n)) * np.geomspace(0.05, 3.0, n)
    return a @ a.T + 1e-3 * np.eye(n)


@pytest.mark.parametrize("gamma", [None, 0.4, 0.8, 1.7, 5.0])
def test_window_lower_limit_is_where_the_reference_xi_block_of_p_loses_definiteness(gamma, rng):
    """With random weights ``S_xi``, ``D_tau`` in [0.3, 3] (fact 17): just above each joint's lower
    limit (1 + 1e-9) the reference ``xi`` block of ``P(gamma)`` is positive definite in that
    joint, just below (1 - 1e-9) it is not, so the gain is reported below its window exactly then;
    without a required gamma the limit is that of ``gamma -> inf`` (here 1e6, whose ``1/(2 gamma^2)``
    terms are below the 1e-9 step)."""
    plant = PlantWeights(tuple(rng.uniform(0.3, 3.0, N)), tuple(rng.uniform(0.3, 3.0, N)))
    mass = random_mass(rng)
    lower = gain_windows(mass, np.ones(N), None, gamma, plant).lower
    for factor, definite in ((1 + 1e-9, True), (1 - 1e-9, False)):
        k_xi = lower * factor
        block = np.diag(reference_xi_block(k_xi, plant, 1e6 if gamma is None else gamma))
        assert np.all((block > 0) == definite), (factor, block)
        assert np.all(gain_windows(mass, k_xi, None, gamma, plant).below != definite)


def test_together_the_gains_break_the_hold_exactly_when_the_held_map_leaves_its_margin(rng):
    """For 10 random coupled inertias and gains scaled so that the held map's most negative eigenvalue
    (``numpy.linalg.eigvals`` of ``I - h M^-1 K_xi``) is ``-(1 - margin) -+ 0.01``: the windows say
    the gains break the hold limit (and say so) exactly when it is below ``-(1 - margin)``, and their
    ``map_radius`` is that eigenvalue's modulus to 1e-9."""
    h = 1 / 500
    for _ in range(10):
        mass = random_mass(rng)
        k_xi = rng.uniform(0.5, 5.0, N)
        lowest = held_map_eigenvalues(mass, k_xi, h).min()
        for target in (-(1 - HOLD_MARGIN) - 0.01, -(1 - HOLD_MARGIN) + 0.01):
            k = k_xi * (1 - target) / (1 - lowest)  # h lambda_max scales with K_xi
            eig = held_map_eigenvalues(mass, k, h)
            assert eig.min() == pytest.approx(target, abs=1e-9)
            windows = gain_windows(mass, k, 500.0, None)
            broken = bool(eig.min() < -(1 - HOLD_MARGIN))
            assert windows.hold_broken == broken
            assert any("hold limit" in line for line in windows.breaks()) == broken
            assert windows.map_radius == pytest.approx(np.abs(eig).max(), abs=1e-9)


def test_a_joints_limit_alone_keeps_the_margin_when_the_others_break_the_hold_already():
    """Three joints with ``(M^-1)_ij = 0.9`` off the diagonal and 1 on it (``h = 1``) at gains 1.2:
    any two break the hold (``1.2 * 1.9 > 1.95``), so every joint's limit is its limit alone,
    ``(2 - margin) / (h (M^-1)_ii) = 1.95``: at that gain with the others at zero the held map's
    eigenvalue (``eigvals``) is ``-(1 - margin)`` to 1e-12, and the gains are reported together."""
    m_inv = np.full((3, 3), 0.9) + 0.1 * np.eye(3)
    mass = np.linalg.inv(m_inv)
    windows = gain_windows(mass, np.full(3, 1.2), 1.0, None)
    assert windows.alone.all() and not windows.above.any() and windows.hold_broken
    assert "the gains together break the hold limit" in windows.warning()
    for i, limit in enumerate(windows.upper):
        k = np.zeros(3)
        k[i] = limit
        assert held_map_eigenvalues(mass, k, 1.0).min() == pytest.approx(-(1 - HOLD_MARGIN), abs=1e-12)


def test_a_gain_exactly_at_one_half_admits_no_finite_gamma_and_is_below_its_window():
    """Without a required gamma the window is open, ``k_xi,i > S_xi,i^2/2``: at ``k_xi,1 = 1/2``
    exactly (unit weights) the reference ``P(gamma)`` (tests/reference.py, bisection on its smallest
    eigenvalue) has no finite gamma, since its ``xi`` block is singular at every ``s > 0``, while at
    ``1/2 + 1e-3`` it has one (the rest of ``P`` does not decide); the window reports the first
    below and the second inside."""
    plant = PlantWeights.unit(N)
    k_c, k_e = np.full(6, 2.0), np.full(6, 3.0)
    for k1, finite in ((0.5, False), (0.5 + 1e-3, True)):
        k_xi = np.r_[k1, np.full(N - 1, 1.5)]
        design = ref.Design(k_xi, k_c, k_e, (1.0, 1.0, 1.0, 1.0), np.array([0.1, 0.0, 0.4]), np.eye(3))
        assert np.isfinite(design.gamma(np.eye(3))) == finite
        windows = gain_windows(np.eye(N), k_xi, None, None, plant)
        assert windows.below[0] == (not finite) and not windows.below[1:].any()
