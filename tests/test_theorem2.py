"""Theorem 2 where it constrains gamma: runs from rest (``x(0) = 0``, so ``V(0) = 0`` and (45)
reads ``int |x|^2 <= gamma^2 int |w|^2``) under the linearisation's worst disturbance. The
measured gain must not exceed any certified gamma and must come within 5% of the lower bound,
so a certifier that under-reports gamma by more than that fails here."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dvfc.analysis.case import Case
from dvfc.analysis.certify import GainPoint, certify, tight_gamma
from dvfc.analysis.linearize import (
    FROM_REST_HORIZON,
    linearize,
    peak_sinusoid,
    rest_simulator,
    sharpest_from_rest,
)
from dvfc.analysis.results import CertificatePoint, lower_bound_record
from dvfc.analysis.simulate import identity_residuals
from dvfc.analysis.verify import ATTAINED, from_rest_claims, theorem_2

from helpers import build_loop


@pytest.fixture(scope="module")
def worst():
    """The default design, its certificates, the linearisation, and the run from rest under the
    linearisation's worst sinusoid driven to its sharpness (the run ``certify`` states and
    ``verify`` checks)."""
    loop, s0, settings = build_loop()
    g = loop.gains
    point = GainPoint(g.k_xi, g.k_c, g.k_e, loop.weights)
    lin = linearize(loop, s0[:6])
    ratio, traj, _ = sharpest_from_rest(loop, lin)
    return {"loop": loop, "s0": s0, "settings": settings, "lin": lin, "ratio": ratio, "traj": traj,
            "paper": certify(point, loop.reference), "tight": tight_gamma(point, loop.reference)}  # fmt: skip


@pytest.mark.slow
def test_run_from_rest_is_exact(worst):
    """The run starts at ``x = 0`` (``V(0) = 0`` to round-off) and satisfies (43) to 1e-6
    (CVODES at 1e-10, the bound of every identity residual)."""
    traj = worst["traj"]
    assert traj.status == "ok" and traj["V"][0, 0] < 1e-20
    assert identity_residuals(traj)["dissipation"] < 1e-6


def test_measured_gain_is_at_most_every_certified_gamma(worst):
    """(45) with ``V(0) = 0`` at every time of the run: for the paper's gamma and for the
    fact-4 gamma with the storage ``alpha V`` (``2 alpha V(0) = 0`` too)."""
    x2, w2 = worst["traj"].integrals["z_squared"], worst["traj"].integrals["d_squared"]
    for gamma in (worst["paper"].gamma, worst["tight"].gamma):
        assert np.all(x2 <= gamma**2 * w2)
    assert worst["ratio"] <= worst["tight"].gamma <= worst["paper"].gamma


def test_measured_gain_attains_the_lower_bounds(worst):
    """The run's gain is at least 95% of the linearisation's H-infinity norm: the check above
    is then within 5% of sharp."""
    assert worst["ratio"] >= ATTAINED * worst["lin"].peak_gain


def test_verify_claims_hold_at_gamma_and_fail_below_the_measured_gain(worst):
    """``verify``'s (44), (45) and gain claims on this run: all pass at the certified gamma; at
    0.97 of the measured gain (a gamma under-reported by about 5%) (44), (45) and the gain fail."""
    traj, lower = worst["traj"], worst["lin"].peak_gain
    claims = from_rest_claims(traj, worst["paper"].gamma, lower)
    assert all(c.passed for c in claims), [c.to_json() for c in claims]
    wrong = from_rest_claims(traj, 0.97 * worst["ratio"], lower)
    assert [c.passed for c in wrong] == [False, False, False, True]


@pytest.mark.slow
def test_verify_runs_theorem_2_from_rest(worst):
    """``verify``'s own run (the linearisation's worst sinusoid from rest, 20 s or longer until
    its gain converges) attains 95% of the H-infinity norm and its claims fail for a gamma 5%
    under the norm."""
    loop, s0, settings = worst["loop"], worst["s0"], worst["settings"]
    short = replace(settings, duration=2.0, jit=False)
    claims = {c.name: c for c in theorem_2(loop, s0, short, 0.95 * worst["lin"].peak_gain)}
    gain = claims["measured gain sqrt(int |x|^2 / int |w|^2) <= gamma"]
    horizon = float(re.search(r"disturbance, (\S+) s$", gain.detail).group(1))
    assert gain.passed is False and horizon >= FROM_REST_HORIZON
    assert next(c for n, c in claims.items() if n.startswith("the measured gain attains")).passed


def run_at_once(loop, lin, horizon: float):
    """The run from rest under the linearisation's worst sinusoid over ``horizon`` seconds, made at once."""
    simulator, s_eq = rest_simulator(loop, lin, peak_sinusoid(lin), horizon)
    return simulator.run(s_eq)


def _rise(traj) -> float:
    """The gain's rise from half the run's horizon to its end, relative to the gain at the end."""
    x2, w2 = traj.integrals["z_squared"], traj.integrals["d_squared"]
    half = int(np.searchsorted(traj.t, traj.t[-1] / 2))
    gain = np.sqrt(x2[-1] / w2[-1])
    return float((gain - np.sqrt(x2[half] / w2[half])) / gain)


@pytest.mark.slow
def test_from_rest_search_stops_at_the_first_converged_horizon(worst):
    """From a 2.5 s first run the horizon doubles until the gain rises by at most 1% from half
    the horizon to its end, and no further: the run kept meets the criterion and the run of half
    its length (the one before it) does not."""
    loop, lin = worst["loop"], worst["lin"]
    _, traj, converged = sharpest_from_rest(loop, lin, 2.5)
    horizon = float(traj.t[-1])
    assert converged and horizon > 2.5 and _rise(traj) <= 0.01
    assert _rise(run_at_once(loop, lin, horizon / 2)) > 0.01


@pytest.mark.slow
def test_certified_lower_bound_is_the_gain_verify_checks(worst):
    """``certify``'s (and the report's) nonlinear lower bound is the measured gain of ``verify``'s
    run from rest: one search, driven to its sharpness in one place. The same run integrated
    twice by CVODES at 1e-10 differs by about 1e-8 relative (measured, repeated runs), so 1e-6,
    the bound of the identity residuals; another horizon moves the gain by up to 1%."""
    loop, s0 = worst["loop"], worst["s0"]
    short = replace(worst["settings"], duration=1.0, jit=False)
    claims = theorem_2(loop, s0, short, worst["paper"].gamma)
    gain = next(c for c in claims if c.name == "measured gain sqrt(int |x|^2 / int |w|^2) <= gamma")
    point = CertificatePoint(gains={}, weights={}, weights_of_plant={}, certified=True, gamma=worst["paper"].gamma,
                             method="-", margin=None, reason=None, worst_rotation=None, gamma_worst_found=None,
                             gap=None)  # fmt: skip
    record = lower_bound_record(loop, s0, point)
    assert record["gamma_lower_nonlinear"] == pytest.approx(gain.value, rel=1e-6)
    assert record["worst_disturbance"]["converged"]


@pytest.mark.slow
def test_from_rest_check_is_conclusive_on_a_seven_joint_arm(tmp_path):
    """The shipped xArm 7 design with ``k_c = 1.5``: slow enough that 20 s from rest reach only
    0.94 of the H-infinity norm; the run is lengthened until its gain converges, and the check
    then bites (at least 95%) instead of ending INCONCLUSIVE on a healthy design."""
    source = Path(__file__).parents[1] / "examples" / "xarm7_circle.toml"
    path = tmp_path / "xarm7.toml"
    path.write_text(re.sub(r"^k_c = .*$", "k_c = 1.5", source.read_text(), flags=re.M))
    case = Case.load(path)
    assert case.loop.robot.n == 7
    short = replace(case.settings, duration=1.0, jit=False)
    gamma = certify(case.point, case.reference).gamma
    claims = theorem_2(case.loop, case.s0, short, gamma)
    attained = next(c for c in claims if c.name.startswith("the measured gain attains"))
    assert attained.passed is True and attained.value >= ATTAINED, attained.to_json()
    assert all(c.passed for c in claims if c.reference.startswith("Theorem 2")), [c.to_json() for c in claims]


def test_a_continued_run_from_rest_is_the_run_made_at_once(worst):
    """The horizon search continues its last run instead of starting again: a run from rest to
    2.5 s continued to 5 s has the samples, states, integrals and signals of the 5 s run made at once,
    to the global error of two step sequences each within CVODES's 1e-10 (1.2e-9 measured on ``qd``;
    1e-8 allowed, as between the compiled and the interpreted right-hand side); its first 2.5 s are
    the shorter run's own, bit for bit."""
    loop, lin = worst["loop"], worst["lin"]
    short = run_at_once(loop, lin, 2.5)
    simulator, s_eq = rest_simulator(loop, lin, peak_sinusoid(lin), 5.0)
    continued, whole = simulator.continued(s_eq, short, 5.0), simulator.run(s_eq)
    assert continued.status == whole.status == "ok" and np.array_equal(continued.t, whole.t)
    assert set(continued.signals) == set(whole.signals) and continued.stats["steps"] > short.stats["steps"]
    for name in whole.signals:
        assert continued[name].shape == whole[name].shape, name
        assert np.abs(continued[name] - whole[name]).max() <= 1e-8 * max(1.0, np.abs(whole[name]).max()), name
        assert np.array_equal(continued[name][: len(short.t)], short[name]), name
    for name in whole.integrals:
        assert continued.integrals[name][-1] == pytest.approx(whole.integrals[name][-1], rel=1e-6)


@pytest.mark.slow
def test_a_longer_run_that_stops_is_dropped_for_the_last_that_completed():
    """On the shipped Puma 560 the run from rest reaches 80 s only by driving the arm to a
    singularity (its worst disturbance is a constant target velocity): the 40 s run that
    completed is kept, and every Theorem 2 claim on it is conclusive."""
    case = Case.load(Path(__file__).parents[1] / "examples" / "puma560_circle.toml")
    short = replace(case.settings, duration=1.0, jit=False)
    claims = [c for c in theorem_2(case.loop, case.s0, short, certify(case.point, case.reference).gamma)
              if c.reference.startswith("Theorem 2") or c.reference == "lower bound"]  # fmt: skip
    assert len(claims) == 4 and all(c.passed is True for c in claims), [c.to_json() for c in claims]
