"""The loop with its design as an input: gains, weights and reference as a parameter vector.

The simulators build their functions (compiled to C under ``jit``) from the loop with
symbolic gains, weights and reference (:func:`symbolic`), once per arm and loop structure,
and pass a design's numbers (:func:`parameter_vector`) at run time::

    p = [k_xi (n); k_c (6); k_e (6); w_pc; w_rc; w_pe; w_re; p_d (3); vec(R_d) (9, column-major)]

so that the generated code, and the compiled library cached by the hash of its source, does
not depend on the design: another design of the same arm runs the same code. The loop with
numbers stays the one every analysis (certificates, linearisation) uses.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace

import casadi as cs
import numpy as np

from dvfc.models.lie import SE3, SO3
from dvfc.models.loop import ClosedLoop, Gains, Weights

CACHE_SIZE = 8
"""Symbolic loops kept (least recently used dropped): one per arm and loop structure in use."""

_symbolic: OrderedDict[tuple, tuple[tuple, ClosedLoop]] = OrderedDict()


def parametrised(loop: ClosedLoop) -> bool:
    """Whether the loop's design enters its functions as :func:`parameter_vector`: the paper's
    loop (the reduced planar loop keeps its numbers in its expressions)."""
    return type(loop) is ClosedLoop


def parameter_count(n: int) -> int:
    """Entries of the parameter vector of an arm with ``n`` joints."""
    return n + 2 * ClosedLoop.task_dim + 4 + 3 + 9


def parameter_vector(loop: ClosedLoop) -> np.ndarray | None:
    """``p`` of the module's description for the numeric ``loop``; None when the loop is not
    :func:`parametrised`."""
    if not parametrised(loop):
        return None
    g, r = loop.gains, loop.reference
    translation = np.asarray(cs.DM(r.translation), dtype=float).ravel()
    rotation = np.asarray(cs.DM(r.rotation.matrix), dtype=float).ravel(order="F")
    return np.concatenate([g.k_xi, g.k_c, g.k_e, loop.weights.as_array(), translation, rotation]).astype(float)


def _structure(loop: ClosedLoop) -> tuple:
    """What a loop's functions depend on besides its design: the objects (held by identity:
    ``dataclasses.replace`` of a loop keeps them) and the flags."""
    objects = (loop.robot, loop.camera, loop.target, loop.inputs, loop.plant, loop.plan, *loop.disturbances)
    return objects, (type(loop), loop.mode, loop.sampled, loop.ramp, len(loop.disturbances), loop.performance)


def symbolic(loop: ClosedLoop) -> ClosedLoop:
    """``loop`` with its gains, weights and reference the entries of a symbol ``p``
    (:attr:`~dvfc.models.loop.ClosedLoop.parameters`), built once per arm and structure and
    shared by every design of it; ``loop`` itself when it is not :func:`parametrised`."""
    if not parametrised(loop):
        return loop
    objects, flags = _structure(loop)
    key = (tuple(map(id, objects)), flags)
    if key in _symbolic:
        _symbolic.move_to_end(key)
        return _symbolic[key][1]
    n, task = loop.robot.n, loop.task_dim
    p = cs.SX.sym("p", parameter_count(n))
    k_xi, k_c, k_e = p[:n], p[n : n + task], p[n + task : n + 2 * task]
    w = p[n + 2 * task : n + 2 * task + 4]
    position = p[n + 2 * task + 4 : n + 2 * task + 7]
    rotation = cs.reshape(p[n + 2 * task + 7 :], 3, 3)
    model = replace(
        loop,
        gains=Gains(k_xi, k_c, k_e),
        weights=Weights(w[0], w[1], w[2], w[3]),
        reference=SE3(position, SO3(rotation)),
        parameters=p,
    )
    _symbolic[key] = (objects, model)  # the objects held: their ids stay theirs while cached
    if len(_symbolic) > CACHE_SIZE:
        _symbolic.popitem(last=False)
    return model
