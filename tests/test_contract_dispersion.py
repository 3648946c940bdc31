"""What a campaign run is given of its draws: each drawn quantity reaches the setting of the run it names
and no other, whole-number quantities are drawn whole, and the box the worst-case search explores is the
range the distributions draw from, within each field's domain."""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import fields

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis.campaign import CampaignSpec
from dvfc.analysis.case import Case
from dvfc.analysis.dispersion import FIELDS, Dispersion
from dvfc.analysis.margins import TrackingBound
from dvfc.analysis.parametric import Inputs
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.schema import DistributionSection
from dvfc.models.robot import Payload

BASE = tomllib.loads(DEFAULT_SCENARIO.read_text())


@pytest.fixture(scope="module")
def spec() -> CampaignSpec:
    """The default example (e_e from the image, a circling target, integral action) with every
    dispersable field dispersed, so that each is an input of the campaign's runs."""
    data = copy.deepcopy(BASE)
    data["dispersion"] = {key: {"dist": "normal", "sigma": 1e-3} for key in FIELDS}
    case = Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent)
    return CampaignSpec.of(case, TrackingBound(1.0, 180.0, "scenario", ""))


def flat(spec: CampaignSpec, settings, s: np.ndarray) -> dict[str, np.ndarray]:
    """Every number a run is given: the implementation's and the plant errors' fields, the loop's inputs
    (radius, mass scale, payload; the scenario's when the run gives none) and the initial state's entries,
    by name."""
    out = {}
    for section in ("implementation", "errors"):
        value = getattr(settings, section)
        for f in fields(value):
            entry = getattr(value, f.name)
            if isinstance(entry, (int, float, np.ndarray, tuple, list)) and not isinstance(entry, bool):
                out[f"{section}.{f.name}"] = np.ravel(np.asarray(entry, dtype=float))
    inputs = settings.inputs or Inputs.of(spec.case.loop.target, settings.plant)
    out["inputs.radius"], out["inputs.mass_scale"] = np.array([inputs.radius]), np.array([inputs.mass_scale])
    p = inputs.payload or Payload(0.0)
    out["inputs.payload"] = np.array([p.mass, *p.com, *p.inertia], dtype=float)
    for i, v in enumerate(s):
        out[f"state[{i}]"] = np.array([v])
    return out


def changed(spec: CampaignSpec, values: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The numbers of the run given ``values`` that differ from the run given nothing: ``name -> (before,
    after)``."""
    before, after = (flat(spec, *spec.run_settings(0, v)) for v in ({}, values))
    assert set(before) == set(after)
    return {k: (before[k], after[k]) for k in after if not np.array_equal(before[k], after[k])}


def nudged(spec: CampaignSpec, key: str) -> np.ndarray:
    """``key``'s scenario value moved within its domain (by 0.1 and 0.01 per entry; a probability to 0.25;
    a whole number by 2)."""
    base = spec.dispersion.base[key]
    f = FIELDS[key]
    if f.high == 1.0:
        return np.full(len(base), 0.25)
    step = 2.0 if f.integer else 0.1 + 0.01 * np.arange(len(base))
    return base + step


ROUTES = {
    "implementation.latency": ["implementation.latency"],
    "implementation.latency_jitter": ["implementation.latency_jitter"],
    "implementation.frame_drop": ["implementation.frame_drop"],
    "implementation.outliers.probability": ["implementation.outlier_probability"],
    "implementation.outliers.size": ["implementation.outlier_size"],
    "implementation.pixel_noise": ["implementation.pixel_noise"],
    "implementation.torque_scale": ["implementation.torque_scale"],
    "plant.mount.xyz": ["errors.mount_xyz"],
    "plant.mount.rpy": ["errors.mount_rpy"],
    "plant.camera.focal_length": ["errors.fx", "errors.fy"],
    "plant.camera.fx": ["errors.fx"],
    "plant.camera.fy": ["errors.fy"],
    "plant.camera.principal_point": ["errors.principal_point"],
    "plant.camera.distortion": ["errors.distortion"],
    "plant.target_points": ["errors.point_errors"],
    "plant.friction.viscous": ["errors.viscous"],
    "plant.friction.coulomb": ["errors.coulomb"],
    "target.motion.radius": ["inputs.radius"],
    "plant.mass_scale": ["inputs.mass_scale"],
    "plant.payload.mass": ["inputs.payload"],
    "plant.payload.com": ["inputs.payload"],
    "plant.payload.inertia": ["inputs.payload"],
}
"""Where each drawn quantity goes in the run (the initial state's are checked on their own)."""


def test_every_dispersable_field_has_a_route():
    """The routes of this file and the initial state's fields cover every dispersable field."""
    assert set(ROUTES) | {"robot.q0", "robot.qd0", "observer.error_xyz", "observer.error_rpy"} == set(FIELDS)


@pytest.mark.parametrize("key", sorted(ROUTES))
def test_a_drawn_quantity_reaches_the_setting_it_names_and_no_other(spec, key):
    """A run given one quantity's value (its scenario value moved) differs from the run given nothing
    exactly in that quantity's setting, which holds the value given (to round-off, 1e-12 relative): a
    focal length sets both ``fx`` and ``fy = fx * aspect``, a payload entry the payload's (the others at the
    scenario's), a whole number stays whole, the latency a whole number of control periods."""
    value = nudged(spec, key)
    diff = changed(spec, {key: value})
    assert sorted(diff) == sorted(ROUTES[key]), diff
    after = {name: new for name, (_, new) in diff.items()}
    target = after[ROUTES[key][0]]
    if key == "plant.camera.focal_length":
        aspect = spec.case.loop.camera.aspect
        np.testing.assert_allclose([after["errors.fx"][0], after["errors.fy"][0]], [value[0], value[0] * aspect],
                                   rtol=1e-12)  # fmt: skip
    elif key.startswith("plant.payload."):
        entry = {"mass": slice(0, 1), "com": slice(1, 4), "inertia": slice(4, 10)}[key.rpartition(".")[2]]
        np.testing.assert_allclose(target[entry], value, rtol=1e-12)
    elif key == "implementation.latency":
        rate = spec.case.settings.sampled.control_rate
        assert target[0] == pytest.approx(round(value[0] * rate) / rate, rel=1e-12)
    else:
        np.testing.assert_allclose(target, value, rtol=1e-12)
    if FIELDS[key].integer:
        assert float(target[0]).is_integer()


START = ["robot.q0", "robot.qd0", "observer.error_xyz", "observer.error_rpy"]


@pytest.mark.parametrize("key", START)
def test_a_drawn_start_changes_the_runs_initial_state_only(spec, key):
    """A drawn start changes the run's initial state and nothing else: joint positions ``q0`` the state's
    first ``n`` entries as given and the observer's estimate, which is the first image's at that ``q0`` (the
    scenario's start: its position within 2 mm of the true relative pose, measured 0.3 mm, where the unused
    ``[observer]`` error is 15 mm), joint speeds ``qd0`` the next ``n`` entries as given and nothing more,
    the observer's initial error the estimate alone."""
    n = spec.case.loop.robot.n
    estimate = spec.case.loop.estimate_slice
    value = nudged(spec, key)
    diff = changed(spec, {key: value})
    assert diff and all(name.startswith("state[") for name in diff), sorted(diff)
    entries = {int(name[6:-1]) for name in diff}
    _, s = spec.run_settings(0, {key: value})
    if key == "robot.q0":
        np.testing.assert_array_equal(s[:n], value)
        assert entries - set(range(n)) and entries - set(range(n)) <= set(range(estimate.start, estimate.stop))
        loop = spec.case.loop
        true = np.asarray(cs.Function("g", [loop.q, loop.t], [loop.relative_pose.as_matrix()])(value, 0.0))
        assert np.linalg.norm(s[estimate][:3] - true[:3, 3]) < 2e-3
    elif key == "robot.qd0":
        np.testing.assert_array_equal(s[n : 2 * n], value)
        assert entries == set(range(n, 2 * n))
    else:
        assert entries <= set(range(estimate.start, estimate.stop))


@pytest.mark.parametrize("start", ["image", "scenario"])
def test_drawing_the_scenarios_own_values_gives_the_scenarios_run(start):
    """Every dispersable field drawn at the scenario's own value (all at once, and each alone), with the
    observer started from the first image or from the ``[observer]`` error: the run's settings and initial
    state are the scenario's, bit for bit (each start field alone too: drawing ``qd0`` at its value does
    not restart the observer from another estimate). With the image start the observer's error is not
    drawn (that start does not read it)."""
    data = copy.deepcopy(BASE)
    data["start"]["observer"] = start
    keys = [k for k in FIELDS if start == "scenario" or not k.startswith("observer.")]
    data["dispersion"] = {key: {"dist": "normal", "sigma": 1e-3} for key in keys}
    own = CampaignSpec.of(Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent),
                          TrackingBound(1.0, 180.0, "scenario", ""))  # fmt: skip
    base = {key: own.dispersion.base[key].copy() for key in keys}
    for values in [base, *({key: base[key]} for key in keys)]:
        assert not changed(own, values), sorted(values)


def test_whole_number_fields_are_drawn_whole():
    """The latency jitter (control periods) drawn from a normal, a uniform and a lognormal: every draw is a
    whole number, within the field's domain (at least 0), and the search's values are taken whole too."""
    base = {"implementation.latency_jitter": np.array([2.0])}
    rng = np.random.default_rng(5)
    for d in (DistributionSection(dist="normal", sigma=1.5), DistributionSection(dist="uniform", low=-3, high=3),
              DistributionSection(dist="lognormal", sigma=0.7)):  # fmt: skip
        dispersion = Dispersion({"implementation.latency_jitter": d}, base)
        draws = np.array([dispersion.draw(rng)["implementation.latency_jitter"][0] for _ in range(500)])
        assert np.all(draws == np.round(draws)) and draws.min() >= 0 and len(set(draws)) > 2, d
        assert dispersion.split(np.array([2.6]))["implementation.latency_jitter"][0] == 3.0


def box_of(key: str, base: list[float], **distribution) -> list[tuple[float, float]]:
    return Dispersion({key: DistributionSection(**distribution)}, {key: np.asarray(base, dtype=float)}).box()


def test_the_search_box_is_the_range_each_distribution_draws_from():
    """The worst-case search's box per column: a normal's ``clip`` sigmas about the scenario's value (3
    without a clip), a uniform's ``[base + low, base + high]``, a lognormal's ``base exp(+-3 sigma)``, a
    choice's smallest and largest value entry by entry; each cut to the field's domain (a noise not below
    0, a probability not above 1). To round-off (1e-12)."""
    cases = [
        (box_of("implementation.pixel_noise", [0.5], dist="normal", sigma=0.2, clip=2.0), [(0.1, 0.9)]),
        (box_of("implementation.pixel_noise", [0.5], dist="normal", sigma=0.2), [(0.0, 1.1)]),
        (box_of("plant.mount.xyz", [0.0, 0.1, -0.1], dist="normal", sigma=[0.01, 0.02, 0.03]),
         [(-0.03, 0.03), (0.04, 0.16), (-0.19, -0.01)]),
        (box_of("implementation.frame_drop", [0.6], dist="uniform", low=-0.2, high=0.5), [(0.4, 1.0)]),
        (box_of("plant.mass_scale", [2.0], dist="lognormal", sigma=0.1), [(2 * math.exp(-0.3), 2 * math.exp(0.3))]),
        (box_of("plant.mount.rpy", [0.0, 0.0, 0.0], dist="choice", values=[[0.0, 0.2, -0.1], [0.1, -0.2, 0.3]]),
         [(0.0, 0.1), (-0.2, 0.2), (-0.1, 0.3)]),
    ]  # fmt: skip
    for box, expected in cases:
        assert len(box) == len(expected)
        for (low, high), (a, b) in zip(box, expected, strict=True):
            assert low == pytest.approx(a, abs=1e-12) and high == pytest.approx(b, abs=1e-12), (box, expected)


def test_every_draw_of_a_bounded_distribution_lies_in_the_search_box():
    """Uniform, choice and clipped normal draws (2000 each) all lie in the box the search explores (so the
    search covers every run the campaign can draw), and reach near both ends of it (within 5% of its
    width: the box is not wider than the draws)."""
    rng = np.random.default_rng(8)
    dispersions = [
        Dispersion({"implementation.pixel_noise": DistributionSection(dist="normal", sigma=0.2, clip=1.0)},
                   {"implementation.pixel_noise": np.array([0.5])}),
        Dispersion({"implementation.frame_drop": DistributionSection(dist="uniform", low=-0.3, high=0.2)},
                   {"implementation.frame_drop": np.array([0.1])}),
        Dispersion({"plant.mount.rpy": DistributionSection(dist="choice", values=[[0.0, 0.2, -0.1], [0.1, -0.2, 0.3]])},
                   {"plant.mount.rpy": np.zeros(3)}),
    ]  # fmt: skip
    for d in dispersions:
        (key,) = d.keys
        box = np.array(d.box())
        draws = np.array([d.draw(rng)[key] for _ in range(2000)])
        assert np.all(draws >= box[:, 0] - 1e-12) and np.all(draws <= box[:, 1] + 1e-12), key
        width = box[:, 1] - box[:, 0]
        assert np.all(draws.min(axis=0) <= box[:, 0] + 0.05 * width), key
        assert np.all(draws.max(axis=0) >= box[:, 1] - 0.05 * width), key
