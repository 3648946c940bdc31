"""What the controller's model gets wrong: the plant's camera mount, intrinsics, lens
distortion, feature points and joint friction, as numbers handed to the compiled loop.

The law and the observer keep the nominal model (the scenario's ``[robot] mount``, ``[camera]``,
``[target] points``, no friction). The image is made by the true camera: the point
``p_oi + dp_i`` seen from the true camera frame ``g_wc Delta`` (``Delta`` the mount error),
projected by OpenCV's Brown-Conrady model with the true intrinsics, read by the controller with
its nominal intrinsics (and undistorted with its nominal coefficients when it has any). Friction
is a torque the law does not model, ``tau_f = b qd + c tanh(qd / eps)``: viscous ``b`` and
Coulomb ``c`` per joint, the sign function smoothed over ``eps`` (so that the held-torque
dynamics stay smooth within a control period).

Every value here is an input of the compiled functions (:meth:`PlantErrors.camera_vector`,
:meth:`PlantErrors.friction_vector`): no run recompiles.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from dvfc.models.camera import Camera
from dvfc.models.lie import SE3, Matrix

UNDISTORT_ITERATIONS = 10
"""Fixed-point iterations of the controller's undistortion (OpenCV's ``undistortPoints`` uses 5)."""


@dataclass(frozen=True)
class PlantErrors:
    """The plant as it is, where the controller's model differs.

    Parameters
    ----------
    mount_xyz, mount_rpy
        The true camera mount relative to the nominal one: ``g_wc,true = g_wc Delta``.
    fx, fy, principal_point, distortion
        The true intrinsics (px) and OpenCV's ``[k1, k2, p1, p2, k3]``.
    point_errors
        ``(m, 3)``: the error of each feature point in the object frame (m).
    viscous, coulomb, smoothing
        Joint friction per joint (N m s/rad and N m, or N s/m and N) and ``eps`` of
        ``tanh(qd / eps)`` (rad/s).
    """

    mount_xyz: np.ndarray
    mount_rpy: np.ndarray
    fx: float
    fy: float
    principal_point: np.ndarray
    distortion: np.ndarray
    point_errors: np.ndarray
    viscous: np.ndarray
    coulomb: np.ndarray
    smoothing: float = 0.05

    @staticmethod
    def none(camera: Camera, n: int) -> PlantErrors:
        """No error: the nominal camera, mount and points, no friction."""
        return PlantErrors(np.zeros(3), np.zeros(3), camera.focal_length, camera.focal_length * camera.aspect,
                           camera.centre if camera.has_image else np.zeros(2), np.asarray(camera.distortion),
                           np.zeros((camera.m, 3)), np.zeros(n), np.zeros(n))  # fmt: skip

    def camera_vector(self, camera: Camera) -> np.ndarray:
        """The input of the compiled image function: mount error, true ``fx, fy``, the true
        principal point's offset from the nominal one, distortion, point errors."""
        nominal = camera.centre if camera.has_image else np.zeros(2)
        offset = np.asarray(self.principal_point, dtype=float) - nominal
        return np.concatenate([self.mount_xyz, self.mount_rpy, [self.fx, self.fy], offset, self.distortion,
                               np.ravel(self.point_errors)]).astype(float)  # fmt: skip

    @property
    def has_dry_friction(self) -> bool:
        """Whether a joint has dry (Coulomb) friction: its smoothed slope at rest ``c / eps`` is as steep as the
        smoothing is narrow, the held dynamics as stiff."""
        return bool(np.any(self.coulomb))

    def friction_vector(self) -> np.ndarray:
        """The input of the compiled control period: ``[b; c; eps]``."""
        return np.concatenate([self.viscous, self.coulomb, [self.smoothing]]).astype(float)

    def window(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """The true image as bounds on the true features about the true principal point, point
        by point (as :meth:`Camera.image_window` tiled)."""
        low = -np.asarray(self.principal_point, dtype=float)
        high = low + np.array([camera.width, camera.height])
        return np.tile(low, camera.m), np.tile(high, camera.m)


def camera_size(m: int) -> int:
    """Entries of :meth:`PlantErrors.camera_vector` for ``m`` points."""
    return 15 + 3 * m


def friction_torque(qd: Matrix, parameters: Matrix, n: int) -> Matrix:
    """``b qd + c tanh(qd / eps)`` from ``parameters = [b; c; eps]``."""
    b, c, eps = parameters[:n], parameters[n : 2 * n], parameters[2 * n]
    return b * qd + c * cs.tanh(qd / eps)


def friction_slope(qd: Matrix, parameters: Matrix, n: int) -> Matrix:
    """``d/dqd (b qd + c tanh(qd / eps)) = b + (c / eps) (1 - tanh(qd / eps)^2)`` per joint (the diagonal of the
    friction's Jacobian) from ``parameters = [b; c; eps]``."""
    b, c, eps = parameters[:n], parameters[n : 2 * n], parameters[2 * n]
    return b + c / eps * (1 - cs.tanh(qd / eps) ** 2)


def distort(x: Matrix, y: Matrix, k: Matrix) -> tuple[Matrix, Matrix, Matrix]:
    """Brown-Conrady on normalised coordinates ``(x, y)`` with ``k = [k1, k2, p1, p2, k3]``:
    the radial factor and the tangential terms, ``x_d = x radial + tx``, ``y_d = y radial + ty``."""
    r2 = x**2 + y**2
    radial = 1 + k[0] * r2 + k[1] * r2**2 + k[4] * r2**3
    tx = 2 * k[2] * x * y + k[3] * (r2 + 2 * x**2)
    ty = k[2] * (r2 + 2 * y**2) + 2 * k[3] * x * y
    return radial, tx, ty


def seen_through(relative: SE3, mount: Matrix) -> SE3:
    """The relative pose ``relative`` (nominal camera to object) as the true camera sees it, mounted with the
    error ``mount`` (``xyz``, ``rpy``: the first six entries of :meth:`PlantErrors.camera_vector`)."""
    return SE3.from_xyz_rpy(mount[0:3], mount[3:6]).inverse() @ relative


def true_features(camera: Camera, relative: SE3, parameters: Matrix) -> tuple[Matrix, Matrix, Matrix]:
    """What the true camera makes of the relative pose ``relative`` (nominal camera to object):
    the true features about the true principal point (px), the same about the nominal principal
    point, and the true depths. ``parameters`` is :meth:`PlantErrors.camera_vector`."""
    fx, fy, offset, k = parameters[6], parameters[7], parameters[8:10], parameters[10:15]
    seen = seen_through(relative, parameters)
    true, nominal, depths = [], [], []
    for i in range(camera.m):
        x, y, z = cs.vertsplit(seen.act(cs.DM(camera.points[i]) + parameters[15 + 3 * i : 18 + 3 * i]))
        radial, tx, ty = distort(x / z, y / z, k)
        # (fx / z) x radial: with no error (radial = 1, tx = 0) exactly the nominal lambda / z x
        f = cs.vertcat(fx / z * x * radial + fx * tx, fy / z * y * radial + fy * ty)
        true.append(f)
        nominal.append(f + offset)
        depths.append(z)
    return cs.vertcat(*true), cs.vertcat(*nominal), cs.vertcat(*depths)


def controller_features(camera: Camera, pixels: Matrix) -> Matrix:
    """The features ``f`` (11) the controller reads from pixel offsets about its principal
    point: ``v`` rescaled to ``fx`` (``fy = aspect fx``) and, when the nominal camera has
    distortion coefficients, undistorted by fixed-point iteration (as OpenCV does)."""
    lam = camera.focal_length
    out = []
    for i in range(camera.m):
        u, v = pixels[2 * i], pixels[2 * i + 1]
        if camera.aspect != 1.0:
            v = v / camera.aspect
        if any(camera.distortion):
            xd, yd = u / lam, v / lam
            x, y = xd, yd
            for _ in range(UNDISTORT_ITERATIONS):
                radial, tx, ty = distort(x, y, cs.DM(camera.distortion))
                x, y = (xd - tx) / radial, (yd - ty) / radial
            u, v = lam * x, lam * y
        out.append(cs.vertcat(u, v))
    return cs.vertcat(*out)
