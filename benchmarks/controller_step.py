"""Benchmark: one step of the exported controller (``dvfc export``), compiled C, against the same
CasADi function called from Python.

For the default UR5 and a 7-joint arm (the xArm 7 as implemented, tests/data/xarm7_sampled.toml):
the time of each of ``--calls`` (default 1e5) calls of ``dvfc_step`` measured in C around the call
(``dvfc_timing.c``), without an image and with one at every call, as min, median, p99.9 and max, in
wall time (``CLOCK_MONOTONIC``: preemption by the machine's other work included) and in the thread's
CPU time (``CLOCK_THREAD_CPUTIME_ID``: the step's own cost); then the median of 2000 calls of
:meth:`dvfc.analysis.controller.Controller.step` (CasADi's virtual machine through its buffer
interface) and its ratio to the compiled median.
Measurements on a shared machine, not a real-time guarantee: the worst case of a real controller is
a property of its real-time kernel too. Goal: p99.9 at most 50 us.

    python benchmarks/controller_step.py [--calls N]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import dvfc
from dvfc.analysis.controller import Controller
from dvfc.analysis.export import compiled_controller, generate, initial_features, timing
from dvfc.analysis.scenario import DEFAULT_SCENARIO

ROOT = Path(__file__).resolve().parent.parent
ARMS = (("UR5 (6 joints)", DEFAULT_SCENARIO), ("xArm 7 (7 joints)", ROOT / "tests" / "data" / "xarm7_sampled.toml"))


def python_median_us(case, calls: int = 2000) -> float:
    """The median time (us) of :meth:`Controller.step` at the case's start, with an image every call."""
    controller = Controller(case)
    n, x = controller.n, controller.initial_state()
    q, qd, f = case.s0[:n], case.s0[n : 2 * n], initial_features(case)
    times = []
    for k in range(calls):
        start = time.perf_counter()
        _, x = controller.step(x, k * controller.period, q, qd, f, k)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=100_000)
    calls = parser.parse_args().calls
    load = os.getloadavg()
    print(f"load average {load[0]:.1f} on {os.cpu_count()} cores (the tail of the wall times is the machine's)")
    for name, path in ARMS:
        case = dvfc.load(path)
        with tempfile.TemporaryDirectory() as folder:
            compiled = compiled_controller(case, generate(case, Path(folder)))
            results = [timing(case, compiled, calls, image, cpu) for cpu in (False, True) for image in (False, True)]
        print(f"{name}: {calls} calls of the compiled step (us)")
        for r in results:
            label = ("CPU " if r.cpu else "wall") + (" with an image" if r.image else " no image     ")
            print(f"  {label}  min {r.min_us:7.2f}  median {r.median_us:7.2f}  p99.9 {r.p999_us:8.2f}  "
                  f"max {r.max_us:8.2f}")  # fmt: skip
        python = python_median_us(case)
        ratio = python / results[1].median_us  # wall, with an image
        print(f"  Python (CasADi VM) median {python:.1f} us with an image: {ratio:.1f}x the C wall median")
        for cpu in (False, True):
            worst = max(r.p999_us for r in results if r.cpu == cpu)
            verdict = "met" if worst <= 50 else "NOT met"
            print(f"  goal p99.9 <= 50 us in {'CPU' if cpu else 'wall'} time: {verdict} ({worst:.1f} us, measured)")


if __name__ == "__main__":
    main()
