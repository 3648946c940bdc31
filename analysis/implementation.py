"""How the loop runs on a robot: the scenario's ``[implementation]``."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from dvfc.models.robot import JointLimits

STEP_ERROR = 1e-8
"""Default target on the relative local error of one control period (``substeps = "auto"``)."""

Method = Literal["rk4", "rosenbrock"]
"""A fixed-step integrator of the control period: classical RK4, or ROS34PW2 linearly implicit in the joint
friction (:mod:`dvfc.analysis.rosenbrock`)."""

MAX_AUTO_SUBSTEPS = 16
"""The most RK4 steps a period ``substeps = "auto"`` chooses: the error falls 16-fold a doubling, so
16 steps are 65536 times more accurate than one; the period is compiled whole, and its code (and
compile time) grows with the steps."""


@dataclass(frozen=True)
class SubstepChoice:
    """How the held-torque dynamics are integrated over a control period, and why.

    ``substeps``: fixed steps a period (None: CVODES) of ``method``, ``"rk4"`` (classical Runge-Kutta) or
    ``"rosenbrock"`` (ROS34PW2, linearly implicit in the joint friction: :mod:`dvfc.analysis.rosenbrock`);
    ``auto``: chosen from the target ``step_error``; ``estimate``: the estimated relative local error of one
    period at ``substeps`` (step doubling, :func:`dvfc.analysis.sampled.step_doubling`; None when not
    estimated); ``met``: whether the estimate meets the target (False: even :data:`MAX_AUTO_SUBSTEPS` does
    not); ``run_error``: of a run by ROS34PW2, the largest estimate of a period's local error in the joint
    angles (rad, from the embedded step: :data:`dvfc.analysis.rosenbrock.EMBEDDED`; None otherwise)."""

    substeps: int | None
    auto: bool = False
    step_error: float | None = None
    estimate: float | None = None
    met: bool = True
    method: Method = "rk4"
    run_error: float | None = None

    @classmethod
    def fixed(cls, imp: Implementation, method: Method | None) -> SubstepChoice:
        """The scenario's own choice: its ``substeps`` steps of ``method`` (:meth:`Implementation.method`), or
        CVODES (None)."""
        return cls(None) if method is None else cls(int(imp.substeps), method=method)

    @classmethod
    def of_run(cls, stats: dict[str, float]) -> SubstepChoice:
        """The choice a sampled run recorded in its ``stats`` (:attr:`stats`)."""
        if "substeps" not in stats:
            return cls(None)
        method: Method = "rosenbrock" if stats.get("rosenbrock") else "rk4"
        run_error = stats.get("local_error_q")
        if "step_error" not in stats:
            return cls(int(stats["substeps"]), method=method, run_error=run_error)
        target, estimate = stats["step_error"], stats["step_error_estimate"]
        return cls(int(stats["substeps"]), True, target, estimate, estimate <= target, method, run_error)

    @classmethod
    def from_dict(cls, record: dict) -> SubstepChoice:
        """The choice of its :meth:`as_dict`."""
        method: Method = "rosenbrock" if record["integrator"] == "rosenbrock" else "rk4"
        return cls(record["substeps"], record["chosen"] == "auto", record["step_error"],
                   record["estimated_step_error"], record["met"], method, record.get("local_error_q"))  # fmt: skip

    @property
    def text(self) -> str:
        """How the periods are integrated, in words (the printed summary)."""
        if self.substeps is None:
            return "CVODES restarted at every sample"
        name = "RK4" if self.method == "rk4" else "ROS34PW2 (linearly implicit in the joint friction)"
        how = f"{name}, {self.substeps} step{'s' if self.substeps > 1 else ''} a control period"
        if self.run_error is not None:
            how += f"; the run's largest local error of q a period {self.run_error:.2g} rad (embedded estimate)"
        if not self.auto:
            return how
        verdict = "<=" if self.met else "ABOVE"
        return f"{how} (auto: estimated local error {self.estimate:.2g} {verdict} step_error {self.step_error:g})"

    @property
    def stats(self) -> dict[str, float]:
        """What a run records of it (:attr:`dvfc.analysis.simulate.Trajectory.stats`): the steps a period
        (``rosenbrock`` 1 when they are ROS34PW2's) and, when chosen, the target and the estimate."""
        if self.substeps is None:
            return {}
        method = {"rosenbrock": 1.0} if self.method == "rosenbrock" else {}
        if not self.auto:
            return {"substeps": self.substeps, **method}
        assert self.step_error is not None and self.estimate is not None, "an automatic choice has both"
        return {"substeps": self.substeps, **method, "step_error": self.step_error,
                "step_error_estimate": self.estimate}  # fmt: skip

    def as_dict(self) -> dict:
        """JSON-ready (summary.json's ``integration``)."""
        return {
            "integrator": "cvodes" if self.substeps is None else self.method,
            "substeps": self.substeps,
            "chosen": "auto" if self.auto else "scenario",
            "step_error": self.step_error,
            "estimated_step_error": self.estimate,
            "met": self.met,
            "local_error_q": self.run_error,
        }


@dataclass(frozen=True, kw_only=True)
class Implementation:
    """The digital controller.

    Parameters
    ----------
    control_rate, camera_rate
        Rates (Hz) of the torque samples and of the images.
    latency
        Seconds from the capture of an image to its use: a whole number of control periods.
    pixel_noise, quantization
        Standard deviation of the Gaussian noise on each image coordinate and the pixel grid
        the coordinates are rounded to (px; 0 for none), with the noise's ``seed``.
    saturate
        Clip the torques at the effort limits.
    torque_scale
        The effort limits as a multiple of the URDF's (a weaker drive, a derating).
    velocity_limits
        ``"report"``: record joint speeds above the URDF's limits; ``"stop"``: end the run
        with status ``"velocity_limit"`` at the first sample where one is exceeded.
    integrator, substeps, step_error
        How the held-torque dynamics are integrated from one sample to the next: ``"rk4"``,
        the classical fourth-order Runge-Kutta method in ``substeps`` equal steps per control
        period (error ``O((h/substeps)^4)``); ``"rosenbrock"``, ROS34PW2, linearly implicit in the
        joint friction (order 3, stable at any friction slope: :mod:`dvfc.analysis.rosenbrock`);
        ``"auto"`` (the default), ROS34PW2 for a plant with dry (Coulomb) friction and RK4 for one without
        (:meth:`method`); or ``"cvodes"``, CVODES restarted at every sample with the run's error
        tolerances (about 5x slower). ``substeps = "auto"``: the
        fewest of 1, 2, 4, ... :data:`MAX_AUTO_SUBSTEPS` whose relative local error over one
        period, estimated by step doubling at the start of the run, is at most ``step_error``
        (:class:`SubstepChoice`; docs/implementation.md).
    latency_jitter, frame_drop, outlier_probability, outlier_size
        Timing and detection faults, drawn per image from the run's fault stream
        (:meth:`arrivals`): up to ``latency_jitter`` further whole control periods of latency
        (uniform), the probability that an image is lost, and per feature point the
        probability of a wrong detection ``outlier_size`` px away in a uniform direction.
    """

    control_rate: float
    camera_rate: float
    latency: float = 0.0
    pixel_noise: float = 0.0
    quantization: float = 0.0
    saturate: bool = False
    torque_scale: float = 1.0
    velocity_limits: Literal["report", "stop"] = "report"
    seed: int = 0
    integrator: Literal["auto", "rk4", "rosenbrock", "cvodes"] = "auto"
    substeps: int | Literal["auto"] = "auto"
    step_error: float = STEP_ERROR
    latency_jitter: int = 0
    frame_drop: float = 0.0
    outlier_probability: float = 0.0
    outlier_size: float = 0.0

    def method(self, dry_friction: bool) -> Method | None:
        """The fixed-step integrator of a period for a plant with or without ``dry_friction`` (None: CVODES):
        ``"auto"`` takes ROS34PW2 with it, whose smoothed slope at rest makes the held flow stiff (docs/math.md,
        fact 28), and RK4 without (viscous friction is a damping of the joint's own time scale)."""
        if self.integrator == "auto":
            return "rosenbrock" if dry_friction else "rk4"
        return None if self.integrator == "cvodes" else self.integrator

    @property
    def period(self) -> float:
        """Control period ``h`` (s)."""
        return 1.0 / self.control_rate

    def limits(self, urdf: JointLimits) -> JointLimits:
        """The URDF's limits with the efforts scaled by :attr:`torque_scale`."""
        return replace(urdf, effort=urdf.effort * self.torque_scale)

    @property
    def latency_steps(self) -> int:
        """The latency in control periods."""
        return round(self.latency * self.control_rate)

    def capture_steps(self, steps: int) -> np.ndarray:
        """Control samples at which images are captured: the first at or after each camera
        tick, over ``steps`` samples (ticks at whole multiples of ``control_rate /
        camera_rate`` samples, so that a tick exactly at the last sample is not lost to
        rounding)."""
        ticks = np.arange(math.floor(steps * self.camera_rate / self.control_rate + 1e-9) + 1)
        return np.unique(np.ceil(ticks * self.control_rate / self.camera_rate - 1e-9).astype(int))

    def arrivals(self, captures: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The images that arrive, as ``(capture steps, arrival steps)``, both increasing: each
        capture arrives :attr:`latency_steps` plus a uniform draw from ``0 .. latency_jitter``
        periods later unless it is dropped (probability :attr:`frame_drop`) or a later image
        arrives no later (the controller uses the newest image, so an overtaken one is never
        used). Without faults no draw is made: every capture arrives ``latency_steps`` later."""
        arrive = captures + self.latency_steps
        kept = np.ones(len(captures), dtype=bool)
        if self.latency_jitter > 0:
            arrive = arrive + rng.integers(0, self.latency_jitter + 1, len(captures))
            later = np.minimum.accumulate(arrive[::-1])[::-1]  # the earliest arrival from each image on
            kept &= np.append(arrive[:-1] < later[1:], True)
        if self.frame_drop > 0:
            kept &= rng.random(len(captures)) >= self.frame_drop
        return captures[kept], arrive[kept]

    def outliers(self, images: int, size: int, rng: np.random.Generator) -> np.ndarray:
        """Wrong detections of ``images`` images, one row each: per point, with probability
        :attr:`outlier_probability`, a displacement of :attr:`outlier_size` px in a uniform direction
        (``size`` = 2 m entries). Drawn image by image (for each, whether each point is hit, then each
        point's direction), so that the rows are those of ``images`` draws of one image each."""
        if self.outlier_probability == 0:
            return np.zeros((images, size))
        draws = rng.random((images, size))  # per image: size / 2 hits, then size / 2 directions
        hit = draws[:, : size // 2] < self.outlier_probability
        angle = 2 * np.pi * draws[:, size // 2 :]  # as rng.uniform(0, 2 pi) draws them
        shift = self.outlier_size * np.stack([np.cos(angle), np.sin(angle)], axis=2) * hit[:, :, None]
        return shift.reshape(images, size)
