"""Rotations and rigid motions: SO(3) and SE(3) in the conventions of the paper.

Conventions (Murray, Li and Sastry; the paper's notation section and (1), (4)):
twists are ordered ``V = [v; w]`` (linear first), ``hat`` maps R^3 to so(3) and a
twist to se(3), ``vee`` is its inverse, ``g = (p, R)`` is the homogeneous 4x4
matrix (1). Every function works on CasADi symbols (SX, MX) and on numbers (DM;
NumPy arrays are accepted and converted), so the same expressions serve the
symbolic model and numerical checks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import casadi as cs
import numpy as np

Matrix: TypeAlias = cs.SX | cs.MX | cs.DM
ArrayLike: TypeAlias = Matrix | np.ndarray | list | tuple

_SMALL_ANGLE = 1e-6


def _one_minus_cos_over_square(theta: Matrix) -> Matrix:
    """``(1 - cos(theta)) / theta^2`` as ``(sin(theta/2) / (theta/2))^2 / 2``: the direct form
    loses ``eps / theta^2`` to cancellation (1e-4 relative at ``theta = 1e-6``, which ``exp``
    multiplies by ``hat(w) v`` of size ``theta |v|``); the half-angle form is accurate to a few ulps."""
    sinc = cs.sin(theta / 2) / (theta / 2)
    return sinc * sinc / 2


def _as_casadi(a: ArrayLike) -> Matrix:
    if isinstance(a, cs.SX | cs.MX | cs.DM):
        return a
    return cs.DM(np.asarray(a, dtype=float))


def hat(a: ArrayLike) -> Matrix:
    """Wedge operator: ``hat(w) b = w x b`` for a 3-vector; for a twist ``[v; w]``,
    the 4x4 matrix ``[[hat(w), v], [0, 0]]`` (paper, (4))."""
    a = _as_casadi(a)
    if a.numel() == 3:
        return cs.vertcat(
            cs.horzcat(0, -a[2], a[1]),
            cs.horzcat(a[2], 0, -a[0]),
            cs.horzcat(-a[1], a[0], 0),
        )
    if a.numel() == 6:
        top = cs.horzcat(hat(a[3:6]), a[0:3])
        return cs.vertcat(top, cs.DM.zeros(1, 4))
    raise ValueError(f"hat takes a 3-vector or a 6-twist, not {a.numel()} entries")


def vee(m: ArrayLike) -> Matrix:
    """Inverse of :func:`hat` for a 3x3 skew matrix or a 4x4 twist matrix."""
    m = _as_casadi(m)
    w = cs.vertcat(m[2, 1], m[0, 2], m[1, 0])
    if m.shape == (3, 3):
        return w
    if m.shape == (4, 4):
        return cs.vertcat(m[0:3, 3], w)
    raise ValueError(f"vee takes a 3x3 or 4x4 matrix, not {m.shape}")


def sk(r: ArrayLike) -> Matrix:
    """Skew part ``sk(R) = (R - R^T) / 2`` (notation section of the paper)."""
    r = _as_casadi(r)
    return (r - r.T) / 2


def rotation_error(r: ArrayLike) -> Matrix:
    """Vector form of a rotation, ``e_R(R) = sk(R)^vee = sin(theta) axis``.

    It satisfies ``R e_R(R) = e_R(R)`` and vanishes at ``R = I`` and at
    ``theta = pi``: it identifies ``R = I`` only for ``|theta| < pi``.
    """
    return vee(sk(r))


def rotation_error_function(r: ArrayLike) -> Matrix:
    """Error function ``phi(R) = tr(I - R) / 2 = 1 - cos(theta)`` of Lemma 1, (29).

    Along ``dR/dt = R hat(w)``: ``d phi / dt = e_R(R)^T w`` (property 2 under (29)).
    """
    r = _as_casadi(r)
    return (3 - cs.trace(r)) / 2


def rpy_to_matrix(rpy: ArrayLike) -> Matrix:
    """Rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` from roll, pitch, yaw (URDF convention)."""
    rpy = _as_casadi(rpy)
    return (
        SO3.exp(cs.vertcat(0, 0, rpy[2])).matrix
        @ SO3.exp(cs.vertcat(0, rpy[1], 0)).matrix
        @ SO3.exp(cs.vertcat(rpy[0], 0, 0)).matrix
    )


def quaternion_to_matrix(quat: ArrayLike) -> Matrix:
    """Rotation matrix of the quaternion ``[qw, qx, qy, qz]`` after normalising it.

    The normalisation makes the matrix orthogonal even when an integrator lets the
    norm drift; the map is invariant to the quaternion's scale.
    """
    quat = _as_casadi(quat)
    quat = quat / cs.norm_2(quat)
    s, v = quat[0], quat[1:4]
    h = hat(v)
    return cs.DM.eye(3) + 2 * s * h + 2 * h @ h


def quaternion_rate(quat: ArrayLike, w: ArrayLike) -> Matrix:
    """Quaternion derivative for the body rate ``w``: ``dq/dt = q (x) [0; w] / 2``,
    the quaternion form of ``dR/dt = R hat(w)``."""
    quat, w = _as_casadi(quat), _as_casadi(w)
    s, v = quat[0], quat[1:4]
    return cs.vertcat(-v.T @ w, s * w + cs.cross(v, w)) / 2


def quaternion_product(a: ArrayLike, b: ArrayLike) -> Matrix:
    """``a (x) b`` for quaternions ``[w, x, y, z]`` (rotation ``R_a R_b``)."""
    a, b = _as_casadi(a), _as_casadi(b)
    return cs.vertcat(a[0] * b[0] - a[1:4].T @ b[1:4], a[0] * b[1:4] + b[0] * a[1:4] + cs.cross(a[1:4], b[1:4]))


def quaternion_exp(w: ArrayLike) -> Matrix:
    """The unit quaternion of ``exp(hat(w))``: ``[cos(theta/2); sin(theta/2) w / theta]``, with the
    series of ``cos(theta/2)`` and ``sin(theta/2)/theta`` below ``theta = 1e-4`` (errors below ``1e-18``;
    differentiable at ``w = 0``, where ``theta = |w|`` is not: the program's Jacobian, docs/math.md, fact 22)."""
    w = _as_casadi(w)
    theta2 = w.T @ w
    theta = cs.sqrt(theta2)
    small = theta2 < 1e-8
    half = cs.if_else(small, 0.5 - theta2 / 48, cs.sin(theta / 2) / theta)
    return cs.vertcat(cs.if_else(small, 1 - theta2 / 8 + theta2**2 / 384, cs.cos(theta / 2)), half * w)


def matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[qw, qx, qy, qz]`` (with ``qw >= 0``) of a numeric rotation."""
    r = np.asarray(r, dtype=float)
    k = np.array(
        [
            [r[0, 0] + r[1, 1] + r[2, 2], r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]],
            [r[2, 1] - r[1, 2], r[0, 0] - r[1, 1] - r[2, 2], r[0, 1] + r[1, 0], r[0, 2] + r[2, 0]],
            [r[0, 2] - r[2, 0], r[0, 1] + r[1, 0], r[1, 1] - r[0, 0] - r[2, 2], r[1, 2] + r[2, 1]],
            [r[1, 0] - r[0, 1], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1], r[2, 2] - r[0, 0] - r[1, 1]],
        ]
    )
    _, vecs = np.linalg.eigh(k / 3)
    quat = vecs[:, -1]
    return quat if quat[0] >= 0 else -quat


@dataclass(frozen=True)
class SO3:
    """A rotation, held as its 3x3 matrix."""

    matrix: Matrix

    @staticmethod
    def identity() -> SO3:
        return SO3(cs.DM.eye(3))

    @staticmethod
    def exp(w: ArrayLike) -> SO3:
        """Rodrigues' formula ``exp(hat(w))``; smooth at ``w = 0``."""
        w = _as_casadi(w)
        theta2 = w.T @ w
        theta = cs.sqrt(theta2)
        small = theta2 < _SMALL_ANGLE**2
        a = cs.if_else(small, 1 - theta2 / 6, cs.sin(theta) / theta)
        b = cs.if_else(small, 0.5 - theta2 / 24, _one_minus_cos_over_square(theta))
        h = hat(w)
        return SO3(cs.DM.eye(3) + a * h + b * h @ h)

    def log(self) -> Matrix:
        """Rotation vector ``theta axis`` for ``|theta| < pi`` (inverse of :meth:`exp`)."""
        e = rotation_error(self.matrix)
        s = cs.norm_2(e)
        c = (cs.trace(self.matrix) - 1) / 2
        theta = cs.atan2(s, c)
        return cs.if_else(s < _SMALL_ANGLE, 1 + s**2 / 6, theta / s) * e

    def inverse(self) -> SO3:
        return SO3(self.matrix.T)

    def __matmul__(self, other: SO3) -> SO3:
        return SO3(self.matrix @ other.matrix)

    def adjoint(self) -> Matrix:
        """``Ad_R = diag(R, R)``, the adjoint of a pure rotation (orthogonal)."""
        return cs.diagcat(self.matrix, self.matrix)

    def error_vector(self) -> Matrix:
        """``e_R(R)``, see :func:`rotation_error`."""
        return rotation_error(self.matrix)

    def error_function(self) -> Matrix:
        """``phi(R)``, see :func:`rotation_error_function`."""
        return rotation_error_function(self.matrix)


@dataclass(frozen=True)
class SE3:
    """A rigid motion ``g = (p, R)`` (paper, (1))."""

    translation: Matrix
    rotation: SO3

    @staticmethod
    def identity() -> SE3:
        return SE3(cs.DM.zeros(3), SO3.identity())

    @staticmethod
    def from_xyz_rpy(xyz: ArrayLike, rpy: ArrayLike) -> SE3:
        return SE3(_as_casadi(xyz), SO3(rpy_to_matrix(rpy)))

    @staticmethod
    def from_matrix(m: ArrayLike) -> SE3:
        m = _as_casadi(m)
        return SE3(m[0:3, 3], SO3(m[0:3, 0:3]))

    @staticmethod
    def exp(twist: ArrayLike) -> SE3:
        """Exponential of the twist ``[v; w]``: ``p = (I + b hat(w) + c hat(w)^2) v``."""
        twist = _as_casadi(twist)
        v, w = twist[0:3], twist[3:6]
        theta2 = w.T @ w
        theta = cs.sqrt(theta2)
        small = theta2 < _SMALL_ANGLE**2
        b = cs.if_else(small, 0.5 - theta2 / 24, _one_minus_cos_over_square(theta))
        c = cs.if_else(small, 1.0 / 6 - theta2 / 120, (theta - cs.sin(theta)) / (theta2 * theta))
        h = hat(w)
        return SE3((cs.DM.eye(3) + b * h + c * h @ h) @ v, SO3.exp(w))

    def log(self) -> Matrix:
        """Twist ``[v; w]`` with ``exp`` equal to this motion, for ``|theta| < pi``."""
        w = self.rotation.log()
        theta2 = w.T @ w
        theta = cs.sqrt(theta2)
        small = theta2 < _SMALL_ANGLE**2
        half = theta / 2
        d = cs.if_else(small, 1.0 / 12 + theta2 / 720, (1 - half * cs.cos(half) / cs.sin(half)) / theta2)
        h = hat(w)
        v = (cs.DM.eye(3) - h / 2 + d * h @ h) @ self.translation
        return cs.vertcat(v, w)

    def inverse(self) -> SE3:
        """``g^-1 = (-R^T p, R^T)``."""
        rt = self.rotation.inverse()
        return SE3(-rt.matrix @ self.translation, rt)

    def __matmul__(self, other: SE3) -> SE3:
        """Composition ``g1 g2`` (paper, (2))."""
        r = self.rotation.matrix
        return SE3(r @ other.translation + self.translation, self.rotation @ other.rotation)

    def act(self, point: ArrayLike) -> Matrix:
        """The point ``g p = R p + p_g`` (paper, (10))."""
        return self.rotation.matrix @ _as_casadi(point) + self.translation

    def as_matrix(self) -> Matrix:
        top = cs.horzcat(self.rotation.matrix, self.translation)
        return cs.vertcat(top, cs.horzcat(cs.DM.zeros(1, 3), 1))

    def position_quaternion(self) -> np.ndarray:
        """``[p; q]`` of a numeric motion: position and unit quaternion ``[qw, qx, qy, qz]``
        (the way simulation states carry a pose)."""
        p = np.asarray(cs.DM(self.translation)).ravel()
        return np.concatenate([p, matrix_to_quaternion(np.asarray(cs.DM(self.rotation.matrix)))])

    def adjoint(self) -> Matrix:
        """``Ad_g = [[R, hat(p) R], [0, R]]``: ``hat(Ad_g V) = g hat(V) g^-1``."""
        r = self.rotation.matrix
        top = cs.horzcat(r, hat(self.translation) @ r)
        return cs.vertcat(top, cs.horzcat(cs.DM.zeros(3, 3), r))

    def error_vector(self) -> Matrix:
        """Pose error vector ``e(g) = [p; e_R(R)]`` used for ``e_e`` (15) and ``e_c`` (24)."""
        return cs.vertcat(self.translation, self.rotation.error_vector())

    def error_function(self) -> Matrix:
        """``|p|^2 / 2`` and ``phi(R)`` stacked: the two terms the storage (38) weighs."""
        p = self.translation
        return cs.vertcat(p.T @ p / 2, self.rotation.error_function())
