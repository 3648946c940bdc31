"""Compiled right-hand sides: C code generated from the symbolic loop, built once with
the system C compiler and cached on disk by the hash of the function's structure (a cache hit
generates no C), one lock per cache entry (two processes never build the same library); loaded
once per process for each function (the same function built again, by another design of the same
arm, is not generated again). The libraries one simulator needs are built together
(:func:`compiled_together`): one compiler process each, as many at once as there are cores."""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import casadi as cs
import numpy as np

CC_FLAGS = ("-shared", "-fPIC")
JACOBIAN_PRAGMA = '#pragma GCC optimize ("O0")\n'
"""The generated Jacobian is large (about 1e5 operations): gcc needs minutes to optimise
it but ten seconds to build it at -O0, where it still runs several times faster than
CasADi's virtual machine. The function itself is optimised (-O1); the pragma switches
the optimiser off from the Jacobian's body on. A function without Jacobian that runs
thousands of times per run (the sampled loop's control period) is worth ``-O2``: about
10 s more to build once, about 10% faster."""

_loaded: dict[str, cs.Function] = {}
"""The compiled functions loaded in this process, by their library's path (:func:`_library`)."""


def cache_dir() -> Path:
    """``$DVFC_CACHE``, else ``$XDG_CACHE_HOME/dvfc``, else ``~/.cache/dvfc``."""
    if "DVFC_CACHE" in os.environ:
        return Path(os.environ["DVFC_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "dvfc"


def _source(function: cs.Function, jacobian: bool, directory: str) -> str:
    generator = cs.CodeGenerator(f"{function.name()}.c")
    generator.add(function)
    if jacobian:
        generator.add(function.jacobian())
    text = Path(generator.generate(directory + os.sep)).read_text()
    marker = "static int casadi_f1("  # the body of the second function added: the Jacobian
    if jacobian and marker in text:
        i = text.index(marker)
        text = text[:i] + JACOBIAN_PRAGMA + text[i:]
    return text


Request = tuple[cs.Function, bool, str]
"""What :func:`compiled_together` builds: a function, whether with its Jacobian, the optimisation level."""


def compiled(function: cs.Function, *, jacobian: bool = True, level: str = "-O1") -> cs.Function:
    """``function`` (and its Jacobian) as compiled C, loaded as a CasADi external.

    The Jacobian is generated under CasADi's name ``jac_<name>`` so that the
    external function differentiates through it, built at the optimisation ``level``
    (see :data:`JACOBIAN_PRAGMA`). Falls back to ``function`` itself (CasADi's virtual
    machine) when no C compiler is on the PATH.
    """
    return compiled_together([(function, jacobian, level)])[0]


def compiled_together(requests: Sequence[Request]) -> list[cs.Function]:
    """:func:`compiled` of each request, in order; the libraries not in the cache are generated one after the
    other and compiled at once, at most one compiler process per core (a simulator's functions are independent:
    their builds overlap instead of adding up)."""
    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        return [function for function, _, _ in requests]
    libraries = [_library(function, jacobian, level, compiler) for function, jacobian, level in requests]
    missing = {str(library): (request, library) for request, library in zip(requests, libraries, strict=True)
               if str(library) not in _loaded}  # fmt: skip
    _build_all([missing[key] for key in sorted(missing)], compiler)  # sorted: one order of locks for every process
    for (function, _, _), library in zip(requests, libraries, strict=True):
        if str(library) not in _loaded:
            _loaded[str(library)] = cs.external(function.name(), str(library))
    return [_loaded[str(library)] for library in libraries]


@functools.cache
def _compiler_identity(compiler: str) -> str:
    """``compiler``'s path and the first line of its ``--version``: a library built by another
    compiler is another cache entry."""
    run = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False)
    return f"{compiler} {run.stdout.splitlines()[0] if run.stdout else ''}"


def _library(function: cs.Function, jacobian: bool, level: str, compiler: str) -> Path:
    """The cache entry of ``function``'s library: named after the function and keyed by the hash of
    its serialisation (its structure, from which the C source is generated), the build's options,
    CasADi's version and the compiler, so that a cache hit generates no C."""
    text = " ".join((function.serialize(), str(jacobian), level, *CC_FLAGS, cs.__version__,
                     _compiler_identity(compiler)))  # fmt: skip
    digest = hashlib.sha256(text.encode()).hexdigest()[:24]
    return cache_dir() / f"{function.name()}-{digest}.so"


@contextlib.contextmanager
def _locked(library: Path) -> Iterator[None]:
    """An exclusive lock on ``library``'s cache entry (``<library>.lock``), held while it is built:
    processes that need the same library wait for the one building it instead of building it again."""
    with open(library.with_suffix(".lock"), "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _build_all(builds: list[tuple[Request, Path]], compiler: str) -> None:
    """Each request built by ``compiler`` into its library, unless it is there already (built by this or another
    process, which holds the entry's lock meanwhile): the locks taken in the order given, the sources generated one
    after the other, the compilers run at once (at most one a core)."""
    with contextlib.ExitStack() as stack:
        commands = []
        for (function, jacobian, level), library in builds:
            if library.exists():
                continue
            library.parent.mkdir(parents=True, exist_ok=True)
            stack.enter_context(_locked(library))
            if library.exists():  # built while this process waited for the lock
                continue
            tmp = stack.enter_context(tempfile.TemporaryDirectory())
            source = Path(tmp) / f"{function.name()}-final.c"
            source.write_text(_source(function, jacobian, tmp))
            partial = library.with_suffix(f".{os.getpid()}.tmp")
            commands.append(([compiler, level, *CC_FLAGS, str(source), "-o", str(partial)], partial, library))
        with ThreadPoolExecutor(max_workers=max(1, min(len(commands), os.cpu_count() or 1))) as pool:
            done = list(pool.map(lambda c: subprocess.run(c[0], check=False, capture_output=True), commands))
        for run, (_, partial, library) in zip(done, commands, strict=True):
            run.check_returncode()
            partial.replace(library)


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
            target[...] = np.reshape(value, target.shape)
        self.trigger()
        return [array.T.copy() for array in self.outputs]
