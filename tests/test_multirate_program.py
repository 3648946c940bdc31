"""Fact 14 for the loop the controller program closes (docs/math.md, fact 22): the monodromy of
``dvfc_program`` linearised, with the plant's held flow, against a sample-by-sample simulation, and its
``rho`` against fact 14's (the sampled simulator's loop, the same one)."""

from __future__ import annotations

from dataclasses import replace

import casadi as cs
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import dvfc
from dvfc.analysis.controller import Layout, program_function
from dvfc.analysis.multirate import _tangent, held_linearization, multirate_loop, program_monodromy, rest_model
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario

from helpers import default_without_integral


def with_integral(case):
    data = case.scenario.model_dump()
    data["gains"]["k_i_factor"] = 10.0
    data["simulation"]["jit"] = False
    return case.with_scenario(Scenario.model_validate(data))


def test_program_monodromy_squared_equals_a_sample_by_sample_simulation():
    """``Pi^2`` of the default UR5 with ``K_I = 10 K_xi`` against two common periods (50 samples)
    simulated in the program's own state (its ring by slot, its counter running, the captures of
    ``Implementation.capture_steps``), the program's step by CasADi's forward derivative, the plant's
    linearisation by ``solve_ivp`` (DOP853, 1e-12): within 1e-8 of each of three random initial states."""
    case = with_integral(dvfc.load(DEFAULT_SCENARIO))
    loop, imp = case.loop, case.settings.implementation
    result = program_monodromy(loop, case.s0[:6], imp)
    lin = held_linearization(loop, case.s0[:6])
    n, m, h, ring, steps, lag = 6, loop.camera.m, imp.period, result.ring, result.schedule.steps, imp.latency_steps
    layout = Layout(n, ring)
    program = program_function(replace(loop, sampled=True, plant=None), imp, ring)
    forward = program.forward(1)
    rest = rest_model(loop)
    f_q = np.asarray(cs.Function("fq", [rest.q], [cs.jacobian(cs.substitute(rest.features, rest.t, 0), rest.q)])(
        lin.q_eq))  # fmt: skip
    f_eq = np.asarray(cs.Function("f", [rest.q], [cs.substitute(rest.features, rest.t, 0)])(lin.q_eq)).ravel()
    gbar = loop.reference.position_quaternion()
    embed, project = _tangent(gbar[3:])
    captures = imp.capture_steps(4 * steps)
    start = steps * (lag // steps + 1)  # the simulation's first sample; its images in flight are captured before
    pending = [int(c) for c in captures if start - lag <= c < start]
    a, b = lin.a[: 2 * n, : 2 * n], lin.b_tau[: 2 * n]
    controller = 12 + n + 6 * ring
    rng = np.random.default_rng(3)
    for _ in range(3):
        v = rng.standard_normal(result.pi.shape[0])
        joints, ctrl = v[: 2 * n], v[2 * n : 2 * n + controller]
        flight = {c: v[2 * n + controller + 2 * m * i : 2 * n + controller + 2 * m * (i + 1)]
                  for i, c in enumerate(pending)}  # fmt: skip
        x_eq, dx = np.zeros(layout.size), np.zeros(layout.size)
        x_eq[layout.gbar], x_eq[layout.q_last] = gbar, lin.q_eq
        dx[layout.gbar], dx[layout.e_e], dx[layout.integral] = embed @ ctrl[:6], ctrl[6:12], ctrl[12:18]
        for j in range(ring):
            x_eq[layout.slot(j)] = gbar
            age = (start - j - 1) % ring + 1
            dx[layout.slot(j)] = embed @ ctrl[18 + 6 * (age - 1) : 18 + 6 * age]
        for k in range(start, start + 2 * steps):
            if k in captures:
                flight[k] = f_q @ joints[:n]
            arriving = k - lag in flight
            features = flight.pop(k - lag) if arriving else np.zeros(2 * m)
            x_eq[layout.counter] = k
            nominal = [1e3, lin.q_eq, np.zeros(n), f_eq, float(k - lag) if arriving else -1.0, x_eq]
            outputs = program(*nominal)
            seeds = [0.0, joints[:n], joints[n:], features, 0.0, dx]
            d_tau, dx, _ = (np.asarray(s).ravel() for s in forward(*nominal, *outputs, *seeds))
            dx[layout.counter] = 0.0
            rate = lambda t, y, tau=d_tau: a @ y + b @ tau  # noqa: E731
            joints = solve_ivp(rate, (0, h), joints, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
        end = start + 2 * steps
        ages = [project @ dx[layout.slot((end - age) % ring)] for age in range(1, ring + 1)]
        simulated = np.concatenate([joints, project @ dx[layout.gbar], dx[layout.e_e], dx[layout.integral], *ages,
                                    *(flight[c + 2 * steps] for c in pending)])  # fmt: skip
        assert np.abs(simulated - result.pi @ result.pi @ v).max() < 1e-8 * np.abs(v).max()


@pytest.mark.slow
@pytest.mark.parametrize("integral", [False, True])
def test_fact_14_monodromy_is_the_programs_linearised_loop(integral):
    """Fact 14's ``rho`` (the held linear flow's matrix exponential with the observer's inputs held, 30 or
    36 states) and the program's (its step ``dvfc_program`` linearised by CasADi's Jacobian, its ring and
    the features in flight as states, 98 or 104) are one loop's: equal to 1e-12 at 500 and 1000 Hz (the
    same 20 ms latency and 50 ms common period), with and without ``K_I = 10 K_xi`` (measured within
    3e-15). With the observer integrated on the continuous ``qd(t)`` instead, the two differed by
    1.2e-6 at 500 Hz (8.3e-5 with the integral), halving with ``h``."""
    case = dvfc.load(DEFAULT_SCENARIO)
    case = with_integral(case) if integral else case.with_scenario(default_without_integral()[0])
    states = []
    for rate in (500.0, 1000.0):
        imp = replace(case.settings.implementation, control_rate=rate)
        program = program_monodromy(case.loop, case.s0[:6], imp)
        states.append(program.pi.shape[0])
        assert abs(program.rho - multirate_loop(case.loop, case.s0[:6], imp).rho()) < 1e-12, rate
    assert states[0] == (104 if integral else 98)
