"""The reduced planar loop of :mod:`dvfc.models.planar`, step by step of its derivation (P1)-(P12),
on the 2-DOF direct-drive testbed."""

from __future__ import annotations

import re
import tomllib
from dataclasses import replace
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from dvfc.analysis.certify import GainPoint, certify_planar, planar_blocks, theorem2_matrices
from dvfc.analysis.scenario import Scenario, ScenarioError, build, load
from dvfc.analysis.verify import lemma_2, theorem_1
from dvfc.models.lie import SE3
from dvfc.models.loop import Weights, pseudo_inverse
from dvfc.models.planar import PlanarLoop

EXAMPLE = Path(__file__).parent.parent / "examples" / "planar2dd_reduced.toml"


@pytest.fixture(scope="module")
def testbed():
    spec, base = load(EXAMPLE)
    loop, s0, settings = build(spec, base)
    return loop, s0, replace(settings, jit=False, duration=5.0)


def test_p5_pinv_of_the_task_jacobian_is_a_right_inverse(testbed, rng):
    """(P5): ``J_p pinv(J_p) = I_2`` away from singularities (the step the 6-D task lacks)."""
    loop, _, _ = testbed
    f = cs.Function("f", [loop.q], [loop.task_jacobian @ pseudo_inverse(loop.task_jacobian)])
    for q in rng.uniform([-np.pi, 0.3], [np.pi, 2.5], (10, 2)):
        assert np.abs(np.asarray(f(q)) - np.eye(2)).max() < 1e-12


def test_p9_lemma_2_identity_on_simulation(testbed):
    """(P9): ``V(T) - V(0) = int u^T nu`` under random smooth inputs, target at rest."""
    loop, s0, settings = testbed
    identity, bound = lemma_2(loop, s0, settings)
    assert identity.passed and identity.value < 1e-6 and bound.passed


def test_p10_theorem_1_on_simulation(testbed):
    """(P10): with ``w = 0``, ``V`` decreases by ``int nu^T K nu`` and ``x -> 0``."""
    loop, s0, settings = testbed
    claims = theorem_1(loop, s0, settings)
    assert all(c.passed for c in claims), [c.to_json() for c in claims]


def test_p11_is_the_translational_part_of_the_papers_p(rng):
    """(P11): the planar ``N^T K N`` is the paper's at ``g_d = I``, ``R_ec = I`` restricted to
    the x, y rows of ``e_c`` and ``e_e`` (isotropic gains)."""
    k_c, k_e, w = rng.uniform(0.5, 5), rng.uniform(0.5, 5), Weights(*rng.uniform(0.5, 5, 4))
    planar = GainPoint(np.full(2, 20.0), np.full(2, k_c), np.full(2, k_e), w)
    paper = GainPoint(np.full(2, 20.0), np.full(6, k_c), np.full(6, k_e), w)
    a_paper, _ = theorem2_matrices(paper, SE3.identity(), np.eye(3))
    rows = [0, 1, 2, 3, 2 + 6, 3 + 6]  # xi, e_c x-y, e_e x-y
    nkn, _ = planar_blocks(planar)
    assert np.allclose(nkn - 0.5 * np.eye(6), a_paper[np.ix_(rows, rows)], rtol=0, atol=1e-12)


def test_p11_certificate_is_tight_at_its_gamma():
    """The planar certificate's gamma makes ``P`` singular: 1% lower it is not ``>= 0``."""
    point = GainPoint(np.full(2, 20.0), np.full(2, 3.0), np.full(2, 10.0), Weights(4, 1, 4, 1))
    cert = certify_planar(point)
    nkn, g = planar_blocks(point)
    p = lambda gamma: nkn - g @ g.T / (2 * gamma**2) - 0.5 * np.eye(6)  # noqa: E731
    assert cert.certified and np.linalg.eigvalsh(p(cert.gamma))[0] >= 0
    assert np.linalg.eigvalsh(p(0.99 * cert.gamma))[0] < 0


def planar_scenario(edit):
    data = tomllib.loads(EXAMPLE.read_text())
    edit(data)
    return Scenario.model_validate(data)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["robot"].update(mount={"xyz": [0, 0, 0], "rpy": [0.15, 0.0, 0.0]}),
         "optical axis is 8.59 deg from the downward"),
        (lambda d: d.update(robot={"model": "ur5", "q0": [0.15, -1.45, 1.45, -1.70, -1.45, 0.20]}),
         "optical axis is"),
        (lambda d: d["target"]["motion"].update(normal=[0.0, 0.2, 1.0]), "11.3 deg from vertical"),
    ],
    ids=["tilted mount", "UR5", "tilted circle"],
)  # fmt: skip
def test_p12_geometry_is_required(edit, message):
    """(P12) needs the camera looking straight down at a constant height and the target moving
    in a horizontal plane: a mount tilted by 0.15 rad, an arm whose camera does not look down
    (the UR5) and a tilted circle are refused, each naming what is wrong."""
    with pytest.raises(ScenarioError, match=re.escape(message)):
        build(planar_scenario(edit), EXAMPLE.parent)


def test_p12_allows_a_circle_normal_pointing_down():
    """A circle normal of [0, 0, -1] is a horizontal plane as well: accepted."""
    loop, _, _ = build(planar_scenario(lambda d: d["target"]["motion"].update(normal=[0.0, 0.0, -1.0])),
                       EXAMPLE.parent)  # fmt: skip
    assert isinstance(loop, PlanarLoop)


def test_planar_region_states_the_rank_condition():
    """The statement needs J_p of full row rank: the certificate's region says so."""
    point = GainPoint(np.full(2, 20.0), np.full(2, 3.0), np.full(2, 10.0), Weights(4.0, 1.0, 4.0, 1.0))
    assert "J_p has full row rank" in certify_planar(point, with_sdp=False).region
