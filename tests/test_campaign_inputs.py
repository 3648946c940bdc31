"""The target's radius and the plant's masses as inputs of the compiled loop: dispersed by a
campaign without recompiling, each run the run of the scenario with its values written in."""

from __future__ import annotations

import copy
import tomllib
from dataclasses import replace

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis import compile as compile_module
from dvfc.analysis.campaign import CampaignSpec, campaign_settings, shared_simulator, simulate_run
from dvfc.analysis.case import Case
from dvfc.analysis.margins import tracking_bound
from dvfc.analysis.parametric import PLANT_ENTRIES, InertialPlant
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.models.robot import Payload, Robot

BASE = tomllib.loads(DEFAULT_SCENARIO.read_text())

INPUTS = {
    "target.motion.radius": {"dist": "uniform", "low": -0.02, "high": 0.02},
    "plant.mass_scale": {"dist": "lognormal", "sigma": 0.1},
    "plant.payload.mass": {"dist": "uniform", "low": 0.2, "high": 1.0},
    "plant.payload.com": {"dist": "normal", "sigma": 0.02},
    "plant.payload.inertia": {"dist": "uniform", "low": 0.0, "high": [1e-3, 0.0, 0.0, 1e-3, 0.0, 1e-3]},
}
"""Every input field drawn, about the default scenario (which has no [plant]: the campaign gives
its loop the URDF's arm as the plant)."""


def case_of(data: dict) -> Case:
    return Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent)


def scenario_data(duration: float = 1.0) -> dict:
    data = copy.deepcopy(BASE)
    data["simulation"]["duration"] = duration
    return data


@pytest.fixture(scope="module")
def drawn_and_written(tmp_path_factory):
    """Run 1 of a campaign drawing :data:`INPUTS`; the run of the scenario with run 1's values
    written in, on a simulator built after the campaign's; the compiled functions built for it."""
    data = scenario_data()
    data["dispersion"] = INPUTS
    case = case_of(data)
    spec = CampaignSpec.of(case, tracking_bound(case))
    values = spec.values(1)
    _, drawn = simulate_run(spec, 1, shared_simulator(case))
    written = scenario_data()
    written["target"]["motion"]["radius"] = float(values["target.motion.radius"][0])
    written["plant"] = {"mass_scale": float(values["plant.mass_scale"][0]),
                        "payload": {"mass": float(values["plant.payload.mass"][0]),
                                    "com": values["plant.payload.com"].tolist(),
                                    "inertia": values["plant.payload.inertia"].tolist()}}  # fmt: skip
    other = case_of(written)
    noise = spec.run_settings(1, values)[0].implementation.seed  # the run's pixel noise and faults
    settings = campaign_settings(other)  # the code path of campaign runs (plant errors, here none)
    settings = replace(settings, implementation=replace(settings.implementation, seed=noise))
    builds = []
    real = compile_module._build_all
    compile_module._build_all = lambda b, c: builds.extend(x[0][0].name() for x in b) or real(b, c)
    try:
        plain = as_implemented(other.loop, settings).run(other.s0)
    finally:
        compile_module._build_all = real
    return drawn, plain, builds


@pytest.mark.slow
def test_a_drawn_radius_mass_scale_and_payload_run_is_the_written_in_scenarios_bit_for_bit(drawn_and_written):
    drawn, plain, _ = drawn_and_written
    assert drawn.status == plain.status == "ok"
    assert set(drawn.signals) == set(plain.signals)
    for name, value in drawn.signals.items():
        assert np.array_equal(value, plain.signals[name]), name


@pytest.mark.slow
def test_the_written_in_radius_and_masses_run_on_the_campaigns_compiled_functions(drawn_and_written):
    """Another radius, mass scale and payload build no function anew (they are entries of ``p``)."""
    assert drawn_and_written[2] == []


def test_the_inertial_plant_has_the_perturbed_urdfs_dynamics(rng):
    """``s`` times the links' ``M`` and ``C qd + g`` plus the payload's equal the dynamics of the URDF with the
    links scaled and the payload added (``C`` from the Christoffel symbols of its ``M``, to 1e-12 relative:
    the same sums in another order, measured about 1e-15)."""
    case = case_of(scenario_data())
    r = case.loop.robot
    payload = Payload(1.3, (0.02, -0.01, 0.05), (0.01, 0.001, -0.002, 0.02, 0.003, 0.015))
    true = Robot(r.urdf, r.frame, r.mount, r.armature, payload, 1.2)
    masses = cs.SX.sym("masses", PLANT_ENTRIES)
    plant = InertialPlant(r, masses)
    expected = cs.Function("urdf", [true.q, true.qd], [true.mass_matrix, true.coriolis @ true.qd + true.gravity])
    given = cs.Function("inputs", [r.q, r.qd, masses], [plant.mass_matrix, plant.bias])
    vector = np.r_[1.2, payload.mass, payload.com, payload.inertia]
    for _ in range(5):
        q, qd = rng.uniform(-2, 2, r.n), rng.uniform(-1, 1, r.n)
        for a, b in zip(expected(q, qd), given(q, qd, vector), strict=True):
            a, b = np.asarray(a), np.asarray(b)
            assert np.allclose(a, b, rtol=0, atol=1e-12 * np.abs(a).max())
