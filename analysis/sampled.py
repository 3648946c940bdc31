"""The loop as a digital controller runs it: sampled torques, a camera with its own rate and
latency, pixel noise and quantisation, actuator saturation, joint-speed limits; the controller is
the program's (:mod:`dvfc.analysis.controller`).

At each sample ``t_k = k h`` the controller is :func:`~dvfc.analysis.controller.sample_update`,
the one definition the exported program runs too (docs/math.md, fact 22). It

1. takes the image captured ``latency`` earlier, if one arrives now: the actual features
   ``f`` (11) plus Gaussian pixel noise, rounded to the pixel grid, turned into ``e_e`` by
   (21) with the estimate ``gbar`` of the capture time and dropped, as the program drops it,
   when that ``e_e`` is not finite or not a possible estimation error
   (:func:`~dvfc.analysis.controller.image_update`; ``e_e = "image"``), or the exact ``e_e``
   (15) of the capture time (``e_e = "ideal"``);
2. evaluates the law (35), (42) with the latest ``e_e`` (held until the next image) and
   clips it at the URDF's effort limits when ``saturate`` is on;
3. steps the observer by the exact flow of (12) over the period with its inputs held, ``V_k =
   J_b(q_k) qd_k`` (34) and ``U_k = u_e(t_k)`` (42): ``gbar_(k+1) = exp(-h hat(V_k)) gbar_k
   exp(h hat(U_k))`` (22.1); before the first image arrives ``e_e = 0``;
4. with integral action (docs/math.md, fact 20), updates ``z_I <- z_I + h xi_k`` with the
   sample's ``xi`` (from ``integral_start`` on), ``z_I`` held over the period like the torque;
   anti-windup by conditional integration: joint ``i`` is not integrated at a sample whose
   commanded torque exceeds its effort limit when the update ``-K_I,i h xi_i`` would push the
   command further beyond it (``tau_i > effort_i`` and ``xi_i < 0``, or ``tau_i < -effort_i`` and
   ``xi_i > 0``).

Between two samples the torque and the observer's inputs are held (zero-order hold) and the plant,
the observer along its held flow (whose end is step 3's) and the quadratures are integrated over
exactly ``[t_k, t_k + h]``: the sample-and-hold is not approximated by a fast continuous loop.
Over one period the held dynamics are smooth and not stiff (no feedback acts inside it), so the
default integrator is the classical Runge-Kutta method (RK4, error ``O(h^4)``, four right-hand
sides per step), in the fewest steps a period that meet a local error target (``substeps =
"auto"``, :meth:`SampledSimulator.choose_substeps`) or in a given number; CVODES restarted at
every sample, error-controlled at the run's tolerances, is the reference (``integrator =
"cvodes"``). Images are captured at the first control sample at or after each camera tick
``j / camera_rate``.

The samples between two image arrivals share one held ``e_e``, so they are integrated in
one call (the period's map accumulated over them, :meth:`casadi.Function.mapaccum`); a
capture whose feature has left the image is found when its image would arrive, and the
run is cut back to the capture.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import casadi as cs
import numpy as np

from dvfc.analysis.compile import Buffered, compiled, compiled_together
from dvfc.analysis.controller import image_update, sample_update
from dvfc.analysis.implementation import MAX_AUTO_SUBSTEPS, Method, SubstepChoice
from dvfc.analysis.output import interrupted
from dvfc.analysis.parametric import parameter_vector
from dvfc.analysis.rosenbrock import ORDER, w_step
from dvfc.analysis.simulate import RunStatus, Settings, Simulator, Stop, Trajectory, joint_peaks
from dvfc.models.errors import (
    PlantErrors,
    camera_size,
    controller_features,
    friction_slope,
    friction_torque,
    seen_through,
    true_features,
)
from dvfc.models.loop import QUADRATURES, ClosedLoop
from dvfc.models.robot import JointLimits


def as_implemented(loop: ClosedLoop, settings: Settings) -> Simulator:
    """The simulator of the loop as it runs on the robot: the plant of ``settings`` (the law
    keeps ``loop``'s model), sampled by :class:`SampledSimulator` when ``settings`` has an
    implementation, else continuous; a feature leaving the image ends the run."""
    if settings.implementation is None:
        return Simulator(replace(loop, plant=settings.plant), replace(settings, view=True))
    return sampled_simulator(loop, settings)


def sampled_simulator(loop: ClosedLoop, settings: Settings) -> SampledSimulator:
    """:func:`as_implemented` for settings with an implementation (a ``ValueError`` without). The plant is the
    settings' or, without one, the law's arm, as a plant whose masses are inputs (mass scale 1, no payload): one
    compiled structure serves the nominal plant and every mass a payload, a margin or a campaign gives it."""
    settings = replace(settings, view=True, implementation=settings.sampled)
    plant = loop.robot if settings.plant is None else settings.plant
    return SampledSimulator(replace(loop, plant=plant, sampled=True), settings)


def robot_limits(loop: ClosedLoop, settings: Settings) -> JointLimits:
    """The joint limits a run is held to: the URDF's, with the implementation's torque scale."""
    imp = settings.implementation
    return loop.robot.limits if imp is None else imp.limits(loop.robot.limits)


def position_ratio(q_min: np.ndarray, q_max: np.ndarray, limits: JointLimits) -> np.ndarray:
    """Per joint, how far the range ``[q_min, q_max]`` reaches toward the position limits: the
    largest distance from the middle of ``[lower, upper]`` over half its width (1 at a limit,
    above 1 beyond it); 0 for a joint without both limits (a continuous joint)."""
    bounded = np.isfinite(limits.lower) & np.isfinite(limits.upper)
    lower, upper = np.where(bounded, limits.lower, -1.0), np.where(bounded, limits.upper, 1.0)
    middle, half = (upper + lower) / 2, np.maximum((upper - lower) / 2, np.finfo(float).tiny)
    return np.where(bounded, np.maximum(q_max - middle, middle - q_min) / half, 0.0)


def limit_record(traj: Trajectory, limits: JointLimits) -> dict:
    """Per joint: the peak commanded and applied torque, the peak speed and the range of
    positions along the run (:func:`dvfc.analysis.simulate.joint_peaks`: over every control
    sample of a sampled run, the output grid of a continuous one, up to a stop), against the
    URDF's effort, velocity and position limits (JSON-ready; ``inf`` limits as None)."""
    peaks = joint_peaks(traj)
    finite = lambda a: [None if not math.isfinite(v) else float(v) for v in a]  # noqa: E731
    q_min, q_max = peaks["q_min"], peaks["q_max"]
    return {
        "peak_torque": peaks["tau_applied"].tolist(),
        "peak_torque_commanded": peaks["tau"].tolist(),
        "effort_limit": finite(limits.effort),
        "peak_speed": peaks["qd"].tolist(),
        "velocity_limit": finite(limits.velocity),
        "position_range": np.column_stack([q_min, q_max]).tolist(),
        "position_limit": [finite(pair) for pair in zip(limits.lower, limits.upper, strict=True)],
        "torque_ratio": (peaks["tau_applied"] / limits.effort).tolist(),
        "torque_commanded_ratio": (peaks["tau"] / limits.effort).tolist(),
        "speed_ratio": (peaks["qd"] / limits.velocity).tolist(),
        "position_ratio": position_ratio(q_min, q_max, limits).tolist(),
        "within_effort": bool(np.all(peaks["tau_applied"] <= limits.effort)),
        "within_velocity": bool(np.all(peaks["qd"] <= limits.velocity)),
        "within_position": bool(np.all(q_min >= limits.lower) and np.all(q_max <= limits.upper)),
    }


PILOT_HORIZON = 0.3
"""Seconds of the pilot run whose states probe the substeps (:meth:`SampledSimulator.choose_substeps`):
on the default example the local error reaches its level of the whole run by 0.2 s."""

PILOT_ROWS = 30
"""Output rows of the pilot run (about), among which the probes are taken."""

PROBES = 8
"""Probe states of the pilot run (at most; its first sample and largest torque and speed among them)."""


def step_doubling(
    coarse: cs.Function,
    fine: cs.Function,
    t: float,
    s: np.ndarray,
    e: np.ndarray,
    held: tuple[np.ndarray, ...],
    order: int = 4,
) -> float:
    """The relative local error of one control period from ``(t, s)`` with ``e`` and ``held`` (the
    effort limits, friction and design) by the ``coarse`` period map, estimated by the ``fine``
    one in twice the steps: over the fixed period the error of a method of ``order`` p (RK4's 4, ROS34PW2's 3)
    falls ``2^p``-fold when its step halves, so the coarse error is ``2^p / (2^p - 1) (x_k - x_2k)``
    (Richardson; RK4's ``16/15``). Relative to the state's change over the period (infinity
    norms; 0 when both are zero): how many digits of the period's increment are right, whatever
    the state's offset. The quadratures are read off the same stages, so they are as accurate as
    the step; their increments change sign (``u^T nu``), so they are not a scale."""
    (a, *_), (b, *_) = ([np.asarray(v).ravel() for v in f(s, t, e, *held)] for f in (coarse, fine))
    gap, change = np.abs(a - b).max(), np.abs(b - s).max()
    if not math.isfinite(gap):
        return math.inf
    return 0.0 if gap == 0 else 2**order / (2**order - 1) * gap / change if change > 0 else math.inf


def period_method(settings: Settings) -> Method | None:
    """The fixed-step integrator of the control periods of ``settings``' run (None: CVODES): its
    implementation's :meth:`~dvfc.analysis.implementation.Implementation.method` for its plant, with or without
    dry friction."""
    assert settings.implementation is not None, "a sampled run is of the loop as implemented"
    return settings.implementation.method(settings.errors is not None and settings.errors.has_dry_friction)


def local_error_stats(errors: list[np.ndarray], periods: int) -> dict[str, float]:
    """``local_error_q``, the largest estimate of a period's local error in the joint angles (rad) over the first
    ``periods`` periods of a run (``errors``: the estimates of each chunk of periods); nothing where the method
    has no estimate (NaN: RK4, CVODES)."""
    values = np.concatenate([np.zeros(0), *errors])[:periods]
    return {"local_error_q": float(np.nanmax(values))} if np.isfinite(values).any() else {}


@dataclass
class _Periods:
    """The control period's map a simulator and its copies (:meth:`SampledSimulator.for_run`) run
    on, built once its substeps are known: at construction, or at the first run for ``"auto"``."""

    choice: SubstepChoice | None = None
    period: cs.Function | None = None
    chunks: dict[int, Buffered] = field(default_factory=dict)

    def set(self, choice: SubstepChoice, build: Callable[[int | None], cs.Function]) -> None:
        self.choice, self.period = choice, build(choice.substeps)


@dataclass(frozen=True, order=True)
class _Stop:
    """Why and where a sampled run ends: the law's steps kept are ``k < tau_end``, the samples
    whose speed counts ``k < qd_end``; stops order by step, then ``rank`` (the first that ends
    the run is the least)."""

    step: int
    rank: int
    stop: Stop = field(compare=False)
    tau_end: int = field(compare=False)
    qd_end: int = field(compare=False)


class SampledSimulator(Simulator):
    """The loop from sample to sample with the torque held, for a loop built with
    ``sampled=True`` and the settings' implementation, image and the arm's URDF limits
    (see the module's description)."""

    def __init__(self, loop: ClosedLoop, settings: Settings) -> None:
        if not loop.sampled or settings.implementation is None:
            raise ValueError("SampledSimulator needs a loop built with sampled=True and an implementation")
        if loop.friction is not None:
            raise ValueError("SampledSimulator takes the plant's friction from the settings' errors, not the loop's")
        super().__init__(loop, settings)
        implementation = settings.implementation
        self.implementation = implementation
        self.limits = limits = implementation.limits(loop.robot.limits)
        self.stride = round(settings.dt * implementation.control_rate)
        n, model = loop.robot.n, self.model
        t, s, e = cs.MX.sym("t"), cs.MX.sym("s", loop.n_state), cs.MX.sym("e", loop.task_dim)
        design = [cs.MX.sym("p", v.size) for v in self.design]  # inputs after the others
        # The torque is clipped at the input ``effort`` (inf: not clipped), so that another
        # torque scale or saturate setting needs no new code; a NaN torque stays NaN.
        effort = cs.MX.sym("effort", n)
        friction = cs.MX.sym("friction", 2 * n + 1)  # [viscous; coulomb; eps] of the plant (models/errors.py)
        self.errors = settings.errors
        self._friction = (self.errors or PlantErrors.none(loop.camera, n)).friction_vector()
        self._effort = limits.effort if implementation.saturate else np.full(n, np.inf)
        self._method = period_method(settings)
        update = sample_update(model, implementation.period)  # the program's (analysis/controller.py)
        if settings.jit and implementation.integrator == "cvodes":  # the RK4 period is compiled whole
            update = compiled(update)
        commanded, observer, estimate, integral = update(t, s, e, effort, *design)
        applied = cs.if_else(commanded > effort, effort, cs.if_else(commanded < -effort, -effort, commanded))
        self._symbols = (t, s, e, effort, friction, design, commanded, applied, observer, estimate, integral)
        # at t = T: the sample's law and observer inputs only
        last = cs.Function("dvfc_last", [t, s, e, effort, *design], [commanded, applied, observer])
        self._periods = _Periods()  # shared by the copies of :meth:`for_run`
        noise = cs.SX.sym("noise", model.features.numel())
        p = [] if model.parameters is None else [model.parameters]  # the image depends on the target's radius
        if self.errors is None:
            camera = cs.Function("dvfc_camera", [model.t, model.state, noise, *p], self._image(noise))
        else:
            errors = cs.SX.sym("errors", camera_size(loop.camera.m))
            image = self._true_image(noise, errors)
            camera = cs.Function("dvfc_true_camera", [model.t, model.state, noise, errors, *p], image)
            self._errors = self.errors.camera_vector(loop.camera)
            self._true_tracking = self._true_tracking_function()
        choice = self._fixed_choice()  # None: chosen at the first run (settle)
        own = {"signals": self.signal_function, "camera": camera}
        if self._method is None:  # CVODES: the law compiled (update), the period CVODES's on the DAE compiled here
            own["dae"] = self.dae
        else:
            own["last"] = last
            if choice is not None:
                own["period"] = self._period_function(choice.substeps)
        if settings.jit:  # built together, at -O1 (the period as fast a call as at -O2, built in 60% of the time), but
            # the law at t = T, called once a run, at -O0 (built in 0.9 s against 2.5 on the xArm 7 cell); CVODES
            # differences the DAE
            requests = [(f, name == "dae", "-O0" if name == "last" else "-O1") for name, f in own.items()]
            own = dict(zip(own, compiled_together(requests), strict=True))
        self.signal_function, self._image_function = own["signals"], Buffered(own["camera"])
        self._last = Buffered(own.get("last", last))
        if "dae" in own:
            self.dae = own["dae"]
        if choice is not None:
            built = own["period"] if "period" in own else self._period_function(choice.substeps)
            self._periods.set(choice, lambda _: built)
        self._read_image = Buffered(image_update(loop))  # the program's (21) and its check, by the VM
        self._window = None  # the image as bounds on f, point by point (when the run checks it)
        if settings.view and loop.camera.has_image:
            self._window = tuple(np.tile(bound, loop.camera.m) for bound in loop.camera.image_window())
            if self.errors is not None:
                self._window = self.errors.window(loop.camera)

    def for_run(self, settings: Settings) -> SampledSimulator:
        """This simulator (its compiled functions) for another run of the same loop: the
        settings' implementation, plant errors (``errors`` set here too) and inputs (target
        radius, plant masses) replace this one's. A campaign builds one simulator and runs it
        with each run's values."""
        if (settings.errors is None) != (self.errors is None):
            raise ValueError("for_run: the plant errors must be given for both runs or neither")
        other = copy.copy(self)
        imp = settings.implementation
        assert imp is not None, "a sampled run is of the loop as implemented"
        other.settings, other.implementation = settings, imp
        design = parameter_vector(self.loop, settings.inputs) if self.design else None
        other.design = [] if design is None else [design]
        other.limits = imp.limits(self.loop.robot.limits)
        other._effort = other.limits.effort if imp.saturate else np.full(self.loop.robot.n, np.inf)
        if (method := period_method(settings)) != self._method:
            other._method, other._periods = method, _Periods()  # another integrator: its own period (settle)
        if settings.errors is not None:
            other.errors = settings.errors
            other._friction = settings.errors.friction_vector()
            other._errors = settings.errors.camera_vector(self.loop.camera)
            if self._window is not None:
                other._window = settings.errors.window(self.loop.camera)
        return other

    def _fixed_choice(self) -> SubstepChoice | None:
        """The implementation's own substeps of the simulator's method, or CVODES; None for ``substeps = "auto"``
        (:meth:`choose_substeps`)."""
        if self._method is not None and self.implementation.substeps == "auto":
            return None
        return SubstepChoice.fixed(self.implementation, self._method)

    def _camera(self, t: float, s: np.ndarray, noise: np.ndarray, *errors: np.ndarray) -> list[np.ndarray]:
        """What the image at ``(t, s)`` gives (:meth:`_image`, :meth:`_true_image` with the plant's
        camera ``errors``), with ``noise`` added to the pixels, for the run's :attr:`design`."""
        return self._image_function(t, s, noise, *errors, *self.design)

    def _period_function(self, substeps: int | None) -> cs.Function:
        """One control period from ``(s, t)`` with ``e``, the effort limits and the friction held:
        the state after it, the commanded and applied torques, the quadratures' increments and the
        observer's held inputs ``[V_k; U_k]``; by CasADi's virtual machine. The controller's update at
        the sample is the program's (:func:`~dvfc.analysis.controller.sample_update`): the estimate and
        ``z_I`` after the period are its; the plant, with the torque held, and the quadratures, along
        the observer's flow with its inputs held, are integrated by ``substeps`` steps of the simulator's
        method (None: CVODES). A last output, the estimate of the period's local error in the joint angles
        (:meth:`_fixed_steps`; NaN where the method has none)."""
        t, s, e, effort, friction, design, commanded, applied, observer, estimate, integral = self._symbols
        after, quad, error = self._held_flow(t, s, cs.vertcat(applied, e, observer), friction, design, substeps)
        after[self.loop.estimate_slice] = estimate  # (22.1), the program's step
        if self.loop.integral:
            after[self.loop.integral_slice] = integral
        return cs.Function("dvfc_period", [s, t, e, effort, friction, *design],
                           [after, commanded, applied, quad, observer, error])  # fmt: skip

    def _compiled_period(self, substeps: int | None) -> cs.Function:
        """:meth:`_period_function`, compiled whole under ``jit`` when RK4 (CVODES calls the
        compiled DAE)."""
        period = self._period_function(substeps)
        whole = self.settings.jit and substeps is not None
        return compiled(period) if whole else period

    def _held_flow(
        self, t: cs.MX, s: cs.MX, hold: cs.MX, friction: cs.MX, design: list[cs.MX], substeps: int | None
    ) -> tuple[cs.MX, cs.MX, cs.MX]:
        """The state after one control period from ``(t, s)`` with ``hold`` held, the quadratures'
        increments and the estimate of the joint angles' local error: :meth:`_fixed_steps`, or CVODES
        (``substeps`` None; its error controlled at the run's tolerances, the estimate NaN)."""
        if substeps is not None:
            return self._fixed_steps(t, s, hold, friction, design, substeps)
        result = self._cvodes()(x0=s, p=cs.vertcat(t, hold, *design))
        return result["xf"], result["qf"], cs.MX(np.nan)

    def _fixed_steps(
        self, t: cs.MX, s: cs.MX, hold: cs.MX, friction: cs.MX, design: list[cs.MX], substeps: int
    ) -> tuple[cs.MX, cs.MX, cs.MX]:
        """The state after one control period from ``(t, s)`` with ``hold`` (the torque applied, ``e``,
        the observer's inputs) held, the torque less the plant's friction at each stage's joint speeds,
        and the quadratures' increments: ``substeps`` equal steps of the simulator's method, classical RK4
        or ROS34PW2 linearly implicit in the friction (:func:`dvfc.analysis.rosenbrock.w_step`, with the
        plant's ``M(q)`` and the friction's slope at each step's start); the model's functions called with
        ``design`` (:attr:`Simulator.design`). Last, the estimate of the period's local error in the joint
        angles: ROS34PW2's embedded estimates, the largest entry of each step's summed over the steps (NaN for
        RK4, which has no embedded step)."""
        model, n = self.model, self.loop.robot.n
        held = cs.Function("dvfc_held", model.arguments[0], [model.state_rate, model.quadratures])
        values = (("t", t), ("x", s), ("hold", hold), ("friction", friction), *(("p", d) for d in design))
        syms = [cs.MX.sym(name, v.numel()) for name, v in values]
        t_, x, inputs, b, *p = syms
        torque = inputs[:n] - friction_torque(x[n : 2 * n], b, n)  # no friction: tau - 0, exactly tau
        stage = cs.Function("dvfc_rate", syms, held(t_, x, cs.vertcat(torque, inputs[n:]), *p))

        def rate(time: cs.MX, state: cs.MX) -> list[cs.MX]:
            return stage(time, state, hold, friction, *design)

        step = self.implementation.period / substeps
        quad = cs.MX.zeros(len(QUADRATURES))
        if self._method == "rosenbrock":
            mass = cs.Function("dvfc_mass", model.arguments[0], [model.plant_dynamics[0]])
            start = cs.Function("dvfc_w", syms, [mass(t_, x, inputs, *p), friction_slope(x[n : 2 * n], b, n)])
            error = cs.MX(0)
            for i in range(substeps):
                t0 = t + i * step
                s, increment, local = w_step(rate, t0, s, step, n, *start(t0, s, hold, friction, *design))
                quad, error = quad + increment, error + cs.mmax(cs.fabs(local[:n]))
            return s, quad, error
        for i in range(substeps):
            t0 = t + i * step
            k1, q1 = rate(t0, s)
            k2, q2 = rate(t0 + step / 2, s + step / 2 * k1)
            k3, q3 = rate(t0 + step / 2, s + step / 2 * k2)
            k4, q4 = rate(t0 + step, s + step * k3)
            s = s + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            quad = quad + step / 6 * (q1 + 2 * q2 + 2 * q3 + q4)
        return s, quad, cs.MX(np.nan)

    def _cvodes(self) -> cs.Function:
        """CVODES over one control period (the reference integrator)."""
        options = {
            **self.cvodes_options(),
            # Adams with fixed-point iteration: over one control period the held-torque
            # dynamics are not stiff, and no Jacobian is formed at each of the many restarts
            # (about 15x faster than BDF/Newton here at the same tolerances).
            "linear_multistep_method": "adams",
            "nonlinear_solver_iteration": "functional",
        }
        return cs.integrator("sampled", "cvodes", self.dae, 0.0, [self.implementation.period], options)

    def _chunk(self, count: int) -> Buffered:
        """``count`` control periods in one call: the period's map accumulated over them, from
        the state at the first, with the times, the held ``e_e`` and the effort limits of each
        (one column per period); the states after each, the torques and quadratures of each.
        (Given the columns, not built from one, the call costs about half as much.)"""
        chunks = self._periods.chunks
        if count not in chunks:
            assert self._periods.period is not None, "settled (settle)"
            chunks[count] = Buffered(self._periods.period.mapaccum("dvfc_chunk", count, [0], [0]))
        return chunks[count]

    def _image(self, noise: cs.SX) -> list[cs.SX]:
        """What one image gives: the true features ``f`` (11), the exact ``e_e`` (15), the
        features the controller reads, ``f`` plus ``noise`` rounded (half up) to the pixel grid, and
        the depths of the points."""
        loop = self.model
        measured = self._quantized(loop.features + noise)
        return [loop.features, loop.e_e, measured, loop.camera.depths(loop.relative_pose)]

    def _quantized(self, measured: cs.SX) -> cs.SX:
        """Pixel offsets about the nominal principal point rounded (half up) to the pixel grid."""
        imp, camera = self.implementation, self.loop.camera
        if imp.quantization == 0:
            return measured
        offset = cs.DM(np.tile(camera.centre if camera.has_image else np.zeros(2), camera.m))
        return cs.floor((measured + offset) / imp.quantization + 0.5) * imp.quantization - offset

    def _true_image(self, noise: cs.SX, errors: cs.SX) -> list[cs.SX]:
        """What one image gives when the plant's camera differs from the controller's
        (:mod:`dvfc.models.errors`, ``errors`` its :meth:`~dvfc.models.errors.PlantErrors.camera_vector`):
        the true features about the true principal point (for the true image's bounds), the
        exact ``e_e`` (15) of the nominal model, the features the controller reads from the pixels
        plus ``noise`` with the nominal intrinsics, and the true depths."""
        loop = self.model
        true, about_nominal, depths = true_features(loop.camera, loop.relative_pose, errors)
        measured = controller_features(loop.camera, self._quantized(about_nominal + noise))
        return [true, loop.e_e, measured, depths]

    def true_tracking(self, t: np.ndarray, states: np.ndarray) -> np.ndarray:
        """The tracking error ``g_d^-1 g`` of the true camera (``g`` seen through the mount
        error) at times ``t`` and ``states`` (rows), as the rows of ``g_tracking`` (the target's
        motion and ``g_d`` of the run's :attr:`design`)."""
        return np.asarray(self._true_tracking(t[None, :], states.T, self._errors[:6], *self.design)).T

    def _true_tracking_function(self) -> cs.Function:
        """``(t, s, mount, [p]) -> g_d^-1 g`` of the camera seen through the ``mount`` error, as a
        column (:meth:`true_tracking`; called with one column a time, it maps over them)."""
        model = self.model
        mount = cs.SX.sym("mount", 6)
        error = cs.vec((model.reference.inverse() @ seen_through(model.relative_pose, mount)).as_matrix())
        p = [] if model.parameters is None else [model.parameters]
        return cs.Function("true_tracking", [model.t, model.state, mount, *p], [error])

    def noise(self, images: int, rng: np.random.Generator, faults: np.random.Generator) -> np.ndarray:
        """The pixel noise of ``images`` images in the order they are captured, one row each
        (``e_e = "image"``; drawn from ``rng``), and their wrong detections (drawn from ``faults``): the
        rows are those of ``images`` draws of one image each."""
        size, imp = self.model.features.numel(), self.implementation
        wrong = imp.outliers(images, size, faults)
        return wrong + imp.pixel_noise * rng.standard_normal((images, size)) if self.loop.mode == "image" else wrong

    def observe(self, t: float, s: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray, Stop | None]:
        """What an image captured at ``(t, s)`` with pixel ``noise`` gives: the exact ``e_e`` (15), the
        features the controller reads, and the stop when the image is lost (a point behind the camera
        or a feature outside the image), or None."""
        errors = () if self.errors is None else (self._errors,)
        f, e_ideal, measured, depth = (v.ravel() for v in self._camera(t, s, noise, *errors))
        if (depth <= 0).any():
            return e_ideal, measured, Stop.behind_camera(t)
        if self._window is not None and ((f < self._window[0]).any() or (f > self._window[1]).any()):
            outside = np.flatnonzero(np.any(((f < self._window[0]) | (f > self._window[1])).reshape(-1, 2), axis=1))
            return e_ideal, measured, Stop.out_of_view(int(outside[0]), t)
        return e_ideal, measured, None

    def _measure(self, t: float, s: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray | None, Stop | None]:
        """The ``e_e`` of an image captured at ``(t, s)`` with pixel ``noise`` (None: the controller drops
        it, as the program does an implausible one, :func:`~dvfc.analysis.controller.image_update`), and
        the stop when there is no image (a feature lost), or None."""
        e_ideal, measured, lost = self.observe(t, s, noise)
        if lost is not None or self.loop.mode != "image":
            return (None if lost else e_ideal), lost
        e_image, usable = self._read_image(s[self.loop.estimate_slice], measured)
        return (e_image.ravel() if usable.ravel()[0] else None), None

    def plant_period(self, s0: np.ndarray) -> Callable[[float, np.ndarray, np.ndarray], np.ndarray]:
        """``(t, s, tau) -> s`` one control period later with ``tau`` held: the plant of the simulator's
        period (its integrator and substeps, settled from ``s0``; its plant's friction and masses; the
        observer's inputs zero), for a controller outside it (:mod:`dvfc.analysis.sil`): the joints of
        the result are the plant's, the rest is not the controller's."""
        self.settle(s0)
        t, s, e, _, friction, design, *_ = self._symbols
        tau = cs.MX.sym("tau", self.loop.robot.n)
        hold = cs.vertcat(tau, cs.MX.zeros(3 * e.numel()))
        assert self._periods.choice is not None, "settled (settle)"
        substeps = self._periods.choice.substeps
        after, *_ = self._held_flow(t, s, hold, friction, design, substeps)
        period = cs.Function("dvfc_plant_period", [t, s, tau, friction, *design], [after])
        period = Buffered(compiled(period) if self.settings.jit and substeps else period)
        return lambda time, state, torque: period(time, state, torque, self._friction, *self.design)[0].ravel()

    @property
    def substeps(self) -> SubstepChoice | None:
        """How the periods are integrated (None: ``"auto"``, chosen at the first run)."""
        return self._periods.choice

    def choose_substeps(self, s0: np.ndarray) -> SubstepChoice:
        """The fewest steps a period of the simulator's method (RK4 or ROS34PW2), of 1, 2, 4, ...
        :data:`MAX_AUTO_SUBSTEPS`, whose relative local error (:func:`step_doubling`) is at most the
        implementation's ``step_error`` at every probe: the states of a pilot run from ``s0`` over its first
        :data:`PILOT_HORIZON` (one step a period, by the virtual machine; its first sample, the samples of its
        largest torque and joint speed, and others evenly spread)."""
        imp, method = self.implementation, self._method
        assert method is not None, "fixed steps (CVODES has no substeps)"
        pilot = copy.copy(self)
        duration, h = min(self.settings.duration, PILOT_HORIZON), imp.period
        rows_every = max(1, math.floor(duration / h / PILOT_ROWS)) * h  # whatever the run's output step
        pilot.settings = replace(self.settings, duration=duration, dt=rows_every)
        pilot._periods = _Periods()
        pilot._periods.set(SubstepChoice(1, method=method), self._period_function)
        traj = pilot.run(s0)
        peaks = [int(np.argmax(np.abs(traj[name]).max(axis=1))) for name in ("tau", "qd")]
        rows = sorted({*np.linspace(0, len(traj.t) - 1, PROBES - 2).astype(int).tolist(), *peaks})
        probes = [(traj.t[r], traj["state"][r], traj["e_e"][r]) for r in rows]
        held = (self._effort, self._friction, *self.design)
        functions = {1: self._period_function(1)}
        order = ORDER if method == "rosenbrock" else 4
        k = 1
        while True:
            functions[2 * k] = self._period_function(2 * k)
            estimate = max(step_doubling(functions[k], functions[2 * k], t, s, e, held, order) for t, s, e in probes)
            if estimate <= imp.step_error or k == MAX_AUTO_SUBSTEPS:
                met = bool(estimate <= imp.step_error)
                return SubstepChoice(k, True, imp.step_error, float(estimate), met, method)
            k *= 2

    def settle(self, s0: np.ndarray) -> SampledSimulator:
        """This simulator with its substeps chosen from ``s0`` now (``"auto"``; otherwise, or when
        already chosen, unchanged): every run of it and of its copies (:meth:`for_run`) then
        integrates the same way, whatever their own start (a campaign's runs)."""
        if self._periods.period is None:
            self._periods.set(self._fixed_choice() or self.choose_substeps(s0), self._compiled_period)
        return self

    def run(self, s0: np.ndarray, progress: Callable[[float], None] | None = None) -> Trajectory:
        """Run the sampled loop from ``s0`` over the settings' horizon (``substeps = "auto"``:
        chosen at the first run of this simulator and its copies, :meth:`settle`)."""
        self.settle(s0)
        assert self._periods.choice is not None, "settled (settle)"
        st, imp, loop = self.settings, self.implementation, self.loop
        n, h = loop.robot.n, imp.period
        steps = round(st.duration * imp.control_rate)
        faults = np.random.default_rng((imp.seed % 2**64, 1))  # timing and detection faults
        captures, arrivals = imp.arrivals(imp.capture_steps(steps), faults)
        noise = self.noise(len(captures), np.random.default_rng(imp.seed), faults)  # of each capture
        s = np.array(s0, dtype=float)
        e_held = np.zeros(loop.task_dim)
        kept = {0: s}  # states at capture steps whose image is not measured yet
        measured = 0  # captures measured so far
        rows: list[tuple[int, np.ndarray, np.ndarray]] = []  # (k, s_k, hold_k) on the output grid
        history: dict[str, list[np.ndarray]] = {"tau": [], "tau_applied": [], "quad": [], "q": [], "qd": []}  # per step
        stops: list[_Stop] = []
        local_errors: list[np.ndarray] = []  # per period, the estimate of the joint angles' local error
        start = time.perf_counter()
        signal_chunks: list[dict[str, np.ndarray]] = []
        held: dict[int, list[np.ndarray]] = {}  # periods in a chunk -> the constant inputs' columns
        evaluated = 0

        def measure_through(last: int, steps_of: np.ndarray) -> np.ndarray | None:
            """Measure in order the images whose step in ``steps_of`` (their arrivals, or their
            captures) is at most ``last``; the latest ``e_e``, or None (and a stop) when a
            feature is lost."""
            nonlocal measured
            e_new = None
            while measured < len(captures) and steps_of[measured] <= last:
                c = int(captures[measured])
                e_read, lost = self._measure(c * h, kept.pop(c), noise[measured])
                e_new = e_new if e_read is None else e_read
                measured += 1
                if lost is not None:
                    stops.append(_Stop(c, 0, lost, c, c))
                    return None
            return e_new

        def check_joints(first: int, joints: np.ndarray) -> None:
            """Record the positions and speeds of the samples ``first, first + 1, ...`` (rows of
            ``joints``: ``q``, ``qd``); a stop at the first whose speed exceeds its limit, when the
            implementation stops there."""
            speeds = np.abs(joints[:, n:])
            history["q"].append(joints[:, :n])
            history["qd"].append(speeds)
            if imp.velocity_limits == "stop" and np.any(over := speeds > self.limits.velocity):
                j, joint = (int(i[0]) for i in np.nonzero(over))
                stop = Stop.velocity_limit((first + j) * h, joint, speeds[j, joint], self.limits.velocity[joint])
                stops.append(_Stop(first + j, 1, stop, first + j, first + j + 1))

        check_joints(0, s[None, : 2 * n])
        k = 0
        while not stops:
            if (e_new := measure_through(k, arrivals)) is not None:
                e_held = e_new
            if stops or k == steps:
                break
            end = min(int(arrivals[measured]), steps) if measured < len(captures) else steps
            try:
                count = end - k
                if count not in held:  # the run's constant inputs, a column a period
                    constant = (self._effort, self._friction, *self.design)
                    held[count] = [np.repeat(v[:, None], count, 1) for v in constant]
                e_columns = np.repeat(e_held[:, None], count, 1)
                chunk = self._chunk(count)(s, np.arange(k, end) * h, e_columns, *held[count])
                after, commanded, applied, quad, observer, error = chunk
            except RuntimeError as exc:
                if interrupted(exc):
                    raise KeyboardInterrupt from exc
                message = f"CVODES failed between t = {k * h:.4g} s and t = {end * h:.4g} s"
                stops.append(_Stop(k, 4, Stop(RunStatus.INTEGRATOR_FAILURE, message), k, k + 1))
                break
            history["tau"].append(np.abs(commanded.T))
            history["tau_applied"].append(np.abs(applied.T))
            history["quad"].append(quad.T)
            local_errors.append(error.ravel())
            for j in range(-k % self.stride, end - k, self.stride):
                hold = np.concatenate([applied[:, j], e_held, observer[:, j]])
                rows.append((k + j, s if j == 0 else after[:, j - 1], hold))
            first, last = np.searchsorted(captures, [k + 1, end + 1])
            for c in captures[first:last]:  # the captures in (k, end]
                kept[int(c)] = after[:, c - k - 1]
            if not (np.isfinite(after).all() and np.isfinite(quad).all()):
                j = int(np.flatnonzero(~np.isfinite(np.vstack([after, quad])).all(axis=0))[0])
                stops.append(_Stop(k + j, 3, Stop.diverged((k + j) * h), k + j + 1, k + j + 1))
            check_joints(k + 1, after[: 2 * n].T)
            if stops:
                break
            s, k = after[:, -1], end
            if len(rows) - evaluated >= st.chunk:
                singular, evaluated = self._evaluate(rows, evaluated, signal_chunks)
                if singular is not None:
                    r = rows[evaluated - 1][0]
                    stops.append(_Stop(r, 2, singular, r + 1, r + 1))
                    break
                if progress is not None:
                    progress(k * h)
                if time.perf_counter() - start > st.time_budget:
                    stops.append(_Stop(k, 4, Stop.time_budget(k * h, st.time_budget), k, k + 1))
        # The captures up to the end (T, or the first stop) not measured yet: a feature lost in
        # one ends the run there, though its image would arrive later.
        measure_through(min(stops).step if stops else steps, captures)
        if not stops:  # the law at t = T, no integration
            last = (v.ravel() for v in self._last(steps * h, s, e_held, self._effort, *self.design))
            commanded, applied, observer = last
            history["tau"].append(np.abs(commanded[None, :]))
            history["tau_applied"].append(np.abs(applied[None, :]))
            if steps % self.stride == 0:
                rows.append((steps, s, np.concatenate([applied, e_held, observer])))
            stop = _Stop(steps, 5, Stop(), steps + 1, steps + 1)
        else:
            stop = min(stops)
        if not rows:  # stopped before the first period: the start is still a row (no torque counted)
            _, applied, observer = self._last(0.0, s, e_held, self._effort, *self.design)
            rows.append((0, s, np.concatenate([applied.ravel(), e_held, observer.ravel()])))
        rows = [r for r in rows if r[0] < max(stop.tau_end, 1)]  # the start is always a row
        if evaluated < len(rows):
            singular, kept_rows = self._evaluate(rows, evaluated, signal_chunks)
            if singular is not None:
                r = rows[kept_rows - 1][0]
                stop = _Stop(r, 2, singular, r + 1, r + 1)
                rows = rows[:kept_rows]
        signals = {name: np.concatenate([c[name] for c in signal_chunks])[: len(rows)] for name in signal_chunks[0]}
        signals["state"] = np.array([r[1] for r in rows])
        if self.errors is not None:  # the camera the image comes from is the one held to g_d
            signals["g_tracking"] = self.true_tracking(np.array([r[0] for r in rows]) * h, signals["state"])
        steps_of_rows = np.array([r[0] for r in rows])
        quad = np.vstack([np.zeros((1, len(QUADRATURES))), *history.pop("quad")]).cumsum(axis=0)[steps_of_rows]
        ends = {"tau": stop.tau_end, "tau_applied": stop.tau_end, "q": max(stop.qd_end, 1), "qd": stop.qd_end}
        samples = {key: np.vstack([np.zeros((0, n)), *v])[: ends[key]] for key, v in history.items()}
        q = samples.pop("q")  # the start at least
        peaks = {key: v.max(axis=0, initial=0.0) for key, v in samples.items()}
        peaks["q_min"], peaks["q_max"] = q.min(axis=0), q.max(axis=0)
        return Trajectory(
            t=steps_of_rows * h,
            signals=signals,
            integrals={name: quad[:, i] for i, name in enumerate(QUADRATURES)},
            status=stop.stop.status,
            message=stop.stop.message,
            wall_time=time.perf_counter() - start,
            stats={
                "steps": stop.tau_end,
                "samples": stop.qd_end - 1,
                **self._periods.choice.stats,
                **local_error_stats(local_errors, stop.tau_end),
            },
            peaks=peaks,
            stopped_at=None if stop.stop.status is RunStatus.OK else stop.step * h,
        )

    def _evaluate(self, rows: list, evaluated: int, chunks: list) -> tuple[Stop | None, int]:
        """Signals of the output rows not yet evaluated, appended to ``chunks``; returns the
        singularity's stop (if any) and how many rows are evaluated (kept)."""
        new = rows[evaluated:]
        t = np.array([r[0] for r in new]) * self.implementation.period
        states = np.array([r[1] for r in new]).T
        holds = np.array([r[2] for r in new]).T
        chunk = self._signals(t, states, holds)
        singular = self._singularity(t, chunk["sigma_min_arm_jacobian"][:, 0], chunk["cond_image_jacobian"][:, 0])
        if singular is not None:
            chunk = {name: v[: singular[0] + 1] for name, v in chunk.items()}
            chunks.append(chunk)
            return singular[1], evaluated + singular[0] + 1
        chunks.append(chunk)
        return None, len(rows)
