"""Margins of the loop as implemented, measured on the nonlinear loop by bisection, and the
linear margins of the sampled loop linearised at rest beside them (docs/math.md, fact 14;
tested in tests/test_multirate.py)."""

from __future__ import annotations

import json
import tomllib
from dataclasses import replace

import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis.case import Case
from dvfc.analysis.cli import app
from dvfc.analysis.margins import PARAMETERS, linear_margin_text, search, tracking_bound, tracking_error, trial
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, build, load


@pytest.fixture(scope="module")
def short_default(tmp_path_factory):
    """The default example over 1 s (compiled: the runs share the cached C of the others), from the
    paper's start (constant reference, the ``[observer]`` error): its start transient is what the
    latency and torque margins break."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["simulation"]["duration"] = 1.0
    data["start"] = {"reference": "constant", "observer": "scenario"}
    path = tmp_path_factory.mktemp("margins") / "short.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_latency_margin_holds_below_and_breaks_above(short_default):
    """The measured latency margin brackets the breaking point: the loop holds at 0.8x the
    margin and breaks at 1.25x (latencies rounded to whole control periods, as the search's)."""
    case = Case.load(short_default)
    bound = tracking_bound(case)
    margin = search(case, "latency", bound)
    value = margin["value"]
    assert value is not None and margin["breaks_at"] <= 1.25 * value
    assert trial(case, "latency", 0.8 * value, bound)["holds"]
    assert not trial(case, "latency", 1.25 * value, bound)["holds"]


@pytest.mark.slow
def test_without_a_certified_envelope_the_criterion_is_twice_the_continuous_loops(short_default, tmp_path):
    """When the design has no certified envelope (here a torque bound of 100 N m: no
    ``theta_bar`` is self-consistent), the tracking bound falls back to twice the continuous
    loop's error, position and angle each, and the criterion says so; with the envelope the
    criterion is its certified ultimate bound."""
    assert tracking_bound(Case.load(short_default)).source == "envelope"
    data = tomllib.loads(short_default.read_text())
    data["envelope"] = {"torque": 100.0}
    path = tmp_path / "unbounded.toml"
    path.write_text(tomli_w.dumps(data))
    bound = tracking_bound(Case.load(path))
    assert bound.source == "continuous" and "2x the continuous loop's" in bound.text
    spec, base = load(path)
    loop, s0, settings = build(spec, base)
    traj = as_implemented(loop, replace(settings, implementation=None, plant=None)).run(s0)
    position, angle = tracking_error(traj)
    assert (bound.position, bound.angle_deg) == (2 * position, 2 * angle)


@pytest.mark.slow
def test_margins_command_writes_the_contract(tmp_path):
    """``dvfc margins --json -`` with two worker processes: every parameter with value,
    unit, holds_at, breaks_at; the criterion; the linear margins of fact 14 (latency, camera
    and control rate) in words; provenance."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    # long enough for the scenario's own run to settle within the envelope's ultimate bound over its
    # last half (the start transient takes about 1.6 s); not compiled: the payload's runs would
    # compile a plant each
    data["simulation"].update(duration=4.0, jit=False)
    path = tmp_path / "tiny.toml"
    path.write_text(tomli_w.dumps(data))
    result = CliRunner().invoke(app, ["margins", str(path), "--out", str(tmp_path / "m"), "--workers", "2",
                                      "--json", "-"])  # fmt: skip
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    assert set(record["margins"]) == set(PARAMETERS)
    for m in record["margins"].values():
        assert {"value", "unit", "holds_at", "breaks_at"} <= set(m)
        assert m["value"] is not None or m["holds_at"] is not None or m["reason"]
    assert "holds" in record["criterion"] and "certified ultimate bound" in record["criterion"]
    assert record["tracking_bound"]["source"] == "envelope"
    linear = record["linear_margins"]
    assert linear["certified"] and set(linear["margins"]) == {"latency", "camera_rate", "control_rate"}
    assert f"latency <= {linear['margins']['latency']['value'] * 1e3:.4g} ms" in linear_margin_text(record)
    assert "provenance" in record and (tmp_path / "m" / "margins.json").exists()


def test_a_run_over_the_effort_limits_does_not_hold_unless_clipped(short_default):
    """The criterion's torque clause: at 0.5x the URDF's efforts the default's start transient
    (joint 2 at 0.87 of its limit) asks for more than the limit, so with ``saturate`` off the
    run does not hold, for that reason; the same search point with ``saturate`` on is judged
    on the run with clipped torques instead (its tracking), not on the torque asked for."""
    case = Case.load(short_default)
    bound = tracking_bound(case)
    over = trial(case, "torque_scale", 0.5, bound)
    assert not over["holds"] and over["detail"].startswith("peak torque"), over
    data = tomllib.loads(short_default.read_text())
    data["implementation"]["saturate"] = True
    clipped = short_default.parent / "clipped.toml"
    clipped.write_text(tomli_w.dumps(data))
    assert not trial(Case.load(clipped), "torque_scale", 0.5, bound)["detail"].startswith("peak torque")
