"""The command line's terminal: its consoles (standard output and error, as wide as a terminal or a
stated width when not one) and its progress (a bar on a terminal, a plain line every few seconds
otherwise: CI logs, nohup)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from rich.console import Console, ConsoleDimensions
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

WIDTH = 200
"""The columns of a table written to a file or a pipe (a terminal's own width otherwise): wide
enough that no column is cut, the same wherever the output goes."""

PROGRESS_EVERY = 5.0
"""Seconds between progress lines when standard error is not a terminal (CI logs, nohup)."""


class FileConsole(Console):
    """A console whose output is not a terminal: ``$COLUMNS`` columns, read at each print, or
    :data:`WIDTH` without it."""

    @property
    def size(self) -> ConsoleDimensions:
        columns = os.environ.get("COLUMNS", "")
        return ConsoleDimensions(int(columns) if columns.isdigit() else WIDTH, super().size.height)

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        Console.size.fset(self, new_size)  # type: ignore[attr-defined]  # rich's property setter


def console(stderr: bool = False) -> Console:
    """A console as wide as its terminal, or a :class:`FileConsole` when the output is not one."""
    terminal = Console(stderr=stderr)
    return terminal if terminal.is_terminal else FileConsole(stderr=stderr)


err = console(stderr=True)
out = console()


def say(text: str, console_: Console | None = None) -> None:
    """One plain line (no markup, wrapped softly) on standard output, or on ``console_``."""
    (console_ or out).print(text, markup=False, soft_wrap=True)


def warn(text: str) -> None:
    """One plain line on standard error."""
    say(text, err)


def remaining(done: float, total: float, elapsed: float) -> str:
    """The estimate of the time left when ``done`` of ``total`` took ``elapsed`` seconds (at the rate so far),
    in words; "estimate after the first" before anything is done."""
    if done <= 0:
        return "estimate after the first"
    left = max(total - done, 0.0) * elapsed / done
    return f"about {left / 60:.0f} min left" if left >= 600 else f"about {left:.0f} s left"


class ProgressLines:
    """Progress for a standard error that is not a terminal: one plain line every
    :data:`PROGRESS_EVERY` seconds (and at the end), ``label: done / total unit (percent), rate, elapsed,
    the time left at that rate``."""

    def __init__(self, label: str, total: float, unit: str) -> None:
        self.label, self.total, self.unit, self.every = label, total, unit, PROGRESS_EVERY
        self.start = self.last = time.perf_counter()

    def __call__(self, done: float) -> None:
        now = time.perf_counter()
        if now - self.last < self.every and done < self.total:
            return
        self.last = now
        elapsed = max(now - self.start, 1e-9)
        warn(f"{self.label}: {done:,.4g} / {self.total:,.4g} {self.unit} ({100 * done / self.total:.0f}%), "
             f"{done / elapsed:,.3g} {self.unit} a second, {elapsed:.0f} s elapsed, "
             f"{remaining(done, self.total, elapsed)}")  # fmt: skip


@contextmanager
def progress_bar(label: str, total: float, unit: str, *, start: str = "") -> Iterator[Callable[[float], None]]:
    """Progress of ``total`` ``unit`` on standard error: a bar on a terminal (described as ``start``
    until the first report), plain :class:`ProgressLines` otherwise; yields the function that reports
    how much is done."""
    columns = (TextColumn(f"[bold]{label}[/] {{task.description}}"), BarColumn(),
               TextColumn(f"{{task.completed:,.4g}} / {{task.total:,.4g}} {unit}"), TimeElapsedColumn(),
               TimeRemainingColumn())  # fmt: skip
    with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task(start, total=total)
        lines = None if err.is_terminal else ProgressLines(label, total, unit)

        def advance(done: float) -> None:
            bar.update(task, completed=done, description="")
            if lines is not None:
                lines(done)

        yield advance


@contextmanager
def announcing(text: str) -> Iterator[Callable[[str], None]]:
    """A status line on standard error starting with ``text``; yields the function that replaces it (also
    a line of its own when standard error is not a terminal)."""
    with err.status(text) as status:

        def announce(now: str) -> None:
            status.update(now)
            if not err.is_terminal:
                warn(now)

        yield announce


def status(text: str) -> Any:
    """A status line on standard error for work without steps to count."""
    return err.status(text)
