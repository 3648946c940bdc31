"""Benchmark: peak memory of grid sweeps of 1e5 and 1e7 points (streamed to disk).

Each sweep runs in a fresh child process; its peak resident set size (``ru_maxrss``)
and throughput are printed, with the ratio of the two peaks: bounded memory means the
1e7 sweep needs about what the 1e5 sweep needs, not 100 times more.

Usage: ``python benchmarks/sweep_memory.py [MAX_POINTS]`` (default 1e7).
"""

from __future__ import annotations

import resource
import subprocess
import sys
import tempfile
import time

CHILD = """
import sys, numpy as np
from pathlib import Path
from dvfc.analysis.certify import GainPoint
from dvfc.analysis.grid import GridSpec, run_sweep
from dvfc.models.lie import SE3
from dvfc.models.loop import Weights
points = int(sys.argv[1])
side = round(points ** (1 / 3))
axes = (("k_c", np.geomspace(0.5, 10, side)), ("k_e_p", np.linspace(1, 20, side)),
        ("k_e_r", np.linspace(1, 20, points // side**2)))
design = GainPoint(np.full(6, 20.0), np.full(6, 3.0), np.full(6, 10.0), Weights(4, 1, 4, 1))
spec = GridSpec.around(design, SE3.from_xyz_rpy([0, 0, 0.35], [0, 0, 0]), axes)
state = run_sweep(spec, Path(sys.argv[2]))
print(spec.size, state.certified)
"""


def sweep(points: int) -> tuple[int, float, float]:
    """Run one sweep in a child process: (points, seconds, peak RSS of that child in MiB)."""
    with tempfile.TemporaryDirectory() as out:
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-c", CHILD, str(points), out], check=True, capture_output=True, text=True
        )
        seconds = time.perf_counter() - start
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    size = int(done.stdout.split()[0])
    return size, seconds, max(peak, before) / 1024


def main() -> None:
    largest = int(float(sys.argv[1])) if len(sys.argv) > 1 else 10**7
    small = sweep(10**5)
    big = sweep(largest)
    for size, seconds, peak in (small, big):
        print(f"  {size:>12,} points  {seconds:8.1f} s  {size / seconds:10,.0f} points/s  peak RSS {peak:8.1f} MiB")
    print(f"  peak RSS ratio (largest / 1e5): {big[2] / small[2]:.2f}")


if __name__ == "__main__":
    main()
