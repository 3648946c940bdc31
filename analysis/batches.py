"""One resumable batch runner, for the grid's sweeps and the dispersion campaigns.

Items ``0 .. total - 1`` are made in batches (tasks of :func:`dvfc.analysis.tasks.run_tasks`), each
batch written atomically as one Parquet file ``<folder>/part-<first item>.parquet`` in the order the
batches finish in sequence, and the run's state saved after each (``<state file>``: the run's identity,
the items done and what the caller keeps of them). A run resumed continues from the recorded item:
batch files past it (of an interrupted batch, or of an older run) are removed first, so nothing is
counted twice and nothing lost; a run whose identity differs is refused.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import closing
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dvfc.analysis.output import atomic_write, json_text, raise_if_interrupted
from dvfc.analysis.tasks import run_tasks

if TYPE_CHECKING:
    import pyarrow as pa


def batches(start: int, total: int, size: int) -> Iterator[tuple[int, int]]:
    """The ranges ``(first, stop)`` of at most ``size`` items from ``start`` up to ``total``."""
    for lo in range(start, total, size):
        yield lo, min(lo + size, total)


@dataclass(frozen=True)
class BatchRun:
    """Where a batch run lives and what it is: ``directory / folder`` its parts, ``directory / state``
    its state, ``identity`` what a resumed run must match (the scenario's hash, the size, a seed), and
    ``other`` what a resume of another run is told ("the sweep in this directory belongs to ...")."""

    directory: Path
    folder: str
    state: str
    identity: dict[str, Any]
    other: str

    def part(self, first: int) -> Path:
        """The Parquet file of the batch starting at item ``first`` (names sort by it)."""
        return self.directory / self.folder / f"part-{first:012d}.parquet"

    def saved(self) -> dict[str, Any] | None:
        """The saved state (None: none)."""
        path = self.directory / self.state
        return json.loads(path.read_text()) if path.exists() else None

    def run(
        self,
        total: int,
        batch_size: int,
        task: Callable[[Any, int, int], dict[str, Any]],
        shared: Any,
        table: Callable[[dict[str, Any]], pa.Table],
        *,
        kept: dict[str, Any] | None = None,
        absorb: Callable[[dict[str, Any], dict[str, Any]], dict[str, Any]] | None = None,
        resume: bool = False,
        workers: int = 1,
        scheduler: str | None = None,
        progress: Callable[[int], None] | None = None,
        compression: str = "snappy",
    ) -> dict[str, Any]:
        """Make items ``0 .. total - 1`` by ``task(shared, first, stop)`` (its result a dict of columns,
        written as ``table(result)``), from the saved state with ``resume``. ``kept`` is what the caller
        keeps of the items (at the start), ``absorb(kept, result)`` its update by a batch; both saved.
        Returns the final state: ``done`` and the caller's ``kept``. ``progress`` gets the items done."""
        state: dict[str, Any] = {"done": 0, **(kept or {})}
        if resume and (saved := self.saved()) is not None:
            if any(saved.get(k) != v for k, v in self.identity.items()):
                raise ValueError(f"resume: {self.other}")
            state = {k: v for k, v in saved.items() if k not in self.identity}
        folder = self.directory / self.folder
        folder.mkdir(parents=True, exist_ok=True)
        for part in folder.glob("part-*.parquet"):  # batches past the recorded item (or of an older run)
            if int(part.stem.removeprefix("part-")) >= state["done"]:
                part.unlink()
        self._save(state)
        ranges = list(batches(state["done"], total, batch_size))
        with closing(run_tasks(task, ranges, workers, scheduler, shared=shared)) as results:
            for (first, stop), result in zip(ranges, results, strict=True):
                raise_if_interrupted()  # keep nothing of this batch
                written = table(result)
                atomic_write(self.part(first), partial(_write_table, written, compression=compression))
                state = {**(state if absorb is None else absorb(state, result)), "done": stop}
                self._save(state)
                if progress is not None:
                    progress(stop)
        return state

    def _save(self, state: dict[str, Any]) -> None:
        data = {**self.identity, **state}
        atomic_write(self.directory / self.state, lambda h: h.write(json_text(data).encode()))


def _write_table(table: pa.Table, handle, compression: str) -> None:
    """``table`` written as Parquet to ``handle`` (pyarrow imported here: a command's imports without it)."""
    import pyarrow.parquet as pq

    pq.write_table(table, handle, compression=compression)
