"""A start configuration from the scenario itself (``[robot] q0 = "auto"``): inverse kinematics
by CasADi's bundled IPOPT for the camera at the reference pose relative to the target, within
the URDF's position limits, the best-conditioned such configuration found.

The camera's goal is ``g_wc* = g_wo(0) g_d^-1``. The constraints are its position and the
rotation error's axis times ``sin(theta)``, ``(R*^T R - R^T R*)^vee / 2 = 0``, with
``trace(R*^T R) >= 0`` ruling out the half-turn that also zeroes it. The objective is
``-log det(J_b J_b^T)`` (``J_b^T J_b`` when ``n < 6``), a smooth surrogate of the smallest
singular value of ``J_b``. From each of several starts drawn inside the limits a least-squares
solve first brings the camera near the goal, then the constrained one conditions it; the largest
``sigma_min`` is kept among the solutions that reach the goal.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from dvfc.analysis.quiet import silenced
from dvfc.models.robot import Robot

LIMIT_MARGIN = 0.02
"""Radians kept between a solution and each position limit (a run from q0 then starts inside)."""

REACHED = 1e-9
"""Largest position (m) and rotation (rad) error at which a solution reaches the goal."""

STARTS = 12
"""Starting points of the search (the first at the middle of the limits)."""


class NoConfigurationError(ValueError):
    """No configuration within the limits puts the camera at its goal (the message says how close)."""


@dataclass(frozen=True)
class Configuration:
    """A solution: joint angles ``q`` (rad), the smallest singular value and the condition number
    of ``J_b`` there, and the pose errors left (m, rad)."""

    q: np.ndarray
    sigma_min: float
    condition: float
    position_error: float
    rotation_error: float


def _bounds(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The position limits narrowed by :data:`LIMIT_MARGIN` (``[-pi, pi]`` where there are none)."""
    lower = np.where(np.isfinite(robot.limits.lower), robot.limits.lower, -np.pi)
    upper = np.where(np.isfinite(robot.limits.upper), robot.limits.upper, np.pi)
    margin = np.minimum(LIMIT_MARGIN, (upper - lower) / 4)
    return lower + margin, upper - margin


def solve_configuration(robot: Robot, goal: np.ndarray, seed: int = 0) -> Configuration:
    """The best-conditioned configuration found that puts the camera at the 4x4 pose ``goal``.

    Raises
    ------
    NoConfigurationError
        No start reached the goal within the limits.
    """
    q, n = robot.q, robot.n
    g = robot.camera_pose.as_matrix()
    error = cs.DM(goal[:3, :3]).T @ g[:3, :3]
    axis = cs.vertcat(error[2, 1] - error[1, 2], error[0, 2] - error[2, 0], error[1, 0] - error[0, 1]) / 2
    jac = robot.body_jacobian
    gram = jac @ jac.T if n >= 6 else jac.T @ jac
    constraints = cs.vertcat(g[:3, 3] - cs.DM(goal[:3, 3]), axis, cs.trace(error))
    nlp = {"x": q, "f": -cs.log(cs.det(gram)), "g": constraints}
    options = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10,
               "ipopt.constr_viol_tol": 1e-12, "ipopt.max_iter": 300, "error_on_fail": False}  # fmt: skip
    lower, upper = _bounds(robot)
    lbg, ubg = np.zeros(7), np.r_[np.zeros(6), np.inf]
    angle = cs.atan2(cs.norm_2(axis), (cs.trace(error) - 1) / 2)  # exact near 0, unlike acos
    measure = cs.Function("measure", [q], [g, angle, jac])
    rng = np.random.default_rng(seed)
    starts = [(lower + upper) / 2, *rng.uniform(lower, upper, size=(STARTS - 1, n))]
    best: Configuration | None = None
    closest = np.inf
    reach = {"x": q, "f": cs.sumsqr(constraints[:6]) + cs.fmax(0, -constraints[6]) ** 2}
    with silenced():
        solver = cs.nlpsol("ik", "ipopt", nlp, options)
        approach = cs.nlpsol("reach", "ipopt", reach, options)  # first near the goal, then conditioned
        for start in starts:
            near = approach(x0=start, lbx=lower, ubx=upper)["x"]
            x = np.clip(np.asarray(solver(x0=near, lbx=lower, ubx=upper, lbg=lbg, ubg=ubg)["x"]).ravel(), lower, upper)
            pose, rotation, jb = (np.asarray(v) for v in measure(x))
            position, rotation = float(np.linalg.norm(pose[:3, 3] - goal[:3, 3])), rotation.item()
            closest = min(closest, max(position, rotation))
            if max(position, rotation) > REACHED:
                continue
            s = np.linalg.svd(jb, compute_uv=False)
            if best is None or s[-1] > best.sigma_min:
                best = Configuration(x, float(s[-1]), float(s[0] / s[-1]), position, rotation)
    if best is None:
        raise NoConfigurationError(
            f"no configuration within the position limits puts the camera at the reference pose relative to the "
            f"target (closest of {STARTS} starts: {closest:.3g} m or rad away)"
        )
    return best
