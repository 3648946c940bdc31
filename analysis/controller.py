"""The certified controller as the program that runs on the robot: one step per control sample.

A real controller sees ``q_k``, ``qd_k`` once per control period ``h`` and, now and then, an
image captured some samples earlier. :func:`step_function` builds that program as one CasADi
function from the symbolic loop of :mod:`dvfc.models.loop` (the law (35), (42), the observer
(12), the image estimate (21)); the same graph is evaluated from Python (:class:`Controller`)
and generated as C (:mod:`dvfc.analysis.export`). One step at ``t_k``:

1. the estimate ``gbar_k`` is written to the ring buffer's slot ``k mod B``;
2. if an image arrives (``capture >= 0``), captured at sample ``c`` (``k - B < c <= k``), its
   ``e_e`` is (21) with the estimate ``gbar_c`` of the capture time (read from the ring) and
   replaces the held one; otherwise the held ``e_e`` stays;
3. the torque is the law (35), (42) at ``(t_k, q_k, qd_k, gbar_k)`` with the held ``e_e``, to be
   held over ``[t_k, t_k + h)``;
4. the observer advances by the exact flow of (12) over one period with the sampled camera
   velocity ``V_wc = J_b(q_k) qd_k`` and ``u_e`` held: ``gbar_(k+1) = exp(-h hat(V_wc)) gbar_k
   exp(h hat(u_e))`` (docs/math.md, fact 22: local error ``O(h^2)``).

Steps 3-4 and the integral update are :func:`sample_update`, the one definition of the controller at a
sample that the sampled simulator (:mod:`dvfc.analysis.sampled`) runs too.

State (flat, :class:`Layout`): ``gbar = [pbar; quat]`` (7), the held ``e_e`` (6), the ring of the
last ``B = latency + jitter + 1`` estimates (``7 B``), the sample counter ``k``, the last finite
``q`` (``n``), and the integral state ``z_I`` (``n``; zero, and passed through, when the law has no
integral action). With integral action (docs/math.md, facts 20-21) the torque reads ``-K_I z_k`` and
``z_(k+1) = z_k + h xi_k`` from ``integral_start`` on (``z_I`` held at 0 before), with the sampled
simulator's conditional anti-windup at the implementation's effort limits (when it saturates): joint
``i`` keeps ``z_I,i`` when its commanded torque is beyond ``+-effort_i`` and the update would push it
further (:mod:`dvfc.analysis.sampled`). A friction compensation ``fhat(qd_d)`` (fact 19) is part of the
law, on the program's own ``qd_d``. A planned reference
(docs/math.md, fact 16b) is part of the program (its start ``gbar(0)``, goal, duration and hold
are constants); its clock is ``t_k``.

Bad input never gives a non-finite torque; the step's status says what happened (:class:`Status`):
an image whose features are not finite, whose estimate (21) is not a possible estimation error
(:func:`plausible`), or whose capture sample is outside the ring, is dropped like a lost frame (the
law's torque, status 1); non-finite ``q`` or ``qd`` give gravity compensation ``g(q)`` at the last
finite ``q`` with the estimate held (status 2); a law or observer that is not finite at finite
joints (a singular ``J_b``) gives ``g(q_k)`` (status 3).
Gravity compensation, not zero torque: a zero torque drops an arm under gravity, ``g(q)``
holds it where it is (it floats, undamped); the caller's own safety layer (a protective stop, brakes)
decides what follows a non-zero status.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum

import casadi as cs
import numpy as np

from dvfc.analysis.case import Case
from dvfc.analysis.compile import Buffered
from dvfc.analysis.implementation import Implementation
from dvfc.analysis.parametric import parameter_vector, symbolic
from dvfc.models.loop import ClosedLoop

LARGEST = float(np.finfo(float).max)
"""``|x| <= LARGEST`` is false exactly for NaN and infinities (IEEE comparisons with NaN are false)."""


class Status(IntEnum):
    """What one step did (the C step's return code)."""

    OK = 0
    IMAGE_REJECTED = 1
    """An image was given but dropped: features or (21) not finite, or capture outside the ring."""
    BAD_JOINTS = 2
    """``q`` or ``qd`` not finite: gravity compensation at the last finite ``q``, estimate held."""
    NOT_FINITE = 3
    """The law or the observer not finite at finite joints: gravity compensation at ``q_k``."""


@dataclass(frozen=True)
class Layout:
    """Where each part of the controller's flat state lies, for ``n`` joints and a ring of
    ``ring`` estimates."""

    n: int
    ring: int

    @property
    def gbar(self) -> slice:
        return slice(0, 7)

    @property
    def e_e(self) -> slice:
        return slice(7, 13)

    def slot(self, j: int) -> slice:
        """The ring's slot ``j``: the estimate of a sample ``k`` with ``k mod ring = j``."""
        return slice(13 + 7 * j, 20 + 7 * j)

    @property
    def counter(self) -> int:
        return 13 + 7 * self.ring

    @property
    def q_last(self) -> slice:
        return slice(self.counter + 1, self.counter + 1 + self.n)

    @property
    def integral(self) -> slice:
        return slice(self.counter + 1 + self.n, self.counter + 1 + 2 * self.n)

    @property
    def size(self) -> int:
        return self.counter + 1 + 2 * self.n


def _finite(x: cs.SX) -> cs.SX:
    """1 when every entry of ``x`` is finite, else 0 (:data:`LARGEST`)."""
    return cs.logic_all(cs.fabs(x) <= LARGEST)


def plausible(e_e: cs.SX, loop: ClosedLoop) -> cs.SX:
    """1 when an image's ``e_e`` (21) is finite and could be an estimation error: its rotational part
    no longer than 1 (``e_R = sin(theta) axis`` of any rotation), its translational part no longer than
    the designed standoff ``|p_d|`` (an image whose error exceeds the whole camera-to-target distance
    is not of this target where the estimate expects it); the reduced planar loop's ``e_e`` is a
    translation alone. ``loop`` has numbers (its ``p_d``)."""
    standoff = float(np.linalg.norm(np.asarray(cs.DM(loop.reference.translation)).ravel()))
    if loop.task_dim != 6:
        return cs.logic_and(_finite(e_e), cs.norm_2(e_e) <= standoff)
    return cs.logic_and(_finite(e_e), cs.logic_and(cs.norm_2(e_e[3:6]) <= 1, cs.norm_2(e_e[0:3]) <= standoff))


def image_update(loop: ClosedLoop) -> cs.Function:
    """``dvfc_image(estimate, features) -> (e_e, usable)``: (21) from the ``features`` read with the
    ``estimate`` (the state's ``[pbar; quat]``) of the image's capture time, and whether to use it (finite
    features, :func:`plausible`; otherwise the held ``e_e`` stays, as for a lost frame): the program's
    reading of an image, and the sampled simulator's (``loop`` with numbers)."""
    estimate = loop.state[loop.estimate_slice]
    features = cs.SX.sym("features", loop.features.numel())
    e_e = loop.image_estimate(features)
    usable = cs.logic_and(_finite(features), plausible(e_e, loop))
    return cs.Function("dvfc_image", [estimate, features], [e_e, usable], ["estimate", "features"], ["e_e", "usable"])


def program_loop(case: Case) -> ClosedLoop:
    """The loop the program evaluates: the case's (the law's model, numbers baked in) in its
    sampled form, ``e_e`` a held input."""
    return replace(case.loop, sampled=True, plant=None)


def ring_size(case: Case) -> int:
    """Estimates the ring keeps: the latency plus its largest jitter, in periods, plus one."""
    imp = case.settings.implementation
    assert imp is not None, "a program of a case with an [implementation] (exportable)"
    return imp.latency_steps + imp.latency_jitter + 1


def step_function(case: Case) -> cs.Function:
    """One control step of the case's controller, ``dvfc_program(t, q, qd, features, capture, x)
    -> (tau, x_next, status)`` (see the module's description; ``capture < 0``: no image)."""
    imp = case.settings.implementation
    assert imp is not None, "a program of a case with an [implementation] (exportable)"
    return program_function(program_loop(case), imp, ring_size(case))


def integral_update(z: cs.SX, xi: cs.SX, tau: cs.SX, effort: cs.SX, h: float) -> cs.SX:
    """``z_I`` after one sample (facts 20-21): ``z + h xi`` (``xi`` the law's integrand, 0 before
    ``integral_start``), joint ``i`` held when its commanded ``tau_i`` is beyond ``effort_i`` and
    ``-K_I,i h xi_i`` would push it further (conditional integration; an infinite effort never holds)."""
    windup = cs.logic_or(cs.logic_and(tau > effort, xi < 0), cs.logic_and(tau < -effort, xi > 0))
    return z + cs.if_else(windup, cs.DM.zeros(z.numel()), h * xi)


def sample_update(loop: ClosedLoop, h: float) -> cs.Function:
    """The controller at one control sample, shared by the program (:func:`program_function`) and the
    sampled simulator: ``dvfc_sample(t, s, e_e, effort[, p]) -> (tau, observer, estimate, z_I)`` for the
    loop in its sampled form (numbers, or :attr:`~dvfc.models.loop.ClosedLoop.parameters` ``p``), ``s``
    its state at the sample, ``e_e`` the estimate held (after any image of the sample):

    - ``tau``: the law (35), (42) (with ``-K_I z_I`` and a friction compensation when the law has them),
      commanded, not clipped;
    - ``observer``: ``[V_k; U_k] = [J_b(q_k) qd_k; u_e(t_k)]``, the observer's inputs held over the period;
    - ``estimate``: ``gbar_(k+1)``, the exact flow of (12) over ``h`` with them held (docs/math.md, fact 22,
      (22.1): :meth:`~dvfc.models.loop.ClosedLoop.held_estimate`);
    - ``z_I``: ``z_(k+1)`` by :func:`integral_update` at ``effort`` (empty without integral action)."""
    n, task = loop.robot.n, loop.task_dim
    arguments, _ = loop.arguments
    t, s, e, effort = cs.SX.sym("t"), cs.SX.sym("s", loop.n_state), cs.SX.sym("e_e", task), cs.SX.sym("effort", n)
    p = arguments[3:]
    design = [cs.SX.sym("p", v.numel()) for v in p]
    law = cs.Function("dvfc_law", arguments, [loop.tau, loop.camera_velocity, loop.u[n + task : n + 2 * task],
                                               loop.integrand])  # fmt: skip
    tau, v_wc, u_e, xi = law(t, s, cs.vertcat(cs.DM.zeros(n), e, cs.DM.zeros(2 * task)), *design)
    v, u = cs.SX.sym("V", task), cs.SX.sym("U", task)
    step = cs.Function("dvfc_observer", [loop.state, v, u], [loop.held_estimate(v, u, h)])
    estimate = step(s, v_wc, u_e)
    z_next = integral_update(s[loop.integral_slice], xi, tau, effort, h) if loop.integral else cs.SX(0, 1)
    # Called, never inlined: a caller's constants (the program's design) are not folded into its
    # operations, which are the simulator's to the bit.
    return cs.Function(
        "dvfc_sample",
        [t, s, e, effort, *design],
        [tau, cs.vertcat(v_wc, u_e), estimate, z_next],
        ["t", "s", "e_e", "effort", *(["p"] if design else [])],
        ["tau", "observer", "estimate", "z_I"],
        {"never_inline": True},
    )


def program_function(loop: ClosedLoop, imp: Implementation, ring: int) -> cs.Function:
    """:func:`step_function` for a loop in its sampled form (:func:`program_loop`), an
    implementation (its period, effort limits) and a ring of ``ring`` estimates. The sample's update
    is a call of :func:`sample_update` of the loop's symbolic model (the sampled simulator's) with the
    loop's design: the simulator's operations (docs/math.md, fact 22)."""
    n, m, h = loop.robot.n, loop.camera.m, imp.period
    layout = Layout(n, ring)
    t, q, qd = cs.SX.sym("t"), cs.SX.sym("q", n), cs.SX.sym("qd", n)
    features, capture, x = cs.SX.sym("features", 2 * m), cs.SX.sym("capture"), cs.SX.sym("x", layout.size)
    gbar, e_held, k = x[layout.gbar], x[layout.e_e], x[layout.counter]
    slots = [cs.if_else(cs.fmod(k, layout.ring) == j, gbar, x[layout.slot(j)]) for j in range(layout.ring)]
    chosen = cs.fmod(capture, layout.ring)
    at_capture = sum(cs.if_else(chosen == j, slot, cs.DM.zeros(7)) for j, slot in enumerate(slots))
    e_new, readable = image_update(loop)(at_capture, features)
    given = capture >= 0
    in_ring = cs.logic_and(cs.logic_and(capture <= k, capture > k - layout.ring), cs.floor(capture) == capture)
    usable = cs.logic_and(cs.logic_and(given, in_ring), readable)
    e_e = cs.if_else(usable, e_new, e_held)
    z_i = x[layout.integral]
    state = cs.vertcat(q, qd, gbar, z_i) if loop.integral else cs.vertcat(q, qd, gbar)
    effort = imp.limits(loop.robot.limits).effort if imp.saturate else np.full(n, np.inf)
    design = parameter_vector(loop)
    # An infinite effort never holds z_I; as the largest double it holds only an infinite torque, which
    # the status replaces by gravity compensation (and the generated C needs no infinity).
    limit = np.where(np.isfinite(effort), effort, LARGEST)
    update = sample_update(symbolic(loop), h)
    tau, _, gbar_next, z_next = update(t, state, e_e, limit, *([] if design is None else [design]))
    joints = cs.logic_and(_finite(q), _finite(qd))
    working = cs.logic_and(_finite(tau), _finite(gbar_next))
    if loop.integral:
        working = cs.logic_and(working, _finite(z_next))
    fine = cs.logic_and(joints, working)
    q_safe = cs.if_else(_finite(q), q, x[layout.q_last])
    gravity = cs.Function("gravity", [loop.robot.q], [loop.robot.gravity])(q_safe)
    status = cs.if_else(
        cs.logic_not(joints),
        int(Status.BAD_JOINTS),
        cs.if_else(
            cs.logic_not(working),
            int(Status.NOT_FINITE),
            cs.if_else(cs.logic_and(given, cs.logic_not(usable)), int(Status.IMAGE_REJECTED), int(Status.OK)),
        ),
    )
    x_next = cs.vertcat(
        cs.if_else(fine, gbar_next, gbar),
        cs.if_else(fine, e_e, e_held),
        *slots,
        k + 1,
        q_safe,
        cs.if_else(fine, z_next, z_i) if loop.integral else z_i,
    )
    return cs.Function(
        "dvfc_program",
        [t, q, qd, features, capture, x],
        [cs.if_else(fine, tau, gravity), x_next, status],
        ["t", "q", "qd", "features", "capture", "x"],
        ["tau", "x_next", "status"],
    )


@dataclass(frozen=True)
class Step:
    """What one step returns: the torque to hold over the period, the next state, the status."""

    tau: np.ndarray
    state: np.ndarray
    status: Status


class Controller:
    """The case's controller as a program (:func:`step_function`), called from Python."""

    def __init__(self, case: Case) -> None:
        self.case = case
        loop = program_loop(case)
        self.n, self.m = loop.robot.n, loop.camera.m
        assert case.settings.implementation is not None, "a program of a case with an [implementation] (exportable)"
        self.period = case.settings.implementation.period
        self.layout = Layout(self.n, ring_size(case))
        self.function = step_function(case)
        self._call = Buffered(self.function)

    def initial_state(self) -> np.ndarray:
        """The state at ``t = 0``: the case's initial estimate ``gbar(0)``, no ``e_e`` yet, the ring
        filled with ``gbar(0)``, ``k = 0``, the initial ``q`` as the last finite one."""
        s0, layout = self.case.s0, self.layout
        x = np.zeros(layout.size)
        gbar0 = s0[2 * self.n : 2 * self.n + 7]
        x[layout.gbar] = gbar0
        for j in range(layout.ring):
            x[layout.slot(j)] = gbar0
        x[layout.q_last] = s0[: self.n]
        return x

    def step(
        self, state: np.ndarray, t: float, q: np.ndarray, qd: np.ndarray, features: np.ndarray | None, capture_step: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(tau, next state)`` of one step (numpy in and out); ``features`` None: no image."""
        result = self.evaluate(state, t, q, qd, features, capture_step)
        return result.tau, result.state

    def evaluate(
        self, state: np.ndarray, t: float, q: np.ndarray, qd: np.ndarray, features: np.ndarray | None, capture_step: int
    ) -> Step:
        """One step with its :class:`Status`."""
        image = features is not None
        f = np.asarray(features, dtype=float) if image else np.zeros(2 * self.m)
        tau, x_next, status = self._call(t, q, qd, f, float(capture_step) if image else -1.0, state)
        return Step(tau.ravel(), x_next.ravel(), Status(int(status.ravel()[0])))
