"""Gain synthesis (MATH fact 6): for fixed ``W_c, W_e, g_d``, ``N`` does not depend on
``K``, so ``P = N^T diag(k) N - I/2 - s W`` is linear in ``(k, s)`` and choosing the gains
that minimise the certified gamma under bounds is an SDP.

The decision variables are ``K_xi`` (n entries), ``K_c`` (6) and a block-isotropic
``K_e = diag(k_ep I3, k_er I3)``, which keeps the certificate exact for every rotation
(fact 2). Two problems:

- ``maximize s`` (``gamma = 1/sqrt(2 s)``) subject to ``P(k, s) >= 0`` and the bounds;
- with a target ``gamma_t``: ``minimize |k|_2`` subject to ``P(k, 1/(2 gamma_t^2)) >= 0``.

The result is handed to the ordinary certifier (closed form, SDP cross-check, a
posteriori eigenvalue check): the synthesised gamma is the certifier's, not the solver's.
Optionally the weights are searched on a log grid around the scenario's (outer loop).

For the operating envelope (MATH facts 7-8) the objective is the certified target speed
instead (:func:`synthesize_speed`): at fixed ``s = 1/(2 gamma'^2)`` and ``theta_bar``, ``D``
does not depend on the gains and ``Q(s) = N^T K N - s W`` is linear in them, so
``maximize kappa`` subject to ``Q(s) - kappa D >= 0`` (and the ``xi`` block) is one SDP; the
largest certified ``wbar^2`` is ``min(c_max, c_vis) 4 s kappa`` with ``c_max`` and ``c_vis``
independent of the gains, so ``s kappa*(s)`` is maximised over ``s`` by golden section.

Neither certificate says anything about the arm's limits: large gains ask for large torques.
:func:`search_within_limits` looks, in a one-parameter family of shrunken gain boxes, for the
best design whose run as implemented stays within the URDF's effort and velocity limits
(measured by simulation; the certificate of the design found is the ordinary one).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import cvxpy as cp
import numpy as np
import tomlkit

from dvfc.analysis.certify import Certificate, GainPoint, certify, estimation_scale, output_blocks, solve
from dvfc.analysis.envelope import GOLDEN_STEPS, design_of, golden_max, pose_diagonal, s_limit
from dvfc.models.inertia import MassBounds
from dvfc.models.lie import SE3
from dvfc.models.loop import PlantWeights, Weights

TARGET_MARGIN = 1e-4
"""Relative margin below a gamma target that the synthesis aims at."""

SEARCH_STEPS = 6
"""Bisection steps of the limits search after its two ends: a bracket of 1/64 of the family."""
FEASIBLE_STEPS = 10
"""Bisection steps (SDPs only, no runs) locating the family's smallest alpha with a certified
design: to 1/1024."""
FAMILY = (
    "the synthesis over the gain boxes [lower, upper(alpha)], upper(alpha) = lower (upper / lower)^alpha for "
    "every gain (alpha = 1: the [synthesize] bounds)"
)
LIMITS_CRITERION = (
    "the run as implemented (the scenario's [implementation] and [plant], else the continuous loop) "
    "completes with every feature in the image, the law's commanded |tau| stays within the effort "
    "limits (times torque_scale; commanded also with saturate on: a design whose law saturates does "
    "not run the loop its certificate is about) and |qd| within the velocity limits on every joint, "
    "along the run"
)


@dataclass(frozen=True)
class Bounds:
    """Lower and upper bounds of each gain (positive); ``k_xi``'s per joint (arrays of ``n``) or
    one pair for every joint."""

    k_xi: tuple[np.ndarray | float, np.ndarray | float]
    k_c: tuple[float, float]
    k_e: tuple[float, float]

    def as_dict(self) -> dict:
        """JSON-ready: ``k_xi`` as ``[lower, upper]`` per joint (one pair when one for all)."""
        k_xi = np.column_stack(np.broadcast_arrays(*self.k_xi)).tolist()
        return {"k_xi": k_xi, "k_c": [float(b) for b in self.k_c], "k_e": [float(b) for b in self.k_e]}


@dataclass
class Synthesis:
    point: GainPoint | None
    certificate: Certificate | None
    status: str
    weights_tried: int = 1


def _sdp(weights: Weights, reference: SE3, n: int, bounds: Bounds, gamma_target: float | None,
         plant: PlantWeights | None):
    """Solve the fact-6 SDP for fixed weights (and the generalized plant's, fact 17); returns
    ``(k_xi, k_c, k_e)`` or None."""  # fmt: skip
    w = weights.as_array()[None]
    n_ce = output_blocks(w, reference, np.eye(3)[None])[0]
    k_xi, k_c = cp.Variable(n), cp.Variable(6)
    k_ep, k_er = cp.Variable(), cp.Variable()
    k_ce = cp.hstack([k_c, k_ep, k_ep, k_ep, k_er, k_er, k_er])
    weighted = GainPoint(np.ones(n), np.ones(6), np.ones(6), weights, plant)
    s2, d_w = weighted.output_squared, weighted.disturbance_weights
    w_ce = np.diag(np.r_[np.zeros(6), estimation_scale(weighted) ** 2])
    a_ce = n_ce.T @ cp.diag(k_ce) @ n_ce - 0.5 * np.diag(s2[n:])
    # aim slightly below the target: the certifier inflates gamma by 1e-6 and the solver's
    # optimum is accurate to ~1e-8, so a 1e-4 margin keeps the certified gamma <= target
    s = cp.Variable() if gamma_target is None else 1.0 / (2 * (gamma_target / (1 + TARGET_MARGIN)) ** 2)
    constraints = [
        (a_ce - s * w_ce + (a_ce - s * w_ce).T) / 2 >> 0,
        k_xi - 0.5 * s2[:n] - s * d_w[:n] ** 2 >= 0,  # the xi block: K_xi - S_xi^2/2 - s D_tau^2 >= 0
        k_xi >= bounds.k_xi[0], k_xi <= bounds.k_xi[1],
        k_c >= bounds.k_c[0], k_c <= bounds.k_c[1],
        cp.hstack([k_ep, k_er]) >= bounds.k_e[0], cp.hstack([k_ep, k_er]) <= bounds.k_e[1],
    ]  # fmt: skip
    objective = cp.Maximize(s) if gamma_target is None else cp.Minimize(cp.norm(cp.hstack([k_xi, k_ce])))
    problem = cp.Problem(objective, constraints)
    if solve(problem)[0] is None:
        return None
    return _clipped(bounds, k_xi, k_c, k_ep, k_er)


def _clipped(bounds: Bounds, k_xi: cp.Variable, k_c: cp.Variable, k_ep: cp.Variable, k_er: cp.Variable):
    """The solved gains ``(K_xi, K_c, K_e)`` clipped to ``bounds`` (the solver's round-off can
    step outside them)."""
    clip = lambda v, b: np.clip(np.asarray(v, dtype=float), *b)  # noqa: E731
    k_e = np.repeat([float(k_ep.value), float(k_er.value)], 3)
    return clip(k_xi.value, bounds.k_xi), clip(k_c.value, bounds.k_c), clip(k_e, bounds.k_e)


def synthesize(
    weights: Weights,
    reference: SE3,
    n: int,
    bounds: Bounds,
    *,
    gamma_target: float | None = None,
    search_weights: bool = False,
    theta_max: float = math.pi,
    plant: PlantWeights | None = None,
) -> Synthesis:
    """Gains within ``bounds`` minimising the certified gamma (or, with ``gamma_target``,
    the smallest gain norm reaching it), certified a posteriori over the rotations
    ``|theta_ec| <= theta_max`` (the ``[certify]`` region), for the generalized plant ``plant``
    (docs/math.md, fact 17; None: the paper's)."""
    candidates = [weights]
    if search_weights:
        scales = (0.25, 0.5, 1.0, 2.0, 4.0)
        base = weights.as_array()
        candidates = [Weights(*(base * np.array(c))) for c in itertools.product(scales, repeat=4)]
    best: Synthesis = Synthesis(None, None, "infeasible: no gains within the bounds certify", len(candidates))
    for w in candidates:
        gains = _sdp(w, reference, n, bounds, gamma_target, plant)
        if gains is None:
            continue
        point = GainPoint(*gains, w, plant)
        cert = certify(point, reference, theta_max=theta_max, gamma_bound=gamma_target)
        if not cert.certified:
            continue
        better = best.certificate is None or (
            cert.gamma < best.certificate.gamma
            if gamma_target is None
            else np.linalg.norm(np.r_[point.k_xi, point.k_c, point.k_e])
            < np.linalg.norm(np.r_[best.point.k_xi, best.point.k_c, best.point.k_e])
        )
        if better:
            best = Synthesis(point, cert, "ok", len(candidates))
    return best


def _speed_problem(weights: Weights, reference: SE3, n: int, bounds: Bounds, mass: MassBounds, theta_bar: float):
    """The fact-7 SDP at a parameter ``s``: ``maximize kappa`` subject to
    ``N^T K N - s W - kappa D_ce >= 0`` on ``(e_c, e_e)``, ``diag(k_xi - s) - (kappa/2) B >= 0`` (the
    decoupled ``xi`` block: equivalent, for ``k_xi > s``, to ``kappa <= 2 / rho(diag(k_xi - s)^-1 B)``,
    the rate of (10.4), docs/math.md, fact 10, since ``rho`` is ``lambda_max`` of the symmetric
    ``(K_xi - s)^-1/2 B (K_xi - s)^-1/2``) and the gain bounds. Returns ``(problem, s, kappa, gains)``."""
    w = weights.as_array()[None]
    n_ce = output_blocks(w, reference, np.eye(3)[None])[0]
    k_xi, k_c = cp.Variable(n), cp.Variable(6)
    k_ep, k_er = cp.Variable(), cp.Variable()
    kappa, s = cp.Variable(), cp.Parameter(nonneg=True)
    k_ce = cp.hstack([k_c, k_ep, k_ep, k_ep, k_er, k_er, k_er])
    w_ce = np.diag(np.r_[np.zeros(6), np.repeat([weights.w_pe**2, weights.w_re**2], 3)])
    d_ce = np.diag(pose_diagonal(w[0], theta_bar, True, 6)[0])
    q_ce = n_ce.T @ cp.diag(k_ce) @ n_ce - s * w_ce - kappa * d_ce
    q_xi = cp.diag(k_xi) - s * np.eye(n) - kappa * (mass.upper / 2)
    constraints = [
        (q_ce + q_ce.T) / 2 >> 0,
        (q_xi + q_xi.T) / 2 >> 0,
        k_xi >= bounds.k_xi[0], k_xi <= bounds.k_xi[1],
        k_c >= bounds.k_c[0], k_c <= bounds.k_c[1],
        cp.hstack([k_ep, k_er]) >= bounds.k_e[0], cp.hstack([k_ep, k_er]) <= bounds.k_e[1],
    ]  # fmt: skip
    return cp.Problem(cp.Maximize(kappa), constraints), s, kappa, (k_xi, k_c, k_ep, k_er)


def synthesize_speed(
    weights: Weights,
    reference: SE3,
    n: int,
    bounds: Bounds,
    mass: MassBounds,
    theta_bar: float,
    *,
    theta_max: float = math.pi,
    plant: PlantWeights | None = None,
) -> Synthesis:
    """Gains within ``bounds`` maximising the certified target speed of the envelope at
    ``theta_bar`` (radians; MATH facts 7-8): ``max over s of s kappa*(s)``, ``kappa*(s)`` the
    SDP of :func:`_speed_problem`.

    ``kappa*`` is concave in ``s`` (the value of a convex program whose constraints are jointly
    linear in ``(s, gains, kappa)``), so ``log(s kappa*)`` is concave and its maximum lies in
    ``[s_top/2, s_top]`` (the tangent argument of :func:`dvfc.analysis.envelope.best_s`), ``s_top``
    the largest ``s`` with a positive rate: that of the upper gains, since ``N^T K N`` grows
    with every gain. The result carries the ordinary Theorem 2 certificate over
    ``|theta_ec| <= theta_max`` for ``plant`` (the envelope itself does not depend on the
    generalized plant's weights); its envelope is computed by the ordinary route by the caller."""
    upper = GainPoint(np.broadcast_to(bounds.k_xi[1], n), np.full(6, bounds.k_c[1]), np.full(6, bounds.k_e[1]), weights)
    top = s_limit(design_of(upper, reference, mass))
    failed = Synthesis(None, None, "infeasible: no gains within the bounds give a positive decay rate")
    if top <= 0:
        return failed
    problem, s, kappa, (k_xi, k_c, k_ep, k_er) = _speed_problem(weights, reference, n, bounds, mass, theta_bar)

    def value(x: float) -> float:
        s.value = x
        solved = solve(problem)[0] is not None and kappa.value is not None
        return x * float(kappa.value) if solved else -math.inf

    best = float(golden_max(lambda x: np.array([value(float(v)) for v in x]), np.array([top]), GOLDEN_STEPS)[0])
    if value(best) <= 0:  # also leaves the solver's variables at the chosen s
        return failed
    point = GainPoint(*_clipped(bounds, k_xi, k_c, k_ep, k_er), weights, plant)
    cert = certify(point, reference, theta_max=theta_max)
    return Synthesis(point, cert, "ok")


def designer(
    weights: Weights,
    reference: SE3,
    n: int,
    *,
    theta_max: float,
    gamma_target: float | None = None,
    search_weights: bool = False,
    speed: tuple[MassBounds, float] | None = None,
    plant: PlantWeights | None = None,
) -> Callable[[Bounds], Synthesis]:
    """The synthesis as a function of the gain box: :func:`synthesize` then :func:`rounded`, or
    with ``speed = (mass, theta_bar)`` :func:`synthesize_speed`; certified over
    ``|theta_ec| <= theta_max`` for the generalized plant ``plant``."""

    def design(bounds: Bounds) -> Synthesis:
        if speed is not None:
            return synthesize_speed(weights, reference, n, bounds, *speed, theta_max=theta_max, plant=plant)
        result = synthesize(weights, reference, n, bounds, gamma_target=gamma_target, search_weights=search_weights,
                            theta_max=theta_max, plant=plant)  # fmt: skip
        return rounded(result, reference, bounds, gamma_target=gamma_target, theta_max=theta_max)

    return design


def _round(values: np.ndarray, digits: int) -> np.ndarray:
    """``values`` to ``digits`` significant figures."""
    return np.array([float(f"{v:.{digits}g}") for v in values])


def rounded(
    result: Synthesis, reference: SE3, bounds: Bounds, *, gamma_target: float | None = None, theta_max: float = math.pi
) -> Synthesis:
    """The synthesised gains rounded to the fewest significant figures (3 to 8) that stay within
    the bounds and certify again, by the ordinary certifier, at a gamma meeting the target (or
    within 0.1% of the unrounded one): a file shows ``20`` where the solver gave
    ``19.99999997``, and its certificate is that of the values written."""
    if result.point is None:
        return result
    p, limit = result.point, gamma_target or result.certificate.gamma * 1.001
    for digits in range(3, 9):
        gains = [_round(v, digits) for v in (p.k_xi, p.k_c, p.k_e)]
        inside = all(np.all((g >= lo) & (g <= hi)) for g, (lo, hi) in zip(gains, (bounds.k_xi, bounds.k_c, bounds.k_e),
                                                                          strict=True))  # fmt: skip
        point = GainPoint(*gains, p.weights, p.plant)
        cert = certify(point, reference, theta_max=theta_max, gamma_bound=gamma_target)
        if inside and cert.certified and cert.gamma <= limit:
            return replace(result, point=point, certificate=cert)
    return result


def scenario_text(original: str, point: GainPoint, *, name: str, weights: bool, urdf: str | None) -> str:
    """The user's scenario file with only the synthesised values replaced (tomlkit keeps its
    comments and layout): ``name``, the ``[gains]`` (and the ``[weights]`` when they were
    searched), the ``[grid]`` dropped so that ``certify`` certifies these gains, and a URDF
    path made absolute (``urdf``) since the file is written elsewhere."""
    doc = tomlkit.parse(original)
    doc["name"] = name
    gains = doc.setdefault("gains", tomlkit.table())
    for key, values in (("k_xi", point.k_xi), ("k_c", point.k_c), ("k_e", point.k_e)):
        gains[key] = [float(v) for v in values]
    if weights:
        for key, value in asdict(point.weights).items():
            doc["weights"][key] = float(value)
    if "grid" in doc:
        del doc["grid"]
    if urdf is not None:
        doc["robot"]["urdf"] = urdf
    return tomlkit.dumps(doc)


def scaled(bounds: Bounds, alpha: float) -> Bounds:
    """The gain box at ``alpha`` in [0, 1]: each upper bound moved toward its lower bound
    geometrically, ``lower (upper / lower)^alpha``. Geometric rather than linear because the
    bounds span decades and the torques grow roughly in proportion to the gains: a step in
    ``alpha`` changes the upper bounds by the same factor wherever it is taken.

    A smaller box contains no better design: the certified optimum is monotone in ``alpha`` (set
    inclusion), for either objective. Tried and not kept: the smallest gains (Euclidean norm)
    certifying ``gamma* / sqrt(alpha)``. It asks less torque at a given gamma, but with ``K_e``
    small beside ``K_c`` the features leave the image: on the idealised UR5 (default bounds,
    0.2 s) its best design within the limits certified gamma 0.87, the boxes' 0.68."""

    def shrink(b: tuple) -> tuple:
        lo, hi = b
        return lo, np.minimum(hi, lo * (np.asarray(hi) / lo) ** alpha)

    return Bounds(shrink(bounds.k_xi), shrink(bounds.k_c), shrink(bounds.k_e))


def within_limits(run: dict) -> bool:
    """:data:`LIMITS_CRITERION` on a run's limit record (:func:`dvfc.analysis.sampled.limit_record`
    with the run's ``status``)."""
    return run["status"] == "ok" and max(run["torque_commanded_ratio"]) <= 1.0 and max(run["speed_ratio"]) <= 1.0


def excess(run: dict) -> str:
    """How a run breaks :data:`LIMITS_CRITERION` (the first way found), in words."""
    if run["status"] != "ok":
        return f"does not complete ({run['status']}: {run['message']})"
    for key, what in (("torque_commanded_ratio", "torque"), ("speed_ratio", "speed")):
        ratios = run[key]
        j = int(np.argmax(ratios))
        if ratios[j] > 1.0:
            return f"exceeds a limit: joint {j + 1} peak {what} {ratios[j]:.3g}x its limit"
    return "is within the limits"


@dataclass
class Trial:
    """One design of the limits family: its synthesis and the limit record of its run (None: no
    certified design to run)."""

    alpha: float
    synthesis: Synthesis
    run: dict | None

    @property
    def within(self) -> bool:
        return self.run is not None and within_limits(self.run)


@dataclass
class LimitSearch:
    """The limits search over the family :data:`FAMILY`: the designs run (in order), the
    bracket ``[lowest, 1]`` of ``alpha`` searched (``lowest``: the smallest alpha with a
    certified design), the design chosen (the largest alpha found within the limits; None: none
    in the family), the run that bounds it from above (the smallest alpha found exceeding the
    limits; None when the unconstrained optimum is within them) and how many syntheses were
    solved."""

    trials: list[Trial]
    lowest: float
    chosen: Trial | None
    exceeds: Trial | None
    syntheses: int

    @property
    def runs(self) -> int:
        return sum(t.run is not None for t in self.trials)

    @property
    def result(self) -> Synthesis:
        """The chosen design's synthesis; else why there is none (the unconstrained synthesis'
        status, or the family's smallest certified design's run exceeding the limits)."""
        if self.chosen is not None:
            return self.chosen.synthesis
        if self.exceeds is None:
            return self.trials[0].synthesis
        return Synthesis(None, None, f"no design within the limits: the family's smallest certified design "
                                     f"(alpha = {self.exceeds.alpha:.4g}) {excess(self.exceeds.run)}")  # fmt: skip


def search_within_limits(
    design: Callable[[Bounds], Synthesis],
    bounds: Bounds,
    run: Callable[[GainPoint], dict],
    progress: Callable[[str], None] | None = None,
) -> LimitSearch:
    """The largest ``alpha`` whose design (``design`` of the box :func:`scaled` from ``bounds``)
    runs within the limits (``run``: the limit record of a design's run as implemented, judged
    by :func:`within_limits`).

    The certified objective is monotone in ``alpha``, so the largest ``alpha`` within the limits
    is the family's best design. First the unconstrained optimum (``alpha = 1``; if it is within
    the limits the search ends there); then the smallest ``alpha`` with a certified design
    by bisection on the SDP alone (:data:`FEASIBLE_STEPS`), which is run: if it exceeds the limits
    no design of the family is within them; otherwise :data:`SEARCH_STEPS` bisection runs between
    the two ends. The peak torques and speeds are measured, not proven monotone in ``alpha``: the
    result is the best found by bisection in this family, not a global optimum over the box."""
    designs: dict[float, Synthesis] = {}
    trials: list[Trial] = []
    say = progress or (lambda _: None)

    def synthesised(alpha: float) -> Synthesis:
        if alpha not in designs:
            say(f"synthesising at alpha = {alpha:.4g}")
            designs[alpha] = design(scaled(bounds, alpha))
        return designs[alpha]

    def tried(alpha: float) -> Trial:
        if (again := next((t for t in trials if t.alpha == alpha), None)) is not None:
            return again
        result = synthesised(alpha)
        if result.point is not None:
            say(f"run {sum(t.run is not None for t in trials) + 1}: the design at alpha = {alpha:.4g}")
        trials.append(Trial(alpha, result, None if result.point is None else run(result.point)))
        return trials[-1]

    def done(lowest: float, chosen: Trial | None, exceeds: Trial | None) -> LimitSearch:
        return LimitSearch(trials, lowest, chosen, exceeds, len(designs))

    top = tried(1.0)
    if top.run is None or top.within:
        return done(1.0, top if top.within else None, None)
    lo, hi = 0.0, 1.0
    if synthesised(lo).point is None:
        for _ in range(FEASIBLE_STEPS):
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if synthesised(mid).point is not None else (mid, hi)
        lo = hi
    good, bad = tried(lo), top
    if not good.within:
        return done(lo, None, good)
    for _ in range(SEARCH_STEPS):
        mid = tried((good.alpha + bad.alpha) / 2)
        good, bad = (mid, bad) if mid.within else (good, mid)
    return done(lo, good, bad)
