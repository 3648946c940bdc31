"""Joint-torque disturbances ``tau_d(t)`` of (33), as closed-form functions of time."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from dvfc.models.lie import Matrix


@dataclass(frozen=True)
class Step:
    """``tau_d = amplitude`` for ``t >= start``, 0 before."""

    amplitude: np.ndarray
    start: float

    def __call__(self, t: Matrix) -> Matrix:
        return cs.if_else(t >= self.start, 1.0, 0.0) * cs.DM(self.amplitude)

    @property
    def breakpoints(self) -> list[float]:
        return [self.start]

    @property
    def bound(self) -> float:
        """``sup_t |tau_d(t)| = |amplitude|``."""
        return float(np.linalg.norm(self.amplitude))


@dataclass(frozen=True)
class Sine:
    """``tau_d = amplitude sin(2 pi frequency t + phase)``."""

    amplitude: np.ndarray
    frequency: float
    phase: float = 0.0

    def __call__(self, t: Matrix) -> Matrix:
        return cs.sin(2 * np.pi * self.frequency * t + self.phase) * cs.DM(self.amplitude)

    @property
    def breakpoints(self) -> list[float]:
        return []

    @property
    def bound(self) -> float:
        """``sup_t |tau_d(t)| <= |amplitude|``."""
        return float(np.linalg.norm(self.amplitude))


@dataclass(frozen=True)
class BandLimitedNoise:
    """Band-limited noise: per joint, a sum of ``tones`` sinusoids with frequencies drawn
    uniformly in ``(0, bandwidth]`` Hz and random phases, scaled to the given RMS.

    Smooth and deterministic for a seed, so the integrator treats it like any other
    input and the same seed gives the same run.
    """

    rms: np.ndarray
    bandwidth: float
    seed: int
    tones: int = 32

    def __call__(self, t: Matrix) -> Matrix:
        rng = np.random.default_rng(self.seed)
        n = len(self.rms)
        freqs = rng.uniform(0.0, self.bandwidth, size=(n, self.tones))
        freqs = np.where(freqs == 0.0, self.bandwidth, freqs)
        phases = rng.uniform(0.0, 2 * np.pi, size=(n, self.tones))
        scale = np.sqrt(2.0 / self.tones)
        rows = [
            self.rms[j] * scale * cs.sum1(cs.sin(2 * np.pi * cs.DM(freqs[j]) * t + cs.DM(phases[j]))) for j in range(n)
        ]
        return cs.vertcat(*rows)

    @property
    def breakpoints(self) -> list[float]:
        return []

    @property
    def bound(self) -> float:
        """``sup_t |tau_d(t)| <= |rms| sqrt(2 tones)``: each joint's sum of ``tones`` sines of
        amplitude ``rms_j sqrt(2 / tones)`` is at most ``rms_j sqrt(2 tones)`` in magnitude."""
        return float(np.linalg.norm(self.rms) * np.sqrt(2.0 * self.tones))


Disturbance = Step | Sine | BandLimitedNoise


def torque_bound(components: list[Disturbance]) -> float:
    """A bound on ``sup_t |tau_d(t)|`` (Euclidean norm): the sum of the components' bounds
    (triangle inequality)."""
    return float(sum(c.bound for c in components))


def torque(components: list[Disturbance], t: Matrix, n: int) -> Matrix:
    """The total joint-torque disturbance ``tau_d(t)`` (n entries)."""
    total = cs.DM.zeros(n)
    for c in components:
        total = total + c(t)
    return total
