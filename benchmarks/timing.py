"""Wall time of a job, for the benchmarks (each prints ratios against a baseline timed in
the same run, never an absolute budget)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def seconds(job: Callable[[], object], repeat: int = 1) -> list[float]:
    """The wall time (s) of each of ``repeat`` runs of ``job``."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        job()
        times.append(time.perf_counter() - start)
    return times


def best_of(job: Callable[[], object], repeat: int = 5) -> float:
    """The shortest of ``repeat`` runs (the least disturbed by other work on the machine)."""
    return min(seconds(job, repeat))


def median_of(job: Callable[[], object], repeat: int = 20) -> float:
    """The median of ``repeat`` runs (for jobs of milliseconds)."""
    return statistics.median(seconds(job, repeat))
