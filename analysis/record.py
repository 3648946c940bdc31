"""Typed results, serialised once at the edge.

A job returns a frozen dataclass deriving from :class:`Record`; its fields are the names of its
JSON, and :meth:`Record.to_json` is the only place a result becomes JSON-ready: nested records,
enums (their values), NumPy arrays and scalars, paths, tuples and mappings are converted there. A
key present only in some results (a grid's files, a synthesis' target speed) defaults to
:data:`ABSENT` and is left out of the JSON until set; a field with ``metadata=INTERNAL`` gives the
code typed access to what the JSON does not hold (a run, a certificate).
"""

from __future__ import annotations

import dataclasses
from enum import Enum
from pathlib import Path
from typing import Any, Final, Protocol

import numpy as np


class Absent:
    """The value of a key a result does not have (left out of its JSON; None is a value)."""

    _instance: Absent | None = None

    def __new__(cls) -> Absent:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "ABSENT"

    def __bool__(self) -> bool:
        return False


ABSENT: Final = Absent()
"""The one :class:`Absent` value."""

INTERNAL: Final = {"internal": True}
"""Field metadata: the field is for the code, not part of the JSON."""


def jsonable(value: Any) -> Any:
    """``value`` as JSON-ready Python: records and dataclasses as objects keyed by their field names (a
    dataclass with its own ``to_json``: that), :data:`ABSENT` and internal fields left out, enums as
    their values, arrays as lists, NumPy scalars as Python numbers, paths as strings."""
    if not isinstance(value, Record) and callable(getattr(value, "to_json", None)):
        return jsonable(value.to_json())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not f.metadata.get("internal") and getattr(value, f.name) is not ABSENT}  # fmt: skip
    if isinstance(value, Enum):
        return jsonable(value.value)
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items() if v is not ABSENT}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value


class Serialisable(Protocol):
    """What the command line writes as JSON: a :class:`Record`, or a result with its own ``to_json``."""

    def to_json(self) -> dict[str, Any]: ...


class Record:
    """A job's typed result (a frozen dataclass deriving from this); :meth:`to_json` its JSON."""

    def to_json(self) -> dict[str, Any]:
        """The result as ``dvfc``'s JSON output (docs/cli.md), keys at every level as documented."""
        out: dict[str, Any] = jsonable(self)
        return out
