"""Compiled right-hand sides: C code generated from the symbolic loop, built once with
the system C compiler and cached on disk by the hash of the function's structure (a cache hit
generates no C), one lock per cache entry (two processes never build the same library); loaded
once per process for each function (the same function built again, by another design of the same
arm, is not generated again). The libraries one simulator needs are built together
(:func:`compiled_together`): one compiler process each, as many at once as there are cores; a command that will
build several simulators one after the other starts the builds of a later one first (:func:`ahead`), so that they
take the cores the earlier ones leave idle.

A library holds the function alone. A function that an implicit integrator differentiates (the
continuous loop's DAE, whose Jacobian CVODES's Newton iteration needs) is loaded with CasADi's finite
differences (:data:`DIFFERENCES`), as SUNDIALS's own difference-quotient Jacobian is: the Newton iteration
needs only an approximate Jacobian (its error test, not the Jacobian, sets the accuracy of a run), and the
symbolic Jacobian's C is 15 times the function's (on the xArm 7 it took 8.5 s of the 11 s a structure's
build took). Measured on the xArm 7 cell's 10 s continuous run: 0.053 s with forward differences, 0.074 s
with the compiled symbolic Jacobian, 0.128 s with central differences; the states of the three within
2e-8 of each other, the level CVODES's tolerances leave between any two Newton iterations."""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import IO

import casadi as cs
import numpy as np

CC_FLAGS = ("-shared", "-fPIC")
DIFFERENCES = {"enable_fd": True, "fd_method": "forward"}
"""How a differentiable compiled function is differentiated: CasADi's forward differences at its default step, one
evaluation a direction (a Jacobian about ``sqrt(eps)`` relative from the exact one)."""

_loaded: dict[tuple[str, bool], cs.Function] = {}
"""The compiled functions loaded in this process, by their library's path (:func:`_library`) and whether
differentiated."""


def cache_dir() -> Path:
    """``$DVFC_CACHE``, else ``$XDG_CACHE_HOME/dvfc``, else ``~/.cache/dvfc``."""
    if "DVFC_CACHE" in os.environ:
        return Path(os.environ["DVFC_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "dvfc"


def _source(function: cs.Function, directory: str) -> str:
    generator = cs.CodeGenerator(f"{function.name()}.c")
    generator.add(function)
    return Path(generator.generate(directory + os.sep)).read_text()


Request = tuple[cs.Function, bool, str]
"""What :func:`compiled_together` builds: a function, whether it is differentiated (by :data:`DIFFERENCES`),
the optimisation level."""


def compiled(function: cs.Function, *, differentiable: bool = False, level: str = "-O1") -> cs.Function:
    """``function`` as compiled C at the optimisation ``level``, loaded as a CasADi external; ``differentiable``:
    its derivatives by :data:`DIFFERENCES` (none otherwise). Falls back to ``function`` itself (CasADi's virtual
    machine, with its symbolic derivatives) when no C compiler is on the PATH."""
    return compiled_together([(function, differentiable, level)])[0]


def compiled_together(requests: Sequence[Request]) -> list[cs.Function]:
    """:func:`compiled` of each request, in order; the libraries not in the cache are generated one after the
    other and compiled at once, at most one compiler process per core (a simulator's functions are independent:
    their builds overlap instead of adding up). Within :func:`ahead`: the builds started, and the functions
    returned as they are, not compiled."""
    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        return [function for function, _, _ in requests]
    libraries = [_library(function, level, compiler) for function, _, level in requests]
    loaded = {path for path, _ in _loaded}
    missing = {str(library): (request, library) for request, library in zip(requests, libraries, strict=True)
               if str(library) not in loaded}  # fmt: skip
    builds = [missing[key] for key in sorted(missing)]  # sorted: one order of locks for every process
    if _ahead.is_set():
        for (function, _, level), library in builds:
            _start(function, level, library, compiler, None)
        return [function for function, _, _ in requests]
    _build_all(builds, compiler)
    keys = [(str(library), differentiable) for (_, differentiable, _), library in zip(requests, libraries, strict=True)]
    for (function, differentiable, _), key in zip(requests, keys, strict=True):
        if key not in _loaded:
            _loaded[key] = cs.external(function.name(), key[0], DIFFERENCES if differentiable else {})
    return [_loaded[key] for key in keys]


_ahead = threading.Event()


@contextlib.contextmanager
def ahead() -> Iterator[None]:
    """Within, :func:`compiled_together` starts the builds of the libraries not in the cache and returns at once,
    its functions not compiled: a simulator made within is a throwaway whose builds run meanwhile in this
    process's compilers (at most one a core), and the simulator made later for its run waits only for what is
    not built yet. Main thread only."""
    _ahead.set()
    try:
        yield
    finally:
        _ahead.clear()


@functools.cache
def _compiler_identity(compiler: str) -> str:
    """``compiler``'s path and the first line of its ``--version``: a library built by another
    compiler is another cache entry."""
    run = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False)
    return f"{compiler} {run.stdout.splitlines()[0] if run.stdout else ''}"


def _library(function: cs.Function, level: str, compiler: str) -> Path:
    """The cache entry of ``function``'s library: named after the function and keyed by the hash of
    its serialisation (its structure, from which the C source is generated), the build's options,
    CasADi's version and the compiler, so that a cache hit generates no C."""
    text = " ".join((function.serialize(), level, *CC_FLAGS, cs.__version__,
                     _compiler_identity(compiler)))  # fmt: skip
    digest = hashlib.sha256(text.encode()).hexdigest()[:24]
    return cache_dir() / f"{function.name()}-{digest}.so"


_background: ThreadPoolExecutor | None = None
"""The compilers of the builds started :func:`ahead`: a thread each, one a core, whose compiler processes run at
the lowest priority (:func:`_lowest_priority`: they take only the time the others leave)."""
_building: dict[Path, Future] = {}
"""The builds this process started and has not waited for, by library."""


_spawning = threading.Lock()
"""Held while a compiler process is started, and by a fork: no child is forked holding the pipes through which
the start of a compiler reports (the parent would wait for the child's end to read it)."""


def _forget_in_child() -> None:
    """In a forked child: the parent's compiler threads and builds are not its own (their locks are released
    by the parent's threads, for which the child waits like any other process)."""
    global _background, _spawning
    _background, _spawning = None, threading.Lock()
    _building.clear()


os.register_at_fork(before=lambda: _spawning.acquire(), after_in_parent=lambda: _spawning.release(),
                    after_in_child=_forget_in_child)  # fmt: skip


def _start(function: cs.Function, level: str, library: Path, compiler: str, pool: ThreadPoolExecutor | None) -> None:
    """Start building ``function`` into ``library`` by ``compiler`` on a thread of ``pool`` (None: of the
    background's, :data:`_background`), unless this process builds it already or it is in the cache (built by
    this or another process, which holds the entry's lock, ``<library>.lock``, meanwhile: this one waits for it).
    The source is generated here; the build keeps the entry's lock until the library is in place."""
    global _background
    if library in _building or library.exists():
        return
    library.parent.mkdir(parents=True, exist_ok=True)
    handle = open(library.with_suffix(".lock"), "a")  # noqa: SIM115 (closed by the build)
    fcntl.flock(handle, fcntl.LOCK_EX)
    if library.exists():  # built while this process waited for the lock
        _release(handle)
        return
    try:
        tmp = tempfile.mkdtemp()
        source = Path(tmp) / f"{function.name()}-final.c"
        source.write_text(_source(function, tmp))
    except BaseException:
        _release(handle)
        raise
    partial = library.with_suffix(f".{os.getpid()}.tmp")
    command = [compiler, level, *CC_FLAGS, str(source), "-o", str(partial)]
    if pool is None:
        if _background is None:
            _background = ThreadPoolExecutor(max_workers=os.cpu_count() or 1, initializer=_lowest_priority)
        pool = _background
    _building[library] = pool.submit(_build, command, partial, library, tmp, handle)


def _lowest_priority() -> None:
    """This thread, and the compiler processes it starts (a child inherits the priority of the thread that
    starts it, on Linux), at the lowest scheduling priority (nice 19)."""
    os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)


def _build(command: list[str], partial: Path, library: Path, tmp: str, handle: IO) -> None:
    """Run the compiler ``command`` into ``partial``, moved to ``library`` when it succeeds; the entry's lock
    (``handle``) released and the source's directory ``tmp`` removed in any case. The compiler writes its
    messages to a file of ``tmp``, not a pipe: a process forked meanwhile holds no end this one waits for."""
    try:
        messages = Path(tmp) / "compiler.log"
        with open(messages, "w") as output:
            with _spawning:
                compiler = subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT)
            if compiler.wait():
                raise subprocess.CalledProcessError(compiler.returncode, command, messages.read_text())
        partial.replace(library)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        _release(handle)


def _release(handle: IO) -> None:
    fcntl.flock(handle, fcntl.LOCK_UN)
    handle.close()


def _build_all(builds: list[tuple[Request, Path]], compiler: str) -> None:
    """Each request built by ``compiler`` into its library, unless it is there already (:func:`_start`), and
    every one of them waited for (those started :func:`ahead` too): the locks taken in the order given, the
    sources generated one after the other, each compiled as soon as it is generated, at most one compiler a
    core."""
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for (function, _, level), library in builds:
            _start(function, level, library, compiler, pool)
        for _, library in builds:
            if (build := _building.pop(library, None)) is not None:
                build.result()


class Buffered:
    """``function`` (dense inputs and outputs) called through CasADi's buffer interface: the
    arguments are copied into NumPy arrays it owns and the results read from others, with
    no conversion to CasADi's matrices (a few microseconds per call instead of about 100 for
    a function with several arguments)."""

    def __init__(self, function: cs.Function) -> None:
        self.buffer, self.trigger = function.buffer()
        # CasADi stores column-major: a (rows, cols) argument is a C-ordered (cols, rows) array.
        self.inputs = [np.zeros((function.size2_in(i), function.size1_in(i))) for i in range(function.n_in())]
        self.outputs = [np.zeros((function.size2_out(i), function.size1_out(i))) for i in range(function.n_out())]
        assert all(function.nnz_in(i) == a.size for i, a in enumerate(self.inputs)), "inputs must be dense"
        assert all(function.nnz_out(i) == a.size for i, a in enumerate(self.outputs)), "outputs must be dense"
        for i, array in enumerate(self.inputs):
            self.buffer.set_arg(i, array.data)
        for i, array in enumerate(self.outputs):
            self.buffer.set_res(i, array.data)
        self._targets = [array[0] if len(array) == 1 else array.T for array in self.inputs]  # vectors flat

    def __call__(self, *args: np.ndarray | float) -> list[np.ndarray]:
        """The outputs (new arrays, CasADi's shapes) at ``args`` (CasADi's shapes; vectors flat)."""
        for target, value in zip(self._targets, args, strict=True):
            if type(value) is np.ndarray and value.shape == target.shape:
                target[...] = value  # the common case, without np.reshape's dispatch
            else:
                target[...] = np.reshape(value, target.shape)
        self.trigger()
        return [array.T.copy() for array in self.outputs]
