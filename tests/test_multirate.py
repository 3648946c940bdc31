"""The local certificate of the loop as implemented (docs/math.md, fact 14): the monodromy of
the linearised sampled multirate loop against an independent simulation of that linear loop,
its rate and latency margin against the nonlinear sampled loop, its Lyapunov check, the 7-joint arm's
self-motion, and the loops it does not apply to."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import replace
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
import scipy
from typer.testing import CliRunner

import dvfc
from dvfc.analysis import multirate, parametric
from dvfc.analysis.cli import app
from dvfc.analysis.multirate import (
    DeclaredPlant,
    implemented_record,
    implemented_text,
    lyapunov_check,
    multirate_loop,
    rest_model,
    rest_state,
    spectral_radius,
)
from dvfc.analysis.sampled import SampledSimulator
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build, load
from dvfc.analysis.simulate import Trajectory
from dvfc.models.robot import Payload, Robot

from helpers import default_without_integral
from loop_reference import linearised_run

XARM7_CELL = Path(__file__).parent.parent / "examples" / "xarm7_cell.toml"


@pytest.fixture(scope="module")
def default():
    """The default example's loop with the paper's law (no integral action: fact 21's monodromy with
    ``z_I`` is tests/test_integral.py's), start, settings and linearised sampled loop."""
    spec, base = default_without_integral()
    loop, s0, settings = build(spec, base)
    return loop, s0, settings, multirate_loop(loop, s0[: loop.robot.n], settings.implementation)


@pytest.fixture(scope="module")
def record(default):
    """Fact 14's record of the default example with the paper's law."""
    loop, s0, settings, _ = default
    return implemented_record(loop, s0, settings)


@pytest.fixture(scope="module")
def shipped():
    """Fact 14's record of the default example as shipped (integral action, fact 21)."""
    loop, s0, settings = build(*load(DEFAULT_SCENARIO))
    assert loop.integral
    return implemented_record(loop, s0, settings)


def test_monodromy_equals_a_sample_by_sample_simulation_of_the_linearised_loop(default):
    """Two common periods (100 ms) of the linearised loop simulated independently: the
    continuous linearised dynamics integrated by ``solve_ivp`` (DOP853, rtol 1e-12) between
    samples with the held torque ``tau_k = F z_k + F_e e_k``, the observer's held inputs
    ``o_k = O z_k + O_e e_k`` (the program's step, docs/math.md fact 22) and the held ``e``, every sample's
    ``C z`` kept in a delay line, the image of each capture (first sample at or after each
    60 Hz tick, by exact rational arithmetic) applied 20 ms (10 samples) later by hand. From a
    random state (``z``, the held ``e``, the image in flight) the result equals ``Pi^2`` applied
    to it to 1e-8 relative: the exact discretisation, the hold, the capture rule and the
    latency of the monodromy are the sampled loop's."""
    _, _, settings, system = default
    imp, lin = settings.implementation, system.lin
    pi, sched = system.monodromy(imp)
    nz, ne = lin.b_e.shape
    rng = np.random.default_rng(14)
    start = rng.standard_normal(pi.shape[0]) * 1e-3
    z, e, period = linearised_run(system, imp, start)
    assert sched.steps == period
    expected = (pi @ pi @ start)[: nz + ne]
    assert np.abs(np.concatenate([z, e]) - expected).max() < 1e-8 * np.abs(expected).max()


def test_exact_and_image_e_e_have_the_same_linearisation_at_rest(default):
    """``D(pinv(J)(f - fbar)) = D e_e`` at the equilibrium (``pinv(J) J = I``): the image
    estimate (21) and the exact ``e_e`` (15) linearise alike, so one monodromy covers both."""
    lin = default[3].lin
    assert np.abs(lin.c_image - lin.c).max() < 1e-8 * np.abs(lin.c).max()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("which", "rho", "control"), [("record", 0.936901, (45.0, 44.0)), ("shipped", 0.940603, (40.0, 39.0))]
)
def test_the_default_is_certified_with_the_stated_numbers(request, which, rho, control):
    """On the default the statement applies and is certified: ``rho`` 0.936901 over 50 ms with the
    paper's law (rate 1.30 1/s; 0.940603 as shipped, with ``z_I`` in the monodromy, fact 21), the
    Lyapunov decrease ``lambda_min(P - Pi^T P Pi)`` is 1 to 1e-9, and the linear margins are
    latency 144 ms (unstable at 146), camera 500/62 Hz (unstable at 500/63) and control 45 Hz
    (unstable at 44; 40 and 39 as shipped); the one-line text says so. (With the observer integrated
    on the continuous ``qd(t)`` instead of the program's step, docs/math.md fact 22: ``rho`` 0.936902
    and 0.940520, latency 140 ms, control 47 and 42 Hz.)"""
    record = request.getfixturevalue(which)
    assert record["applies"] and record["certified"]
    assert record["period"] == pytest.approx(0.05) and record["rho"] == pytest.approx(rho, abs=1e-6)
    assert record["rate"] == pytest.approx(-math.log(record["rho"]) / 0.05)
    assert abs(record["lyapunov_margin"] - 1) < 1e-9 and record["pi_error_tolerance"] > 1e-6
    m = record["margins"]
    assert (m["latency"]["stable_at"], m["latency"]["unstable_at"]) == pytest.approx((0.144, 0.146))
    assert (m["camera_rate"]["value"], m["camera_rate"]["unstable_at"]) == pytest.approx((500 / 62, 500 / 63))
    assert (m["control_rate"]["value"], m["control_rate"]["unstable_at"]) == control
    said = f"CERTIFIED for the plant equal to the controller's model: rho = {rho:.6g} over 50 ms"
    assert said in implemented_text(record)


def log_decay_rate(traj: Trajectory) -> float:
    """``-d ln|x| / dt`` fitted over the last half of the run (negative: growing)."""
    x = np.linalg.norm(np.hstack([traj["xi"], traj["e_c"], traj["e_e"]]), axis=1)
    half = traj.t >= traj.t[-1] / 2
    return float(-np.polyfit(traj.t[half], np.log(x[half]), 1)[0])


def run_at_rest(default, **change) -> Trajectory:
    """The nonlinear sampled loop (RK4 at 500 Hz, virtual machine) with the target at rest and
    no pixel noise, the implementation changed by ``change``, for 10 s from 0.01 rad off
    ``q_eq`` in every joint."""
    loop, _, settings, system = default
    imp = replace(settings.implementation, pixel_noise=0.0, **change)
    s = rest_state(loop, system.lin.q_eq)
    s[: loop.robot.n] += 0.01
    return SampledSimulator(rest_model(loop), replace(settings, implementation=imp, jit=False, dt=0.02)).run(s)


@pytest.mark.slow
def test_certified_rate_matches_the_decay_of_the_nonlinear_sampled_loop(default, record):
    """From 0.01 rad off ``q_eq`` the nonlinear sampled loop with the target at rest decays at
    the certified local rate: ``|x|`` over [5, 10] s at 1.34 1/s against 1.30. The measured rate
    is at least the slowest mode's less rounding, and the faster modes still present lift it a
    little: within [0.97, 1.1] x the certified rate."""
    measured = log_decay_rate(run_at_rest(default))
    assert 0.97 * record["rate"] <= measured <= 1.1 * record["rate"], (measured, record["rate"])


@pytest.mark.slow
def test_nonlinear_sampled_loop_decays_below_and_grows_above_the_linear_latency_margin(default, record):
    """The linear latency margin (144 ms) is where the nonlinear sampled loop turns unstable:
    at 0.9x (130 ms) ``|x|`` decays over the last half of 10 s, at 1.1x (158 ms) it grows (until
    the run ends at a singular image Jacobian)."""
    margin = record["margins"]["latency"]["value"]
    h = 1 / default[2].implementation.control_rate
    for factor, decays in ((0.9, True), (1.1, False)):
        rate = log_decay_rate(run_at_rest(default, latency=round(factor * margin / h) * h))
        assert (rate > 0) == decays, (factor, rate)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"quantization": 1.0}, "quantization 1 px"),
        ({"latency": 0.021}, "not a whole number of control periods"),
        ({"camera_rate": 500 / math.pi}, "not rational"),
    ],
)
def test_the_statement_does_not_apply_to_a_loop_without_its_equilibrium_or_schedule(default, change, words):
    """Quantization (no fixed point), a latency between samples, an irrational rate ratio (no
    common period): the record says the statement does not apply and why, and has no numbers."""
    loop, s0, settings, _ = default
    changed = implemented_record(loop, s0, replace(settings, implementation=replace(settings.implementation, **change)))
    assert not changed["applies"] and not changed["certified"] and changed["rho"] is None
    assert changed["reason"].startswith("does not apply") and words in changed["reason"]


@pytest.fixture(scope="module")
def redundant():
    """The 7-joint cell (``examples/xarm7_cell.toml``) with the plant equal to the model and no timing
    faults (the statement's loop): its loop, start, settings and linearised sampled loop."""
    spec, base = load(XARM7_CELL)
    loop, s0, settings = build(spec, base)
    faultless = replace(settings.implementation, latency_jitter=0, frame_drop=0.0, outlier_probability=0.0)
    settings = replace(settings, errors=None, implementation=faultless)
    return loop, s0, settings, multirate_loop(loop, s0[: loop.robot.n], settings.implementation)


@pytest.mark.slow
def test_on_a_seven_joint_arm_pi_fixes_the_self_motion_and_rho_is_that_across_it(redundant):
    """On the xArm 7 the tangent of the equilibria's manifold, ``T = [null(J_b(q_eq)); 0]`` (one
    column), is fixed by the monodromy (``||Pi T - T|| < 1e-12 ||Pi||``), so ``Pi`` has the eigenvalue
    1 (``rho(Pi) = 1``: the self-motion); its other eigenvalues are those of ``Q^T Pi Q`` across it
    (to 1e-9), and the record's ``rho`` is their largest modulus, certified below 1."""
    loop, s0, settings, system = redundant
    lin = system.lin
    jacobian = np.asarray(cs.Function("j", [loop.robot.q], [loop.robot.body_jacobian])(lin.q_eq))
    assert lin.self_motion.shape == (7, 1) and np.abs(jacobian @ lin.self_motion).max() < 1e-12
    pi = system.monodromy(settings.implementation)[0]
    across = system.transverse(pi)
    assert across.dimension == 1 and across.residual < 1e-12 * np.linalg.norm(pi, 2)
    assert spectral_radius(pi) == pytest.approx(1, abs=1e-9)
    full = np.sort_complex(np.linalg.eigvals(pi))
    expected = np.sort_complex(np.r_[1.0, np.linalg.eigvals(across.pi)])
    assert np.abs(full - expected).max() < 1e-9
    record = implemented_record(loop, s0, settings)
    assert record["applies"] and record["certified"] and record["self_motion"]["dimension"] == 1
    assert record["rho"] == pytest.approx(np.sort(np.abs(full))[-2], abs=1e-9) and record["rho"] < 0.99


@pytest.mark.slow
def test_a_tangent_the_monodromy_does_not_fix_is_not_certified(redundant, monkeypatch):
    """Across a direction that is not the self-motion (joint 1 alone in place of ``null(J_b)``) the
    compression ``Q^T Pi Q`` has ``rho < 1`` and a Lyapunov check that passes, but it is no statement about
    the loop: the computed ``Pi`` moves that direction (``||Pi T - T||`` above 1, against a tolerance on
    ``Pi`` of about 1e-5), so the record is not certified and names the residual."""
    loop, s0, settings, _ = redundant
    true = multirate.held_linearization
    joint_1 = np.eye(loop.robot.n)[:, :1]  # the tangent in dq alone (tangent None), joint 1's direction
    monkeypatch.setattr(multirate, "held_linearization",
                        lambda *a: replace(true(*a), self_motion=joint_1, tangent=None))  # fmt: skip
    record = implemented_record(loop, s0, settings)
    assert record["rho"] < 1 and record["lyapunov_margin"] > 0.5 and record["self_motion"]["tangent_residual"] > 1
    assert not record["certified"] and "self-motion's residual" in record["reason"]


def moving_the_self_motion(by: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A monodromy of a 7-joint arm's loop (``dq``, ``dqd``: 14 states) with a one-dimensional self-motion
    ``T`` (a unit direction of ``dq``, zero in ``dqd``): ``Pi = T T^T + Q A Q^T + e u T^T`` in an orthonormal
    basis ``[T, Q]``, ``A`` stable (``rho`` about 0.8) and ``u = Q v`` a unit direction across ``T``, so
    ``Pi`` moves ``T`` by ``||Pi T - T|| = e``, ``by`` times the tolerance on ``Pi`` of the Lyapunov
    check of ``A``, and its compression across ``T`` is ``A`` whatever ``e``. Returns ``(Pi, T's dq,
    e)``."""
    draw = np.random.default_rng(7)
    tangent = np.zeros((14, 1))
    tangent[:7, 0] = draw.normal(size=7)
    tangent /= np.linalg.norm(tangent)
    across = scipy.linalg.null_space(tangent.T)
    a = 0.6 * np.eye(13) + 0.05 * draw.normal(size=(13, 13))
    assert spectral_radius(a) < 0.9
    away = across @ (v := draw.normal(size=(13, 1))) / np.linalg.norm(v)
    moved = by * lyapunov_check(a).tolerance
    return tangent @ tangent.T + across @ a @ across.T + moved * away @ tangent.T, tangent[:7], moved


@pytest.mark.parametrize(("by", "certified"), [(0.0, True), (0.5, True), (0.9, True), (1.1, False), (2.0, False),
                                               (9.0, False)])  # fmt: skip
def test_the_self_motion_is_fixed_only_within_the_lyapunov_checks_tolerance(by, certified):
    """Fact 14 on a 7-joint arm: the Lyapunov check across the self-motion ``T`` speaks of the loop only if
    the computed ``Pi`` fixes ``T``, to within the tolerance on ``Pi`` that check allows (a ``Pi`` moving
    ``T`` by more may be the computed image of a true monodromy that does not fix it: ``T`` is then not
    shown to be the self-motion). With the same stable compression across ``T`` (its check certifies,
    margin 1, its poses found to be equilibria), a ``Pi`` moving ``T`` by ``by`` times that tolerance is
    certified exactly when ``by < 1``."""
    pi, self_motion, moved = moving_the_self_motion(by)
    across = multirate.transverse(pi, self_motion, multirate.SelfMotionCheck(4, 0.0, 1.0))
    check = lyapunov_check(across.pi)
    assert across.dimension == 1 and check.certified and check.margin == pytest.approx(1.0, abs=1e-9)
    assert across.residual == pytest.approx(moved, rel=1e-6, abs=1e-15)
    assert moved == pytest.approx(by * check.tolerance, rel=1e-6)
    assert across.certified(check) is certified


@pytest.mark.slow
def test_on_a_seven_joint_arm_the_nonlinear_loop_settles_on_the_self_motion_at_the_certified_rate(redundant):
    """From 0.01 rad off ``q_eq`` in every joint the nonlinear sampled loop of the xArm 7 (target at
    rest) decays at the rate certified across the self-motion (``|x|`` over [5, 10] s within [0.97, 1.1]x
    of it) and comes to rest at another equilibrium of the manifold: the camera at the reference
    (``|(e_c, e_e)|`` below 1e-3 of its largest) with the posture off ``q_eq`` along ``null(J_b)`` (at
    least half the start's offset along it), not back at ``q_eq``."""
    system = redundant[3]
    record = implemented_record(*redundant[:3])
    traj = run_at_rest(redundant)
    measured = log_decay_rate(traj)
    assert 0.97 * record["rate"] <= measured <= 1.1 * record["rate"], (measured, record["rate"])
    pose = np.linalg.norm(np.hstack([traj["e_c"], traj["e_e"]]), axis=1)
    assert pose[-1] < 1e-3 * pose.max()
    along = system.lin.self_motion[:, 0]
    start, end = (float(along @ (traj["q"][i] - system.lin.q_eq)) for i in (0, -1))
    assert abs(end) >= 0.5 * abs(start) > 0, (start, end)


def test_lyapunov_check_certifies_only_a_decreasing_positive_definite_form():
    """On a non-normal stable matrix (``rho`` 0.5, ``||Pi|| > 10``) the check finds
    ``P - Pi^T P Pi = I`` to rounding and certifies; on an unstable one (``rho`` 1.5) the
    Lyapunov equation still has a solution with ``P - Pi^T P Pi = I``, but ``P`` is indefinite:
    not certified."""
    stable = lyapunov_check(np.array([[0.5, 10.0], [0.0, 0.5]]))
    assert stable.certified and abs(stable.margin - 1) < 1e-9 and stable.p_min > 0
    assert stable.tolerance == pytest.approx(1 / (2 * stable.p_norm * np.linalg.norm([[0.5, 10], [0, 0.5]], 2)),
                                             rel=1e-3)  # fmt: skip
    unstable = np.array([[1.5, 1.0], [0.0, 0.2]])
    check = lyapunov_check(unstable)
    assert spectral_radius(unstable) == pytest.approx(1.5)
    assert not check.certified and check.p_min < 0 and abs(check.margin - 1) < 1e-9


@pytest.mark.slow
def test_certify_reports_the_loop_as_implemented(tmp_path):
    """``dvfc certify --json -`` on the default: ``points[0].implemented`` with ``rho``, ``rate``,
    ``period``, ``lyapunov_margin``, ``scope`` and the three margins, each with value, unit,
    stable_at and unstable_at; the human output has its line."""
    result = CliRunner().invoke(app, ["certify", str(DEFAULT_SCENARIO), "--no-lower-bounds", "--json",
                                      str(tmp_path / "c.json")])  # fmt: skip
    implemented = json.loads((tmp_path / "c.json").read_text())["points"][0]["implemented"]
    assert {"rho", "rate", "period", "lyapunov_margin", "scope", "margins"} <= set(implemented)
    assert "local" in implemented["scope"] and "target at rest" in implemented["scope"]
    for m in implemented["margins"].values():
        assert {"value", "unit", "stable_at", "unstable_at"} <= set(m)
    assert "loop as implemented, linearised at rest (fact 14, local): CERTIFIED" in result.output.replace("\n", " ")


def test_an_isolated_fixed_point_whose_map_fixes_the_tangent_is_not_the_self_motion():
    """``F(a, b) = (a + a^2 + c b, b / 2)`` fixes ``T = (1, 0)`` to first order (``DF(0) T = T``: its residual
    across is 0, its compression 1/2 certified by the Lyapunov check), yet its only fixed point near 0 is 0:
    from ``(step, 0)`` Newton's least-norm iteration on ``F(y) - y`` returns to 0 (moved 0 of the step), so
    the check that the self-motion's poses are equilibria fails and fact 14 across ``T`` is not certified;
    a map with a line of fixed points, ``F(a, b) = (a + c b, b / 2)``, passes it (moved all of the step)."""
    y, c = cs.SX.sym("y", 2), 0.3

    def residual(first: cs.SX) -> cs.Function:
        r = cs.vertcat(first + c * y[1], -y[1] / 2)
        return cs.Function("residual", [y], [r, cs.jacobian(r, y)])

    tangent = np.array([[1.0], [0.0]])
    isolated = multirate.self_motion_check(residual(y[0] ** 2), np.zeros(2), tangent[:1])
    line = multirate.self_motion_check(residual(cs.DM(0.0)), np.zeros(2), tangent[:1])
    assert isolated.residual < multirate.EQUILIBRIUM_TOLERANCE and abs(isolated.moved) < 1e-3 and not isolated.holds
    assert line.holds and line.moved == pytest.approx(1.0, abs=1e-12)
    pi = np.array([[1.0, c], [0.0, 0.5]])
    for check, certified in ((isolated, False), (line, True)):
        across = multirate.transverse(pi, tangent[:1], check)
        assert across.residual == 0.0 and lyapunov_check(across.pi).certified
        assert across.certified(lyapunov_check(across.pi)) is certified


@pytest.mark.slow
def test_a_payload_on_the_seven_joint_arm_moves_its_equilibria_with_the_integral_state():
    """On the xArm 7 cell a 1 kg payload: with integral action the loop still rests on a manifold of
    equilibria (its poses checked: every one found, moved by the whole step) whose tangent moves ``z_I`` (the
    payload's weight changes along the self-motion), fixed by the plant's monodromy to 1e-10, and fact 14 across
    it is certified; without integral action the payload's weight along the self-motion has nothing to hold it
    and no equilibrium is found: the statement does not apply."""
    data = tomllib.loads(XARM7_CELL.read_text())
    data["plant"] = {"payload": {"mass": 1.0}}
    loop, s0, settings = build(Scenario.model_validate(data), XARM7_CELL.parent)
    record = implemented_record(loop, s0, settings)
    moves = record["self_motion"]
    assert record["certified"] and moves["tangent_residual"] < 1e-10 and moves["equilibria"]["holds"], moves
    assert moves["equilibria"]["smallest_moved"] > 0.99
    system = multirate_loop(loop, s0[: loop.robot.n], settings.implementation, DeclaredPlant.of(settings))
    assert np.abs(system.lin.tangent[-loop.robot.n :]).max() > 1e-3  # z_I moves along the self-motion
    data["gains"].pop("k_i_factor")
    loop, s0, settings = build(Scenario.model_validate(data), XARM7_CELL.parent)
    record = implemented_record(loop, s0, settings)
    assert not record["applies"] and "no equilibrium of the plant as declared" in record["reason"]


LINEARISATION_ROUND_OFF = 1e-12
"""Relative difference allowed between fact 14's matrices evaluated from the structure's functions (the design and
the plant's masses inputs) and built with the numbers folded in: round-off of a different order of operations."""


def test_a_draws_plant_linearises_on_the_structures_functions(monkeypatch):
    """Fact 14 for a plant as drawn (payload, mass scale, camera mount) evaluates the functions of the arm's
    structure, built once (:func:`multirate.held_functions`, the same object for every draw), and gives the
    matrices and equilibrium of the linearisation built with the draw's numbers, to
    :data:`LINEARISATION_ROUND_OFF`."""
    case = dvfc.load(XARM7_CELL)
    loop, q0, errors = case.loop, case.s0[: case.loop.robot.n], case.settings.errors
    r = case.settings.plant or loop.robot
    moved = [replace(errors, mount_xyz=np.asarray(errors.mount_xyz) + np.array(d)) for d in ([0.002, -0.001, 0.0],
                                                                                             [0.0, 0.001, 0.003])]
    plants = [DeclaredPlant(Robot(r.urdf, r.frame, r.mount, r.armature, Payload(mass, (0.0, 0.0, 0.02)), scale),
                            drawn) for mass, scale, drawn in ((0.3, 1.0, moved[0]), (0.7, 1.05, moved[1]))]  # fmt: skip
    built: list = []
    original = multirate.held_functions
    monkeypatch.setattr(multirate, "held_functions", lambda *a: built.append(original(*a)) or built[-1])
    evaluated = [multirate.held_linearization(loop, q0, plant) for plant in plants]
    assert built[0] is built[1]
    monkeypatch.setattr(parametric, "parametrised", lambda loop: False)
    for lin, plant in zip(evaluated, plants, strict=True):
        reference = multirate.held_linearization(loop, q0, plant)
        pairs = {name: (getattr(lin, name), getattr(reference, name)) for name in (
            "a", "b_tau", "b_e", "b_o", "f", "f_e", "o", "o_e", "c", "c_image", "xi", "xi_e", "state", "tau_eq")}
        pairs["tangent"] = (lin.tangent @ lin.tangent.T, reference.tangent @ reference.tangent.T)  # a basis' sign
        for name, (x, y) in pairs.items():
            assert np.abs(x - y).max() <= LINEARISATION_ROUND_OFF * max(1.0, np.abs(y).max()), name
    assert not np.allclose(evaluated[0].a, evaluated[1].a)  # the draws' plants differ
