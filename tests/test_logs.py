"""The JSON-lines logs of finished runs (margin searches, the limits search of synthesize)."""

from __future__ import annotations

import json

from dvfc.analysis.output import append_log, read_log


def test_a_line_cut_short_by_an_interruption_is_ignored(tmp_path):
    """A kill while a line is written leaves a partial last line: the runs before it are read
    back, the partial one is not (it is run again on resume)."""
    log = tmp_path / "runs.jsonl"
    append_log(log, {"value": 0.1, "holds": True})
    append_log(log, {"value": 0.2, "holds": False, "peak": float("nan")})
    with open(log, "a") as handle:
        handle.write('{"value": 0.3, "hol')
    assert read_log(log) == [{"value": 0.1, "holds": True}, {"value": 0.2, "holds": False, "peak": None}]


def test_entries_are_strict_json_one_a_line(tmp_path):
    """Each entry is one line a strict parser reads (no NaN)."""
    log = tmp_path / "runs.jsonl"
    append_log(log, {"x": float("inf")})
    (line,) = log.read_text().splitlines()
    assert json.loads(line, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c))) == {"x": None}


def test_a_missing_log_has_no_entries(tmp_path):
    assert read_log(tmp_path / "none.jsonl") == []
