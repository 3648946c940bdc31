"""The full ``dvfc`` command line: the analysis commands (:mod:`dvfc.analysis.cli`) and ``dvfc report``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from dvfc.analysis.cli import (
    OutOpt,
    ScenarioArg,
    command_provenance,
    load_case,
    prepare_out_dir,
    require_six,
    resumable,
)
from dvfc.analysis.cli import app as analysis
from dvfc.analysis.console import progress_bar, say
from dvfc.analysis.defaults import DEFAULT_SCENARIO
from dvfc.analysis.output import atomic_write

if TYPE_CHECKING:
    from dvfc.reports.document import ReportResult

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    help="Dynamic visual feedback control: simulate, verify, certify, report.",
)
app.add_typer(analysis)


@app.command()
def report(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    resume: Annotated[bool, typer.Option(help="Reuse the stages of a report in --out whose inputs are unchanged "
                                               "(interrupted, or of an edited scenario).")] = False,
) -> None:
    """Write the design-review report of a scenario: report.html (self-contained) and report.pdf.
    Exit 0: certified and every check passes; 1: not certified, or a check fails or is inconclusive."""
    from dvfc.reports.document import STEPS
    from dvfc.reports.document import report as write_report
    from dvfc.reports.stages import CACHE, TIMINGS, StageCache, StepTimes

    times = StepTimes()
    times("scenario built")
    case = load_case(scenario)
    require_six(case, "report")
    directory = prepare_out_dir(out_dir or Path("out") / case.name)
    provenance_ = command_provenance(scenario)
    cache = StageCache(directory / CACHE, str(provenance_["toolkit"]["dvfc"]), resume)
    stages = [*STEPS, "HTML and PDF"]
    with (
        resumable(f"dvfc report {scenario} --out {directory} --resume"),
        progress_bar("report", len(stages), "stages") as advance,
    ):

        def step(name: str) -> None:
            times(name)
            advance(stages.index(name))

        result = write_report(case, directory, provenance_, progress=step, cache=cache)
        times("end")
        atomic_write(directory / CACHE / TIMINGS, lambda h: h.write(times.table(cache).encode()))
    show_report(result)
    if not result.verdict.passed:
        raise typer.Exit(1)


def show_report(result: ReportResult) -> None:
    """Human output of ``report``: the files, the verdict's headline, what keeps it from passing."""
    outcome = result.verdict
    say(f"report: {result.html}\n        {result.pdf}")
    say(outcome.headline)
    for claim in outcome.failed + outcome.inconclusive:
        say(f"  {claim['status']} {claim['paper']}: {claim['claim']} ({claim['detail']})")
    for s in outcome.not_certified:
        say(f"  {s.status} {s.statement} ({s.loop}): {s.detail}")
