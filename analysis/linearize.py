"""Lower bounds on the true L2 gain from ``w = [tau_d; V_wo]`` to ``x``.

1. The linearisation of the closed loop at its equilibrium, exported as a python-control
   ``StateSpace``: states ``z = [dq; dqd; dpbar; dthetabar; zeta]`` (``Rbar = Rbar* exp(dthetabar)``,
   the target ``g_wo = g_wo* exp(zeta)`` moved by ``V_wo``; :class:`DrivenTargetLoop`),
   inputs ``w``, outputs ``x``. Its
   H-infinity norm is a lower bound on the nonlinear loop's L2 gain (small signals).
2. The nonlinear loop driven from ``x(0) = 0`` by the linearisation's worst input (a
   sinusoid at the peak frequency), its horizon doubled until the gain has converged
   (:func:`sharpest_from_rest`); ``sqrt(int |x|^2 / int |w|^2)`` of that run is a lower bound.
   ``dvfc certify`` (and the report) state it, and ``dvfc verify`` checks Theorem 2 on the
   same run.

Both are lower bounds: a certified gamma below either is a contradiction (a bug).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from dvfc.analysis.simulate import RunStatus, Settings, Simulator, Trajectory
from dvfc.models.driven import DrivenPlanarLoop, DrivenTargetLoop, Sinusoid
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop
from dvfc.models.planar import TASK, PlanarLoop

if TYPE_CHECKING:
    import control


def driven(loop: ClosedLoop, disturbance_input: Callable[[cs.SX], cs.SX] | Sinusoid) -> ClosedLoop:
    """``loop`` in ideal mode, its target at rest at ``g_wo(0)`` unless moved by
    ``disturbance_input``, which supplies all of ``w`` (a :class:`~dvfc.models.driven.DrivenTargetLoop`, or a
    :class:`~dvfc.models.driven.DrivenPlanarLoop` for the planar loop), with the constant reference ``g_d`` (a
    planned one ends there: the equilibrium and the L2 gain are those of the paper's loop). A
    :class:`~dvfc.models.driven.Sinusoid` is the loop's data (its numbers enter the compiled functions as inputs);
    any other signal is an expression of ``t``."""
    fields = {f: getattr(loop, f) for f in ClosedLoop.__dataclass_fields__}
    fields.update(target=loop.target.at_rest(), disturbances=[], mode="ideal", inputs=None, plan=None)
    kind = DrivenPlanarLoop if isinstance(loop, PlanarLoop) else DrivenTargetLoop
    if isinstance(disturbance_input, Sinusoid):
        return kind(**fields, drive=disturbance_input)
    return kind(**fields, disturbance_input=disturbance_input)


def equilibrium_state(loop: ClosedLoop, q_eq: np.ndarray) -> np.ndarray:
    """State of :class:`DrivenTargetLoop` at the equilibrium: ``x = 0`` (and ``z_I = 0``), target at ``g_wo(0)``."""
    z_i = np.zeros(loop.robot.n if loop.integral else 0)
    poses = [loop.reference.position_quaternion(), z_i, loop.target.start.position_quaternion()]
    return np.concatenate([q_eq, np.zeros(loop.robot.n), *poses])


def weight_diagonals(loop: ClosedLoop) -> tuple[np.ndarray, np.ndarray]:
    """The diagonals of ``S`` and ``D_w`` of the loop's generalized plant (docs/math.md, fact 17;
    ones for the paper's)."""
    n, task = loop.robot.n, loop.task_dim
    if loop.performance is None:
        return np.ones(n + 2 * task), np.ones(n + task)
    return loop.performance.output(task), loop.performance.disturbance(task)


def peak_sinusoid(lin: Linearization, amplitude: float = 1e-2) -> Sinusoid:
    """The linearisation's worst input: ``Re(v exp(j omega t))`` with ``v`` the right singular
    vector of ``G(j omega)`` at the peak frequency (a constant when the peak is at ``omega = 0``),
    scaled so that its mean square is ``amplitude^2``. Over a long run from rest its L2 gain
    tends to ``sigma_max(G(j omega))``, a lower bound on the true gain."""
    v, omega = lin.worst_input, lin.peak_frequency
    if omega == 0.0:
        v = np.real(v)
        return Sinusoid(amplitude * v / np.linalg.norm(v), np.zeros(v.size), 0.0)
    scale = amplitude * np.sqrt(2.0) / np.linalg.norm(v)
    return Sinusoid(scale * np.real(v), -scale * np.imag(v), omega)


def rest_simulator(loop: ClosedLoop, lin: Linearization, disturbance: Sinusoid, horizon: float, dt: float = 0.01,
                   jit: bool = False) -> tuple[Simulator, np.ndarray]:  # fmt: skip
    """The ideal loop driven by ``disturbance`` (all of the normalised ``d``, ``w = D_w d``, docs/math.md,
    fact 17), simulated by CVODES over ``horizon`` (compiled under ``jit``: the sinusoid's numbers are inputs of
    the arm's one compiled driven loop), and its equilibrium state (``x(0) = 0``, so ``V(0) = 0``)."""
    _, s_eq = driven_at_rest(loop, cs.SX.zeros(loop.robot.n + loop.task_dim), lin.q_eq)
    d_w = weight_diagonals(loop)[1]
    scaled = Sinusoid(d_w * disturbance.cos_part, d_w * disturbance.sin_part, disturbance.omega)
    return Simulator(driven(loop, scaled), Settings(duration=horizon, dt=dt, jit=jit)), s_eq


def gain_of(traj: Trajectory, k: int = -1) -> float:
    """``sqrt(int |z|^2 / int |d|^2)`` of a run from rest at its sample ``k`` (the last by default):
    Theorem 2 says it is at most every certified gamma."""
    return float(np.sqrt(traj.integrals["z_squared"][k] / traj.integrals["d_squared"][k]))


FROM_REST_HORIZON = 20.0
"""Seconds of the first run from rest of :func:`sharpest_from_rest`, which doubles it until the
measured gain converges (the transient from ``x = 0`` costs the rest)."""


def sharpest_from_rest(
    loop: ClosedLoop,
    lin: Linearization,
    horizon: float = FROM_REST_HORIZON,
    *,
    tolerance: float = 0.01,
    longest: float = 1280.0,
    jit: bool = False,
) -> tuple[float, Trajectory, bool]:
    """The run from rest (:func:`rest_simulator`) under :func:`peak_sinusoid`, its horizon doubled from ``horizon``
    until the measured gain has converged: from rest the transient costs a fixed energy, so
    the gain's shortfall from its steady value decays like ``1/T`` and equals, to first order,
    its rise from ``T/2`` to ``T``; the search stops when that rise is at most ``tolerance``
    of the gain (within about ``tolerance`` of the run's sharpness), or at ``longest`` seconds.
    A longer run that stops (the disturbance, a constant target velocity say, drives the arm to
    a singularity) is dropped for the last one that completed. Each longer run continues the last
    (:meth:`Simulator.continued`): the horizons cost the longest alone; compiled under ``jit``. Returns the gain of
    the run kept, that run, and whether its gain had converged."""
    simulator, s_eq = rest_simulator(loop, lin, peak_sinusoid(lin), horizon, jit=jit)
    kept: tuple[float, Trajectory] | None = None
    while True:
        traj = simulator.run(s_eq) if kept is None else simulator.continued(s_eq, kept[1], horizon)
        ratio = gain_of(traj)
        if traj.status is not RunStatus.OK:
            return (*kept, False) if kept is not None else (ratio, traj, False)
        rise = ratio - gain_of(traj, int(np.searchsorted(traj.t, traj.t[-1] / 2)))
        if rise <= tolerance * ratio:
            return ratio, traj, True
        if 2 * horizon > longest:
            return ratio, traj, False
        kept, horizon = (ratio, traj), 2 * horizon


def newton(step: cs.Function, q0: np.ndarray, iterations: int) -> tuple[np.ndarray, float]:
    """Newton's method ``q += dq`` with ``step(q) = (dq, error)``, from ``q0``, until
    ``|error| < 1e-13`` or ``iterations``: the joint angles and the final residual ``|error|``."""
    q = np.array(q0, dtype=float)
    for _ in range(iterations):
        dq, err = (np.asarray(v).ravel() for v in step(q))
        q = q + dq
        if np.linalg.norm(err) < 1e-13:
            break
    return q, float(np.linalg.norm(np.asarray(step(q)[1])))


def equilibrium_configuration(loop: ClosedLoop, q0: np.ndarray, iterations: int = 50) -> np.ndarray:
    """Joint angles with ``g_wc(q) = g_wo(0) g_d^-1`` (camera at the reference), by Newton's
    method on ``log(g_wc(q)^-1 g_target)`` with the body Jacobian, from ``q0``."""
    target = np.asarray(cs.DM((loop.target.start @ loop.reference.inverse()).as_matrix()))
    r = loop.robot
    error = SE3.from_matrix(r.camera_pose.inverse().as_matrix() @ cs.DM(target)).log()
    step = cs.Function("step", [r.q], [cs.pinv(r.body_jacobian) @ error, error])
    q, residual = newton(step, q0, iterations)
    if residual > 1e-9:
        raise ValueError(f"no equilibrium configuration found from q0 (pose residual {residual:.2e})")
    return q


@dataclass
class Linearization:
    """The linearised loop, its equilibrium, and its H-infinity norm (two ways)."""

    system: control.StateSpace
    reduced: control.StateSpace
    q_eq: np.ndarray
    hinf: float
    peak_gain: float
    peak_frequency: float
    worst_input: np.ndarray


def linearize(loop: ClosedLoop, q0: np.ndarray) -> Linearization:
    """Linearise the ideal loop at its equilibrium (static target at ``g_wo(0)``, ``x = 0``);
    the planar loop by :func:`linearize_planar`."""
    if isinstance(loop, PlanarLoop):
        return linearize_planar(loop, q0)
    q_eq = equilibrium_configuration(loop, q0)
    n = loop.robot.n
    w = cs.SX.sym("w", n + 6)
    model = driven(loop, lambda t: w)
    dq, dqd, dp, dth = cs.SX.sym("dq", n), cs.SX.sym("dqd", n), cs.SX.sym("dp", 3), cs.SX.sym("dth", 3)
    zeta = cs.SX.sym("zeta", 6)
    dz_i = cs.SX.sym("dz_I", n if loop.integral else 0)  # integral action: z_I, with dz_I/dt = xi (fact 20)
    z = cs.vertcat(dq, dqd, dp, dth, dz_i, zeta)
    s_eq = equilibrium_state(loop, q_eq)
    o = 2 * n + 7 + dz_i.shape[0]  # where the target's pose starts
    r_o = np.asarray(cs.DM(loop.target.start.rotation.matrix))
    # local coordinates, exact to first order: Rbar = Rbar* exp(dth), g_wo = g_wo* exp(zeta)
    state = cs.vertcat(
        s_eq[: 2 * n] + cs.vertcat(dq, dqd),
        s_eq[2 * n : 2 * n + 3] + dp,
        _quaternion_product(s_eq[2 * n + 3 : 2 * n + 7], cs.vertcat(1, dth / 2)),
        dz_i,
        s_eq[o : o + 3] + r_o @ zeta[0:3],
        _quaternion_product(s_eq[o + 3 :], cs.vertcat(1, zeta[3:6] / 2)),
    )
    integral = model.xi if loop.integral else cs.SX(0, 1)  # the loop after the start's transient
    local = cs.vertcat(model.qd, model.qdd, model.estimate_rate[0:3], model.estimate_velocity[3:6], integral, w[n:])
    local = cs.substitute(local, model.state, state)
    output = cs.substitute(model.x, model.state, state)
    return _linearization(local, output, z, w, model.t, q_eq, weight_diagonals(loop))



@dataclass(frozen=True)
class FromRest:
    """The linearisation's H-infinity norm at the equilibrium (``peak_gain`` at ``peak_frequency``,
    rad/s, and python-control's ``hinf``) and the run from rest under its worst sinusoid
    (:func:`sharpest_from_rest`: its gain, the run, whether the gain converged): made once and
    shared by the lower bound of ``certify`` and the Theorem 2 checks from rest of ``verify``."""

    peak_gain: float
    peak_frequency: float
    hinf: float
    gain: float
    run: Trajectory
    converged: bool


def from_rest(loop: ClosedLoop, q0: np.ndarray, jit: bool = False) -> FromRest:
    """:func:`linearize` at ``q0`` and :func:`sharpest_from_rest` (compiled under ``jit``; ``ValueError`` when
    the loop has no equilibrium near ``q0``)."""
    lin = linearize(loop, q0)
    return FromRest(lin.peak_gain, lin.peak_frequency, lin.hinf, *sharpest_from_rest(loop, lin, jit=jit))


def _linearization(rate, output, z, w, t, q_eq: np.ndarray, weights: tuple[np.ndarray, np.ndarray]) -> Linearization:
    """The Jacobians of ``dz/dt = rate(z, w)`` and ``x = output(z, w)`` at ``z = 0, w = 0``, as a
    python-control system from ``d`` to ``S x`` (``weights = (S, D_w)`` diagonals, ``w = D_w d``,
    docs/math.md, fact 17), with its H-infinity norm and frequency peak."""
    import control

    jacobians = [cs.jacobian(rate, z), cs.jacobian(rate, w), cs.jacobian(output, z), cs.jacobian(output, w)]
    f = cs.Function("lin", [z, w, t], jacobians)
    a, b, c, d = (np.asarray(m) for m in f(np.zeros(z.shape[0]), np.zeros(w.shape[0]), 0.0))
    s, d_w = weights
    b, c, d = b * d_w, s[:, None] * c, s[:, None] * d * d_w
    system = control.ss(a, b, c, d)
    reduced = observable_quotient(system)
    peak, omega, direction = frequency_peak(reduced)
    return Linearization(system, reduced, q_eq, hinf_norm(reduced), peak, omega, direction)


def _planar_rest(loop: PlanarLoop) -> tuple[np.ndarray, np.ndarray]:
    """The target's horizontal position ``o(0)`` and the desired offset ``p_d``."""
    o0 = np.asarray(cs.DM(loop.target.start.translation)).ravel()[:TASK]
    return o0, np.asarray(cs.DM(loop.reference.translation)).ravel()[:TASK]


def driven_at_rest(loop: ClosedLoop, w: cs.SX, q_eq: np.ndarray) -> tuple[ClosedLoop, np.ndarray]:
    """``loop`` (the paper's or the planar one) driven by the disturbance symbol ``w``, and its
    state at the equilibrium with joint angles ``q_eq``."""
    model = driven(loop, lambda t: w)
    if not isinstance(loop, PlanarLoop):
        return model, equilibrium_state(loop, q_eq)
    o0, p_d = _planar_rest(loop)
    return model, np.concatenate([q_eq, np.zeros(loop.robot.n), p_d, o0])


def linearize_planar(loop: PlanarLoop, q0: np.ndarray, iterations: int = 50) -> Linearization:
    """Linearise the reduced planar loop at its equilibrium: target at rest at ``o(0)``, camera
    at ``o(0) - p_d`` (joint angles by Newton's method with ``pinv(J_p)`` from ``q0``), ``x = 0``."""
    n = loop.robot.n
    w = cs.SX.sym("w", n + TASK)
    model, _ = driven_at_rest(loop, w, np.asarray(q0, dtype=float))
    assert isinstance(model, PlanarLoop), "the planar loop driven is planar"
    o0, p_d = _planar_rest(loop)
    error = cs.DM(o0 - p_d) - model.camera_position
    step = cs.Function("step", [model.q], [cs.pinv(model.task_jacobian) @ error, error])
    q, residual = newton(step, q0, iterations)
    if residual > 1e-9:
        raise ValueError("no equilibrium configuration found from q0 (the target is out of reach)")
    z = cs.SX.sym("z", model.n_state)
    state = cs.DM(driven_at_rest(loop, w, q)[1]) + z
    rate = cs.substitute(model.state_rate, model.state, state)
    output = cs.substitute(model.x, model.state, state)
    return _linearization(rate, output, z, w, model.t, q, weight_diagonals(loop))


def _quaternion_product(p: np.ndarray | cs.SX, q):
    """The quaternion product ``p (x) q`` of ``[w; x; y; z]`` columns (``p`` numbers or symbols)."""
    p = p if isinstance(p, cs.SX) else cs.DM(p)
    s1, v1 = p[0], p[1:4]
    s2, v2 = q[0], q[1:4]
    return cs.vertcat(s1 * s2 - v1.T @ v2, s1 * v2 + s2 * v1 + cs.cross(v1, v2))


def observable_quotient(sys: control.StateSpace, tol: float = 1e-9) -> control.StateSpace:
    """The loop on the quotient by its unobservable equilibrium directions.

    Moving the target and the camera together leaves ``x = 0``: those directions span
    ``ker [A; C]``, an ``A``-invariant subspace with eigenvalue 0 that ``x`` never sees.
    With ``V`` an orthonormal basis of its complement, ``(V^T A V, V^T B, C V, D)`` has
    the same transfer function and no poles at 0.
    """
    import control

    a, b, c, d = sys.A, sys.B, sys.C, sys.D
    _, sv, vh = np.linalg.svd(np.vstack([a, c]))
    rank = int(np.sum(sv > tol * sv[0]))
    keep = vh[:rank].T
    return control.ss(keep.T @ a @ keep, keep.T @ b, c @ keep, d)


MARGINAL = 1e-9
"""A pole with real part above ``-MARGINAL max(1, |pole|)`` counts as on the imaginary axis."""

MARGINAL_POLES = (
    "the linearised loop has poles on the imaginary axis (modes that neither grow nor decay): "
    "its H-infinity norm is infinite"
)
"""What an infinite :func:`hinf_norm` means, in one line."""


def hinf_norm(sys: control.StateSpace) -> float:
    """H-infinity norm by python-control (Hamiltonian bisection; slycot not needed); ``inf``
    when a pole lies on the imaginary axis (:data:`MARGINAL`, :data:`MARGINAL_POLES`), which
    python-control would only warn about.

    ``control.system_norm`` 0.10.2 mis-sizes a non-square ``D``; zero input columns (which
    change no singular value) make the system square first.
    """
    import control

    poles = np.linalg.eigvals(sys.A)
    if poles.size and np.any(poles.real > -MARGINAL * np.maximum(1.0, np.abs(poles))):
        return math.inf
    extra = sys.noutputs - sys.ninputs
    b, d = sys.B, sys.D
    if extra > 0:
        b = np.hstack([b, np.zeros((b.shape[0], extra))])
        d = np.hstack([d, np.zeros((d.shape[0], extra))])
    with warnings.catch_warnings():  # near the axis: the value stands, the library's doubt is not ours to print
        warnings.simplefilter("ignore", UserWarning)
        return float(control.system_norm(control.ss(sys.A, b, sys.C, d), p="inf"))


def frequency_peak(sys: control.StateSpace) -> tuple[float, float, np.ndarray]:
    """Largest singular value of ``G(jw) = C (jwI - A)^-1 B + D`` over ``w = 0`` and a log grid
    (1e-3 to 1e4 rad/s) refined around the peak, with the peak frequency and the worst
    input direction. Every value is attained, so it is a lower bound on the H-infinity norm."""
    a, b, c, d = sys.A, sys.B, sys.C, sys.D
    eye = np.eye(a.shape[0])

    def sigma(w: float) -> tuple[float, np.ndarray]:
        _, s, vh = np.linalg.svd(c @ np.linalg.solve(1j * w * eye - a, b) + d)
        return float(s[0]), vh[0].conj()

    grid = np.r_[0.0, np.logspace(-3, 4, 1400)]
    k = int(np.argmax([sigma(w)[0] for w in grid]))
    fine = np.linspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 400)
    best = max(fine, key=lambda w: sigma(w)[0])
    value, direction = sigma(best)
    return value, float(best), direction
