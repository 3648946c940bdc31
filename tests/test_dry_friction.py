"""Fact 29: the largest motion dry friction, a torque bounded by its Coulomb level whatever its model, drives in
the linearised sampled loop of ``examples/ur5_cell.toml`` (its plant, integral action and schedule; the viscous
friction in the linearisation)."""

from __future__ import annotations

import numpy as np
import pytest

import dvfc
from dvfc.analysis.dry_friction import TRACKING, friction_bound, input_kernel, period_response, tracking_rows
from dvfc.analysis.multirate import DeclaredPlant, MultirateLoop, held_linearization

from helpers import CELL
from loop_reference import linearised_run


@pytest.fixture(scope="module")
def cell():
    """The cell's loop linearised at rest with its viscous friction alone, its Coulomb levels, and the outputs:
    the tracking error's motion (:func:`tracking_rows`) and the joints."""
    case = dvfc.load(CELL)
    loop, settings = case.loop, case.settings
    plant = DeclaredPlant.of(settings)
    n = loop.robot.n
    lin = held_linearization(loop, case.s0[:n], plant).with_friction(np.asarray(plant.errors.viscous, float))
    system = MultirateLoop(lin, settings.implementation, loop.mode, {})
    mount = plant.errors.camera_vector(loop.camera)[:6]
    output = np.vstack([tracking_rows(loop, system, mount), np.eye(n, len(lin.a))])
    return system, np.asarray(plant.errors.coulomb, float), output, TRACKING + tuple(f"q{j + 1}" for j in range(n))


def test_fact_29_the_worst_friction_over_two_periods_drives_the_sum_of_its_terms(cell):
    """Over two common periods from rest, the torque ``c_j sign(r Gamma_l b_j)`` (constant on each quarter of a
    control period, within the friction's bounds) drives the output to ``sum |r Gamma_l b_j| c_j`` exactly: the
    linearised loop integrated by ``solve_ivp`` (DOP853, rtol 1e-12) with the schedule and latency by hand
    (``loop_reference.linearised_run``) agrees with the sum to 1e-8 of it, for the rotation about the optical
    axis and for wrist 3."""
    system, coulomb, output, rows = cell
    lin, imp, parts = system.lin, system.implementation, 4
    pi, sched = system.monodromy(imp)
    response = period_response(*lin.period_map(imp.period), system.output, sched, output)
    gamma, _ = input_kernel(lin.a, lin.b_tau, imp.period, parts)
    for name in ("rz", "q6"):
        i = rows.index(name)
        # y at the sample after two periods: g[0] (pi omega_k w_(0, k) + omega_k w_(1, k))
        reach = [response.g[0][i] @ pi @ w for w in response.omega] + [response.g[0][i] @ w for w in response.omega]
        signs = np.array([[np.sign(r @ gamma[part]) for part in range(parts)] for r in reach])
        torque = signs * coulomb
        expected = sum(np.abs(r @ gamma[part]) @ coulomb for r in reach for part in range(parts))
        z, _, _ = linearised_run(system, imp, np.zeros(len(pi)), integral=lin.b_tau.shape[1], torque=torque)
        assert abs(output[i] @ z - expected) <= 1e-8 * expected, name


def test_fact_29_the_bounds_close_in_on_the_supremum_as_the_parts_shrink(cell):
    """The lower bound (a torque constant on each of ``L`` parts of a period) grows and the upper bound (every
    torque) shrinks from ``L`` = 4 to 32, each pair in order, and at 32 parts they are within 5% of each other on
    every output; the joints' bound is finite (6-joint arm: nothing moves freely)."""
    system, coulomb, output, rows = cell
    coarse = friction_bound(system, coulomb, output, rows, parts=4)
    fine = friction_bound(system, coulomb, output, rows, parts=32)
    assert np.all(coarse.lower <= fine.lower * (1 + 1e-12)) and np.all(fine.upper <= coarse.upper * (1 + 1e-12))
    assert np.all(fine.lower <= fine.upper) and np.all(fine.upper <= 1.05 * fine.lower)
    assert np.all(np.isfinite(fine.upper))
