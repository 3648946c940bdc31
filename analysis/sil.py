"""Software in the loop: the controller program (:mod:`dvfc.analysis.controller`) driving the plant.

Between two control samples the plant (33) alone is integrated with the torque the program
returned held (RK4, the implementation's ``substeps`` per period, the plant's friction as in
:mod:`dvfc.analysis.sampled`); at each sample the program receives what a robot gives it: the
sampled ``q_k``, ``qd_k`` and, when one arrives, an image captured earlier. The images follow the
implementation's schedule and draws exactly as :class:`~dvfc.analysis.sampled.SampledSimulator`
makes them (the same captures, arrivals, pixel noise, quantisation, outliers and frame drops from
the same seeds, the same camera model): the features the controller reads, made from the plant's
state at the capture. The difference from the sampled simulator is the controller itself: there
the observer (12) is integrated with the plant on the continuous ``qd(t)`` and ``u_e(t)``; here it
steps on the samples (docs/math.md, fact 22).

A feature behind the camera or outside the image at a capture ends the run there (status
``out_of_view``), as in the sampled simulator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import casadi as cs
import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.compile import Buffered, compiled
from dvfc.analysis.controller import Controller
from dvfc.analysis.sampled import SampledSimulator, as_implemented
from dvfc.models.errors import PlantErrors, controller_features, friction_torque, true_features

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
    status: str
    message: str


class Plant:
    """The plant of a case's loop as implemented, one control period at a time: ``[q; qd]`` after
    ``h`` with a torque held (RK4), and the image the camera makes at ``(t, q)``."""

    def __init__(self, case: Case, simulator: SampledSimulator) -> None:
        settings, imp = case.settings, case.settings.implementation
        loop = replace(case.loop, plant=settings.plant, sampled=True)
        n = loop.robot.n
        self.errors = settings.errors or PlantErrors.none(loop.camera, n)
        joints, held, t = cs.SX.sym("x", 2 * n), cs.SX.sym("tau", n), cs.SX.sym("t")
        rate = cs.Function(
            "plant_rate", [loop.t, cs.vertcat(loop.q, loop.qd), loop.hold], [cs.vertcat(loop.qd, loop.qdd)]
        )
        friction = cs.DM(self.errors.friction_vector())
        step = imp.period / imp.substeps

        def f(time: cs.SX, x: cs.SX) -> cs.SX:
            torque = held - friction_torque(x[n:], friction, n)
            return rate(time, x, cs.vertcat(torque, cs.DM.zeros(loop.task_dim)))

        x = joints
        for i in range(imp.substeps):  # the classical RK4, as the sampled simulator's
            t0 = t + i * step
            k1 = f(t0, x)
            k2 = f(t0 + step / 2, x + step / 2 * k1)
            k3 = f(t0 + step / 2, x + step / 2 * k2)
            k4 = f(t0 + step, x + step * k3)
            x = x + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        period = cs.Function("dvfc_plant_period", [t, joints, held], [x])
        self._period = Buffered(compiled(period, jacobian=False, level="-O2") if settings.jit else period)
        noise = cs.SX.sym("noise", 2 * loop.camera.m)
        if settings.errors is None:
            f_true = loop.features
            measured = simulator._quantized(f_true + noise)
            depths = loop.camera.depths(loop.relative_pose)
        else:
            vector = cs.DM(self.errors.camera_vector(loop.camera))
            f_true, about_nominal, depths = true_features(loop.camera, loop.relative_pose, vector)
            measured = controller_features(loop.camera, simulator._quantized(about_nominal + noise))
        self.window = simulator._window
        self._camera = Buffered(cs.Function("dvfc_sil_camera", [loop.t, loop.q, noise], [measured, f_true, depths]))

    def advance(self, t: float, joints: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """``[q; qd]`` one control period after ``(t, joints)`` with ``tau`` held."""
        return self._period(t, joints, tau)[0].ravel()

    def image(self, t: float, q: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, str | None]:
        """The features the controller reads from an image at ``(t, q)`` with pixel ``noise``, and
        why the image is lost (a point behind the camera or outside the image), or None."""
        measured, f, depth = (v.ravel() for v in self._camera(t, q, noise))
        if np.any(depth <= 0):
            return measured, f"a feature point is behind the camera at t = {t:.4g} s"
        if self.window is not None and (np.any(f < self.window[0]) or np.any(f > self.window[1])):
            return measured, f"a feature left the image at t = {t:.4g} s"
        return measured, None


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
    simulator = as_implemented(case.loop, case.settings)
    plant = Plant(case, simulator)
    n, m, h = controller.n, controller.m, imp.period
    steps = round((case.settings.duration if duration is None else duration) * imp.control_rate)
    rng = np.random.default_rng(imp.seed)
    faults = np.random.default_rng((imp.seed % 2**64, 1))
    captures, arrivals = imp.arrivals(imp.capture_steps(steps), faults)
    image_mode = case.loop.mode == "image"
    joints = np.array(case.s0[: 2 * n], dtype=float)
    state = controller.initial_state()
    record = {key: [] for key in ("q", "qd", "tau", "captures", "features", "states")}
    taken: dict[int, np.ndarray] = {}  # the features of each capture not handed over yet
    status, message, j = "ok", "", 0
    for k in range(steps):
        t = k * h
        record["q"].append(joints[:n])
        record["qd"].append(joints[n:])
        while j < len(captures) and captures[j] == k:  # the image captured now, drawn in capture order
            noise = imp.pixel_noise * rng.standard_normal(2 * m) if image_mode else np.zeros(2 * m)
            if imp.outlier_probability > 0:
                noise = noise + imp.outliers(2 * m, faults)
            taken[k], lost = plant.image(t, joints[:n], noise)
            if lost is not None:
                status, message = "out_of_view", lost
            j += 1
        if status != "ok":
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
        status=status,
        message=message,
    )


@dataclass(frozen=True)
class Comparison:
    """A software-in-the-loop run against the sampled simulator's run of the same case (the same
    images, noise and plant), at the simulator's output samples: the largest differences of the joint
    positions (rad), speeds (rad/s) and held torques (N m), and the largest torque of the run. A
    measurement; docs/math.md, fact 22 says where the difference comes from (the observer stepped
    on the samples)."""

    samples: int
    max_position_difference: float
    max_speed_difference: float
    max_torque_difference: float
    peak_torque: float


def compare_with_sampled(case: Case, run: SilRun) -> Comparison:
    """``run`` against :class:`~dvfc.analysis.sampled.SampledSimulator` over the same horizon."""
    imp = case.settings.implementation
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
