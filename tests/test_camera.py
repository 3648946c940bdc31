"""Pinhole camera (10)-(11), image Jacobian (19)-(20) and the first-order relation (18)."""

from __future__ import annotations

import casadi as cs
import numpy as np

from models.camera import Camera
from models.lie import SE3

SQUARE = np.array([[0.05, 0.05, 0.0], [-0.05, 0.05, 0.0], [-0.05, -0.05, 0.0], [0.05, -0.05, 0.0]])
CAMERA = Camera(800.0, SQUARE)
GBAR = SE3.from_xyz_rpy([0.02, -0.01, 0.4], [0.1, -0.2, 0.3])


def num(m) -> np.ndarray:
    return np.asarray(cs.DM(m))


def test_projection_is_perspective():
    """(11): ``f_i = lambda / z_ci [x_ci; y_ci]`` with ``p_ci = g p_oi`` (10)."""
    f = num(CAMERA.project(GBAR)).reshape(-1, 2)
    p = (num(GBAR.rotation.matrix) @ SQUARE.T).T + num(GBAR.translation).ravel()
    assert np.allclose(f, 800.0 * p[:, :2] / p[:, 2:], rtol=1e-14)


def test_first_order_relation_is_quadratic_in_error(rng):
    """(18): ``f - fbar - J(gbar) e_e`` is O(|e_e|^2): halving the error quarters it.

    The ratio of residuals at scales s and s/2 is 4 up to O(s) terms; with s <= 1e-2
    it lies in [3.5, 4.5].
    """
    direction = rng.normal(size=6)
    direction /= np.linalg.norm(direction)
    j = num(CAMERA.jacobian(GBAR))
    residuals = []
    for scale in (1e-2, 5e-3, 2.5e-3):
        g_ee = SE3.exp(scale * direction)
        g = GBAR @ g_ee
        e_e = num(g_ee.error_vector()).ravel()
        residuals.append(np.linalg.norm(num(CAMERA.project(g) - CAMERA.project(GBAR)).ravel() - j @ e_e))
    ratios = np.array(residuals[:-1]) / np.array(residuals[1:])
    assert np.all((ratios > 3.5) & (ratios < 4.5)), ratios


def test_jacobian_has_rank_six_for_four_points():
    s = np.linalg.svd(num(CAMERA.jacobian(GBAR)), compute_uv=False)
    assert s[-1] > 1e-3 * s[0]


def test_jacobian_is_rank_deficient_for_collinear_points():
    line = Camera(800.0, np.array([[x, 0.0, 0.0] for x in (-0.1, -0.03, 0.04, 0.1)]))
    s = np.linalg.svd(num(line.jacobian(GBAR)), compute_uv=False)
    assert s[-1] < 1e-10 * s[0]


def test_estimation_error_from_image_is_exact_to_first_order(rng):
    """(21): ``pinv(J)(f - fbar)`` recovers ``e_e`` up to O(|e_e|^2)."""
    e = 1e-4 * rng.normal(size=6)
    g_ee = SE3.exp(e)
    g = GBAR @ g_ee
    estimate = num(CAMERA.estimation_error(CAMERA.project(g), GBAR)).ravel()
    exact = num(g_ee.error_vector()).ravel()
    assert np.linalg.norm(estimate - exact) < 100 * np.linalg.norm(exact) ** 2
