"""``verify``: every claim holds on the default scenario and on a rotating target, and a
deliberately wrong controller is caught (the checker can fail)."""

from __future__ import annotations

from dataclasses import replace
from functools import cached_property

import pytest

from analysis.certify import GainPoint, certify
from analysis.verify import verify
from models.loop import ClosedLoop
from tests.conftest import build_loop


def claims_of(loop, s0, settings):
    g = loop.gains
    gamma = certify(GainPoint(g.k_xi, g.k_c, g.k_e, loop.weights), loop.reference, with_sdp=False).gamma
    return verify(loop, s0, replace(settings, duration=4.0), gamma)


def rotating_target(data):
    data["target"]["motion"] = {"kind": "circle_spin", "radius": 0.04, "period": 5.0, "spin_axis": [0.0, 0.0, 1.0],
                                "spin_rate": 0.4}  # fmt: skip


@pytest.mark.parametrize("edit", [None, rotating_target], ids=["default", "rotating target"])
def test_every_claim_holds(edit):
    claims = claims_of(*build_loop(edit))
    failed = [c.as_dict() for c in claims if c.passed is False]
    assert not failed, failed
    assert sum(c.passed is True for c in claims) >= 15


class WithoutCoriolisFeedforward(ClosedLoop):
    """The law (35) with ``C qd_d`` dropped: the xi-cancellation of Lemma 2 breaks."""

    @cached_property
    def tau(self):
        r = self.robot
        return super().tau - r.coriolis @ self.qd_d


def test_wrong_controller_is_caught():
    loop, s0, settings = build_loop()
    wrong = WithoutCoriolisFeedforward(**{f: getattr(loop, f) for f in loop.__dataclass_fields__})
    failed = {c.reference for c in claims_of(wrong, s0, settings) if c.passed is False}
    assert {"Lemma 2, (40)-(41)", "Theorem 1, (43)", "(43) with w"} <= failed
