"""The controller program as C (``dvfc export``): generated from the same CasADi graph as
:class:`~dvfc.analysis.controller.Controller`, wrapped in a small hand-written C API, built with the
system C compiler, and checked against the Python step sample by sample and in closed loop.

Files written to the export folder: ``dvfc_program.c/.h`` (:class:`casadi.CodeGenerator`, with
header), ``dvfc_controller.h/.c`` (the API: :mod:`dvfc.analysis.export_c`), ``dvfc_timing.c``,
``replay.c``, ``ros2_control_example.cpp``, ``Makefile``, ``README.md``.

Bits: the C step evaluates the same operations in the same order as CasADi's virtual machine on the
same libm, so with :data:`CFLAGS` (no fast math, no fused multiply-add) the torques agree to the last
bit; :func:`check` measures it (the tolerance the tests allow is ``1e-12`` relative, for a platform
whose libm differs from the one CasADi's library calls).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import casadi as cs
import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.compile import cache_dir
from dvfc.analysis.controller import Controller, program_loop, ring_size
from dvfc.analysis.sil import SilRun, software_in_the_loop

CFLAGS = ("-O2", "-fno-fast-math", "-ffp-contract=off")
"""The compiler flags of the export (its Makefile's, and the check's)."""

SOURCES = ("dvfc_controller.c", "dvfc_program.c")
"""The controller's C sources."""

TEMPLATES = ("dvfc_controller.h.in", "dvfc_controller.c.in", "Makefile", "README.md.in")
COPIED = ("dvfc_timing.c", "replay.c", "ros2_control_example.cpp")


TORQUE_TOLERANCE = 1e-12
"""Largest relative difference of a torque between the compiled and the Python step :func:`check`
accepts: the same operations in the same order agree to the bit; a libm whose ``sin``, ``cos`` or
``sqrt`` round differently in the last bit moves a torque by a few ulps of its terms, far below this."""

CLOSED_LOOP_TOLERANCE = 1e-9
"""Largest difference of a joint position (rad) or speed (rad/s) between the loop closed by the
compiled step and by the Python step that :func:`check` accepts (identical torques give 0)."""


PROGRAM = ("dvfc_controller.h", "dvfc_controller.c", "dvfc_program.h", "dvfc_program.c")
"""The files of the program itself (its API and its step): what :func:`program_digest` hashes."""


class ExportError(ValueError):
    """A scenario that cannot be exported (one line naming the field)."""


@dataclass(frozen=True)
class Export:
    """An exported controller: its folder, the files written, the API header, the state's size."""

    directory: Path
    files: tuple[Path, ...]
    api: Path
    state_size: int


@dataclass(frozen=True)
class Check:
    """The compiled step against the Python step: over ``samples`` control samples of a
    software-in-the-loop run (its inputs written to ``inputs`` for ``replay.c``), the largest torque
    difference (the same inputs) and the largest difference of the plant's joints when the C step
    closes the loop instead."""

    inputs: Path
    samples: int
    max_abs_torque_difference: float
    max_rel_torque_difference: float
    closed_loop_max_state_difference: float

    @classmethod
    def of(cls, inputs: Path, reference: SilRun, taus: np.ndarray, closed: SilRun) -> Check:
        """The check of the torques ``taus`` the compiled step gave on the inputs of ``reference`` (the
        run with the Python step) and of ``closed``, the loop the compiled step closed: each torque's
        difference relative to that torque, and the largest difference of the plant's joint positions
        and speeds (infinite when one run stopped before the other: they are not the same loop)."""
        difference = np.abs(taus - reference.tau)
        scale = np.maximum(np.abs(reference.tau), np.finfo(float).tiny)
        joints = np.hstack([reference.q, reference.qd]), np.hstack([closed.q, closed.qd])
        same_length = len(joints[0]) == len(joints[1])  # a run cut short by one step only: a difference
        state_difference = float(np.abs(joints[0] - joints[1]).max()) if same_length else float("inf")
        return cls(inputs=inputs, samples=len(reference.tau),
                   max_abs_torque_difference=float(difference.max(initial=0.0)),
                   max_rel_torque_difference=float((difference / scale).max(initial=0.0)),
                   closed_loop_max_state_difference=state_difference)  # fmt: skip

    @property
    def passed(self) -> bool:
        """Both within :data:`TORQUE_TOLERANCE` and :data:`CLOSED_LOOP_TOLERANCE`."""
        return (self.max_rel_torque_difference <= TORQUE_TOLERANCE
                and self.closed_loop_max_state_difference <= CLOSED_LOOP_TOLERANCE)  # fmt: skip

    def as_dict(self) -> dict:
        """JSON-ready (``dvfc export --json``'s ``check``)."""
        return {"samples": self.samples, "max_abs_torque_difference": self.max_abs_torque_difference,
                "max_rel_torque_difference": self.max_rel_torque_difference,
                "closed_loop_max_state_difference": self.closed_loop_max_state_difference,
                "passed": self.passed}  # fmt: skip

    def text(self) -> str:
        """One sentence for the export's README."""
        return (f"{self.samples} samples, largest torque difference {self.max_abs_torque_difference:.3g} N m "
                f"(relative {self.max_rel_torque_difference:.3g}), closed loop: joints within "
                f"{self.closed_loop_max_state_difference:.3g}")  # fmt: skip


@dataclass(frozen=True)
class Timing:
    """Time of the compiled step (microseconds), over ``calls`` calls: a measurement on this machine,
    with an image at every call (``image``) or none, in wall time (``cpu`` False: what a control
    cycle sees, preemption by other processes included) or the thread's CPU time (the step's own cost)."""

    calls: int
    image: bool
    cpu: bool
    min_us: float
    median_us: float
    p999_us: float
    max_us: float

    def as_dict(self) -> dict:
        """JSON-ready, the times in microseconds."""
        return {"calls": self.calls, "image": self.image, "cpu": self.cpu, "min_us": self.min_us,
                "median_us": self.median_us, "p999_us": self.p999_us, "max_us": self.max_us}  # fmt: skip

    @staticmethod
    def of(seconds: np.ndarray, image: bool, cpu: bool) -> Timing:
        us = np.asarray(seconds) * 1e6
        return Timing(len(us), image, cpu, float(us.min()), float(np.median(us)), float(np.quantile(us, 0.999)),
                      float(us.max()))  # fmt: skip


def exportable(case: Case) -> None:
    """Raise :class:`ExportError` when the case has no program to export."""
    if case.settings.implementation is None:
        raise ExportError(
            "implementation: the scenario has no [implementation] (control rate, camera): nothing to export"
        )
    if case.planar:
        raise ExportError("loop: the reduced planar loop cannot be exported; export the paper's loop")


def _fill(text: str, values: dict[str, object]) -> str:
    for key, value in values.items():
        text = text.replace(f"@{key}@", str(value))
    return text


NOT_CHECKED = "not run: `dvfc export --check` runs it"


def generate(case: Case, directory: Path) -> Export:
    """Write the export of ``case`` to ``directory`` (created)."""
    exportable(case)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    controller = Controller(case)
    function = controller.function
    generator = cs.CodeGenerator("dvfc_program.c", {"with_header": True})
    generator.add(function)
    generator.generate(str(directory) + os.sep)
    imp, loop = case.settings.implementation, program_loop(case)
    assert imp is not None, "exportable"
    values = {
        "NAME": case.name,
        "SCENARIO": case.path or case.name,
        "ROBOT": case.scenario.robot.model or case.scenario.robot.urdf,
        "JOINTS": ", ".join(loop.robot.joints),
        "N": controller.n,
        "F": 2 * controller.m,
        "S": controller.layout.size,
        "RING": ring_size(case),
        "PERIOD": repr(imp.period),
        "RATE": f"{imp.control_rate:g}",
        "CAMERA": f"{1 / imp.camera_rate:g}",
        "LATENCY": imp.latency_steps,
        "SZ_ARG": function.sz_arg(),
        "SZ_RES": function.sz_res(),
        "SZ_IW": function.sz_iw(),
        "SZ_W": function.sz_w(),
        "X0": ", ".join(repr(float(v)) for v in controller.initial_state()),
        "CFLAGS": " ".join(CFLAGS),
        "CHECK": NOT_CHECKED,
    }
    source = resources.files("dvfc.analysis.export_c")
    for name in TEMPLATES:
        (directory / name.removesuffix(".in")).write_text(_fill(source.joinpath(name).read_text(), values))
    for name in COPIED:
        (directory / name).write_text(source.joinpath(name).read_text())
    names = ["dvfc_controller.h", "dvfc_controller.c", "dvfc_program.c", "dvfc_program.h", "Makefile",
             "README.md", *COPIED]  # fmt: skip
    return Export(directory, tuple(directory / n for n in names), directory / "dvfc_controller.h",
                  controller.layout.size)  # fmt: skip


def record_check(export: Export, result: Check) -> None:
    """Say in the export's README what :func:`check` found."""
    readme = export.directory / "README.md"
    readme.write_text(readme.read_text().replace(f"({NOT_CHECKED})", f"({result.text()})"))


def program_digest(export: Export) -> str:
    """The SHA-256 of the exported program: each file of :data:`PROGRAM`, its name then its bytes, in
    that order. The same scenario exports the same bytes, so the digest names the program a robot
    runs; the README, the Makefile and the examples beside it are not part of it."""
    digest = hashlib.sha256()
    for name in PROGRAM:
        digest.update(name.encode() + b"\0" + (export.directory / name).read_bytes())
    return digest.hexdigest()


def c_compiler() -> str | None:
    """The system C compiler (``cc``, else ``gcc``) on the PATH, or None."""
    return shutil.which("cc") or shutil.which("gcc")


def build(export: Export) -> Path:
    """The export's controller and timing as a shared library built by the system ``cc`` with
    :data:`CFLAGS` (cached in :func:`dvfc.analysis.compile.cache_dir` by the hash of the sources)."""
    compiler = c_compiler()
    if compiler is None:
        raise ExportError("check: no C compiler (cc) on the PATH")
    files = [export.directory / name for name in (*SOURCES, "dvfc_timing.c")]
    headers = [export.directory / name for name in ("dvfc_controller.h", "dvfc_program.h")]
    digest = hashlib.sha256(b"".join(f.read_bytes() for f in files + headers) + " ".join(CFLAGS).encode())
    library = cache_dir() / f"dvfc_export-{digest.hexdigest()[:24]}.so"
    if not library.exists():
        library.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory() as tmp:
            partial = Path(tmp) / library.name
            command = [compiler, *CFLAGS, "-fPIC", "-shared", "-I", str(export.directory), *map(str, files), "-o",
                       str(partial), "-lm"]  # fmt: skip
            subprocess.run(command, check=True, capture_output=True)
            shutil.move(partial, library)
    return library


class CompiledController:
    """The compiled C step through ctypes, with :meth:`Controller.step`'s signature (the state a
    NumPy vector copied in and out)."""

    def __init__(self, library: Path, n: int, features: int, state_size: int) -> None:
        self.lib = ctypes.CDLL(str(library))
        self.n, self.features, self.size = n, features, state_size
        pointer = ctypes.POINTER(ctypes.c_double)
        self.lib.dvfc_step.argtypes = [pointer, ctypes.c_double, pointer, pointer, pointer, ctypes.c_int, pointer]
        self.lib.dvfc_step.restype = ctypes.c_int
        self.lib.dvfc_init.argtypes = [pointer]
        self.lib.dvfc_time_steps.argtypes = [ctypes.c_long, pointer, pointer, pointer, ctypes.c_int, pointer]
        self.lib.dvfc_time_steps.restype = ctypes.c_int
        self.last_status = 0

    @staticmethod
    def _p(array: np.ndarray | None):
        return None if array is None else array.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    def initial_state(self) -> np.ndarray:
        state = np.zeros(self.size)
        self.lib.dvfc_init(self._p(state))
        return state

    def step(
        self, state: np.ndarray, t: float, q: np.ndarray, qd: np.ndarray, features: np.ndarray | None, capture_step: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(tau, next state)`` of the C step; its return code in :attr:`last_status`."""
        x = np.array(state, dtype=float)
        tau = np.zeros(self.n)
        q, qd = (np.ascontiguousarray(v, dtype=float) for v in (q, qd))
        f = None if features is None else np.ascontiguousarray(features, dtype=float)
        self.last_status = self.lib.dvfc_step(self._p(x), float(t), self._p(q), self._p(qd), self._p(f),
                                              int(capture_step), self._p(tau))  # fmt: skip
        return tau, x

    def time_steps(
        self, calls: int, q: np.ndarray, qd: np.ndarray, features: np.ndarray | None, cpu: bool = False
    ) -> np.ndarray:
        """The wall time (or the thread's CPU time) in seconds of each of ``calls`` steps (``dvfc_time_steps``)."""
        seconds = np.zeros(calls)
        q, qd = (np.ascontiguousarray(v, dtype=float) for v in (q, qd))
        f = None if features is None else np.ascontiguousarray(features, dtype=float)
        self.lib.dvfc_time_steps(calls, self._p(q), self._p(qd), self._p(f), int(cpu), self._p(seconds))
        return seconds


def compiled_controller(case: Case, export: Export) -> CompiledController:
    """The export of ``case`` built and loaded."""
    controller_sizes = Controller(case)
    return CompiledController(build(export), controller_sizes.n, 2 * controller_sizes.m, export.state_size)


def replay(step, run: SilRun, initial: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The torques and states ``step`` gives on the inputs of ``run``, from ``initial``."""
    state, taus, states = initial, [], []
    for k in range(len(run.tau)):
        features = run.features[k] if run.captures[k] >= 0 else None
        tau, state = step(state, run.t[k], run.q[k], run.qd[k], features, int(run.captures[k]))
        taus.append(tau)
        states.append(state)
    return np.array(taus), np.array(states)


def write_inputs(run: SilRun, path: Path) -> None:
    """A run's inputs as ``replay.c`` reads them: ``t, capture_step, q, qd, features`` a line."""
    columns = np.column_stack([run.t[: len(run.tau)], run.captures, run.q[: len(run.tau)], run.qd[: len(run.tau)],
                               run.features])  # fmt: skip
    np.savetxt(path, columns, delimiter=",", fmt="%.17g", header="t, capture_step, q (n), qd (n), features (2m)")


def check(case: Case, export: Export, duration: float | None = None) -> tuple[Check, SilRun]:
    """Replay a software-in-the-loop run's inputs through the compiled step and compare every torque
    with the Python step's; then close the loop with the compiled step and compare the plant's joints
    (the SIL run with the Python step as reference). Writes the inputs to ``sil_inputs.csv``."""
    controller = Controller(case)
    reference = software_in_the_loop(case, duration=duration, controller=controller)
    c_step = compiled_controller(case, export)
    taus, _ = replay(c_step.step, reference, c_step.initial_state())
    write_inputs(reference, export.directory / "sil_inputs.csv")
    closed = software_in_the_loop(case, c_step.step, duration=duration, controller=controller)
    return Check.of(export.directory / "sil_inputs.csv", reference, taus, closed), reference


def timing(
    case: Case, compiled: CompiledController, calls: int = 100_000, image: bool = True, cpu: bool = False
) -> Timing:
    """The compiled step timed over ``calls`` calls at the case's start (``q0``, ``qd0``, the
    features of the initial pose), with an image at every call or none, in wall or CPU time."""
    n = compiled.n
    features = initial_features(case) if image else None
    return Timing.of(compiled.time_steps(calls, case.s0[:n], case.s0[n : 2 * n], features, cpu), image, cpu)


def initial_features(case: Case) -> np.ndarray:
    """The features (11) at the case's initial state."""
    loop = case.loop
    function = cs.Function("f0", [loop.t, loop.state], [loop.features])
    return np.asarray(function(0.0, case.s0)).ravel()


@dataclass(frozen=True)
class ExportResult:
    """What ``dvfc export`` did: the export, and with ``--check`` the check and the timing of the
    compiled step with an image at every call, in wall time and in the thread's CPU time."""

    export: Export
    check: Check | None = None
    timing: Timing | None = None
    cpu_timing: Timing | None = None

    @property
    def passed(self) -> bool:
        """Not checked, or the check passed."""
        return self.check is None or self.check.passed

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``dvfc export`` (docs/cli.md): the files written (the replay's inputs with
        ``--check``), the API header, the state size, the program's SHA-256, the check and timing."""
        e = self.export
        files = [str(f) for f in e.files] + ([] if self.check is None else [str(self.check.inputs)])
        timing = None if self.timing is None or self.cpu_timing is None else (
            {**self.timing.as_dict(), "thread_cpu": self.cpu_timing.as_dict()})  # fmt: skip
        return {"files": files, "api": str(e.api), "state_size": e.state_size, "sha256": program_digest(e),
                "check": None if self.check is None else self.check.as_dict(), "timing": timing}  # fmt: skip


def export_controller(case: Case, directory: Path, *, checked: bool = False, calls: int = 100_000) -> ExportResult:
    """Export ``case``'s controller to ``directory``; with ``checked``, :func:`check` it over the
    scenario's duration and time ``calls`` steps."""
    export = generate(case, directory)
    if not checked:
        return ExportResult(export)
    result, _ = check(case, export)
    record_check(export, result)
    compiled = compiled_controller(case, export)
    return ExportResult(export, result, timing(case, compiled, calls), timing(case, compiled, calls, cpu=True))


NO_COMPILER = "no C compiler (cc) on the PATH: the exported controller is not built, replayed or timed"


def running_controller(case: Case, directory: Path, calls: int = 10_000) -> dict:
    """The controller that runs, as the report states it: ``case``'s export written to ``directory``,
    its :func:`program_digest`, :func:`check` over the scenario's duration and the compiled step
    timed over ``calls`` calls without and with an image, in wall and in the thread's CPU time, with
    the load average when timed (measurements on this machine). ``{"reason": ...}`` when there is
    nothing to export or no C compiler."""
    try:
        exportable(case)
    except ExportError as exc:
        return {"reason": str(exc)}
    if c_compiler() is None:
        return {"reason": NO_COMPILER}
    export = generate(case, directory)
    result, _ = check(case, export)
    compiled = compiled_controller(case, export)
    load = os.getloadavg()[0]
    timings = [timing(case, compiled, calls, image, cpu).as_dict() for cpu in (False, True) for image in (False, True)]
    return {"sha256": program_digest(export), "files": list(PROGRAM), "state_size": export.state_size,
            "check": result.as_dict(), "tolerances": {"torque_relative": TORQUE_TOLERANCE,
                                                      "closed_loop": CLOSED_LOOP_TOLERANCE},
            "timing": timings, "load_average": load, "cores": os.cpu_count()}  # fmt: skip
