"""Gain synthesis (docs/math.md, fact 6): bounds respected, certified at the reported gamma, no point
of a grid inside the bounds certifies a smaller gamma (an optimum at a corner), and the
smallest gains reaching a gamma target (an interior optimum) beat a fine grid."""

from __future__ import annotations

import itertools
import json
import math
import shutil
import tomllib
from dataclasses import astuple, replace
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
import tomli_w
import yaml
from typer.testing import CliRunner

from dvfc.analysis.case import Case
from dvfc.analysis.certify import GainPoint, certify, exact_gamma
from dvfc.analysis.cli import app
from dvfc.analysis.envelope import DisturbanceBounds, design_of, envelope
from dvfc.analysis.multirate import implemented_record
from dvfc.analysis.results import envelope_record, speed_theta_bar
from dvfc.analysis.scenario import build, load
from dvfc.analysis.synthesize import (
    FEASIBLE_STEPS,
    SEARCH_STEPS,
    TARGET_MARGIN,
    Bounds,
    CaseSynthesis,
    Outcome,
    Synthesis,
    design_runner,
    designed_loop,
    designer,
    logged_runs,
    rounded,
    sampled_shortfall,
    scaled,
    scenario_text,
    search_within_limits,
    synthesis_bounds,
    synthesis_record,
    synthesize,
    synthesize_speed,
    written_case,
)
from dvfc.analysis.windows import HOLD_MARGIN, WindowSpec, case_window_spec, case_windows
from dvfc.models.lie import SE3
from dvfc.models.loop import Weights

import reference as ref
from helpers import scenario_dict

REFERENCE = SE3.from_xyz_rpy([0.02, -0.01, 0.35], [0.1, -0.2, 0.3])
WEIGHTS = Weights(4.0, 1.0, 4.0, 1.0)
EXAMPLES = Path(__file__).parent.parent / "examples"
BOUNDS = Bounds((1.0, 30.0), (0.5, 5.0), (0.5, 8.0))
runner = CliRunner()


@pytest.fixture(scope="module")
def result():
    return synthesize(WEIGHTS, REFERENCE, 6, BOUNDS)


def test_synthesized_gains_respect_bounds(result):
    p = result.point
    for values, (lo, hi) in ((p.k_xi, BOUNDS.k_xi), (p.k_c, BOUNDS.k_c), (p.k_e, BOUNDS.k_e)):
        assert np.all(values >= lo) and np.all(values <= hi)


def test_synthesized_gains_certify_at_reported_gamma(result):
    again = certify(result.point, REFERENCE)
    assert again.certified and again.gamma == pytest.approx(result.certificate.gamma, rel=1e-12)


def test_no_grid_point_in_bounds_certifies_smaller_gamma(result):
    """A 4^4 grid over (k_xi, k_c, k_ep, k_er) inside the bounds: every gamma is at least the
    synthesised one, up to the certificate's 1e-6 inflation and the SDP optimum's accuracy
    (Clarabel's relative gap 1e-8 on s, so ~1e-8 on gamma; allowed 1e-7)."""
    best = result.certificate.gamma / (1 + 1e-6) / (1 + 1e-7)
    for k_xi, k_c, k_ep, k_er in itertools.product(
        np.linspace(*BOUNDS.k_xi, 4),
        np.linspace(*BOUNDS.k_c, 4),
        np.linspace(*BOUNDS.k_e, 4),
        np.linspace(*BOUNDS.k_e, 4),
    ):
        point = GainPoint(np.full(6, k_xi), np.full(6, k_c), np.repeat([k_ep, k_er], 3), WEIGHTS)
        assert exact_gamma(point, REFERENCE, np.eye(3))[0] >= best


def test_the_minimum_gamma_design_is_the_box_corner(result):
    """docs/math.md, fact 6 (uniqueness): without windows the minimum-gamma design is the box's upper
    corner, bit for bit (the solver's point on the optimal face is not), and no grid point beats it
    (:func:`test_no_grid_point_in_bounds_certifies_smaller_gamma`)."""
    p = result.point
    assert np.array_equal(p.k_xi, np.full(6, BOUNDS.k_xi[1])) and np.array_equal(p.k_c, np.full(6, BOUNDS.k_c[1]))
    assert np.array_equal(p.k_e, np.full(6, BOUNDS.k_e[1]))


@pytest.mark.parametrize("alpha", [1.0, 0.9358])
def test_the_design_is_the_same_when_the_data_move_by_round_off(alpha):
    """Green on every machine (docs/math.md, fact 6): the default's written design (gains rounded as
    written) within the gain windows, on the limits search's box at ``alpha``, is the same when the
    weights move by 1e-13 relative either way, as another machine's BLAS moves the last bits. The
    solver's own point on the optimal face moved in the 4th digit (``k_xi,1`` 57.19 to 57.20)."""
    case = Case.load(EXAMPLES / "ur5_circle.toml")
    spec, windows = case.scenario, case_window_spec(case)
    box = scaled(synthesis_bounds(case), alpha)
    base = Weights(**spec.weights.model_dump())

    def written(eps: float) -> np.ndarray:
        design = designer(Weights(*(base.as_array() * (1 + eps))), case.reference, 6, windows=windows,
                          theta_max=math.radians(spec.certify.theta_max_deg), plant=case.point.plant)  # fmt: skip
        p = design(box).point
        return np.r_[p.k_xi, p.k_c, p.k_e]

    first = written(0.0)
    for eps in (1e-13, -1e-13):
        assert np.array_equal(written(eps), first), eps


@pytest.mark.slow
def test_the_target_speed_sdp_keeps_every_gain_inside_its_window_with_margin():
    """The same windows in fact 7's SDP (:func:`synthesize_speed`, the UR5's mass bounds, the light
    ``M(q0)`` above held at 500 Hz): alone it puts ``k_xi,1 = 16.6``, ``h lambda_max(M^-1 K_xi)``
    past 2; with the windows at most ``0.8 x 1.95`` (numpy's eigenvalues), and a rate is certified."""
    a = np.random.default_rng(0).normal(size=(6, 6))
    mass = 0.0008 * (a @ a.T + 6 * np.eye(6))
    held = lambda k: np.linalg.eigvals(np.linalg.solve(mass, np.diag(k))).real.max() / 500.0  # noqa: E731
    case = Case.load(EXAMPLES / "ur5_circle.toml")
    box = Bounds((1.0, 30.0), (0.5, 5.0), (0.5, 15.0))
    free, kept = (synthesize_speed(WEIGHTS, case.reference, 6, box, case.loop.robot.mass_bounds, math.radians(10),
                                   windows=w) for w in (None, WindowSpec(mass, 500.0, None)))  # fmt: skip
    assert held(free.point.k_xi) > 2.0 and kept.status == "ok" and kept.certificate.certified
    assert held(kept.point.k_xi) <= 0.8 * (2 - HOLD_MARGIN) * (1 + 1e-7)


def test_gains_on_an_upper_bound_round_toward_zero_to_three_figures():
    """The rounding (docs/cli.md): on the box ``scaled(BOUNDS, 0.95)`` the optimum puts ``k_c`` on its
    upper end 4.45625, whose nearest 3 figures (4.46) leave the box (the nearest rounding needs 4:
    4.456); rounded toward zero the file gets 3 figures (4.45) within the box, certified within 0.1%
    of the unrounded gamma."""
    box = scaled(BOUNDS, 0.95)
    solved = synthesize(WEIGHTS, REFERENCE, 6, box)
    kept = rounded(solved, REFERENCE, box)
    for values, (_, hi) in ((kept.point.k_c, box.k_c), (kept.point.k_e, box.k_e)):
        assert np.all(values <= hi) and all(float(f"{v:.3g}") == v for v in values)
    assert kept.certificate.gamma <= solved.certificate.gamma * 1.001


def test_gamma_target_gives_smallest_gains(result):
    """With a target gamma the gains reach it, and are no larger than the minimum-gamma gains."""
    target = 1.5 * result.certificate.gamma
    reached = synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, gamma_target=target)
    assert reached.certificate.certified and reached.certificate.gamma <= target
    norm = lambda p: np.linalg.norm(np.r_[p.k_xi, p.k_c, p.k_e])  # noqa: E731
    assert norm(reached.point) < norm(result.point)


def test_the_sdp_keeps_every_gain_inside_its_window_with_margin():
    """docs/math.md, "Gain windows": on a light arm (``M`` with eigenvalues 0.005-0.013 kg m^2) held at
    500 Hz, the minimum-gamma design alone puts ``k_xi`` at the box's upper 30 on every joint, a held
    map with ``h lambda_max(M^-1 K_xi) = 12.3``, far past 2 (diverges); with the windows, ``h lambda_max``
    (numpy's eigenvalues of ``M^-1 K_xi``, not the LMI) is at most ``0.8 x 1.95``, every gain at most 0.8
    of its hold limit (by bisection, :func:`dvfc.analysis.windows.hold_limits`) and at least 1.1 x 1/2,
    at the same gamma."""
    a = np.random.default_rng(0).normal(size=(6, 6))
    mass = 0.0008 * (a @ a.T + 6 * np.eye(6))
    spec = WindowSpec(mass, 500.0, None)
    held = lambda k: np.linalg.eigvals(np.linalg.solve(mass, np.diag(k))).real.max() / 500.0  # noqa: E731
    free, kept = (synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, windows=w) for w in (None, spec))
    assert held(free.point.k_xi) > 2.0
    assert held(kept.point.k_xi) <= 0.8 * (2 - HOLD_MARGIN) * (1 + 1e-7)
    windows = spec.of(kept.point.k_xi)
    assert np.all(kept.point.k_xi <= 0.8 * windows.upper * (1 + 1e-7)) and np.all(kept.point.k_xi >= 1.1 * 0.5)
    assert kept.certificate.gamma == pytest.approx(free.certificate.gamma, rel=1e-6)


def test_unreachable_target_is_reported():
    out = synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, gamma_target=1e-3)
    assert out.point is None and "infeasible" in out.status


def test_region_is_the_scenarios():
    """With ``[certify] theta_max_deg = 90`` the synthesised certificate states that region,
    not every rotation."""
    out = synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, theta_max=np.radians(90))
    assert out.certificate.region == "every rotation R_ec with |theta_ec| <= 90 deg"


WIDE = Bounds((0.5, 30.0), (0.05, 10.0), (0.05, 10.0))


def test_smallest_gains_for_a_target_are_interior_and_beat_a_fine_grid():
    """With a gamma target (1.5 times the smallest reachable) the smallest gains sit inside the
    bounds, on the boundary ``P = 0`` of the feasible set (an interior optimum, unlike the
    minimum-gamma problem's corner). A 201 x 201 grid of the plane that scales ``K_c`` and ``K_e``
    (``t_c K_c, t_e K_e`` with ``t`` in [0.5, 1.5], the optimum at (1, 1)), each point judged
    feasible by the independent reference (``lambda_min(P) >= 0`` at the gamma the synthesis
    aims at), has no feasible point of smaller norm (to the solver's 1e-6), and its best feasible
    point is within the grid step of the optimum: ``P`` grows with ``K``, so ``(1 + h, 1 + h)``
    is feasible and its norm exceeds the optimum's by at most ``h (|K_c| + |K_e|)``."""
    best_gamma = synthesize(WEIGHTS, REFERENCE, 6, WIDE).certificate.gamma
    out = synthesize(WEIGHTS, REFERENCE, 6, WIDE, gamma_target=1.5 * best_gamma)
    p = out.point
    for values, (lo, hi) in ((p.k_xi, WIDE.k_xi), (p.k_c, WIDE.k_c), (p.k_e, WIDE.k_e)):
        assert np.all(values > 1.01 * lo) and np.all(values < 0.99 * hi)
    gamma_aimed = 1.5 * best_gamma / (1 + TARGET_MARGIN)
    pose = np.asarray(cs.DM(REFERENCE.as_matrix()))
    w = np.array([WEIGHTS.w_pc, WEIGHTS.w_rc, WEIGHTS.w_pe, WEIGHTS.w_re])
    n_matrix = ref.output_matrix(w, pose[:3, 3], pose[:3, :3], np.eye(3), 6)
    weight = ref.disturbance_weight(w, 6)
    t = np.linspace(0.5, 1.5, 201)
    t_c, t_e = (v.ravel() for v in np.meshgrid(t, t, indexing="ij"))
    k = np.hstack([np.tile(p.k_xi, (len(t_c), 1)), t_c[:, None] * p.k_c, t_e[:, None] * p.k_e])
    a = np.einsum("ji,bj,jk->bik", n_matrix, k, n_matrix) - 0.5 * np.eye(18)
    feasible = ref.lambda_min(a - weight / (2 * gamma_aimed**2)) >= 0
    norms = np.linalg.norm(k, axis=1)
    optimum = np.linalg.norm(np.r_[p.k_xi, p.k_c, p.k_e])
    h = t[1] - t[0]
    assert feasible.any() and norms[feasible].min() >= optimum * (1 - 1e-6)
    assert norms[feasible].min() <= optimum + h * (np.linalg.norm(p.k_c) + np.linalg.norm(p.k_e))


SPEED_BOUNDS = Bounds((1.0, 30.0), (0.5, 5.0), (0.5, 15.0))


@pytest.mark.slow
def test_target_speed_synthesis_beats_every_point_of_a_grid():
    """Facts 7-8 with fact 6: the gains maximising ``s kappa*(s)`` have a certified target speed
    (the ordinary envelope's, from ``V(0) = 0``, at ``theta_bar`` of its own choice) at least that
    of every point of a 4^3 grid over ``(k_xi, k_c, k_e)`` inside the bounds. Allowed 1e-7
    relative: the SDP's gains are accurate to Clarabel's ~1e-8 relative gap (an optimal gain at
    its bound comes back 1e-8 below it), and the speed is a square root of a quantity linear in
    ``kappa``."""
    spec, base = load(EXAMPLES / "ur5_envelope.toml")
    loop = build(spec, base)[0]
    reference, mass, camera = spec.reference.se3(), loop.robot.mass_bounds, loop.camera
    disturbance = DisturbanceBounds(0.0785, 0.0, 0.0)
    theta = speed_theta_bar(Case(spec, base))
    out = synthesize_speed(WEIGHTS, reference, 6, SPEED_BOUNDS, mass, theta)

    def speed(point: GainPoint) -> float:
        env = envelope(design_of(point, reference, mass), camera, disturbance, {"V0": 0.0})
        return env.max_target_speed or 0.0

    best = speed(out.point) * (1 + 1e-7)
    for k_xi, k_c, k_e in itertools.product(*(np.linspace(*b, 4) for b in astuple(SPEED_BOUNDS))):
        grid_point = GainPoint(np.full(6, k_xi), np.full(6, k_c), np.full(6, k_e), WEIGHTS)
        assert speed(grid_point) <= best, (k_xi, k_c, k_e)


# --- a design within the arm's limits ([synthesize] respect_limits) ----------------------------

LIMITS_BOUNDS = Bounds((1.0, 100.0), (0.1, 20.0), (0.1, 50.0))  # the [synthesize] defaults


def _threshold_search(feasible_above: float, limit: float):
    """The search on a synthetic family whose "design" has every gain at its box's upper bound,
    certified when ``k_xi``'s upper bound reaches ``feasible_above``, and whose "run" peaks at
    ``k_xi / limit`` times the effort limit: within the limits exactly when ``k_xi <= limit``."""

    def design(b: Bounds) -> Synthesis:
        if b.k_xi[1] < feasible_above:
            return Synthesis(None, None, Outcome.INFEASIBLE, "below the feasible box")
        point = GainPoint(np.full(6, b.k_xi[1]), np.full(6, b.k_c[1]), np.full(6, b.k_e[1]), WEIGHTS)
        return Synthesis(point, None)

    def run(point: GainPoint) -> dict:
        return {"status": "ok", "message": "", "torque_commanded_ratio": [point.k_xi[0] / limit], "speed_ratio": [0.5]}

    return search_within_limits(design, LIMITS_BOUNDS, run)


def test_limits_search_brackets_the_largest_alpha_within_the_limits():
    """On a family whose limit is crossed once (at ``k_xi = 20``, ``alpha = log 20 / log 100``)
    and whose designs certify from ``k_xi = 2`` on, the search returns the smallest certified
    alpha to 1/1024 (:data:`FEASIBLE_STEPS`), a chosen design within the limits and the run just
    above it exceeding them, the two 1/64 of the bracket apart (:data:`SEARCH_STEPS`), with the
    crossing between them; 2 + 6 runs."""
    search = _threshold_search(2.0, 20.0)
    crossing, feasible = math.log(20) / math.log(100), math.log(2) / math.log(100)
    assert feasible <= search.lowest <= feasible + 2**-FEASIBLE_STEPS
    assert search.chosen.within and not search.exceeds.within
    assert search.chosen.alpha <= crossing < search.exceeds.alpha
    assert search.exceeds.alpha - search.chosen.alpha == pytest.approx((1 - search.lowest) / 2**SEARCH_STEPS)
    assert search.runs == 2 + SEARCH_STEPS


def test_limits_search_reports_no_design_when_the_smallest_exceeds():
    """When even the family's smallest certified design exceeds the limits there is no design
    (the search stops after that run) and the status says which limit and by how much."""
    search = _threshold_search(2.0, 1.5)
    assert search.chosen is None and search.result.point is None and search.runs == 2
    assert "no design within the limits" in search.result.status and "torque" in search.result.status


def test_interrupted_limits_search_resumes_without_running_a_design_again(tmp_path):
    """The runs logged before an interruption (the last line cut short by it) are reused on
    ``resume`` for the same designs, each design run once in all; without ``resume`` the log
    starts empty."""
    calls: list[float] = []

    def run(point: GainPoint) -> dict:
        calls.append(float(point.k_xi[0]))
        return {"status": "ok", "message": "", "torque_commanded_ratio": [point.k_xi[0] / 20.0], "speed_ratio": [0.5]}

    log = tmp_path / "runs.jsonl"
    points = [GainPoint(np.full(6, k), np.ones(6), np.ones(6), WEIGHTS) for k in (10.0, 30.0, 15.0)]
    first = logged_runs(run, log, resume=False)
    before = [first(p) for p in points[:2]]
    with open(log, "a") as handle:
        handle.write('{"design": "[[15.0')  # interrupted while writing
    again = logged_runs(run, log, resume=True)
    assert [again(p) for p in points][:2] == before
    assert calls == [10.0, 30.0, 15.0]  # only the design whose line was cut short ran again
    logged_runs(run, log, resume=False)(points[0])
    assert calls[-1] == 10.0 and len(log.read_text().splitlines()) == 1


def _limits_scenario(tmp_path: Path, name: str, edit=None) -> Path:
    """The idealised UR5 (the paper's continuous loop, the URDF's limits) over 0.2 s: the law's
    torque peaks at the start (``xi(0) = -qd_d(0)``), so a short run shows it."""

    def short(data: dict) -> None:
        data["simulation"]["duration"] = 0.2
        if edit is not None:
            edit(data)

    path = tmp_path / name
    path.write_text(tomli_w.dumps(scenario_dict(short)))
    return path


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    """``synthesize`` of the same scenario with the default bounds, unconstrained and with
    ``respect_limits``: the two JSON records and the file the second wrote. The unconstrained
    optimum's run exceeds the torque limits, so it is refused (exit 1, nothing written)."""
    tmp = tmp_path_factory.mktemp("limits")
    free = _limits_scenario(tmp, "free.toml")
    bound = _limits_scenario(tmp, "bound.toml", lambda d: d.update(synthesize={"respect_limits": True}))
    records = []
    for scenario in (free, bound):
        result = runner.invoke(app, ["synthesize", str(scenario), "--out", str(tmp / f"{scenario.stem}-syn.toml"),
                                     "--json", "-"])  # fmt: skip
        records.append(json.loads(result.stdout))
        refused = scenario is free
        assert result.exit_code == int(refused), result.output
        assert records[-1]["status"].startswith("refused, nothing written: its run as implemented exceeds") == refused
        assert (tmp / f"{scenario.stem}-syn.toml").exists() != refused
    return records[0], records[1], tmp / "bound-syn.toml"


def _worst(limits: dict) -> float:
    return max(max(limits["torque_commanded_ratio"]), max(limits["speed_ratio"]))


@pytest.mark.slow
def test_design_respecting_limits_runs_within_them_where_the_optimum_does_not(limited, tmp_path):
    """The unconstrained optimum exceeds the UR5's limits (its own run); the written design,
    simulated afresh from its file by ``dvfc simulate``, completes within every joint's effort
    and velocity limits."""
    free, _, written = limited
    assert _worst(free["limits"]) > 1
    result = runner.invoke(app, ["simulate", str(written), "--out", str(tmp_path / "run"), "--json", "-"])
    assert result.exit_code == 0, result.output
    assert _worst(json.loads(result.stdout)["limits"]) <= 1


@pytest.mark.slow
def test_design_respecting_limits_certifies_no_better_gamma_than_the_optimum(limited):
    """The constrained design's gamma is at least the unconstrained one's (its box lies inside the
    bounds; both are rounded to within 0.1% of their box's optimum, so allowed 1e-3), and it is
    the gamma ``certify`` gives the written file."""
    free, bound, written = limited
    assert bound["point"]["gamma"] >= free["point"]["gamma"] * (1 - 1e-3)
    assert bound["limit_search"]["gamma_unconstrained"] == free["point"]["gamma"]
    again = runner.invoke(app, ["certify", str(written), "--no-lower-bounds", "--json", "-"])
    assert again.exit_code == 0 and json.loads(again.stdout)["points"][0]["gamma"] == bound["point"]["gamma"]


@pytest.mark.slow
def test_the_next_bracket_point_above_the_chosen_design_exceeds_a_limit(limited, tmp_path):
    """Maximality to the bisection's resolution: the design of the box one step (1/64 of the
    bracket) above the chosen alpha, synthesised and written again here and simulated by
    ``dvfc simulate``, breaks the limits (exceeds one, or does not complete)."""
    _, bound, written = limited
    search = bound["limit_search"]
    step = (1 - search["bracket"][0]) / 2**SEARCH_STEPS
    assert search["exceeds_at"] == pytest.approx(search["alpha"] + step)
    spec, _ = load(written)
    box = scaled(LIMITS_BOUNDS, search["exceeds_at"])
    windows = case_window_spec(Case.load(written))  # the search's synthesis: the same SDP, the same windows
    above = designer(WEIGHTS, spec.reference.se3(), 6, theta_max=math.pi, windows=windows)(box)
    scenario = tmp_path / "above.toml"
    scenario.write_text(scenario_text(written.read_text(), above.point, name="above", weights=False,
                                      source=written.parent, target=scenario))
    result = runner.invoke(app, ["simulate", str(scenario), "--out", str(tmp_path / "run"), "--json", "-"])
    summary = json.loads(result.stdout)
    assert result.exit_code == 1 or _worst(summary["limits"]) > 1


@pytest.mark.slow
def test_no_design_within_the_limits_is_exit_1_and_writes_nothing(tmp_path):
    """Effort limits at 1% of the URDF's (``[implementation] torque_scale``): gravity alone
    exceeds them, no design of the family is within them; exit 1, no file, the status says so."""
    implementation = {"control_rate": 500.0, "torque_scale": 0.01}
    scenario = _limits_scenario(tmp_path, "weak.toml", lambda d: d.update(
        synthesize={"respect_limits": True}, implementation=implementation))  # fmt: skip
    target = tmp_path / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(scenario), "--out", str(target), "--json", "-"])
    assert result.exit_code == 1 and not target.exists()
    record = json.loads(result.stdout)
    assert record["point"] is None and record["status"].startswith("no design within the limits")


@pytest.mark.slow
def test_target_speed_design_respecting_limits_runs_within_them(tmp_path):
    """The same search for ``objective = "target_speed"``: the speed-optimal gains exceed the
    UR5's limits, the design written runs within them, and its certified target speed (the
    written file's envelope) exists."""
    synthesize_section = {"objective": "target_speed", "respect_limits": True, "k_xi": [1.0, 30.0],
                          "k_c": [0.5, 5.0], "k_e": [0.5, 15.0]}  # fmt: skip
    scenario = _limits_scenario(tmp_path, "speed.toml", lambda d: d.update(synthesize=synthesize_section))
    result = runner.invoke(app, ["synthesize", str(scenario), "--out", str(tmp_path / "syn.toml"), "--json", "-"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    assert not record["limit_search"]["trials"][0]["within"] and _worst(record["limits"]) <= 1
    assert record["max_target_speed"] is not None


CALIBRATION = {"image_width": 1280, "image_height": 1024, "camera_name": "cell", "distortion_model": "plumb_bob",
               "camera_matrix": {"rows": 3, "cols": 3, "data": [800.0, 0, 640.0, 0, 800.0, 512.0, 0, 0, 1]},
               "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5}}  # fmt: skip


@pytest.fixture(scope="module")
def windowed(tmp_path_factory):
    """``synthesize`` on the light wrist (``tests/data/light_wrist6.urdf``, 500 Hz hold) with wrist 3's
    ``[performance]`` weights 0.5, its URDF and camera calibration named relative to the scenario
    (``src/arm``, ``src/cam``), written to another folder (``out/deep``). The synthesis before the
    windows' constraint put wrist 3 at ``k_xi = 0.4867``, above its hold limit 0.4852 (``pose`` warned).
    Returns the folder, the JSON record, the human output and the written file."""
    tmp = tmp_path_factory.mktemp("windowed")
    (tmp / "src" / "arm").mkdir(parents=True)
    (tmp / "src" / "cam").mkdir()
    shutil.copy(Path(__file__).parent / "data" / "light_wrist6.urdf", tmp / "src" / "arm" / "light.urdf")
    (tmp / "src" / "cam" / "cam.yaml").write_text(yaml.safe_dump(CALIBRATION))
    data = tomllib.loads((EXAMPLES / "ur5_circle.toml").read_text())
    data["simulation"].update(duration=0.05, jit=False)
    data["robot"].pop("model")
    data["robot"]["urdf"] = "arm/light.urdf"
    data["camera"] = {"calibration": "cam/cam.yaml"}
    light = [1.0] * 5 + [0.5]
    data["performance"] = {"output": {"xi": light}, "disturbance": {"tau_d": light}}
    (tmp / "src" / "s.toml").write_text(tomli_w.dumps(data))
    target = tmp / "out" / "deep" / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(tmp / "src" / "s.toml"), "--out", str(target), "--json",
                                 str(tmp / "syn.json")], env={"COLUMNS": "400"})  # fmt: skip
    assert result.exit_code == 0 and target.exists(), result.output
    return tmp, json.loads((tmp / "syn.json").read_text()), result.stdout, target


@pytest.mark.slow
def test_every_synthesized_gain_lies_inside_its_window_with_margin_and_pose_warns_of_nothing(windowed):
    """docs/math.md, "Gain windows": each ``k_xi,i`` of the written design, its windows computed
    afresh from the written file (``M(q0)`` of its URDF, 500 Hz), lies in ``[1.1 lower, 0.8 upper]``,
    and ``dvfc pose`` on that file prints no warning."""
    _, _, _, target = windowed
    windows = case_windows(Case.load(target))
    assert np.all(windows.k_xi >= 1.1 * windows.lower)
    assert np.all(windows.k_xi <= 0.8 * windows.upper)
    assert windows.held <= 0.8 * (2 - HOLD_MARGIN)
    result = runner.invoke(app, ["pose", str(target)])
    assert result.exit_code == 0 and "warning" not in result.stderr, result.stderr


@pytest.mark.slow
def test_the_written_design_passes_the_sampled_loops_certificate_with_margin(windowed):
    """Fact 14 on the written design, recomputed from its file (the multirate monodromy, not the
    synthesis' record): ``rho <= 0.99`` and the linear control-rate margin at most 0.8 of 500 Hz."""
    _, _, _, target = windowed
    case = Case.load(target)
    record = implemented_record(case.loop, case.s0, case.settings)
    assert record["certified"] and record["rho"] <= 0.99
    control = record["margins"]["control_rate"]
    assert control["value"] is None or control["value"] <= 0.8 * 500.0


@pytest.mark.slow
def test_synthesize_says_when_the_written_design_loses_the_start_certificate(tmp_path):
    """Fact 16b: the default's own (isotropic) ``K_c`` certifies its planned start; the smallest gains
    reaching gamma 0.5 (fact 6's strictly convex program) have a ``K_c`` unequal across axes, so the
    written design's start is not certified, which the JSON and the human output of ``synthesize``
    state (and ``certify`` of the written file agrees)."""
    data = tomllib.loads((EXAMPLES / "ur5_circle.toml").read_text())
    data["simulation"]["duration"] = 0.05
    data["synthesize"] = {"gamma": 0.5}
    (tmp_path / "s.toml").write_text(tomli_w.dumps(data))
    target = tmp_path / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(tmp_path / "s.toml"), "--out", str(target), "--json",
                                 str(tmp_path / "syn.json")], env={"COLUMNS": "400"})  # fmt: skip
    assert result.exit_code == 0 and target.exists(), result.output
    record = json.loads((tmp_path / "syn.json").read_text())
    assert np.ptp(record["point"]["gains"]["k_c"]) > 0
    start = record["start"]
    assert start["original_certified"] and not start["written_certified"] and start["lost"]
    assert "START NOT CERTIFIED" in result.stdout and "K_c is not isotropic" in result.stdout
    assert envelope_record(Case.load(target), search=False)["start"]["inside"] is False


@pytest.mark.slow
def test_the_minimum_gamma_design_keeps_an_isotropic_start(windowed):
    """The box's corner (fact 6) has ``K_c`` equal across axes: the written design keeps the start
    certificate of the scenario's own gains (fact 16b), and ``synthesize`` says nothing of a lost start."""
    _, record, text, _ = windowed
    assert np.ptp(record["point"]["gains"]["k_c"]) == 0
    assert record["start"]["original_certified"] and record["start"]["written_certified"]
    assert not record["start"]["lost"] and "START NOT CERTIFIED" not in text


@pytest.mark.slow
def test_the_written_scenario_names_its_files_relative_to_itself_and_loads_after_moving(windowed, tmp_path):
    """The URDF and the calibration are written the same way, relative to the written file's folder;
    moved with its data (the whole folder elsewhere), the file loads with the same URDF and camera."""
    tmp, _, _, target = windowed
    written = tomllib.loads(target.read_text())
    assert written["robot"]["urdf"] == "../../src/arm/light.urdf"
    assert written["camera"]["calibration"] == "../../src/cam/cam.yaml"
    moved = tmp_path / "moved"
    shutil.copytree(tmp, moved)
    calibration = {**CALIBRATION, "camera_matrix": {"rows": 3, "cols": 3,
                                                    "data": [810.0, 0, 640.0, 0, 810.0, 512.0, 0, 0, 1]}}
    (moved / "src" / "cam" / "cam.yaml").write_text(yaml.safe_dump(calibration))  # which copy is read
    case = Case.load(moved / "out" / "deep" / "syn.toml")
    assert case.loop.robot.urdf == (moved / "src" / "arm" / "light.urdf").resolve()
    assert case.loop.camera.focal_length == 810.0


@pytest.mark.slow
def test_no_design_of_the_family_passing_fact_14_with_margin_is_refused_in_one_line(tmp_path):
    """The default example with a 120 ms latency and ``[synthesize]`` lower bounds ``k_c >= 8``,
    ``k_e >= 30``: the SDP's design is certified for the ideal loop, but its sampled loop is not
    (fact 14, ``rho > 1``), so the family of smaller boxes is searched a posteriori; its smallest
    design is not certified either. Exit 1, nothing written, one status line saying what limits it."""
    data = tomllib.loads((EXAMPLES / "ur5_circle.toml").read_text())
    data["simulation"].update(duration=0.05, jit=False)
    data["implementation"]["latency"] = 0.12
    data["synthesize"] = {"k_c": [8.0, 20.0], "k_e": [30.0, 50.0]}
    path = tmp_path / "late.toml"
    path.write_text(tomli_w.dumps(data))
    target = tmp_path / "out" / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(path), "--out", str(target), "--json", "-"])
    record = json.loads(result.stdout)
    assert result.exit_code == 1 and not target.exists() and record["point"] is None
    assert record["limit_search"]["trials"][0]["sampled"].startswith("the loop as implemented is not certified")
    status = record["status"]
    assert "\n" not in status and status.startswith("no design within the limits: the family's smallest certified "
                                                    "design (alpha = 0) falls short of the sampled loop's margins")


def test_the_python_synthesis_refuses_a_loop_it_is_not_for_before_any_work(tmp_path):
    """``dvfc.synthesize`` (the curated API) on the reduced planar loop: a :class:`ScenarioError`
    naming ``loop`` (fact 6 is for the paper's loop with n >= 6 joints), nothing written; the command
    says the same in one line, exit 2."""
    import dvfc
    from dvfc.analysis.scenario import ScenarioError

    planar = Path(__file__).resolve().parent.parent / "examples" / "planar2dd_reduced.toml"
    target = tmp_path / "out" / "designed.toml"
    with pytest.raises(ScenarioError, match=r"^loop: gain synthesis is for the paper's loop with n >= 6 joints"):
        dvfc.synthesize(dvfc.load(planar), target)
    assert not target.parent.exists()
    result = CliRunner().invoke(app, ["synthesize", str(planar), "--out", str(target)])
    assert result.exit_code == 2 and "loop: gain synthesis is for the paper's loop" in result.output
    assert not target.parent.exists()


def test_a_written_design_without_a_certified_target_speed_is_uncertified(result):
    """A target-speed synthesis whose written design's envelope certifies no speed: its outcome is
    ``uncertified`` (typed, not read from words), the JSON's status says why, ``max_target_speed`` is
    null and the design is not counted as written (``dvfc synthesize`` exits 1); with a certified speed
    the same record is ``ok`` and written."""
    envelope = {"max_target_speed": None, "reason": "no theta_bar keeps the features in view"}
    done = CaseSynthesis("s", "maximise the certified target speed (facts 7-8)", result, BOUNDS, None, None, None,
                         "text", envelope, None, math.radians(3.0))  # fmt: skip
    record = synthesis_record(done, Path("s.toml"), {}, 0.0)
    assert record.outcome is Outcome.UNCERTIFIED and not record.written
    assert record.status == "uncertified: no target speed certified for the written design (no theta_bar keeps the "\
        "features in view)"
    assert record.to_json()["max_target_speed"] is None and record.point.envelope is envelope
    certified = synthesis_record(replace(done, envelope=envelope | {"max_target_speed": 0.2}), Path("s.toml"), {}, 0.0)
    assert certified.outcome is Outcome.DESIGNED and certified.written and certified.status == "ok"


TWO_JOINTS = WindowSpec(np.diag([0.5, 0.02]), 500.0, None)
"""Two joints of inertia 0.5 and 0.02 kg m^2, uncoupled, held at 500 Hz, any finite gamma: each gain's
window is ``(1/2, (2 - HOLD_MARGIN) 500 m_i)`` whatever the other gain within its own."""
HOLD_LIMITS = (2 - HOLD_MARGIN) * 500.0 * np.array([0.5, 0.02])


def fact_14(rho: float, slowest: float | None) -> dict:
    """A stand-in of fact 14's record at 500 Hz: certified, with ``rho`` and the linearised loop stable
    down to ``slowest`` Hz (None: over the whole range searched)."""
    control = {"value": slowest, "unstable_at": None if slowest is None else slowest - 1.0, "range": [500.0, 10.0]}
    return {"applies": True, "certified": True, "reason": None, "rho": rho, "margins": {"control_rate": control}}


@pytest.mark.parametrize(
    ("hold", "lower", "rho", "slowest", "shortfall"),
    [
        (0.5, 2.0, 0.9, None, None),
        (0.79, 1.11, 0.985, 395.0, None),
        (0.81, 2.0, 0.9, None, "gain window: joint 1 k_xi"),
        (1.0, 2.0, 0.9, None, "gain window: joint 1 k_xi"),
        (0.5, 1.09, 0.9, None, "gain window: joint 2 k_xi"),
        (0.5, 1.001, 0.9, None, "gain window: joint 2 k_xi"),
        (0.5, 2.0, 0.995, None, "fact 14: rho"),
        (0.5, 2.0, 0.9999, None, "fact 14: rho"),
        (0.5, 2.0, 0.9, 405.0, "fact 14: the linearised loop is stable only down to"),
    ],
    ids=["well inside", "just inside every margin", "0.81 of a hold limit", "at a hold limit", "1.09 x a lower end",
         "just above a lower end", "rho 0.995", "rho 0.9999", "stable only down to 0.81 x the control rate"],
)  # fmt: skip
def test_a_design_is_inside_the_synthesis_margins_only_with_every_margin_kept(hold, lower, rho, slowest, shortfall):
    """The synthesis' margins (docs/math.md, "Gain windows"; fact 14 with margin): joint 1's gain at ``hold``
    of its hold limit and joint 2's at ``lower`` times its window's lower end, fact 14 certifying ``rho``
    and the linear control-rate margin ``slowest``. Inside exactly when every gain is at most 0.8 of its
    hold limit and at least 1.1 x its lower end, ``rho <= 0.99`` and the loop stays stable down to 0.8 of
    the control rate; a design short of one is said to be, naming the joint or the statement: a gain on
    its full hold limit, one just above its lower end, a ``rho`` between 0.99 and 1 are not inside."""
    k_xi = np.array([hold * HOLD_LIMITS[0], lower * 0.5])
    windows = TWO_JOINTS.of(k_xi)
    assert windows.upper == pytest.approx(HOLD_LIMITS, rel=1e-12) and np.all(windows.lower == 0.5)
    found = sampled_shortfall(windows, fact_14(rho, slowest))
    assert found is None if shortfall is None else found is not None and found.startswith(shortfall), found


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_the_synthesis_runs_each_design_with_its_own_integral_gain(tmp_path, factor):
    """The default example (``K_I = 10 K_xi``, engaging from t = 0 here, 0.1 s): the synthesis' run of a
    design with ``factor`` times the scenario's ``K_xi`` is the run of the scenario file written with that
    design, whose ``K_I`` is 10 times the design's ``K_xi``, not the scenario's: the limits it is
    judged by are the written design's (the peaks of the two runs the same to 1e-12, measured the same to
    the bit; with the scenario's ``K_I`` up to 3e-3 apart)."""
    data = tomllib.loads((EXAMPLES / "ur5_circle.toml").read_text())
    data["simulation"].update(duration=0.1, jit=False)
    data["gains"]["integral_start"] = 0.0
    path = tmp_path / "s.toml"
    path.write_text(tomli_w.dumps(data))
    case = Case.load(path)
    given = case.point
    point = GainPoint(factor * given.k_xi, given.k_c, given.k_e, given.weights, given.plant)
    assert designed_loop(case, point).gains.k_i == pytest.approx(10.0 * point.k_xi, rel=1e-15)
    target = tmp_path / "out" / "syn.toml"
    text = scenario_text(path.read_text(), point, name="syn", weights=False, source=tmp_path, target=target)
    written = written_case(case, text, target)
    measured, own = design_runner(case)(point), design_runner(written)(written.point)
    for key in ("peak_torque_commanded", "peak_speed"):
        assert np.asarray(measured[key]) == pytest.approx(np.asarray(own[key]), rel=1e-12, abs=0.0), key
