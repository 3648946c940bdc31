"""Gain synthesis (MATH fact 6): bounds respected, certified at the reported gamma, and no
point of a grid inside the bounds certifies a smaller gamma."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from analysis.certify import GainPoint, certify, exact_gamma
from analysis.synthesize import Bounds, synthesize
from models.lie import SE3
from models.loop import Weights

REFERENCE = SE3.from_xyz_rpy([0.02, -0.01, 0.35], [0.1, -0.2, 0.3])
WEIGHTS = Weights(4.0, 1.0, 4.0, 1.0)
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
