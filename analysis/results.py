"""JSON-ready results of the toolkit's jobs, shared by the command line and the reports."""

from __future__ import annotations

import math
import time

import numpy as np

from analysis.certify import ASSUMPTIONS, Certificate, GainPoint, TightCertificate, certify, tight_gamma
from analysis.linearize import linearize, worst_case_disturbance
from analysis.scenario import Scenario, gain_point
from analysis.simulate import Settings
from analysis.verify import Claim, verify
from models.loop import ClosedLoop


def point_record(point: GainPoint, cert: Certificate, tight: TightCertificate | None = None) -> dict:
    """One gain point of a certificate (with the fact-4 bound when computed)."""
    w = point.weights
    extra = {} if tight is None else {"gamma_tight": tight.gamma, "alpha": tight.alpha, "tight_reason": tight.reason}
    return {
        "gains": {"k_xi": point.k_xi.tolist(), "k_c": point.k_c.tolist(), "k_e": point.k_e.tolist()},
        "weights": {"w_pc": w.w_pc, "w_rc": w.w_rc, "w_pe": w.w_pe, "w_re": w.w_re},
        "certified": cert.certified,
        "gamma": cert.gamma,
        "method": cert.method,
        "margin": cert.margin,
        "reason": cert.reason,
        "worst_rotation": cert.worst_rotation,
        "gamma_worst_found": cert.gamma_worst_found,
        "gap": cert.gap,
        **extra,
    }


def lower_bound_record(loop: ClosedLoop, s0: np.ndarray, record: dict) -> dict:
    """Lower bounds on the true L2 gain and how far the certificates sit above them."""
    try:
        lin = linearize(loop, s0[: loop.robot.n])
    except ValueError as exc:
        return {"gamma_lower": None, "lower_bound_reason": str(exc)}
    nonlinear, disturbance = worst_case_disturbance(loop, lin)
    lower = max(lin.peak_gain, nonlinear)
    ratio = lambda g: None if g is None else g / lower  # noqa: E731
    return {
        "gamma_lower_linear": lin.peak_gain,
        "hinf_python_control": lin.hinf,
        "gamma_lower_nonlinear": nonlinear,
        "worst_disturbance": disturbance,
        "gamma_lower": lower,
        "tightness": ratio(record["gamma"]),
        "tightness_tight": ratio(record.get("gamma_tight")),
    }


def certificate_result(
    spec: Scenario, loop: ClosedLoop, s0: np.ndarray, provenance: dict, *, lower_bounds: bool = True
) -> tuple[dict, Certificate]:
    """Theorem 2 at the scenario's gains: the paper's gamma, the fact-4 gamma, and (optionally)
    lower bounds on the true gain, over the ``[certify]`` region."""
    start = time.perf_counter()
    point = gain_point(spec, loop.robot.n)
    reference = spec.reference.se3()
    cert = certify(point, reference, theta_max=math.radians(spec.certify.theta_max_deg), gamma_bound=spec.certify.gamma)
    record = point_record(point, cert, tight_gamma(point, reference))
    if lower_bounds:
        record.update(lower_bound_record(loop, s0, record))
    result = {
        "scenario": spec.name,
        "region": cert.region,
        "assumptions": list(ASSUMPTIONS),
        "gamma_required": spec.certify.gamma,
        "points": [record],
        "summary": {
            "points": 1,
            "certified": int(cert.certified),
            "gamma_min": cert.gamma,
            "seconds": time.perf_counter() - start,
        },
        "provenance": provenance,
    }
    return result, cert


def verification_result(
    spec: Scenario, loop: ClosedLoop, s0: np.ndarray, settings: Settings, provenance: dict
) -> tuple[dict, list[Claim]]:
    """Every claim of the paper checked on simulated runs, at the gamma certified for the gains."""
    start = time.perf_counter()
    g = loop.gains
    cert = certify(GainPoint(g.k_xi, g.k_c, g.k_e, loop.weights), loop.reference, with_sdp=False)
    claims = verify(loop, s0, settings, cert.gamma)
    failed = [c for c in claims if c.passed is False]
    result = {
        "scenario": spec.name,
        "gamma": cert.gamma,
        "claims": [c.as_dict() for c in claims],
        "summary": {"claims": sum(c.passed is not None for c in claims), "failed": len(failed),
                    "seconds": time.perf_counter() - start},
        "provenance": provenance,
    }  # fmt: skip
    return result, claims
