"""Keeping the libraries' own words from the user: C code writing to the standard streams
(CVODES' dumps, IPOPT) and Python warnings raised inside a call."""

from __future__ import annotations

import io
import os
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout


@contextmanager
def silenced() -> Iterator[None]:
    """Run the block with Python's standard streams (where CasADi prints its dumps) and file
    descriptors 1 and 2 (C code past Python's streams) sent nowhere, and Python's warnings
    ignored: a library's failures reach the caller as exceptions only, for the caller to state
    in its own words."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in (1, 2)]
    try:
        with (open(os.devnull, "w") as null, warnings.catch_warnings(), redirect_stdout(io.StringIO()),
              redirect_stderr(io.StringIO())):  # fmt: skip
            warnings.simplefilter("ignore")
            for fd in (1, 2):
                os.dup2(null.fileno(), fd)
            yield
    finally:
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)
