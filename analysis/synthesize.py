"""Gain synthesis (docs/math.md, fact 6): for fixed ``W_c, W_e, g_d``, ``N`` does not depend on
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

For the operating envelope (docs/math.md, facts 7-8) the objective is the certified target speed
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
import json
import math
import os
import time
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import tomlkit

from dvfc.analysis.case import Case
from dvfc.analysis.certify import Certificate, GainPoint, certify, estimation_scale, output_blocks, solve
from dvfc.analysis.envelope import GOLDEN_STEPS, design_of, golden_max, pose_diagonal, s_limit
from dvfc.analysis.multirate import implemented_record, with_program_record
from dvfc.analysis.output import append_log, atomic_write, read_log
from dvfc.analysis.record import ABSENT, INTERNAL, Absent, Record
from dvfc.analysis.results import CertificatePoint, envelope_record, point_record, speed_theta_bar
from dvfc.analysis.sampled import as_implemented, limit_record, robot_limits
from dvfc.analysis.scenario import Scenario, ScenarioError, integral_gain
from dvfc.analysis.windows import GainWindows, WindowSpec, case_window_spec, case_windows
from dvfc.models.inertia import MassBounds
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop, Gains, PlantWeights, Weights
from dvfc.models.robot import spans_the_task

TARGET_MARGIN = 1e-4
"""Relative margin below a gamma target that the synthesis aims at."""
CORNER_SLACK = 1e-6
"""Relative slack on the solver's largest ``s`` at which :func:`corner` meets the ``xi`` block: far above
the solver's accuracy (about 1e-10 on ``s``), far below a printed digit."""

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
RHO_MAX = 0.99
"""Fact 14 with margin: the monodromy's spectral radius at most this (1 - 0.01)."""
CONTROL_RATE_FRACTION = 0.8
"""Fact 14 with margin: the linear control-rate margin (the smallest control rate found stable)
at most this fraction of the control rate."""
SAMPLED_CRITERION = (
    f"every k_xi inside its gain window with the synthesis' margins (at least 1.1 x the lower end, at most "
    f"0.8 x the hold limit: docs/math.md, \"Gain windows\"), and where fact 14 applies the loop as implemented "
    f"certified with margin: rho <= {RHO_MAX:g} and the linear control-rate margin at most "
    f"{CONTROL_RATE_FRACTION:g} x the control rate"
)

if TYPE_CHECKING:
    import cvxpy as cp


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


class Outcome(StrEnum):
    """How a synthesis ended: a design (``ok``), or the kind of reason there is none; for the written
    design, refused (its run as implemented exceeds the limits) or its target speed not certified."""

    DESIGNED = "ok"
    INFEASIBLE = "infeasible"
    OUTSIDE_LIMITS = "no design within the limits"
    REFUSED = "refused, nothing written"
    UNCERTIFIED = "uncertified"

    def status(self, reason: str) -> str:
        """The outcome as ``synthesize``'s JSON says it: ``ok``, else ``<outcome>: <reason>``."""
        return self.value if self is Outcome.DESIGNED else f"{self.value}: {reason}"


@dataclass
class Synthesis:
    """A synthesis' design and its certificate, or (``point`` None) why there is none: ``outcome``
    and ``reason`` in words."""

    point: GainPoint | None
    certificate: Certificate | None
    outcome: Outcome = Outcome.DESIGNED
    reason: str = ""
    weights_tried: int = 1

    @property
    def status(self) -> str:
        """The outcome in words (:meth:`Outcome.status`)."""
        return self.outcome.status(self.reason)


def window_constraints(windows: WindowSpec | None, k_xi: cp.Variable) -> list:
    """The gain windows with the synthesis' margins (docs/math.md, "Gain windows"): ``k_xi >=``
    :meth:`WindowSpec.synthesis_lower` and ``K_xi <=`` :meth:`WindowSpec.synthesis_hold` (an LMI);
    none without ``windows``."""
    import cvxpy as cp

    if windows is None:
        return []
    constraints = [k_xi >= windows.synthesis_lower()]
    if (hold := windows.synthesis_hold()) is not None:
        constraints.append(hold - cp.diag(k_xi) >> 0)
    return constraints


def _sdp(weights: Weights, reference: SE3, n: int, bounds: Bounds, gamma_target: float | None,
         plant: PlantWeights | None, windows: WindowSpec | None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Solve the fact-6 SDP for fixed weights (and the generalized plant's, fact 17) within the gain
    windows (:func:`window_constraints`); returns ``(k_xi, k_c, k_e)`` or None.

    Without a target the optimum ``maximize s`` is not unique (``K_xi`` enters only its own block, and
    the gains beyond what the LMI needs are free), and where on that face a solver stops depends on the
    last bits of the arithmetic (on another BLAS kernel the same problem moved the gains by 2e-4). The
    design is then :func:`corner` at the solver's ``s`` less :data:`CORNER_SLACK`."""  # fmt: skip
    import cvxpy as cp

    w = weights.as_array()[None]
    n_ce = output_blocks(w, reference, np.eye(3)[None])[0]
    k_xi, k_c = cp.Variable(n), cp.Variable(6)
    k_ep, k_er = cp.Variable(), cp.Variable()
    k_ce = cp.hstack([k_c, k_ep, k_ep, k_ep, k_er, k_er, k_er])
    plant = plant if plant is not None else PlantWeights.unit(n)
    s2, d_w = plant.output() ** 2, plant.disturbance()
    w_ce = np.diag(np.r_[np.zeros(6), estimation_scale(weights, plant) ** 2])
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
    constraints += window_constraints(windows, k_xi)
    objective = cp.Maximize(s) if gamma_target is None else cp.Minimize(cp.norm(cp.hstack([k_xi, k_ce])))
    problem = cp.Problem(objective, constraints)
    if solve(problem)[0] is None:
        return None
    if isinstance(s, cp.Variable):  # no target: the minimum-gamma design
        level = float(np.asarray(s.value)) * (1 - CORNER_SLACK)
        return corner(n, bounds, windows, 0.5 * s2[:n] + level * d_w[:n] ** 2)
    return _clipped(bounds, k_xi, k_c, k_ep, k_er)


def corner(n: int, bounds: Bounds, windows: WindowSpec | None,
           needed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The minimum-gamma design of the box (docs/math.md, fact 6, uniqueness): ``K_c`` and ``K_e`` at
    their upper bounds (``K_e`` isotropic: fact 2), and ``K_xi`` at its upper bounds scaled by the
    largest ``t <= 1`` with ``t diag(upper) <= H`` (:meth:`WindowSpec.synthesis_hold`; ``t`` the least
    eigenvalue of ``diag(upper)^-1/2 H diag(upper)^-1/2``) when that meets ``needed``, the least
    ``K_xi`` of the ``xi`` block at the optimal ``s``; else (the ``xi`` block binds) the least ``K_xi``
    allowed: ``needed``, the box's lower bounds and :meth:`WindowSpec.synthesis_lower`, elementwise.

    Fact 6's ``P = N^T diag(k) N - I/2 - s W`` grows (in the Loewner order) with every gain, so any
    optimal point of the SDP is dominated by this one, which is then optimal too, and within the hold
    LMI (``H - diag(k) >= 0`` stays so when ``k`` decreases). Every number is a bound, one symmetric
    eigenvalue or the optimal ``s``: the same on any machine to round-off, where the solver's point on
    the optimal face is not."""
    upper = np.broadcast_to(np.asarray(bounds.k_xi[1], dtype=float), n).copy()
    if windows is not None and (hold := windows.synthesis_hold()) is not None:
        root = 1.0 / np.sqrt(upper)
        upper *= min(1.0, float(np.linalg.eigvalsh(root[:, None] * hold * root[None, :])[0]))
    lowest = np.maximum(bounds.k_xi[0], 0.0 if windows is None else windows.synthesis_lower())
    k_xi = upper if np.all(upper >= np.maximum(needed, lowest)) else np.maximum(needed, lowest)
    return k_xi, np.full(6, float(bounds.k_c[1])), np.full(6, float(bounds.k_e[1]))


def _clipped(bounds: Bounds, k_xi: cp.Variable, k_c: cp.Variable, k_ep: cp.Variable,
             k_er: cp.Variable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The solved gains ``(K_xi, K_c, K_e)`` clipped to ``bounds`` (the solver's round-off can
    step outside them)."""
    clip = lambda v, b: np.clip(np.asarray(v, dtype=float), *b)  # noqa: E731
    k_e = np.repeat([float(np.asarray(k_ep.value)), float(np.asarray(k_er.value))], 3)
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
    windows: WindowSpec | None = None,
) -> Synthesis:
    """Gains within ``bounds`` and the gain ``windows`` (:func:`window_constraints`; None: no
    window) minimising the certified gamma (or, with ``gamma_target``, the smallest gain norm
    reaching it), certified a posteriori over the rotations ``|theta_ec| <= theta_max`` (the
    ``[certify]`` region), for the generalized plant ``plant`` (docs/math.md, fact 17; None: the paper's)."""
    candidates = [weights]
    if search_weights:
        scales = (0.25, 0.5, 1.0, 2.0, 4.0)
        base = weights.as_array()
        candidates = [Weights(*(base * np.array(c))) for c in itertools.product(scales, repeat=4)]
    where = "the bounds" if windows is None else "the bounds and the gain windows (with the synthesis' margins)"
    best = Synthesis(None, None, Outcome.INFEASIBLE, f"no gains within {where} certify", len(candidates))
    for w in candidates:
        gains = _sdp(w, reference, n, bounds, gamma_target, plant, windows)
        if gains is None:
            continue
        point = GainPoint(*gains, w, plant)
        cert = certify(point, reference, theta_max=theta_max, gamma_bound=gamma_target)
        if not cert.certified:
            continue
        chosen, chosen_cert = best.point, best.certificate
        better = chosen is None or chosen_cert is None or (
            float(cert.gamma or math.inf) < float(chosen_cert.gamma or math.inf)
            if gamma_target is None
            else np.linalg.norm(np.r_[point.k_xi, point.k_c, point.k_e])
            < np.linalg.norm(np.r_[chosen.k_xi, chosen.k_c, chosen.k_e])
        )
        if better:
            best = Synthesis(point, cert, weights_tried=len(candidates))
    return best


def _speed_problem(weights: Weights, reference: SE3, n: int, bounds: Bounds, mass: MassBounds, theta_bar: float,
                   windows: WindowSpec | None = None):  # fmt: skip
    """The fact-7 SDP at a parameter ``s``: ``maximize kappa`` subject to
    ``N^T K N - s W - kappa D_ce >= 0`` on ``(e_c, e_e)``, ``diag(k_xi - s) - (kappa/2) B >= 0`` (the
    decoupled ``xi`` block: equivalent, for ``k_xi > s``, to ``kappa <= 2 / rho(diag(k_xi - s)^-1 B)``,
    the rate of (10.4), docs/math.md, fact 10, since ``rho`` is ``lambda_max`` of the symmetric
    ``(K_xi - s)^-1/2 B (K_xi - s)^-1/2``), the gain bounds and windows (:func:`window_constraints`).
    Returns ``(problem, s, kappa, gains)``."""
    import cvxpy as cp

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
    constraints += window_constraints(windows, k_xi)
    return cp.Problem(cp.Maximize(kappa), constraints), s, kappa, (k_xi, k_c, k_ep, k_er)


def largest_positive(value: Callable[[float], float], top: float) -> float:
    """The largest ``s`` in ``[0, top]`` with ``value(s) > 0``, to ``top / 2^FEASIBLE_STEPS``, by
    bisection: ``kappa*(s)`` is concave with ``kappa*(0) > 0`` where any rate is, so the ``s`` with a
    positive rate form an interval from 0. The hold LMI of the windows bounds ``K_xi`` jointly, so
    the upper gains' ``s_limit`` is only an upper bound on that interval's end."""
    lo, hi = 0.0, top
    for _ in range(FEASIBLE_STEPS):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if value(mid) > 0 else (lo, mid)
    return lo


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
    windows: WindowSpec | None = None,
) -> Synthesis:
    """Gains within ``bounds`` and the gain ``windows`` maximising the certified target speed of
    the envelope at ``theta_bar`` (radians; docs/math.md, facts 7-8): ``max over s of s kappa*(s)``,
    ``kappa*(s)`` the SDP of :func:`_speed_problem`.

    ``kappa*`` is concave in ``s`` (the value of a convex program whose constraints are jointly
    linear in ``(s, gains, kappa)``), so ``log(s kappa*)`` is concave and its maximum lies in
    ``[s_top/2, s_top]`` (the tangent argument of :func:`dvfc.analysis.envelope.best_s`), ``s_top``
    the largest ``s`` with a positive rate: that of the upper gains, since ``N^T K N`` grows
    with every gain (with the windows' hold LMI, found by :func:`largest_positive` below it). The
    result carries the ordinary Theorem 2 certificate over ``|theta_ec| <= theta_max`` for
    ``plant`` (the envelope itself does not depend on the generalized plant's weights); its
    envelope is computed by the ordinary route by the caller."""
    upper = GainPoint(np.broadcast_to(bounds.k_xi[1], n), np.full(6, bounds.k_c[1]), np.full(6, bounds.k_e[1]), weights)
    top = s_limit(design_of(upper, reference, mass))
    where = "the bounds" if windows is None else "the bounds and the gain windows (with the synthesis' margins)"
    failed = Synthesis(None, None, Outcome.INFEASIBLE, f"no gains within {where} give a positive decay rate")
    if top <= 0:
        return failed
    problem, s, kappa, (k_xi, k_c, k_ep, k_er) = _speed_problem(weights, reference, n, bounds, mass, theta_bar, windows)

    def value(x: float) -> float:
        s.value = x
        solved = solve(problem)[0] is not None and kappa.value is not None
        return x * float(kappa.value) if solved else -math.inf

    if windows is not None and windows.synthesis_hold() is not None:
        top = largest_positive(value, top)
    best = float(golden_max(lambda x: np.array([value(float(v)) for v in x]), np.array([top]), GOLDEN_STEPS)[0])
    if value(best) <= 0:  # also leaves the solver's variables at the chosen s
        return failed
    point = GainPoint(*_clipped(bounds, k_xi, k_c, k_ep, k_er), weights, plant)
    cert = certify(point, reference, theta_max=theta_max)
    return Synthesis(point, cert)


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
    windows: WindowSpec | None = None,
) -> Callable[[Bounds], Synthesis]:
    """The synthesis as a function of the gain box: :func:`synthesize` then :func:`rounded`, or
    with ``speed = (mass, theta_bar)`` :func:`synthesize_speed`; certified over
    ``|theta_ec| <= theta_max`` for the generalized plant ``plant``, within the gain ``windows``."""

    def design(bounds: Bounds) -> Synthesis:
        if speed is not None:
            return synthesize_speed(weights, reference, n, bounds, *speed, theta_max=theta_max, plant=plant,
                                    windows=windows)  # fmt: skip
        result = synthesize(weights, reference, n, bounds, gamma_target=gamma_target, search_weights=search_weights,
                            theta_max=theta_max, plant=plant, windows=windows)  # fmt: skip
        return rounded(result, reference, bounds, gamma_target=gamma_target, theta_max=theta_max, windows=windows)

    return design


def _round(values: np.ndarray, digits: int) -> np.ndarray:
    """``values`` to ``digits`` significant figures."""
    return np.array([float(f"{v:.{digits}g}") for v in values])


def _round_down(values: np.ndarray, digits: int) -> np.ndarray:
    """``values`` (positive) to ``digits`` significant figures, toward zero: no entry grows, so upper
    bounds hold, and a diagonal ``K_xi`` below the hold LMI stays below it (:meth:`WindowSpec.synthesis_hold`)."""
    nearest = _round(values, digits)
    step = 10.0 ** (np.floor(np.log10(values)) - digits + 1)
    return np.where(nearest <= values, nearest, _round(nearest - step, digits))


def rounded(
    result: Synthesis, reference: SE3, bounds: Bounds, *, gamma_target: float | None = None, theta_max: float = math.pi,
    windows: WindowSpec | None = None,
) -> Synthesis:
    """The synthesised gains rounded to the fewest significant figures (3 to 8) that stay within
    the bounds and the ``windows`` with their margins (:meth:`GainWindows.outside_margins`; where the
    nearest values break them, the values rounded toward zero) and certify again, by the
    ordinary certifier, at a gamma meeting the target (or within 0.1% of the unrounded one): a file
    shows ``20`` where the solver gave ``19.99999997``, and its certificate is that of the values
    written."""
    if result.point is None:
        return result
    assert result.certificate is not None and result.certificate.gamma is not None  # a design is certified
    p, limit = result.point, gamma_target or result.certificate.gamma * 1.001
    for digits, rounder in itertools.product(range(3, 9), (_round, _round_down)):
        gains = tuple(rounder(v, digits) for v in (p.k_xi, p.k_c, p.k_e))
        inside = all(np.all((g >= lo) & (g <= hi)) for g, (lo, hi) in zip(gains, (bounds.k_xi, bounds.k_c, bounds.k_e),
                                                                          strict=True))  # fmt: skip
        inside = inside and (windows is None or not windows.of(gains[0]).outside_margins())
        point = GainPoint(gains[0], gains[1], gains[2], p.weights, p.plant)
        cert = certify(point, reference, theta_max=theta_max, gamma_bound=gamma_target)
        if inside and cert.certified and cert.gamma is not None and cert.gamma <= limit:
            return replace(result, point=point, certificate=cert)
    return result


PATH_FIELDS = (("robot", "urdf"), ("camera", "calibration"))
"""The scenario's fields that name a file, each read relative to the scenario file's folder."""


def rebased(path: str, source: Path, folder: Path) -> str:
    """``path`` as given in a scenario file in ``source`` (relative to it, or absolute), written for a
    file in ``folder``: relative to ``folder`` when a relative path reaches it (POSIX: always; not
    across Windows drives), else absolute."""
    resolved = (source / path).resolve()
    try:
        return Path(os.path.relpath(resolved, folder.resolve())).as_posix()
    except ValueError:
        return str(resolved)


def scenario_text(original: str, point: GainPoint, *, name: str, weights: bool, source: Path, target: Path) -> str:
    """The user's scenario file with only the synthesised values replaced (tomlkit keeps its
    comments and layout): ``name``, the ``[gains]`` (and the ``[weights]`` when they were
    searched), the ``[grid]`` dropped so that ``certify`` certifies these gains, and every file it
    names (:data:`PATH_FIELDS`, given relative to ``source``, the original's folder) rewritten by
    :func:`rebased` for ``target``, the file to be written: moved with its data, it still loads."""
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
    for section, key in PATH_FIELDS:
        if section in doc and doc[section].get(key) is not None:
            doc[section][key] = rebased(str(doc[section][key]), source, target.parent)
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
    with the run's ``status``), and :data:`SAMPLED_CRITERION` when the record carries its check
    (``sampled``: why it falls short, None when it passes; :func:`design_checker`)."""
    within = run["status"] == "ok" and max(run["torque_commanded_ratio"]) <= 1.0 and max(run["speed_ratio"]) <= 1.0
    return within and run.get("sampled") is None


def excess(run: dict) -> str:
    """How a run breaks :data:`LIMITS_CRITERION` or :data:`SAMPLED_CRITERION` (the first way
    found), in words."""
    if run.get("sampled") is not None:
        return f"falls short of the sampled loop's margins: {run['sampled']}"
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
        smallest = f"the family's smallest certified design (alpha = {self.exceeds.alpha:.4g})"
        return Synthesis(None, None, Outcome.OUTSIDE_LIMITS, f"{smallest} {excess(self.exceeds.run or {})}")


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
        trial = tried((good.alpha + bad.alpha) / 2)
        good, bad = (trial, bad) if trial.within else (good, trial)
    return done(lo, good, bad)


def designed_loop(case: Case, point: GainPoint) -> ClosedLoop:
    """The case's loop with a design ``point``: its gains of (42) and weights, with the case's integral
    action (docs/math.md, fact 20): ``K_I = k_i_factor K_xi`` at the design's ``K_xi`` when the scenario
    gives a factor, its fixed ``k_i`` otherwise, none without (the loop of the scenario written with
    the design)."""
    gains = Gains(point.k_xi, point.k_c, point.k_e, integral_gain(case.scenario.gains, point.k_xi))
    return replace(case.loop, gains=gains, weights=point.weights)


def design_runner(case: Case) -> Callable[[GainPoint], dict]:
    """Runs of designs (gains and weights) of one case as implemented (its controller,
    plant and image; compiled as the case says: the gains and weights are inputs of the compiled
    functions, so every design runs on the same libraries): for a design, the run's status and, per
    joint, the peak torques and speed against the URDF's limits."""
    settings = case.settings
    limits = robot_limits(case.loop, settings)

    def run(point: GainPoint) -> dict:
        traj = as_implemented(designed_loop(case, point), settings).run(case.s0)
        return {"status": traj.status, "message": traj.message, **limit_record(traj, limits)}

    return run


def logged_runs(run: Callable[[GainPoint], dict], log: Path, *, resume: bool) -> Callable[[GainPoint], dict]:
    """``run`` with every run appended to ``log`` (JSON lines: the design's gains and weights,
    and the run's record) as it finishes; with ``resume`` the runs already in ``log`` are reused
    for the same design (a line cut short by an interruption is ignored), otherwise ``log``
    starts empty."""
    if not resume:
        log.unlink(missing_ok=True)
    done = {entry["design"]: entry["run"] for entry in read_log(log)}

    def logged(point: GainPoint) -> dict:
        design = json.dumps([point.k_xi.tolist(), point.k_c.tolist(), point.k_e.tolist(), asdict(point.weights)])
        if design not in done:
            done[design] = run(point)
            append_log(log, {"design": design, "run": done[design]})
        return done[design]

    return logged


DEFAULT_K_XI = (1.0, 100.0)
"""``[synthesize] k_xi`` where the gain windows have no upper limit (the continuous loop), and
the cap on a hold limit: the former one interval for every joint."""


def synthesis_bounds(case: Case) -> Bounds:
    """The ``[synthesize]`` gain box of the case: ``k_xi`` per joint as given (one interval for
    every joint, or one per joint: their number must be ``n``, else :class:`ScenarioError`
    naming the field), or by default each joint's gain window
    (:func:`dvfc.analysis.windows.case_windows`): ``[1, min(100, upper)]``, the lower end the
    window's own when the hold limit is below 1."""
    cfg, n = case.scenario.synthesize, case.loop.robot.n
    if cfg.k_xi is not None and isinstance(cfg.k_xi[0], list):
        if len(cfg.k_xi) != n:
            raise ScenarioError(f"synthesize.k_xi: {len(cfg.k_xi)} intervals for {n} joints (give one, or one a joint)")
        k_xi = tuple(np.array(b, dtype=float) for b in zip(*cfg.k_xi, strict=True))
    elif cfg.k_xi is not None:
        k_xi = tuple(np.full(n, b, dtype=float) for b in cfg.k_xi)
    else:
        windows = case_windows(case)
        assert windows is not None  # the paper's loop (refuse_unless_synthesisable) has its windows
        hi = np.full(n, DEFAULT_K_XI[1]) if windows.upper is None else np.minimum(windows.upper, DEFAULT_K_XI[1])
        k_xi = (np.where(hi >= DEFAULT_K_XI[0], DEFAULT_K_XI[0], np.minimum(windows.lower, hi)), hi)
    (k_c_lo, k_c_hi), (k_e_lo, k_e_hi) = cfg.k_c, cfg.k_e
    return Bounds((k_xi[0], k_xi[1]), (k_c_lo, k_c_hi), (k_e_lo, k_e_hi))


def limit_search_record(search: LimitSearch, bounds: Bounds) -> dict:
    """The limits search of ``synthesize`` (JSON-ready): what was searched (family, bracket,
    criterion, runs), the ``alpha`` chosen and its gain box, the run bounding it from above, the
    unconstrained optimum's certified gamma, and every run with its certified gamma and worst
    torque and speed ratios."""
    top = search.trials[0]

    def trial(t: Trial) -> dict:
        run = t.run or {}
        worst = lambda key: None if key not in run else max(run[key])  # noqa: E731
        gamma = None if t.synthesis.certificate is None else t.synthesis.certificate.gamma
        return {"alpha": t.alpha, "gamma": gamma, "status": run.get("status", t.synthesis.status),
                "torque_commanded_ratio": worst("torque_commanded_ratio"), "speed_ratio": worst("speed_ratio"),
                "sampled": run.get("sampled"), "within": t.within}  # fmt: skip

    chosen, exceeds = search.chosen, search.exceeds
    if chosen is None:
        found = "no design of the family runs within the limits"
    elif exceeds is None:
        found = "the unconstrained optimum runs within the limits: nothing to search"
    else:
        found = (f"alpha = {chosen.alpha:.4g} is the largest found within the limits (alpha = {exceeds.alpha:.4g} "
                 "exceeds them): the best design found by bisection in this family, not a global optimum over the "
                 "[synthesize] bounds")  # fmt: skip
    return {
        "family": FAMILY,
        "criterion": f"{LIMITS_CRITERION}; and {SAMPLED_CRITERION}",
        "bracket": [search.lowest, 1.0],
        "resolution": None if chosen is None or exceeds is None else exceeds.alpha - chosen.alpha,
        "alpha": None if chosen is None else chosen.alpha,
        "exceeds_at": None if exceeds is None else exceeds.alpha,
        "bounds": None if chosen is None else scaled(bounds, chosen.alpha).as_dict(),
        "gamma_unconstrained": None if top.synthesis.certificate is None else top.synthesis.certificate.gamma,
        "runs": search.runs,
        "syntheses": search.syntheses,
        "statement": found,
        "trials": [trial(t) for t in search.trials],
    }


def sampled_shortfall(windows: GainWindows | None, implemented: dict | None) -> str | None:
    """Why a design falls short of :data:`SAMPLED_CRITERION`, in words, or None: its gains'
    ``windows`` (None: the planar loop) outside the synthesis' margins, or fact 14's record
    ``implemented`` (None: no ``[implementation]``; a record that does not apply: no check) not
    certifying it, ``rho`` above :data:`RHO_MAX` or the control-rate margin above
    :data:`CONTROL_RATE_FRACTION` of the control rate."""
    if windows is not None and (outside := windows.outside_margins()):
        return "gain window: " + "; ".join(outside)
    if implemented is None or not implemented["applies"]:
        return None
    if not implemented["certified"]:
        return f"the loop as implemented is not certified (fact 14): {implemented['reason']}"
    if implemented["rho"] > RHO_MAX:
        return f"fact 14: rho = {implemented['rho']:.6g} above {RHO_MAX:g}"
    control = implemented["margins"]["control_rate"]
    rate = control["range"][0]
    if control["value"] is not None and control["value"] > CONTROL_RATE_FRACTION * rate:
        return (f"fact 14: the linearised loop is stable only down to {control['value']:.4g} Hz (unstable at "
                f"{control['unstable_at']:.4g} Hz), above {CONTROL_RATE_FRACTION:g} x {rate:g} Hz")  # fmt: skip
    return None


def design_checker(case: Case, run: Callable[[GainPoint], dict]) -> Callable[[GainPoint], dict]:
    """``run`` (a design's limit record, :func:`design_runner`) with the design's sampled-loop
    checks: ``implemented``, its fact-14 record (None without an ``[implementation]``), and
    ``sampled``, :func:`sampled_shortfall` (None: it passes), both read by :func:`within_limits`."""
    spec = case_window_spec(case)

    def check(point: GainPoint) -> dict:
        record = dict(run(point))
        implemented = None
        if case.settings.implementation is not None:
            implemented = implemented_record(designed_loop(case, point), case.s0, case.settings, case.criterion,
                                             program=False)  # fmt: skip
        windows = None if spec is None else spec.of(point.k_xi)
        return {**record, "implemented": implemented, "sampled": sampled_shortfall(windows, implemented)}

    return check


@dataclass(frozen=True)
class StartCheck:
    """Whether the start is certified (the envelope record's ``start.inside``, docs/math.md, fact
    16) for the scenario's own gains (``original``) and for the written design (``written``), and
    the written design's start record's reason when it is not."""

    original: bool
    written: bool
    reason: str | None

    @property
    def lost(self) -> bool:
        """The scenario's gains certify the start and the written design's do not."""
        return self.original and not self.written

    def as_dict(self) -> dict:
        text = (f"the start is NOT certified for the written design ({self.reason}), though it is for the "
                "scenario's own gains" if self.lost else None)  # fmt: skip
        return {"original_certified": self.original, "written_certified": self.written, "lost": self.lost,
                "reason": self.reason, "statement": text}  # fmt: skip


@dataclass(frozen=True)
class CaseSynthesis:
    """A scenario's synthesis (:func:`synthesize_case`): the scenario's name, the objective in
    words, the design (``result.point`` None: none, and why in ``result.status``), the gain box,
    the limits search (None: none run), the checked run of the design (:func:`design_checker`;
    None without a design), why it is refused (None: accepted), the scenario file's text (None:
    nothing to write), the written design's envelope record and start check (None without an
    accepted design), and the ``theta_bar`` of a target-speed synthesis (None: the gamma objective)."""

    scenario: str
    objective: str
    result: Synthesis
    bounds: Bounds
    search: LimitSearch | None
    run: dict | None
    refused: str | None
    text: str | None
    envelope: dict | None
    start: StartCheck | None
    theta_bar: float | None

    @property
    def accepted(self) -> bool:
        return self.text is not None


def written_case(case: Case, text: str, target: Path) -> Case:
    """The case of the scenario file ``text`` as written at ``target`` (its paths relative to it)."""
    scenario = Scenario.model_validate(tomllib.loads(text))
    return Case(scenario, target.parent.resolve(), None, case.mode, case.check_view)


def synthesize_case(
    case: Case,
    target: Path,
    *,
    runs: Callable[[Callable[[GainPoint], dict]], Callable[[GainPoint], dict]] | None = None,
    progress: Callable[[str], None] | None = None,
) -> CaseSynthesis:
    """The ``[synthesize]`` workflow on a case of the paper's loop (``n >= 6``) loaded from a scenario
    file (:meth:`Case.load`: the file written is that file edited), for a file to be written at
    ``target``: the box (:func:`synthesis_bounds`, :class:`ScenarioError` on a bad one), the
    synthesis within it and the gain windows, each design checked by :func:`design_checker` (its
    run, the limits, the windows' margins and fact 14 with margin). With ``respect_limits`` the
    family search (:func:`search_within_limits`); otherwise the synthesis, and when its design falls
    short of :data:`SAMPLED_CRITERION` the same search, a posteriori. ``runs`` wraps the checked run
    (a log, say). The accepted design's scenario text (:func:`scenario_text`) and its envelope
    (the written file's, re-certified by the ordinary route) and start check come with it."""
    spec, loop = case.scenario, case.loop
    cfg, n = spec.synthesize, loop.robot.n
    bounds = synthesis_bounds(case)
    windows = case_window_spec(case)
    speed = cfg.objective == "target_speed"
    theta = speed_theta_bar(case) if speed else None
    design = designer(Weights(**spec.weights.model_dump()), spec.reference.se3(), n,
                      theta_max=math.radians(spec.certify.theta_max_deg), gamma_target=cfg.gamma,
                      search_weights=cfg.search_weights,
                      speed=(loop.robot.mass_bounds, theta) if theta is not None else None,
                      plant=case.point.plant, windows=windows)  # fmt: skip
    objective = ("maximise the certified target speed (facts 7-8)" if speed else
                 "minimise gamma" if cfg.gamma is None else f"smallest gains with gamma <= {cfg.gamma:g}")  # fmt: skip
    check = design_checker(case, design_runner(case))
    check = check if runs is None else runs(check)
    search, run, say = None, None, progress or (lambda _: None)
    if cfg.respect_limits:
        search = search_within_limits(design, bounds, check, say)
        result = search.result
    else:
        say("solving the gain-synthesis SDP" + ("s (golden section over s)" if speed else ""))
        result = design(bounds)
        if result.point is not None and (run := check(result.point)).get("sampled") is not None:
            say("the design falls short of the sampled loop's margins: searching the family of smaller boxes")
            search = search_within_limits(design, bounds, check, say)
            result = search.result
    if search is not None:
        run = None if search.chosen is None else search.chosen.run
    if run is not None and run.get("implemented") is not None and result.point is not None:  # the kept design's
        run = {**run, "implemented": with_program_record(run["implemented"], designed_loop(case, result.point),
                                                         case.s0, case.settings)}  # fmt: skip
    if result.point is None:
        if windows is not None and (empty := windows.empty(bounds.k_xi)):
            result = replace(result, outcome=Outcome.INFEASIBLE, reason="; ".join(empty))
        return CaseSynthesis(spec.name, objective, result, bounds, search, None, None, None, None, None, theta)
    assert run is not None and case.path is not None  # a design's run is checked; the case is a file's
    if not within_limits(run):
        refused = f"its run as implemented {excess(run)}"
        return CaseSynthesis(spec.name, objective, result, bounds, search, run, refused, None, None, None, theta)
    text = scenario_text(case.path.read_text(), result.point, name=f"{spec.name}-synthesized",
                         weights=cfg.search_weights, source=case.path.parent, target=target)  # fmt: skip
    say("certifying the written design's operating envelope")
    envelope = envelope_record(written_case(case, text, target), search=speed)
    original = envelope_record(case, search=False)["start"]["inside"]
    start = StartCheck(bool(original), bool(envelope["start"]["inside"]), envelope["start"].get("reason"))
    return CaseSynthesis(spec.name, objective, result, bounds, search, run, None, text, envelope, start, theta)


@dataclass(frozen=True, kw_only=True)
class SynthesisResult(Record):
    """``dvfc synthesize`` (docs/cli.md): the outcome (``status``, in words; ``outcome``, typed), the
    objective, the gain box, the design's certificate point (None: no design), the file written (None:
    nothing written); the target speed of a target-speed synthesis, the limits search, the design's run
    against the limits and fact 14, the start check, when made."""

    scenario: str
    status: str
    objective: str
    bounds: dict[str, Any]
    weights_tried: int
    point: CertificatePoint | None
    region: str | None
    scenario_file: str | None
    seconds: float
    provenance: dict[str, Any]
    synthesis_theta_bar_deg: float | Absent = ABSENT
    max_target_speed: float | Absent | None = ABSENT
    limit_search: dict[str, Any] | Absent = ABSENT
    limits: dict[str, Any] | Absent = ABSENT
    implemented: dict[str, Any] | Absent = ABSENT
    sampled: dict[str, Any] | Absent = ABSENT
    start: dict[str, Any] | Absent = ABSENT
    outcome: Outcome = field(metadata=INTERNAL)

    @property
    def written(self) -> bool:
        """A design was accepted, certified, and written."""
        return self.scenario_file is not None and self.outcome is Outcome.DESIGNED


def synthesis_record(done: CaseSynthesis, written: Path | None, provenance: dict, seconds: float) -> SynthesisResult:
    """The result of ``synthesize`` from its workflow's result and the file written (None: nothing
    written)."""
    result = done.result
    outcome, reason = (result.outcome, result.reason) if done.refused is None else (Outcome.REFUSED, done.refused)
    point = None if result.point is None or result.certificate is None else point_record(result.point,
                                                                                          result.certificate)
    speed: dict[str, Any] = {}
    if done.theta_bar is not None:
        speed = {"synthesis_theta_bar_deg": math.degrees(done.theta_bar), "max_target_speed": None}
        if done.envelope is not None and point is not None:  # the written design's own envelope
            point = replace(point, envelope=done.envelope)
            speed["max_target_speed"] = done.envelope["max_target_speed"]
            if speed["max_target_speed"] is None:
                outcome = Outcome.UNCERTIFIED
                reason = f"no target speed certified for the written design ({done.envelope['reason']})"
    run: dict[str, Any] = {}
    if done.run is not None:
        run = {"limits": {k: v for k, v in done.run.items() if k not in ("implemented", "sampled")},
               "implemented": done.run["implemented"],
               "sampled": {"criterion": SAMPLED_CRITERION, "shortfall": done.run["sampled"]}}  # fmt: skip
    return SynthesisResult(
        scenario=done.scenario, status=outcome.status(reason), outcome=outcome, objective=done.objective,
        bounds=done.bounds.as_dict(), weights_tried=result.weights_tried, point=point,
        region=None if result.certificate is None else result.certificate.region,
        scenario_file=None if written is None else str(written), seconds=seconds, provenance=provenance,
        limit_search=ABSENT if done.search is None else limit_search_record(done.search, done.bounds),
        start=ABSENT if done.start is None else done.start.as_dict(), **speed, **run,
    )  # fmt: skip


def refuse_unless_synthesisable(case: Case) -> None:
    """Raise :class:`ScenarioError` unless the case is of the paper's loop with ``n >= 6`` joints, which
    the gain synthesis is for (fact 6)."""
    n = case.loop.robot.n
    if case.scenario.loop != "paper" or not spans_the_task(n):
        raise ScenarioError(f"loop: gain synthesis is for the paper's loop with n >= 6 joints "
                            f"(this is {case.scenario.loop}, n = {n})")  # fmt: skip


def synthesize_scenario(
    case: Case, target: Path, provenance: dict, *, resume: bool = False, progress: Callable[[str], None] | None = None
) -> SynthesisResult:
    """The ``[synthesize]`` workflow (:func:`synthesize_case`) on a case of the paper's loop with
    ``n >= 6`` joints, its design written as a scenario at ``target`` when accepted, the checked runs
    logged beside it (``target.runs.jsonl``, reused with ``resume``, removed when done); the JSON of
    ``dvfc synthesize`` (:func:`synthesis_record`) with ``provenance``. Bad input raises before any work:
    :class:`ScenarioError` naming the field, :class:`ValueError` naming the argument."""
    start = time.perf_counter()
    refuse_unless_synthesisable(case)
    synthesis_bounds(case)
    log = target.with_name(target.name + ".runs.jsonl")
    if resume and not log.exists():
        raise ValueError(f"resume: no limits search to resume ({log} not found)")
    target.parent.mkdir(parents=True, exist_ok=True)
    done = synthesize_case(case, target, runs=lambda run: logged_runs(run, log, resume=resume), progress=progress)
    log.unlink(missing_ok=True)  # the search is done: its runs are in the result
    if done.text is not None:
        data = done.text.encode()
        atomic_write(target, lambda h: h.write(data))
    return synthesis_record(done, target if done.accepted else None, provenance, time.perf_counter() - start)
