"""``substeps = "auto"``: the sampled simulator integrates each control period in the fewest RK4 steps
(1, 2, 4, ... 16) whose step-doubling estimate of the local error, relative to the state's change over
the period, is at most ``step_error``. Relative to the change, not to the state's size: the state's
entries are of order 1 (quaternions, joint angles) while a period moves them by a few hundredths, so an
error judged against the size would pass with one or two fewer digits right in what the period does."""

from __future__ import annotations

import math
from dataclasses import replace

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis import sampled
from dvfc.analysis.implementation import MAX_AUTO_SUBSTEPS
from dvfc.analysis.pose import integration_cost
from dvfc.analysis.sampled import as_implemented, step_doubling
from dvfc.models.errors import PlantErrors

from helpers import default_from_the_papers_start


def period_maps(increment: np.ndarray, error: np.ndarray) -> tuple[cs.Function, cs.Function]:
    """Two period maps of a 3-entry state with the simulator's signature ``(s, t, e, effort, friction)``:
    the fine one moves the state by ``increment``, the coarse one by ``increment + error``."""
    s, t, e = cs.SX.sym("s", 3), cs.SX.sym("t"), cs.SX.sym("e", 2)
    effort, friction = cs.SX.sym("effort", 1), cs.SX.sym("friction", 3)
    quad = cs.SX.zeros(2)
    inputs = [s, t, e, effort, friction]
    fine = cs.Function("fine", inputs, [s + cs.DM(increment), quad])
    coarse = cs.Function("coarse", inputs, [s + cs.DM(increment) + cs.DM(error), quad])
    return coarse, fine


HELD = (np.array([1.0]), np.zeros(3))
E = np.zeros(2)


@pytest.mark.parametrize("offset", [0.0, 1.0, -3.0, 1e3])
@pytest.mark.parametrize(("increment", "error"), [
    ([1e-2, -3e-3, 0.0], [1e-10, 0.0, -2e-10]),
    ([0.0, 2e-5, 1e-6], [0.0, 3e-10, 0.0]),
    ([0.4, 0.1, -0.2], [0.0, 0.0, 5e-9]),
])  # fmt: skip
def test_the_step_error_estimate_is_the_doubling_difference_over_the_states_change(offset, increment, error):
    """With known period maps (the coarse one off the fine one by ``error``): the estimate is Richardson's
    ``16/15 |x_k - x_2k|`` over the change ``|x_2k - s|`` of the period (infinity norms), and it is the
    same whatever the state's offset from zero (a state of size 1e3 or 0 moving by the same increment has
    the same digits of its increment right). Tolerance: the round-off of the two differences, each within
    ``4 eps`` of the state's size, relative to the smaller of the difference and the change."""
    increment, error = np.asarray(increment), np.asarray(error)
    coarse, fine = period_maps(increment, error)
    s = offset + np.array([0.3, -0.2, 0.1])
    gap, change = np.abs(error).max(), np.abs(increment).max()
    rel = 4 * np.finfo(float).eps * np.abs(s).max() / min(gap, change) + 1e-14
    assert step_doubling(coarse, fine, 0.0, s, E, HELD) == pytest.approx(16 / 15 * gap / change, rel=rel)


def test_a_period_that_changes_nothing_is_exact_only_without_a_difference():
    """The edges of the ratio: no difference between the two maps is no error (0), whatever the change; a
    difference on a period that changes nothing (no change to be relative to) is an infinite error, so
    never accepted; a non-finite difference (a map that blew up) is infinite too."""
    s = np.array([1.0, 0.5, -0.5])
    assert step_doubling(*period_maps(np.array([1e-3, 0.0, 0.0]), np.zeros(3)), 0.0, s, E, HELD) == 0.0
    assert step_doubling(*period_maps(np.zeros(3), np.zeros(3)), 0.0, s, E, HELD) == 0.0
    assert step_doubling(*period_maps(np.zeros(3), np.array([0.0, 1e-15, 0.0])), 0.0, s, E, HELD) == math.inf
    blown = np.array([np.nan, 0.0, 0.0]), np.array([np.inf, 0.0, 0.0])
    for error in blown:
        assert step_doubling(*period_maps(np.array([1e-3, 0.0, 0.0]), error), 0.0, s, E, HELD) == math.inf


@pytest.fixture(scope="module")
def papers_start():
    """The default UR5 as implemented (500 Hz, a 60 Hz camera) from the paper's start over 0.2 s, by the
    virtual machine: its fast transient is what the pilot run probes."""
    loop, s0, settings = default_from_the_papers_start(0.2)
    imp = replace(settings.implementation, camera_rate=60.0, substeps="auto")
    return loop, s0, replace(settings, dt=0.02, implementation=imp)


def with_viscous_friction(papers_start, viscous: float, **implementation):
    """The simulator of :func:`papers_start` with ``viscous`` N m s/rad on every joint of the plant."""
    loop, _, settings = papers_start
    errors = replace(PlantErrors.none(loop.camera, loop.robot.n), viscous=np.full(loop.robot.n, viscous))
    imp = replace(settings.implementation, **implementation)
    return as_implemented(loop, replace(settings, errors=errors, implementation=imp))


def test_auto_asks_for_the_steps_the_states_change_requires_not_its_size(papers_start, monkeypatch):
    """With 3 N m s/rad of viscous friction on every joint (its slope over the wrist's inertia makes the
    held dynamics stiffer), the choice's estimates are, probe by probe, ``16/15 |x_k - x_2k| / |x_2k - s|``
    recomputed from the same maps (1e-12 relative), and the choice is the fewest steps whose largest
    estimate meets ``step_error = 1e-8``. The pilot's states have size ~1.7 and move by 0.02 to 0.4 a
    period, so the same differences over the state's size would have accepted half the steps (8: measured
    6.5e-9 <= 1e-8); with those the error against the period integrated in 64 steps (whose own error is
    16^3 times below 8 steps') is above the target (measured 2.8e-8) while with the chosen steps it is
    within it (measured 1.7e-9)."""
    calls = []
    original = sampled.step_doubling

    def spy(coarse, fine, t, s, e, held, order=4):
        value = original(coarse, fine, t, s, e, held, order)
        (a, *_), (b, *_) = ([np.asarray(v).ravel() for v in f(s, t, e, *held)] for f in (coarse, fine))
        calls.append((coarse, t, s, e, held, value, np.abs(a - b).max(), np.abs(b - s).max(), np.abs(s).max()))
        return value

    monkeypatch.setattr(sampled, "step_doubling", spy)
    sim = with_viscous_friction(papers_start, 3.0)
    choice = sim.settle(papers_start[1]).substeps
    monkeypatch.undo()
    target, k = choice.step_error, choice.substeps
    assert choice.auto and choice.met and k > 1
    by_steps: dict[int, list] = {}  # the coarse map of 1, 2, 4, ... k steps: its estimates at every probe
    for call in calls:
        coarse, *_, value, gap, change, _ = call
        assert value == pytest.approx(16 / 15 * gap / change, rel=1e-12)
        by_steps.setdefault(id(coarse), []).append(call)
    assert len(by_steps) == int(math.log2(k)) + 1 and len({len(group) for group in by_steps.values()}) == 1
    estimates = [max(c[5] for c in group) for group in by_steps.values()]  # 1, 2, 4, ... k steps, in order
    assert estimates[-1] == choice.estimate <= target < estimates[-2]
    lax = [max(16 / 15 * c[6] / c[8] for c in group) for group in by_steps.values()]
    assert lax[-2] <= target  # judged against the state's size, k / 2 steps would have passed
    probes = [c[1:5] for c in next(iter(by_steps.values()))]
    reference = sim._period_function(64)

    def true_error(steps: int) -> float:
        rk4, worst = sim._period_function(steps), 0.0
        for t, s, e, held in probes:
            exact, approx = (np.asarray(f(s, t, e, *held)[0]).ravel() for f in (reference, rk4))
            worst = max(worst, np.abs(approx - exact).max() / np.abs(exact - s).max())
        return worst

    assert true_error(k) <= target < true_error(k // 2)


def test_a_plant_with_a_steeper_friction_gets_more_substeps(papers_start):
    """Viscous friction of 0, 0.3, 1 and 3 N m s/rad on every joint (the friction torque's slope in the joint
    speed): the steeper the slope, the stiffer the held dynamics, and the choice never takes fewer steps
    for a steeper one; without friction one step a period meets the target and with 3 N m s/rad several
    are needed (measured 1, 2, 4, 16), each choice meeting it."""
    s0 = papers_start[1]
    choices = [with_viscous_friction(papers_start, b).settle(s0).substeps for b in (0.0, 0.3, 1.0, 3.0)]
    steps = [c.substeps for c in choices]
    assert all(c.met and c.estimate <= c.step_error for c in choices), choices
    assert steps == sorted(steps) and steps[0] == 1 and steps[-1] >= 4 * steps[0], steps


def test_a_tighter_step_error_never_gets_fewer_substeps(papers_start):
    """The same plant (0.3 N m s/rad) with ``step_error`` 1e-6, 1e-8, 1e-10, 1e-12: the chosen steps never
    fall as the target tightens, and each choice's estimate meets its own target (or the most steps are
    taken and the choice says the target is not met)."""
    s0 = papers_start[1]
    choices = [with_viscous_friction(papers_start, 0.3, step_error=target).settle(s0).substeps
               for target in (1e-6, 1e-8, 1e-10, 1e-12)]  # fmt: skip
    steps = [c.substeps for c in choices]
    assert steps == sorted(steps) and steps[-1] > steps[0], steps
    for c in choices:
        assert c.met == (c.estimate <= c.step_error) and (c.met or c.substeps == MAX_AUTO_SUBSTEPS), c


def test_a_plant_too_stiff_for_the_most_substeps_says_the_target_is_not_met(papers_start):
    """With 10 N m s/rad on every joint even 16 steps a period leave the estimate above 1e-8 (measured 1.4e-7):
    the choice is 16 steps, not met, and its text and record say so (``ABOVE``, ``met: false``), so that a
    run made with it is not taken for one integrated to the target."""
    choice = with_viscous_friction(papers_start, 10.0).settle(papers_start[1]).substeps
    assert choice.substeps == MAX_AUTO_SUBSTEPS and not choice.met and choice.estimate > choice.step_error
    assert "ABOVE step_error" in choice.text and choice.as_dict()["met"] is False


def test_pose_states_the_substeps_a_run_will_use_and_what_it_costs(papers_start):
    """``dvfc pose``'s integration cost: with ``substeps = "auto"`` the choice the runs will make (the settled
    simulator's, from the same start: same steps, same estimate) with its text, and a measured time a run over
    the part of the run it timed (positive, the run as implemented completed); without an implementation,
    CVODES at the run's tolerances."""
    loop, s0, settings = papers_start
    cost = integration_cost(loop, s0, settings)
    choice = as_implemented(loop, settings).settle(s0).substeps
    assert cost["integrator"] == {**choice.as_dict(), "text": choice.text} and cost["integrator"]["chosen"] == "auto"
    assert cost["timed_horizon"] == settings.duration == cost["duration"] and cost["timed_status"] == "ok"
    assert cost["wall_time_per_run"] > 0
    continuous = integration_cost(loop, s0, replace(settings, implementation=None))
    assert continuous["integrator"]["text"].startswith("CVODES") and f"rtol {settings.rtol:g}" in continuous[
        "integrator"]["text"]  # fmt: skip
