"""Pinhole camera (10)-(11), image Jacobian (19)-(20) and the first-order relation (18)."""

from __future__ import annotations

from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis.scenario import build, load
from dvfc.models.camera import Camera
from dvfc.models.lie import SE3

SQUARE = np.array([[0.05, 0.05, 0.0], [-0.05, 0.05, 0.0], [-0.05, -0.05, 0.0], [0.05, -0.05, 0.0]])
CAMERA = Camera(800.0, SQUARE)
EXAMPLES = Path(__file__).parent.parent / "examples"
GBAR = SE3.from_xyz_rpy([0.02, -0.01, 0.4], [0.1, -0.2, 0.3])


def num(m) -> np.ndarray:
    return np.asarray(cs.DM(m))


def test_projection_is_perspective():
    """(11): ``f_i = lambda / z_ci [x_ci; y_ci]`` with ``p_ci = g p_oi`` (10)."""
    f = num(CAMERA.project(GBAR)).reshape(-1, 2)
    p = (num(GBAR.rotation.matrix) @ SQUARE.T).T + num(GBAR.translation).ravel()
    assert np.allclose(f, 800.0 * p[:, :2] / p[:, 2:], rtol=1e-14)


def test_pixels_are_features_about_the_principal_point():
    """A feature ``f`` (11) measured about the principal point ``(u0, v0)`` is at pixel
    ``(u0, v0) + f``; it is inside the image iff ``0 <= u <= width`` and ``0 <= v <= height``.
    Exact comparisons: the window is a sum of two given numbers."""
    camera = Camera(800.0, SQUARE, 640.0, 480.0, (300.0, 250.0))
    low, high = camera.image_window()
    assert np.array_equal(low, [-300.0, -250.0]) and np.array_equal(high, [340.0, 230.0])
    f = np.array([0.0, 0.0, 339.0, -249.0, 341.0, 0.0, 0.0, 231.0])
    assert camera.outside_image(f).tolist() == [2, 3]
    centred = Camera(800.0, SQUARE, 640.0, 480.0)
    assert np.array_equal(centred.centre, [320.0, 240.0])


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


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.toml")), ids=lambda p: p.stem)
def test_every_example_states_its_sensor_and_starts_in_view(path):
    """Every shipped example names an image size (a real sensor, stated in its comments) and
    every feature is inside that image at t = 0 (``build`` rejects a start outside it)."""
    spec, base = load(path)
    assert spec.camera.width and spec.camera.height
    assert "px" in path.read_text().split("[camera]")[1].split("[target]")[0]
    loop, _, _ = build(spec, base)
    assert loop.camera.has_image
