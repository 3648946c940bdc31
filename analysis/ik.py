"""A start configuration from the scenario itself (``[robot] q0 = "auto"``): inverse kinematics
for the camera at the reference pose relative to the target, within the URDF's position
limits, the best-conditioned such configuration found.

The camera's goal is ``g_wc* = g_wo(0) g_d^-1``. The search has three stages.

1. Reach, from many starts: bounded least squares (``scipy.optimize.least_squares``, trust
   region reflective, the CasADi Jacobian) on the residual ``r(q) = [p - p*; vec(R - R*) / 2]``,
   zero only at the goal (``|R - R*|_F^2 = 8 sin^2(theta / 2)``: no spurious half-turn). The
   starts: the middle of the limits, then a scrambled Sobol sample of the whole box of limits
   (seeded, so the search is deterministic), in that order, until :data:`SOLUTIONS` distinct
   solutions are found or :data:`STARTS` starts are spent.
2. When no start reaches the goal, a global search: ``|r(q)|^2`` evaluated at
   :data:`SCREENED` further Sobol points of the box (one vectorised CasADi call), then the same
   least squares from the :data:`GLOBAL_STARTS` lowest of them.
3. Each solution is conditioned by CasADi's bundled IPOPT: the objective ``-log det(J_b J_b^T)``
   (``J_b^T J_b`` when ``n < 6``), a smooth surrogate of the smallest singular value of
   ``J_b``, subject to the camera's position and the rotation error's axis times
   ``sin(theta)``, ``(R*^T R - R^T R*)^vee / 2 = 0``, with ``trace(R*^T R) >= 0`` ruling out
   the half-turn that also zeroes it; the largest ``sigma_min`` is kept among the solutions
   that reach the goal.

A joint without position limits (a continuous joint) is searched over ``[-pi, pi]``, every angle
it can take; the others over their limits narrowed by :data:`LIMIT_MARGIN` (:func:`_bounds`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as cs
import numpy as np

from dvfc.analysis.quiet import silenced
from dvfc.models.robot import Robot

LIMIT_MARGIN = 0.02
"""Radians kept between a solution and each position limit (a run from q0 then starts inside)."""

REACHED = 1e-9
"""Largest position (m) and rotation (rad) error at which a solution reaches the goal."""

NEAR = 1e-6
"""Largest error (m, rad) of a least-squares solution handed to the conditioning solve."""

STARTS = 1 + 2**5
"""Starting points of the local search at most: the middle of the limits and a Sobol sample."""

SOLUTIONS = 4
"""Distinct solutions after which the local search stops (the best-conditioned is kept)."""

SCREENED = 2**12
"""Sobol points of the box at which the global search evaluates the residual."""

GLOBAL_STARTS = 32
"""Starts of the global search's least squares: the screened points of lowest residual."""


class NoConfigurationError(ValueError):
    """No configuration within the limits puts the camera at its goal: the message gives the
    closest one found, its position and rotation errors (``closest``)."""

    def __init__(self, message: str, closest: Configuration) -> None:
        super().__init__(message)
        self.closest = closest


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
    """The position limits narrowed by :data:`LIMIT_MARGIN`; a side without a limit is a full turn
    from the other side's limit, or ``-pi``/``pi`` where there is neither (every angle)."""
    low, high = robot.limits.lower, robot.limits.upper
    finite_low, finite_high = np.isfinite(low), np.isfinite(high)
    lower = np.where(finite_low, low, np.where(finite_high, high - 2 * np.pi, -np.pi))
    upper = np.where(finite_high, high, np.where(finite_low, low + 2 * np.pi, np.pi))
    margin = np.minimum(LIMIT_MARGIN, (upper - lower) / 4)
    return lower + np.where(finite_low, margin, 0.0), upper - np.where(finite_high, margin, 0.0)


def sobol(lower: np.ndarray, upper: np.ndarray, size: int, seed: int) -> np.ndarray:
    """``size`` (a power of 2) points of a scrambled Sobol sequence in the box ``[lower, upper]``."""
    from scipy.stats import qmc

    sample = qmc.Sobol(lower.size, scramble=True, seed=seed).random_base2(int(np.log2(size)))
    return qmc.scale(sample, lower, upper)


class _Search:
    """The residual of the goal, its Jacobian and the errors (m, rad) of a configuration."""

    def __init__(self, robot: Robot, goal: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        q = robot.q
        g = robot.camera_pose.as_matrix()
        residual = cs.vertcat(g[:3, 3] - cs.DM(goal[:3, 3]), cs.vec(g[:3, :3] - cs.DM(goal[:3, :3])) / 2)
        error = cs.DM(goal[:3, :3]).T @ g[:3, :3]
        axis = cs.vertcat(error[2, 1] - error[1, 2], error[0, 2] - error[2, 0], error[1, 0] - error[0, 1]) / 2
        angle = cs.atan2(cs.norm_2(axis), (cs.trace(error) - 1) / 2)  # exact near 0, unlike acos
        self.lower, self.upper = lower, upper
        self._residual = cs.Function("residual", [q], [residual, cs.jacobian(residual, q)])
        self._cost = cs.Function("cost", [q], [cs.sumsqr(residual)])
        self._errors = cs.Function("errors", [q], [cs.norm_2(g[:3, 3] - cs.DM(goal[:3, 3])), angle])
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residual and its Jacobian at ``q`` (both from one evaluation: least squares asks
        for them in turn at the same point)."""
        if self._last is None or not np.array_equal(self._last[0], q):
            r, jac = self._residual(q)
            self._last = (np.array(q, dtype=float), np.asarray(r).ravel(), np.asarray(jac))
        return self._last[1], self._last[2]

    def residual(self, q: np.ndarray) -> np.ndarray:
        return self._at(q)[0]

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        return self._at(q)[1]

    def cost(self, q: np.ndarray) -> np.ndarray:
        """``|r(q)|^2`` at each column of ``q`` (n x k)."""
        return np.asarray(self._cost.map(q.shape[1])(q)).ravel()

    def errors(self, q: np.ndarray) -> tuple[float, float]:
        position, rotation = self._errors(q)
        return float(position), float(rotation)

    def reach(self, start: np.ndarray) -> np.ndarray:
        """Bounded least squares from ``start`` (inside the box)."""
        from scipy.optimize import least_squares

        x0 = np.clip(start, self.lower, self.upper)
        fit = least_squares(self.residual, x0, self.jacobian, bounds=(self.lower, self.upper), method="trf",
                            xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100)  # fmt: skip
        return np.clip(fit.x, self.lower, self.upper)

    def screened(self, seed: int) -> np.ndarray:
        """The global search's starts: of :data:`SCREENED` Sobol points, the
        :data:`GLOBAL_STARTS` of lowest residual, lowest first."""
        points = sobol(self.lower, self.upper, SCREENED, seed)
        return points[np.argsort(self.cost(points.T), kind="stable")[:GLOBAL_STARTS]]


def solve_configuration(robot: Robot, goal: np.ndarray, seed: int = 0) -> Configuration:
    """The best-conditioned configuration found that puts the camera at the 4x4 pose ``goal``.

    Raises
    ------
    NoConfigurationError
        Neither the local starts nor the global search reached the goal within the limits.
    """
    lower, upper = _bounds(robot)
    search = _Search(robot, goal, lower, upper)
    local = np.vstack([(lower + upper) / 2, sobol(lower, upper, STARTS - 1, seed)])
    found: list[np.ndarray] = []
    closest = lower
    for stage in (local, None):  # None: the global search, only when the local one found nothing
        for start in search.screened(seed + 1) if stage is None else stage:
            x = search.reach(start)
            if search.cost(x[:, None])[0] < search.cost(closest[:, None])[0]:
                closest = x
            if max(search.errors(x)) <= NEAR and not any(np.allclose(x, y, atol=1e-6) for y in found):
                found.append(x)
                if len(found) == SOLUTIONS:
                    break
        if found:
            break
    best = _best_conditioned(robot, goal, search, found)
    if best is not None:
        best = replace(best, q=nearest_turn(best.q, robot.limits.lower, robot.limits.upper))
    if best is None:
        position, rotation = search.errors(closest)
        raise NoConfigurationError(
            "no configuration within the position limits puts the camera at the reference pose relative to the "
            f"target: the closest found ({STARTS} starts, then {GLOBAL_STARTS} of {SCREENED} screened) is "
            f"{position:.3g} m and {rotation:.3g} rad away, at q = [{', '.join(f'{v:.4g}' for v in closest)}]",
            _configuration(robot, closest, position, rotation),
        )
    return best


def nearest_turn(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Each joint angle moved by whole turns (the same pose: every joint is revolute) to the value
    within its limits nearest the middle of its range (0 where a side is unlimited), so that a start
    does not sit a turn away from where the joint has room on both sides."""
    finite = np.isfinite(lower) & np.isfinite(upper)
    middle = np.where(finite, (np.where(finite, lower, 0.0) + np.where(finite, upper, 0.0)) / 2, 0.0)
    moved = q + 2 * np.pi * np.round((middle - q) / (2 * np.pi))
    inside = (moved >= lower) & (moved <= upper)
    return np.where(inside, moved, q)


def _configuration(robot: Robot, q: np.ndarray, position: float, rotation: float) -> Configuration:
    s = np.linalg.svd(np.asarray(cs.Function("jb", [robot.q], [robot.body_jacobian])(q)), compute_uv=False)
    return Configuration(q, float(s[-1]), float(s[0] / s[-1]), position, rotation)


def _best_conditioned(robot: Robot, goal: np.ndarray, search: _Search, found: list[np.ndarray]) -> Configuration | None:
    """Each solution conditioned (IPOPT, the module's stage 3); the largest ``sigma_min`` of those
    that reach the goal within :data:`REACHED`, or None."""
    if not found:
        return None
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
    lbg, ubg = np.zeros(7), np.r_[np.zeros(6), np.inf]
    best: Configuration | None = None
    with silenced():
        solver = cs.nlpsol("ik", "ipopt", nlp, options)
        for near in found:
            solved = solver(x0=near, lbx=search.lower, ubx=search.upper, lbg=lbg, ubg=ubg)["x"]
            x = np.clip(np.asarray(solved).ravel(), search.lower, search.upper)
            # the least-squares solution itself when conditioning loses the goal
            y = next((y for y in (x, near) if max(search.errors(y)) <= REACHED), None)
            if y is not None:
                c = _configuration(robot, y, *search.errors(y))
                if best is None or c.sigma_min > best.sigma_min:
                    best = c
    return best
