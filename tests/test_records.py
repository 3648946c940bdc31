"""Typed results serialised once (:mod:`dvfc.analysis.record`): what ``to_json`` keeps and converts,
that no public job hands out a dict, and that the command line holds no workflow."""

from __future__ import annotations

import ast
import json
import typing
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np
import pytest

import dvfc
from dvfc.analysis.record import ABSENT, INTERNAL, Absent, Record, jsonable

ROOT = Path(__file__).resolve().parent.parent


class Colour(StrEnum):
    RED = "red"


@dataclass(frozen=True, kw_only=True)
class Inner(Record):
    value: float


@dataclass(frozen=True, kw_only=True)
class Outer(Record):
    name: str
    colour: Colour
    inner: Inner
    array: np.ndarray
    scalar: np.float64
    path: Path
    missing: float | Absent = ABSENT
    nothing: float | None = None
    code_only: int = field(default=7, metadata=INTERNAL)


def test_to_json_is_strict_json_with_the_fields_names():
    """Enums as their values, arrays as lists, NumPy scalars as numbers, paths as strings, nested
    records as objects: ``json.dumps`` takes the result with no ``default``."""
    record = Outer(name="a", colour=Colour.RED, inner=Inner(value=1.5), array=np.arange(3.0), scalar=np.float64(2.0),
                   path=Path("x") / "y")  # fmt: skip
    data = json.loads(json.dumps(record.to_json(), allow_nan=False))
    assert data == {"name": "a", "colour": "red", "inner": {"value": 1.5}, "array": [0.0, 1.0, 2.0], "scalar": 2.0,
                    "path": str(Path("x") / "y"), "nothing": None}  # fmt: skip


def plain() -> Outer:
    return Outer(name="a", colour=Colour.RED, inner=Inner(value=0.0), array=np.zeros(0), scalar=np.float64(0),
                 path=Path())  # fmt: skip


def test_an_absent_key_is_left_out_and_none_is_kept():
    """A key only some results have is absent until set; None is a value (null), kept."""
    base = plain()
    assert "missing" not in base.to_json() and base.to_json()["nothing"] is None
    assert jsonable({"a": ABSENT, "b": 1}) == {"b": 1}


def test_an_internal_field_is_the_codes_not_the_jsons():
    base = plain()
    assert base.code_only == 7 and "code_only" not in base.to_json()


def test_absent_is_one_value_and_false():
    assert Absent() is ABSENT and not ABSENT and repr(ABSENT) == "ABSENT"


@pytest.mark.parametrize("name", [n for n in dvfc.__all__ if n not in ("Case",)])
def test_no_public_job_returns_a_dict(name):
    """Every function of the curated API returns a typed object (a record, a run, a map, a program)."""
    returned = typing.get_type_hints(getattr(dvfc, name), vars(dvfc) | _types())["return"]
    assert typing.get_origin(returned) is not dict and returned is not dict, (name, returned)


def _types() -> dict:
    """The names the curated API's annotations use (imported there only for the type checker)."""
    from dvfc.analysis.campaign import CampaignResult
    from dvfc.analysis.case import Case
    from dvfc.analysis.controller import Controller
    from dvfc.analysis.grid import GainMap
    from dvfc.analysis.margins import MarginsResult
    from dvfc.analysis.results import CertificateResult, VerificationResult
    from dvfc.analysis.simulate import Trajectory
    from dvfc.analysis.synthesize import SynthesisResult
    from dvfc.reports.document import ReportResult

    return {"np": np, **{t.__name__: t for t in (CampaignResult, Case, Controller, GainMap, MarginsResult,
                                                  CertificateResult, VerificationResult, Trajectory, SynthesisResult,
                                                  ReportResult)}}  # fmt: skip


COMMAND_LINES = 40
"""The longest a command's function may be: it parses, calls its job, shows progress and prints."""


@pytest.mark.parametrize("module", ["analysis/cli.py", "reports/cli.py"])
def test_every_command_is_thin(module):
    """No command function of the command line is longer than :data:`COMMAND_LINES` lines of body
    (its signature of options and its docstring left out): the workflows are the jobs'."""
    tree = ast.parse((ROOT / module).read_text())
    long = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and any(_is_command(d) for d in node.decorator_list):
            body = node.body[1:] if isinstance(node.body[0], ast.Expr) else node.body  # after the docstring
            lines = body[-1].end_lineno - body[0].lineno + 1
            if lines > COMMAND_LINES:
                long[node.name] = lines
    assert not long, long


def _is_command(decorator: ast.expr) -> bool:
    target = decorator.func if isinstance(decorator, ast.Call) else decorator
    return isinstance(target, ast.Attribute) and target.attr == "command"
