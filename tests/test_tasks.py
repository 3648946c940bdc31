"""The one executor of the jobs that fan out (analysis/tasks.py): stopped early (Ctrl-C, or the parent's SIGINT
alone), its worker processes stop their running tasks within a step and start none of the queued ones."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from dvfc.analysis.tasks import run_tasks

STEPS = 2000
"""Steps of 10 ms a task makes when nothing stops it (20 s)."""


def stepping(log: Path, steps: int) -> int:
    """A task of ``steps`` steps of 10 ms, each appended to ``log`` with the worker's pid."""
    for _ in range(steps):
        time.sleep(0.01)
        with open(log, "a") as handle:
            handle.write(f"{os.getpid()}\n")
    return steps


def test_stopping_early_stops_the_workers_running_tasks_and_starts_no_queued_one(tmp_path):
    """Four tasks on two workers; once both run, the parent is interrupted (``KeyboardInterrupt`` where it
    awaits a result, as Ctrl-C raises it): the two running tasks stop within a few steps of it, the two queued
    ones never start, and no worker process is left."""
    logs = [tmp_path / f"{i}.log" for i in range(4)]
    running = lambda: [log for log in logs if log.exists()]  # noqa: E731

    def poll() -> None:
        if len(running()) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        list(run_tasks(stepping, [(log, STEPS) for log in logs], workers=2, poll=poll))
    stopped = {log: len(log.read_text().splitlines()) for log in running()}
    pids = {int(line) for log in stopped for line in log.read_text().split()}
    time.sleep(0.5)  # a task that had not stopped would still be writing
    assert set(stopped) == set(logs[:2])
    assert all(len(log.read_text().splitlines()) == count < STEPS / 2 for log, count in stopped.items())
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
