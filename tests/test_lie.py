"""SO(3) and SE(3): group axioms and the identities the proofs use.

Tolerances are absolute with ``rtol=0`` (``np.allclose``'s default ``rtol=1e-5`` would admit
a relative error of 1e-5 behind any ``atol``):

- :data:`EPS` = 1e-12 for products and compositions of entries of order 1 (unit rotations,
  translations of order 1): each of the O(10-100) flops rounds by 1.1e-16, a few 1e-15 in
  all; 1e-12 leaves a margin for CasADi's evaluation order.
- 1e-11 for adjoints of the random poses (``|p|`` up to about 5: the ``hat(p) R`` block and
  its inverse multiply round-off by ``|p|^2``), and for the exp/log round trips at angles up to
  ``pi - 1e-3``, where ``log`` divides by ``sin(theta) >= 1e-3``: 1e-16 / 1e-3 times a few
  flops; measured at most 3.1e-13 over 2000 draws near that angle.
- finite differences: the truncation and round-off bound stated in each test.
"""

from __future__ import annotations

import casadi as cs
import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from dvfc.models.lie import (
    SE3,
    SO3,
    hat,
    matrix_to_quaternion,
    quaternion_rate,
    quaternion_to_matrix,
    rotation_error,
    rotation_error_function,
    vee,
)

EPS = 1e-12  # a few ulps of O(1) quantities after O(10) flops
vec3 = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(np.array)


def rotation_vector(direction: np.ndarray, angle: float) -> np.ndarray:
    n = np.linalg.norm(direction)
    return np.array([1.0, 0.0, 0.0]) * angle if n < 1e-6 else direction / n * angle


def num(m) -> np.ndarray:
    return np.asarray(cs.DM(m))


def random_se3(rng: np.random.Generator) -> SE3:
    return SE3.exp(np.concatenate([rng.normal(size=3), rng.normal(size=3)]))


def test_hat_vee_inverse(rng):
    """``vee(hat(v)) = v`` exactly: ``vee`` reads back the entries ``hat`` placed (no arithmetic)."""
    for v in (rng.normal(size=3), rng.normal(size=6)):
        assert np.array_equal(num(vee(hat(v))).ravel(), v)


def test_hat_is_cross_product(rng):
    a, b = rng.normal(size=3), rng.normal(size=3)
    assert np.allclose(num(hat(a) @ cs.DM(b)).ravel(), np.cross(a, b), rtol=0, atol=EPS)


@settings(max_examples=200, deadline=None)
@given(vec3, st.floats(0.0, np.pi - 1e-3))
def test_so3_exp_log_round_trip(direction, angle):
    w = rotation_vector(direction, angle)
    assert np.allclose(num(SO3.exp(w).log()).ravel(), w, rtol=0, atol=1e-11)


@settings(max_examples=200, deadline=None)
@given(vec3, st.floats(0.0, np.pi - 1e-3), vec3)
@example(np.zeros(3), 1e-6, np.array([0.0, 0.0, 1.0]))  # just above the series branch: (1 - cos)/theta^2 cancelled
def test_se3_exp_log_round_trip(direction, angle, v):
    twist = np.concatenate([v, rotation_vector(direction, angle)])
    assert np.allclose(num(SE3.exp(twist).log()).ravel(), twist, rtol=0, atol=1e-11)


def test_exp_is_orthogonal(rng):
    r = num(SO3.exp(rng.normal(size=3) * 2).matrix)
    assert np.allclose(r.T @ r, np.eye(3), rtol=0, atol=EPS)
    assert np.isclose(np.linalg.det(r), 1.0, rtol=0, atol=EPS)


def test_inverse(rng):
    g = random_se3(rng)
    assert np.allclose(num((g @ g.inverse()).as_matrix()), np.eye(4), rtol=0, atol=EPS)


def test_associative(rng):
    a, b, c = (random_se3(rng) for _ in range(3))
    assert np.allclose(num(((a @ b) @ c).as_matrix()), num((a @ (b @ c)).as_matrix()), rtol=0, atol=EPS)


def test_adjoint_of_product(rng):
    a, b = random_se3(rng), random_se3(rng)
    assert np.allclose(num((a @ b).adjoint()), num(a.adjoint() @ b.adjoint()), rtol=0, atol=1e-11)


def test_adjoint_of_inverse(rng):
    g = random_se3(rng)
    assert np.allclose(num(g.inverse().adjoint()), np.linalg.inv(num(g.adjoint())), rtol=0, atol=1e-11)


def test_adjoint_conjugates_twists(rng):
    """``hat(Ad_g V) = g hat(V) g^-1`` (Murray, Li and Sastry, Lemma 2.13), used for (9)."""
    g, v = random_se3(rng), rng.normal(size=6)
    lhs = num(hat(g.adjoint() @ cs.DM(v)))
    rhs = num(g.as_matrix() @ hat(v) @ g.inverse().as_matrix())
    assert np.allclose(lhs, rhs, rtol=0, atol=1e-11)


def test_rotation_error_is_fixed_by_rotation(rng):
    """``R e_R(R) = e_R(R)``: e_R is along the rotation axis."""
    r = SO3.exp(rng.normal(size=3)).matrix
    assert np.allclose(num(r @ rotation_error(r)), num(rotation_error(r)), rtol=0, atol=EPS)


def test_rotation_error_is_sine_axis(rng):
    w = rng.normal(size=3)
    theta = np.linalg.norm(w)
    assert np.allclose(num(rotation_error(SO3.exp(w).matrix)).ravel(), np.sin(theta) * w / theta, rtol=0, atol=EPS)


def test_rotation_error_vanishes_at_pi():
    """e_R identifies R = I only for |theta| < pi: at pi it is zero although R != I."""
    r = SO3.exp([0.0, 0.0, np.pi]).matrix
    assert np.allclose(num(rotation_error(r)), 0, rtol=0, atol=EPS) and not np.allclose(num(r), np.eye(3))


def test_phi_is_one_minus_cos(rng):
    w = rng.normal(size=3)
    phi = float(rotation_error_function(SO3.exp(w).matrix))
    assert np.isclose(phi, 1 - np.cos(np.linalg.norm(w)), rtol=0, atol=EPS)


def test_phi_rate_is_rotation_error_times_rate(rng):
    """Property 2 under (29): along ``dR/dt = R hat(w)``, ``d phi/dt = e_R(R)^T w``.

    Central differences with h = 1e-5 have truncation error ~h^2 and round-off ~1e-16/h:
    both below 1e-9.
    """
    r0, w, h = num(SO3.exp(rng.normal(size=3)).matrix), rng.normal(size=3), 1e-5

    def phi(t):
        return float(rotation_error_function(r0 @ num(SO3.exp(w * t).matrix)))

    fd = (phi(h) - phi(-h)) / (2 * h)
    assert np.isclose(fd, float(rotation_error(r0).T @ cs.DM(w)), rtol=0, atol=1e-9)


def test_quaternion_round_trip(rng):
    r = num(SO3.exp(rng.normal(size=3)).matrix)
    assert np.allclose(num(quaternion_to_matrix(matrix_to_quaternion(r))), r, rtol=0, atol=EPS)


def test_quaternion_rate_matches_body_rate(rng):
    """``dq/dt = q (x) [0; w] / 2`` moves R(q) as ``dR/dt = R hat(w)``. Central differences with
    h = 1e-6: truncation ~h^2 |qdot|^3 ~ 1e-12 (the map is quadratic in q, so only the
    ``|q| != 1`` drift enters), round-off ~1e-16 / h = 1e-10; 1e-8 is 100 times that."""
    q = matrix_to_quaternion(num(SO3.exp(rng.normal(size=3)).matrix))
    w, h = rng.normal(size=3), 1e-6
    qdot = num(quaternion_rate(q, w)).ravel()
    fd = (num(quaternion_to_matrix(q + h * qdot)) - num(quaternion_to_matrix(q - h * qdot))) / (2 * h)
    assert np.allclose(fd, num(quaternion_to_matrix(q)) @ num(hat(w)), rtol=0, atol=1e-8)


def test_rpy_is_z_y_x(rng):
    roll, pitch, yaw = rng.normal(size=3)
    g = SE3.from_xyz_rpy([0, 0, 0], [roll, pitch, yaw])
    expected = num(SO3.exp([0, 0, yaw]).matrix) @ num(SO3.exp([0, pitch, 0]).matrix) @ num(SO3.exp([roll, 0, 0]).matrix)
    assert np.allclose(num(g.rotation.matrix), expected, rtol=0, atol=EPS)
