"""Long work talks: a progress line says how much is done, at what rate and about how long is left, also
when standard error is not a terminal; the campaign synthesis reports each batch of runs within a
generation, not only at its end."""

from __future__ import annotations

import pytest

from dvfc.analysis import cell, console
from dvfc.analysis.console import ProgressLines, remaining


@pytest.mark.parametrize(("done", "total", "elapsed", "words"), [
    (0, 10, 5.0, "estimate after the first"),
    (1, 4, 10.0, "about 30 s left"),
    (3, 4, 30.0, "about 10 s left"),
    (4, 4, 40.0, "about 0 s left"),
    (1, 100, 60.0, "about 99 min left"),
])  # fmt: skip
def test_the_time_left_is_the_rate_so_far_applied_to_what_remains(done, total, elapsed, words):
    """``(total - done) elapsed / done``, in seconds below ten minutes and in minutes above; nothing is
    promised before the first unit is done."""
    assert remaining(done, total, elapsed) == words


def test_a_progress_line_without_a_terminal_gives_the_time_left(monkeypatch):
    """Every :data:`PROGRESS_EVERY` seconds and at the end: done, total, percent, rate, elapsed and the time
    left; between two lines, nothing."""
    clock = iter([0.0, 1.0, 6.0, 12.0])
    lines: list[str] = []
    monkeypatch.setattr(console.time, "perf_counter", lambda: next(clock))
    monkeypatch.setattr(console, "warn", lines.append)
    progress = ProgressLines("campaign", 10, "runs")
    progress(1)  # 1 s after the start: too soon
    progress(3)  # 6 s
    progress(10)  # the end
    assert len(lines) == 2
    assert lines[0].startswith("campaign: 3 / 10 runs (30%)") and "about 14 s left" in lines[0]
    assert "10 / 10 runs (100%)" in lines[1] and "about 0 s left" in lines[1]


def test_the_campaign_synthesis_hears_of_every_batch_of_runs(monkeypatch):
    """``run_rows`` tells its listener the runs made so far of all its campaigns after each batch: rising to
    the total, one report a batch (two campaigns of 5 runs in batches of 3 and 2 on 2 workers)."""
    monkeypatch.setattr(cell, "run_tasks", lambda f, tasks, workers: ({"run": list(range(a, b))}
                                                                     for _, a, b in tasks))  # fmt: skip
    told: list[tuple[int, int]] = []
    first, second = object(), object()
    columns = cell.run_rows([first, second], 5, 2, lambda done, total: told.append((done, total)))
    assert told == [(3, 10), (5, 10), (8, 10), (10, 10)]
    assert columns == [{"run": [0, 1, 2, 3, 4]}] * 2
