"""The loop as a digital controller runs it: sampled torques, a camera with its own rate and
latency, pixel noise and quantisation, actuator saturation, joint-speed limits.

Between two control samples ``t_k = k h`` the torque is held (zero-order hold) and the
plant, the observer and the quadratures are integrated by CVODES over exactly ``[t_k,
t_k + h]``: the sample-and-hold is not approximated by a fast continuous loop. At each
sample the controller

1. takes the image captured ``latency`` earlier, if one arrives now: the actual features
   ``f`` (11) plus Gaussian pixel noise, rounded to the pixel grid, turned into ``e_e`` by
   (21) with the estimate ``gbar`` of the capture time (``e_e = "image"``), or the exact
   ``e_e`` (15) of the capture time (``e_e = "ideal"``);
2. evaluates the law (35), (42) with the latest ``e_e`` (held until the next image) and
   clips it at the URDF's effort limits when ``saturate`` is on.

The observer (12) runs between images on the joint velocities (``V_wc = J_b qd``, (34)),
integrated exactly, with ``u_e`` built from the latest ``e_e``. Images are captured at the
first control sample at or after each camera tick ``j / camera_rate``; before the first
image arrives the observer runs on the joints alone (``e_e = 0``).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace

import casadi as cs
import numpy as np

from analysis.compile import compiled
from analysis.output import interrupted
from analysis.simulate import Settings, Simulator, Trajectory
from models.loop import QUADRATURES, ClosedLoop
from models.robot import JointLimits


def as_implemented(loop: ClosedLoop, settings: Settings) -> Simulator:
    """The simulator of the loop as it runs on the robot: the plant of ``settings`` (the law
    keeps ``loop``'s model), sampled by :class:`SampledSimulator` when ``settings`` has an
    implementation, else continuous; a feature leaving the image ends the run."""
    loop = replace(loop, plant=settings.plant)
    settings = replace(settings, view=True)
    imp = settings.implementation
    if imp is None:
        return Simulator(loop, settings)
    return SampledSimulator(replace(loop, sampled=True), settings)


def robot_limits(loop: ClosedLoop, settings: Settings) -> JointLimits:
    """The joint limits a run is held to: the URDF's, with the implementation's torque scale."""
    imp = settings.implementation
    return loop.robot.limits if imp is None else imp.limits(loop.robot.limits)


def limit_record(traj: Trajectory, limits: JointLimits) -> dict:
    """Per joint: the peak commanded and applied torque and the peak speed along the run
    (over every control sample of a sampled run, the output grid of a continuous one),
    against the URDF's effort and velocity limits (JSON-ready; ``inf`` limits as None)."""
    peaks = traj.peaks or {
        "tau": np.abs(traj["tau"]).max(axis=0),
        "tau_applied": np.abs(traj["tau_applied"]).max(axis=0),
        "qd": np.abs(traj["qd"]).max(axis=0),
    }
    finite = lambda a: [None if not math.isfinite(v) else float(v) for v in a]  # noqa: E731
    return {
        "peak_torque": peaks["tau_applied"].tolist(),
        "peak_torque_commanded": peaks["tau"].tolist(),
        "effort_limit": finite(limits.effort),
        "peak_speed": peaks["qd"].tolist(),
        "velocity_limit": finite(limits.velocity),
        "torque_ratio": (peaks["tau_applied"] / limits.effort).tolist(),
        "torque_commanded_ratio": (peaks["tau"] / limits.effort).tolist(),
        "speed_ratio": (peaks["qd"] / limits.velocity).tolist(),
        "within_effort": bool(np.all(peaks["tau_applied"] <= limits.effort)),
        "within_velocity": bool(np.all(peaks["qd"] <= limits.velocity)),
    }


class SampledSimulator(Simulator):
    """CVODES from sample to sample with the torque held, for a loop built with
    ``sampled=True`` and the settings' implementation, image and the arm's URDF limits
    (see the module's description)."""

    def __init__(self, loop: ClosedLoop, settings: Settings) -> None:
        if not loop.sampled or settings.implementation is None:
            raise ValueError("SampledSimulator needs a loop built with sampled=True and an implementation")
        super().__init__(loop, settings)
        implementation = settings.implementation
        self.implementation = implementation
        self.limits = limits = implementation.limits(loop.robot.limits)
        self.stride = round(settings.dt * implementation.control_rate)
        n = loop.robot.n
        options = {
            "abstol": settings.atol,
            "reltol": settings.rtol,
            "quad_err_con": True,
            "max_num_steps": 100000,
            "min_step_size": 1e-12,
            # Adams with fixed-point iteration: over one control period the held-torque
            # dynamics are not stiff, and no Jacobian is formed at each of the many restarts
            # (about 15x faster than BDF/Newton here at the same tolerances).
            "linear_multistep_method": "adams",
            "nonlinear_solver_iteration": "functional",
        }
        integrator = cs.integrator("sampled", "cvodes", self._dae, 0.0, [implementation.period], options)
        t, s, e = cs.MX.sym("t"), cs.MX.sym("s", loop.n_state), cs.MX.sym("e", loop.task_dim)
        law = cs.Function("dvfc_law", [loop.t, loop.state, loop.hold], [loop.tau])
        if settings.jit:
            law = compiled(law, jacobian=False)
        commanded = law(t, s, cs.vertcat(cs.MX.zeros(n), e))
        effort = cs.DM(np.where(np.isfinite(limits.effort), limits.effort, 1e300))
        applied = cs.fmin(cs.fmax(commanded, -effort), effort) if implementation.saturate else commanded
        result = integrator(x0=s, p=cs.vertcat(t, applied, e))
        self._step = cs.Function("step", [t, s, e], [commanded, applied, result["xf"], result["qf"]])
        self._last = cs.Function("last", [t, s, e], [commanded, applied])  # at t = T: the law, no integration
        f = cs.SX.sym("f", loop.features.numel())
        camera = [loop.features, loop.e_e, loop.image_estimate(f), loop.camera.depths(loop.relative_pose)]
        self._camera = cs.Function("camera", [loop.t, loop.state, f], camera)

    def _measure(self, t: float, s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, str | None]:
        """The ``e_e`` of an image captured at ``(t, s)``, or the reason there is none."""
        imp = self.implementation
        f, e_ideal, _, depth = (np.asarray(v).ravel() for v in self._camera(t, s, np.zeros(self.loop.features.numel())))
        if np.any(depth <= 0):
            return e_ideal, f"a feature point is behind the camera at t = {t:.4g} s"
        if (outside := np.flatnonzero(self.outside_image(f[None, :])[0])).size:
            return e_ideal, f"feature {int(outside[0])} left the image at t = {t:.4g} s"
        if self.loop.mode == "ideal":
            return e_ideal, None
        measured = f + imp.pixel_noise * rng.standard_normal(f.size)
        if imp.quantization > 0:
            camera = self.loop.camera
            offset = np.tile(camera.centre if camera.has_image else np.zeros(2), f.size // 2)
            measured = np.round((measured + offset) / imp.quantization) * imp.quantization - offset
        return np.asarray(self._camera(t, s, measured)[2]).ravel(), None

    def run(self, s0: np.ndarray, progress: Callable[[float], None] | None = None) -> Trajectory:
        """Run the sampled loop from ``s0`` over the settings' horizon."""
        st, imp, loop = self.settings, self.implementation, self.loop
        n = loop.robot.n
        steps = round(st.duration * imp.control_rate)
        captures = set(imp.capture_steps(steps).tolist())
        rng = np.random.default_rng(imp.seed)
        arrivals: deque[tuple[int, np.ndarray]] = deque()
        e_held = np.zeros(loop.task_dim)
        s = np.asarray(s0, dtype=float).copy()
        integral = np.zeros(len(QUADRATURES))
        rows: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []  # (t, s, hold, integrals)
        peaks = {key: np.zeros(n) for key in ("tau", "tau_applied", "qd")}
        status, message = "ok", ""
        start = time.perf_counter()
        chunks: list[dict[str, np.ndarray]] = []
        evaluated = 0
        n_steps = 0
        k = 0
        while True:
            t = k * imp.period
            if k in captures:
                e_new, lost = self._measure(t, s, rng)
                if lost is not None:
                    status = "behind_camera" if "behind" in lost else "out_of_view"
                    message = lost
                    break
                arrivals.append((k + imp.latency_steps, e_new))
            while arrivals and arrivals[0][0] <= k:
                e_held = arrivals.popleft()[1]
            speed = np.abs(s[n : 2 * n])
            peaks["qd"] = np.maximum(peaks["qd"], speed)
            if imp.velocity_limits == "stop" and np.any(speed > self.limits.velocity):
                j = int(np.flatnonzero(speed > self.limits.velocity)[0])
                status = "velocity_limit"
                message = (
                    f"stopped at t = {t:.4g} s: joint {j + 1} speed {speed[j]:.4g} rad/s exceeds its limit "
                    f"{self.limits.velocity[j]:.4g} rad/s"
                )
                break
            try:
                step = self._last if k == steps else self._step
                commanded, applied, *after = (np.asarray(v).ravel() for v in step(t, s, e_held))
            except RuntimeError as exc:
                if interrupted(exc):
                    raise KeyboardInterrupt from exc
                status, message = "integrator_failure", f"CVODES failed between t = {t:.4g} s and the next sample"
                break
            n_steps += 1
            peaks["tau"] = np.maximum(peaks["tau"], np.abs(commanded))
            peaks["tau_applied"] = np.maximum(peaks["tau_applied"], np.abs(applied))
            if k % self.stride == 0:
                rows.append((t, s, np.concatenate([applied, e_held]), integral.copy()))
            if k == steps:
                break
            xf, qf = after
            if not (np.all(np.isfinite(xf)) and np.all(np.isfinite(qf))):
                status, message = "diverged", f"non-finite state after t = {t:.4g} s"
                break
            for q in loop.quaternions:
                xf[q] /= np.linalg.norm(xf[q])
            s, integral = xf, integral + qf
            k += 1
            if len(rows) - evaluated >= st.chunk:
                singular, evaluated = self._evaluate(rows, evaluated, chunks)
                if singular is not None:
                    rows = rows[:evaluated]
                    status, message = "singular", singular
                    break
                if progress is not None:
                    progress(t)
                if time.perf_counter() - start > st.time_budget:
                    status = "time_budget"
                    message = f"stopped at t = {t:.4g} s: time budget {st.time_budget:g} s exceeded"
                    break
        if evaluated < len(rows):
            self._evaluate(rows, evaluated, chunks)
        times = np.array([r[0] for r in rows])
        signals = {name: np.concatenate([c[name] for c in chunks]) for name in chunks[0]}
        signals["state"] = np.array([r[1] for r in rows])
        integrals = np.array([r[3] for r in rows])
        return Trajectory(
            t=times,
            signals=signals,
            integrals={name: integrals[:, i] for i, name in enumerate(QUADRATURES)},
            status=status,
            message=message,
            wall_time=time.perf_counter() - start,
            stats={"steps": n_steps, "samples": k},
            peaks=peaks,
        )

    def _evaluate(self, rows: list, evaluated: int, chunks: list) -> tuple[str | None, int]:
        """Signals of the output rows not yet evaluated, appended to ``chunks``; returns the
        singularity message (if any) and how many rows are evaluated (kept)."""
        new = rows[evaluated:]
        t = np.array([r[0] for r in new])
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
