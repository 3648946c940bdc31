"""The levels the envelope and the start statements claim (docs/math.md, facts 7, 16b and 16a),
checked against their statements: the envelope's level covers ``V(0)`` and lies within the
self-consistent level ``min(w_rc, w_re)(1 - cos theta_bar)`` (fact 7, first exit); the planned
start's level does too, strictly at the boundary; the path's Lipschitz slack is the stated ``L``
over half a cell, and ``L`` bounds the variation of ``Ad_(g^-1) Ad_(g^-1)^T`` (16b.2); the ramp's
level bounds every step of its recursion and the limit ``b/k`` it rises to, and its visibility time
never precedes the last step above the visible level (16a.3). The idealised UR5 (``ur5_paper_ideal``)
from rest with the planned reference or the ramp; the statement functions are called directly (the
tube form, which is checked elsewhere, is left out of the planned start to keep these short)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dvfc.analysis import start as start_module
from dvfc.analysis.case import Case
from dvfc.analysis.envelope import THETA_GRID, design_of, disturbance_bounds, envelope, start_storage
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario

import reference as ref
from helpers import scenario_dict


def from_rest(start: dict):
    """An edit: the idealised scenario from rest with the ``[start]`` section ``start``."""

    def edit(data: dict) -> None:
        data["start"] = start
        data["robot"]["qd0"] = [0.0] * 6

    return edit


def statement_inputs(edit) -> dict:
    """The design, camera, disturbance bounds, start storage and plan of the idealised scenario."""
    case = Case(Scenario.model_validate(scenario_dict(edit)), DEFAULT_SCENARIO.parent)
    loop = case.loop
    return {
        "design": design_of(case.point, case.reference, loop.robot.mass_bounds),
        "camera": loop.camera,
        "disturbance": disturbance_bounds(case.scenario.envelope, loop),
        "start": start_storage(loop, case.s0),
        "plan": loop.plan,
        "ramp": loop.ramp,
    }


def self_consistent(weights, theta_bar_deg: float) -> float:
    """Fact 7: ``c_max = min(w_rc, w_re)(1 - cos theta_bar)``."""
    _, w_rc, _, w_re = weights
    return min(w_rc, w_re) * (1 - math.cos(math.radians(theta_bar_deg)))


@pytest.fixture(scope="module")
def planned_inputs():
    return statement_inputs(from_rest({"reference": "planned", "duration": 1.0, "observer": "scenario"}))


def test_envelope_level_covers_the_start_and_stays_within_the_self_consistent_level(planned_inputs):
    """Fact 7's first exit: ``V(t) <= c`` for all ``t`` needs ``V(0) <= c``, ``c_inf <= c`` and
    ``c <= c_max(theta_bar)``. For starts below ``c_inf``, between ``c_inf`` and the smallest
    ``c_max`` of the grid, between two ``c_max`` and above every ``c_max`` (``2 min(w_rc, w_re)``):
    a covered start has ``level = max(c_inf, V(0)) >= V(0)`` and ``level <= invariant_v``, the
    latter the formula of fact 7 at the chosen ``theta_bar`` to 1e-12; an uncovered one is reported
    outside (the ultimate statement)."""
    i = planned_inputs
    design, weights = i["design"], i["design"].weights
    base = envelope(design, i["camera"], i["disturbance"], {**i["start"], "V0": 0.0}, search=False)
    c_inf = base.ultimate_V
    above_all = 2 * min(weights[1], weights[3]) * 1.01
    for v0 in (0.5 * c_inf, 1.5 * c_inf, self_consistent(weights, 4.0) * 0.999, 0.01, above_all):
        env = envelope(design, i["camera"], i["disturbance"], {**i["start"], "V0": v0}, search=False)
        assert env.invariant_V == pytest.approx(self_consistent(weights, env.theta_bar_deg), rel=1e-12)
        assert env.ultimate_V <= env.invariant_V
        if v0 >= above_all:
            assert not env.start["inside"] and env.start["level"] is None
            continue
        assert env.start["inside"], v0
        assert env.level == pytest.approx(max(env.ultimate_V, v0), rel=1e-15)
        assert v0 <= env.level <= env.invariant_V


@pytest.mark.slow
def test_planned_start_level_lies_strictly_below_its_self_consistent_level_at_the_boundary(planned_inputs, monkeypatch):
    """(16b.3) needs ``c = max(V(0), c_inf,path) < c_max(theta_bar)``; equality is the first-exit
    argument's boundary case, not covered (fact 7, step 7). With ``V(0)`` exactly ``c_max`` at 4
    degrees (a grid point) the statement moves to 5 degrees; just below it (0.999) it stays at 4.
    Either way ``V(0) <= level < c_max``, ``c_max`` the formula of fact 7 to 1e-12."""
    monkeypatch.setattr(start_module, "tube_start", lambda *args: {"inside": False})
    i = planned_inputs
    design = i["design"]
    boundary = float(design.c_max(THETA_GRID[3:4])[0])
    assert math.degrees(THETA_GRID[3]) == pytest.approx(4.0)
    assert boundary == pytest.approx(self_consistent(design.weights, 4.0), rel=1e-12)
    for v0, degrees in ((boundary, 5.0), (0.999 * boundary, 4.0)):
        env = envelope(design, i["camera"], i["disturbance"], {**i["start"], "V0": v0}, search=False)
        record = start_module.planned_start(design, i["camera"], i["disturbance"], env, i["plan"])
        assert record["inside"] and record["theta_bar_deg"] == pytest.approx(degrees)
        assert record["invariant_V"] == pytest.approx(self_consistent(design.weights, degrees), rel=1e-12)
        assert v0 <= record["level"] < record["invariant_V"]
        assert record["level"] == max(v0, record["ultimate_V_path"])


def x_matrix(radius: float) -> np.ndarray:
    """``X(p) = Ad_(g^-1) Ad_(g^-1)^T`` at ``g = (radius e_z, I)`` (tests/reference.py's ``Ad``)."""
    ad = ref.adjoint(np.array([0.0, 0.0, -radius]), np.eye(3))
    return ad @ ad.T


@pytest.mark.slow
@pytest.mark.parametrize(("s", "theta_deg"), [(0.5, 4.0), (0.2, 10.0)])
def test_path_rate_slack_is_the_stated_lipschitz_constant_over_half_a_cell(planned_inputs, s, theta_deg):
    """(16b.2): the slack subtracted from the path's rate is ``L h / 2`` with ``h = (r_hi - r_lo) /
    cells`` and ``L = max(k_c) max(w_pc, w_rc)^2 (2 r_hi + 1) / min(D_ce)``, ``D_ce`` fact 7's
    ``diag(w_pc/2, w_rc/(1 + cos theta_bar), w_pe/2, w_re/(1 + cos theta_bar))`` (to 1e-12). The
    constant rests on ``||X(p) - X(p')||_2 <= (r + r' + 1)|r - r'|``, checked here on 2000 random
    pairs of radii in ``[0, 2]`` (tolerance 1e-12 relative); for close radii at ``r = 2`` the ratio is
    ``2 + sqrt(5) = 4.236`` against ``2 r + 1 = 5``: a constant ``r_hi + 1`` (3) would not bound it."""
    i = planned_inputs
    design = i["design"]
    radii = start_module.path_range(i["plan"])
    theta = math.radians(theta_deg)
    rate = start_module.path_rate(design, radii, s, theta)
    w_pc, w_rc, w_pe, w_re = design.weights
    d_min = min(w_pc / 2, w_rc / (1 + math.cos(theta)), w_pe / 2, w_re / (1 + math.cos(theta)))
    lipschitz = float(np.max(design.point.k_c)) * max(w_pc, w_rc) ** 2 * (2 * radii[1] + 1) / d_min
    assert rate.slack == pytest.approx(lipschitz * (radii[1] - radii[0]) / rate.cells / 2, rel=1e-12)
    rng = np.random.default_rng(16)
    r, r2 = rng.uniform(0, 2, (2, 2000))
    gap = np.array([np.linalg.norm(x_matrix(a) - x_matrix(b), 2) for a, b in zip(r, r2, strict=True)])
    assert np.all(gap <= (r + r2 + 1) * np.abs(r - r2) * (1 + 1e-12))
    close = np.linalg.norm(x_matrix(2.0) - x_matrix(2.0 - 1e-6), 2) / 1e-6
    assert close == pytest.approx(2 + math.sqrt(5), rel=1e-5) and close > 2.0 + 1


@pytest.fixture(scope="module")
def ramp_runs():
    """The ramp's statement (0.5 s) on the idealised scenario from rest: as computed, with the
    visible level replaced by the stated level, and by just below and just above its final step's
    bound."""
    i = statement_inputs(from_rest({"ramp": 0.5}))
    env = envelope(i["design"], i["camera"], i["disturbance"], i["start"], search=False)
    args = (i["design"], i["camera"], i["disturbance"], env, i["ramp"])
    plain = start_module.ramp_start(*args)
    out = {"plain": plain}
    with pytest.MonkeyPatch.context() as patch:
        last = plain["ultimate_V_ramp"]
        for name, level in (
            ("at_level", plain["level"]),
            ("below_last", last * (1 - 1e-9)),
            ("above_last", last * (1 + 1e-9)),
        ):
            patch.setattr(start_module, "visible_level", lambda *a, value=level, **k: value)
            out[name] = start_module.ramp_start(*args)
    return out


@pytest.mark.slow
def test_ramp_level_bounds_every_step_of_its_recursion(ramp_runs):
    """(16a.3): ``V(t) <= c = max_j Vbar_j`` from ``t = 0``. Against a visible level equal to the
    stated ``c``, no step's bound lies above it, so the statement is visibility from ``t = 0`` (and
    ``c >= V(0)`` and ``c >=`` the final step's bound); a level below the recursion's peak (the
    ramp's start, before ``sigma`` grows, raises ``Vbar`` above ``V(0)``: 0.0796 against 0.0770)
    would leave a step above it."""
    plain, at_level = ramp_runs["plain"], ramp_runs["at_level"]
    assert plain["inside"] and plain["level"] >= max(plain["V0"], plain["ultimate_V_ramp"])
    assert at_level["visible"] is True and at_level["visible_from_s"] == 0.0


@pytest.mark.slow
def test_ramp_visibility_never_starts_before_the_last_step_above_the_visible_level(ramp_runs):
    """(16a.3): visibility from ``t_vis``, the first grid time after which every ``Vbar_j`` is at most
    the visible level. On the default the start (``V(0) = 0.077``) is above it, so ``t_vis`` is a
    positive multiple of the 0.01 s step; against a visible level just below the final step's bound
    no grid time qualifies: visibility is not certified at all. Just above it (1 + 1e-9), only the
    final step qualifies: the recursion approaches its limit from above (measured: each of the last
    steps lowers ``Vbar`` by ~1e-4 relative), so ``t_vis`` is the final grid time, ``steps * h``, and
    not the step before, whose bound is above the level."""
    plain, below = ramp_runs["plain"], ramp_runs["below_last"]
    assert plain["V0"] > plain["visible_level"] and plain["visible"] is False
    t_vis = plain["visible_from_s"]
    assert t_vis > 0 and abs(t_vis / plain["step_s"] - round(t_vis / plain["step_s"])) < 1e-9
    assert below["visible"] is False and below["visible_from_s"] is None
    assert "not certified at all" in below["reason"]
    above = ramp_runs["above_last"]
    assert above["visible_from_s"] == pytest.approx(above["steps"] * above["step_s"], rel=1e-12)


@pytest.mark.slow
def test_ramp_level_covers_the_limit_its_recursion_rises_to():
    """(16a.3): ``V(t) <= c`` for all ``t >= 0``, after the recursion's last step too, where fact 7's
    first exit keeps ``V <= max(Vbar_last, b/k)``, ``b/k`` the last step's limit: ``c`` takes it. From
    ``V(0) = 0`` (at rest at the reference, with the ramp) ``Vbar`` rises to within 1% of its limit (the
    stopping rule): no step's bound lies above the last (probed as visibility from ``t = 0`` against a
    visible level 1e-12 above it, relative), and a rising step moves ``Vbar`` strictly toward ``b/k``,
    so ``b/k`` lies above the last bound: ``Vbar_last < c <= Vbar_last / 0.99``."""
    i = statement_inputs(from_rest({"ramp": 0.5}))
    env = envelope(i["design"], i["camera"], i["disturbance"], {**i["start"], "V0": 0.0}, search=False)
    args = (i["design"], i["camera"], i["disturbance"], env, i["ramp"])
    record = start_module.ramp_start(*args)
    last = record["ultimate_V_ramp"]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(start_module, "visible_level", lambda *a, **k: last * (1 + 1e-12))
        probe = start_module.ramp_start(*args)
    assert probe["visible_from_s"] == 0.0  # every step's bound at most the last: Vbar rose to it
    assert record["inside"] and record["V0"] == 0.0
    assert last < record["level"] <= last / 0.99
