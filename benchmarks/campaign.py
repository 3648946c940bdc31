"""Benchmark: dispersion campaigns, each time against a baseline timed in the same run.

Times, on the default 10 s scenario: the nominal run as implemented (compiled, the baseline),
then campaign runs of the same loop with every dispersable field of
:data:`dvfc.analysis.dispersion.FIELDS` drawn (the cell example's ``[dispersion]`` and
``[plant] friction``, plus a small spread on every other field), on the campaign's shared
compiled functions: their runs per second against the nominal run's (target >= 0.67, i.e. at
most 1.5x its time). Then a campaign of ``--runs`` runs (default 1000) of the cell example
end to end with ``dvfc campaign --workers 2`` in a fresh process (target: within 3 minutes on 2
cores), against the nominal run's time times the runs over 2 workers; and ``--scaling-runs``
runs (default 100) with 1 and with 2 workers (target: 2 workers at least 1.8x faster). On cores
shared with other work every ratio moves with the load; the load average is printed, and the
campaign's processor time beside its wall time.

    python benchmarks/campaign.py [--runs N] [--scaling-runs N]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import tomllib
from dataclasses import replace
from pathlib import Path

from timing import seconds

from dvfc.analysis.campaign import CampaignSpec, run_campaign, shared_simulator, simulate_run
from dvfc.analysis.case import Case
from dvfc.analysis.dispersion import FIELDS
from dvfc.analysis.margins import tracking_bound
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario

CELL = Path(__file__).resolve().parent.parent / "examples" / "ur5_cell.toml"
SPREAD = {
    "plant.camera.fx": {"dist": "lognormal", "sigma": 0.01},
    "plant.camera.fy": {"dist": "lognormal", "sigma": 0.01},
    "implementation.latency": {"dist": "choice", "values": [0.018, 0.02, 0.022]},
    "implementation.outliers.size": {"dist": "uniform", "low": -10.0, "high": 10.0},
    "implementation.pixel_noise": {"dist": "uniform", "low": -0.2, "high": 0.5},
    "implementation.torque_scale": {"dist": "uniform", "low": 0.0, "high": 0.2},
    "observer.error_xyz": {"dist": "normal", "sigma": 0.002},
    "observer.error_rpy": {"dist": "normal", "sigma": 0.005},
    "robot.q0": {"dist": "normal", "sigma": 0.005},
    "robot.qd0": {"dist": "normal", "sigma": 0.005},
    "target.motion.radius": {"dist": "uniform", "low": -0.005, "high": 0.005},
    "plant.mass_scale": {"dist": "lognormal", "sigma": 0.02},
    "plant.payload.mass": {"dist": "uniform", "low": 0.0, "high": 0.1},
    "plant.payload.com": {"dist": "normal", "sigma": 0.005},
    "plant.payload.inertia": {"dist": "uniform", "low": 0.0, "high": [1e-5, 0.0, 0.0, 1e-5, 0.0, 1e-5]},
}
"""Small spreads on the dispersable fields the cell example leaves alone (so that every field is
drawn in the benchmark's runs)."""


def every_dispersion() -> Case:
    """The cell example with every field of :data:`FIELDS` dispersed."""
    data = tomllib.loads(CELL.read_text())
    data["dispersion"] = copy.deepcopy(data["dispersion"]) | SPREAD
    missing = set(FIELDS) - set(data["dispersion"])
    if missing:
        raise SystemExit(f"benchmark: no spread for {sorted(missing)}")
    return Case(Scenario.model_validate(data), CELL.parent)


def campaign_seconds(spec: CampaignSpec, runs: int, workers: int) -> float:
    """The wall time of ``runs`` runs of ``spec`` on ``workers`` local processes, in batches of
    :data:`SCALING_BATCH` runs (enough batches to keep both workers busy). Its case is loaded anew, so
    that each campaign builds its simulator as a campaign does (in this process with 1 worker, in each
    worker with 2; from the compile cache) and neither reuses this process's."""
    spec = replace(spec, case=every_dispersion())
    with tempfile.TemporaryDirectory() as directory:
        job = lambda: run_campaign(spec, Path(directory), runs, workers=workers, batch_size=SCALING_BATCH)  # noqa: E731
        return seconds(job)[0]


SCALING_BATCH = 10
"""Runs per batch of the 1-worker and 2-worker campaigns."""
PAIRS = 10
"""Nominal and dispersed runs timed in turn (so that both see the same load on shared cores)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--scaling-runs", type=int, default=100)
    args = parser.parse_args()
    default = Case.load(DEFAULT_SCENARIO)
    nominal = as_implemented(default.loop, default.settings)
    nominal.run(default.s0)  # compiled (or loaded from the cache) before timing
    case = every_dispersion()
    spec = CampaignSpec.of(case, tracking_bound(case))
    shared = shared_simulator(case)
    shared.run(case.s0)
    pairs = [(seconds(lambda: nominal.run(default.s0))[0], seconds(lambda k=k: simulate_run(spec, k, shared))[0])
             for k in range(PAIRS)]  # fmt: skip
    t_nominal, per_run = (statistics.median(times) for times in zip(*pairs, strict=True))
    t_one = campaign_seconds(spec, args.scaling_runs, 1)
    t_two = campaign_seconds(spec, args.scaling_runs, 2)
    with tempfile.TemporaryDirectory() as directory:
        command = [sys.executable, "-m", "dvfc.reports", "campaign", str(CELL), "--runs", str(args.runs),
                   "--workers", "2", "--out", directory, "--json", str(Path(directory) / "result.json")]  # fmt: skip
        cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t_campaign = seconds(lambda: subprocess.run(command, capture_output=True, check=False))[0]
        cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (cpu_after.ru_utime + cpu_after.ru_stime) - (cpu_before.ru_utime + cpu_before.ru_stime)
        result = json.loads((Path(directory) / "result.json").read_text())
    print(f"default scenario, {default.settings.duration:g} s runs, {os.cpu_count()} cores; load average "
          f"{os.getloadavg()[0]:.2f} at the end (the cores are shared)")  # fmt: skip
    print(f"  nominal run as implemented, compiled (baseline)   {t_nominal:8.3f} s   median of {PAIRS}")
    print(f"  run with all {len(FIELDS)} dispersable fields drawn        {per_run:8.3f} s   median of {PAIRS} runs; "
          f"runs per second {t_nominal / per_run:.3g}x the nominal's (target >= 0.67)")
    ideal = t_nominal * args.runs / 2
    verdict = ("met" if t_campaign <= 180 else "NOT met") if args.runs == 1000 else "not judged"
    print(f"  dvfc campaign {CELL.name}, {args.runs} runs, 2 workers  {t_campaign:8.1f} s   "
          f"{t_campaign / ideal:.3g}x {args.runs} nominal runs over 2 workers ({ideal:.1f} s); "
          f"target for 1000 runs 180 s: {verdict}")
    print(f"    its processor time {cpu:.1f} s ({cpu / args.runs:.3f} s a run): {cpu / 2:.1f} s of wall time on 2 "
          f"cores of its own; wall / that {t_campaign / (cpu / 2):.3g}x (the share of the cores it had)")
    print(f"    its statement: {result['failures']} failures in {result['runs']} runs, "
          f"P(fail) <= {result['p_fail_upper']:.3g} at {result['confidence']:.0%}")
    print(f"  {args.scaling_runs} runs on 1 worker (baseline)              {t_one:8.1f} s")
    print(f"  {args.scaling_runs} runs on 2 workers                        {t_two:8.1f} s   "
          f"speed-up {t_one / t_two:.3g}x (target >= 1.8)")


if __name__ == "__main__":
    main()
