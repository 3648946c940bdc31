"""Benchmark: ``margins()`` on the default scenario, against one continuous run.

Times, in one process: one 10 s run of the continuous loop (compiled, the baseline), one
run of the loop as implemented, fact 14's linearisation at rest and its monodromy with the
three linear margins (also against the run as implemented), one run with a 1 kg payload on the nominal
run's compiled libraries (a payload is an input of the plant's functions: nothing is built) and the same
run in CasADi's virtual machine, then the whole margin search of
:func:`dvfc.analysis.margins.margins` with ``--workers`` local processes (default 2). Prints the
times and their ratios to the continuous run.

    python benchmarks/margins.py [--workers N]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from timing import best_of, seconds

from dvfc.analysis.case import Case
from dvfc.analysis.margins import margins, with_value
from dvfc.analysis.multirate import linear_margins, multirate_loop, spectral_radius
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, build, load
from dvfc.analysis.tasks import run_tasks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    workers = parser.parse_args().workers
    spec, base = load(DEFAULT_SCENARIO)
    loop, s0, settings = build(spec, base)
    continuous = as_implemented(loop, replace(settings, implementation=None, plant=None))
    continuous.run(s0)  # compiled (or loaded from the cache) before timing
    t_continuous = seconds(lambda: continuous.run(s0))[0]
    sampled = as_implemented(loop, settings)
    sampled.run(s0)
    t_sampled = seconds(lambda: sampled.run(s0))[0]
    imp = settings.implementation
    t_linearise = best_of(lambda: multirate_loop(loop, s0[: loop.robot.n], imp), 3)
    linear = multirate_loop(loop, s0[: loop.robot.n], imp)

    def fact14() -> None:
        system = replace(linear, _maps={})  # the period maps (matrix exponentials) computed anew
        spectral_radius(system.monodromy(imp)[0])
        linear_margins(system)

    t_fact14 = best_of(fact14, 3)
    payload = with_value(loop, settings, "payload_mass", 1.0)
    t_payload = seconds(lambda: as_implemented(loop, payload).run(s0))[0]  # the nominal run's libraries
    t_vm = seconds(lambda: as_implemented(loop, replace(payload, jit=False)).run(s0))[0]
    with tempfile.TemporaryDirectory() as directory:
        start = time.perf_counter()
        result = margins(Case.load(DEFAULT_SCENARIO), Path(directory),
                         map_tasks=lambda f, a: run_tasks(f, a, workers))  # fmt: skip
        t_margins = time.perf_counter() - start
    runs = sum(m.get("runs", 0) for m in result.margins.values())
    print(f"default scenario, {settings.duration:g} s runs, {os.cpu_count()} cores, {workers} workers")
    rows = (
        ("continuous run, compiled (baseline)", t_continuous),
        ("run as implemented, compiled", t_sampled),
        ("fact 14: linearisation at rest", t_linearise),
        ("fact 14: monodromy and its 3 margins", t_fact14),
        ("payload run, compiled (no new library)", t_payload),
        ("payload run, virtual machine", t_vm),
        (f"margins(), {runs} runs + 2", t_margins),
    )
    for label, wall in rows:
        print(f"  {label:40s} {wall:8.2f} s   {wall / t_continuous:8.1f}x the baseline")
    print(f"  fact 14's monodromy and margins: {t_fact14 / t_sampled:.3g}x one run as implemented")
    print(f"  a payload's run: {t_payload / t_sampled:.3g}x the nominal run as implemented")
    fmt = lambda v: "-" if v is None else f"{v:.4g}"  # noqa: E731
    for name, m in result.margins.items():
        print(f"  {name:14s} holds at {fmt(m['holds_at']):>8}  breaks at {fmt(m['breaks_at']):>8}  {m['unit']}")
    for name, m in result.linear_margins["margins"].items():
        print(f"  linear {name:12s} stable at {fmt(m['stable_at']):>8}  unstable at {fmt(m['unstable_at']):>8}  "
              f"{m['unit']}")


if __name__ == "__main__":
    main()
