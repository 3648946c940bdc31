"""Compiled right-hand sides: C code generated from the symbolic loop, built once with
the system C compiler and cached on disk by the hash of its source."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as cs

CC_FLAGS = ("-O0", "-shared", "-fPIC")
"""The generated Jacobian is large (about 1e5 operations); at -O0 gcc builds it in
about ten seconds and the compiled code still runs several times faster than
CasADi's virtual machine."""


def cache_dir() -> Path:
    """``$DVFC_CACHE``, else ``$XDG_CACHE_HOME/dvfc``, else ``~/.cache/dvfc``."""
    if "DVFC_CACHE" in os.environ:
        return Path(os.environ["DVFC_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "dvfc"


def compiled(function: cs.Function, *, jacobian: bool = True) -> cs.Function:
    """``function`` (and its Jacobian) as compiled C, loaded as a CasADi external.

    The Jacobian is generated under CasADi's name ``jac_<name>`` so that the
    external function differentiates through it. Falls back to ``function`` itself
    (CasADi's virtual machine) when no C compiler is on the PATH.
    """
    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        return function
    name = function.name()
    with tempfile.TemporaryDirectory() as tmp:
        generator = cs.CodeGenerator(f"{name}.c")
        generator.add(function)
        if jacobian:
            generator.add(function.jacobian())
        source = Path(generator.generate(tmp + os.sep))
        digest = hashlib.sha256(source.read_bytes() + " ".join(CC_FLAGS).encode()).hexdigest()[:24]
        library = cache_dir() / f"{name}-{digest}.so"
        if not library.exists():
            library.parent.mkdir(parents=True, exist_ok=True)
            partial = library.with_suffix(f".{os.getpid()}.tmp")
            subprocess.run([compiler, *CC_FLAGS, str(source), "-o", str(partial)], check=True, capture_output=True)
            partial.replace(library)
    return cs.external(name, str(library))
