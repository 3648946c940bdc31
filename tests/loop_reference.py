"""Independent sample-by-sample references of the loop as implemented: what the simulator and
fact 14's monodromy compute, rebuilt by hand (rational capture times, RK4 written out, the held
linearised flow integrated by ``solve_ivp``) for the tests to compare against."""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm


def captured(k: int, control_rate: Fraction, camera_rate: Fraction) -> bool:
    """Whether control sample ``k >= 1`` is the first at or after some camera tick
    ``j / camera_rate``: the first tick after ``t_(k-1)`` is not after ``t_k`` (exact rational
    arithmetic)."""
    first_tick = math.floor((k - 1) * camera_rate / control_rate) + 1
    return first_tick / camera_rate <= k / control_rate


def twist_hat(v: np.ndarray) -> np.ndarray:
    """``hat(V)`` of a twist ``[v; w]`` (4 x 4)."""
    w = v[3:]
    return np.array([[0, -w[2], w[1], v[0]], [w[2], 0, -w[0], v[1]], [-w[1], w[0], 0, v[2]], [0, 0, 0, 0.0]])


def twist_exp(v: np.ndarray) -> np.ndarray:
    """``exp(hat(V))`` by scipy's matrix exponential."""
    return expm(twist_hat(v))


def pose_of(state: np.ndarray) -> np.ndarray:
    """The homogeneous matrix of ``[p; quat]`` (``quat = [w, x, y, z]``, normalised), in NumPy."""
    w, x, y, z = state[3:7] / np.linalg.norm(state[3:7])
    g = np.eye(4)
    g[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                 [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                 [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]  # fmt: skip
    g[:3, 3] = state[:3]
    return g


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


def held_period(
    rate: Callable,
    t: float,
    s: np.ndarray,
    tau: np.ndarray,
    e: np.ndarray,
    v_k: np.ndarray,
    u_k: np.ndarray,
    h: float,
    substeps: int,
    n: int,
) -> np.ndarray:
    """One control period of the loop as implemented, by hand: ``substeps`` RK4 steps of ``rate(t, s,
    hold)`` with ``hold = [tau; e; V_k; U_k]``, then the estimate ``s[2n : 2n + 7]`` replaced by
    ``expm(-h hat(V_k)) gbar expm(h hat(U_k))`` (scipy's matrix exponential; docs/math.md, fact 22), its
    quaternion of the sign nearer the state's."""
    gbar = twist_exp(-h * v_k) @ pose_of(s[2 * n : 2 * n + 7]) @ twist_exp(h * u_k)
    after = rk4_period(rate, t, s, np.concatenate([tau, e, v_k, u_k]), h, substeps)
    quat = _quaternion(gbar[:3, :3])
    after[2 * n : 2 * n + 7] = np.concatenate([gbar[:3, 3], quat if quat @ s[2 * n + 3 : 2 * n + 7] >= 0 else -quat])
    return after


def _quaternion(r: np.ndarray) -> np.ndarray:
    """A unit quaternion of the rotation ``r`` (Shepperd's method, the largest of the four squares)."""
    trace = np.trace(r)
    squares = np.array([1 + trace, 1 + 2 * r[0, 0] - trace, 1 + 2 * r[1, 1] - trace, 1 + 2 * r[2, 2] - trace])
    i = int(np.argmax(squares))
    q = np.empty(4)
    q[i] = np.sqrt(squares[i]) / 2
    pairs = {0: (r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]),
             1: (r[2, 1] - r[1, 2], r[0, 1] + r[1, 0], r[0, 2] + r[2, 0]),
             2: (r[0, 2] - r[2, 0], r[0, 1] + r[1, 0], r[1, 2] + r[2, 1]),
             3: (r[1, 0] - r[0, 1], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1])}  # fmt: skip
    others = [j for j in range(4) if j != i]
    for j, value in zip(others, pairs[i], strict=True):
        q[j] = value / (4 * q[i])
    return q


def linearised_run(
    system, imp, start: np.ndarray, integral: int = 0, torque: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Two common periods of fact 14's linearised sampled loop from the monodromy's state ``start``
    (``z``, the held ``e``, the images in flight), simulated independently: the continuous
    linearised dynamics integrated by ``solve_ivp`` (DOP853, rtol 1e-12) between samples with the
    held torque ``tau_k = F z_k + F_e e_k`` and the held ``e``, every sample's ``C z`` kept in a
    delay line, the image of each capture (first sample at or after each camera tick, by exact
    rational arithmetic) applied ``latency`` later, the observer's inputs ``o_k = O z_k + O_e e_k``
    held over the period like the torque (the program's step, docs/math.md, fact 22); with
    ``integral`` joints, the last ``integral`` entries of ``z`` (``z_I``) advanced by ``h xi_k`` after
    each period. With ``torque`` (``(samples, parts, n)``), as many control periods as its rows, each driven
    by one more joint torque, constant on each of ``parts`` equal parts of the period (integrated part by part).
    Returns ``z``, ``e`` and the common period in samples."""
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
    for k in range(2 * period if torque is None else len(torque)):
        line[k] = c @ z
        if capture(k - lag):
            e = line[k - lag]
        tau, o = lin.f @ z + lin.f_e @ e, lin.o @ z + lin.o_e @ e
        xi = lin.xi @ z + lin.xi_e @ e if integral else None
        for d in np.zeros((1, len(tau))) if torque is None else torque[k]:
            flow = solve_ivp(lambda t, y, u=tau + d, m=e, v=o: lin.a @ y + lin.b_tau @ u + lin.b_e @ m + lin.b_o @ v,
                             (0.0, h / (1 if torque is None else torque.shape[1])), z, method="DOP853", rtol=1e-12,
                             atol=1e-16)  # fmt: skip
            z = flow.y[:, -1]
        if integral:
            z[-integral:] += h * xi
    return z, e, period
