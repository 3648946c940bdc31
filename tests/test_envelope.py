"""The operating envelope (docs/math.md, facts 7-9): each link of fact 7's chain on its own, the mass
bounds from the URDF, the rotation reductions, and visibility on simulated runs."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
from typer.testing import CliRunner

from dvfc.analysis.adversary import worst_disturbance
from dvfc.analysis.case import Case
from dvfc.analysis.certify import GainPoint, output_blocks, random_rotations, solve
from dvfc.analysis.cli import app
from dvfc.analysis.envelope import (
    DisturbanceBounds,
    decays,
    design_of,
    desired_features,
    disturbance_bounds,
    envelope,
    error_bounds,
    feature_boxes,
    rates,
    recheck,
    start_storage,
    storage_diagonal,
    xi_rates,
)
from dvfc.analysis.grid import GridSpec, certify_batch
from dvfc.analysis.linearize import driven, driven_at_rest, equilibrium_configuration
from dvfc.analysis.results import envelope_record, grid_envelope_for
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build, gain_point, load
from dvfc.analysis.simulate import Settings, Simulator
from dvfc.analysis.synthesize import Bounds, _speed_problem
from dvfc.analysis.verify import adversarial_claim, envelope_claims, rotation_angles
from dvfc.models.camera import Camera
from dvfc.models.disturbance import Sine
from dvfc.models.lie import SO3
from dvfc.models.loop import Weights
from dvfc.models.robot import BUILTIN_ARMATURE, BUILTIN_CAMERA_FRAME, BUILTIN_URDF, Robot, builtin_urdf

from helpers import build_loop, run, scenario_dict

EXAMPLES = Path(__file__).parent.parent / "examples"


def angle(r: np.ndarray) -> np.ndarray:
    """Rotation angles of a batch (B, 3, 3)."""
    return np.arccos(np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))


def test_phi_has_quadratic_bounds_in_e_r(rng):
    """Fact 7: ``|e_R|^2 / 2 <= phi(R) <= |e_R|^2 / (1 + cos theta_bar)`` for ``|theta| <= theta_bar``.
    The two sides meet as ``theta -> 0`` and at ``theta = theta_bar``, so the relative
    tolerance 1e-12 covers only rounding of ``cos``/``sin`` (~1e-16) amplified by ``1/sin^2``; and
    ``phi = tr(I - R)/2`` carries an absolute rounding error of a few ``eps`` (the trace of entries
    of order 1), which at ``theta ~ 1e-6`` exceeds the relative one: ``atol = 1e-15``."""
    theta_bar = math.radians(150.0)
    rotations = random_rotations(2000, theta_bar, rng)
    phi, e_r = [], []
    for r in rotations:
        phi.append(float(SO3(cs.DM(r)).error_function()))
        e_r.append(float(cs.sumsqr(SO3(cs.DM(r)).error_vector())))
    phi, e_r = np.array(phi), np.array(e_r)
    atol = 1e-15
    assert np.all(phi >= e_r / 2 * (1 - 1e-12) - atol)
    assert np.all(phi <= e_r / (1 + math.cos(theta_bar)) * (1 + 1e-12) + atol)


@pytest.fixture(scope="module")
def default_loop():
    return build_loop()


def storage_and_state(loop) -> cs.Function:
    """``(t, s) -> (V, xi, e_c, e_e, theta_ec, theta_ee)`` of the loop."""
    angles = [
        cs.acos(cs.fmin(1, cs.fmax(-1, (cs.trace(p.rotation.matrix) - 1) / 2)))
        for p in (loop.control_pose_error, loop.estimation_pose_error)
    ]
    kinetic = loop.xi.T @ loop.robot.mass_matrix @ loop.xi / 2
    return cs.Function("Vx", [loop.t, loop.state], [loop.storage, kinetic, loop.xi, loop.e_c, loop.e_e, *angles])


def random_states(loop, s0: np.ndarray, count: int, rng) -> list[np.ndarray]:
    """States around ``s0``: random joints in [-pi, pi], joint rates up to 3 rad/s, and the
    observer pose perturbed by up to 0.1 m and 0.6 rad."""
    n = loop.robot.n
    out = []
    for _ in range(count):
        s = s0.copy()
        s[:n] = rng.uniform(-math.pi, math.pi, n)
        s[n : 2 * n] = rng.uniform(-3, 3, n)
        s[2 * n : 2 * n + 3] += rng.uniform(-0.1, 0.1, 3)
        quat = s[2 * n + 3 :] + rng.uniform(-0.3, 0.3, 4)
        s[2 * n + 3 :] = quat / np.linalg.norm(quat)
        out.append(s)
    return out


def test_storage_is_below_x_d_x(default_loop, rng):
    """Fact 7: ``V <= x^T D x`` while ``theta_ec, theta_ee <= theta_bar``, term by term (the kinetic
    term with ``D_M / 2`` of docs/math.md, fact 10, at the Perron vector for ``s = 0.3``, the pose
    terms with ``1 + cos theta_bar``); and ``V`` bounds every error (``error_bounds(V)`` above each
    one) with ``m_lo``. Tolerance 1e-12 relative: the pose terms are the same sums evaluated twice
    (the kinetic term has a gap: ``D_M`` bounds every ``M(q)``)."""
    loop, s0, _ = default_loop
    design = design_of(gain_point(Scenario.model_validate(scenario_dict()), 6), loop.reference,
                       loop.robot.mass_bounds)  # fmt: skip
    f = storage_and_state(loop)
    theta_bar = math.radians(120.0)
    d = storage_diagonal(design, 0.3, theta_bar)
    checked = 0
    for s in random_states(loop, s0, 300, rng):
        v, kinetic, xi, e_c, e_e, th_c, th_e = (np.asarray(a).ravel() for a in f(0.0, s))
        bounds = error_bounds(design, float(v[0]))
        assert np.linalg.norm(e_c[:3]) <= bounds["p_ec"] * (1 + 1e-12)
        assert np.linalg.norm(e_e[:3]) <= bounds["p_ee"] * (1 + 1e-12)
        assert math.degrees(th_c[0]) <= bounds["theta_ec_deg"] * (1 + 1e-9) + 1e-9
        assert math.degrees(th_e[0]) <= bounds["theta_ee_deg"] * (1 + 1e-9) + 1e-9
        assert np.linalg.norm(xi) <= bounds["xi"] * (1 + 1e-12)
        if max(th_c[0], th_e[0]) <= theta_bar:
            x = np.concatenate([xi, e_c, e_e])
            assert kinetic[0] <= xi @ (d[:6] * xi) * (1 + 1e-12)
            assert v[0] - kinetic[0] <= x[6:] @ (d[6:] * x[6:]) * (1 + 1e-12)
            checked += 1
    assert checked > 100


@pytest.mark.parametrize("name", sorted(BUILTIN_URDF))
def test_mass_bounds_hold_at_random_configurations(name, rng):
    """``m_lo <= lambda_min(M(q))`` and ``lambda_max(M(q)) <= m_hi`` at 10^4 random ``q`` in
    ``[-pi, pi]^n`` (every configuration of a revolute arm). No tolerance: the bounds are
    proven, and the eigenvalue solver's error (~1e-15 ||M||) is far below every gap measured."""
    robot = Robot(builtin_urdf(name), BUILTIN_CAMERA_FRAME[name], armature=BUILTIN_ARMATURE.get(name, ()))
    bounds = robot.mass_bounds
    count = 10_000
    q = rng.uniform(-math.pi, math.pi, (robot.n, count))
    m = np.asarray(cs.Function("M", [robot.q], [robot.mass_matrix]).map(count)(q))
    eig = np.linalg.eigvalsh(m.reshape(robot.n, count, robot.n).transpose(1, 0, 2))
    assert eig[:, -1].max() <= bounds.m_hi
    assert 0 < bounds.m_lo <= eig[:, 0].min()


def design_at(design, reference, rotation: np.ndarray, k_e: np.ndarray):
    """The design's ``(e_c, e_e)`` block of ``N^T K N`` at ``R_ec = rotation`` with gains ``k_e``."""
    w = design.point.weights
    n_ce = output_blocks(np.array([[w.w_pc, w.w_rc, w.w_pe, w.w_re]]), reference, rotation[None])[0]
    k = np.concatenate([design.point.k_c, k_e])
    return replace(design, nkn=n_ce.T @ (k[:, None] * n_ce))


def test_isotropic_rate_does_not_depend_on_r_ec(default_loop, rng):
    """Fact 7 with fact 2: for block-isotropic ``K_e``, ``kappa(s)`` at random ``R_ec`` equals the
    one at ``I`` (congruence by an orthogonal matrix commuting with ``D``); 1e-10 relative
    covers the eigenvalue solver's error on matrices of norm ~1e2."""
    loop, _, _ = default_loop
    point = gain_point(Scenario.model_validate(scenario_dict(lambda d: d["gains"].update(k_xi=1e4))), 6)
    design = design_of(point, loop.reference, loop.robot.mass_bounds)
    s, theta = np.array([0.3]), np.array([math.radians(40.0)])
    reference = rates(design, s, theta)[0]
    assert reference < (1e4 - 0.3) / (design.mass.m_hi / 2)  # decided by the (e_c, e_e) block
    for r in random_rotations(50, math.pi, rng):
        value = rates(design_at(design, loop.reference, r, point.k_e), s, theta)[0]
        assert value == pytest.approx(reference, rel=1e-10)


def test_anisotropic_k_min_rate_is_below_every_rotation(default_loop, rng):
    """Fact 7 with fact 5: with anisotropic ``K_e`` the envelope uses ``K_min``; its ``kappa`` is at
    most the true ``kappa`` at every sampled ``R_ec``, some of which lie below ``kappa`` at
    ``R_ec = I`` (so checking ``I`` alone would not be sound for these gains)."""
    loop, _, _ = default_loop
    k_e = np.array([10.0, 1.0, 1.0, 10.0, 1.0, 1.0])
    edit = lambda d: d["gains"].update(k_e=k_e.tolist(), k_xi=1e4)  # noqa: E731
    point = gain_point(Scenario.model_validate(scenario_dict(edit)), 6)
    design = design_of(point, loop.reference, loop.robot.mass_bounds)
    s, theta = np.array([0.2]), np.array([math.radians(40.0)])
    sound = rates(design, s, theta)[0]
    assert sound < (1e4 - 0.2) / (design.mass.m_hi / 2)  # decided by the (e_c, e_e) block
    rotations = random_rotations(300, math.pi, rng)
    values = [rates(design_at(design, loop.reference, r, k_e), s, theta)[0] for r in rotations]
    at_identity = rates(design_at(design, loop.reference, np.eye(3), k_e), s, theta)[0]
    assert sound > 0 and min(values) >= sound * (1 - 1e-12)
    assert min(values) < at_identity * (1 - 1e-4)


def test_dissipation_rate_holds_pointwise_on_a_run(default_loop):
    """Fact 7: ``dV/dt <= -kappa V + gamma'^2/2 |w|^2`` at every output step of a run with the
    moving target and a torque disturbance, while the rotation errors stay below ``theta_bar``.
    ``dV/dt`` is exact (automatic differentiation of (38)); the slack 1e-8 (V + |w|^2) covers
    the identity residual of the run (~1e-10) and rounding."""
    loop, s0, settings = build_loop(lambda d: d.update(disturbance={"torque": [
        {"kind": "sine", "amplitude": [3.0, -2.0, 1.0, 0.5, 0.5, 0.2], "frequency": 0.7}]}))  # fmt: skip
    point = gain_point(Scenario.model_validate(scenario_dict()), 6)
    design = design_of(point, loop.reference, loop.robot.mass_bounds)
    theta_bar = math.radians(60.0)
    (decay,) = decays(design, np.array([theta_bar]))
    assert recheck(design, decay.s, theta_bar, decay.kappa) >= 0
    s = decay.s
    traj = run(loop, s0, settings, duration=4.0)
    v, vdot, w = traj["V"][:, 0], traj["Vdot"][:, 0], traj["w"]
    w2 = np.sum(w**2, axis=1)
    th_c, th_e = rotation_angles(traj, loop.reference)
    inside = np.maximum(th_c, th_e) <= theta_bar
    assert inside.mean() > 0.9
    excess = vdot - (-decay.kappa * v + w2 / (4 * s))
    assert np.all(excess[inside] <= 1e-8 * (v + w2)[inside])


def test_features_stay_in_their_boxes_when_the_start_is_inside():
    """Fact 8 with fact 7: the shipped start with ``V(0) <= c`` (near the reference, ``xi(0) = 0``),
    the target moving and a torque disturbance inside the bounds: ``V(t) <= c`` and every
    feature stays in its certified box at every output step. The boxes are rigorous; the only
    tolerance is the integrator's (1e-9 relative on ``V``, run at rtol 1e-10)."""
    spec, base = load(EXAMPLES / "ur5_envelope.toml")
    loop, s0, settings = build(spec, base)
    env = envelope(design_of(gain_point(spec, 6), loop.reference, loop.robot.mass_bounds), loop.camera,
                   disturbance_bounds(spec.envelope, loop), start_storage(loop, s0), search=False)  # fmt: skip
    assert env.start["inside"] and env.visible
    traj = run(loop, s0, settings, duration=5.0, jit=False)
    assert traj.status == "ok"
    assert np.all(traj["V"][:, 0] <= env.level * (1 + 1e-9))
    boxes = np.asarray(env.boxes_px)
    pixels = traj["f"].reshape(len(traj.t), -1, 2) + loop.camera.centre
    assert np.all(pixels >= boxes[None, :, :2]) and np.all(pixels <= boxes[None, :, 2:])


def test_a_design_whose_region_crosses_the_border_is_not_visible(default_loop):
    """Fact 8: an image just large enough for the desired features, but smaller than the boxes
    at the certified level, is reported ``visible = false`` with a negative margin."""
    loop, s0, _ = default_loop
    point = gain_point(Scenario.model_validate(scenario_dict()), 6)
    design = design_of(point, loop.reference, loop.robot.mass_bounds)
    desired = desired_features(loop.camera, loop.reference)
    f = loop.camera.focal_length * desired[:, :2] / desired[:, 2:]
    half = np.abs(f).max(axis=0) + 5.0  # the desired features 5 px inside the border
    small = Camera(loop.camera.focal_length, loop.camera.points, 2 * half[0], 2 * half[1])
    assert feature_boxes(design, small, desired, 0.0).visible
    env = envelope(design, small, DisturbanceBounds(0.0785, 0.0, 0.0), start_storage(loop, s0))
    assert env.visible is False and env.image_margin_px < 0
    assert env.max_target_speed is not None and env.max_target_speed < 0.0785


@pytest.mark.parametrize("gain", ["k_xi", "k_c", "k_e"])
def test_max_target_speed_grows_with_each_gain(default_loop, gain):
    """Facts 7-8: ``N^T K N`` grows with every gain, so ``kappa(s)`` does for every ``s`` and
    ``theta_bar``, ``c_inf`` falls and the largest certified speed cannot drop."""
    loop, s0, _ = default_loop
    start = start_storage(loop, s0)
    speeds = []
    for factor in (1.0, 1.5, 3.0):
        data = scenario_dict()
        data["gains"][gain] = (np.asarray(data["gains"][gain], dtype=float) * factor).tolist()
        point = gain_point(Scenario.model_validate(data), 6)
        design = design_of(point, loop.reference, loop.robot.mass_bounds)
        speeds.append(envelope(design, loop.camera, DisturbanceBounds(0.0785, 0.0, 0.0), start).max_target_speed)
    assert speeds[0] is not None and speeds[0] <= speeds[1] <= speeds[2]


CONTRACT = {"rate", "gamma_prime", "theta_bar_deg", "m_hi", "ultimate_V", "bounds", "visible", "image_margin_px",
            "depth_min", "start", "max_target_speed", "max_torque", "wbar"}  # fmt: skip


@pytest.mark.slow
def test_certify_reports_the_envelope_contract(tmp_path):
    """``dvfc certify --json``: ``points[0].envelope`` carries every key of the contract, with the
    bounds in SI units and degrees where the key says so, and the start covered for the
    shipped envelope example (the human table says so too)."""
    result = CliRunner().invoke(app, ["certify", str(EXAMPLES / "ur5_envelope.toml"), "--out", str(tmp_path),
                                      "--no-lower-bounds", "--json", "-"])  # fmt: skip
    assert result.exit_code == 0, result.output
    env = json.loads(result.stdout)["points"][0]["envelope"]
    assert set(env) >= CONTRACT
    assert set(env["bounds"]) == {"p_ec", "theta_ec_deg", "p_ee", "theta_ee_deg", "xi"}
    assert set(env["start"]) >= {"V0", "inside"} and env["start"]["inside"] and env["visible"]
    assert env["max_target_speed"] > env["disturbance"]["target_speed"]
    table = CliRunner().invoke(app, ["certify", str(EXAMPLES / "ur5_envelope.toml"), "--out", str(tmp_path),
                                     "--no-lower-bounds"])  # fmt: skip
    assert "every feature stays in the image for all t >= 0" in " ".join(table.stdout.split())


@pytest.mark.slow
def test_verify_confirms_the_envelope_on_a_run():
    """``dvfc verify``'s envelope claims (fact 7's inequality from t = 0, fact 8's boxes, the
    ultimate errors against fact 7's bound, the worst ``V(T)`` an adversarial search finds from
    ``V(0) = 0``) and its planned start's (fact 16b) all pass on the shipped example that starts at
    rest inside its envelope."""
    case = Case.load(EXAMPLES / "ur5_envelope.toml")
    claims = envelope_claims(case.loop, case.s0, replace(case.settings, duration=4.0, jit=False),
                             envelope_record(case, search=False))  # fmt: skip
    assert len(claims) == 9 and all(c.passed for c in claims), [c.to_json() for c in claims if not c.passed]


def test_p13_planar_envelope_holds_on_a_run():
    """(P13): for the reduced planar loop ``V <= x^T D x`` with no ``theta_bar``, so every start is
    covered; on the shipped planar run with a torque disturbance, ``dV/dt <= -kappa V +
    |w|^2/(4 s)`` at every output step and ``V(t)`` stays below fact 7's bound from t = 0.
    Slack 1e-8 (V + |w|^2): the run's identity residual (~1e-10) and rounding."""
    spec, base = load(EXAMPLES / "planar2dd_reduced.toml")
    loop, s0, settings = build(spec, base)
    loop = replace(loop, disturbances=[Sine(np.array([0.2, -0.1]), 0.8)])
    design = design_of(gain_point(spec, loop.robot.n), None, loop.robot.mass_bounds)
    env = envelope(design, loop.camera, DisturbanceBounds(loop.target.speed, 0.0, math.hypot(0.2, 0.1)),
                   start_storage(loop, s0))  # fmt: skip
    assert env.rate > 0 and env.start["inside"] and env.theta_bar_deg is None
    traj = run(loop, s0, settings, duration=4.0, jit=False)
    v, vdot, w2 = traj["V"][:, 0], traj["Vdot"][:, 0], np.sum(traj["w"] ** 2, axis=1)
    s = 1 / (2 * env.gamma_prime**2)
    assert np.all(vdot + env.rate * v - w2 / (4 * s) <= 1e-8 * (v + w2))
    bound = np.exp(-env.rate * traj.t) * v[0] + env.ultimate_V * np.maximum.accumulate(w2) / env.wbar**2
    assert np.all(v <= bound * (1 + 1e-9))


def test_grid_columns_match_the_single_design_envelope():
    """A grid's ``rate`` and ``max_target_speed`` columns at the design's own gains agree with the
    single-design envelope at the same ``theta_bar`` (from ``V(0) = 0``): the grid's few
    golden-section steps can only lose tightness (speed at most the single one's, within 1e-3;
    the optimum of ``s kappa(s)`` is flat), and a larger ``k_c`` never lowers either column's
    speed (``N^T K N`` grows with every gain)."""
    spec, base = load(EXAMPLES / "ur5_envelope.toml")
    loop, _, _ = build(spec, base)
    point = gain_point(spec, 6)
    context = grid_envelope_for(Case(spec, base))
    grid = GridSpec.around(point, loop.reference, [("k_c", np.array([2.0, 3.0, 4.5]))], None, context)
    columns = certify_batch(grid, 0, grid.size)
    design = design_of(point, loop.reference, loop.robot.mass_bounds)
    single = envelope(design, loop.camera, disturbance_bounds(spec.envelope, loop), {"V0": 0.0},
                      context.theta_bar)  # fmt: skip
    assert columns["max_target_speed"][1] <= single.max_target_speed * (1 + 1e-9)
    assert columns["max_target_speed"][1] >= single.max_target_speed * (1 - 1e-3)
    assert columns["rate"][1] == pytest.approx(single.rate, rel=2e-2)
    assert np.all(np.diff(columns["max_target_speed"]) >= 0)


@pytest.mark.slow
def test_worst_motion_at_095_of_the_largest_certified_speed_keeps_every_feature_in_view():
    """Facts 7-8 at the edge: with the target speed at 0.95 of ``max_target_speed`` (rate and
    torque as the scenario bounds them) the statement still holds, so from the equilibrium
    (``V(0) = 0``) under the worst target motion and joint torques the adversarial search finds,
    ``V(t)`` stays below the certified level and every feature stays in its box and in the image
    at every output step. The boxes are rigorous; the only tolerance is the integrator's
    (1e-9 relative on ``V``, run at rtol 1e-10)."""
    spec, base = load(EXAMPLES / "ur5_envelope.toml")
    loop, s0, _ = build(spec, base)
    design = design_of(gain_point(spec, 6), loop.reference, loop.robot.mass_bounds)
    given = disturbance_bounds(spec.envelope, loop)
    top = envelope(design, loop.camera, given, start_storage(loop, s0)).max_target_speed
    bounds = DisturbanceBounds(0.95 * top, given.target_rate, given.torque)
    q_eq = equilibrium_configuration(loop, s0[: loop.robot.n])
    _, s_eq = driven_at_rest(loop, cs.SX.zeros(loop.robot.n + 6), q_eq)
    env = envelope(design, loop.camera, bounds, {"V0": 0.0, "kinetic": 0.0, "pose": 0.0}, search=False)
    assert env.visible and env.level >= env.ultimate_V
    worst = worst_disturbance(loop, s0[: loop.robot.n], bounds, horizon=3.0, intervals=6, iterations=3)  # as verify
    pieces, h = np.asarray(worst["w"]), worst["horizon_s"] / worst["intervals"]

    def disturbance(t):
        w = cs.DM(pieces[-1])
        for k in range(len(pieces) - 2, -1, -1):
            w = cs.if_else(t < (k + 1) * h, cs.DM(pieces[k]), w)
        return w

    traj = Simulator(driven(loop, disturbance), Settings(duration=worst["horizon_s"], dt=0.01)).run(s_eq)
    assert traj.status == "ok"
    assert np.all(traj["V"][:, 0] <= env.level * (1 + 1e-9))
    boxes = np.asarray(env.boxes_px)
    pixels = traj["f"].reshape(len(traj.t), -1, 2) + loop.camera.centre
    assert np.all(pixels >= boxes[None, :, :2]) and np.all(pixels <= boxes[None, :, 2:])
    assert np.all(pixels >= 0) and np.all(pixels <= [loop.camera.width, loop.camera.height])


@pytest.mark.parametrize(("w_rc", "w_re"), [(1.0, 3.0), (3.0, 1.0)])
def test_self_consistent_level_keeps_both_rotations_within_theta_bar(default_loop, w_rc, w_re):
    """Fact 7's first exit: at the self-consistent level ``c_max(theta_bar)`` the rotation bounds
    of ``V <= c_max`` (``theta <= arccos(1 - c/w_r)``) stay within ``theta_bar`` for both errors,
    with ``w_rc != w_re`` either way round (the smaller weight decides), and the level is the
    largest such (1e-6 above it one of them exceeds). Tolerance 1e-9 deg: ``arccos`` near its
    argument's rounding."""
    loop, _, _ = default_loop
    edit = lambda d: d["weights"].update(w_rc=w_rc, w_re=w_re)  # noqa: E731
    design = design_of(gain_point(Scenario.model_validate(scenario_dict(edit)), 6), loop.reference,
                       loop.robot.mass_bounds)  # fmt: skip
    for degrees in (3.0, 30.0, 120.0):
        level = float(design.c_max(np.radians(degrees)))
        bounds = error_bounds(design, level)
        assert max(bounds["theta_ec_deg"], bounds["theta_ee_deg"]) <= degrees + 1e-9
        above = error_bounds(design, level * (1 + 1e-6))
        assert max(above["theta_ec_deg"], above["theta_ee_deg"]) > degrees


def test_recheck_refuses_a_rate_above_the_certified_one(default_loop):
    """The a posteriori check ``lambda_min(Q - kappa D) >= 0`` (``D = diag(D_M/2, D_ce)``, fact 10)
    passes at the certified rate and refuses rates 1.5x (decided by the pose block on the
    default design) and 1.01x of it (decided by the joint block, with gains small enough that
    the joint block sets the rate): it is made against the whole of ``D``."""
    loop, _, _ = default_loop
    theta_bar = math.radians(30.0)
    for edit in (None, lambda d: d["gains"].update(k_xi=[1.0, 1.0, 1.0, 0.8, 0.8, 0.6])):
        design = design_of(gain_point(Scenario.model_validate(scenario_dict(edit)), 6), loop.reference,
                           loop.robot.mass_bounds)  # fmt: skip
        (decay,) = decays(design, np.array([theta_bar]))
        assert recheck(design, decay.s, theta_bar, decay.kappa) >= 0
        factor = 1.5 if edit is None else 1.01
        assert recheck(design, decay.s, theta_bar, decay.kappa * factor) < 0
    assert decay.kappa == pytest.approx(xi_rates(design.mass, design.k_xi, np.array([decay.s]))[0], rel=1e-5)


def test_a_design_whose_regions_reach_zero_depth_is_not_visible(default_loop):
    """Fact 8: the smallest certified depth is ``min_i z_i - rho_i`` (the radius subtracted); at a
    level whose radius reaches beyond the nearest feature's depth the regions reach zero depth,
    and the design is not called visible, even by a camera with no image size (where no border
    can decide it)."""
    loop, _, _ = default_loop
    design = design_of(gain_point(Scenario.model_validate(scenario_dict()), 6), loop.reference,
                       loop.robot.mass_bounds)  # fmt: skip
    desired = desired_features(loop.camera, loop.reference)
    blind = Camera(loop.camera.focal_length, loop.camera.points)
    near = feature_boxes(design, blind, desired, 1e-8)
    assert near.visible is None and 0 < near.depth_min < desired[:, 2].min()
    level = 2.0  # |p_ec| + |p_ee| alone reach 2 sqrt(2 c / 4) = 2 m, beyond every depth
    assert 2 * math.sqrt(2 * level / 4.0) > desired[:, 2].max()
    far = feature_boxes(design, blind, desired, level)
    assert far.depth_min <= 0 and far.visible is False
    assert feature_boxes(design, loop.camera, desired, level).visible is False


@pytest.mark.slow
def test_certify_reports_the_inertia_matrices_of_the_rate():
    """``points[0].envelope.without_integral.inertia`` of the default example (its design without
    ``K_I``: the envelope of the law (42), fact 20.4): ``upper`` is ``diag(D_M)`` at the optimum,
    ``lower`` is ``m_lo I``, both n x n; ``D_M = rho (K_xi - s)`` (the Perron vector's equal ratios,
    1e-9 relative) and bounds ``M`` at the start configuration."""
    result = CliRunner().invoke(app, ["certify", str(EXAMPLES / "ur5_circle.toml"), "--no-lower-bounds",
                                      "--json", "-"])  # fmt: skip
    assert result.exit_code == 0, result.output
    env = json.loads(result.stdout)["points"][0]["envelope"]["without_integral"]
    upper, lower = np.array(env["inertia"]["upper"]), np.array(env["inertia"]["lower"])
    assert upper.shape == lower.shape == (6, 6) and "fact 10" in env["inertia"]["method"]
    assert np.allclose(lower, env["m_lo"] * np.eye(6), rtol=1e-12, atol=0)
    spec, base = load(EXAMPLES / "ur5_circle.toml")
    k_xi = np.asarray(gain_point(spec, 6).k_xi)
    s = 1 / (2 * env["gamma_prime"] ** 2)
    ratio = np.diag(upper) / (k_xi - s)
    assert ratio == pytest.approx(np.full(6, ratio[0]), rel=1e-9)
    loop, s0, _ = build(spec, base)
    m = np.asarray(cs.Function("M", [loop.robot.q], [loop.robot.mass_matrix])(s0[:6]))
    assert np.linalg.eigvalsh(upper - m)[0] > 0 and np.linalg.eigvalsh(m - lower)[0] > 0


@pytest.mark.parametrize("k_xi", [0.8, 20.0])
def test_target_speed_sdp_rate_is_the_envelope_rate(default_loop, k_xi):
    """The target-speed synthesis's SDP at fixed ``s`` has, as its optimum, the envelope's rate
    (10.4) at the upper gains (the rate grows with every gain): its joint-block constraint
    ``diag(k_xi - s) - (kappa/2) B >= 0`` is ``kappa <= 2 / rho(diag(k_xi - s)^-1 B)`` (binding for
    ``k_xi = 0.8``), its pose block the same ``D_ce`` (binding for ``k_xi = 20``). 1e-6 relative:
    Clarabel's accuracy (2e-8 measured); the gain boxes have width (a box of zero width is
    degenerate for the interior-point solver)."""
    loop, _, _ = default_loop
    weights = Weights(4.0, 1.0, 4.0, 1.0)
    bounds = Bounds((k_xi / 2, k_xi), (1.5, 3.0), (5.0, 10.0))
    theta_bar, s_value = math.radians(20.0), 0.4
    problem, s, kappa, _ = _speed_problem(weights, loop.reference, 6, bounds, loop.robot.mass_bounds, theta_bar)
    s.value = s_value
    assert solve(problem)[0] is not None
    point = GainPoint(np.full(6, k_xi), np.full(6, 3.0), np.full(6, 10.0), weights)
    design = design_of(point, loop.reference, loop.robot.mass_bounds)
    expected = rates(design, np.array([s_value]), np.array([theta_bar]))[0]
    assert float(kappa.value) == pytest.approx(expected, rel=1e-6)
    xi = xi_rates(design.mass, design.k_xi, np.array([s_value]))[0]
    assert (expected == pytest.approx(xi, rel=1e-12)) == (k_xi < 1)


def _rotations(rng, count: int, scale: float) -> np.ndarray:
    """Random rotations (count, 3, 3) with angles up to ``scale`` (uniform axes)."""
    from scipy.spatial.transform import Rotation

    axes = rng.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return Rotation.from_rotvec(axes * rng.uniform(0, scale, (count, 1))).as_matrix()


def _phi(r: np.ndarray) -> np.ndarray:
    return 1.0 - np.cos(angle(r))


@pytest.mark.parametrize("weights", [(4.0, 1.0, 4.0, 1.0), (4.0, 0.02, 4.0, 0.05)])
def test_joint_radius_bounds_every_feature_offset_and_is_attained(rng, weights):
    """docs/math.md, fact 16 (16.0.1): on random states (``g = g_d g_ec g_ee``, small to large errors,
    the kinetic term 0, ``c = V`` of the state), ``|p_ci - g_d p_oi| <= sqrt(2 c S_i)``; and the
    bound is attained as ``c -> 0`` (the Cauchy-Schwarz equality state: the offsets and both
    rotations aligned, ratio above ``1 - 1e-3``). Light rotational weights make the rotation
    term dominate (a Frobenius-norm radius, ``sqrt(2)`` larger there, is then far from attained)."""
    from dvfc.analysis.envelope import joint_radius

    w_pc, w_rc, w_pe, w_re = weights
    points = np.array([[0.05, 0.05, 0.0], [-0.05, 0.05, 0.0], [0.3, -0.1, 0.02]])
    count = 4000
    r_d = _rotations(rng, 1, math.pi)[0]
    worst = 0.0
    for scale in (0.01, 0.3, 3.0):
        r_ec, r_ee = _rotations(rng, count, scale), _rotations(rng, count, scale)
        p_ec, p_ee = rng.normal(size=(count, 3)) * scale / 10, rng.normal(size=(count, 3)) * scale / 10
        v = w_pc * np.sum(p_ec**2, 1) / 2 + w_pe * np.sum(p_ee**2, 1) / 2 + w_rc * _phi(r_ec) + w_re * _phi(r_ee)
        for i, p in enumerate(points):
            offset = np.einsum("ij,bj->bi", r_d, np.einsum("bij,j->bi", r_ec @ r_ee, p) - p
                               + np.einsum("bij,bj->bi", r_ec, p_ee) + p_ec)  # fmt: skip
            rho = joint_radius(weights, True, points, 1.0)[i] * np.sqrt(v)  # rho_i(c) = rho_i(1) sqrt(c)
            worst = max(worst, float((np.linalg.norm(offset, axis=1) / rho).max()))
    assert worst <= 1 + 1e-9
    small = 1e-8  # the equality state of Cauchy-Schwarz at a small level
    for i, p in enumerate(points):
        rho = joint_radius(weights, True, points, small)[i]
        k = rho / (1 / w_pc + 1 / w_pe + p @ p * (1 / w_rc + 1 / w_re))
        n = np.cross(p, [0.0, 0.0, 1.0]) if np.linalg.norm(p[:2]) else np.array([1.0, 0.0, 0.0])
        n /= np.linalg.norm(n)
        axis = np.cross(p, n) / np.linalg.norm(p)
        turn = [2 * math.asin(k * np.linalg.norm(p) / w / 2) for w in (w_rc, w_re)]
        r_ec, r_ee = (np.asarray(cs.DM(SO3.exp(axis * th).matrix)) for th in turn)
        offset = (r_ec @ r_ee - np.eye(3)) @ p + r_ec @ (r_ec.T @ n * k / w_pe) + n * k / w_pc
        rotation = w_rc * _phi(r_ec[None])[0] + w_re * _phi(r_ee[None])[0]
        v = w_pc * (k / w_pc) ** 2 / 2 + w_pe * (k / w_pe) ** 2 / 2 + rotation
        assert v == pytest.approx(small, rel=1e-6)
        assert np.linalg.norm(offset) / rho > 1 - 1e-3


def test_cone_interval_contains_the_ball_and_touches_its_ends(rng):
    """docs/math.md, fact 16 (16.0.2): for random balls in front of the camera, the image ``x/z`` (and
    ``y/z``) of random points of the ball lies in the interval, and the tangent points of the
    ball (in the plane of that axis and the optical axis) map onto both ends exactly."""
    from dvfc.analysis.envelope import cone_interval

    for _ in range(200):
        centre = np.array([*rng.uniform(-0.4, 0.4, 2), rng.uniform(0.2, 1.0)])
        radius = rng.uniform(0.0, 0.95) * centre[2]
        points = rng.normal(size=(3000, 3))
        points *= (radius * rng.uniform(0, 1, (3000, 1)) ** (1 / 3)) / np.linalg.norm(points, axis=1, keepdims=True)
        points += centre
        for axis in (0, 1):
            lo, hi = cone_interval(centre, axis, np.asarray(radius))
            ratio = points[:, axis] / points[:, 2]
            assert ratio.min() >= lo - 1e-12 and ratio.max() <= hi + 1e-12
            phi, d = math.atan2(centre[axis], centre[2]), math.hypot(centre[axis], centre[2])
            beta, length = math.asin(radius / d), math.sqrt(d**2 - radius**2)
            for end, sign in ((lo, -1), (hi, 1)):
                touch = np.array(centre)
                touch[axis], touch[2] = length * math.sin(phi + sign * beta), length * math.cos(phi + sign * beta)
                assert np.linalg.norm(touch - centre) == pytest.approx(radius, abs=1e-12)
                assert touch[axis] / touch[2] == pytest.approx(end, rel=1e-9, abs=1e-12)


def test_default_visible_level_grows_with_the_joint_radius_and_the_cone(default_loop):
    """docs/math.md, fact 16 (16.0): on the default's design the largest visible level is 0.0211
    (fact 8's corner boxes gave 0.00432)."""
    from dvfc.analysis.envelope import visible_level

    loop, _, _ = default_loop
    design = design_of(gain_point(Scenario.model_validate(scenario_dict()), 6), loop.reference,
                       loop.robot.mass_bounds)  # fmt: skip
    assert visible_level(design, loop.camera, desired_features(loop.camera, loop.reference)) == pytest.approx(
        0.02106, rel=2e-3)


@pytest.mark.slow
def test_adversarial_search_drops_a_disturbance_that_drives_the_arm_singular():
    """On a Z1-like arm with an offset camera bracket (``tests/data/z1_bracket.urdf``) near a
    poorly conditioned pose, the search's first gradient step drives joint 5 towards pi/2 (``J_b``
    singular, outside the envelope's premise) and CVODES stops on it: that disturbance is dropped
    for one between it and the last that ran, and the check stays conclusive (and holds)."""

    def z1(data):
        data["robot"] = {"urdf": str(Path(__file__).parent / "data" / "z1_bracket.urdf"),
                         "camera_frame": "camera_link", "q0": [0.5, 1.0, -2.0, 1.0, 0.3, 0.5]}  # fmt: skip
        data["target"] = {**{k: v for k, v in data["target"].items() if k not in ("xyz", "rpy")},
                          "relative_to_camera": {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}}  # fmt: skip

    case = Case(Scenario.model_validate(scenario_dict(z1)), DEFAULT_SCENARIO.parent)
    claim = adversarial_claim(case.loop, case.s0, envelope_record(case, search=False))
    assert claim.status == "PASS" and "disturbance(s) dropped" in claim.detail, claim.to_json()
