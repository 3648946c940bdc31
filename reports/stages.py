"""The report's finished stages, kept on disk, each keyed on what it depends on.

A stage's key is the SHA-256 of the toolkit's version, the stage's name, the validated scenario
without the fields the stage does not read (:data:`IGNORES`), the contents of the files the
scenario names (its URDF, its calibration) and the results of earlier stages it takes
(:meth:`StageCache.key`). An edit of a field a stage does not read (a comment, the name, the
campaign's runs for the certificate) keeps it; an edit of anything else makes it anew.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from dvfc.analysis.case import Case
from dvfc.analysis.output import atomic_write, raise_if_interrupted
from dvfc.analysis.schema import Scenario

CACHE = ".dvfc-report"
"""Directory (inside the output directory) holding the finished stages of a report."""

TIMINGS = "timings.txt"
"""The file (in :data:`CACHE`) a report writes its table of step times to (:class:`StepTimes`)."""

DISPLAY = ("name", "grid", "synthesize", "synthesized_from", "report.map")
"""Fields no kept stage reads: the name shown, the gain map's (drawn anew by every report), the
synthesis' (no report stage synthesises), the design before synthesis (its campaign's stage is keyed on
that design's own case, :meth:`dvfc.analysis.case.Case.before`, where it is the ``[gains]``)."""

RUNS = (*DISPLAY, "certify", "envelope", "dispersion", "report")
"""Fields the runs of the scenario (the paper's loop, the loop as implemented) do not read."""

IGNORES: dict[str, tuple[str, ...]] = {
    "implemented": RUNS,
    "simulation": RUNS,
    "from_rest": (*RUNS, "simulation"),  # its own horizon and tolerances
    "certificate": (*DISPLAY, "dispersion", "report"),
    "verification": (*DISPLAY, "dispersion", "report", "certify.gamma"),  # its gamma: P >= 0 without the bound
    "margins": (*DISPLAY, "dispersion", "report", "certify"),
    "controller": RUNS,  # the export, its replay over the run as implemented, its step times
    "dispersions": (*DISPLAY, "certify"),
    "dispersions_before": (*DISPLAY, "certify"),  # of the design before synthesis; takes the criterion's bound
}
"""Per kept stage, the dotted scenario fields it does not read (every other field is part of its
key: a section added to the schema counts until it is listed here). The results a stage takes
from another (the envelope, the run as implemented) enter its key by their content."""


def _without(data: dict, dotted: Iterable[str]) -> dict:
    """``data`` (nested dictionaries) without the entries at the dotted paths ``dotted``."""
    out = json.loads(json.dumps(data))
    for path in dotted:
        *parents, last = path.split(".")
        node = out
        for name in parents:
            node = node.get(name) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(last, None)
    return out


def named_files(scenario: Scenario, base: Path) -> dict[str, str]:
    """The SHA-256 of each file the scenario names (``robot.urdf``, ``camera.calibration``,
    relative to its folder ``base``), by field; a file that cannot be read counts by its path."""
    out = {}
    for name, path in (("robot.urdf", scenario.robot.urdf), ("camera.calibration", scenario.camera.calibration)):
        if path is not None:
            try:
                out[name] = hashlib.sha256((base / path).read_bytes()).hexdigest()
            except OSError:
                out[name] = str(base / path)
    return out


def digest(value: object) -> str:
    """The SHA-256 of a stage's result (its pickle): what a later stage taking it is keyed on."""
    return hashlib.sha256(pickle.dumps(value)).hexdigest()


@dataclass
class StageCache:
    """Finished stages of a report, kept in ``directory`` so that a later report (with ``resume``)
    reuses each one whose key (:meth:`key`) is unchanged; None: nothing is kept. ``toolkit``:
    the toolkit's version (a stage kept by another version is made anew).

    ``timings`` records, per stage called, its wall time (s) and whether it was reused."""

    directory: Path | None
    toolkit: str
    resume: bool
    timings: dict[str, tuple[float, bool]] = field(default_factory=dict)

    def key(self, name: str, case: Case, uses: tuple = ()) -> str:
        """The key of stage ``name`` (one of :data:`IGNORES`) of ``case`` taking the results
        ``uses`` of earlier stages."""
        payload = {
            "toolkit": self.toolkit,
            "stage": name,
            "scenario": _without(case.scenario.model_dump(mode="json"), IGNORES[name]),
            "mode": case.mode,
            "files": named_files(case.scenario, case.base),
            "uses": [digest(value) for value in uses],
        }
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()

    def __call__(self, name: str, case: Case, compute: Callable[[], object], uses: tuple = ()):
        """The result of stage ``name`` of ``case``: the one kept under its key (with ``resume``),
        else ``compute()``, kept (atomically) unless interrupted."""
        start = time.perf_counter()
        key = self.key(name, case, uses)
        path = None if self.directory is None else self.directory / f"{name}.pkl"
        if self.resume and path is not None and path.exists():
            with path.open("rb") as handle:
                stored = pickle.load(handle)
            if stored["key"] == key:
                self.timings[name] = (time.perf_counter() - start, True)
                return stored["value"]
        value = compute()
        raise_if_interrupted()  # the stage may be incomplete: not kept
        if path is not None:
            path.parent.mkdir(exist_ok=True)
            payload = pickle.dumps({"key": key, "value": value})
            atomic_write(path, lambda h: h.write(payload))
        self.timings[name] = (time.perf_counter() - start, False)
        return value

    def scratch(self, name: str, case: Case, uses: tuple = ()) -> Path | None:
        """A directory for the partial work of stage ``name`` of ``case`` (kept for a resumed
        report of the same key, emptied otherwise); None when nothing is kept."""
        if self.directory is None:
            return None
        key = self.key(name, case, uses)
        path, stamp = self.directory / name, self.directory / f"{name}.key"
        if not (self.resume and stamp.exists() and stamp.read_text() == key):
            shutil.rmtree(path, ignore_errors=True)
        path.mkdir(parents=True, exist_ok=True)
        atomic_write(stamp, lambda h: h.write(key.encode()))
        return path


def _clock() -> tuple[float, float]:
    """Wall time and the CPU time of this process and its children (the C compiler), in seconds."""
    t = os.times()
    return time.perf_counter(), t.user + t.system + t.children_user + t.children_system


@dataclass
class StepTimes:
    """The wall and CPU time of each step of a report: calling it with a step's name ends the
    step before (``"end"`` ends the last); :meth:`table` says which kept stages each reused."""

    rows: list[tuple[str, float, float]] = field(default_factory=list)
    _open: tuple[str, float, float] | None = None

    def __call__(self, name: str) -> None:
        wall, cpu = _clock()
        if self._open is not None:
            self.rows.append((self._open[0], wall - self._open[1], cpu - self._open[2]))
        self._open = None if name == "end" else (name, wall, cpu)

    def table(self, cache: StageCache) -> str:
        """The steps as a text table (wall, CPU with the compiler's), then the kept stages made or reused."""
        lines = [f"{'step':32s} {'wall [s]':>9s} {'CPU [s]':>9s}"]
        lines += [f"{name:32s} {wall:9.1f} {cpu:9.1f}" for name, wall, cpu in self.rows]
        lines.append(f"{'total':32s} {sum(r[1] for r in self.rows):9.1f} {sum(r[2] for r in self.rows):9.1f}")
        lines += ["", f"{'kept stage':32s} {'wall [s]':>9s}"]
        kept = cache.timings.items()
        lines += [f"{name:32s} {wall:9.1f} {'reused' if reused else 'made'}" for name, (wall, reused) in kept]
        return "\n".join(lines) + "\n"
