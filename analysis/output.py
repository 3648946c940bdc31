"""Writing results: atomic files (temporary file, then rename) and provenance."""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import IO, Any

DEPENDENCIES = (
    "casadi", "numpy", "scipy", "cvxpy", "clarabel", "scs", "control", "adam-robotics", "example-robot-data",
    "matplotlib", "pydantic", "jinja2", "weasyprint",
)  # fmt: skip


def atomic_write(path: Path, write: Callable[[IO[bytes]], object]) -> None:
    """Write ``path`` through ``write`` into a temporary file in the same directory,
    then rename it over ``path``: readers never see a partial file."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def strict(data: Any) -> Any:
    """``data`` with every non-finite number (NaN, an infinity) replaced by None, in every
    dictionary, list and tuple it holds: JSON has no such numbers, ``null`` stands for "no
    number"."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {key: strict(value) for key, value in data.items()}
    if isinstance(data, list | tuple):
        return [strict(value) for value in data]
    return data


def json_text(data: Any, indent: int | None = 2) -> str:
    """``data`` as strict JSON (:func:`strict`; ``allow_nan=False`` guards it), one line when
    ``indent`` is None, with a final newline."""
    return json.dumps(strict(data), indent=indent, allow_nan=False) + "\n"


def write_json(target: str | Path, data: Any) -> None:
    """JSON to a file (atomically) or, for ``"-"``, to standard output."""
    text = json_text(data)
    if str(target) == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        atomic_write(Path(target), lambda h: h.write(text.encode()))


def _version(package: str) -> str | None:
    try:
        return version(package)
    except PackageNotFoundError:
        return None


def provenance(scenario_path: Path | None, command: list[str], content: bytes | None = None) -> dict[str, Any]:
    """Toolkit and dependency versions, the scenario's SHA-256 (of the file, or of ``content``
    for a scenario that is not a file), the command and the date."""
    if content is None:
        assert scenario_path is not None, "a scenario that is not a file is given by its content"
        content = Path(scenario_path).read_bytes()
    return {
        "toolkit": {"dvfc": _version("dvfc")},
        "dependencies": {name: _version(name) for name in DEPENDENCIES},
        "python": sys.version.split()[0],
        "scenario": str(scenario_path),
        "scenario_sha256": hashlib.sha256(content).hexdigest(),
        "command": command,
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
    }


_SIGINT = threading.Event()


@contextmanager
def interrupt_aware() -> Iterator[None]:
    """Within, Ctrl-C raises ``KeyboardInterrupt`` as usual and is also remembered, so that
    :func:`interrupted` knows of it where native code turns it into an ordinary error (CVODES
    inside CasADi reports a failed right-hand side). Main thread only."""

    def handler(signum, frame):
        _SIGINT.set()
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _SIGINT.clear()


_IN_TASK = threading.Event()


def remember_interrupts() -> None:
    """In a worker process (its pool's initializer): Ctrl-C, or the parent's SIGINT when it stops, is
    remembered as within :func:`interrupt_aware` and, the first time and within a :func:`worker_task`, raises
    ``KeyboardInterrupt``, so that a run whose native code swallows it stops as interrupted instead of being
    recorded as failed and followed by the next; an idle worker, or a second signal, raises nothing (the pool
    then stops the worker)."""

    def handler(signum, frame):
        first = not _SIGINT.is_set()
        _SIGINT.set()
        if first and _IN_TASK.is_set():
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)


@contextmanager
def worker_task() -> Iterator[None]:
    """One task of a worker process (:func:`remember_interrupts`): not started once interrupted, and Ctrl-C
    raises ``KeyboardInterrupt`` within it."""
    raise_if_interrupted()
    _IN_TASK.set()
    try:
        raise_if_interrupted()  # a signal between the check above and the flag
        yield
    finally:
        _IN_TASK.clear()


def read_log(path: Path) -> list[dict]:
    """The entries of a JSON-lines log of finished runs (none when it does not exist); a last
    line cut short by an interruption is ignored."""
    if not path.exists():
        return []
    entries = []
    for line in path.read_text().splitlines():
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return entries


def append_log(path: Path, entry: dict) -> None:
    """Append one finished run to a JSON-lines log (strict JSON, one line)."""
    with open(path, "a") as handle:
        handle.write(json_text(entry, indent=None))


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` when Ctrl-C was received within :func:`interrupt_aware` but
    swallowed by native code on the way (CVODES inside CasADi reports a failed right-hand
    side): the work just finished may be cut short, and is not to be kept."""
    if _SIGINT.is_set():
        raise KeyboardInterrupt


def interrupted(exc: BaseException | None) -> bool:
    """Whether ``exc`` is Ctrl-C or an error it caused: Ctrl-C was received within
    :func:`interrupt_aware`, or ``exc`` is (caused by) ``KeyboardInterrupt`` or Clarabel's
    ``InterruptedError`` (CasADi wraps it in a ``SystemError``)."""
    if _SIGINT.is_set():
        return True
    while exc is not None:
        if isinstance(exc, KeyboardInterrupt | InterruptedError):
            return True
        exc = exc.__cause__ if exc.__cause__ is not None else None if exc.__suppress_context__ else exc.__context__
    return False
