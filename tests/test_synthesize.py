"""Gain synthesis (MATH fact 6): bounds respected, certified at the reported gamma, no point
of a grid inside the bounds certifies a smaller gamma (an optimum at a corner), and the
smallest gains reaching a gamma target (an interior optimum) beat a fine grid."""

from __future__ import annotations

import itertools
from dataclasses import astuple
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from analysis.certify import GainPoint, certify, exact_gamma
from analysis.envelope import DisturbanceBounds, design_of, envelope
from analysis.results import speed_theta_bar
from analysis.scenario import build, gain_point, load
from analysis.synthesize import TARGET_MARGIN, Bounds, synthesize, synthesize_speed
from models.lie import SE3
from models.loop import Weights
from tests import reference as ref

REFERENCE = SE3.from_xyz_rpy([0.02, -0.01, 0.35], [0.1, -0.2, 0.3])
WEIGHTS = Weights(4.0, 1.0, 4.0, 1.0)
EXAMPLES = Path(__file__).parent.parent / "examples"
BOUNDS = Bounds((1.0, 30.0), (0.5, 5.0), (0.5, 8.0))


@pytest.fixture(scope="module")
def result():
    return synthesize(WEIGHTS, REFERENCE, 6, BOUNDS)


def test_synthesized_gains_respect_bounds(result):
    p = result.point
    for values, (lo, hi) in ((p.k_xi, BOUNDS.k_xi), (p.k_c, BOUNDS.k_c), (p.k_e, BOUNDS.k_e)):
        assert np.all(values >= lo) and np.all(values <= hi)


def test_synthesized_gains_certify_at_reported_gamma(result):
    again = certify(result.point, REFERENCE)
    assert again.certified and again.gamma == pytest.approx(result.certificate.gamma, rel=1e-12)


def test_no_grid_point_in_bounds_certifies_smaller_gamma(result):
    """A 4^4 grid over (k_xi, k_c, k_ep, k_er) inside the bounds: every gamma is at least the
    synthesised one, up to the certificate's 1e-6 inflation and the SDP optimum's accuracy
    (Clarabel's relative gap 1e-8 on s, so ~1e-8 on gamma; allowed 1e-7)."""
    best = result.certificate.gamma / (1 + 1e-6) / (1 + 1e-7)
    for k_xi, k_c, k_ep, k_er in itertools.product(
        np.linspace(*BOUNDS.k_xi, 4),
        np.linspace(*BOUNDS.k_c, 4),
        np.linspace(*BOUNDS.k_e, 4),
        np.linspace(*BOUNDS.k_e, 4),
    ):
        point = GainPoint(np.full(6, k_xi), np.full(6, k_c), np.repeat([k_ep, k_er], 3), WEIGHTS)
        assert exact_gamma(point, REFERENCE, np.eye(3))[0] >= best


def test_gamma_target_gives_smallest_gains(result):
    """With a target gamma the gains reach it, and are no larger than the minimum-gamma gains."""
    target = 1.5 * result.certificate.gamma
    reached = synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, gamma_target=target)
    assert reached.certificate.certified and reached.certificate.gamma <= target
    norm = lambda p: np.linalg.norm(np.r_[p.k_xi, p.k_c, p.k_e])  # noqa: E731
    assert norm(reached.point) < norm(result.point)


def test_unreachable_target_is_reported():
    out = synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, gamma_target=1e-3)
    assert out.point is None and "infeasible" in out.status


def test_region_is_the_scenarios():
    """With ``[certify] theta_max_deg = 90`` the synthesised certificate states that region,
    not every rotation."""
    out = synthesize(WEIGHTS, REFERENCE, 6, BOUNDS, theta_max=np.radians(90))
    assert out.certificate.region == "every rotation R_ec with |theta_ec| <= 90 deg"


WIDE = Bounds((0.5, 30.0), (0.05, 10.0), (0.05, 10.0))


def test_smallest_gains_for_a_target_are_interior_and_beat_a_fine_grid():
    """With a gamma target (1.5 times the smallest reachable) the smallest gains sit inside the
    bounds, on the boundary ``P = 0`` of the feasible set (an interior optimum, unlike the
    minimum-gamma problem's corner). A 201 x 201 grid of the plane that scales ``K_c`` and ``K_e``
    (``t_c K_c, t_e K_e`` with ``t`` in [0.5, 1.5], the optimum at (1, 1)), each point judged
    feasible by the independent reference (``lambda_min(P) >= 0`` at the gamma the synthesis
    aims at), has no feasible point of smaller norm (to the solver's 1e-6), and its best feasible
    point is within the grid step of the optimum: ``P`` grows with ``K``, so ``(1 + h, 1 + h)``
    is feasible and its norm exceeds the optimum's by at most ``h (|K_c| + |K_e|)``."""
    best_gamma = synthesize(WEIGHTS, REFERENCE, 6, WIDE).certificate.gamma
    out = synthesize(WEIGHTS, REFERENCE, 6, WIDE, gamma_target=1.5 * best_gamma)
    p = out.point
    for values, (lo, hi) in ((p.k_xi, WIDE.k_xi), (p.k_c, WIDE.k_c), (p.k_e, WIDE.k_e)):
        assert np.all(values > 1.01 * lo) and np.all(values < 0.99 * hi)
    gamma_aimed = 1.5 * best_gamma / (1 + TARGET_MARGIN)
    pose = np.asarray(cs.DM(REFERENCE.as_matrix()))
    w = np.array([WEIGHTS.w_pc, WEIGHTS.w_rc, WEIGHTS.w_pe, WEIGHTS.w_re])
    n_matrix = ref.output_matrix(w, pose[:3, 3], pose[:3, :3], np.eye(3), 6)
    weight = ref.disturbance_weight(w, 6)
    t = np.linspace(0.5, 1.5, 201)
    t_c, t_e = (v.ravel() for v in np.meshgrid(t, t, indexing="ij"))
    k = np.hstack([np.tile(p.k_xi, (len(t_c), 1)), t_c[:, None] * p.k_c, t_e[:, None] * p.k_e])
    a = np.einsum("ji,bj,jk->bik", n_matrix, k, n_matrix) - 0.5 * np.eye(18)
    feasible = ref.lambda_min(a - weight / (2 * gamma_aimed**2)) >= 0
    norms = np.linalg.norm(k, axis=1)
    optimum = np.linalg.norm(np.r_[p.k_xi, p.k_c, p.k_e])
    h = t[1] - t[0]
    assert feasible.any() and norms[feasible].min() >= optimum * (1 - 1e-6)
    assert norms[feasible].min() <= optimum + h * (np.linalg.norm(p.k_c) + np.linalg.norm(p.k_e))


SPEED_BOUNDS = Bounds((1.0, 30.0), (0.5, 5.0), (0.5, 15.0))


def test_target_speed_synthesis_beats_every_point_of_a_grid():
    """Facts 7-8 with fact 6: the gains maximising ``s kappa*(s)`` have a certified target speed
    (the ordinary envelope's, from ``V(0) = 0``, at ``theta_bar`` of its own choice) at least that
    of every point of a 4^3 grid over ``(k_xi, k_c, k_e)`` inside the bounds. Allowed 1e-7
    relative: the SDP's gains are accurate to Clarabel's ~1e-8 relative gap (an optimal gain at
    its bound comes back 1e-8 below it), and the speed is a square root of a quantity linear in
    ``kappa``."""
    spec, base = load(EXAMPLES / "ur5_envelope.toml")
    loop = build(spec, base)[0]
    reference, mass, camera = spec.reference.se3(), loop.robot.mass_bounds, loop.camera
    disturbance = DisturbanceBounds(0.0785, 0.0, 0.0)
    theta = speed_theta_bar(spec, loop, gain_point(spec, 6))
    out = synthesize_speed(WEIGHTS, reference, 6, SPEED_BOUNDS, mass, theta)

    def speed(point: GainPoint) -> float:
        env = envelope(design_of(point, reference, mass), camera, disturbance, {"V0": 0.0})
        return env.max_target_speed or 0.0

    best = speed(out.point) * (1 + 1e-7)
    for k_xi, k_c, k_e in itertools.product(*(np.linspace(*b, 4) for b in astuple(SPEED_BOUNDS))):
        grid_point = GainPoint(np.full(6, k_xi), np.full(6, k_c), np.full(6, k_e), WEIGHTS)
        assert speed(grid_point) <= best, (k_xi, k_c, k_e)
