"""Benchmark: the default scenario, 10 s simulated.

Compares, in one run, the CVODES simulation of the continuous loop with the right-hand
side compiled to C, the same with CasADi's virtual machine, and a plain baseline: scipy's
``solve_ivp`` (LSODA) calling a NumPy right-hand side of the same model (the CasADi
function evaluated point by point) at the same tolerances. Then the loop as implemented
(the scenario's ``[implementation]``: 500 Hz torques held, 60 Hz camera), integrated
from sample to sample by RK4 and by CVODES, against the compiled continuous run, with the
largest difference of the RK4 run's states from the CVODES run's. Last, a gain change end
to end (the scenario built and run as implemented, compiled) against a first run that
compiles into an empty cache. Prints the times, the ratios and the real-time factors.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import replace

import numpy as np
from scipy.integrate import solve_ivp
from timing import best_of

from dvfc.analysis.sampled import SampledSimulator, as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build, load
from dvfc.analysis.simulate import Simulator
from dvfc.models.errors import PlantErrors


def main() -> None:
    scenario, base = load(DEFAULT_SCENARIO)
    loop, s0, settings = build(scenario, base)
    settings = replace(settings, duration=10.0)
    horizon = settings.duration

    start = time.perf_counter()
    compiled = Simulator(loop, replace(settings, jit=True))
    setup = time.perf_counter() - start
    vm = Simulator(loop, replace(settings, jit=False))

    t_compiled = best_of(lambda: compiled.run(s0))
    t_vm = best_of(lambda: vm.run(s0))
    imp = settings.implementation
    if imp is not None:
        sampled = {
            method: as_implemented(loop, replace(settings, jit=True, implementation=replace(imp, integrator=method)))
            for method in ("rk4", "cvodes")
        }
        t_sampled = {method: best_of(lambda s=s: s.run(s0)) for method, s in sampled.items()}
        rk4, cvodes = (sampled[m].run(s0)["state"] for m in ("rk4", "cvodes"))

    rhs = loop.rhs_function()

    def f(t, s):
        ode, _ = rhs(t, s)
        return np.asarray(ode).ravel()

    grid = np.arange(round(horizon / settings.dt) + 1) * settings.dt

    def baseline():
        sol = solve_ivp(f, (0.0, horizon), s0, method="LSODA", t_eval=grid, rtol=settings.rtol, atol=settings.atol)
        assert sol.success, sol.message

    t_scipy = best_of(baseline, repeat=1)
    end_compiled = compiled.run(s0)["state"][-1]
    sol = solve_ivp(f, (0.0, horizon), s0, method="LSODA", rtol=settings.rtol, atol=settings.atol)
    agreement = np.abs(sol.y[:, -1] - end_compiled).max()

    print(f"default scenario, {horizon:g} s simulated, rtol = atol = {settings.rtol:g}")
    print(f"  compile (or load from cache)     {setup:8.3f} s")
    for label, seconds in (
        ("CVODES, compiled RHS", t_compiled),
        ("CVODES, CasADi virtual machine", t_vm),
        ("scipy solve_ivp LSODA + NumPy", t_scipy),
    ):
        print(f"  {label:32s} {seconds * 1e3:8.1f} ms   real-time factor {horizon / seconds:7.0f}x")
    print(f"  ratio scipy / compiled           {t_scipy / t_compiled:8.1f}x")
    print(f"  ratio VM / compiled              {t_vm / t_compiled:8.1f}x")
    print(f"  final-state agreement, scipy vs CVODES: {agreement:.2e}")
    if imp is not None:
        print(f"  sampled loop: {imp.control_rate:g} Hz control, {imp.camera_rate:g} Hz camera, "
              f"{imp.latency * 1e3:g} ms latency, compiled")
        for method, seconds in t_sampled.items():
            print(f"    from sample to sample by {method:6s}     {seconds * 1e3:8.1f} ms   real-time factor "
                  f"{horizon / seconds:7.1f}x   ratio to the continuous run {seconds / t_compiled:5.1f}x")
        print(f"    ratio CVODES / RK4               {t_sampled['cvodes'] / t_sampled['rk4']:8.1f}x")
        print(f"    max |state RK4 - state CVODES|   {np.abs(rk4 - cvodes).max():.2e}")
        faulty = with_every_error(loop, settings)
        t_faulty = best_of(lambda: faulty.run(s0))
        print(f"    every plant error and fault on   {t_faulty * 1e3:8.1f} ms   ratio to the nominal RK4 run "
              f"{t_faulty / t_sampled['rk4']:5.2f}x (at most 1.5x; the friction by {faulty.substeps.method})")
    first, change = gain_change(scenario, base)
    print(f"  gain change end to end (build + compiled run as implemented, {horizon:g} s), empty cache")
    print(f"    first run, compiling             {first:8.2f} s")
    print(f"    gain change, no compilation      {change:8.2f} s   (target under 2 s)   ratio first / change "
          f"{first / change:6.1f}x")


def gain_change(scenario: Scenario, base) -> tuple[float, float]:
    """Wall seconds of the default scenario built and run as implemented (10 s, compiled) into a
    fresh ``DVFC_CACHE`` (the first run compiles), then of the same with ``k_c`` and ``k_xi``
    changed (another design of the same arm: nothing compiles)."""

    def build_and_run(scenario: Scenario) -> float:
        start = time.perf_counter()
        loop, s0, settings = build(scenario, base)
        traj = as_implemented(loop, replace(settings, jit=True, duration=10.0)).run(s0)
        assert traj.status == "ok", traj.message
        return time.perf_counter() - start

    gains = scenario.gains.model_copy(update={"k_c": (1.2 * np.asarray(scenario.gains.k_c)).tolist(), "k_xi": (0.9 * np.asarray(scenario.gains.k_xi)).tolist()})  # noqa: E501
    saved = os.environ.get("DVFC_CACHE")
    with tempfile.TemporaryDirectory() as cache:
        os.environ["DVFC_CACHE"] = cache
        try:
            return build_and_run(scenario), build_and_run(scenario.model_copy(update={"gains": gains}))
        finally:
            if saved is None:
                del os.environ["DVFC_CACHE"]
            else:
                os.environ["DVFC_CACHE"] = saved


def with_every_error(loop, settings) -> SampledSimulator:
    """The sampled loop with a mount error, other intrinsics and distortion, point errors,
    friction on every joint, latency jitter, frame drops and outliers (compiled; the dry friction integrated by
    ROS34PW2, ``integrator = "auto"``: docs/math.md, fact 28)."""
    n = loop.robot.n
    errors = replace(PlantErrors.none(loop.camera, n), mount_xyz=np.array([1e-3, -1e-3, 2e-3]),
                     mount_rpy=np.radians([0.6, -0.4, 0.3]), fx=815.0, fy=812.0, principal_point=np.array([650, 505.0]),
                     distortion=np.array([-0.1, 0.02, 1e-3, -1e-3, 0.0]), point_errors=np.full((loop.camera.m, 3), 5e-4),  # noqa: E501
                     viscous=np.full(n, 0.2), coulomb=np.full(n, 0.1))  # fmt: skip
    imp = replace(settings.implementation, integrator="auto", latency_jitter=2, frame_drop=0.05,
                  outlier_probability=0.01, outlier_size=20.0)  # fmt: skip
    return as_implemented(loop, replace(settings, jit=True, implementation=imp, errors=errors))


if __name__ == "__main__":
    main()
