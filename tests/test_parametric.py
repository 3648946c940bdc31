"""The design as an input of the simulators' functions: the same numbers as the per-design build,
one build (and one compiled library) for every design of an arm."""

from __future__ import annotations

import re
import tomllib
from dataclasses import replace
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
import tomli_w

import dvfc
from dvfc.analysis import compile as compile_module
from dvfc.analysis import parametric
from dvfc.analysis.case import Case
from dvfc.analysis.linearize import linearize, peak_sinusoid, rest_simulator
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, build, load
from dvfc.analysis.simulate import Simulator, dynamics_function
from dvfc.models.driven import Sinusoid
from dvfc.models.lie import SE3
from dvfc.models.loop import Gains, Weights
from dvfc.models.robot import BUILTIN_CAMERA_FRAME, builtin_urdf

from helpers import CELL, build_loop


def other_design(loop):
    """Another design of the loop: every gain, weight and the reference changed."""
    g = loop.gains
    return replace(
        loop,
        gains=Gains(g.k_xi * 1.3, g.k_c * 0.8, g.k_e * 1.1, None if g.k_i is None else g.k_i * 0.9),
        weights=Weights(*(loop.weights.as_array() * [1.2, 0.9, 1.1, 0.7])),
        reference=SE3.exp([0.01, -0.02, 0.03, 0.02, -0.01, 0.03]) @ loop.reference,
    )


def per_design(monkeypatch: pytest.MonkeyPatch) -> None:
    """From here on the simulators build their functions from the loop with its numbers (the
    build before the design was an input)."""
    monkeypatch.setattr(parametric, "parametrised", lambda loop: False)


TARGET_VELOCITY_ROUNDING = 1e-15
"""How far what is built from the target's velocity (``w``, ``dV/dt``, the quadratures) of the
symbolic loop may be from the numeric loop's: its radius is an entry of ``p``, and CasADi folds
a numeric radius into the constants of the time derivative; measured at most about 1e-17."""
ROUNDED = ("w", "Vdot", "V_a_dot")
"""The signals built from the target's velocity (``V_a_dot``: ``Vdot`` plus fact 20.1's term)."""


def assert_same_run(a, b, tol: float = 0.0) -> None:
    assert a.status == b.status == "ok"
    assert np.array_equal(a.t, b.t)
    for name in a.signals:
        limit = max(tol, TARGET_VELOCITY_ROUNDING) if name in ROUNDED else tol
        assert np.abs(a[name] - b[name]).max() <= limit * max(1.0, np.abs(b[name]).max()), name
    for name in a.integrals:
        assert np.abs(a.integrals[name] - b.integrals[name]).max() <= max(tol, TARGET_VELOCITY_ROUNDING), name


def test_symbolic_loop_evaluates_as_the_numeric_one(rng):
    """At random states, the right-hand side and every signal of the symbolic loop at a design's
    ``p`` equal the numeric loop's bit for bit, for two designs (the reference included), but
    what is built from the target's velocity (:data:`TARGET_VELOCITY_ROUNDING`)."""
    loop, s0, _ = build_loop()
    for design in (loop, other_design(loop)):
        model, p = parametric.symbolic(design), parametric.parameter_vector(design)
        numeric, symbolic = dynamics_function(design), dynamics_function(model)
        signals, signals_p = design.signals_function(), model.signals_function()
        for _ in range(5):
            t, s = rng.uniform(0, 5), s0 + 0.02 * rng.standard_normal(s0.size)
            (ode, _, quad, _), (ode_p, _, quad_p, _) = (numeric(t, s, [], 0.1, []),
                                                        symbolic(t, s, [], np.r_[0.1, p], []))  # fmt: skip
            assert np.array_equal(np.asarray(ode), np.asarray(ode_p))
            assert np.allclose(np.asarray(quad), np.asarray(quad_p), rtol=0, atol=TARGET_VELOCITY_ROUNDING)
            a, b = signals(t, s), signals_p(t, s, p)
            for name, x, y in zip(design.signals, a, b, strict=True):
                tol = TARGET_VELOCITY_ROUNDING if name in ROUNDED else 0.0
                assert np.abs(np.asarray(x) - np.asarray(y)).max(initial=0.0) <= tol, name


def test_a_design_change_reuses_the_symbolic_loop():
    """``replace`` of a loop's design reuses its symbolic loop, and so does the scenario built again (the
    same arm and camera objects); another structure (mode, the sampled loop) gets its own (another arm:
    :func:`test_a_scenario_rebuilt_with_other_numbers_shares_its_arm_camera_and_structure`)."""
    loop, _, _ = build_loop()
    model = parametric.symbolic(loop)
    assert parametric.symbolic(other_design(loop)) is model
    assert parametric.symbolic(replace(loop, mode="image")) is not model
    assert parametric.symbolic(replace(loop, sampled=True)) is not model
    assert parametric.symbolic(build_loop()[0]) is model  # built again: the same Robot and Camera objects
    assert not np.array_equal(parametric.parameter_vector(loop), parametric.parameter_vector(other_design(loop)))


def test_sampled_run_equals_the_per_design_build(monkeypatch):
    """The sampled loop (RK4 periods, image mode, pixel noise) of two designs run with the design
    as an input equals the run built with the design's numbers to 1e-10 relative: round-off (the two builds
    fold the numbers into different operations, one ulp apart at some states; over 0.3 s the runs part by at most
    8e-13 rad/s in ``qd`` and 5e-11 N m in ``tau``, measured)."""
    scenario, base = load(DEFAULT_SCENARIO)
    loop, s0, settings = build(scenario, base)
    settings = replace(settings, jit=False, duration=0.3)
    designs = (loop, other_design(loop))
    runs = [as_implemented(d, settings).run(s0) for d in designs]
    per_design(monkeypatch)
    for run, d in zip(runs, designs, strict=True):
        assert_same_run(run, as_implemented(d, settings).run(s0), 1e-10)


@pytest.mark.slow
def test_compiled_once_for_two_designs(monkeypatch):
    """Compiled (the shared cache, nothing loaded in this process): the second design of the default
    scenario loads nothing new and its runs use the first's libraries (one for the right-hand side, one
    for the signals, one for the control period); the sampled runs equal the per-design build's to 1e-9
    relative (it folds the design, ``K_I`` included, into constants: round-off, 1.0e-10 at most
    measured); the continuous runs to 1e-8 (their right-hand sides agree to round-off, and the Jacobians
    CVODES's Newton steps use, forward differences of each, by that round-off over the step: each run is within its
    own 1e-10 tolerance)."""
    monkeypatch.setattr(compile_module, "_loaded", {})
    scenario, base = load(DEFAULT_SCENARIO)
    loop, s0, settings = build(scenario, base)
    settings = replace(settings, jit=True, duration=2.0)
    designs = (loop, other_design(loop))
    builds: list[Path] = []
    build_all = compile_module._build_all
    monkeypatch.setattr(compile_module, "_build_all", lambda b, c: builds.extend(x[-1] for x in b) or build_all(b, c))

    def both(design):
        return Simulator(replace(design, plant=None), settings).run(s0), as_implemented(design, settings).run(s0)

    first = both(designs[0])
    libraries = sorted(builds)
    second = both(designs[1])
    assert sorted(builds) == libraries and all(library.exists() for library in libraries)
    assert sorted(p.name.split("-")[0] for p in libraries) == ["dvfc_camera", "dvfc_dynamics", "dvfc_last",
                                                                "dvfc_period", "signals", "signals"]  # fmt: skip
    per_design(monkeypatch)
    for (continuous, sampled), design in zip((first, second), designs, strict=True):
        reference_continuous, reference_sampled = both(design)
        assert_same_run(sampled, reference_sampled, 1e-9)
        assert np.abs(continuous["state"] - reference_continuous["state"]).max() < 1e-8


def test_a_run_from_rest_takes_its_sinusoid_as_an_input(monkeypatch):
    """The run from rest under the linearisation's worst sinusoid (the lower bound, Theorem 2 from rest) with the
    sinusoid's numbers and the design entries of ``p`` equals the run built with its numbers, to the round-off of
    what is built from the target's velocity; another sinusoid and another design of the arm reuse the one
    symbolic driven loop."""
    loop, s0, _ = build_loop()
    lin = linearize(loop, s0[: loop.robot.n])
    sinusoid = peak_sinusoid(lin)
    simulator, s_eq = rest_simulator(loop, lin, sinusoid, 0.5)
    other = Sinusoid(0.5 * sinusoid.sin_part, 2.0 * sinusoid.cos_part, 3.0)
    model = simulator.model
    assert model.parameters is not None and simulator.design[0][-1] == sinusoid.omega
    assert rest_simulator(other_design(loop), lin, other, 0.5)[0].model is model
    runs = [simulator.run(s_eq), rest_simulator(loop, lin, other, 0.5)[0].run(s_eq)]
    per_design(monkeypatch)
    for run, drive in zip(runs, (sinusoid, other), strict=True):
        reference = rest_simulator(loop, lin, drive, 0.5)[0]
        assert reference.model.parameters is None
        assert_same_run(run, reference.run(s_eq), 1e-12)


def test_a_planned_start_takes_its_start_duration_and_hold_as_inputs(monkeypatch):
    """The ``ur5_cell`` loop as implemented with its planned start (docs/math.md, fact 16) and integral action
    (fact 20): with the plan's start pose, duration and hold (the latency sets it) and the time ``z_I`` starts
    from entries of ``p``, another latency, start, duration and integral start reuse the one symbolic loop, and
    each run equals the run built with those numbers to 1e-9 relative (that build folds them into constants:
    round-off)."""
    case = dvfc.load(CELL)
    loop, s0 = case.loop, case.s0
    settings = replace(case.settings, jit=False, duration=0.3)
    plan = loop.plan
    assert plan is not None and plan.hold > 0 and loop.integral and loop.integral_start > settings.duration
    other = replace(loop, plan=replace(plan, start=SE3.exp([0.01, 0.0, -0.01, 0.02, 0.0, 0.01]) @ plan.start,
                                       duration=1.5, hold=2 * plan.hold), integral_start=0.1)  # fmt: skip
    model = parametric.symbolic(replace(loop, sampled=True))
    assert parametric.symbolic(replace(other, sampled=True)) is model
    runs = [as_implemented(design, settings).run(s0) for design in (loop, other)]
    assert not np.allclose(runs[0]["state"], runs[1]["state"])  # the plan's numbers reach the run
    per_design(monkeypatch)
    for run, design in zip(runs, (loop, other), strict=True):
        assert_same_run(run, as_implemented(design, settings).run(s0), 1e-9)


def test_a_scenario_rebuilt_with_other_numbers_shares_its_arm_camera_and_structure(tmp_path):
    """One model per arm: the default with other gains (a synthesis' candidate) is built on the same
    :class:`Robot` and :class:`Camera` objects, so its symbolic structure is the first's; an arm whose URDF
    text changed (a link 10% heavier, same file), or another focal length, is built anew and its numbers are
    its own."""
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(builtin_urdf("ur5").read_text())
    first = Case.load(write_scenario(tmp_path, urdf))
    other = first.with_gains(k_e=11.0)
    assert other.loop.robot is first.loop.robot and other.loop.camera is first.loop.camera
    assert parametric.symbolic(other.loop) is parametric.symbolic(first.loop)
    mass = lambda case: np.asarray(cs.Function("m", [case.loop.robot.q], [case.loop.robot.mass_matrix])(case.s0[:6]))  # noqa: E731
    text = urdf.read_text()
    heavier = re.sub(r'(<link name="forearm_link">.*?<mass value=")([0-9.]+)', lambda m: f"{m[1]}{1.1 * float(m[2])!r}",
                     text, count=1, flags=re.S)  # fmt: skip
    assert heavier != text
    urdf.write_text(heavier)
    edited = Case.load(write_scenario(tmp_path, urdf))
    assert edited.loop.robot is not first.loop.robot
    assert np.abs(mass(edited) - mass(first)).max() > 1e-3
    assert edited.loop.robot.mass_bounds.m_hi > first.loop.robot.mass_bounds.m_hi
    zoomed = first.with_scenario(first.scenario.model_copy(update={"camera": first.scenario.camera.model_copy(
        update={"focal_length": 1.1 * first.scenario.camera.focal_length})}))  # fmt: skip
    assert zoomed.loop.camera is not first.loop.camera
    assert zoomed.loop.camera.focal_length == pytest.approx(1.1 * first.loop.camera.focal_length)


def write_scenario(folder: Path, urdf: Path) -> Path:
    """The default scenario on the arm of the URDF file ``urdf`` (the UR5's camera link), written in ``folder``."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["robot"].pop("model")
    data["robot"] |= {"urdf": str(urdf), "camera_frame": BUILTIN_CAMERA_FRAME["ur5"]}
    path = folder / "arm.toml"
    path.write_text(tomli_w.dumps(data))
    return path
