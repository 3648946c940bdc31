"""Gain-grid sweeps of the Theorem 2 certificate: batched, stored as Parquet, resumable.

The cartesian product of the ``[grid]`` axes is enumerated by a flat index; batches of
consecutive indices are certified with the exact closed form (docs/math.md, fact 3) and an
a posteriori eigenvalue check of the ``(e_c, e_e)`` block of ``P`` (the ``xi`` block is
diagonal and checked directly). Anisotropic ``K_e`` uses the blockwise-minimum bound
(docs/math.md, fact 5), sound for every ``R_ec``; grids do not run the worst-rotation search.

Each batch is written as one Parquet file (zstd) in ``points/``, atomically (temporary
file, then rename): the folder is one dataset for pyarrow, pandas, polars and Dask. After
each batch the number of points done is written atomically to ``sweep.json``. A resumed
sweep removes any batch file past the recorded point and continues there: nothing lost,
nothing repeated. :func:`export_csv` writes the same rows as one CSV file.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from dvfc.analysis.batches import BatchRun
from dvfc.analysis.certify import INFLATION, GainPoint, Reason, exact_s, gamma_of, output_blocks, sound_k_e, xi_limits
from dvfc.analysis.envelope import GridEnvelope, envelope_columns
from dvfc.analysis.output import atomic_write
from dvfc.models.lie import SE3, SO3
from dvfc.models.loop import PlantWeights
from dvfc.models.planar import TASK, planar_output_matrix

if TYPE_CHECKING:
    import pyarrow as pa

AXES = {
    "k_xi": ("k_xi", None),
    "k_c": ("k_c", slice(0, 6)),
    "k_c_p": ("k_c", slice(0, 3)),
    "k_c_r": ("k_c", slice(3, 6)),
    "k_e": ("k_e", slice(0, 6)),
    "k_e_p": ("k_e", slice(0, 3)),
    "k_e_r": ("k_e", slice(3, 6)),
    "w_pc": ("w", 0),
    "w_rc": ("w", 1),
    "w_pe": ("w", 2),
    "w_re": ("w", 3),
}
"""Sweepable names: a gain vector (all entries), its translational (``_p``) or
rotational (``_r``) half, or one weight."""

PAPER_ONLY_AXES = ("k_c_r", "k_e_r", "w_rc", "w_re")
"""Axes without meaning for the planar loop (it has no rotational task)."""


@dataclass(frozen=True)
class GridSpec:
    """A base design and the axes swept around it (all plain arrays: picklable)."""

    k_xi: np.ndarray
    k_c: np.ndarray
    k_e: np.ndarray
    weights: np.ndarray
    p_d: np.ndarray
    r_d: np.ndarray
    axes: tuple[tuple[str, np.ndarray], ...]
    gamma_bound: float | None = None
    envelope: GridEnvelope | None = None
    """With a scenario's ``[envelope]``: the context of the columns ``rate`` and
    ``max_target_speed`` (:func:`dvfc.analysis.envelope.envelope_columns`)."""
    plant: PlantWeights | None = None
    """The generalized plant's weights every point is certified for (docs/math.md, fact 17;
    None: the paper's)."""

    @property
    def planar(self) -> bool:
        """The reduced planar loop (:mod:`dvfc.models.planar`): two-entry ``K_c``, ``K_e``."""
        return len(self.k_c) == TASK

    @staticmethod
    def around(
        point: GainPoint, reference: SE3, axes, gamma_bound: float | None = None, envelope: GridEnvelope | None = None
    ) -> GridSpec:
        """The grid of ``axes`` (name, values) around the design ``point`` (of the paper's
        loop, or of the planar loop when its ``K_c`` has two entries)."""
        w = point.weights
        if len(point.k_c) == TASK:
            unused = [name for name, _ in axes if name in PAPER_ONLY_AXES]
            if unused:
                raise ValueError(f"grid.{unused[0]}: the planar loop has no rotational gains or weights to sweep")
        return GridSpec(
            point.k_xi, point.k_c, point.k_e, w.as_array(),
            np.asarray(cs.DM(reference.translation)).ravel(), np.asarray(cs.DM(reference.rotation.matrix)),
            tuple(axes), gamma_bound, envelope, point.plant,
        )  # fmt: skip

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for _, v in self.axes)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def values(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """The axis values of points ``start .. stop - 1``."""
        index = np.unravel_index(np.arange(start, stop), self.shape)
        return {name: vals[i] for (name, vals), i in zip(self.axes, index, strict=True)}

    def designs(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Gains and weights of points ``start .. stop - 1`` as batched arrays."""
        b = stop - start
        out = {
            "k_xi": np.tile(self.k_xi, (b, 1)),
            "k_c": np.tile(self.k_c, (b, 1)),
            "k_e": np.tile(self.k_e, (b, 1)),
            "w": np.tile(self.weights, (b, 1)),
        }
        for name, column in self.values(start, stop).items():
            target, where = AXES[name]
            if where is None:
                out[target][:] = column[:, None]
            elif isinstance(where, int):
                out[target][:, where] = column
            else:
                out[target][:, where] = column[:, None]
        return out


def certify_batch(spec: GridSpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """Certify points ``start .. stop - 1``: gamma, margin, certified flag, reason code
    (:class:`~dvfc.analysis.certify.Reason`: 0 certified, 1-3 the certifier's, 4 failed re-check, 5 above
    the bound)."""
    d = spec.designs(start, stop)
    b = stop - start
    weights, which = np.unique(d["w"], axis=0, return_inverse=True)  # N depends on the weights only
    if spec.planar:
        k_e_sound, w_e = d["k_e"], np.repeat(d["w"][:, 2:3], TASK, axis=1)
        n_ce = np.stack([planar_output_matrix(w[0], w[2], 0) for w in weights])[which.ravel()]
    else:
        k_e_sound = sound_k_e(d["k_e"])
        w_e = np.repeat(d["w"][:, 2:], 3, axis=1)
        reference = SE3(spec.p_d, SO3(spec.r_d))
        n_ce = output_blocks(weights, reference, np.tile(np.eye(3), (len(weights), 1, 1)))[which.ravel()]
    n, t = d["k_xi"].shape[1], w_e.shape[1]
    plant = spec.plant if spec.plant is not None else PlantWeights.unit(n)
    xi_limit = xi_limits(d["k_xi"], plant)
    s2, d_w = plant.output(t) ** 2, plant.disturbance(t)
    scaled = w_e * d_w[n:]  # W_e D_v (docs/math.md, fact 17)
    s, reason, a = exact_s(n_ce, xi_limit, d["k_c"], k_e_sound, scaled, s2[n:])
    gamma = gamma_of(s) * (1 + INFLATION)
    finite = np.isfinite(gamma)
    s_check = np.where(finite, 1.0 / (2 * np.where(finite, gamma, 1.0) ** 2), 0.0)
    w_ce = np.concatenate([np.zeros((b, t)), scaled**2], axis=1)
    p = a - s_check[:, None, None] * (w_ce[:, :, None] * np.eye(2 * t))
    xi_block = (d["k_xi"] - 0.5 * s2[:n] - s_check[:, None] * d_w[:n] ** 2).min(axis=1)
    margin = np.minimum(np.linalg.eigvalsh((p + p.transpose(0, 2, 1)) / 2)[:, 0], xi_block)
    margin = np.where(finite, margin, np.nan)
    reason = np.where((reason == Reason.CERTIFIED) & (margin < 0), Reason.RECHECK, reason)
    if spec.gamma_bound is not None:
        reason = np.where((reason == Reason.CERTIFIED) & (gamma > spec.gamma_bound), Reason.ABOVE_BOUND, reason)
    certified = reason == Reason.CERTIFIED
    extra = {}
    if spec.envelope is not None:
        nkn = a + 0.5 * np.diag(s2[n:])  # the envelope's W is the unweighted one (facts 7-10)
        unweighted = np.concatenate([np.zeros((b, t)), w_e**2], axis=1)
        extra["rate"], extra["max_target_speed"] = envelope_columns(spec.envelope, nkn, unweighted, d["k_xi"], d["w"])
    return {
        **extra,
        "index": np.arange(start, stop),
        "gain_norm": np.linalg.norm(np.hstack([d["k_xi"], d["k_c"], d["k_e"]]), axis=1),
        "gamma": np.where(finite, gamma, np.nan),
        "margin": margin,
        "certified": certified,
        "reason": reason,
        **spec.values(start, stop),
    }




POINTS = "points"
"""Folder of the grid's results in the output directory: one Parquet file per batch."""

BYTES_PER_POINT = 20
"""Disk size of one grid point in Parquet (zstd), for the estimate printed before a sweep:
gamma and margin (8 bytes each, nearly incompressible) plus the index, the axis values,
the flag and the reason code (a few bytes after dictionary and run-length encoding); the
measured size is in docs/measured.md (``benchmarks/certify.py``), at most this."""


def batch_table(result: dict[str, np.ndarray], axes: list[str]) -> pa.Table:
    """A batch as a table: ``index``, the axis values, ``certified``, ``gamma`` and ``margin``
    (null where no gamma exists) and ``reason`` (code, see :class:`~dvfc.analysis.certify.Reason`)."""
    import pyarrow as pa  # here: a command's imports without it

    nan = lambda v: pa.array(v, mask=np.isnan(v))  # noqa: E731
    return pa.table({
        "index": pa.array(result["index"], pa.uint64()),
        **{a: pa.array(result[a], pa.float64()) for a in axes},
        "certified": pa.array(result["certified"]),
        "gamma": nan(result["gamma"]),
        "margin": nan(result["margin"]),
        "reason": pa.array(result["reason"].astype(np.uint8)),
        **{k: nan(result[k]) for k in ENVELOPE_COLUMNS if k in result},
    })  # fmt: skip


ENVELOPE_COLUMNS = ("rate", "max_target_speed")
"""Columns added when the scenario has an ``[envelope]`` (null where not certified)."""


def read_points(directory: Path) -> pa.Table:
    """Every point of a sweep in ``directory``, in index order."""
    import pyarrow.parquet as pq

    return pq.read_table(directory / POINTS).sort_by("index")


def export_csv(directory: Path, target: Path) -> None:
    """The sweep's points as one CSV file (header, then one row per point), atomically."""
    parts = sorted((directory / POINTS).glob("part-*.parquet"))

    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    def write(handle) -> None:
        for i, part in enumerate(parts):
            pacsv.write_csv(pq.read_table(part), handle, pacsv.WriteOptions(include_header=i == 0))

    atomic_write(target, write)


@dataclass
class SweepState:
    """Progress of a sweep: points done and certified, and the points worth naming, each as
    ``(value, index)``: ``best`` the smallest certified gamma, ``worst`` the largest gamma
    (infinite when some point is not certified), ``cheapest`` the certified point of smallest
    gain norm ``|[k_xi; k_c; k_e]|`` (with a gamma requirement: the cheapest meeting it)."""

    done: int
    certified: int
    best: tuple[float, int] | None
    worst: tuple[float, int] | None
    cheapest: tuple[float, int] | None


def run_sweep(
    spec: GridSpec,
    directory: Path,
    *,
    batch_size: int = 20000,
    workers: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[int], None] | None = None,
    scenario_sha256: str = "",
) -> SweepState:
    """Certify every grid point, one Parquet file per batch in ``directory / points``; resumable
    (:class:`dvfc.analysis.batches.BatchRun`, its state ``sweep.json``)."""
    axes = [name for name, _ in spec.axes]
    run = BatchRun(directory, POINTS, "sweep.json", {"scenario_sha256": scenario_sha256, "total": spec.size},
                   "the sweep in this directory belongs to another scenario or grid")  # fmt: skip

    def absorb(kept: dict, result: dict[str, np.ndarray]) -> dict:
        state = _state(kept)
        _record(state, result)
        return _saved(state)

    final = run.run(spec.size, batch_size, certify_batch, spec, lambda result: batch_table(result, axes),
                    kept=_saved(SweepState(0, 0, None, None, None)), absorb=absorb, resume=resume, workers=workers,
                    scheduler=scheduler, progress=progress, compression="zstd")  # fmt: skip
    return _state(final)


def _saved(state: SweepState) -> dict:
    """The sweep's state as ``sweep.json`` keeps it."""
    named = (("best", state.best), ("worst", state.worst), ("cheapest", state.cheapest))
    return {"done": state.done, "certified": state.certified, **{k: list(v) if v else None for k, v in named}}


def _state(saved: dict) -> SweepState:
    """The sweep's state of ``sweep.json``."""
    return SweepState(saved["done"], saved["certified"], *(_named(saved[k]) for k in ("best", "worst", "cheapest")))


def _named(saved: list | None) -> tuple[float, int] | None:
    """A named point of ``sweep.json`` as :class:`SweepState` holds it: ``(value, index)``, the value
    infinite where the strict JSON has null (the worst point when no gamma is certified)."""
    if not saved:
        return None
    value, index = saved
    return (math.inf if value is None else float(value), int(index))


def _record(state: SweepState, result: dict[str, np.ndarray]) -> None:
    """Count a written batch into the sweep state (done, certified, best, worst, cheapest)."""
    state.done = int(result["index"][-1]) + 1
    certified = result["certified"]
    state.certified += int(certified.sum())
    gammas = np.where(certified, result["gamma"], np.inf)
    i = int(np.argmin(gammas))
    if np.isfinite(gammas[i]) and (state.best is None or gammas[i] < state.best[0]):
        state.best = (float(gammas[i]), int(result["index"][i]))
    j = int(np.argmax(gammas))
    if state.worst is None or gammas[j] > state.worst[0]:
        state.worst = (float(gammas[j]), int(result["index"][j]))
    costs = np.where(certified, result["gain_norm"], np.inf)
    k = int(np.argmin(costs))
    if np.isfinite(costs[k]) and (state.cheapest is None or costs[k] < state.cheapest[0]):
        state.cheapest = (float(costs[k]), int(result["index"][k]))


@dataclass(frozen=True)
class GainMap:
    """The certified gamma over one or two swept axes, every other gain at the design.

    ``gamma`` and ``certified`` have shape ``(len(y), len(x))`` (one row for a single axis).
    """

    x_axis: str
    y_axis: str | None
    x: np.ndarray
    y: np.ndarray
    gamma: np.ndarray
    certified: np.ndarray
    note: str
    quantity: str = "gamma"
    """What the map shows: ``gamma``, or an envelope column (``rate``, ``max_target_speed``)."""
    values: np.ndarray | None = None
    """The shown quantity (NaN where not certified); None for ``gamma``."""

    def shown(self) -> np.ndarray:
        """The map's values, NaN where nothing is certified."""
        if self.values is None:
            return np.where(self.certified, self.gamma, np.nan)
        return self.values

    def best(self) -> dict[str, float]:
        """The certified point of smallest gamma: axis values and gamma."""
        gamma = np.where(self.certified, self.gamma, np.inf)
        if not np.isfinite(gamma).any():
            raise ValueError("no point of the map is certified")
        row, col = np.unravel_index(np.argmin(gamma), gamma.shape)
        point = {self.x_axis: float(self.x[col]), "gamma": float(gamma[row, col])}
        if self.y_axis is not None:
            point[self.y_axis] = float(self.y[row])
        return point


MAP_RESOLUTION = 81
"""Largest number of values per axis of a :class:`GainMap` (longer axes are subsampled)."""


def gain_map(
    point: GainPoint, reference: SE3, axes=None, gamma_bound: float | None = None, resolution: int = MAP_RESOLUTION,
    envelope: GridEnvelope | None = None, quantity: str = "gamma",
) -> GainMap:
    """Certify the plane of the first two of ``axes`` (name, values) through the design
    ``point``; without axes, ``k_c`` and ``k_e`` from a tenth to ten times their mean. With an
    ``envelope`` context, ``quantity`` may be one of :data:`ENVELOPE_COLUMNS`."""  # fmt: skip
    if not axes:
        axes = [(name, np.geomspace(v.mean() / 10, v.mean() * 10, resolution))
                for name, v in (("k_c", point.k_c), ("k_e", point.k_e))]  # fmt: skip
        note = "scenario without [grid]: k_c and k_e (all six entries) from 1/10 to 10 times the design's mean"
    else:
        note = "the first two [grid] axes" if len(axes) > 1 else "the [grid] axis"
        if len(axes) > 2:
            note += f"; {', '.join(name for name, _ in axes[2:])} at the design's value"
    plane = []
    for name, values in axes[:2]:
        pick = np.unique(np.linspace(0, len(values) - 1, min(len(values), resolution)).round().astype(int))
        plane.append((name, np.asarray(values, dtype=float)[pick]))
    spec = GridSpec.around(point, reference, plane[::-1], gamma_bound, envelope)  # last axis fastest: x
    result = certify_batch(spec, 0, spec.size)
    x_name, x = plane[0]
    y_name, y = plane[1] if len(plane) > 1 else (None, np.zeros(1))
    shape = (len(y), len(x))
    values = None if quantity == "gamma" else result[quantity].reshape(shape)
    return GainMap(x_name, y_name, x, y, result["gamma"].reshape(shape), result["certified"].reshape(shape), note,
                   quantity, values)  # fmt: skip


def axis_value(point: GainPoint, name: str) -> float:
    """The design's value on a sweepable axis (the mean of the entries it sets)."""
    target, where = AXES[name]
    if target == "w":
        return float(point.weights.as_array()[where])
    values = getattr(point, target)
    return float(np.mean(values if where is None else values[where]))
