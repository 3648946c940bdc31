"""Closed-loop simulation of (36) with CVODES, and the energy identities it must satisfy.

The state ``s = [q; qd; pbar; quat]`` is integrated by CVODES (BDF, Newton with CasADi's
Jacobian: symbolic when the loop runs in CasADi's virtual machine, forward differences of the
compiled right-hand side under ``jit``, :data:`dvfc.analysis.compile.DIFFERENCES`) together with the quadratures of
:data:`dvfc.models.loop.QUADRATURES` (error-controlled as well). The run proceeds in
chunks of the output grid so that progress can be shown and a run that diverges, loses
its features or exceeds its time budget stops with a clear status.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cached_property

import casadi as cs
import numpy as np

from dvfc.analysis.compile import compiled_together
from dvfc.analysis.implementation import Implementation
from dvfc.analysis.output import interrupted
from dvfc.analysis.parametric import Inputs, parameter_vector, symbolic
from dvfc.models.errors import PlantErrors
from dvfc.models.loop import QUADRATURES, ClosedLoop
from dvfc.models.robot import Robot


@dataclass(frozen=True, kw_only=True)
class Settings:
    """Integration settings.

    Parameters
    ----------
    duration, dt
        Horizon and output step (s).
    rtol, atol
        CVODES tolerances (states and quadratures).
    jit
        Compile the right-hand side and the signals to C (cached on disk); CVODES then differentiates the
        compiled right-hand side by forward differences.
    time_budget
        Wall-clock seconds after which the run stops with status ``"time_budget"``.
    sigma_min
        The run stops with status ``"singular"`` when the smallest singular value of the
        arm's Jacobian (``J_b``, or ``J_p`` of the planar loop) falls below this: the law's
        ``pinv`` would divide by it. Near a singularity the law drives the arm into it
        within milliseconds, so the default (about a tenth of the built-in arms' values in
        their working poses) catches it at the output step before the integrator collapses.
    chunk
        Output steps of the first CVODES call; each later call is :data:`CHUNK_GROWTH` times
        the one before (CVODES restarts at every call, so fewer calls are faster; the calls are
        where progress is shown and checked). The calls depend on the step count only, never on
        the machine's speed, so that a run is the same run wherever it is made.
    implementation, plant
        The loop as it runs on the robot (:func:`dvfc.analysis.sampled.as_implemented`): the
        digital controller (None: the paper's continuous loop), the arm as it really is
        (None: the URDF's).
    errors
        What the controller's model gets wrong in the plant of the loop as implemented
        (:class:`dvfc.models.errors.PlantErrors`: camera mount, intrinsics, feature points,
        friction); None: nothing beyond ``plant``.
    view
        End the run with status ``"out_of_view"`` when a feature leaves the camera's image
        (when its size is known): the runs as implemented do, the paper's claims do not.
    inputs
        The target's radius and the plant's masses of this run, in place of the loop's and
        ``plant``'s own (:class:`dvfc.analysis.parametric.Inputs`: entries of the compiled
        functions' parameter vector); None: theirs.
    """

    duration: float = 10.0
    dt: float = 0.01
    rtol: float = 1e-10
    atol: float = 1e-10
    jit: bool = False
    time_budget: float = 600.0
    chunk: int = 100
    sigma_min: float = 0.02
    implementation: Implementation | None = None
    plant: Robot | None = None
    errors: PlantErrors | None = None
    view: bool = False
    inputs: Inputs | None = None

    @property
    def sampled(self) -> Implementation:
        """The implementation, for what only the loop as implemented has (a :class:`ValueError` naming
        the section when there is none)."""
        if self.implementation is None:
            raise ValueError("implementation: the loop as implemented needs an [implementation] section")
        return self.implementation


CHUNK_GROWTH = 4
"""Each CVODES call of a continuous run this many times the output steps of the one before."""

CONDITION_MAX = 1e6
"""In image mode a run stops when the condition number of the image Jacobian the law
inverts exceeds this."""


class RunStatus(StrEnum):
    """How a run ended: ``ok`` (it reached its horizon) or why it stopped."""

    OK = "ok"
    DIVERGED = "diverged"
    SINGULAR = "singular"
    TIME_BUDGET = "time_budget"
    BEHIND_CAMERA = "behind_camera"
    OUT_OF_VIEW = "out_of_view"
    VELOCITY_LIMIT = "velocity_limit"
    INTEGRATOR_FAILURE = "integrator_failure"


@dataclass(frozen=True)
class Stop:
    """How a run ended and what it says of it, worded once for both simulators (this module's
    and :class:`~dvfc.analysis.sampled.SampledSimulator`)."""

    status: RunStatus = RunStatus.OK
    message: str = ""

    @classmethod
    def behind_camera(cls, t: float) -> Stop:
        return cls(RunStatus.BEHIND_CAMERA, f"a feature point is behind the camera at t = {t:.4g} s")

    @classmethod
    def out_of_view(cls, feature: int, t: float) -> Stop:
        return cls(RunStatus.OUT_OF_VIEW, f"feature {feature} left the image at t = {t:.4g} s")

    @classmethod
    def time_budget(cls, t: float, budget: float) -> Stop:
        return cls(RunStatus.TIME_BUDGET, f"stopped at t = {t:.4g} s: time budget {budget:g} s exceeded")

    @classmethod
    def diverged(cls, t: float) -> Stop:
        return cls(RunStatus.DIVERGED, f"non-finite state after t = {t:.4g} s")

    @classmethod
    def velocity_limit(cls, t: float, joint: int, speed: float, limit: float) -> Stop:
        """Joint ``joint`` (from 0) at ``speed`` over its ``limit`` (rad/s)."""
        return cls(RunStatus.VELOCITY_LIMIT, f"stopped at t = {t:.4g} s: joint {joint + 1} speed {speed:.4g} rad/s "
                                             f"exceeds its limit {limit:.4g} rad/s")  # fmt: skip


@dataclass
class Trajectory:
    """Signals on the time grid (first axis: time) and the accumulated integrals."""

    t: np.ndarray
    signals: dict[str, np.ndarray]
    integrals: dict[str, np.ndarray]
    status: RunStatus = RunStatus.OK
    message: str = ""
    wall_time: float = 0.0
    stats: dict[str, float] = field(default_factory=dict)
    peaks: dict[str, np.ndarray] = field(default_factory=dict)
    """Per-joint peaks ``|tau|``, ``|tau_applied|``, ``|qd|`` and range ``q_min``, ``q_max`` over
    every control sample (sampled runs; :func:`joint_peaks` for any run)."""
    stopped_at: float | None = None
    """Where a run that did not complete stopped (s), when that is after its last output sample;
    None: at its last output sample."""

    def __post_init__(self) -> None:
        self.status = RunStatus(self.status)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]


def dynamics_function(loop: ClosedLoop) -> cs.Function:
    """The DAE of the loop in CasADi's integrator signature, with the time offset of the
    chunk as parameter ``p`` (the integrator's own clock starts at 0 every chunk), followed
    by the loop's further arguments: the held inputs of the sampled loop
    (:attr:`dvfc.models.loop.ClosedLoop.hold`), the design of a symbolic loop
    (:attr:`dvfc.models.loop.ClosedLoop.parameters`).

    Interpreted, the Jacobian of a symbolic loop is taken in forward mode, the mode CasADi chooses for the
    loop with numbers: the design's inputs would tip its choice to reverse mode, whose round-off
    differs (by about 1e-9 in the Jacobian, 1e-11 in the states CVODES's Newton steps reach)."""
    t_local, offset = cs.SX.sym("t"), cs.SX.sym("p")
    ode, quad = cs.substitute([loop.state_rate, loop.quadratures], [loop.t], [t_local + offset])
    empty = cs.SX(0, 1)
    parameters = cs.vertcat(offset, *loop.arguments[0][2:])
    forward = {} if loop.parameters is None else {"ad_weight": 0.0, "ad_weight_sp": 0.0}
    return cs.Function(
        "dvfc_dynamics_sampled" if loop.sampled else "dvfc_dynamics",
        [t_local, loop.state, empty, parameters, empty],
        [ode, empty, quad, empty],
        cs.dyn_in(),
        cs.dyn_out(),
        forward,
    )


def _singular_values(j: np.ndarray) -> np.ndarray:
    """Singular values of a batch ``(T, r, c)``, ascending, by SVD: accurate to about
    ``eps sigma_max`` (the square root of a Gram matrix's eigenvalues resolves only
    ``sqrt(eps) sigma_max`` ~ 1e-8, which hides how singular a matrix is). NaN for a matrix with a
    non-finite entry (a diverged run's last samples)."""
    finite = np.isfinite(j).all(axis=(1, 2))
    out = np.full((len(j), min(j.shape[1:])), np.nan)
    if finite.any():
        out[finite] = np.linalg.svd(j[finite], compute_uv=False)[:, ::-1]
    return out


def conditioning_of(flat: np.ndarray, shapes) -> tuple[np.ndarray, np.ndarray]:
    """``sigma_min`` of the arm's Jacobian and the condition number of the image Jacobian from
    their column-major vectorisations side by side (``flat``: one row per time)."""
    (ra, ca), (ri, ci) = shapes
    arm = flat[:, : ra * ca].reshape(-1, ca, ra).transpose(0, 2, 1)
    image = flat[:, ra * ca :].reshape(-1, ci, ri).transpose(0, 2, 1)
    s_image = _singular_values(image)
    with np.errstate(divide="ignore"):
        return _singular_values(arm)[:, 0], s_image[:, -1] / s_image[:, 0]


class Simulator:
    """CVODES integrator and signal evaluator for one closed loop.

    Its functions are built from :attr:`model`, the loop with its design symbolic (shared by
    every design of the same arm and structure, :func:`dvfc.analysis.parametric.symbolic`),
    and called with :attr:`design`, the numbers of :attr:`loop`."""

    def __init__(self, loop: ClosedLoop, settings: Settings) -> None:
        self.loop = loop
        self.settings = settings
        self.model = model = symbolic(loop)
        p = parameter_vector(loop, settings.inputs)
        self.design: list[np.ndarray] = [] if p is None else [p]
        """The last arguments of the model's functions: ``[p]``, or none for a loop that keeps its
        numbers (:func:`dvfc.analysis.parametric.parametrised`)."""
        self._integrators: dict[int, cs.Function] = {}
        self.signal_names = list(model.signals)
        self._mapped: dict[int, tuple] = {}
        signals = model.signals_function()
        self.signal_function = signals
        if settings.jit and not loop.sampled:  # the sampled simulator compiles its signals with its own functions
            # both at -O0, the DAE differentiated: a call costs more (on the xArm 7 cell the signals 41 us against 7 at
            # -O1, the DAE 18 against 6), a build less (2.2 s against 6.2, 0.8 against 3.7), and a structure's runs
            # make few calls (a whole verify of that cell, 23308 samples of signals and 12917 DAE evaluations)
            requests = [(signals, False, "-O0"), (dynamics_function(model), True, "-O0")]
            self.signal_function, self.dae = compiled_together(requests)
        (arm, arm_jac), (image, image_jac) = model.conditioning.items()
        self._monitored = (arm, image)
        self._shapes = (arm_jac.shape, image_jac.shape)

    @cached_property
    def dae(self) -> cs.Function:
        """The DAE of :func:`dynamics_function` (under ``jit`` compiled at construction, beside the signals or, for
        the sampled loop integrated by CVODES, beside the sampled simulator's functions, and differentiated by
        forward differences; otherwise built at first use: the fixed-step sampled loop never needs it)."""
        return dynamics_function(self.model)

    def cvodes_options(self) -> dict:
        """CVODES's options for a run: the settings' tolerances on the states and quadratures."""
        return {
            "abstol": self.settings.atol,
            "reltol": self.settings.rtol,
            "quad_err_con": True,
            "max_num_steps": 100000,
            "min_step_size": 1e-12,  # a collapsing step ends the run at once instead of grinding
            "disable_internal_warnings": True,  # SUNDIALS' own lines: the run's status says it instead
        }

    def integrator(self, count: int) -> cs.Function:
        """CVODES over ``count`` output steps (built once per size)."""
        if count not in self._integrators:
            grid = np.arange(1, count + 1) * self.settings.dt
            options = self.cvodes_options()
            self._integrators[count] = cs.integrator("closed_loop", "cvodes", self.dae, 0.0, grid, options)
        return self._integrators[count]

    def evaluate_signals(
        self, t: np.ndarray, states: np.ndarray, holds: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """All signals at times ``t`` (``states``, and ``holds`` of the sampled loop: one column
        per time), evaluated in one mapped call writing straight into NumPy arrays (CasADi's
        buffer interface)."""
        count = len(t)
        columns = [states] if holds is None else [states, holds]
        if count not in self._mapped:  # the design is one column for every time
            shared = list(range(1 + len(columns), 1 + len(columns) + len(self.design)))
            mapped = self.signal_function.map("signals_map", "serial", count, shared, [])
            self._mapped[count] = (mapped, *mapped.buffer())
        mapped, buffer, trigger = self._mapped[count]
        inputs = [np.ascontiguousarray(t, dtype=float), *(np.ascontiguousarray(c.T, dtype=float) for c in columns),
                  *self.design]  # fmt: skip
        outputs = {k: np.empty((count, mapped.size1_out(i))) for i, k in enumerate(self.signal_names)}
        assert all(mapped.nnz_out(i) == v.size for i, v in enumerate(outputs.values())), "signals must be dense"
        for i, value in enumerate(inputs):
            buffer.set_arg(i, value.data)
        for i, value in enumerate(outputs.values()):
            buffer.set_res(i, value.data)
        trigger()
        return outputs

    def conditioning(self, t: np.ndarray, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smallest singular value of the arm's Jacobian and condition number of the image
        Jacobian at times ``t`` (``states``: one column per time)."""
        signals = self._signals(t, states)
        return signals["sigma_min_arm_jacobian"][:, 0], signals["cond_image_jacobian"][:, 0]

    def _signals(self, t: np.ndarray, states: np.ndarray, holds: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """:meth:`evaluate_signals` with the conditioning of the two Jacobians the law inverts."""
        signals = self.evaluate_signals(t, states, holds)
        flat = np.hstack([signals["body_jacobian"], signals["image_jacobian"]])
        sigma, cond = conditioning_of(flat, self._shapes)
        signals["sigma_min_arm_jacobian"], signals["cond_image_jacobian"] = sigma[:, None], cond[:, None]
        return signals

    def outside_image(self, f: np.ndarray) -> np.ndarray:
        """Which points of the features ``f`` (one row per time) lie outside the image, when
        the settings ask for it and the camera's size is known (one column per point)."""
        camera = self.loop.camera
        xy = f.reshape(len(f), -1, 2)
        if not (self.settings.view and camera.has_image):
            return np.zeros(xy.shape[:2], dtype=bool)
        low, high = camera.image_window()
        return np.any((xy < low) | (xy > high), axis=2)

    def _singularity(self, t: np.ndarray, sigma: np.ndarray, cond: np.ndarray) -> tuple[int, Stop] | None:
        """The first of the times ``t`` where the law would divide by a near-zero (``sigma``,
        ``cond`` from :func:`conditioning_of`), with its stop, or None."""
        arm, image = self._monitored
        bad_arm = np.flatnonzero(~(sigma >= self.settings.sigma_min))
        bad_image = np.flatnonzero(~(cond <= CONDITION_MAX)) if self.loop.mode == "image" else np.array([], int)
        first = min([*bad_arm[:1], *bad_image[:1]], default=None)
        if first is None:
            return None
        if bad_arm.size and bad_arm[0] == first:
            what = f"{arm} is near-singular: sigma_min({arm}) = {sigma[first]:.3g} < {self.settings.sigma_min:g}"
        else:
            what = f"{image} is ill-conditioned: cond({image}) = {cond[first]:.3g} > {CONDITION_MAX:g}"
        return first, Stop(RunStatus.SINGULAR, f"stopped at t = {t[first]:.4g} s: {what} (the law would divide by it)")

    def run(self, s0: np.ndarray, progress: Callable[[float], None] | None = None) -> Trajectory:
        """Integrate from ``s0`` over the settings' horizon."""
        return self._integrate(s0, round(self.settings.duration / self.settings.dt), None, progress)

    def continued(self, s0: np.ndarray, after: Trajectory, until: float) -> Trajectory:
        """:meth:`run` from ``s0`` to ``until`` seconds, continuing ``after``, a completed run of this
        simulator from ``s0`` over a shorter horizon, instead of starting again: its samples, integrals
        and signals are kept and CVODES restarts from its last state, as it does between two of its own
        calls (the run made at once, to the integrator's tolerance). For the continuous loop's runs
        (a subclass that runs otherwise has none to continue)."""
        assert type(self).run is Simulator.run, "a continuous loop's run"
        assert after.status is RunStatus.OK and after.t[-1] <= until, "a completed, shorter run"
        return self._integrate(s0, round(until / self.settings.dt), after, None)

    def _integrate(self, s0: np.ndarray, steps: int, after: Trajectory | None,
                   progress: Callable[[float], None] | None) -> Trajectory:  # fmt: skip
        """CVODES from ``s0`` over ``steps`` output steps, continuing ``after`` when given."""
        st = self.settings
        t = np.arange(steps + 1) * st.dt
        states = np.empty((self.loop.n_state, steps + 1))
        integrals = np.zeros((len(QUADRATURES), steps + 1))
        k, n_steps, spent = 0, 0, 0.0
        if after is None:
            states[:, 0] = s0
            chunks = [self._signals(t[:1], states[:, :1])]  # signals, evaluated as the run goes
        else:
            k, n_steps, spent = len(after.t) - 1, int(after.stats["steps"]), after.wall_time
            states[:, : k + 1] = after["state"].T
            integrals[:, : k + 1] = np.array([after.integrals[name] for name in QUADRATURES])
            chunks = [{name: v for name, v in after.signals.items() if name != "state"}]
        stop = Stop()
        start = time.perf_counter() - spent
        size = st.chunk
        refining = False  # after a failed chunk: one output step at a time, to locate the failure
        while k < steps:
            count = min(size, steps - k)
            integrator = self.integrator(count)
            try:
                result = integrator(x0=states[:, k], p=np.concatenate([t[k : k + 1], *self.design]))
            except RuntimeError as exc:
                if interrupted(exc):
                    raise KeyboardInterrupt from exc
                if count > 1:
                    refining, size = True, 1
                    continue
                reached = t[k] + float(integrator.stats().get("tcur", 0.0) or 0.0)
                sigma, cond = chunks[-1]["sigma_min_arm_jacobian"][-1], chunks[-1]["cond_image_jacobian"][-1]  # (1,)
                arm, image = self._monitored
                stop = Stop(RunStatus.INTEGRATOR_FAILURE,
                            f"CVODES stopped at t = {reached:.4g} s: the step size collapsed or the step limit was "
                            f"reached (the run diverges or is too stiff); at t = {t[k]:.4g} s sigma_min({arm}) = "
                            f"{sigma[0]:.3g}, cond({image}) = {cond[0]:.3g}")  # fmt: skip
                break
            size = 1 if refining else CHUNK_GROWTH * size
            n_steps += int(integrator.stats().get("nsteps", 0))
            xf = np.asarray(result["xf"])[:, :count]
            qf = np.asarray(result["qf"])[:, :count]
            if not (np.all(np.isfinite(xf)) and np.all(np.isfinite(qf))):
                stop = Stop.diverged(t[k])
                break
            for q in self.loop.quaternions:
                xf[q] /= np.linalg.norm(xf[q], axis=0)
            states[:, k + 1 : k + 1 + count] = xf
            integrals[:, k + 1 : k + 1 + count] = integrals[:, k : k + 1] + qf
            chunk = self._signals(t[k + 1 : k + 1 + count], xf)
            singular = self._singularity(
                t[k + 1 : k + 1 + count], chunk["sigma_min_arm_jacobian"][:, 0], chunk["cond_image_jacobian"][:, 0]
            )
            if singular is not None:
                chunks.append({name: v[: singular[0] + 1] for name, v in chunk.items()})
                k, stop = k + singular[0] + 1, singular[1]
                break
            chunks.append(chunk)
            k += count
            if progress is not None:
                progress(t[k])
            if time.perf_counter() - start > st.time_budget:
                stop = Stop.time_budget(t[k], st.time_budget)
                break
        t, states, integrals = t[: k + 1], states[:, : k + 1], integrals[:, : k + 1]
        signals = {name: np.concatenate([c[name] for c in chunks]) for name in chunks[0]}
        signals["state"] = states.T
        behind = np.flatnonzero(np.any(signals["depth"] <= 0, axis=1))
        outside = self.outside_image(signals["f"])
        lost = np.flatnonzero(outside.any(axis=1))
        if stop.status is RunStatus.OK and behind.size:
            stop = Stop.behind_camera(t[int(behind[0])])
        elif stop.status is RunStatus.OK and lost.size:
            i = int(lost[0])
            stop = Stop.out_of_view(int(np.flatnonzero(outside[i])[0]), t[i])
        return Trajectory(
            t=t,
            signals=signals,
            integrals={name: integrals[i] for i, name in enumerate(QUADRATURES)},
            status=stop.status,
            message=stop.message,
            wall_time=time.perf_counter() - start,
            stats={"steps": n_steps},
        )


def joint_peaks(traj: Trajectory) -> dict[str, np.ndarray]:
    """Per joint: the peaks ``|tau|`` (commanded), ``|tau_applied|``, ``|qd|`` and the range
    ``q_min``, ``q_max`` up to the end or the stop of a run: over every control sample of a
    sampled run (:attr:`Trajectory.peaks`), else over the output grid."""
    if traj.peaks:
        return traj.peaks
    q = traj["q"]
    return {
        "tau": np.abs(traj["tau"]).max(axis=0),
        "tau_applied": np.abs(traj["tau_applied"]).max(axis=0),
        "qd": np.abs(traj["qd"]).max(axis=0),
        "q_min": q.min(axis=0),
        "q_max": q.max(axis=0),
    }


def rotation_angle(r: np.ndarray) -> np.ndarray:
    """The angle (rad) of each rotation of a batch ``(..., 3, 3)``, by ``atan2(|sk(R)^vee|,
    (tr R - 1)/2)``: accurate at every angle (``arccos`` of the trace resolves only about
    1e-8 rad near 0)."""
    vee = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1) / 2
    return np.arctan2(np.linalg.norm(vee, axis=-1), (np.trace(r, axis1=-2, axis2=-1) - 1) / 2)


def identity_residuals(traj: Trajectory) -> dict[str, float]:
    """Energy identities along the run, each as a relative residual (max over time).

    - ``passivity`` (Lemma 2, (40)-(41) with ``w``): ``V(t) - V(0) = int (u^T nu + x^T G w)``;
      holds for any input, so in both modes.
    - ``dissipation`` ((43), with ``w``): ``V(t) - V(0) = int (-nu^T K nu + x^T G w)``;
      exact only when ``u = -K N x`` with the exact ``e_e`` (ideal mode). With integral action,
      ``V_a = V + z_I^T K_I z_I / 2`` in place of ``V`` (docs/math.md, fact 20.1).

    The scale is ``max(V(0), max_t |int u^T nu|, max_t |int x^T G w|)``.
    """
    v = traj["V"][:, 0]
    dv = v - v[0]
    i = traj.integrals
    scale = max(v[0], np.abs(i["supply_u_nu"]).max(), np.abs(i["supply_x_G_w"]).max(), np.finfo(float).tiny)
    passivity = dv - i["supply_u_nu"] - i["supply_x_G_w"]
    if "V_a" in traj.signals:
        dv = traj["V_a"][:, 0] - traj["V_a"][0, 0]
    dissipation = dv + i["dissipation_nu_K_nu"] - i["supply_x_G_w"]
    return {
        "passivity": float(np.abs(passivity).max() / scale),
        "dissipation": float(np.abs(dissipation).max() / scale),
    }


def summary(traj: Trajectory) -> dict:
    """Headline numbers of a run (JSON-ready). ``final`` starts with the true tracking error
    ``g_d^-1 g`` (position in m, angle in degrees; the planar loop's horizontal ``p - p_d``),
    then the control error ``e_c`` (of the estimate) and the estimation error ``e_e``, at
    ``final_at``: the end, or for a run that stopped (``stopped``, at ``stopped_at``) its last
    output sample. ``max_torque`` is the largest applied ``|tau|`` of :func:`joint_peaks`, the
    samples of the per-joint peaks of :func:`dvfc.analysis.sampled.limit_record`."""
    e_c, e_e = traj["e_c"], traj["e_e"]
    v = traj["V"][:, 0]
    gap = np.linalg.norm(traj["e_e_image"] - e_e, axis=1)
    tracking = traj["g_tracking"][-1].reshape(4, 4, order="F")  # g_d^-1 g at the end
    return {
        "status": traj.status,
        "message": traj.message,
        "t_final": float(traj.t[-1]),
        "stopped": traj.status is not RunStatus.OK,
        "stopped_at": float(traj.t[-1] if traj.stopped_at is None else traj.stopped_at),
        "final_at": float(traj.t[-1]),
        "final": {
            "tracking_position": float(np.linalg.norm(tracking[:3, 3])),
            "tracking_angle_deg": float(np.degrees(rotation_angle(tracking[:3, :3]))) if e_c.shape[1] == 6 else None,
            "e_c_position": float(np.linalg.norm(e_c[-1, :3])),
            "e_c_rotation": float(np.linalg.norm(e_c[-1, 3:])) if e_c.shape[1] == 6 else None,
            "e_e_position": float(np.linalg.norm(e_e[-1, :3])),
            "e_e_rotation": float(np.linalg.norm(e_e[-1, 3:])) if e_e.shape[1] == 6 else None,
            "x_norm": float(np.linalg.norm(np.hstack([traj["xi"][-1], e_c[-1], e_e[-1]]))),
        },
        "max_torque": float(joint_peaks(traj)["tau_applied"].max()),
        "V0": float(v[0]),
        "VT": float(v[-1]),
        "V_max_increase": float(np.maximum(np.diff(v), 0.0).max(initial=0.0)),
        "integrals": {k: float(val[-1]) for k, val in traj.integrals.items()},
        "identity_residuals": identity_residuals(traj),
        "image_estimate_gap_max": float(gap.max()),
        "min_sigma_arm_jacobian": float(traj["sigma_min_arm_jacobian"].min()),
        "max_cond_image_jacobian": float(traj["cond_image_jacobian"].max()),
        "wall_time": traj.wall_time,
        "integrator_steps": traj.stats.get("steps", 0),
    }
