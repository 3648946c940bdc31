"""Which drawn quantities drive a campaign's outcome: global, moment-independent sensitivity
from the runs already made (given data, no designed sample).

A rank correlation sees only a monotone effect: a quantity that fails the loop both ways (a
mount rotation of either sign) has a correlation near zero. PAWN (``SALib.analyze.pawn``)
compares the outcome's whole distribution within a slice of a quantity with its unconditioned
distribution: the largest, over :func:`slices` equal-count slices, Kolmogorov-Smirnov distance
between the two (the maximum statistic: a driver that fails both ways moves the middle slice),
0 when the outcome does not depend on the quantity. It is indifferent to ties, which the outcome
has when many runs fail alike. (Borgonovo's delta, SALib's other given-data measure, is a kernel
density estimate that misleads on such ties and costs about a hundred times as much.)

It is an estimate from finitely many runs and is biased upwards: an input the outcome does not
depend on still scores above 0. Each campaign therefore adds :data:`REFERENCES` inputs drawn
independently of everything (uniform, their own seed); an input whose score exceeds every
reference's is told apart from no effect by a rank test at level ``1 / (REFERENCES + 1) = 0.05``
(under no effect its score is exchangeable with the references'). These are measurements on the
runs made, not causes.

The outcome is the run's closeness to failing (the largest of its tracking ratio and limit
ratios: above 1 it fails). A run that did not complete has no finite closeness; it stands in
above every finite value, the higher the earlier it stopped, so that when most runs fail the
measures rank by how soon they fail rather than on a tie.
"""

from __future__ import annotations

import contextlib
import io
import math
import warnings
from dataclasses import dataclass

import numpy as np

REFERENCES = 19
"""Independent reference inputs: their largest PAWN score is the floor (a rank test at level 0.05)."""

@dataclass(frozen=True)
class Scores:
    """One input's moment-independent sensitivity: PAWN's largest KS distance over slices."""

    pawn: float


@dataclass(frozen=True)
class Floor:
    """The largest PAWN score of the independent reference inputs (None when nothing was scored)
    and what it means."""

    pawn: float | None
    note: str


def outcome(closeness: np.ndarray, end_time: np.ndarray, horizon: float) -> np.ndarray:
    """A finite outcome per run: the closeness where finite; for a run that did not complete,
    ``top (2 + (T - t_end) / T)`` with ``top`` the largest finite closeness (at least 1), above
    every finite value and larger the earlier the run stopped."""
    closeness = np.asarray(closeness, dtype=float)
    finite = np.isfinite(closeness)
    top = max(float(closeness[finite].max()) if finite.any() else 1.0, 1.0)
    early = np.clip((horizon - np.asarray(end_time, dtype=float)) / horizon, 0.0, 1.0)
    return np.where(finite, closeness, top * (2.0 + early))


SLICES = (3, 4, 5, 7, 8, 10)
"""PAWN's numbers of slices that SALib 1.6 builds correctly (it makes the slices' quantile
levels by ``arange(0, 1 + 1/S, 1/S)``, which overshoots 1 for 6 and 9)."""


def slices(runs: int) -> int:
    """PAWN's number of slices: about 10 runs a slice, 3 to 10 slices (one of :data:`SLICES`)."""
    return max(s for s in SLICES if s <= max(3, runs // 10))


def moment_independent(x: np.ndarray, y: np.ndarray, seed: int = 0) -> tuple[list[Scores | None], Floor]:
    """The scores of each column of ``x`` (runs x inputs) for the outcome ``y`` (finite), and the
    floor of :data:`REFERENCES` independent inputs drawn with ``seed``. A column that does not
    vary has no score (None); nothing is scored when the outcome does not vary or there are
    fewer than 10 runs."""
    from SALib.analyze import pawn

    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    runs = len(y)
    if runs < 10:
        return [None] * x.shape[1], Floor(None, f"{runs} runs are too few for a distribution-based sensitivity")
    if np.ptp(y) == 0:
        return [None] * x.shape[1], Floor(None, "the outcome is the same in every run: no input moves it")
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31,)))
    varies = [j for j in range(x.shape[1]) if np.ptp(x[:, j]) > 0]
    columns = np.column_stack([x[:, varies], rng.uniform(size=(runs, REFERENCES))])
    bounds = [[float(c.min()), float(c.max())] for c in columns.T]
    problem = {"num_vars": len(bounds), "names": [f"x{j}" for j in range(len(bounds))], "bounds": bounds}
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():  # SALib's bin-merge notices
        warnings.simplefilter("ignore")
        p = pawn.analyze(problem, columns, y, S=slices(runs), seed=seed)
    out: list[Scores | None] = [None] * x.shape[1]
    for i, j in enumerate(varies):
        out[j] = Scores(float(p["maximum"][i]))
    floor = float(np.max(p["maximum"][len(varies) :]))
    note = (
        f"the largest PAWN score of {REFERENCES} inputs drawn independently of the loop is {floor:.3f} on these "
        f"{runs} runs: an input above it is told apart from no effect at level 0.05 (a rank test)"
    )
    return out, Floor(floor, note)


def above_floor(scores: Scores | None, floor: Floor) -> bool | None:
    """Whether ``scores``' PAWN score exceeds the floor (None when either is missing)."""
    if scores is None or floor.pawn is None or math.isnan(scores.pawn):
        return None
    return scores.pawn > floor.pawn
