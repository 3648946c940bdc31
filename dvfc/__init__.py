"""dvfc: passivity-based dynamic visual feedback control (Kawai and Fujita), executable and checkable.

The curated API, one function a job, each taking a :class:`~dvfc.analysis.case.Case` (a
scenario read, validated and built once)::

    import dvfc

    case = dvfc.load()                       # the built-in default, or dvfc.load("my_cell.toml")
    run = dvfc.simulate(case)                # the loop as implemented (a Trajectory)
    certificate = dvfc.certify(case)         # Theorem 2 and the operating envelope (.to_json(): its JSON)
    plane = dvfc.gain_map(case)              # Theorem 2 over a plane of gains
    verification = dvfc.verify(case)         # every claim of the paper on simulated runs
    margins = dvfc.margins(case, "out/m")    # where the loop as implemented stops holding (measured)
    campaign = dvfc.campaign(case, "out/c")  # the [dispersion] as a campaign of runs (measured)
    design = dvfc.synthesize(case, "out/s.toml")  # gains of the [synthesize] box, written as a scenario
    review = dvfc.report(case, "out/r")      # the design-review report: .html, .pdf, .verdict
    program = dvfc.controller(case)          # the controller as the robot runs it, one step a sample

Everything else lives in the layers: :mod:`dvfc.models` (the symbolic model), :mod:`dvfc.analysis`
(runs, certificates, checks, synthesis) and :mod:`dvfc.reports`. The names are imported on first
use, so ``import dvfc.models.lie`` stays light.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    import numpy as np

    from dvfc.analysis.campaign import CampaignResult
    from dvfc.analysis.case import Case
    from dvfc.analysis.controller import Controller
    from dvfc.analysis.grid import GainMap
    from dvfc.analysis.margins import MarginsResult
    from dvfc.analysis.results import CertificateResult, VerificationResult
    from dvfc.analysis.simulate import Trajectory
    from dvfc.analysis.synthesize import SynthesisResult
    from dvfc.reports.document import ReportResult

__all__ = ["Case", "campaign", "certify", "controller", "gain_map", "load", "margins", "report", "simulate",
           "synthesize", "verify"]


def __getattr__(name: str):
    if name == "Case":
        from dvfc.analysis.case import Case

        return Case
    raise AttributeError(f"module 'dvfc' has no attribute {name!r}")


def load(path: str | Path | None = None, *, mode: Literal["ideal", "image"] | None = None) -> Case:
    """Read, validate and build a scenario file (the built-in default when None); ``mode``
    overrides ``[simulation] mode`` ("ideal" or "image"). Bad input raises
    :class:`~dvfc.analysis.scenario.ScenarioError` naming the field."""
    from dvfc.analysis.case import Case
    from dvfc.analysis.scenario import DEFAULT_SCENARIO

    return Case.load(DEFAULT_SCENARIO if path is None else path, mode=mode)


def simulate(case: Case) -> Trajectory:
    """The case's loop as implemented (sampled when it has an ``[implementation]``, else the
    paper's continuous loop), from its initial state."""
    from dvfc.analysis.sampled import as_implemented

    return as_implemented(case.loop, case.settings).run(case.s0)


def controller(case: Case) -> Controller:
    """The case's controller as the program a robot runs (its ``[implementation]`` needed): one
    step per control sample from the sampled ``q``, ``qd`` and, when one arrives, an image,
    ``.step(state, t, q, qd, features_or_None, capture_step) -> (tau, state)`` from
    ``.initial_state()``; ``dvfc export`` generates the same step as C."""
    from dvfc.analysis.controller import Controller
    from dvfc.analysis.export import exportable

    exportable(case)
    return Controller(case)


def certify(case: Case, *, lower_bounds: bool = True) -> CertificateResult:
    """Theorem 2 at the case's gains (closed form, SDP cross-check, a posteriori check), the
    scaled-storage gamma, lower bounds on the true gain (unless ``lower_bounds`` is False) and
    the operating envelope; ``.to_json()`` is the JSON of ``dvfc certify``."""
    from dvfc.analysis.results import certificate_result

    return certificate_result(case, case.provenance(["dvfc.certify"]), lower_bounds=lower_bounds)


def gain_map(case: Case, axes: list[tuple[str, np.ndarray]] | None = None) -> GainMap:
    """Theorem 2 certified over the plane of two gain or weight ``axes`` (name, values) through
    the case's design (by default ``k_c`` and ``k_e`` from a tenth to ten times the design's),
    each point by the exact closed form with its a posteriori check."""
    from dvfc.analysis.grid import gain_map as certify_plane

    return certify_plane(case.point, case.reference, axes, case.scenario.certify.gamma)


def verify(case: Case) -> VerificationResult:
    """Every claim of the paper checked on simulated runs of the case; ``.to_json()`` is the JSON of
    ``dvfc verify``."""
    from dvfc.analysis.results import verification_result

    return verification_result(case, case.provenance(["dvfc.verify"]))


def margins(case: Case, directory: str | Path, *, workers: int = 1, resume: bool = False) -> MarginsResult:
    """The measured margins of the case's loop as implemented (each parameter by bisection on the
    nonlinear sampled loop, runs logged in ``directory``); ``.to_json()`` is the JSON of ``dvfc margins``."""
    from dvfc.analysis.jobs import margins as measure

    return measure(case, Path(directory), case.provenance(["dvfc.margins"]), workers=workers, resume=resume)


def campaign(case: Case, directory: str | Path, runs: int = 100, *, seed: int = 0, workers: int = 1,
             resume: bool = False, confidence: float | None = None, p_fail: float | None = None,
             quantile: float | None = None, search: int = 0) -> CampaignResult:
    """The case's ``[dispersion]`` as a campaign of ``runs`` runs of the loop as implemented, each judged
    by the margins criterion, stored in ``directory`` (``resume`` continues one); the failure probability's
    bound at ``confidence``, the zero-failure count for ``p_fail``, the tracking error's ``quantile``
    (None: the command's defaults) and, with ``search`` runs, the worst case found
    (:func:`dvfc.analysis.campaign.campaign`); ``.to_json()`` is the JSON of ``dvfc campaign``."""
    from dvfc.analysis import campaign as defaults
    from dvfc.analysis.jobs import campaign as run

    return run(case, Path(directory), case.provenance(["dvfc.campaign"]), runs, seed=seed, workers=workers,
               resume=resume, confidence=defaults.CONFIDENCE if confidence is None else confidence,
               p_fail=defaults.P_FAIL if p_fail is None else p_fail,
               quantile=defaults.QUANTILE if quantile is None else quantile, search=search)


def synthesize(case: Case, target: str | Path, *, resume: bool = False) -> SynthesisResult:
    """Gains within the case's ``[synthesize]`` box minimising the certified gamma (fact 6), reaching its
    gamma with the smallest gains, or maximising the certified target speed (facts 7-8), each design
    checked on the loop as implemented; the accepted design written as a scenario at ``target`` (the case
    loaded from a file); ``.to_json()`` is the JSON of ``dvfc synthesize``."""
    from dvfc.analysis.synthesize import synthesize_scenario

    return synthesize_scenario(case, Path(target), case.provenance(["dvfc.synthesize"]), resume=resume)


def report(case: Case, directory: str | Path) -> ReportResult:
    """Write the design-review report of the case: ``directory/report.html`` and ``report.pdf``, with the
    review's verdict."""
    from dvfc.reports.document import report as write_report

    return write_report(case, Path(directory), case.provenance(["dvfc.report"]))
