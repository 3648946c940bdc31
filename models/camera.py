"""Pinhole camera with m feature points, and the image Jacobian of the observer.

Implements (10)-(11) (actual features), (13)-(14) (estimated features),
(19)-(20) (the Jacobian ``J(gbar)`` with ``f - fbar = J(gbar) e_e`` to first order,
(18)) and (21) (``e_e = pinv(J) (f - fbar)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from dvfc.models.lie import SE3, Matrix, hat


@dataclass(frozen=True)
class Camera:
    """A pinhole camera of focal length ``focal_length`` seeing the object points.

    Parameters
    ----------
    focal_length
        ``lambda`` in (11), in the units of the image coordinates per metre of depth
        ratio (pixels, or metres on the sensor).
    points
        ``(m, 3)`` feature points ``p_oi`` in the object frame (metres).
    width, height
        Image size in pixels, or ``None`` when the sensor is not stated (then no
        visibility statement is possible).
    principal_point
        ``(u0, v0)`` in pixels from the image's top-left corner; ``None`` means the centre.
        The features ``f`` of (11) are measured about it: pixel ``(u, v) = (u0, v0) + f``
        (``(u0, v0) + (f_u, aspect f_v)`` when ``aspect != 1``).
    aspect, distortion
        ``fy / fx`` (``focal_length`` is ``fx``) and OpenCV's ``[k1, k2, p1, p2, k3]``: the
        controller reads pixels through them (:func:`dvfc.models.errors.controller_features`);
        the features ``f`` of (11) are undistorted, in units of ``fx``.
    """

    focal_length: float
    points: np.ndarray
    width: float | None = None
    height: float | None = None
    principal_point: tuple[float, float] | None = None
    aspect: float = 1.0
    distortion: tuple[float, ...] = (0.0,) * 5

    @property
    def has_image(self) -> bool:
        """Whether the image size is known."""
        return self.width is not None and self.height is not None

    @property
    def size(self) -> tuple[float, float]:
        """The image size ``(width, height)`` in pixels."""
        if self.width is None or self.height is None:
            raise ValueError("the image size is not known")
        return self.width, self.height

    @property
    def centre(self) -> np.ndarray:
        """The principal point ``(u0, v0)`` in pixels (the image centre unless given)."""
        if self.principal_point is not None:
            return np.asarray(self.principal_point, dtype=float)
        if self.width is None or self.height is None:
            raise ValueError("the image size is not known")
        return np.array([self.width / 2, self.height / 2])

    def image_window(self) -> tuple[np.ndarray, np.ndarray]:
        """The image as a box in feature coordinates (about the principal point):
        ``f`` is inside the image iff ``low <= f <= high`` componentwise (per point)."""
        scale = np.array([1.0, 1.0 / self.aspect])
        low = -self.centre * scale
        return low, low + np.array([self.width, self.height]) * scale

    def outside_image(self, f: np.ndarray) -> np.ndarray:
        """Indices of the points whose features ``f`` (2m, about the principal point) lie
        outside the image."""
        low, high = self.image_window()
        xy = np.asarray(f, dtype=float).reshape(-1, 2)
        return np.flatnonzero(np.any((xy < low) | (xy > high), axis=1))

    @property
    def m(self) -> int:
        return self.points.shape[0]

    def point_in_camera(self, g: SE3, i: int) -> Matrix:
        """``p_ci = g p_oi`` (10), or ``pbar_ci = gbar p_oi`` (13)."""
        return g.act(self.points[i])

    def depths(self, g: SE3) -> Matrix:
        """The depths ``z_ci`` of all points: the projection needs them positive."""
        return cs.vertcat(*[self.point_in_camera(g, i)[2] for i in range(self.m)])

    def project(self, g: SE3) -> Matrix:
        """Stacked image features ``f = [f_1; ...; f_m]``, ``f_i = lambda/z [x; y]`` (11), (14)."""
        out = []
        for i in range(self.m):
            p = self.point_in_camera(g, i)
            out.append(self.focal_length / p[2] * p[0:2])
        return cs.vertcat(*out)

    def jacobian(self, gbar: SE3) -> Matrix:
        """Image Jacobian ``J(gbar)`` (19)-(20), of size ``2m x 6``."""
        lam = self.focal_length
        rows = []
        for i in range(self.m):
            x, y, z = cs.vertsplit(self.point_in_camera(gbar, i))
            projection = cs.vertcat(
                cs.horzcat(lam / z, 0, -lam * x / z**2),
                cs.horzcat(0, lam / z, -lam * y / z**2),
            )
            lever = cs.horzcat(cs.DM.eye(3), -hat(self.points[i]))
            rows.append(projection @ gbar.rotation.matrix @ lever)
        return cs.vertcat(*rows)

    def estimation_error(self, f: Matrix, gbar: SE3) -> Matrix:
        """First-order estimation error from the image, ``e_e = pinv(J(gbar)) (f - fbar)`` (21).

        ``J`` has full column rank (m >= 4 generic points), so ``pinv(J) = (J^T J)^-1 J^T``.
        """
        j = self.jacobian(gbar)
        return cs.solve(j.T @ j, j.T @ (f - self.project(gbar)))
