"""Benchmark: what a change of the plant or the schedule costs, and the certificate jobs on a cold cache.

1. On ``examples/ur5_cell.toml`` (as implemented, compiled into an empty cache of its own, so that every value is
   new to it): the nominal scenario built and run end to end once to fill the cache, then again (the baseline),
   then with a payload, the joints' friction, the camera mount or the latency changed: each the best of 3 (as the
   baseline: a run on shared cores varies by more than the ratios measured) and the first run's wall time, the
   ratio of the best to the baseline (target: at most 1.2x) and the libraries its first run added to the cache
   (target: none; every such change is an input of the compiled functions: the nominal plant too is a plant whose
   masses are inputs).
2. ``dvfc certify`` and ``dvfc verify`` of ``examples/xarm7_cell.toml`` in fresh processes, each with an empty
   compile cache (cold; target: within 30 s) and again with the libraries it wrote (warm).
3. With ``--synthesis``: ``dvfc synthesize --for-campaign examples/xarm7_cell.toml --workers 2`` (target: within
   10 minutes).

On cores shared with other work every time moves with the load; the load average is printed.

    python benchmarks/cost.py [--synthesis]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path

import tomli_w
from timing import best_of, seconds

import dvfc
from dvfc.analysis import compile as compile_module
from dvfc.analysis.sampled import as_implemented

ROOT = Path(__file__).resolve().parent.parent
CELL, XARM7 = ROOT / "examples" / "ur5_cell.toml", ROOT / "examples" / "xarm7_cell.toml"
CHANGES: dict[str, Callable[[dict], None]] = {
    "payload 0.4 kg": lambda d: d["plant"].update(payload={"mass": 0.4, "com": [0.0, 0.0, 0.03]}),
    "payload 0.7 kg": lambda d: d["plant"].update(payload={"mass": 0.7, "com": [0.0, 0.0, 0.03]}),
    "friction x1.5": lambda d: d["plant"]["friction"].update(
        coulomb=[1.5 * c for c in d["plant"]["friction"]["coulomb"]]),
    "camera mount 5 mrad": lambda d: d["plant"].update(mount={"xyz": [0.0, 0.0, 0.0], "rpy": [0.005, 0.0, 0.0]}),
    "latency 30 ms": lambda d: d["implementation"].update(latency=0.03),
    "latency 40 ms": lambda d: d["implementation"].update(latency=0.04),
}
"""The changes timed against the nominal cell, each an edit of its TOML (a second payload and latency: what a
change costs once the first has been made)."""


def end_to_end(data: dict, folder: Path) -> Callable[[], object]:
    """The scenario ``data`` written to a file of its own, read, built and run as implemented (a new file each
    time: nothing of an earlier build is reused but the compiled libraries and the symbolic loops)."""

    def job() -> object:
        path = folder / f"s{len(list(folder.iterdir()))}.toml"
        path.write_text(tomli_w.dumps(data))
        case = dvfc.load(path)
        return as_implemented(case.loop, case.settings).run(case.s0)

    return job


def changes() -> None:
    nominal = tomllib.loads(CELL.read_text())
    libraries = lambda: set(compile_module.cache_dir().glob("*.so"))  # noqa: E731 (the libraries compiled so far)
    previous = os.environ.get("DVFC_CACHE")
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as cache:
        os.environ["DVFC_CACHE"] = cache
        folder = Path(tmp)
        end_to_end(nominal, folder)()  # the nominal structure's libraries compiled once
        base = best_of(end_to_end(nominal, folder), 3)
        print(f"ur5_cell, {nominal['simulation']['duration']:g} s as implemented, built and run end to end")
        print(f"  nominal (baseline)          {base:7.2f} s")
        for name, edit in CHANGES.items():
            data = tomllib.loads(CELL.read_text())
            edit(data)
            before = libraries()
            first = seconds(end_to_end(data, folder))[0]
            compiled = len(libraries() - before)
            best = min(first, best_of(end_to_end(data, folder), 2))
            print(f"  {name:26s}  {best:7.2f} s  {best / base:5.2f}x the nominal  (first {first:5.2f} s)  "
                  f"{compiled} libraries compiled")  # fmt: skip
    os.environ.pop("DVFC_CACHE") if previous is None else os.environ.update(DVFC_CACHE=previous)


def command(args: list[str], cache: Path) -> float:
    """Wall time of ``dvfc args`` in a fresh process with the compile cache ``cache``."""
    env = {**os.environ, "DVFC_CACHE": str(cache)}
    binary = str(Path(sys.executable).parent / "dvfc")
    return seconds(lambda: subprocess.run([binary, *args], env=env, capture_output=True))[0]


def cold_certificates() -> None:
    print("xarm7_cell, fresh processes: cold (an empty compile cache), then warm")
    for name in ("certify", "verify"):
        with tempfile.TemporaryDirectory() as tmp:
            cold = command([name, str(XARM7), "--out", f"{tmp}/out"], Path(tmp) / "cache")
            warm = command([name, str(XARM7), "--out", f"{tmp}/out"], Path(tmp) / "cache")
        print(f"  dvfc {name:8s} cold {cold:6.1f} s   warm {warm:6.1f} s")


def synthesis() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        wall = command(["synthesize", str(XARM7), "--for-campaign", "--workers", "2", "--out", f"{tmp}/s.toml"],
                       Path.home() / ".cache" / "dvfc")  # fmt: skip
    print(f"dvfc synthesize --for-campaign xarm7_cell, 2 workers: {wall:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--synthesis", action="store_true")
    options = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at the start")
    changes()
    cold_certificates()
    if options.synthesis:
        synthesis()


if __name__ == "__main__":
    main()
