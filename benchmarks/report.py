"""Benchmark: ``dvfc report`` against ``dvfc verify`` on the same scenario.

For the default scenario and the 7-joint ``examples/xarm7_circle.toml``, in one run and each in
a fresh process: ``dvfc verify`` (the baseline: every claim checked on simulated runs) and
``dvfc report`` (the runs, the certificate with its lower bounds, the verification, the margins,
the gain map, the figures, HTML and PDF), on a warm compile cache (a report of the scenario cut
to 1 s compiles what it needs before the timing); then the same report again with ``--resume``
after an edit of the scenario's name (every stage kept, only the page made). Prints the wall and
processor times (the processes' and the C compiler's), the ratios report / verify, and the
report's own step table (``.dvfc-report/timings.txt``). Goal: a 7-joint report within 4 minutes
on 2 cores.

    python benchmarks/report.py [SCENARIO ...]
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = (ROOT / "analysis" / "scenarios" / "ur5_circle.toml", ROOT / "examples" / "xarm7_circle.toml")
DVFC = [sys.executable, "-m", "dvfc.reports"]


def timed(command: list[str]) -> tuple[float, float]:
    """Wall and processor time (s, the process and its children) of ``command`` (exit 0 or 1)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if run.returncode not in (0, 1):
        sys.exit(f"{' '.join(command)} failed ({run.returncode}):\n{run.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def edited(scenario: Path, directory: Path, name: str, change=None) -> Path:
    """The scenario with ``change(data)`` applied to its table (none: a copy), written to ``directory/name``."""
    data = tomllib.loads(scenario.read_text())
    if change is not None:
        change(data)
    path = directory / name
    path.write_text(tomli_w.dumps(data))
    return path


def bench(scenario: Path, directory: Path) -> None:
    warm = edited(scenario, directory, "warm.toml", lambda d: d.setdefault("simulation", {}).update(duration=1.0))
    timed([*DVFC, "report", str(warm), "--out", str(directory / "w")])
    path = edited(scenario, directory, scenario.name)
    t_verify = timed([*DVFC, "verify", str(path), "--out", str(directory / "v")])
    out = directory / "r"
    t_report = timed([*DVFC, "report", str(path), "--out", str(out)])
    table = (out / ".dvfc-report" / "timings.txt").read_text()
    renamed = edited(scenario, directory, scenario.name, lambda d: d.update(name="renamed"))
    t_resumed = timed([*DVFC, "report", str(renamed), "--out", str(out), "--resume"])
    print(f"{scenario.name}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end")
    for label, (wall, cpu) in (("dvfc verify (baseline)", t_verify), ("dvfc report", t_report),
                               ("dvfc report --resume, name edited", t_resumed)):  # fmt: skip
        print(f"  {label:36s} wall {wall:7.1f} s  {wall / t_verify[0]:5.2f}x   processor {cpu:7.1f} s  "
              f"{cpu / t_verify[1]:5.2f}x the baseline's")
    print("  the report's steps (.dvfc-report/timings.txt):")
    print("".join(f"    {line}\n" for line in table.rstrip().splitlines()), end="")


def main() -> None:
    scenarios = [Path(a) for a in sys.argv[1:]] or list(SCENARIOS)
    for scenario in scenarios:
        with tempfile.TemporaryDirectory() as directory:
            bench(scenario.resolve(), Path(directory))


if __name__ == "__main__":
    main()
