"""Solver faults: Clarabel failing, stopping early or crashing falls back to SCS and is
re-checked; when SCS is not clean either the point is "uncertified", never "certified"."""

from __future__ import annotations

import numpy as np
import pytest

from dvfc.analysis.certify import GainPoint, certify, p_min_eigenvalue, tight_gamma
from dvfc.models.lie import SE3
from dvfc.models.loop import Weights

REFERENCE = SE3.from_xyz_rpy([0.0, 0.0, 0.35], [0.0, 0.0, 0.0])
POINT = GainPoint(np.full(6, 20.0), np.full(6, 3.0), np.full(6, 10.0), Weights(4, 1, 4, 1))

CLARABEL_FAULTS = {
    "iteration limit": {"max_iter": 0},
    "crash (unknown setting)": {"no_such_setting": 1},
    "inexact (tolerances unreachable in 3 iterations)": {"max_iter": 3},
}
SCS_FAULTS = {
    "inexact": {"max_iters": 2},
    "crash (unknown setting)": {"no_such_setting": 1},
}


@pytest.mark.parametrize("fault", CLARABEL_FAULTS)
def test_clarabel_fault_falls_back_to_scs_and_is_rechecked(fault):
    cert = certify(POINT, REFERENCE, solver_options={"CLARABEL": CLARABEL_FAULTS[fault]})
    assert cert.certified and "sdp-scs" in cert.method
    assert p_min_eigenvalue(POINT, REFERENCE, np.eye(3), cert.gamma) >= 0


@pytest.mark.parametrize("clarabel", CLARABEL_FAULTS)
@pytest.mark.parametrize("scs", SCS_FAULTS)
def test_both_solvers_faulty_is_uncertified(clarabel, scs):
    options = {"CLARABEL": CLARABEL_FAULTS[clarabel], "SCS": SCS_FAULTS[scs]}
    cert = certify(POINT, REFERENCE, solver_options=options)
    assert not cert.certified and cert.gamma is None and cert.reason.startswith("solver trouble")


def test_tight_certificate_with_faulty_solvers_searches_alpha_and_rechecks():
    """Both solvers faulty: ``alpha`` comes from the 1-D search, gamma is exact at it and
    re-checked (margin >= 0), and it equals the solver's optimum to 1e-6 (the inflation)."""
    options = {"CLARABEL": {"max_iter": 0}, "SCS": {"max_iters": 2}}
    tight = tight_gamma(POINT, REFERENCE, solver_options=options)
    clean = tight_gamma(POINT, REFERENCE)
    assert "1-D search" in tight.method and "CLARABEL: status" in tight.method
    assert tight.margin >= 0 and abs(tight.gamma / clean.gamma - 1) <= 1e-6
