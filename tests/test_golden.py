"""Every command's JSON against the one recorded in ``tests/data/golden/``: the same keys at every
level and the same values, numbers to :data:`RTOL`, so that a change in how results are built or
serialised cannot change what the commands promise (docs/cli.md).

Run on the default example (``simulate``, ``pose``, ``certify``, ``verify``, ``export --check``,
``synthesize``), on the default shortened to :data:`SHORT` s (``margins``, on two worker processes), on the
shipped cell shortened likewise (``campaign``, three runs) and on ``examples/ur5_grid.toml`` (``certify`` of a
grid). Left out of the comparison: what is the machine's and not the result's (:data:`VOLATILE`: wall times, the
step's timing, provenance, the load) and the output folder's path (written ``<OUT>``).
``DVFC_WRITE_GOLDEN=1 pytest tests/test_golden.py`` records them anew.
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from pathlib import Path

import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.reports.cli import app

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = Path(__file__).resolve().parent / "data" / "golden"
SHORT = 4.0
"""Duration (s) of the shortened scenarios: past the planned start (2.02 s), so that the criterion's last
quarter is after it."""

RTOL = 1e-6
"""Relative tolerance of a number: the recorded values come from the same code on another machine, whose
BLAS, LAPACK and libm may round the last bits differently; CVODES' steps and the SDP solver's iterations
amplify those to about 1e-9 relative (measured between two machines' runs of the default); 1e-6 is far
below any digit a command prints (at most 6 significant) and far above round-off."""

ATOL = 1e-7
"""Absolute tolerance of a number near zero (a residual, a state's norm at the end of a run): CVODES' global
error over a 10 s run at ``rtol = atol = 1e-10``. A perturbation of the last bit (the compiled right-hand side
against the virtual machine's, another libm) changes its step sequence and so moves such a number by the global
error, not by round-off: measured 1.1e-8 on ``|x(T)| / |x(0)|`` (Theorem 1's claim, 3.6e-6) between two runs."""

VOLATILE = frozenset({"provenance", "seconds", "timing", "wall_time", "wall_time_per_run", "load_average"})
"""Keys whose values are the machine's (times, load, versions and paths of provenance), not the result's."""

WRITE = os.environ.get("DVFC_WRITE_GOLDEN") == "1"


def shortened(source: Path, folder: Path) -> Path:
    """``source`` with its ``[simulation] duration`` set to :data:`SHORT`, written in ``folder``."""
    data = tomllib.loads(source.read_text())
    data["simulation"]["duration"] = SHORT
    path = folder / source.name
    path.write_text(tomli_w.dumps(data))
    return path


def commands(folder: Path) -> dict[str, list[str]]:
    """Each recorded command's arguments (without ``--json``), its outputs in ``folder``."""
    default, short = str(DEFAULT_SCENARIO), str(shortened(DEFAULT_SCENARIO, folder))
    cell = str(shortened(ROOT / "examples" / "ur5_cell.toml", folder))
    return {
        "simulate": ["simulate", default, "--out", str(folder / "simulate")],
        "pose": ["pose", default],
        "certify": ["certify", default, "--out", str(folder / "certify")],
        "certify_grid": ["certify", str(ROOT / "examples" / "ur5_grid.toml"), "--out", str(folder / "grid")],
        "verify": ["verify", default, "--out", str(folder / "verify")],
        "export": ["export", default, "--out", str(folder / "export"), "--check"],
        "synthesize": ["synthesize", default, "--out", str(folder / "synthesize" / "designed.toml")],
        "margins": ["margins", short, "--out", str(folder / "margins"), "--workers", "2"],
        "campaign": ["campaign", cell, "--runs", "3", "--out", str(folder / "campaign")],
    }


def comparable(value, folder: str):
    """``value`` without its :data:`VOLATILE` keys, the output folder written ``<OUT>``."""
    if isinstance(value, dict):
        return {k: comparable(v, folder) for k, v in value.items() if k not in VOLATILE}
    if isinstance(value, list):
        return [comparable(v, folder) for v in value]
    if isinstance(value, str):
        return value.replace(folder, "<OUT>")
    return value


def differences(got, want, where: str = "") -> list[str]:
    """Where ``got`` differs from ``want``: a key missing or added, a type, a string, a number beyond
    :data:`RTOL` and :data:`ATOL`, a list's length."""
    if isinstance(want, dict) and isinstance(got, dict):
        out = [f"{where}.{k}: missing" for k in want if k not in got]
        out += [f"{where}.{k}: not recorded" for k in got if k not in want]
        for k in want.keys() & got.keys():
            out += differences(got[k], want[k], f"{where}.{k}")
        return out
    if isinstance(want, list) and isinstance(got, list):
        if len(got) != len(want):
            return [f"{where}: {len(got)} items, recorded {len(want)}"]
        return [d for i, (g, w) in enumerate(zip(got, want, strict=True)) for d in differences(g, w, f"{where}[{i}]")]
    numbers = (int, float)
    if isinstance(want, numbers) and isinstance(got, numbers) and not isinstance(want, bool) \
            and not isinstance(got, bool):  # fmt: skip
        same = math.isclose(got, want, rel_tol=RTOL, abs_tol=ATOL) or (math.isnan(got) and math.isnan(want))
        return [] if same else [f"{where}: {got!r}, recorded {want!r}"]
    return [] if type(got) is type(want) and got == want else [f"{where}: {got!r}, recorded {want!r}"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("golden")


@pytest.fixture(scope="module")
def arguments(folder) -> dict[str, list[str]]:
    """:func:`commands` in ``folder``, its shortened scenarios written once for the module."""
    return commands(folder)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["simulate", "pose", "certify", "certify_grid", "verify", "export", "synthesize",
                                  "margins", "campaign"])  # fmt: skip
def test_each_commands_json_is_the_recorded_one(name, folder, arguments):
    """The command's JSON has the recorded keys at every level and the recorded values (numbers to
    :data:`RTOL`), and it exits with the recorded status."""
    target = folder / f"{name}.json"
    result = CliRunner().invoke(app, [*arguments[name], "--json", str(target)], env={"COLUMNS": "400"})
    assert result.exit_code in (0, 1), result.output
    got = {"exit_code": result.exit_code, "json": comparable(json.loads(target.read_text()), str(folder))}
    recorded = GOLDEN / f"{name}.json"
    if WRITE:
        GOLDEN.mkdir(parents=True, exist_ok=True)
        recorded.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
    found = differences(got, json.loads(recorded.read_text()))
    assert not found, "\n".join(found[:20])


def test_the_comparison_sees_a_changed_key_value_or_length():
    """The comparison itself: a renamed key, a number moved by 1e-5 relative, a string and a list's
    length are each a difference; a number moved by 1e-9 relative, one near zero moved by less than
    :data:`ATOL` and a volatile key are not."""
    want = {"a": 1.0, "b": "x", "c": [1, 2], "d": {"e": 0.5}}
    assert differences(want, want) == []
    assert differences({**want, "a": 1.0 + 1e-9}, want) == []
    assert differences({**want, "a": 1e-8}, {**want, "a": 2e-8}) == []  # within the integrator's global error
    assert differences({**want, "a": 1.0 + 1e-5}, want) == [".a: 1.00001, recorded 1.0"]
    assert differences({**want, "b": "y"}, want) == [".b: 'y', recorded 'x'"]
    assert differences({**want, "c": [1]}, want) == [".c: 1 items, recorded 2"]
    assert sorted(differences({"a": 1.0, "b": "x", "c": [1, 2], "f": {"e": 0.5}}, want)) == [".d: missing",
                                                                                             ".f: not recorded"]
    assert comparable({"seconds": 3.0, "p": "/tmp/x/y", "q": 1}, "/tmp/x") == {"p": "<OUT>/y", "q": 1}
