"""Every claim of the paper, checked on trajectories integrated by CVODES.

Each :class:`Claim` names the paper's statement, the quantity measured, the bound it
must meet and whether it does. Measurements that the paper does not claim (the image
loop's gap from the ideal one) are reported with ``passed = None``.

Bounds: identity residuals are relative (see :func:`dvfc.analysis.simulate.identity_residuals`)
and must be <= 1e-6 at CVODES tolerances 1e-10; pointwise inequalities on the storage along a
run are checked with a slack of 1e-9 times the storage scale (the integration's error in ``V``);
a slack of computed terms compared with zero (an integral inequality, a distance outside a
region) with :func:`roundoff` of its terms (docs/math.md, "Tolerances").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import StrEnum

import casadi as cs
import numpy as np

from dvfc.analysis.adversary import worst_disturbance
from dvfc.analysis.compile import ahead
from dvfc.analysis.envelope import DisturbanceBounds, level_bounds
from dvfc.analysis.implementation import SubstepChoice
from dvfc.analysis.linearize import FromRest, from_rest, weight_diagonals
from dvfc.analysis.quiet import silenced
from dvfc.analysis.sampled import as_implemented, limit_record, robot_limits
from dvfc.analysis.simulate import RunStatus, Settings, Simulator, Trajectory, identity_residuals, rotation_angle
from dvfc.analysis.start import run_regions
from dvfc.models.disturbance import BandLimitedNoise
from dvfc.models.kinematic import VisualFeedbackSystem
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop
from dvfc.models.planar import PlanarLoop

IDENTITY_TOL = 1e-6

ROUNDOFF = 1e-12
"""Relative round-off of a slack of computed terms: 1e-12 is about 4500 ulp of double precision, the
error of summing several terms each accumulated over thousands of output steps (an ulp of the
running total at each); a violation of 1e-9 of the terms, 1000 times more, still fails."""


STORAGE_ULPS = 4
"""Ulps of the numbers it cancels (:func:`storage_floor`) to which the storage is evaluated."""


def roundoff(*terms: np.ndarray | float, floor: float = 0.0) -> float:
    """The tolerance of comparing with zero a slack made of ``terms``: :data:`ROUNDOFF` times the sum
    of their largest magnitudes over the run, plus ``floor``, the round-off of a term computed from
    larger numbers than itself (:func:`storage_floor`). A slack ``>= -roundoff(...)`` passes."""
    return ROUNDOFF * float(sum(np.max(np.abs(np.asarray(t, dtype=float)), initial=0.0) for t in terms)) + floor


def storage_floor(loop: ClosedLoop | None) -> float:
    """The round-off of one evaluation of the storage, whatever its size: each rotation error
    ``phi(R) = (3 - tr R) / 2`` (Lemma 1, (29)) subtracts numbers up to 3, so ``V`` is known to
    :data:`STORAGE_ULPS` ulp of ``3/2 (w_rc + w_re)`` (it evaluates to 2.2e-16, one ulp of 1, at the
    xArm7's equilibrium ``x = 0``); 0 for the planar storage (P8), a sum of squares. None: the
    kinematic storages of :func:`kinematic_claims` (unit weights)."""
    if isinstance(loop, PlanarLoop):
        return 0.0
    rotation = 2.0 if loop is None else float(loop.weights.w_rc) + float(loop.weights.w_re)
    return STORAGE_ULPS * float(np.finfo(float).eps) * 1.5 * rotation


IMPLEMENTED_TOL = 1e-5
"""Bound on fact 11's residual on the run as implemented: RK4 at the control period truncates
(7e-6 with one step a period on the default example at 500 Hz, 4e-7 with the two its local error
target chooses); CVODES restarted at every sample meets 1e-6. A residual above it names the
setting that brings it within (:func:`integration_hint`)."""


class ClaimStatus(StrEnum):
    """The verdict on a claim (see :class:`Claim`)."""

    PASS = "PASS"
    FAIL = "FAIL"
    MEASURED = "MEASURED"
    INCONCLUSIVE = "INCONCLUSIVE"


@dataclass
class Claim:
    """One claim of the paper checked on a run.

    ``passed``: True (PASS), False (FAIL: the measurement breaks the bound, so the claim is
    false on this run) or None: a measurement the paper does not claim (MEASURED), or, with
    ``inconclusive``, a check that could not be run as designed (INCONCLUSIVE: the run left
    the region where the claim is stated, or the check cannot resolve what it measures).
    A FAIL or an INCONCLUSIVE always carries its reason in ``detail``.
    """

    name: str
    reference: str
    value: float
    bound: str
    passed: bool | None
    detail: str = ""
    inconclusive: bool = False

    def __post_init__(self) -> None:
        self.value = float(self.value)
        self.passed = None if self.passed is None or self.inconclusive else bool(self.passed)
        if self.passed is False and not self.detail:
            self.detail = f"measured {self.value:.3g}, required {self.bound}"
        if self.inconclusive and not self.detail:
            raise ValueError(f"an inconclusive check needs its reason: {self.name}")

    @property
    def status(self) -> ClaimStatus:
        if self.inconclusive:
            return ClaimStatus.INCONCLUSIVE
        return {True: ClaimStatus.PASS, False: ClaimStatus.FAIL, None: ClaimStatus.MEASURED}[self.passed]

    def to_json(self) -> dict:
        return {
            "claim": self.name,
            "paper": self.reference,
            "value": self.value,
            "bound": self.bound,
            "status": self.status,
            "detail": self.detail,
        }


def on_run(name: str, reference: str, traj: Trajectory, value: float, bound: str, holds: bool,
           detail: str = "") -> Claim:
    """A claim measured on ``traj``: FAIL when the measurement breaks the bound (with the run's
    stop message, if any); INCONCLUSIVE when it holds on the part that ran but the run stopped
    early (it left the region where the claim is stated, or ran out of time)."""  # fmt: skip
    if not holds:
        why = f"measured {value:.3g}, required {bound}"
        return Claim(name, reference, value, bound, False, "; ".join(filter(None, (why, detail, traj.message))))
    if traj.status is not RunStatus.OK:
        why = f"holds up to t = {traj.t[-1]:.4g} s, where the run stopped ({traj.message}); not checked beyond"
        return Claim(name, reference, value, bound, None, "; ".join(filter(None, (why, detail))), inconclusive=True)
    return Claim(name, reference, value, bound, True, detail)


def smooth_signal(seed: int, size: int, amplitude: np.ndarray, band: tuple[float, float] = (0.2, 2.0)):
    """A smooth random signal of time: per entry, three sinusoids with random frequencies in
    ``band`` (Hz) and random phases, scaled by ``amplitude``."""
    rng = np.random.default_rng(seed)
    freqs = rng.uniform(*band, (size, 3))
    phases = rng.uniform(0, 2 * np.pi, (size, 3))

    def signal(t):
        waves = [cs.sum1(cs.sin(2 * np.pi * cs.DM(freqs[i]) * t + cs.DM(phases[i]))) / 3 for i in range(size)]
        return cs.DM(amplitude) * cs.vertcat(*waves)

    return signal


def _error_state(traj: Trajectory) -> np.ndarray:
    return np.hstack([traj["xi"], traj["e_c"], traj["e_e"]])


def static(loop: ClosedLoop) -> ClosedLoop:
    """The same loop with the target at rest (:meth:`~dvfc.models.target.TargetMotion.at_rest`) and no torque
    disturbance (w = 0)."""
    return replace(loop, target=loop.target.at_rest(), disturbances=[])


def theorem_1(loop: ClosedLoop, s0: np.ndarray, settings: Settings) -> list[Claim]:
    traj = Simulator(replace(static(loop), mode="ideal"), settings).run(s0)
    v = traj[storage_of(traj)][:, 0]
    x = _error_state(traj)
    residual = identity_residuals(traj)["dissipation"]
    rise = float(np.diff(v).max(initial=0.0) / v[0])
    ratio = float(np.linalg.norm(x[-1]) / np.linalg.norm(x[0]))
    bound = f"|x(T)| / |x(0)| <= 1e-2 at T = {settings.duration:g} s"
    if traj.status is RunStatus.OK:
        converged = Claim("x -> 0", "Theorem 1", ratio, bound, ratio <= 1e-2)
    else:
        converged = Claim("x -> 0", "Theorem 1", ratio, bound, None, f"the run stopped before T: {traj.message}",
                          inconclusive=True)  # fmt: skip
    s = storage_of(traj)
    return [
        on_run(f"{s}(t) - {s}(0) = -int nu^T K nu (w = 0)", "Theorem 1, (43)", traj, residual,
               f"<= {IDENTITY_TOL:g}", residual <= IDENTITY_TOL),
        on_run(f"{s} non-increasing", "Theorem 1, (43)", traj, rise, f"max step rise / {s}(0) <= 1e-9", rise <= 1e-9),
        converged,
        *([self_motion(traj)] if loop.robot.n > loop.task_dim else []),
    ]  # fmt: skip


def storage_of(traj: Trajectory) -> str:
    """The storage Theorems 1-2 are stated with on the run: ``V`` (38), or ``V_a = V + z_I^T K_I z_I / 2``
    with integral action (docs/math.md, facts 20.1-20.2)."""
    return "V_a" if "V_a" in traj.signals else "V"


def self_motion(traj: Trajectory) -> Claim:
    """For a redundant arm, the joint motion in the null space of ``J_b``, which ``x`` does not
    contain. Since ``qd_d = pinv(J_b) u_d`` lies in the row space, ``(I - pinv(J_b) J_b) qd =
    (I - pinv(J_b) J_b) xi``: the self-motion is bounded by ``int |xi| dt``, which Theorem 1
    drives to a finite limit."""
    qd, t = traj["qd"], traj.t
    n = qd.shape[1]
    jac = traj["body_jacobian"].reshape(len(qd), n, -1).transpose(0, 2, 1)
    null = np.eye(n) - np.linalg.pinv(jac) @ jac
    integral = lambda f: float(np.sum((f[1:] + f[:-1]) / 2 * np.diff(t)))  # noqa: E731
    drift = integral(np.linalg.norm(np.einsum("tij,tj->ti", null, qd), axis=1))
    bound = integral(np.linalg.norm(traj["xi"], axis=1))
    return Claim("self-motion int |(I - pinv(J_b) J_b) qd| dt <= int |xi| dt", f"n = {n} > 6, Theorem 1",
                 drift, f"<= {bound:.3g} rad", drift <= bound * (1 + 1e-9))  # fmt: skip


def fastest_rate(loop: ClosedLoop, s0: np.ndarray) -> float:
    """The loop's fastest rate at the start (1/s): the spectral radius of the Jacobian of
    ``ds/dt`` at ``s0``. With a light wrist it is about ``lambda_max(M^-1 K_xi)``."""
    jacobian = cs.Function("A", [loop.t, loop.state], [cs.jacobian(loop.state_rate, loop.state)])
    return float(np.abs(np.linalg.eigvals(np.asarray(jacobian(0.0, s0)))).max())


DERIVATIVE_TOL = 1e-4
"""Bound on the relative gap between the symbolic dV/dt and differences of V."""


def lyapunov_derivative(loop: ClosedLoop, s0: np.ndarray, settings: Settings) -> Claim:
    """The symbolic dV/dt against fourth-order central differences of V over the initial
    transient, on 2000 steps of ``h = min(50 us, 0.02 / rho)``, ``rho`` the fastest rate
    (:func:`fastest_rate`): the truncation error is about ``(h rho)^4 / 30 ~ 5e-9`` relative,
    CVODES' error at tolerance 1e-10 amplified by ``1.5 / (h rho) ~ 75``. The differences
    at ``2 h`` estimate the truncation error a posteriori (Richardson: a fifteenth of their
    gap); when that estimate is not well below the bound, the check could not resolve V and
    says so (INCONCLUSIVE) instead of failing the claim."""
    name, ref, bound = "symbolic dV/dt = derivative of V along the run", "(39)-(40)", f"<= {DERIVATIVE_TOL:g} relative"
    rho = fastest_rate(loop, s0)
    h = min(5e-5, 0.02 / rho)
    traj = Simulator(static(loop), replace(settings, duration=2000 * h, dt=h)).run(s0)
    v, vdot = traj["V"][:, 0], traj["Vdot"][:, 0]
    scale = np.abs(vdot).max()

    fd = (-v[4:] + 8 * v[3:-1] - 8 * v[1:-3] + v[:-4]) / (12 * h)
    fd2 = (-v[8:] + 8 * v[6:-2] - 8 * v[2:-6] + v[:-8]) / (24 * h)  # step 2h, centred on samples 4 .. -5
    err = float(np.abs(fd - vdot[2:-2]).max() / scale)
    resolution = float(np.abs(fd[2:-2] - fd2).max() / scale / 15)
    detail = f"h = {h:.3g} s from the fastest time scale 1/rho = {1 / rho:.3g} s; estimated resolution {resolution:.2g}"
    if err <= DERIVATIVE_TOL:
        return on_run(name, ref, traj, err, bound, True, detail)
    if resolution > DERIVATIVE_TOL / 10:
        why = f"differences of V at h = {h:.3g} s cannot resolve dV/dt (estimated error {resolution:.2g})"
        return Claim(name, ref, err, bound, None, f"{why}; fastest time scale {1 / rho:.3g} s", inconclusive=True)
    return on_run(name, ref, traj, err, bound, False, detail)


LEFT_REGION = (RunStatus.BEHIND_CAMERA, RunStatus.SINGULAR)
"""Stops of a run that leave the region where the paper's statements hold."""


def lemma_2(
    loop: ClosedLoop, s0: np.ndarray, settings: Settings, seed: int = 1, tries: int = 3, size: float = 1.0
) -> list[Claim]:
    """Lemma 2 on (36) driven by random smooth ``u`` (``size`` times 0.5 N m on ``u_xi``,
    0.02 on ``u_d``, ``u_e``) with ``w = 0``. The lemma is stated where the features are in
    front of the camera and ``J_b`` is nonsingular: when the input drives the run out of
    there, it is scaled down (by 4, up to ``tries`` runs); a run that never stays inside
    makes the check INCONCLUSIVE, not the claim false."""
    n, task = loop.robot.n, loop.task_dim
    names = (("V(T) - V(0) = int u^T nu (random smooth u, w = 0)", "Lemma 2, (40)-(41)", f"<= {IDENTITY_TOL:g}"),
             ("int u^T nu >= -beta, beta = V(0)", "Lemma 2, (37)", ">= 0 to round-off"))  # fmt: skip
    for attempt in range(tries):
        scale = size * 0.25**attempt
        amplitude = scale * np.concatenate([np.full(n, 0.5), np.full(2 * task, 0.02)])
        driven = replace(static(loop), inputs=smooth_signal(seed, n + 2 * task, amplitude))
        traj = Simulator(driven, replace(settings, duration=min(settings.duration, 3.0))).run(s0)
        if traj.status not in LEFT_REGION:
            break
    residual = identity_residuals(traj)["passivity"]
    low = float(traj.integrals["supply_u_nu"].min()) + traj["V"][0, 0]
    tol = roundoff(traj.integrals["supply_u_nu"], traj["V"][0, 0], floor=storage_floor(loop))
    if traj.status in LEFT_REGION:
        why = f"the run left the lemma's region even with the input at {scale:g} of its nominal size: {traj.message}"
        return [Claim(*names[0][:2], residual, names[0][2], None, why, inconclusive=True),
                Claim(*names[1][:2], low, names[1][2], None, why, inconclusive=True)]  # fmt: skip
    detail = "" if attempt == 0 else f"input scaled to {scale:g} of its nominal size to keep the run inside the region"
    return [
        on_run(*names[0][:2], traj, residual, names[0][2], residual <= IDENTITY_TOL, detail),
        on_run(*names[1][:2], traj, low, f">= -{tol:.1e} (round-off of the terms)", low >= -tol, detail),
    ]


def initial_poses(loop: ClosedLoop, s0: np.ndarray) -> tuple[SE3, SE3]:
    """The relative pose ``g(0)`` and its estimate ``gbar(0)`` of the scenario's start ``s0``."""
    poses = cs.Function("g0", [loop.t, loop.state], [loop.relative_pose.as_matrix(), loop.estimate.as_matrix()])
    g, gbar = poses(0.0, s0)
    return SE3.from_matrix(np.asarray(g)), SE3.from_matrix(np.asarray(gbar))


def kinematic_claims(loop: ClosedLoop, s0: np.ndarray, seed: int = 2, duration: float = 3.0) -> list[Claim]:
    """Lemma 1 and the passivity remarks after (9) and (23), on (26) driven by random
    smooth ``V_wc`` and ``u_e`` from the scenario's start (``g(0)``, ``gbar(0)`` of ``s0``)."""
    system = VisualFeedbackSystem(
        loop.reference,
        smooth_signal(seed, 6, np.r_[np.full(3, 0.05), np.full(3, 0.2)]),
        smooth_signal(seed + 1, 6, np.r_[np.full(3, 0.05), np.full(3, 0.2)]),
    )
    quad = system.supplies
    grid = np.linspace(0, duration, 301)[1:]
    integrator = cs.integrator("vfs", "cvodes", {"x": system.state, "t": system.t, "ode": system.state_rate,
                                                 "quad": quad}, 0.0, grid,
                               {"abstol": 1e-10, "reltol": 1e-10, "quad_err_con": True,
                                "disable_internal_warnings": True})  # fmt: skip
    start, est = initial_poses(loop, s0)
    x0 = np.concatenate([start.position_quaternion(), est.position_quaternion()])
    result = integrator(x0=x0)
    states = np.hstack([x0[:, None], np.asarray(result["xf"])])
    integrals = np.hstack([np.zeros((3, 1)), np.asarray(result["qf"])])
    storage = cs.Function("V", [system.t, system.state], [system.storages]).map(states.shape[1])
    v = np.asarray(storage(np.r_[0.0, grid][None, :], states))
    claims = []
    names = [
        ("V_r(T) - V_r(0) = int V_wc^T (-e_r)", "remark after (9)"),
        ("V_e(T) - V_e(0) = int u_e^T (-e_e)", "remark after (23)"),
        ("V_ce(T) - V_ce(0) = int u_ce^T nu_ce", "Lemma 1, (31)-(32)"),
    ]
    for i, (name, ref) in enumerate(names):
        dv = v[i] - v[i, 0]
        scale = max(v[i, 0], np.abs(integrals[i]).max())
        residual = float(np.abs(dv - integrals[i]).max() / scale)
        claims.append(Claim(name, ref, residual, f"<= {IDENTITY_TOL:g}", residual <= IDENTITY_TOL,
                            f"from the scenario's start, V(0) = {v[i, 0]:.6g}"))  # fmt: skip
        low = float(integrals[i].min() + v[i, 0])
        tol = roundoff(integrals[i], v[i, 0], floor=storage_floor(None))
        claims.append(
            Claim(f"{name.split(' = ')[1]} >= -V(0)", ref, low, f">= -{tol:.1e} (round-off of the terms)", low >= -tol)
        )
    return claims


def conditioning_claim(traj: Trajectory, threshold: float) -> Claim:
    """The arm's Jacobian stays away from singularity along a run (the law uses its pinv)."""
    sigma = float(traj["sigma_min_arm_jacobian"].min())
    return Claim("no singularity: min sigma_min of the arm's Jacobian along the run", "Section V-A, pinv",
                 sigma, f">= {threshold:g}", traj.status is not RunStatus.SINGULAR and sigma >= threshold,
                 traj.message)  # fmt: skip


def theorem_2(
    loop: ClosedLoop, s0: np.ndarray, settings: Settings, gamma: float | None, rest: FromRest | None = None
) -> list[Claim]:
    """(43) with disturbances along a run with the scenario's target motion and torque
    disturbances (band-limited noise of 1 N m RMS added if it has none); (44) and (45) on a run
    from rest under the worst disturbance of the linearisation (:func:`from_rest_claims`; ``rest``:
    that run, when already made by :func:`dvfc.analysis.linearize.from_rest`)."""
    disturbed = loop if loop.disturbances else replace(
        loop, disturbances=[BandLimitedNoise(np.ones(loop.robot.n), 5.0, seed=0)]
    )  # fmt: skip
    traj = Simulator(replace(disturbed, mode="ideal"), settings).run(s0)
    residual = identity_residuals(traj)["dissipation"]
    claims = [
        conditioning_claim(traj, settings.sigma_min),
        on_run(f"{storage_of(traj)}(T) - {storage_of(traj)}(0) = int (-nu^T K nu + x^T G w)", "(43) with w", traj,
               residual, f"<= {IDENTITY_TOL:g}", residual <= IDENTITY_TOL),
    ]  # fmt: skip
    if gamma is None:
        return [*claims, Claim("dissipation inequality at the certified gamma", "Theorem 2, (44)-(45)",
                               float("nan"), "a gamma from P >= 0", False, "P >= 0 holds for no gamma")]  # fmt: skip
    try:
        rest = from_rest(loop, s0[: loop.robot.n], settings.jit) if rest is None else rest
    except ValueError as exc:  # no configuration puts the camera at the reference (n < 6)
        return [*claims, Claim("dissipation inequality at the certified gamma from x(0) = 0", "Theorem 2, (44)-(45)",
                               float("nan"), "a run from the equilibrium", None, f"not run: {exc}",
                               inconclusive=True)]  # fmt: skip
    weights = None if loop.performance is None else weight_diagonals(loop)
    return [*claims, *from_rest_claims(rest.run, gamma, rest.peak_gain, converged=rest.converged, weights=weights,
                                       v_floor=storage_floor(loop))]


ATTAINED = 0.95
"""Fraction of the lower bound the run from rest must attain for its (45) check to bite."""


def from_rest_claims(traj: Trajectory, gamma: float, gamma_lower: float, *, converged: bool = True,
                     weights: tuple[np.ndarray, np.ndarray] | None = None, v_floor: float = 0.0) -> list[Claim]:
    """Theorem 2 where it constrains gamma: from ``x(0) = 0`` (``V(0) = 0``) under the worst
    disturbance of the linearisation, (45) reads ``int |x|^2 <= gamma^2 int |w|^2`` at every time,
    so the measured gain ``sqrt(int |x|^2 / int |w|^2)`` must not exceed gamma, and (44) holds
    pointwise. The run must also attain ``ATTAINED`` of the lower bound ``gamma_lower`` (the
    linearisation's H-infinity norm): a gamma under-reported by more than 5% then fails (45).
    ``converged``: whether the run's gain had converged in its horizon
    (:func:`dvfc.analysis.linearize.sharpest_from_rest`), said when it falls short. ``weights``:
    the diagonals of ``S`` and ``D_w`` of the generalized plant (docs/math.md, fact 17): the claims
    then read ``z = S x`` for ``x`` and ``d = D_w^-1 w`` for ``w`` (None: the paper's, unit). The
    integral slack of (45) and the gain are compared to :func:`roundoff` of their terms, ``v_floor``
    the round-off of ``V(0)`` (:func:`storage_floor`: from rest ``V(0)`` is zero only to it, of
    either sign, however small the run's integrals)."""
    x, w = _error_state(traj), traj["w"]
    if weights is not None:
        x, w = x * weights[0], w / weights[1]
    storage = storage_of(traj)
    lhs44 = traj[f"{storage}_dot" if storage == "V_a" else "Vdot"][:, 0] + 0.5 * (x * x).sum(1) - 0.5 * gamma**2 * (
        w * w
    ).sum(1)
    x2, w2 = traj.integrals["z_squared"], traj.integrals["d_squared"]
    x_, w_ = ("x", "w") if weights is None else ("z", "d")
    slack45 = gamma**2 * w2 + 2 * traj[storage][0, 0] - x2
    tol45 = roundoff(gamma**2 * w2, 2 * traj[storage][0, 0], x2, floor=2 * v_floor)
    tol = 1e-9 * gamma**2 * float((w * w).sum(1).max())  # round-off of (44) relative to its terms
    ratio = float(np.sqrt(x2[-1] / w2[-1]))
    run = f"from x(0) = 0 under the linearisation's worst disturbance, {traj.t[-1]:g} s" + (
        "" if weights is None else ", z = S x and d = D_w^-1 w with the [performance] weights")
    name = f"the measured gain attains {ATTAINED:g} of the lower bound (the (45) check bites)"
    bound, share = f">= {ATTAINED:g}", ratio / gamma_lower
    lower = f"H-infinity norm of the linearisation {gamma_lower:.6g}"
    attained = (
        Claim(name, "lower bound", share, bound, True, lower) if share >= ATTAINED
        else Claim(name, "lower bound", share, bound, None,
                   f"{lower}: the run does not test gamma sharply ("
                   + ("its gain converged below the bound: the nonlinear loop from rest is less sharp than its "
                      "linearisation" if converged else f"its gain had not converged at {traj.t[-1]:g} s") + ")",
                   inconclusive=True)
    )  # fmt: skip
    return [
        on_run(f"d{storage}/dt + |{x_}|^2/2 - gamma^2 |{w_}|^2/2 <= 0 pointwise", "Theorem 2, (44)", traj,
               float(lhs44.max()), f"<= {tol:.1e}", bool(lhs44.max() <= tol), f"gamma = {gamma:.6g}, {run}"),
        on_run(f"int |{x_}|^2 <= gamma^2 int |{w_}|^2 + 2 {storage}(0) at every time", "Theorem 2, (45)", traj,
               float(slack45.min()), f"slack >= -{tol45:.1e} (round-off of the terms)", bool(slack45.min() >= -tol45),
               f"V(0) = {traj['V'][0, 0]:.2g}, {run}"),
        on_run(f"measured gain sqrt(int |{x_}|^2 / int |{w_}|^2) <= gamma", "Theorem 2", traj, ratio,
               f"<= {gamma:.6g}", ratio <= gamma + roundoff(gamma, ratio), run),
        attained,
    ]  # fmt: skip


def rotation_angles(traj: Trajectory, reference: SE3) -> tuple[np.ndarray, np.ndarray]:
    """``theta_ec``, ``theta_ee`` along a run, from ``g``, ``gbar`` and ``g_d`` ((24), (15))."""
    rot = {k: traj[k].reshape(-1, 4, 4).transpose(0, 2, 1)[:, :3, :3] for k in ("g", "gbar")}  # CasADi vec: columns
    r_d = np.asarray(cs.DM(reference.rotation.matrix))
    r_ec = np.einsum("ji,bjk->bik", r_d, rot["gbar"])
    r_ee = np.einsum("bji,bjk->bik", rot["gbar"], rot["g"])
    return rotation_angle(r_ec), rotation_angle(r_ee)


def envelope_claims(
    loop: ClosedLoop, s0: np.ndarray, settings: Settings, env: dict, run: Trajectory | None = None
) -> list[Claim]:
    """Facts 7-8 on a run with the scenario's own target motion and torque disturbances (``run``:
    that run of the ideal loop, when already made):

    - the premise ``|w(t)| <= wbar``;
    - (fact 7) ``V(t) <= exp(-kappa (t - t0)) V(t0) + gamma'^2/(2 kappa) sup_{t0<=s<=t} |w(s)|^2``
      from ``t0 = 0`` when the start is inside the certified set, else from the first output
      step with ``V <= c_max`` (the set the statement covers);
    - (fact 8) every feature inside its certified box at every step with ``V <= c`` (the boxes
      bound every state of that sublevel set);
    - every error over the last quarter of the run within the bound of fact 7's level there,
      with the ratio to the certified ultimate bound (the envelope's tightness) reported.
    """
    if env.get("rate") is None:
        claims = [Claim("operating envelope", "docs/math.md, facts 7-8", float("nan"), "an envelope", None,
                        f"not certified: {env.get('reason')}")]  # fmt: skip
        start = env.get("start") or {}
        if start.get("until_s") is None or not start["inside"]:
            return claims
        traj = Simulator(replace(loop, mode="ideal"), settings).run(s0) if run is None else run
        return [*claims, *_until_integral_claims(loop, traj, env)]
    traj = Simulator(replace(loop, mode="ideal"), settings).run(s0) if run is None else run
    t, v = traj.t, traj["V"][:, 0]
    w2 = np.sum(traj["w"] ** 2, axis=1)
    wbar = env["wbar"]
    tol = 1e-9 * max(1.0, v[0])
    claims = [on_run("premise: |w(t)| <= wbar along the run", "fact 7", traj, float(np.sqrt(w2.max())),
                     f"<= {wbar:.4g}", bool(np.sqrt(w2.max()) <= wbar * (1 + 1e-12)))]  # fmt: skip
    start = env["start"]
    if start.get("method") == "planned":
        return [*claims, *_planned_claims(loop, traj, env, tol)]
    if start.get("method") == "ramp":
        return [*claims, *_ramp_claims(loop, traj, env, tol)]
    kappa, gamma = env["rate"], env["gamma_prime"]
    cap = env["level"] if env["start"]["inside"] else env["invariant_V"]
    entered = np.flatnonzero(v <= cap)
    if not entered.size:
        return [*claims, Claim("the run enters the certified set V <= c", "fact 7", float(v.min()),
                               f"<= {cap:.4g}", None, "never entered: nothing is claimed for this run")]  # fmt: skip
    k0 = 0 if env["start"]["inside"] else int(entered[0])
    running = np.maximum.accumulate(w2[k0:])
    bound = np.exp(-kappa * (t[k0:] - t[k0])) * v[k0] + gamma**2 / (2 * kappa) * running
    excess = float(np.max(v[k0:] - bound))
    claims.append(on_run("V(t) <= exp(-kappa t) V(t0) + gamma'^2/(2 kappa) sup |w|^2", "fact 7", traj, excess,
                         f"<= {tol:.1e}", excess <= tol, f"from t0 = {t[k0]:.3g} s, kappa = {kappa:.4g} 1/s"))
    if env.get("boxes_px") is not None:
        claims.append(feature_region_claim(traj, loop.camera.centre, env))
    claims.extend(_ultimate_errors(loop, traj, env, bound, k0))
    if not isinstance(loop, PlanarLoop):  # the search starts from the 6-D loop's equilibrium
        claims.append(adversarial_claim(loop, s0, env))
    return claims


def feature_region_claim(traj: Trajectory, centre: np.ndarray, env: dict) -> Claim:
    """Fact 8 on a run of the paper's loop: every feature inside its certified box (``env["boxes_px"]``,
    pixels from the top-left corner; ``centre`` the principal point) at every step with ``V <= c``.
    Vacuous, so MEASURED with the reason, when no step has ``V <= c`` or the boxes are not
    certified visible (``env["visible"]``: a box crosses the image border or a depth can reach
    zero), since being inside them then keeps no feature in view."""
    name = "every feature inside its certified box while V <= c"
    boxes = np.asarray(env["boxes_px"])
    pixels = traj["f"].reshape(len(traj.t), -1, 2) + centre
    tol = roundoff(pixels, boxes)
    bound = f"<= {tol:.1e} px (distance outside the box; round-off of the pixels)"
    inside = traj["V"][:, 0] <= env["level"]
    out = np.maximum(boxes[None, :, :2] - pixels, pixels - boxes[None, :, 2:]).max(axis=(1, 2))[inside]
    steps = f"{int(inside.sum())} of {len(traj.t)} steps have V <= c = {env['level']:.4g}"
    if not out.size:
        return Claim(name, "fact 8", float("nan"), bound, None, f"vacuous: {steps}, so no step is checked")
    worst = float(out.max())
    if env.get("visible") is not True:
        margin = env.get("image_margin_px")
        where = "a depth can reach zero" if margin is None else f"image margin {margin:.4g} px"
        return Claim(name, "fact 8", worst, bound, None,
                     f"vacuous: the certified boxes are not within the image ({where}), so being inside them "
                     f"keeps no feature in view; {steps}")  # fmt: skip
    return on_run(name, "fact 8", traj, worst, bound, worst <= tol, steps)


SEARCH_STOPPED = (
    "the integrator stopped on the disturbed loop before the horizon (a disturbance within the bounds drove "
    "the state where the loop's right-hand side is not finite, or beyond the integrator's step budget)"
)


def _start_level_claim(traj: Trajectory, start: dict, tol: float, fact: str, how: str) -> Claim:
    """A start statement's level on the run: ``V(t) <= c`` at every step from ``t = 0``, or, when
    the start is not certified, a claim saying so and why."""
    if not start["inside"]:
        return Claim(f"the start ({how}) is certified", fact, float("nan"), "a start statement", None,
                     f"not certified: {start.get('reason')}")  # fmt: skip
    v, level = traj["V"][:, 0], start["level"]
    excess = float(np.max(v - level))
    return on_run(f"V(t) <= c at every step from t = 0 ({how})", fact, traj, excess, f"<= {tol:.1e} (c = {level:.4g})",
                  excess <= tol, f"V(0) = {v[0]:.4g}, max V = {v.max():.4g}")


def _until_integral_claims(loop: ClosedLoop, traj: Trajectory, env: dict) -> list[Claim]:
    """Fact 20.6 on the run of the design with ``K_I``: its start statement (that of the design
    without it) on the steps ``t <= integral_start``, where ``z_I = 0`` and the two loops are one."""
    start = env["start"]
    keep = traj.t <= start["until_s"] + 1e-12
    cut = replace(traj, t=traj.t[keep], signals={k: v[keep] for k, v in traj.signals.items()},
                  integrals={k: v[keep] for k, v in traj.integrals.items()})  # fmt: skip
    tol = 1e-9 * max(1.0, float(cut["V"][0, 0]))
    if start.get("method") == "planned":
        return _planned_claims(loop, cut, env, tol, ultimate=False)
    if start.get("method") == "ramp":
        return _ramp_claims(loop, cut, env, tol)
    return [_start_level_claim(cut, start, tol, "fact 20.6", "until integral action engages")]


def _planned_claims(loop: ClosedLoop, traj: Trajectory, env: dict, tol: float, *, ultimate: bool = True) -> list[Claim]:
    """Fact 16b's start statement on the run with the planned reference: ``V(t) <= c`` at every
    step, fact 7's bound with the path's rate from ``t = 0``, every feature in its region (16.0)
    about ``g_d(t) p_oi`` at every step, and (``ultimate``) the errors over the last quarter."""
    start = env["start"]
    claims = [_start_level_claim(traj, start, tol, "fact 16b", "planned reference")]
    if not start["inside"]:
        return claims
    t, v, level = traj.t, traj["V"][:, 0], start["level"]
    kappa, gamma = start["rate"], start["gamma_prime"]
    running = np.maximum.accumulate(np.sum(traj["w"] ** 2, axis=1))
    bound = np.exp(-kappa * t) * v[0] + gamma**2 / (2 * kappa) * running
    worst = float(np.max(v - bound))
    claims.append(on_run("V(t) <= exp(-kappa t) V(0) + gamma'^2/(2 kappa) sup |w|^2 (the path's rate)", "fact 16b",
                         traj, worst, f"<= {tol:.1e}", worst <= tol, f"kappa = {kappa:.4g} 1/s along the path"))
    if start.get("visible") is not None and loop.camera.has_image:
        lo, hi = run_regions(loop, t, level)
        pixels = traj["f"].reshape(len(t), -1, 2) + loop.camera.centre
        out, px_tol = float(np.maximum(lo - pixels, pixels - hi).max()), roundoff(pixels, lo, hi)
        claims.append(on_run("every feature inside its region about g_d(t) at every step", "fact 16b, 16.0", traj,
                             out, f"<= {px_tol:.1e} px (outside the region; round-off)", out <= px_tol,
                             f"regions of the balls B(g_d(t) p_oi, rho_i(c)), c = {level:.4g}"))  # fmt: skip
    if ultimate:
        claims.extend(_ultimate_errors(loop, traj, env, bound, 0))
    return claims


def _ramp_claims(loop: ClosedLoop, traj: Trajectory, env: dict, tol: float) -> list[Claim]:
    """Fact 16a's start statement on the run with the ramp: ``V(t) <= c`` at every step from
    ``t = 0``, and every feature inside its region (16.0) at the visible level at every step from
    ``t_vis`` on."""
    start = env["start"]
    claims = [_start_level_claim(traj, start, tol, "fact 16a", "ramp")]
    if not start["inside"]:
        return claims
    t = traj.t
    since = start.get("visible_from_s")
    if start.get("visible_boxes_px") is not None and since is not None:
        boxes = np.asarray(start["visible_boxes_px"])
        pixels = (traj["f"].reshape(len(t), -1, 2) + loop.camera.centre)[t >= since - 1e-9]
        out = float(np.maximum(boxes[None, :, :2] - pixels, pixels - boxes[None, :, 2:]).max())
        px_tol = roundoff(pixels, boxes)
        claims.append(on_run(f"every feature inside its region at the visible level from t = {since:.3g} s",
                             "fact 16a, 16.0", traj, out, f"<= {px_tol:.1e} px (outside the region; round-off)",
                             out <= px_tol,
                             f"c_vis = {start['visible_level']:.4g}"))  # fmt: skip
    return claims


def adversarial_claim(loop: ClosedLoop, s0: np.ndarray, env: dict) -> Claim:
    """The worst ``V(T)`` found by :func:`dvfc.analysis.adversary.worst_disturbance` from ``V(0) = 0``
    against fact 7's ``c_inf (1 - exp(-kappa T))``, with the errors there against the ultimate
    bounds (the envelope's tightness)."""
    d = env["disturbance"]
    bounds = DisturbanceBounds(d["target_speed"], d["target_rate"], d["torque"])
    name = "worst V(T) found by adversarial search from V(0) = 0"
    try:
        with silenced():
            worst = worst_disturbance(loop, s0[: loop.robot.n], bounds, horizon=3.0, intervals=6, iterations=3)
    except (RuntimeError, ValueError) as exc:  # no equilibrium near the start (ours), or CVODES stopped
        why = str(exc) if isinstance(exc, ValueError) else SEARCH_STOPPED
        return Claim(name, "fact 7", float("nan"), "<= c_inf (1 - exp(-kappa T))", None,
                     f"the search could not run: {why}", inconclusive=True)  # fmt: skip
    limit = env["ultimate_V"] * (1 - math.exp(-env["rate"] * worst["horizon_s"]))
    errors = ", ".join(f"{k} {v:.3g} (bound {env['bounds'][k]:.3g})" for k, v in worst["errors"].items()
                       if v is not None)  # fmt: skip
    dropped = (f"; {worst['dropped']} disturbance(s) dropped: the integrator stopped on them (J_b singular along "
               "the run, outside the envelope's premise)") if worst["dropped"] else ""  # fmt: skip
    return Claim(name, "fact 7", worst["V"],
                 f"<= c_inf (1 - exp(-kappa T)) = {limit:.4g}", worst["V"] <= limit * (1 + 1e-9) + 1e-12,
                 f"T = {worst['horizon_s']:g} s; worst / c_inf = {worst['V'] / env['ultimate_V']:.3g}; there {errors}"
                 + dropped)


def _ultimate_errors(loop: ClosedLoop, traj: Trajectory, env: dict, bound: np.ndarray, k0: int) -> list[Claim]:
    """The errors over the last quarter of the run against fact 7's bound at that time (a claim)
    and against the certified ultimate bound (a ratio: the envelope's tightness)."""
    tail = slice(max(k0, 3 * len(traj.t) // 4), None)
    level = float(bound[tail.start - k0 :].max())
    measured = {
        "p_ec": np.linalg.norm(traj["e_c"][tail, :3], axis=1).max(),
        "p_ee": np.linalg.norm(traj["e_e"][tail, :3], axis=1).max(),
        "xi": np.linalg.norm(traj["xi"][tail], axis=1).max(),
    }
    if env["bounds"]["theta_ec_deg"] is not None:
        th_c, th_e = rotation_angles(traj, loop.reference)
        measured["theta_ec_deg"] = np.degrees(th_c[tail].max())
        measured["theta_ee_deg"] = np.degrees(th_e[tail].max())
    w = loop.weights
    at_level = level_bounds(tuple(w.as_array()), env["m_lo"], "theta_ec_deg" in measured, level)
    claims = []
    for name, value in measured.items():
        ultimate = env["bounds"][name]
        claims.append(on_run(f"max {name} over the last quarter of the run", "fact 7", traj, float(value),
                             f"<= {at_level[name]:.4g} (fact 7's bound there)",
                             bool(value <= at_level[name] * (1 + 1e-9)),
                             f"certified ultimate bound {ultimate:.4g}; measured / ultimate = "
                             f"{value / ultimate if ultimate else float('nan'):.3g}"))  # fmt: skip
    return claims


def image_mode(loop: ClosedLoop, s0: np.ndarray, settings: Settings, run: Trajectory | None = None) -> list[Claim]:
    """The loop run on ``e_e`` from the image: for the paper's loop the first-order estimate
    (21), a measurement, not a claim; for the planar loop the exact map (P12), a claim (``run``:
    that run, when already made)."""
    traj = Simulator(replace(loop, mode="image"), settings).run(s0) if run is None else run
    gap = float(np.linalg.norm(traj["e_e_image"] - traj["e_e"], axis=1).max())
    cond = float(traj["cond_image_jacobian"].max())
    residual = identity_residuals(traj)["dissipation"]
    if isinstance(loop, PlanarLoop):
        scale = float(np.abs(traj["e_e"]).max())
        return [
            on_run("max |pinv(A)(f - fbar) - e_e| / max |e_e|", "(P12)", traj, gap / scale, "<= 1e-9",
                   gap <= 1e-9 * scale),
            on_run("(43) identity with e_e from the image", "(P10), image loop", traj, residual,
                   f"<= {IDENTITY_TOL:g}", residual <= IDENTITY_TOL),
            Claim("max condition number of A", "(P12)", cond, "measured", None),
        ]  # fmt: skip
    return [
        Claim("max |pinv(J)(f - fbar) - e_e|", "(21) vs (15)", gap, "measured", None),
        Claim("(43) identity residual with e_e from the image", "(43), image loop", residual, "measured", None),
        Claim("max condition number of J(gbar)", "(19)-(20)", cond, "measured", None),
    ]


def implemented_storage(traj: Trajectory) -> float:
    """The storage identity of the loop as implemented (docs/math.md, fact 11, (11.1) integrated),
    as a relative residual: ``max_t |V(t) - V(0) - int (u^T nu + x^T G w) - int xi^T delta - int o|``
    over the scale of :func:`dvfc.analysis.simulate.identity_residuals`. ``u`` is the law's input, its
    ``u_e`` built from the held image estimate ``e_k``, so the recorded ``u^T nu`` is
    ``-nu^T K nu + nu_e^T K_e W_e eps`` (``eps = e_k - e_e``: the camera channel);
    ``delta = M qdd + C qd + g - tau - tau_d`` (the hold, saturation and plant error); ``o`` the
    observer's hold ((11.2), 0 on a continuous run)."""
    v = traj["V"][:, 0]
    i = traj.integrals
    scale = max(v[0], np.abs(i["supply_u_nu"]).max(), np.abs(i["supply_x_G_w"]).max(), np.finfo(float).tiny)
    gap = v - v[0] - i["supply_u_nu"] - i["supply_x_G_w"] - i["unmodelled_supply"] - i["observer_supply"]
    return float(np.abs(gap).max() / scale)


def integration_hint(traj: Trajectory, residual: float, tol: float) -> str:
    """Which setting brings fact 11's residual on the sampled run ``traj`` within ``tol``: the
    identity is exact, so its residual is the integration's. RK4's falls 16-fold each time its
    steps a period double (order 4, ``tests/test_sampled.py``): the fewest doubled substeps whose
    predicted residual is at most ``tol / 2``, and a ``step_error`` that makes ``"auto"`` choose
    them (the estimate scales alike: 4 times its prediction there, a factor 4 from the estimates of
    the next and previous counts); CVODES's follows its tolerances."""
    choice = SubstepChoice.of_run(traj.stats)
    if choice.substeps is None:
        return "integration error: lower [simulation] rtol and atol (CVODES restarted at every sample)"
    k = choice.substeps
    doublings = max(1, math.ceil(math.log2(residual / (tol / 2)) / 4))
    finer = k * 2**doublings
    setting = f"set [implementation] substeps = {finer}"
    if choice.estimate is not None:
        setting += f" or step_error <= {4 * choice.estimate / 16**doublings:.1g}"  # between the estimates of k', k'/2
    return (
        f"integration error (the identity is exact; RK4's truncation falls 16-fold each time its steps double): "
        f"{setting} (predicted residual {residual / 16**doublings:.1g})"
    )


def implemented(loop: ClosedLoop, s0: np.ndarray, settings: Settings, run: Trajectory | None = None) -> list[Claim]:
    """The run as implemented (:func:`dvfc.analysis.sampled.as_implemented`: the scenario's
    controller, plant and image; ``run`` when already made) against what the robot can do:
    measurements, not claims of the paper, failing when a URDF limit is exceeded or the run
    does not complete."""
    traj = as_implemented(loop, settings).run(s0) if run is None else run
    limits = robot_limits(loop, settings)
    record = limit_record(traj, limits)
    how = "sampled" if settings.implementation is not None else "continuous"
    torque = np.asarray(record["torque_commanded_ratio"])
    speed = np.asarray(record["speed_ratio"])
    position = np.asarray(record["position_ratio"])
    j, i, p = int(np.argmax(torque)), int(np.argmax(speed)), int(np.argmax(position))
    clipped = settings.implementation is not None and settings.implementation.saturate
    low, high = record["position_range"][p]
    torque_detail = (
        f"joint {j + 1}: peak |tau| {record['peak_torque_commanded'][j]:.4g} N m, limit {limits.effort[j]:.4g} N m"
        + ("; clipped at the limit (saturate)" if clipped else "")
    )
    storage = implemented_storage(traj)
    storage_detail = ("the storage of the loop as implemented: hold, camera and plant errors enter through the "
                      "channels of u_xi (delta) and u_e (eps, inside u^T nu), the observer's held inputs through o "
                      "(11.2); exact, measured to the integrator's truncation")  # fmt: skip
    if settings.implementation is not None:
        storage_detail += f" ({SubstepChoice.of_run(traj.stats).text})"
        if storage > IMPLEMENTED_TOL:
            storage_detail = f"{integration_hint(traj, storage, IMPLEMENTED_TOL)}; {storage_detail}"
    return [
        Claim(f"the {how} run completes", "as implemented", traj.t[-1], f"t = {settings.duration:g} s",
              None if traj.status is RunStatus.OK else False, traj.message),
        on_run(f"V(t) - V(0) = int (u^T nu + x^T G w + xi^T delta + o) on the {how} run", "docs/math.md, fact 11",
               traj, storage, f"<= {IMPLEMENTED_TOL:g}", storage <= IMPLEMENTED_TOL, storage_detail),
        Claim("torques within effort limits", "URDF <limit effort>", torque.max(), "max peak |tau| / effort <= 1",
              None if torque.max() <= 1 + ROUNDOFF or clipped else False, torque_detail),
        Claim("joint speeds within velocity limits", "URDF <limit velocity>", speed.max(),
              "max peak |qd| / velocity <= 1", None if speed.max() <= 1 + ROUNDOFF else False,
              f"joint {i + 1}: peak |qd| {record['peak_speed'][i]:.4g} rad/s, limit {limits.velocity[i]:.4g} rad/s"),
        Claim("joint position limits", "URDF <limit lower upper>", position.max(),
              "max range / position limits <= 1", record["within_position"],
              f"joint {p + 1}: range [{low:.4g}, {high:.4g}], limits [{limits.lower[p]:.4g}, {limits.upper[p]:.4g}]"),
    ]  # fmt: skip


def verify(
    loop: ClosedLoop,
    s0: np.ndarray,
    settings: Settings,
    gamma: float | None,
    envelope: dict | None = None,
    implemented_run: Trajectory | None = None,
    rest: FromRest | None = None,
    paper_run: Trajectory | None = None,
) -> list[Claim]:
    """All claims, in the paper's order, on the paper's loop (continuous, exact model, no
    image border), then the operating envelope's (facts 7-8) when given, then the run as
    implemented against the robot's limits. Every run follows the scenario's ``jit``: the design is an input of
    the compiled functions, and the loop with ``w = 0`` is the scenario's with the target's radius at zero, but
    each variant with disturbances or inputs of its own (Lemma 2's input, a torque noise, a step) is a structure
    of its own, compiled once per arm (on the xArm 7 cell 5 continuous ones, the run from rest's among them).
    ``implemented_run``: the run as implemented, when already made (else its simulator's libraries, a sampled
    loop's the largest, are started first, :func:`dvfc.analysis.compile.ahead`, and built on the cores the paper's
    runs leave idle); ``rest``: the run from rest of Theorem 2's checks, ``paper_run``: the paper's loop run from
    ``s0`` in the loop's own mode, each when already made."""
    paper = replace(settings, implementation=None, plant=None, view=False)
    if implemented_run is None and settings.jit:  # its libraries (a sampled loop's the largest) built meanwhile
        with ahead():
            as_implemented(loop, settings)
    return [
        *verify_paper(loop, s0, paper, gamma, envelope, rest, paper_run),
        *implemented(loop, s0, settings, implemented_run),
    ]


def verify_paper(
    loop: ClosedLoop,
    s0: np.ndarray,
    settings: Settings,
    gamma: float | None,
    envelope: dict | None = None,
    rest: FromRest | None = None,
    run: Trajectory | None = None,
) -> list[Claim]:
    """The paper's claims on its idealised loop, and the operating envelope's when given (``rest``:
    the run from rest of :func:`theorem_2`, ``run``: the loop's run from ``s0`` in its own mode,
    which :func:`image_mode` or :func:`envelope_claims` takes, each when already made)."""
    image, ideal = (run if loop.mode == mode else None for mode in ("image", "ideal"))
    return [
        *([] if isinstance(loop, PlanarLoop) else kinematic_claims(loop, s0)),
        *lemma_2(loop, s0, settings),
        *theorem_1(loop, s0, settings),
        lyapunov_derivative(loop, s0, settings),
        *theorem_2(loop, s0, settings, gamma, rest),
        *image_mode(loop, s0, settings, image),
        *([] if envelope is None else envelope_claims(loop, s0, settings, envelope, ideal)),
    ]
