"""Margins of the loop as implemented, measured on the nonlinear loop by bisection, and the
linear margins of the sampled loop linearised at rest beside them (docs/math.md, fact 14;
tested in tests/test_multirate.py)."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis import margins as margins_module
from dvfc.analysis.campaign import CampaignSpec, read_runs, run_campaign
from dvfc.analysis.case import Case
from dvfc.analysis.cli import app
from dvfc.analysis.margins import (
    DEFAULT_FRICTION,
    ENDS_HOLDING,
    GROWTH_RATE,
    LINEAR,
    PARAMETERS,
    PAYLOAD_FACTOR,
    PERIODS,
    PLANT,
    PLANT_STEPS,
    UNCHECKED,
    LinearCheck,
    TrackingBound,
    base_value,
    envelope_growth,
    judge,
    judged_period,
    linear_margin_text,
    linear_statement,
    range_end,
    search,
    tracking_bound,
    tracking_error,
    trial,
    with_value,
)
from dvfc.analysis.multirate import implemented_record, implemented_text
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build, load
from dvfc.analysis.show import tolerance_text
from dvfc.analysis.simulate import Trajectory
from dvfc.models.errors import PlantErrors
from dvfc.models.target import TargetMotion


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


@pytest.mark.slow
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


def test_margins_json_has_the_contract():
    """``dvfc margins``' JSON (docs/cli.md), read from its golden record (tests/data/golden/margins.json: the
    default shortened to 4 s, two worker processes; ``tests/test_golden.py`` holds the command's JSON to it
    key by key and number by number): every parameter with value, unit, holds_at, breaks_at; the criterion;
    the linear margins of fact 14 (latency, camera and control rate) in words."""
    recorded = json.loads((Path(__file__).parent / "data" / "golden" / "margins.json").read_text())
    assert recorded["exit_code"] == 0
    record = recorded["json"]
    assert set(record["margins"]) == set(PARAMETERS)
    for m in record["margins"].values():
        assert {"value", "unit", "holds_at", "breaks_at"} <= set(m)
        assert m["value"] is not None or m["holds_at"] is not None or m["reason"]
    assert "holds" in record["criterion"] and "certified ultimate bound" in record["criterion"]
    assert record["tracking_bound"]["source"] == "envelope"
    linear = record["linear_margins"]
    assert linear["certified"] and set(linear["margins"]) == {"latency", "camera_rate", "control_rate"}
    assert f"latency <= {linear['margins']['latency']['value'] * 1e3:.4g} ms" in linear_margin_text(record)


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


def test_plant_error_parameters_change_their_own_entry_only(short_default):
    """``with_value`` on a plant-error parameter sets exactly its entry of the plant errors (the
    mount turned about the camera's x axis, ``fx`` and ``fy`` the fraction above the controller's,
    friction the multiple of :data:`DEFAULT_FRICTION` of the effort limits when the scenario has
    none) and the frame-drop probability its implementation entry; nothing else changes."""
    case = Case.load(short_default)
    loop, settings = case.loop, case.settings
    none = PlantErrors.none(loop.camera, loop.robot.n)
    effort = loop.robot.limits.effort
    expected = {
        "mount_rotation": (12.0, replace(none, mount_rpy=np.array([np.radians(12.0), 0.0, 0.0]))),
        "focal_length_error": (0.05, replace(none, fx=840.0, fy=840.0)),
        "friction_scale": (3.0, replace(none, viscous=3 * DEFAULT_FRICTION[0] * effort,
                                        coulomb=3 * DEFAULT_FRICTION[1] * effort)),
    }  # fmt: skip
    for name, (value, errors) in expected.items():
        assert base_value(name, settings) == 0.0
        changed = with_value(loop, settings, name, value)
        assert changed.implementation == settings.implementation, name
        for field in fields(PlantErrors):
            got, want = getattr(changed.errors, field.name), getattr(errors, field.name)
            assert np.allclose(got, want, rtol=1e-15, atol=0), (name, field.name)
    dropped = with_value(loop, settings, "frame_drop", 0.25)
    assert dropped.implementation == replace(settings.implementation, frame_drop=0.25) and dropped.errors is None


def test_a_large_mount_rotation_breaks_the_loop_and_a_small_one_does_not(short_default):
    """The mount-rotation search point judged on its run: 45 deg of tilt puts a feature out of
    the image at once; 2 deg holds."""
    case = Case.load(short_default)
    bound = tracking_bound(case)
    broken = trial(case, "mount_rotation", 45.0, bound)
    assert not broken["holds"] and broken["detail"].startswith("out_of_view"), broken
    assert trial(case, "mount_rotation", 2.0, bound)["holds"]


@pytest.fixture(scope="module")
def default_case():
    """The default example as it is (10 s, planned start), its tracking bound and fact 14's check."""
    case = Case.load(DEFAULT_SCENARIO)
    return case, tracking_bound(case), LinearCheck.of(case, implemented_record(case.loop, case.s0, case.settings))


def synthetic(t: np.ndarray, position: np.ndarray) -> Trajectory:
    """A completed run whose true tracking error ``g_d^-1 g`` is a translation of ``position`` m
    along x and no rotation (poses stored column-major, as CasADi's ``vec``)."""
    g = np.tile(np.eye(4), (len(t), 1, 1))
    g[:, 0, 3] = position
    return Trajectory(t, {"g_tracking": g.transpose(0, 2, 1).reshape(len(t), 16)}, {})


def test_the_error_envelope_grows_only_when_the_error_grows():
    """The steady-state check on runs built by hand (20 s at 100 Hz, bound 1 m, whole 4 s periods after the
    first: (4, 8] ... (16, 20]): a mode growing by rho = 1 + 1e-3 every 50 ms grows by ``1.001^80`` a period
    (closed form: each period's samples are the one before's times it), above ``exp(0.04)``: growing; a decaying
    transient onto the error of a target circling every 4 s, and a constant error, repeat their level: steady;
    growth of exactly
    ``exp(GROWTH_RATE T)`` a period is at the limit (steady), 1% more a period is not; a 10 s run holds one
    whole period after the first, fewer than ``PERIODS``: not judged."""
    t = np.linspace(0.0, 20.0, 2001)
    bound = TrackingBound(1.0, 180.0, "envelope", "")
    growing = envelope_growth(synthetic(t, 1e-3 * 1.001 ** (t / 0.05)), bound, 4.0)
    assert growing.growing and len(growing.levels) == len(growing.peaks) == 4
    assert growing.ratio == pytest.approx(1.001**80, rel=1e-12)
    settling = 0.3 * np.exp(-2 * t) + 0.02 * (1.5 + np.sin(2 * np.pi * (t + 0.5) / 4))
    assert 0.999 < envelope_growth(synthetic(t, settling), bound, 4.0).ratio <= 1.0
    assert envelope_growth(synthetic(t, np.full_like(t, 0.01)), bound, 4.0).ratio == 1.0
    at_limit = envelope_growth(synthetic(t, np.exp(GROWTH_RATE * t)), bound, 4.0)
    assert at_limit.ratio == pytest.approx(at_limit.limit, rel=1e-12) and not at_limit.growing
    assert envelope_growth(synthetic(t, np.exp(GROWTH_RATE * t) * 1.01 ** (t / 4)), bound, 4.0).growing
    assert envelope_growth(synthetic(t[t <= 10.0], np.full(1001, 0.01)), bound, 4.0) is None


def test_a_transient_does_not_hide_a_growing_mode_nor_noise_make_one():
    """Consecutive periods' levels: a 20 s trace of a decaying start ``0.6 exp(-0.5 t)``, a steady error repeating
    every 4 s with a component at 1.3 s that does not, and a mode ``0.01 exp(0.1 t)`` (ten times the rule's rate)
    is growing, although its last period's peak is below the largest before it (the start's transient in the
    first judged period; the rule that compared with it judged the trace steady); the same trace without the mode,
    and with white noise of a tenth of the error added, is steady."""
    t = np.linspace(0.0, 20.0, 10001)
    bound = TrackingBound(1.0, 180.0, "envelope", "")
    steady = 0.6 * np.exp(-0.5 * t) + 0.23 * np.abs(np.cos(np.pi * t / 4)) + 0.02 * np.sin(2 * np.pi * t / 1.3)
    growing = envelope_growth(synthetic(t, steady + 0.01 * np.exp(0.1 * t)), bound, 4.0)
    assert growing.growing and growing.peaks[-1] < max(growing.peaks[:-1])
    noise = 0.025 * np.random.default_rng(0).standard_normal(t.size)
    for trace in (steady, steady + noise):
        assert not envelope_growth(synthetic(t, np.abs(trace)), bound, 4.0).growing


def test_growth_is_judged_over_the_targets_period_or_quarters_of_a_run_at_rest(default_case):
    """The default's circle repeats every 4 s: its runs are judged over 4 s periods; a target at rest has no
    period, and its runs over ``duration / (PERIODS + 1)``."""
    case = default_case[0]
    assert judged_period(case.loop, 10.0) == 4.0
    at_rest = replace(case.loop, target=TargetMotion(case.loop.target.start))
    assert judged_period(at_rest, 10.0) == 10.0 / (PERIODS + 1)


@pytest.mark.slow
def test_a_latency_where_the_linearised_loop_is_unstable_does_not_hold_though_its_run_does(default_case):
    """At 146 ms on the default over 4 s (73 control periods; fact 14's linear margin is 140 ms)
    the sampled loop linearised at rest is unstable (rho > 1): the point does not hold, for that
    reason, although its run alone is within the tracking bound (the slow instability a short
    horizon hides: the search on the 10 s horizon alone found 144 ms)."""
    case, bound, linear = default_case
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["simulation"]["duration"] = 4.0
    short = case.with_scenario(Scenario.model_validate(data))
    point = trial(short, "latency", 0.146, bound, linear)
    assert linear.rho("latency", 0.146) > 1
    assert not point["holds"] and "unstable at this value (fact 14: rho = 1.00" in point["detail"], point
    assert point["linear"] == {"rho": linear.rho("latency", 0.146), "stable": False}
    # the run alone holds by judge, on its own horizon (one 4 s period: too few for the growth check)
    assert point["growth"] is None and point["horizons"] == [4.0]
    assert "its run over 4 s: tracking error" in point["detail"] and ">" not in point["detail"].split("; ")[1]


@pytest.mark.slow
def test_a_loop_just_past_its_linear_margin_fails_the_steady_state_check_alone(default_case):
    """Without fact 14's check (as where it does not apply) the steady-state check alone: at 146 ms, just past
    the linear margin (rho = 1.00293 per 50 ms), the 10 s run is within the bound but holds one whole 4 s period
    after the first (not judged), and over 20 s the last period's peak is about 1.14x the largest before it
    (> exp(0.04)): growing; over 40 s the error leaves the bound: does not hold, the record keeping all three
    horizons. The scenario's own run (20 ms) is judged on 20 s and is steady (its peaks within 1%)."""
    case, bound, _ = default_case
    first = with_value(case.loop, case.settings, "latency", 0.146)
    run = as_implemented(case.loop, first).run(case.s0)
    assert judge(run, case.loop, first, bound)[0] and envelope_growth(run, bound, 4.0) is None
    longer = replace(first, duration=20.0)
    growth = envelope_growth(as_implemented(case.loop, longer).run(case.s0), bound, 4.0)
    assert growth.growing and growth.ratio > 1.1, growth
    point = trial(case, "latency", 0.146, bound)
    assert not point["holds"] and point["horizons"] == [10.0, 20.0, 40.0], point
    assert point["linear"] == {"rho": None, "stable": None}
    own = trial(case, "latency", case.settings.implementation.latency, bound)
    assert own["holds"] and own["horizons"] == [10.0, 20.0] and not own["growth"]["growing"], own
    assert own["growth"]["ratio"] < 1.01


@pytest.mark.slow
def test_the_measured_latency_and_camera_margins_never_pass_the_linear_ones(default_case):
    """On the default, the measured latency margin is at most fact 14's linear margin (140 ms)
    and the measured camera-rate margin at least its (8.065 Hz), and so is the last point judged
    to hold (not merely clipped): each point beyond them judged not holding; the margin record
    says it was checked (the search on the scenario's 10 s horizon alone found 144 ms)."""
    case, bound, linear = default_case
    for name, worse in (("latency", 1), ("camera_rate", -1)):
        margin = search(case, name, bound, linear=linear)
        lin = linear.margins[name]
        assert worse * margin["value"] <= worse * lin["stable_at"], (name, margin)
        assert worse * margin["holds_at"] <= worse * lin["stable_at"], (name, margin)  # not merely clipped
        assert margin["linear"]["checked"] and margin["holds_run"]["linear"]["stable"], margin
        assert margin["breaks_run"]["linear"]["rho"] is not None


def test_a_measured_margin_beyond_the_linear_one_is_clipped_to_it():
    """The clipping rule on a UR3-like record: a measured 152 ms latency margin against a linear
    130 ms is reported as 130 ms, clipped, saying so; 120 ms stays; a camera rate is clipped from
    below; a search that holds over its whole range is clipped to a linear margin inside it;
    parameters fact 14 has no margin for, and loops it does not apply to, are not checked."""
    margins = {"latency": {"value": 0.13, "stable_at": 0.13, "unstable_at": 0.132, "range": [0.02, 0.25]},
               "camera_rate": {"value": 10.0, "stable_at": 10.0, "unstable_at": 9.8, "range": [60.0, 1.0]}}  # fmt: skip
    linear = LinearCheck(None, margins, None)
    clipped = linear_statement("latency", 0.152, linear)
    assert clipped["clipped"] and clipped["value"] == 0.13 and "clipped to it" in clipped["statement"]
    assert linear_statement("latency", 0.12, linear) | {"statement": ""} == {"basis": "linear margin",
        "checked": True, "linear_margin": 0.13, "value": 0.12, "clipped": False, "statement": ""}  # fmt: skip
    assert linear_statement("camera_rate", 8.0, linear)["value"] == 10.0
    assert linear_statement("camera_rate", 12.0, linear)["value"] == 12.0
    assert linear_statement("latency", None, linear)["value"] == 0.13
    for name, check in (("pixel_noise", linear), ("latency", LinearCheck(None, None, "does not apply: n = 7"))):
        record = linear_statement(name, 3.0, check)
        assert not record["checked"] and record["value"] == 3.0
        assert record["basis"] == "measured only" and record["statement"].startswith("measured only")


def test_every_searched_parameter_is_checked_by_fact_14_or_says_why_not():
    """Each parameter the margins search is a schedule parameter of fact 14 (:data:`LINEAR`), a plant
    parameter it linearises anew (:data:`PLANT`) or one it does not check, with the reason (:data:`UNCHECKED`):
    exactly one of the three."""
    groups = (set(LINEAR), set(PLANT), set(UNCHECKED))
    assert set(PARAMETERS) == set().union(*groups) and sum(map(len, groups)) == len(PARAMETERS)
    assert "schedule" in UNCHECKED["frame_drop"] and "not certified" in UNCHECKED["frame_drop"]


def test_a_linear_margin_stable_at_the_ranges_end_reads_as_such():
    """Fact 14's line when a margin is stable at its searched range's end (the bisection checks no value
    between): the range's end in words, not "<= none in range" nor "throughout"."""
    margin = lambda value, end: {"value": value, "stable_at": end, "unstable_at": None, "range": [0, end]}  # noqa: E731
    record = {"rho": 0.9, "certified": True, "reason": None, "rate": 1.0, "period": 0.05, "lyapunov_margin": 1.0,
              "plant": "the plant equal to the controller's model",
              "margins": {"latency": margin(None, 0.25), "camera_rate": margin(None, 1.0),
                          "control_rate": margin(47.0, 10.0)}}  # fmt: skip
    text = implemented_text(record)
    assert "none in range" not in text
    assert "latency stable at the searched range's end up to 250 ms" in text and "throughout" not in text
    assert "camera stable at the searched range's end down to 1 Hz" in text and "control >= 47 Hz" in text


def test_the_payload_range_scales_with_the_arms_mass():
    """The payload's searched range ends at ``PAYLOAD_FACTOR`` times the URDF's total link mass
    (against adam's total mass of the same URDF: 20.99 kg on the UR5). The default example loaded alone:
    the range needs its loop and settings, not :func:`default_case`'s tracking bound and fact-14 check."""
    case = Case.load(DEFAULT_SCENARIO)
    total = float(case.loop.robot._kindyn.get_total_mass())
    end = range_end("payload_mass", case.loop, case.settings)
    assert end == pytest.approx(PAYLOAD_FACTOR * total, rel=1e-12) and 20 < total < 22


def test_the_campaign_tolerance_line_prints_its_bounds():
    """The campaign's tolerance line states the order statistic's values (position, angle,
    tracking ratio), not only the sentence; too few runs: the sentence alone."""
    tolerance = {"quantile": 0.9, "confidence": 0.95, "rank": 279, "tracking_position": 0.0399,
                 "tracking_angle_deg": 6.53, "tracking_ratio": 1.098, "statement": "with 95% confidence ...",
                 "note": "runs that did not complete count as an infinite tracking error"}  # fmt: skip
    text = tolerance_text(tolerance)
    assert text.startswith("with 95% confidence ...: ")
    assert "position <= 0.0399 m" in text and "angle <= 6.53 deg" in text and "tracking ratio <= 1.098" in text
    few = {**tolerance, "rank": None, "statement": "2 runs are too few to bound the 90% quantile at 95%"}
    assert tolerance_text(few) == few["statement"]


@pytest.mark.slow
def test_replaying_a_failed_campaign_run_reports_the_failure_and_exits_1(tmp_path):
    """A campaign run that completes but fails the criterion (the mount tilted 0.15-0.2 rad: the
    torque exceeds the effort limits, 2 s runs) replayed by ``dvfc simulate --campaign-run 0``:
    exit 1 (a failing check, docs/cli.md), the campaign dataset's reason on standard error, and
    ``campaign_row.holds`` false, as the campaign recorded it."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["simulation"]["duration"] = 2.0
    data["dispersion"] = {"plant.mount.rpy": {"dist": "uniform", "low": [0.15, 0.0, 0.0], "high": [0.2, 0.0, 0.0]}}
    path = tmp_path / "tilted.toml"
    path.write_text(tomli_w.dumps(data))
    case = Case.load(path)
    run_campaign(CampaignSpec.of(case, tracking_bound(case)), tmp_path / "campaign", 1)
    recorded = read_runs(tmp_path / "campaign").to_pylist()[0]
    assert not recorded["holds"] and recorded["status"] == "ok", recorded
    result = CliRunner().invoke(app, ["simulate", str(path), "--campaign-run", "0", "--out", str(tmp_path / "r"),
                                      "--json", "-"])  # fmt: skip
    assert result.exit_code == 1, result.output
    assert f"campaign run 0: FAILS by the margins criterion ({recorded['reason']})" in result.stderr
    row = json.loads(result.stdout)["campaign_row"]
    assert row["holds"] is False and row["reason"] == recorded["reason"]


@pytest.mark.slow
def test_a_plant_parameter_is_checked_on_the_plant_linearised_at_its_value(default_case):
    """A payload, mount rotation, focal-length error or friction scale changes the plant fact 14 linearises: at
    each search point the check's rho is that of the plant as declared with the value (equal to fact 14's
    record for that plant to 1e-12, not the scenario's rho), and a point whose plant has rho >= 1 does not
    hold whatever its run (a focal length twice the controller's: no equilibrium near the model's)."""
    case, bound, linear = default_case
    for name, value in (("payload_mass", 6.0), ("focal_length_error", 0.5), ("friction_scale", 10.0)):
        changed = with_value(case.loop, case.settings, name, value)
        record = implemented_record(case.loop, case.s0, changed)
        assert linear.rho(name, value) == pytest.approx(record["rho"], abs=1e-12), name
        assert abs(record["rho"] - linear.system.rho()) > 1e-4, name
    assert linear.rho("focal_length_error", 1.0) == math.inf
    point = trial(case, "focal_length_error", 1.0, bound, linear)
    assert not point["holds"] and point["linear"] == {"rho": math.inf, "stable": False}


@pytest.mark.slow
def test_a_plant_parameters_margin_is_never_beyond_its_linear_margin(default_case, monkeypatch):
    """A focal-length error's runs said to hold over the whole searched range (a stand-in for the runs) give a
    margin no larger than fact 14's linear margin of the plant as declared: the bisection's last stable value
    has rho < 1 and its first unstable one rho >= 1 (a focal length twice the controller's has no equilibrium
    near the model's), and the reported margin is clipped to it, saying so."""
    case, bound, linear = default_case
    held = lambda case, name, value, bound, linear, first=None: {  # noqa: E731
        "value": value, "holds": True, "detail": "", "horizon": 10.0, "horizons": [10.0], "growth": None,
        "linear": {"rho": None, "stable": None}}  # fmt: skip
    monkeypatch.setattr(margins_module, "trial", held)
    margin = search(case, "focal_length_error", bound, linear=linear)
    lin = linear.margin("focal_length_error", 0.0, 1.0)
    assert lin["value"] is not None and lin["unstable_at"] - lin["stable_at"] <= 1.0 / 2**PLANT_STEPS
    rho = lambda value: linear.rho("focal_length_error", value)  # noqa: E731
    assert rho(lin["stable_at"]) < 1 <= rho(lin["unstable_at"])
    assert margin["value"] == lin["stable_at"] and margin["linear"]["clipped"], margin["linear"]
    assert margin["linear"]["basis"] == "linear margin of the plant as declared"


def test_a_search_whose_ranges_end_holds_says_it_ran_that_value_only(monkeypatch):
    """When the run at the searched range's end holds, the bisection runs nothing else: the margin's reason
    says that one value was run and none between (not that the loop holds over the whole range), and so does
    the linear line of a value clipped from there."""
    case = Case.load(DEFAULT_SCENARIO)
    ran = []
    held = lambda case, name, value, bound, linear, first=None: ran.append(value) or {  # noqa: E731
        "value": value, "holds": True, "detail": "", "horizon": 1.0, "horizons": [1.0], "growth": None,
        "linear": {"rho": None, "stable": None}}  # fmt: skip
    monkeypatch.setattr(margins_module, "trial", held)
    margin = search(case, "latency", None, linear=None)
    assert ran == [margin["range"][1]] and margin["runs"] == 1 and margin["holds_at"] == margin["range"][1]
    assert margin["reason"] == ENDS_HOLDING and "end" in ENDS_HOLDING and "whole" not in ENDS_HOLDING
    linear = LinearCheck(None, {"latency": {"value": 0.13, "stable_at": 0.13, "unstable_at": 0.132,
                                            "range": [0.02, 0.25]}}, None)  # fmt: skip
    assert linear_statement("latency", None, linear)["statement"].startswith("a run at the searched range's end")
