"""The largest motion dry friction can drive in the linearised sampled loop: its peak-to-peak gain
(docs/math.md, fact 29).

Dry friction on joint ``j`` is, whatever its model (Coulomb, smoothed or not, Stribeck, a dynamic model), a
torque ``d_j(t)`` with ``|d_j(t)| <= c_j``; viscous friction ``b qd`` is passive damping and stays in the
linearisation (:meth:`~dvfc.analysis.multirate.HeldLinearization.with_friction` with ``b`` alone). Over the
control period ``k`` the torque moves ``z`` by ``w_k = int_0^h exp(A (h - s)) B_tau d(kh + s) ds``, one more input
of fact 14's multirate map. An output ``y_i`` at a sample is a sum of such inputs through rows ``r``, so the
largest ``|y_i|`` any such torque drives from rest is ``sum_j c_j sum_r int_0^h |r exp(A (h - s)) b_j| ds``
(``b_j`` the column of ``B_tau``), attained by ``d_j = c_j sign(r exp(A (h - s)) b_j)`` period by period.
:func:`friction_bound` computes it over ``L`` equal parts of a period: with ``Gamma_l`` the integral of
``exp(A (h - s)) B_tau`` over part ``l``, the sum of ``|r Gamma_l b_j| c_j`` is attained by a torque constant on
each part (``lower``); a part's integral of ``|g|`` exceeds ``|int g|`` by at most ``delta^2 / 3 sup |g'|``, bounded
from ``g'`` at the part's middle and ``A^2`` (``upper``); the periods after those summed are bounded in a norm
weighted by one period's contribution through each state, by the powers of the monodromy across the self-motion
(fact 29.2). Both are statements about the outputs at the samples of
the loop linearised at its equilibrium (the target at rest, no noise).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from dvfc.analysis.parametric import parameter_vector, symbolic
from dvfc.models.errors import seen_through
from dvfc.models.loop import ClosedLoop

if TYPE_CHECKING:  # the linearised loop's module builds on this one
    from dvfc.analysis.multirate import MultirateLoop, Schedule

SUB_INTERVALS = 4
"""``L``: the parts of a control period on each of which the torque attaining ``lower`` is constant."""

TAIL = 1e-3
"""Common periods are summed until the bound on all later ones is at most this share of the sum."""

MAX_PERIODS = 5000
"""Common periods summed at most (the bound is infinite where the rest is not small by then)."""

TRACKING = ("x", "y", "z", "rx", "ry", "rz")
"""The rows of :func:`tracking_rows`: the tracking error's position (m) and rotation vector (rad)."""


@dataclass(frozen=True)
class FrictionBound:
    """The largest ``|y_i|`` at a sample that dry-friction torques ``|d_j| <= c_j`` drive in the linearised
    sampled loop from rest, per output row (fact 29): ``lower`` is attained by a torque constant on each of
    ``sub_intervals`` parts of a control period, ``upper`` bounds every torque (``inf`` where a row moves along
    the self-motion, which nothing restores, or the sum did not converge); ``periods`` common periods were
    summed and the rest bounded."""

    rows: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    periods: int
    sub_intervals: int


@dataclass(frozen=True)
class PeriodResponse:
    """One common period of fact 14's multirate map with the friction's inputs ``w_k`` (one a control period
    ``k``, added to ``z`` at its end): ``X' = Pi X + sum_k omega[k] w_k`` (``Pi`` the monodromy), and the outputs
    at its samples, ``y_p = g[p] X + sum_(k < p) within[p, k] w_k``."""

    omega: np.ndarray  # (steps, X, nz)
    g: np.ndarray  # (steps, rows, X)
    within: np.ndarray  # (steps, steps, rows, nz), zero where k >= p


def period_response(a_z: np.ndarray, a_e: np.ndarray, c: np.ndarray, sched: Schedule,
                    output: np.ndarray) -> PeriodResponse:  # fmt: skip
    """:class:`PeriodResponse` of the period maps ``(a_z, a_e)``, the images ``c z`` and the schedule ``sched``,
    for the outputs ``output @ z``: the steps of :func:`dvfc.analysis.multirate.monodromy` with the inputs as
    more columns."""
    nz, ne = a_e.shape
    size = nz + ne * (1 + len(sched.pending))
    columns = np.eye(size, size + sched.steps * nz)
    z, e = columns[:nz], columns[nz : nz + ne]
    flight = {p: columns[nz + ne * (i + 1) : nz + ne * (i + 2)] for i, p in enumerate(sched.pending)}
    captures = set(sched.captures)
    outputs = []
    for k in range(sched.steps):
        outputs.append(output @ z)
        if k in captures:
            flight[k] = c @ z
        if k - sched.lag in flight:
            e = flight.pop(k - sched.lag)
        z = a_z @ z + a_e @ e
        z[:, size + k * nz : size + (k + 1) * nz] += np.eye(nz)
    end = np.vstack([z, e, *(flight.pop(p + sched.steps) for p in sched.pending)])
    y = np.array(outputs)
    within = y[:, :, size:].reshape(sched.steps, -1, sched.steps, nz).transpose(0, 2, 1, 3)
    omega = end[:, size:].reshape(size, sched.steps, nz).transpose(1, 0, 2)
    return PeriodResponse(omega, y[:, :, :size], within)


def input_kernel(a: np.ndarray, b: np.ndarray, h: float, parts: int) -> tuple[np.ndarray, np.ndarray]:
    """``Gamma_l`` and ``exp(A (h - s_l)) A B`` for ``l = 0 .. parts - 1`` (each ``(parts, nz, n)``): the integral
    of ``exp(A (h - s)) B`` over the part ``l`` of ``[0, h]``, exactly ``exp(A (h - (l + 1) delta)) int_0^delta
    exp(A s) B ds``, and the derivative of ``exp(A (h - s)) B`` in ``-s`` at the part's middle ``s_l``."""
    import scipy.linalg  # here: a command's imports without it
    nz, n = b.shape
    delta = h / parts
    generator = np.zeros((nz + n, nz + n))
    generator[:nz] = np.hstack([a, b])
    flow = scipy.linalg.expm(generator * delta)[:nz]
    phi, gamma = flow[:, :nz], [flow[:, nz:]]
    slope = [scipy.linalg.expm(a * delta / 2) @ a @ b]
    for _ in range(parts - 1):
        gamma.append(phi @ gamma[-1])
        slope.append(phi @ slope[-1])
    return np.array(gamma[::-1]), np.array(slope[::-1])


def tracking_rows(
    rest: ClosedLoop, state: np.ndarray, mount: np.ndarray | None = None
) -> tuple[np.ndarray, float, float]:
    """The rows of ``z`` (of the loop at rest ``rest``, linearised at ``state``) giving to first order the tracking
    error's motion from its value there: the position of ``g_d^-1 g`` (3, m) and its rotation vector in its own
    frame (3, rad), ``g`` the relative pose of the camera seen through the ``mount`` error (6: ``xyz``, ``rpy``;
    None: none), moved by ``dq``; and that error's position (m) and angle (rad) at ``state``."""
    model = symbolic(rest)
    camera = seen_through(model.relative_pose, cs.DM.zeros(6) if mount is None else cs.DM(mount))
    matrix = (model.reference.inverse() @ camera).as_matrix()
    jacobian = cs.jacobian(cs.vec(matrix[:3, :]), model.state)
    p = [] if model.parameters is None else [model.parameters]
    function = cs.Function("tracking", [model.t, model.state, *p], [matrix, jacobian])
    values = [] if model.parameters is None else [parameter_vector(rest)]
    at, d = (np.asarray(v) for v in function(0.0, state, *values))
    n = rest.robot.n
    d = d[:, :n].reshape(4, 3, n).transpose(1, 0, 2)  # d[row, column, joint] of [R p]
    spin = np.einsum("ij,ikn->jkn", at[:3, :3], d[:, :3])  # R^T dR: skew, its vee the rotation vector
    rows = np.zeros((6, len(state) - 1))  # z has the quaternion's three angles: one entry fewer
    rows[:3, :n] = d[:, 3]
    rows[3:, :n] = np.stack([spin[2, 1], spin[0, 2], spin[1, 0]])
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(at[:3, :3])) - 1) / 2)))
    return rows, float(np.linalg.norm(at[:3, 3])), angle


def friction_bound(system: MultirateLoop, coulomb: np.ndarray, output: np.ndarray, rows: tuple[str, ...],
                   parts: int = SUB_INTERVALS,
                   settled: Callable[[np.ndarray, np.ndarray], bool] | None = None) -> FrictionBound:  # fmt: skip
    """:class:`FrictionBound` of ``system`` (linearised with the viscous friction alone) under dry-friction
    torques ``|d_j| <= coulomb[j]`` at the scenario's schedule, for the outputs ``output @ z`` named ``rows``;
    ``settled(upper, lower)``: whether the bounds so far (each row's, the upper one with the rest of the sum, the
    lower one of the periods summed) already settle the caller's question, which stops the sum there (its
    ``upper`` and ``lower`` are then those bounds)."""
    import scipy.linalg  # here: a command's imports without it
    imp, lin = system.implementation, system.lin
    h, delta = imp.period, imp.period / parts
    pi, sched = system.monodromy(imp)
    response = period_response(*lin.period_map(h), system.output, sched, output)
    coulomb = np.asarray(coulomb, dtype=float)
    gamma, slope = input_kernel(lin.a, lin.b_tau, h, parts)
    # a part's int |g| <= |int g| + delta^2 / 3 sup |g'|, sup |g'| <= |g'(s_l)| + delta / 2 ||r|| e^(mu h) ||A^2 B c||
    kernel = np.concatenate([gamma, delta**2 / 3 * slope], axis=2) * np.tile(coulomb, 2)  # (L, nz, 2n)
    kernel = kernel.transpose(1, 0, 2).reshape(len(lin.a), -1)
    halves = np.kron(np.ones((parts, 1)), np.kron(np.eye(2), np.ones((len(coulomb), 1))))  # (L 2n, 2): the sums
    growth = math.exp(max(0.0, float(np.linalg.eigvalsh((lin.a + lin.a.T) / 2)[-1])) * h)  # >= ||exp(A s)||
    second = h * delta**2 / 6 * growth * float(np.linalg.norm(lin.a @ lin.a @ lin.b_tau, axis=0) @ coulomb)

    def summed(terms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the rows ``terms`` (``(phases, rows, inputs, nz)``) through which inputs ``w`` reach the outputs:
        per phase and output, the sum of ``|r Gamma_l b_j| c_j`` and the bound on its excess."""
        values = (np.abs(terms @ kernel) @ halves).sum(axis=2)  # summed over the parts and joints by a product
        return values[..., 0], values[..., 1] + np.linalg.norm(terms, axis=-1).sum(axis=2) * second

    steps, nz = sched.steps, len(lin.a)
    earlier = np.tril(np.ones((steps, steps)), -1)[:, None, :, None]  # within[p, k] counts for k < p
    lower, excess = summed(response.within.transpose(0, 2, 1, 3) * earlier)
    upper = lower + excess
    tangent = system.tangent(pi)
    moving = np.abs(response.g @ tangent).max(axis=(0, 2), initial=0.0) > 1e-9 * np.abs(response.g).max()
    basis = scipy.linalg.null_space(tangent.T) if tangent.shape[1] else np.eye(len(pi))
    omega = response.omega.transpose(1, 0, 2).reshape(len(pi), steps * nz)  # (X, steps nz)

    def contribution(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One period's inputs through the state rows ``v`` (``(phases, rows, X)``): per phase and row the lower
        sum and its excess, each a seminorm of ``v``."""
        return summed((v @ omega).reshape(*v.shape[:2], steps, nz))

    # A row v with v T = 0 is (v Q) Q^T: its contribution is at most |v Q| @ weights (the triangle inequality)
    low, more = contribution(basis.T[None])
    weights = (low + more)[0]
    weights = weights + 1e-9 * weights.max()
    gain = _power_gain(basis.T @ pi @ basis, weights)
    g, periods = response.g, 0
    while True:
        low, more = contribution(g)
        lower, upper = lower + low, upper + low + more
        periods += 1
        g = g @ pi
        tail = (np.abs(g @ basis) @ weights * gain).max(axis=0)
        if np.all(tail <= TAIL * lower.max(axis=0)) or periods >= MAX_PERIODS or not math.isfinite(gain):
            break
        if settled is not None and not moving.any() and settled(upper.max(axis=0) + tail, lower.max(axis=0)):
            break
    bounded = np.isfinite(tail) & ~moving  # upper + tail bounds the sum wherever the tail is finite
    return FrictionBound(rows, lower.max(axis=0), np.where(bounded, upper.max(axis=0) + tail, math.inf), periods,
                         parts)  # fmt: skip


def _power_gain(pi: np.ndarray, weights: np.ndarray) -> float:
    """A bound on ``sum_m ||y pi^m||_w / ||y||_w`` for the row norm ``||y||_w = |y| @ weights``: its induced norm
    ``mu(A) = max_s sum_t |A_st| w_t / w_s``, ``K`` the first power with ``theta = mu(pi^K) <= 1/2``, and
    ``sum_(m < K) mu(pi^m) / (1 - theta)`` (``mu`` is submultiplicative); ``inf`` where no power up to
    :data:`MAX_PERIODS` is that small."""
    power, total = np.eye(len(pi)), 0.0
    for _ in range(MAX_PERIODS):
        norm = float((np.abs(power) @ weights / weights).max())
        if norm <= 0.5 and total > 0:
            return total / (1 - norm)
        total += norm
        power = power @ pi
    return math.inf


def at_rest(upper: np.ndarray, position: float, angle: float) -> tuple[float, float]:
    """The largest tracking position error (m) and angle (deg) at rest: the equilibrium's ``position`` (m) and
    ``angle`` (rad) plus the norms of the bounds ``upper`` on :data:`TRACKING` (each component bounded, so the norm
    of the bounds bounds the norm; angles add along a product of rotations)."""
    return position + float(np.linalg.norm(upper[:3])), math.degrees(angle + float(np.linalg.norm(upper[3:])))


@dataclass(frozen=True)
class DryFrictionCheck:
    """Fact 29 for a plant's tracking error at rest: the motion its dry friction (``coulomb``, N m a joint) can
    drive (``bound``, on :data:`TRACKING`), added to the tracking error at the equilibrium (``offset_position``,
    m, and ``offset_angle``, rad), against a ``criterion`` (position m, angle deg; None: none given)."""

    coulomb: np.ndarray
    bound: FrictionBound
    offset_position: float
    offset_angle: float
    criterion: tuple[float, float] | None = None

    @property
    def position(self) -> float:
        """The tracking position error at rest it states (m, :func:`at_rest`): from the upper bounds, or where no
        finer sum can bring it within the criterion (:attr:`beyond`), from the attained ones."""
        return at_rest(self._stated, self.offset_position, self.offset_angle)[0]

    @property
    def angle_deg(self) -> float:
        """The tracking angle at rest it states (deg), as :attr:`position`."""
        return at_rest(self._stated, self.offset_position, self.offset_angle)[1]

    @property
    def _stated(self) -> np.ndarray:
        return self.bound.lower if self.beyond else self.bound.upper

    @property
    def within(self) -> bool | None:
        """Whether the error at rest from the upper bounds stays within the criterion (None: no criterion)."""
        upper = at_rest(self.bound.upper, self.offset_position, self.offset_angle)
        return None if self.criterion is None else _within(*upper, self.criterion)

    @property
    def beyond(self) -> bool:
        """Whether no finer sum can bring the check within the criterion: the error at rest computed from the
        attained bounds ``lower`` is already beyond it (every upper bound is at least ``lower``)."""
        lower = at_rest(self.bound.lower, self.offset_position, self.offset_angle)
        return self.criterion is not None and not _within(*lower, self.criterion)

    def words(self) -> str:
        """The statement in words."""
        levels = ", ".join(f"{c:g}" for c in self.coulomb)
        held = f"{self.position * 1e3:.4g} mm and {self.angle_deg:.4g} deg"
        text = f"dry friction up to {levels} N m (fact 29: a torque bounded by its Coulomb level, no smoothing) "
        scope = "the equilibrium's own error included; linearised"
        if self.criterion is None:
            return text + f"can hold the tracking error at rest at up to {held} ({scope})"
        criterion = f"the criterion's {self.criterion[0] * 1e3:.4g} mm and {self.criterion[1]:.4g} deg"
        if self.beyond:
            return (text + f"holds the tracking error at rest beyond {criterion} whatever the sum's resolution (its "
                    f"attained bounds give {held}; {scope})")
        return (text + f"can hold the tracking error at rest at up to {held} ({scope}), "
                f"{'within' if self.within else 'beyond'} {criterion}")

    def as_dict(self) -> dict:
        """JSON-ready."""
        return {"coulomb": self.coulomb.tolist(), "position": self.position, "angle_deg": self.angle_deg,
                "rows": list(self.bound.rows), "upper": self.bound.upper.tolist(),
                "lower": self.bound.lower.tolist(), "periods": self.bound.periods,
                "sub_intervals": self.bound.sub_intervals,
                "criterion": None if self.criterion is None else list(self.criterion), "within": self.within,
                "statement": self.words()}  # fmt: skip


def _within(position: float, angle_deg: float, criterion: tuple[float, float]) -> bool:
    return position <= criterion[0] and angle_deg <= criterion[1]


def dry_friction_check(
    system: MultirateLoop, rest: ClosedLoop, state: np.ndarray, coulomb: np.ndarray, mount: np.ndarray | None,
    criterion: tuple[float, float] | None, tight: bool = False,
) -> DryFrictionCheck:
    """:class:`DryFrictionCheck` of ``system`` (linearised at ``state`` of the loop at rest ``rest``, with the
    plant's viscous friction alone): the bound summed until it settles ``criterion`` (within it; ``tight``: until
    it converges whatever the criterion) or converges, with :data:`SUB_INTERVALS` parts of a period, and where the
    upper bound is beyond the criterion (and the lower one does not rule it out) with 4 times as many, so that only
    a criterion within the gap between the bounds then is left undecided (not certified)."""
    rows, position, angle = tracking_rows(rest, state, mount)
    levels = np.asarray(coulomb, dtype=float)
    settled = None
    if criterion is not None and not tight:
        def settled(upper: np.ndarray, lower: np.ndarray) -> bool:  # within, or no finer sum can be
            return _within(*at_rest(upper, position, angle), criterion) or not _within(
                *at_rest(lower, position, angle), criterion)

    for parts in (SUB_INTERVALS, 4 * SUB_INTERVALS):
        check = DryFrictionCheck(levels, friction_bound(system, levels, rows, TRACKING, parts, settled), position,
                                 angle, criterion)  # fmt: skip
        if check.within is not False or check.beyond:
            break
    return check
