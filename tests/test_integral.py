"""Integral action ``u_xi = -K_xi xi - K_I z_I`` (docs/math.md, facts 20 and 21): the storage
identity with ``V_a`` on CVODES runs, the constant-torque equilibrium, fact 14's monodromy with
the integral state against an independent simulation, the sampled law against a sample-by-sample
loop, and the law without integral action unchanged."""

from __future__ import annotations

import hashlib
from dataclasses import replace

import casadi as cs
import numpy as np
import pytest
from pydantic import ValidationError

from dvfc.analysis.case import Case
from dvfc.analysis.certify import certify
from dvfc.analysis.linearize import linearize
from dvfc.analysis.messages import one_line
from dvfc.analysis.multirate import implemented_record, multirate_loop, spectral_radius
from dvfc.analysis.parametric import parameter_vector, symbolic
from dvfc.analysis.results import envelope_record
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, ScenarioError, build, load
from dvfc.analysis.simulate import identity_residuals
from dvfc.models.loop import Gains

from helpers import (
    build_loop,
    cell_with_default_design,
    default_from_the_papers_start,
    default_without_integral,
    run,
    scenario_dict,
    static_target,
)
from loop_reference import held_period, linearised_run

WRIST_3_TWO_SIGMA = 0.56 * np.exp(0.6)
"""Wrist 3's Coulomb friction at +2 sigma of the cell's dispersion (N m)."""
CELL_FRICTION = np.concatenate([[1.0, 1.0, 1.0, 0.1, 0.1, 0.1], [3.0, 3.0, 3.0, 0.56, 0.56, WRIST_3_TWO_SIGMA], [0.05]])
"""``[b; c; eps]`` of ``examples/ur5_cell.toml`` with wrist 3 at +2 sigma."""


def with_integral(loop, factor: float = 10.0, **changes):
    """``loop`` with ``K_I = factor K_xi`` (and other fields changed)."""
    g = loop.gains
    return replace(loop, gains=Gains(g.k_xi, g.k_c, g.k_e, factor * np.asarray(g.k_xi)), **changes)


def dissipation_residual(traj, storage: str) -> float:
    """``max_t |S(t) - S(0) - int(-nu^T K nu + x^T G w)|`` over the scale of
    :func:`dvfc.analysis.simulate.identity_residuals`, for the storage signal ``storage``."""
    v, i = traj[storage][:, 0], traj.integrals
    scale = max(traj["V_a"][0, 0], np.abs(i["supply_u_nu"]).max(), np.abs(i["supply_x_G_w"]).max())
    return float(np.abs(v - v[0] + i["dissipation_nu_K_nu"] - i["supply_x_G_w"]).max() / scale)


@pytest.fixture(scope="module")
def friction_run():
    """The ideal continuous loop (exact ``e_e``, the target circling) with the cell's friction, wrist
    3 at +2 sigma, and ``K_I = 10 K_xi``, over 1 s by CVODES (rtol = atol = 1e-10)."""
    loop, s0, settings = build_loop()
    loop = with_integral(loop, friction=CELL_FRICTION)
    traj = run(loop, np.concatenate([s0, np.zeros(loop.robot.n)]), settings, duration=1.0)
    assert traj.status == "ok", traj.message
    return traj


@pytest.mark.slow
def test_fact_20_1_the_augmented_storage_keeps_the_supply_of_43(friction_run):
    """(20.1) ``V_a = V + z_I^T K_I z_I / 2`` satisfies ``V_a(t) - V_a(0) = int(-nu^T K nu + x^T G w)``
    along the loop with friction (``w``'s torque ``-f(qd)``, fact 18.1) to 1e-8 relative (CVODES at
    1e-10 reaches 3e-9); with ``V`` in place of ``V_a`` the residual is 0.16: the ``-z_I^T K_I xi``
    the law adds is what ``V_a``'s new term pays, exactly."""
    assert np.abs(friction_run["z_I"]).max() > 1e-2  # the integrator is not idle
    assert dissipation_residual(friction_run, "V_a") <= 1e-8
    assert dissipation_residual(friction_run, "V") > 1e-2
    assert identity_residuals(friction_run)["dissipation"] <= 1e-8  # the summary's check uses V_a too


@pytest.fixture(scope="module")
def default_multirate():
    """The default example's linearised sampled loop, without and with ``K_I = 10 K_xi``."""
    spec, base = default_without_integral()
    loop, s0, settings = build(spec, base)
    imp, q0 = settings.implementation, s0[: loop.robot.n]
    return multirate_loop(loop, q0, imp), multirate_loop(with_integral(loop), q0, imp), imp


@pytest.mark.parametrize("integral", [False, True])
def test_fact_20_3_a_constant_torque_leaves_no_control_error_with_the_integral(default_multirate, integral):
    """(20.3, fact 21) The fixed point of the linearised sampled loop under a constant 1 N m on wrist 3:
    with ``K_I = 10 K_xi`` the control error ``e_c`` (to first order ``[R_d^T dpbar; dthetabar]``) is
    below 1e-9 and ``K_I z_I`` carries the torque (``K_I,6 z_I,6 = 1`` to 1e-9); without the integral
    ``|e_c|`` is 0.18 (10.3 deg about the optical axis: the arm at rest, the law's command balancing the torque)."""
    without, with_, imp = default_multirate
    system = with_ if integral else without
    n, h = 6, imp.period
    tau_d = np.zeros(n)
    tau_d[5] = 1.0
    z = system.lin.steady_state(h, system.output, tau_d)
    e_c = np.linalg.norm(z[2 * n : 2 * n + 6])
    if integral:
        k_i = 10 * np.array([20.0, 20.0, 20.0, 5.0, 5.0, 1.5])
        assert e_c < 1e-9 and np.abs(k_i * z[2 * n + 6 :] - tau_d).max() < 1e-9
    else:
        assert e_c > 0.05


@pytest.mark.slow
def test_fact_20_3_a_run_under_a_constant_torque_settles_at_zero_error_only_with_the_integral():
    """(20.3) The ideal continuous loop (CVODES), the target at rest, a constant 1 N m on wrist 3 from
    ``t = 0``, 8 s: with ``K_I = 10 K_xi`` the final ``|e_c|`` is below 2% of the loop's without the
    integral, which settles at its nonzero equilibrium (``|e_c| = 0.016``, its last second moving it by
    1e-6; with the integral 3e-6)."""

    def edit(data: dict) -> None:
        static_target(data)
        data["disturbance"] = {"torque": [{"kind": "step", "amplitude": [0, 0, 0, 0, 0, 1.0]}]}

    loop, s0, settings = build_loop(edit)
    plain = run(loop, s0, settings, duration=8.0, dt=0.05)
    pi = run(with_integral(loop), np.concatenate([s0, np.zeros(loop.robot.n)]), settings, duration=8.0, dt=0.05)
    assert plain.status == pi.status == "ok"
    e_plain, e_int = (np.linalg.norm(t["e_c"], axis=1) for t in (plain, pi))
    last_second = plain.t >= 7.0
    assert np.ptp(e_plain[last_second]) < 0.01 * e_plain[-1]
    assert e_int[-1] < 0.02 * e_plain[-1], (e_int[-1], e_plain[-1])


def test_fact_21_zero_integral_gain_keeps_todays_monodromy(default_multirate):
    """(21) With ``K_I = 0`` the integral state does not act on the loop: the monodromy on the 36 states
    restricted to the 30 of fact 14 equals today's to 1e-12, and the 6 further eigenvalues are 1 (the
    idle integrators). Without ``k_i`` (the default) ``rho`` is fact 14's 0.936901257464392 to 1e-14 (the last bit of
    LAPACK's eigenvalues of the 30 x 30 monodromy varies with the machine's BLAS; the
    loop with the program's observer step; 0.9369024199206657 with the observer integrated on ``qd(t)``)."""
    without, _, imp = default_multirate
    loop, s0, _ = build(*load(DEFAULT_SCENARIO))
    zero = multirate_loop(with_integral(loop, 0.0), s0[:6], imp)
    pi, _ = without.monodromy(imp)
    pi_zero, _ = zero.monodromy(imp)
    keep = np.r_[0:18, 24:36]  # every state but z_I (after [dq; dqd; dpbar; dthetabar])
    assert np.abs(pi_zero[np.ix_(keep, keep)] - pi).max() <= 1e-12
    assert np.allclose(np.sort(np.abs(np.linalg.eigvals(pi_zero)))[-6:], 1.0, atol=1e-9)
    assert abs(spectral_radius(pi) - 0.936901257464392) <= 1e-14


def test_fact_21_monodromy_with_the_integral_equals_a_sample_by_sample_simulation(default_multirate):
    """(21) Two common periods of the linearised loop with ``K_I = 10 K_xi`` simulated independently:
    the held flow by ``solve_ivp`` (DOP853, rtol 1e-12) with ``tau_k = F z_k + F_e e_k`` (``F`` reading
    ``-K_I z_I``), ``z_I <- z_I + h xi_k`` after each period with the sample's ``xi``, the 60 Hz captures
    used 10 samples later by hand. From a random state the result equals ``Pi^2`` applied to it to 1e-8."""
    _, system, imp = default_multirate
    lin = system.lin
    pi, sched = system.monodromy(imp)
    nz, ne = lin.b_e.shape
    assert pi.shape == (36, 36) and nz == 24
    rng = np.random.default_rng(21)
    start = rng.standard_normal(pi.shape[0]) * 1e-3
    z, e, period = linearised_run(system, imp, start, integral=6)
    assert sched.steps == period
    expected = (pi @ pi @ start)[: nz + ne]
    assert np.abs(np.concatenate([z, e]) - expected).max() < 1e-8 * np.abs(expected).max()


@pytest.mark.slow
def test_fact_21_rho_of_the_cell_with_the_integral_and_its_viscous_friction():
    """(21) On ``examples/ur5_cell.toml``'s plant with the default design and ``K_I = 10 K_xi``: 36 states,
    ``rho = 0.940459`` (certified) for the plant as declared, its viscous friction in the linearisation (its dry
    friction a bounded torque, fact 29, whose bound the record gives), 0.940603 without friction; without the
    integral 0.938504 and 0.936901."""
    spec, base = cell_with_default_design()
    loop, s0, settings = build(spec, base)
    plain = implemented_record(loop, s0, settings)
    record = implemented_record(with_integral(loop), s0, settings)
    assert plain["states"] == 30 and record["states"] == 36 and record["certified"] and record["integral_state"]
    assert record["rho"] == pytest.approx(0.940459, abs=1e-6) and plain["rho"] == pytest.approx(0.938504, abs=1e-6)
    assert record["friction_slope"]["rho_without_friction"] == pytest.approx(0.940603, abs=1e-6)
    assert plain["friction_slope"]["rho_without_friction"] == pytest.approx(0.936901, abs=1e-6)
    assert record["dry_friction"]["within"] is None and "fact 29" in record["dry_friction"]["statement"]


@pytest.fixture(scope="module")
def as_built():
    """The default example from the paper's start (constant reference, ``[observer]`` error) over 0.1 s,
    by the virtual machine, without its own integral action (each test adds the ``K_I`` it checks)."""
    return default_from_the_papers_start(0.1)


def test_sampled_integral_law_equals_a_sample_by_sample_loop(as_built):
    """Step 1 (fact 20, the loop as implemented): ``z_I`` held over each period and updated once per
    period with the sample's ``xi``, not integrated where the commanded torque is beyond its effort
    limit and the update would push it further (joint limits scaled to 0.2 so that saturation acts).
    A plain loop over the samples (RK4 of the held flow, the observer stepped by scipy's matrix
    exponential, ``xi`` and the law from the model's own expressions, the anti-windup rule in NumPy)
    gives the same states to 1e-10, and the rule skips some updates."""
    loop, s0, settings = as_built
    loop = with_integral(loop)
    n = loop.robot.n
    s0 = np.concatenate([s0, np.zeros(n)])
    imp = replace(settings.implementation, saturate=True, torque_scale=0.2, pixel_noise=0.0)
    traj = as_implemented(loop, replace(settings, implementation=imp)).run(s0)
    sampled = replace(loop, sampled=True)
    hold = sampled.hold
    rate = cs.Function("rate", [sampled.t, sampled.state, hold], [sampled.state_rate])
    law = cs.Function("law", [sampled.t, sampled.state, hold], [sampled.tau, sampled.xi, sampled.camera_velocity,
                                                                 sampled.u[n + 6 : n + 12]])  # fmt: skip
    camera = cs.Function("camera", [sampled.t, sampled.state], [sampled.e_e_image])
    effort, h = imp.limits(loop.robot.limits).effort, imp.period
    steps = round(settings.duration / h)
    captures = set(imp.capture_steps(steps).tolist())
    pending, e_held, s, states, skipped = [], np.zeros(6), s0.copy(), [s0], 0
    for k in range(steps):
        t = k * h
        if k in captures:
            pending.append((k + imp.latency_steps, np.asarray(camera(t, s)).ravel()))
        while pending and pending[0][0] <= k:
            e_held = pending.pop(0)[1]
        tau, xi, v_k, u_k = (np.asarray(v).ravel() for v in law(t, s, np.concatenate([np.zeros(n), e_held,
                                                                                      np.zeros(12)])))  # fmt: skip
        z_i = s[-n:].copy()
        windup = ((tau > effort) & (xi < 0)) | ((tau < -effort) & (xi > 0))
        skipped += int(windup.sum())
        s = held_period(rate, t, s, np.clip(tau, -effort, effort), e_held, v_k, u_k, h, imp.substeps, n)
        s[-n:] = z_i + np.where(windup, 0.0, h * xi)
        states.append(s)
    assert traj.status == "ok", traj.message
    assert skipped > 0
    assert np.abs(traj["state"] - np.array(states[:: round(settings.dt / h)])).max() <= 1e-10


@pytest.mark.slow
def test_without_integral_action_the_default_run_is_unchanged(as_built):
    """``K_I`` absent (every existing scenario): the state, the parameter vector and the run are those of
    the law (35), (42): 19 states, 35 parameters (and the planned start's 20), and the default example's
    sampled run over 0.2 s has the recorded SHA-256 of its states (the loop running the program's observer
    step and the Coriolis product by docs/math.md fact 27; ``24b7b90bc2963aa6`` with the Christoffel product,
    the states at most 6.2e-14 apart; ``8fc862f9f743932d`` with the observer integrated on ``qd(t)``, fact 22).
    With ``K_I = 0`` the sampled loop
    carries ``z_I`` but moves the arm bit for bit as without it (the default example without its
    ``k_i_factor``)."""
    loop, s0, settings = build(*default_without_integral())
    assert loop.n_state == 19 and loop.plan is not None and len(parameter_vector(loop)) == 35 + 20
    traj = as_implemented(loop, replace(settings, duration=0.2, jit=False)).run(s0)
    digest = hashlib.sha256(np.ascontiguousarray(traj["state"]).tobytes()).hexdigest()
    assert digest[:16] == "705fb79044574a94"
    loop, s0, settings = as_built
    plain = as_implemented(loop, settings).run(s0)
    zero = as_implemented(with_integral(loop, 0.0), settings).run(np.concatenate([s0, np.zeros(6)]))
    assert np.array_equal(zero["state"][:, :19], plain["state"])


def test_a_change_of_integral_gain_reuses_the_compiled_loop():
    """``K_I`` is an entry of the compiled functions' parameter vector ``p`` (the ``n`` before the time
    integral action starts from, its last entry here): two designs with other ``K_I`` share one symbolic loop,
    and ``p`` ends with each one's ``K_I`` and its start."""
    loop, _, _ = build_loop()
    a, b = with_integral(loop, 10.0), with_integral(loop, 20.0)
    assert symbolic(a) is symbolic(b)
    assert np.array_equal(parameter_vector(b)[-7:-1], 20 * np.asarray(loop.gains.k_xi))
    assert parameter_vector(b)[-1] == b.integral_start


@pytest.mark.parametrize(
    ("gains", "words"),
    [
        ({"k_i": 10.0, "k_i_factor": 10.0}, "give k_i or k_i_factor, not both"),
        ({"integral_start": 0.5}, "integral_start: needs k_i or k_i_factor"),
        ({"k_i": [1.0, 2.0]}, "gains.k_i"),
    ],
)
def test_bad_integral_gains_are_refused_naming_the_field(gains, words):
    """Both spellings at once, a start without a gain, a wrong length: a one-line error naming the field."""

    def edit(data: dict) -> None:
        data["gains"].update(gains)

    try:
        build(Scenario.model_validate(scenario_dict(edit)), DEFAULT_SCENARIO.parent)
        message = ""
    except ValidationError as exc:  # what `load` and the command line turn it into
        message = one_line(exc, Scenario, sections=True)
    except ScenarioError as exc:
        message = str(exc)
    assert words in message and "\n" not in message, message


def test_integral_starts_where_the_planned_start_ends():
    """The default integral start is the planned reference's hold plus its duration (the default
    example: 2 s plan, 24 ms first-image hold), ``[gains] integral_start`` when given; ``k_i_factor``
    is ``K_I = k_i_factor K_xi`` joint by joint."""
    spec, base = load(DEFAULT_SCENARIO)
    data = spec.model_dump()
    data["gains"]["k_i_factor"] = 10.0
    loop, _, _ = build(Scenario.model_validate(data), base)
    assert loop.integral_start == pytest.approx(loop.plan.hold + loop.plan.duration)
    assert np.array_equal(loop.gains.k_i, 10 * np.asarray(loop.gains.k_xi))
    data["gains"]["integral_start"] = 0.5
    assert build(Scenario.model_validate(data), base)[0].integral_start == 0.5


@pytest.mark.slow
def test_fact_20_2_the_integral_loop_keeps_gamma_and_its_linearised_gain_stays_below_it():
    """(20.2) Theorem 2's ``P(gamma)`` never sees ``z_I``: the certified gamma of the default design is the
    same with ``K_I = 10 K_xi`` (0.7071075), and the H-infinity norm from ``w`` to ``x`` of the integral
    loop linearised at rest (30 states, an independent computation) is below it (0.6608; 0.6553 without
    the integral): the same gamma bounds the new loop. The envelope says it is not certified, naming
    fact 20.4, and keeps the same design's without ``K_I`` apart."""
    case = Case.load(DEFAULT_SCENARIO)
    integral = case.with_gains(k_i_factor=10.0)
    gamma = certify(case.point, case.reference, with_sdp=False).gamma
    assert certify(integral.point, case.reference, with_sdp=False).gamma == gamma
    lin = linearize(integral.loop, integral.s0[:6])
    assert lin.system.nstates == 30 and lin.hinf <= gamma
    env = envelope_record(integral, search=False)
    assert env["rate"] is None and "fact 20.4" in env["reason"] and env["without_integral"]["rate"] is not None


@pytest.fixture(scope="module")
def default_case() -> Case:
    """The default example: integral action ``k_i_factor = 10`` engaging where the planned start ends."""
    case = Case.load(DEFAULT_SCENARIO)
    assert case.loop.integral and case.loop.integral_start > 0
    return case


@pytest.mark.slow
def test_fact_20_6_until_integral_start_the_run_is_the_design_without_k_i(default_case):
    """Fact 20.6: before ``integral_start`` the loop with ``K_I`` and the one without are one ODE from
    one state, so their CVODES runs (rtol = atol = 1e-10) agree to the solver's tolerance up to it
    (1e-7 on every state but ``z_I``, which stays 0 but for CVODES's interpolation across ``integral_start``,
    1e-12) and part once ``z_I`` moves."""
    loop, s0, settings = default_case.loop, default_case.s0, default_case.settings
    n, t_i = loop.robot.n, loop.integral_start
    g = loop.gains
    ideal = replace(loop, mode="ideal")
    with_k = run(ideal, s0, settings, duration=t_i + 0.6)
    without = run(replace(ideal, gains=Gains(g.k_xi, g.k_c, g.k_e)), s0[:-n], settings, duration=t_i + 0.6)
    before, after = with_k.t < t_i, with_k.t >= t_i + 0.3
    assert np.abs(with_k["z_I"][before]).max() <= 1e-12
    gap = np.abs(with_k["state"][:, :-n] - without["state"])
    assert gap[before].max() <= 1e-7
    assert gap[after].max() >= 1e-4  # the integral acts after it: the comparison can fail


@pytest.mark.slow
def test_fact_20_6_the_start_is_certified_until_integral_action_engages(default_case):
    """The envelope of a design with ``K_I`` is not certified (fact 20.4), but its start is, up to
    ``integral_start``: the planned start's statement of the same design without ``K_I``, said for
    ``0 <= t <= integral_start``; from ``t = 0`` (``integral_start = 0``) it is not certified."""
    record = envelope_record(default_case, search=False)
    start, t_i = record["start"], default_case.loop.integral_start
    assert record["rate"] is None and start["inside"] and start["until_s"] == t_i
    assert f"for 0 <= t <= {t_i:.4g} s" in start["statement"] and "for all t >= 0" not in start["statement"]
    assert start["level"] == record["without_integral"]["start"]["level"]
    sc = default_case.scenario
    at_once = default_case.with_scenario(
        sc.model_copy(update={"gains": sc.gains.model_copy(update={"integral_start": 0.0})})
    )
    assert not envelope_record(at_once, search=False)["start"]["inside"]
