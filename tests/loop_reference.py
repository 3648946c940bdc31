"""Independent sample-by-sample references of the loop as implemented: what the simulator and
fact 14's monodromy compute, rebuilt by hand (rational capture times, RK4 written out, the held
linearised flow integrated by ``solve_ivp``) for the tests to compare against."""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction

import numpy as np
from scipy.integrate import solve_ivp


def captured(k: int, control_rate: Fraction, camera_rate: Fraction) -> bool:
    """Whether control sample ``k >= 1`` is the first at or after some camera tick
    ``j / camera_rate``: the first tick after ``t_(k-1)`` is not after ``t_k`` (exact rational
    arithmetic)."""
    first_tick = math.floor((k - 1) * camera_rate / control_rate) + 1
    return first_tick / camera_rate <= k / control_rate


def rk4_period(rate: Callable, t: float, s: np.ndarray, u: np.ndarray, h: float, substeps: int) -> np.ndarray:
    """The state after one control period ``h`` from ``(t, s)`` with the input ``u`` held:
    ``substeps`` classical RK4 steps of ``rate(t, s, u)``."""
    step = h / substeps
    for i in range(substeps):
        t0 = t + i * step
        k1 = np.asarray(rate(t0, s, u)).ravel()
        k2 = np.asarray(rate(t0 + step / 2, s + step / 2 * k1, u)).ravel()
        k3 = np.asarray(rate(t0 + step / 2, s + step / 2 * k2, u)).ravel()
        k4 = np.asarray(rate(t0 + step, s + step * k3, u)).ravel()
        s = s + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s


def linearised_run(system, imp, start: np.ndarray, integral: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """Two common periods of fact 14's linearised sampled loop from the monodromy's state ``start``
    (``z``, the held ``e``, the images in flight), simulated independently: the continuous
    linearised dynamics integrated by ``solve_ivp`` (DOP853, rtol 1e-12) between samples with the
    held torque ``tau_k = F z_k + F_e e_k`` and the held ``e``, every sample's ``C z`` kept in a
    delay line, the image of each capture (first sample at or after each camera tick, by exact
    rational arithmetic) applied ``latency`` later; with ``integral`` joints, the last ``integral``
    entries of ``z`` (``z_I``) advanced by ``h xi_k`` after each period. Returns ``z``, ``e`` and
    the common period in samples."""
    lin = system.lin
    nz, ne = lin.b_e.shape
    z, e = start[:nz], start[nz : nz + ne]
    control, camera = Fraction(imp.control_rate).limit_denominator(), Fraction(imp.camera_rate).limit_denominator()
    period = (control / camera).numerator  # samples after which the captures repeat
    lag = round(imp.latency * imp.control_rate)
    capture = lambda k: captured(k + 100 * period, control, camera)  # noqa: E731
    before = [k for k in range(-lag, 0) if capture(k)]  # the images in flight at the start
    line = {k: start[nz + ne * (i + 1) : nz + ne * (i + 2)] for i, k in enumerate(before)}
    h, c = 1 / imp.control_rate, system.output
    for k in range(2 * period):
        line[k] = c @ z
        if capture(k - lag):
            e = line[k - lag]
        tau = lin.f @ z + lin.f_e @ e
        xi = lin.xi @ z + lin.xi_e @ e if integral else None
        flow = solve_ivp(lambda t, y, u=tau, m=e: lin.a @ y + lin.b_tau @ u + lin.b_e @ m, (0.0, h), z,
                         method="DOP853", rtol=1e-12, atol=1e-16)  # fmt: skip
        z = flow.y[:, -1]
        if integral:
            z[-integral:] += h * xi
    return z, e, period
