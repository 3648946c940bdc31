"""The control period of a plant with joint friction, integrated linearly implicitly in the friction
(docs/math.md, fact 28).

Over a control period the torque is held and the plant is ``M(q) qdd = tau - C(q, qd) qd - g(q) - f(qd)``
with the joint friction ``f(qd) = b qd + c tanh(qd / eps)`` (:func:`dvfc.models.errors.friction_torque`). Its
slope at rest, ``b + c / eps``, makes the flow stiff: wrist 3 of the UR5 cell with ``c`` = 1.251 N m relaxes at
``(M^-1)_66 c / eps`` = 1500 1/s, three times a 2 ms period, past the stability limit of the classical RK4
step (2.785 on the real axis). The method here is ROS34PW2 (Rang and Angermann, BIT 45, 2005), a
Rosenbrock-W method: each stage solves a linear system with a matrix ``W`` that need only approximate the
Jacobian, its order 3 holds for any ``W``, and its stability function is L-stable (``R(inf) = 0``). ``W`` is the
part of the Jacobian the friction and the kinematics make, ``[[0, I], [0, -M^-1 D]]`` on ``(q, qd)`` with
``D = diag(f'(qd))`` at the step's start (zero on every other state): each stage is one ``n x n`` solve with
``M + h gamma D``. Without friction the period is integrated by classical RK4 instead (more accurate on the
non-stiff flow, fact 28).
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as cs

GAMMA = 4.3586652150845900e-01
"""The diagonal ``gamma`` of ROS34PW2 (the same at every stage)."""

ALPHA = (
    (),
    (8.7173304301691801e-01,),
    (8.4457060015369423e-01, -1.1299064236484185e-01),
    (0.0, 0.0, 1.0),
)
"""``alpha_ij``: the stage ``i`` is evaluated at ``y + sum_j alpha_ij k_j``, at ``t + (sum_j alpha_ij) h``."""

COUPLING = (
    (),
    (-8.7173304301691801e-01,),
    (-9.0338057013044082e-01, 5.4180672388095326e-02),
    (2.4212380706095346e-01, -1.2232505839045147e00, 5.4526025533510214e-01),
)
"""``gamma_ij`` (``j < i``): the stage ``i``'s right side gains ``h W sum_j gamma_ij k_j``."""

WEIGHTS = (2.4212380706095346e-01, -1.2232505839045147e00, 1.5452602553351020e00, 4.3586652150845900e-01)
"""``b_i``: the step is ``y + sum_i b_i k_i`` (order 3)."""

EMBEDDED = (3.7810903145819369e-01, -9.6042292212423178e-02, 5.0000000000000000e-01, 2.1793326075422950e-01)
"""``bhat_i``: the embedded step ``y + sum_i bhat_i k_i`` of order 2; its difference from the step, ``sum_i (b_i -
bhat_i) k_i``, estimates the embedded step's local error, and so bounds the step's own (of a higher order) where
the step is small enough for the orders to show."""

ORDER = 3
"""The order of the step, for any ``W`` (the step-doubling estimate's ``2^p``)."""

Rate = Callable[[cs.MX, cs.MX], list[cs.MX]]


def w_step(rate: Rate, t: cs.MX, s: cs.MX, h: float, n: int, mass: cs.MX, slope: cs.MX) -> tuple[cs.MX, cs.MX, cs.MX]:
    """One ROS34PW2 step of ``h`` from ``(t, s)`` for a state ``[q; qd; ...]`` of ``n`` joints: ``rate(t, s)`` is
    ``[ds/dt, quadratures' rates]``, ``mass`` the plant's ``M(q)`` and ``slope`` the friction's ``f'(qd)`` (``n``)
    at the start. Each stage solves ``(I - h gamma W) k_i = h f(Y_i) + h W sum_j gamma_ij k_j`` with
    ``W = [[0, I], [0, -M^-1 D]]`` on ``(q, qd)``: for the speeds ``(M + h gamma D) k_qd = h M f_qd - h D v_qd``
    (``v = sum_j gamma_ij k_j``), then ``k_q = h f_q + h v_qd + h gamma k_qd``, the other states explicit.
    Returns the state after the step, the quadratures' increments (their stages' weights are the step's) and the
    local error estimate ``sum_i (b_i - bhat_i) k_i`` of the state (:data:`EMBEDDED`)."""
    system = mass + h * GAMMA * cs.diag(slope)
    stages: list[cs.MX] = []
    quadrature_rates: list[cs.MX] = []
    for i in range(len(WEIGHTS)):
        point = s + sum((a * k for a, k in zip(ALPHA[i], stages, strict=True)), cs.MX.zeros(s.shape))
        f, q_rate = rate(t + sum(ALPHA[i]) * h, point)
        v = sum((g * k[n : 2 * n] for g, k in zip(COUPLING[i], stages, strict=True)), cs.MX.zeros(n))
        k_qd = cs.solve(system, h * (mass @ f[n : 2 * n]) - h * slope * v)
        k_q = h * f[:n] + h * v + h * GAMMA * k_qd
        stages.append(cs.vertcat(k_q, k_qd, h * f[2 * n :]))
        quadrature_rates.append(q_rate)
    after = s + sum(b * k for b, k in zip(WEIGHTS, stages, strict=True))
    quadrature = h * sum(b * r for b, r in zip(WEIGHTS, quadrature_rates, strict=True))
    error = sum((b - bhat) * k for b, bhat, k in zip(WEIGHTS, EMBEDDED, stages, strict=True))
    return after, quadrature, error
