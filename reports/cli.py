"""The full ``dvfc`` command line: the analysis commands plus ``dvfc report``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from dvfc.analysis.cli import (
    DEFAULT_SCENARIO,
    OutOpt,
    ScenarioArg,
    app,
    command_provenance,
    err,
    load_case,
    out,
    prepare_out_dir,
    require_six,
    resumable,
)
from dvfc.analysis.output import atomic_write
from dvfc.analysis.results import statements, verdict
from dvfc.reports.document import STEPS, assemble, write
from dvfc.reports.stages import CACHE, TIMINGS, StageCache, StepTimes


@app.command()
def report(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    resume: Annotated[bool, typer.Option(help="Reuse the stages of a report in --out whose inputs are unchanged "
                                               "(interrupted, or of an edited scenario).")] = False,
) -> None:
    """Write the design-review report of a scenario: report.html (self-contained) and report.pdf.
    Exit 0: certified and every check passes; 1: not certified, or a check fails or is inconclusive."""
    times = StepTimes()
    times("scenario built")
    case = load_case(scenario)
    require_six(case, "report")
    directory = prepare_out_dir(out_dir or Path("out") / case.name)
    provenance_ = command_provenance(scenario)
    cache = StageCache(directory / CACHE, str(provenance_["toolkit"]["dvfc"]), resume)
    columns = (
        SpinnerColumn(),
        TextColumn("[bold]report[/] {task.description}"),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
    )
    with (
        resumable(f"dvfc report {scenario} --out {directory} --resume"),
        Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar,
    ):
        task = bar.add_task("", total=len(STEPS) + 1)

        def step(name: str) -> None:
            times(name)
            done = STEPS.index(name) if name in STEPS else len(STEPS)
            bar.update(task, description=name, completed=done)
            if not err.is_terminal:  # CI logs, nohup: one plain line a stage
                err.print(f"report: {name} ({done + 1}/{len(STEPS) + 1})", markup=False)

        data = assemble(case, provenance_, progress=step, cache=cache)
        step("HTML and PDF")
        html, pdf = write(data, directory)
        times("end")
        atomic_write(directory / CACHE / TIMINGS, lambda h: h.write(times.table(cache).encode()))
    out.print(f"report: {html}\n        {pdf}", markup=False)
    review = statements(data.certificate, data.verification, data.margins, data.dispersion, data.controller)
    outcome = verdict(data.certificate, data.verification, review)
    out.print(outcome["headline"], markup=False)
    for claim in outcome["failed"] + outcome["inconclusive"]:
        out.print(f"  {claim['status']} {claim['paper']}: {claim['claim']} ({claim['detail']})", markup=False)
    for s in outcome["not_certified"]:
        out.print(f"  {s['status']} {s['statement']} ({s['loop']}): {s['detail']}", markup=False)
    if not outcome["passed"]:
        raise typer.Exit(1)
