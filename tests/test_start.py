"""A start the certificate covers (docs/math.md, fact 16b): the planned reference with feedforward,
the observer from the first image, and the start statement checked on runs from rest."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import casadi as cs
import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis.case import Case
from dvfc.analysis.cli import app
from dvfc.analysis.results import envelope_record, statements
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.start import run_regions
from dvfc.analysis.verify import envelope_claims

from helpers import CELL, build_loop, default_dict_without_integral, default_without_integral, run, scenario_dict


def planned(duration: float = 2.0, observer: str = "scenario"):
    """An edit: the idealised scenario from rest with the planned reference."""

    def edit(data: dict) -> None:
        data["start"] = {"reference": "planned", "duration": duration, "observer": observer}
        data["robot"]["qd0"] = [0.0] * 6

    return edit


def ramped(seconds: float):
    """An edit: the idealised scenario from rest with the paper's reference and a ramp of ``u_d``."""

    def edit(data: dict) -> None:
        data["start"] = {"ramp": seconds}
        data["robot"]["qd0"] = [0.0] * 6

    return edit


@pytest.mark.parametrize("edit", [planned(1.5), ramped(0.5)], ids=["planned", "ramp"])
def test_storage_rate_is_minus_nu_k_nu_plus_x_g_w_along_the_start(edit):
    """(16b.1), (16a.1): along a CVODES run (``rtol = atol = 1e-10``) from rest with the planned
    reference (or the ramp), ``dV/dt`` by automatic differentiation of (38) (through ``g_d(t)`` or
    ``sigma(t)`` too) equals ``-x^T N(t)^T K(t) N(t) x + x^T G w`` at every output step, and
    integrated ``V(t) - V(0) = int(-nu^T K nu + x^T G w)``; the start has ``xi(0) = 0``."""
    loop, s0, settings = build_loop(edit)
    traj = run(loop, s0, settings, duration=2.5)
    assert traj.status == "ok"
    assert np.abs(traj["xi"][0]).max() < 1e-12
    u = np.clip(traj.t / (loop.ramp or 1.0), 0, 1)[:, None]
    sigma = 3 * u**2 - 2 * u**3 if loop.ramp else np.ones_like(u)
    gains = loop.gains
    k = np.concatenate([np.broadcast_to(gains.k_xi, (len(u), 6)), sigma * gains.k_c,
                        np.broadcast_to(gains.k_e, (len(u), 6))], 1)  # fmt: skip
    nu, w = traj["nu"], loop.weights
    rot = {name: traj[name].reshape(-1, 4, 4).transpose(0, 2, 1)[:, :3, :3] for name in ("g", "gbar")}
    r_ee = np.einsum("bji,bjk->bik", rot["gbar"], rot["g"])  # R_ee = Rbar^T R
    v_wo = traj["w"][:, 6:]
    ad = np.concatenate([np.einsum("bij,bj->bi", r_ee, v_wo[:, :3]), np.einsum("bij,bj->bi", r_ee, v_wo[:, 3:])], 1)
    w_e = np.array([w.w_pe] * 3 + [w.w_re] * 3)
    supply = np.sum(traj["xi"] * traj["w"][:, :6], 1) + np.sum(traj["e_e"] * w_e * ad, 1)  # x^T G w
    law = -np.sum(nu * k * nu, 1) + supply
    ad = traj["Vdot"][:, 0]
    scale = np.abs(ad).max()
    assert scale > 1e-3  # the plan moves the storage
    assert np.abs(ad - law).max() <= 1e-9 * scale
    v = traj["V"][:, 0]
    integrated = v - v[0] + traj.integrals["dissipation_nu_K_nu"] - traj.integrals["supply_x_G_w"]
    assert np.abs(integrated).max() <= 1e-7 * max(v.max(), np.abs(traj.integrals["dissipation_nu_K_nu"]).max())


def _start_holds(case: Case) -> tuple[bool, dict]:
    """The start statement on the case's own run (ideal continuous loop): ``V(t)`` below the level
    the statement covers at every step and, for a planned start, every feature in its region; for
    a planned start also at the tube form's level (``holds`` true only when both hold)."""
    env = envelope_record(case, search=False)
    start = env["start"]
    level = start["level"] if start["inside"] else env["invariant_V"]
    traj = run(case.loop, case.s0, case.settings, duration=4.0)
    holds = _within(case, traj, level, start["method"] == "planned" and start["inside"])
    if start["method"] == "planned" and start["tube"]["inside"]:
        holds &= _within(case, traj, start["tube"]["level"], True)
    return holds, env


def _within(case: Case, traj, level: float, regions: bool) -> bool:
    """``V(t) <= level`` at every step and, with ``regions``, every feature in its region (16.0) at
    ``level`` about ``g_d(t) p_oi``."""
    holds = bool(np.all(traj["V"][:, 0] <= level * (1 + 1e-9)))
    if regions:
        lo, hi = run_regions(case.loop, traj.t, level)
        pixels = traj["f"].reshape(len(traj.t), -1, 2) + case.loop.camera.centre
        holds &= bool(np.all((pixels >= lo) & (pixels <= hi)))
    return holds


@pytest.mark.slow
@pytest.mark.parametrize("seconds", [0.5, 1.0])
def test_ramp_bounds_v_from_the_start_and_visibility_from_t_vis(seconds):
    """(16a.3): from rest with the ramp, ``V(t)`` stays below the certified ``c`` at every step; the
    statement says that visibility is not certified from t = 0 on the default's offset (``c`` above
    the visible level) and from when it is; every feature stays in its region from then on."""
    case = Case(Scenario.model_validate(scenario_dict(ramped(seconds))), DEFAULT_SCENARIO.parent)
    env = envelope_record(case, search=False)
    start = env["start"]
    assert start["method"] == "ramp" and start["inside"] and start["recheck_margin"] >= 0
    assert start["visible"] is False and "NOT certified from t = 0" in start["reason"]
    assert 0 < start["visible_from_s"] < 3
    traj = run(case.loop, case.s0, case.settings, duration=4.0)
    assert np.all(traj["V"][:, 0] <= start["level"])
    claims = envelope_claims(case.loop, case.s0, case.settings, env)
    assert all(c.passed is not False for c in claims), [(c.name, c.detail) for c in claims if c.passed is False]
    assert any(c.reference == "fact 16a, 16.0" and c.passed for c in claims)


@pytest.mark.slow
@pytest.mark.parametrize(("duration", "observer"), [(1.0, "scenario"), (2.0, "scenario"), (2.0, "image")])
def test_planned_start_is_certified_and_holds_on_runs_from_rest(duration, observer):
    """(16b.3), (16b.4): from rest with the planned reference the start statement covers the run
    from t = 0, with every feature in view, in the fixed-level and the tube form (its level no
    higher); on the run ``V(t)`` stays below both levels at every step and every feature stays in
    its region about ``g_d(t)`` at both; verify's claims on it all hold."""
    case = Case(Scenario.model_validate(scenario_dict(planned(duration, observer))), DEFAULT_SCENARIO.parent)
    holds, env = _start_holds(case)
    start = env["start"]
    assert start["method"] == "planned" and start["inside"] and start["visible"]
    assert start["kinetic"] == 0.0 and start["recheck_margin"] >= 0
    tube = start["tube"]
    assert tube["inside"] and tube["visible"] and tube["level"] <= start["level"] * (1 + 1e-12)
    assert holds
    claims = envelope_claims(case.loop, case.s0, case.settings, env)
    assert all(c.passed is not False for c in claims), [(c.name, c.detail) for c in claims if c.passed is False]
    assert any(c.reference == "fact 16b, 16.0" and c.passed for c in claims)


def test_the_papers_start_from_rest_is_not_covered_on_the_default():
    """The same check with the paper's constant reference, from rest, on the default example:
    ``V(0)`` (mostly kinetic, ``xi(0) = -qd_d(0)``) lies above every certified level, so the start
    statement does not cover the run, and ``V(t)`` is not below it at every step (the paper's law:
    without the default's integral action, whose start statement is fact 20.6's)."""
    scenario, base = default_without_integral()
    data = scenario.model_dump()
    data["start"] = {"reference": "constant", "duration": 2.0, "observer": "scenario"}
    data["robot"]["qd0"] = [0.0] * 6
    data["simulation"]["jit"] = False
    data.pop("implementation")
    holds, env = _start_holds(Case(Scenario.model_validate(data), base))
    assert env["start"]["method"] == "constant" and not env["start"]["inside"]
    assert env["start"]["V0"] > 10 and not holds


def test_observer_from_the_image_starts_at_the_true_pose():
    """``[start] observer = "image"``: ``gbar(0)`` is the pose estimate (solvePnP) of the noiseless
    first image, the true relative pose to 1e-9, so ``e_e(0) = 0``."""
    loop, s0, _ = build_loop(planned(2.0, "image"))
    error = cs.Function("e0", [loop.t, loop.state], [loop.e_e])(0.0, s0)
    assert np.abs(np.asarray(error)).max() < 1e-9


def test_the_arm_is_held_until_the_first_image_arrives():
    """With the observer from the image and a 20 ms latency (the default example as implemented),
    the plan starts when the image captured at t = 0 arrives: until then ``g_d`` is the plan's
    start, the law commands no motion and the joints stay at rest (gravity held exactly by the
    model, the plant here); after it the arm moves."""
    case = Case.load(DEFAULT_SCENARIO)
    assert case.loop.plan.hold == pytest.approx(0.02)
    settings = replace(case.settings, duration=0.1, dt=0.002, jit=False)
    traj = as_implemented(case.loop, settings).run(case.s0)
    qd = np.abs(traj["qd"])
    held = traj.t < 0.02 - 1e-9
    assert qd[held].max() < 1e-9 and qd[traj.t > 0.05].max() > 1e-6


@pytest.mark.slow
def test_a_start_the_planned_reference_does_not_certify_is_inside_in_no_output(tmp_path):
    """One decision about the start (docs/math.md, fact 16b): with gains unequal across the axes of
    ``K_c`` (``(3, 3, 3, 3, 3, 2.9)``) on the default example, the planned reference's rate along the
    path is not derived, so its start record is not certified, though ``V(0) = 5.5e-5`` lies inside
    the fixed-reference set ``V <= c_max`` that the envelope's own test reads. The envelope's
    statement, the statements table and the human output read the start record: none says inside
    (the paper's law: without the default's integral action)."""
    data = default_dict_without_integral()
    data["simulation"].update(duration=0.05, jit=False)
    data["gains"]["k_c"] = [3.0, 3.0, 3.0, 3.0, 3.0, 2.9]
    path = tmp_path / "aniso.toml"
    path.write_text(tomli_w.dumps(data))
    result = CliRunner().invoke(app, ["certify", str(path), "--no-lower-bounds", "--out", str(tmp_path / "c")],
                           env={"COLUMNS": "400"})  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    certificate = json.loads((tmp_path / "c" / "certificate.json").read_text())
    env = certificate["points"][0]["envelope"]
    assert env["start"]["method"] == "planned" and env["start"]["inside"] is False
    assert env["start"]["V0"] < env["invariant_V"]  # the fixed-reference test alone would say inside
    assert "is inside the certified set" not in env["statement"] and "not certified" in env["statement"]
    text = result.stdout
    assert "NOT inside the certified set" in text and "is inside the certified set" not in text
    verification = {"summary": {"claims": 0, "failed": 0, "inconclusive": 0}}
    row = next(r for r in statements(certificate, verification) if r.statement == "the start")
    assert row.status == "NOT CERTIFIED" and "inside the certified set" not in row.detail


def ramp_then_integral(data: dict) -> None:
    """An edit: the idealised scenario with a 0.5 s ramp of ``u_d`` and integral action
    (``k_i_factor = 10``) from the ramp's end."""
    data["start"] = {"ramp": 0.5}
    data["gains"]["k_i_factor"] = 10.0


TIME = re.compile(r"\bt (?:=|<=|>=) (\d+(?:\.\d*)?(?:e[-+]?\d+)?) s\b")
"""A time a statement names: ``t = 0.97 s``, ``0 <= t <= 0.5 s``."""


def test_every_time_a_start_statement_names_lies_before_integral_action_engages():
    """Fact 20.6: the start of a design with ``K_I`` is the start of the design without it on
    ``0 <= t <= T_I`` and says nothing after. With a 0.5 s ramp and ``k_i_factor = 10`` on the
    idealised scenario (``T_I = 0.5 s``, the ramp's end), the design without ``K_I`` sees every
    feature only from a later time (0.97 s): the start with ``K_I`` names no time past ``T_I`` (each
    printed to at most 4 significant figures: 5e-4 relative), its record's ``visible_from_s`` is none
    or within ``[0, T_I]``, and it says that visibility is not certified after ``T_I``."""
    case = Case(Scenario.model_validate(scenario_dict(ramp_then_integral)), DEFAULT_SCENARIO.parent)
    env = envelope_record(case, search=False)
    start, own = env["start"], env["without_integral"]["start"]
    t_i = start["until_s"]
    assert t_i == 0.5 and start["inside"] and own["visible_from_s"] > t_i  # the case in point
    assert start.get("visible_from_s") is None or 0 <= start["visible_from_s"] <= t_i
    times = [float(x) for x in TIME.findall(start["statement"] + " " + str(start.get("reason")))]
    assert times and all(0 <= x <= t_i * (1 + 5e-4) for x in times), start["statement"]
    assert "not certified after T_I" in start["statement"]


@pytest.mark.slow
def test_the_start_computed_without_friction_says_so_wherever_it_is_printed(tmp_path):
    """The start statements are the ideal continuous loop's, whose plant is the law's model, without
    friction (docs/math.md, facts 16, 20.6). On ``examples/ur5_cell.toml``, whose plant has friction, the
    envelope's statement says "for the plant without friction" (fact 18), and so must its start, certified
    until integral action engages: the record's statement, certify's printed ``START`` line and the
    statements row the report and its summary print (its loop column naming the plant)."""
    out = tmp_path / "c"
    result = CliRunner().invoke(app, ["certify", str(CELL), "--no-lower-bounds", "--out", str(out)],
                                env={"COLUMNS": "4000"})  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    certificate = json.loads((out / "certificate.json").read_text())
    env = certificate["points"][0]["envelope"]
    start, said = env["start"], "for the plant without friction"
    assert env["friction"] is not None and start["inside"] and start["until_s"] > 0  # the case in point
    assert said in start["statement"]
    line = next(line for line in result.stdout.splitlines() if line.startswith("START"))
    assert said in line
    verification = {"summary": {"claims": 0, "failed": 0, "inconclusive": 0}}
    row = next(r for r in statements(certificate, verification) if r.statement.startswith("the start"))
    assert said in row.loop and said in row.detail
