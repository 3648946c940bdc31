"""Adversarial check of the operating envelope (docs/math.md, fact 7): the worst disturbance found.

From the equilibrium (``x(0) = 0``, so ``V(0) = 0``, inside every certified set) the
nonlinear loop is driven by a piecewise-constant disturbance ``w = [tau_d; v; omega]``
within the envelope's bounds on every piece (``|tau_d| <= torque``, ``|v| <= target_speed``,
``|omega| <= target_rate``: a piecewise-smooth target motion). The search maximises the
storage ``V(T)`` at the horizon: the gradient comes from CVODES' adjoint sensitivities
(CasADi reverse mode), and each step moves to the disturbance that maximises the
linearised objective over those balls (each block of the gradient scaled to its bound, a
conditional-gradient step). Fact 7 says ``V(T) <= c_inf (1 - exp(-kappa T))``: the worst
found must stay below, and the ratio measures the envelope's tightness. A search finds a
lower bound on the worst case, never a certificate.
"""

from __future__ import annotations

import math

import casadi as cs
import numpy as np

from dvfc.analysis.envelope import DisturbanceBounds
from dvfc.analysis.linearize import driven_at_rest, equilibrium_configuration
from dvfc.models.loop import ClosedLoop


def _blocks(n: int, task: int, bounds: DisturbanceBounds) -> list[tuple[slice, float]]:
    """The pieces of ``w`` and their sup-norm bounds: torque, target velocity (linear, angular)."""
    if task == 6:
        return [(slice(0, n), bounds.torque), (slice(n, n + 3), bounds.target_speed),
                (slice(n + 3, n + 6), bounds.target_rate)]  # fmt: skip
    return [(slice(0, n), bounds.torque), (slice(n, n + task), bounds.target_speed)]


def _to_balls(direction: np.ndarray, blocks: list[tuple[slice, float]]) -> np.ndarray:
    """Each block of each piece (columns) scaled to the length of its bound."""
    out = np.zeros_like(direction)
    for where, bound in blocks:
        part = direction[where]
        norm = np.linalg.norm(part, axis=0, keepdims=True)
        out[where] = np.where(norm > 0, bound * part / np.where(norm > 0, norm, 1.0), 0.0)
    return out


BACKTRACKS = 4
"""Disturbances the search may drop: one on which the integrator stops (it drove the arm to where
``J_b`` is singular, outside the envelope's premise) is replaced by the midpoint between it and
the last one that ran (half of it when none has), within the bounds by convexity."""


def worst_disturbance(
    loop: ClosedLoop,
    q0: np.ndarray,
    bounds: DisturbanceBounds,
    *,
    horizon: float = 4.0,
    intervals: int = 8,
    iterations: int = 4,
    seed: int = 0,
) -> dict:
    """The largest ``V(T)`` found from the equilibrium near ``q0`` under disturbances within
    ``bounds`` (module text), with the control and estimation errors there, the disturbance
    (one row per piece) and how many disturbances were dropped (:data:`BACKTRACKS`); a
    ``RuntimeError`` when the integrator stopped on every one tried."""
    n, task = loop.robot.n, loop.task_dim
    w_sym = cs.SX.sym("w", n + task)
    model, s_eq = driven_at_rest(loop, w_sym, equilibrium_configuration(loop, q0))
    h = horizon / intervals
    dae = {"x": model.state, "t": model.t, "p": w_sym, "ode": model.state_rate}
    step = cs.integrator("piece", "cvodes", dae, 0.0, h,
                         {"abstol": 1e-10, "reltol": 1e-10, "disable_internal_warnings": True})  # fmt: skip
    rotational = task == 6
    angles = [cs.acos(cs.fmin(1, cs.fmax(-1, (cs.trace(p.rotation.matrix) - 1) / 2)))
              for p in (model.control_pose_error, model.estimation_pose_error)] if rotational else [0, 0]  # fmt: skip
    outputs = cs.Function("out", [model.t, model.state], [model.storage, model.e_c, model.e_e, *angles])
    w = cs.MX.sym("W", n + task, intervals)
    state = cs.MX(cs.DM(s_eq))
    for k in range(intervals):
        state = step(x0=state, p=w[:, k])["xf"]
    v_final, e_c, e_e, th_c, th_e = outputs(horizon, state)
    search = cs.Function("J", [w], [v_final, cs.gradient(v_final, w), e_c, e_e, th_c, th_e])
    blocks = _blocks(n, task, bounds)
    current = _to_balls(np.random.default_rng(seed).normal(size=(n + task, intervals)), blocks)
    best, last, dropped = None, None, 0
    while iterations > 0:
        try:
            value, gradient, e_c_t, e_e_t, th_c_t, th_e_t = (np.asarray(v) for v in search(current))
        except RuntimeError:  # the integrator stopped: the disturbance drove the arm where J_b is singular
            dropped += 1
            if dropped > BACKTRACKS:
                break
            current = current / 2 if last is None else (last + current) / 2  # still within the bounds
            continue
        iterations -= 1
        if best is None or value.item() > best["V"]:
            best = {"V": value.item(), "e_c": e_c_t.ravel(), "e_e": e_e_t.ravel(), "w": current,
                    "angles": (math.degrees(th_c_t.item()), math.degrees(th_e_t.item()))}  # fmt: skip
        if not np.all(np.isfinite(gradient)) or not np.any(gradient):
            break
        last, current = current, _to_balls(gradient, blocks)
    if best is None:
        raise RuntimeError("the integrator stopped on every disturbance tried")
    e_c, e_e = best["e_c"], best["e_e"]
    th_c, th_e = best["angles"] if rotational else (None, None)
    return {
        "V": best["V"],
        "horizon_s": horizon,
        "intervals": intervals,
        "errors": {
            "p_ec": float(np.linalg.norm(e_c[:3])),
            "theta_ec_deg": th_c,
            "p_ee": float(np.linalg.norm(e_e[:3])),
            "theta_ee_deg": th_e,
        },
        "w": best["w"].T.tolist(),
        "dropped": dropped,
    }
