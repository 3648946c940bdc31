"""How the loop runs on a robot: the scenario's ``[implementation]``."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from dvfc.models.robot import JointLimits


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
    integrator, substeps
        How the held-torque dynamics are integrated from one sample to the next: ``"rk4"``,
        the classical fourth-order Runge-Kutta method in ``substeps`` equal steps per control
        period (error ``O((h/substeps)^4)``), or ``"cvodes"``, CVODES restarted at every
        sample with the run's error tolerances (about 5x slower).
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
    integrator: Literal["rk4", "cvodes"] = "rk4"
    substeps: int = 1

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
