"""Software in the loop: the controller program (:mod:`dvfc.analysis.controller`) driving the plant.

Between two control samples the plant (33) alone is integrated with the torque the program
returned held (the sampled simulator's own period: its integrator, substeps, the plant's friction
and masses); at each sample the program receives what a robot gives it: the sampled ``q_k``,
``qd_k`` and, when one arrives, an image captured earlier. The images follow the implementation's
schedule and draws exactly as :class:`~dvfc.analysis.sampled.SampledSimulator` makes them (the same
captures, arrivals, pixel noise, quantisation, outliers and frame drops from the same seeds, the
simulator's camera): the features the controller reads, made from the plant's state at the capture.
The sampled simulator runs the same program's update at each sample
(:func:`~dvfc.analysis.controller.sample_update`), so with the program's Python step the two are
one loop: what this adds is the program as it is called (its state, its ring of estimates, its
checks) and any other step with its signature, the compiled C one (``dvfc export --check``).

A feature behind the camera or outside the image at a capture ends the run there with the sampled
simulator's own stop (:class:`~dvfc.analysis.simulate.Stop`: ``behind_camera`` or ``out_of_view``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.controller import Controller
from dvfc.analysis.sampled import SampledSimulator, as_implemented, sampled_simulator
from dvfc.analysis.simulate import RunStatus, Stop

StepFunction = Callable[
    [np.ndarray, float, np.ndarray, np.ndarray, np.ndarray | None, int], tuple[np.ndarray, np.ndarray]
]
"""``(state, t, q, qd, features or None, capture step) -> (tau, next state)``: :meth:`Controller.step`."""


@dataclass(frozen=True)
class SilRun:
    """A software-in-the-loop run: per control sample ``k < K`` what the program received and
    returned, and the plant's joints at every sample ``k <= K``.

    ``captures[k]`` is the capture sample of the image handed over at ``k`` (-1: none) and
    ``features[k]`` its features (zeros when none); ``states`` the program's state before each step."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    captures: np.ndarray
    features: np.ndarray
    states: np.ndarray
    status: RunStatus
    message: str


class Plant:
    """The plant of a case's loop as implemented and its camera, one control period at a time: the
    sampled simulator's own (:meth:`~dvfc.analysis.sampled.SampledSimulator.plant_period`, its
    integrator and substeps; :meth:`~dvfc.analysis.sampled.SampledSimulator.observe`), driven by a
    controller outside it."""

    def __init__(self, case: Case, simulator: SampledSimulator) -> None:
        self.n = case.loop.robot.n
        self.simulator = simulator
        self._period = simulator.plant_period(case.s0)
        self._rest = np.array(case.s0[2 * self.n :], dtype=float)  # the state's estimate (and z_I): not the plant's

    def advance(self, t: float, joints: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """``[q; qd]`` one control period after ``(t, joints)`` with ``tau`` held."""
        return self._period(t, np.concatenate([joints, self._rest]), tau)[: 2 * self.n]

    def image(self, t: float, q: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, Stop | None]:
        """The features the controller reads from an image at ``(t, q)`` with pixel ``noise``, and
        the stop when the image is lost (a point behind the camera or outside the image), or None."""
        _, measured, lost = self.simulator.observe(t, np.concatenate([q, np.zeros(self.n), self._rest]), noise)
        return measured, lost


def software_in_the_loop(
    case: Case, step: StepFunction | None = None, *, duration: float | None = None, controller: Controller | None = None
) -> SilRun:
    """The case's plant driven by its controller program sample by sample over ``duration``
    (default: the scenario's), from the case's initial state; ``step`` replaces the program's
    Python step (the compiled C step, say) with the same inputs and state."""
    imp = case.settings.implementation
    if imp is None:
        raise ValueError("software in the loop needs an [implementation]")
    controller = controller or Controller(case)
    step = step or controller.step
    simulator = sampled_simulator(case.loop, case.settings)
    plant = Plant(case, simulator)
    n, m, h = controller.n, controller.m, imp.period
    steps = round((case.settings.duration if duration is None else duration) * imp.control_rate)
    rng = np.random.default_rng(imp.seed)
    faults = np.random.default_rng((imp.seed % 2**64, 1))
    captures, arrivals = imp.arrivals(imp.capture_steps(steps), faults)
    noise = simulator.noise(len(captures), rng, faults)  # of each capture, in capture order
    joints = np.array(case.s0[: 2 * n], dtype=float)
    state = controller.initial_state()
    record: dict[str, list] = {key: [] for key in ("q", "qd", "tau", "captures", "features", "states")}
    taken: dict[int, np.ndarray] = {}  # the features of each capture not handed over yet
    stop, j = Stop(), 0
    for k in range(steps):
        t = k * h
        record["q"].append(joints[:n])
        record["qd"].append(joints[n:])
        while j < len(captures) and captures[j] == k:  # the image captured now, drawn in capture order
            taken[k], lost = plant.image(t, joints[:n], noise[j])
            stop = stop if lost is None else lost
            j += 1
        if stop.status is not RunStatus.OK:
            break
        arriving = np.flatnonzero(arrivals == k)
        capture = int(captures[arriving[0]]) if len(arriving) else -1
        features = taken.pop(capture) if capture >= 0 else None
        record["captures"].append(capture)
        record["features"].append(np.zeros(2 * m) if features is None else features)
        record["states"].append(state)
        tau, state = step(state, t, joints[:n], joints[n:], features, capture)
        record["tau"].append(np.asarray(tau, dtype=float))
        joints = plant.advance(t, joints, np.asarray(tau, dtype=float))
        for c in [c for c in taken if c <= k - controller.layout.ring]:  # never to arrive (dropped)
            del taken[c]
    else:
        record["q"].append(joints[:n])
        record["qd"].append(joints[n:])
    count = len(record["tau"])
    return SilRun(
        t=np.arange(len(record["q"])) * h,
        q=np.array(record["q"]),
        qd=np.array(record["qd"]),
        tau=np.array(record["tau"]).reshape(count, n),
        captures=np.array(record["captures"], dtype=int),
        features=np.array(record["features"]).reshape(count, 2 * m),
        states=np.array(record["states"]).reshape(count, controller.layout.size),
        status=stop.status,
        message=stop.message,
    )


@dataclass(frozen=True)
class Comparison:
    """A software-in-the-loop run against the sampled simulator's run of the same case (the same
    images, noise and plant), at the simulator's output samples: the largest differences of the joint
    positions (rad), speeds (rad/s) and held torques (N m), and the largest torque of the run. A
    measurement: 0 when the step is the program's Python one (the same operations, docs/math.md,
    fact 22)."""

    samples: int
    max_position_difference: float
    max_speed_difference: float
    max_torque_difference: float
    peak_torque: float


def compare_with_sampled(case: Case, run: SilRun) -> Comparison:
    """``run`` against :class:`~dvfc.analysis.sampled.SampledSimulator` over the same horizon."""
    imp = case.settings.sampled
    duration = len(run.tau) * imp.period
    trajectory = as_implemented(case.loop, replace(case.settings, duration=duration)).run(case.s0)
    n = case.loop.robot.n
    steps = np.round(trajectory.t * imp.control_rate).astype(int)
    kept = steps < len(run.tau)
    states, steps = trajectory.signals["state"][kept], steps[kept]
    torque = trajectory.signals["tau_applied"][kept]
    return Comparison(
        samples=int(kept.sum()),
        max_position_difference=float(np.abs(states[:, :n] - run.q[steps]).max()),
        max_speed_difference=float(np.abs(states[:, n : 2 * n] - run.qd[steps]).max()),
        max_torque_difference=float(np.abs(torque - run.tau[steps]).max()),
        peak_torque=float(np.abs(run.tau).max()),
    )
