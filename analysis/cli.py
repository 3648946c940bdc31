"""The analysis commands of ``dvfc`` (``simulate``, ``pose``, ``certify``, ``verify``, ``synthesize``,
``margins``, ``campaign``, ``export``; :mod:`dvfc.reports.cli` adds ``report``): each parses its
options, calls its job (:mod:`dvfc.analysis.jobs`), shows progress, prints the result
(:mod:`dvfc.analysis.show`) and writes its JSON.

Exit status: 0 success; 1 the job's answer is no (a run did not finish cleanly, a point is not
certified, a claim fails, a campaign run fails, nothing synthesised); 2 bad input (one line on
standard error naming the field or the option, before any output); 130 interrupted (with the line
that resumes).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer

from dvfc.analysis.console import announcing, err, progress_bar, say, status, warn
from dvfc.analysis.defaults import CONFIDENCE, DEFAULT_SCENARIO, MAX_GRID_BYTES, MAX_GRID_POINTS, P_FAIL, QUANTILE
from dvfc.analysis.output import interrupt_aware, interrupted, provenance, raise_if_interrupted, write_json

if TYPE_CHECKING:
    from dvfc.analysis.case import Case
    from dvfc.analysis.record import Serialisable

# The jobs, and the numerical libraries under them, are imported by the command that runs them, so that
# ``dvfc --help`` and a command's option parsing load none of them.

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    help="Dynamic visual feedback control: simulate, verify, certify.",
)


class Mode(StrEnum):
    ideal = "ideal"
    image = "image"


def fail(message: str) -> typer.Exit:
    """Print one line naming the problem and return the exit for status 2."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(2)


def check_out_dir(path: Path) -> None:
    """Fail (status 2) when the output directory's path is taken by something else than a directory."""
    if path.exists() and not path.is_dir():
        raise fail(f"--out: {path} exists and is not a directory")


def prepare_out_dir(path: Path) -> Path:
    """Create the output directory, or fail (status 2) before any work is done."""
    check_out_dir(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise fail(f"--out: cannot create {path}: {exc.strerror}") from exc
    if not os.access(path, os.W_OK):
        raise fail(f"--out: {path} is not writable")
    return path


def check_json_target(target: str | None) -> None:
    if target in (None, "-"):
        return
    parent = Path(target).parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise fail(f"--json: cannot write {target} (directory missing or not writable)")


def emit(result: Serialisable, saved: Path | None, json_target: str | None, show_: Callable[[Any], None]) -> None:
    """Write ``result``'s JSON to ``saved`` (atomically) and to ``--json``; show it to a person unless the
    JSON goes to standard output."""
    data = result.to_json()
    if saved is not None:
        write_json(saved, data)
    if json_target is not None:
        write_json(json_target, data)
    if json_target != "-":
        show_(result)


@contextmanager
def resumable(command: str) -> Iterator[None]:
    """On Ctrl-C, wherever it lands (see :func:`dvfc.analysis.output.interrupted`): one line saying
    how to resume with ``command``, exit status 130."""
    with interrupt_aware():
        try:
            yield
            raise_if_interrupted()
        except BaseException as exc:
            if not interrupted(exc):
                raise
            warn(f"interrupted: resume with  {command}")
            raise typer.Exit(130) from None


@contextmanager
def library_errors(flags: dict[str, str], out: Path | None = None) -> Iterator[None]:
    """Bad input raised by a job (``"argument: why"``): one line, exit 2, the argument named by its
    option (``flags``), a scenario field as it is; the output folder ``out`` not writable as ``--out``."""
    from dvfc.analysis.export import ExportError
    from dvfc.analysis.schema import ScenarioError

    try:
        yield
    except ScenarioError as exc:
        raise fail(str(exc)) from exc
    except PermissionError as exc:
        raise fail(f"--out: cannot write in {out}: {exc.strerror}") from exc
    except (ValueError, ExportError) as exc:
        name, _, why = str(exc).partition(": ")
        raise fail(f"{flags[name]}: {why}" if name in flags else str(exc)) from exc


def command_provenance(scenario: Path) -> dict:
    """Provenance of this command line on ``scenario``."""
    return provenance(scenario, ["dvfc", *sys.argv[1:]])


def load_case(path: Path, mode: Literal["ideal", "image"] | None = None, check_view: bool = True) -> Case:
    """Read, validate and build a scenario once for the command, or exit with status 2 and one
    line: every command rejects the same bad input, whether or not it uses the faulty part."""
    from dvfc.analysis.case import Case
    from dvfc.analysis.schema import ScenarioError

    try:
        case = Case.load(path, mode=mode, check_view=check_view)
        if case.scenario.grid is not None:  # its ranges are checked here, before any work
            case.scenario.grid.axes()
    except ScenarioError as exc:
        raise fail(str(exc)) from exc
    return case


def warn_fewer_than_six(case: Case) -> None:
    """One warning line on standard error when Theorems 1-2 do not apply (:attr:`Case.theorems_do_not_apply`)."""
    if (why := case.theorems_do_not_apply) is not None:
        warn(f"warning: {why}")


def warn_windows(case: Case) -> None:
    """One warning line on standard error, before any run, when a gain ``k_xi,i`` lies outside
    its window (:func:`dvfc.analysis.windows.case_windows`), naming the limit it breaks."""
    from dvfc.analysis.windows import case_windows

    windows = case_windows(case)
    if windows is not None and (line := windows.warning()) is not None:
        warn(f"warning: {line}")


def require_six(case: Case, command: str) -> None:
    """Refuse ``command`` (status 2, before any work) when it rests on Theorems 1-2 and they do
    not apply (:attr:`Case.theorems_do_not_apply`)."""
    from dvfc.analysis import jobs

    with library_errors({}):
        jobs.require_theorems(case, command)


def hint(command: str) -> None:
    """The line pointing at ``--what-would-pass`` when nothing passes (standard error)."""
    warn(f"what would pass: {command} searches the least change of the control rate, camera rate or latency at "
         "which the synthesis for the campaign succeeds")  # fmt: skip


ScenarioArg = Annotated[Path, typer.Argument(help="Scenario TOML file (default: the built-in UR5 scenario).")]
OutOpt = Annotated[Path | None, typer.Option("--out", help="Output directory (default: out/<scenario name>).")]
JsonOpt = Annotated[str | None, typer.Option("--json", help="Write the JSON summary to FILE, or '-' for stdout.")]
SchedulerOpt = Annotated[str | None, typer.Option(help="Dask scheduler address, or 'local' for a LocalCluster.")]
WhatWouldPassOpt = Annotated[bool, typer.Option(
    "--what-would-pass",
    help="Search the least change of the control rate, camera rate or latency at which synthesize --for-campaign "
         "succeeds (a bisection on each, measured; resumable with --resume).")]  # fmt: skip
REPLAY_FLAGS = {"campaign_run": "--campaign-run", "campaign_values": "--campaign-values"}


@app.command()
def simulate(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
    mode: Annotated[Mode | None, typer.Option(help="Override [simulation] mode.")] = None,
    campaign_run: Annotated[int | None, typer.Option(min=0, help="Replay run K of `dvfc campaign`.")] = None,
    campaign_values: Annotated[
        Path | None, typer.Option(help="Replay the values of a worst-case file of `dvfc campaign`.")
    ] = None,
    campaign_seed: Annotated[int, typer.Option(min=0, help="The campaign's --seed.")] = 0,
) -> None:
    """Simulate the closed loop (36), (42) and check its energy identities."""
    from dvfc.analysis import jobs, show

    case = load_case(scenario, mode.value if mode else None)
    check_json_target(json_target)
    directory = out_dir or Path("out") / case.name
    check_out_dir(directory)
    warn_fewer_than_six(case)
    warn_windows(case)
    with (
        library_errors(REPLAY_FLAGS, directory),
        progress_bar(f"simulate {case.name}", case.settings.duration, "s", start="compiling") as advance,
    ):
        result = jobs.simulate(case, directory, command_provenance(scenario), campaign_run=campaign_run,
                               campaign_values=campaign_values, campaign_seed=campaign_seed, progress=advance)
    emit(result, directory / "summary.json", json_target, show.show_simulation)
    if not result.completed:
        warn(f"run stopped: {result.run.message}")
        raise typer.Exit(1)
    if isinstance(row := result.campaign_row, dict):
        which = "worst-case values" if campaign_values else f"run {campaign_run}"
        warn(f"campaign {which}: {'holds' if row['holds'] else 'FAILS'} by the margins criterion ({row['reason']})")
        if not row["holds"]:
            raise typer.Exit(1)


@app.command()
def pose(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    json_target: JsonOpt = None,
    solve: Annotated[bool, typer.Option("--solve", help="Solve for q0 (as [robot] q0 = \"auto\") and show "
                                        "the start from there, with the line to paste.")] = False,
) -> None:
    """Show where everything is at the start: the camera's pose at q0, the target's pose (in the
    world and from the camera) and each feature point's image position and depth, for placing
    the target in view (see [target] relative_to_camera). With --solve, q0 is first solved for
    the camera at the reference pose relative to the target, within the position limits, and
    printed with its conditioning, pose error and limits. Exit 1 when a point is out of view."""
    from dvfc.analysis import jobs, show

    case = load_case(scenario, check_view=False)
    check_json_target(json_target)
    warn_fewer_than_six(case)
    with library_errors({}):
        result = jobs.pose(case, solve=solve)
    if result.windows_warning is not None:
        warn(f"warning: {result.windows_warning}")
    emit(result, None, json_target, show.show_pose)
    if not result.in_view:
        raise typer.Exit(1)


GRID_FLAGS = {"large": "--large", "resume": "--resume"}


@app.command("certify")
def certify_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
    workers: Annotated[int, typer.Option(min=1, help="Local worker processes for a grid.")] = 1,
    scheduler: SchedulerOpt = None,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted grid sweep in --out.")] = False,
    large: Annotated[bool, typer.Option(help=f"Allow grids of more than {MAX_GRID_POINTS:.0e} points or "
                                             f"{MAX_GRID_BYTES:.0e} bytes.")] = False,
    batch_size: Annotated[int, typer.Option(min=1, help="Grid points per batch (one Parquet file each).")] = 20000,
    csv: Annotated[bool, typer.Option("--csv", help="Grid: also export the points as DIR/points.csv.")] = False,
    lower_bounds: Annotated[
        bool, typer.Option(help="Single point: also measure lower bounds on the true L2 gain (linearisation, search).")
    ] = True,
) -> None:
    """Certify Theorem 2 (L2 gain <= gamma) for the scenario's gains, or every point of its
    [grid], over the [certify] region. Exit 0: all certified; 1: some not; 2: bad input."""
    from dvfc.analysis import jobs, show
    from dvfc.analysis.certify import NOT_APPLICABLE
    from dvfc.analysis.results import certificate_result

    case = load_case(scenario)
    check_json_target(json_target)
    warn_windows(case)
    if case.scenario.grid is None:
        directory = prepare_out_dir(out_dir) if out_dir is not None else None
        with status("certifying and measuring lower bounds on the L2 gain"):
            result = certificate_result(case, command_provenance(scenario), lower_bounds=lower_bounds)
        emit(result, directory / "certificate.json" if directory else None, json_target, show.show_certificate)
        raise typer.Exit(0 if result.certified else 1)
    if case.theorems_do_not_apply is not None and case.scenario.loop == "paper":
        warn(f"NOT CERTIFIED: {NOT_APPLICABLE.format(n=case.loop.robot.n)}")
        raise typer.Exit(1)
    directory = out_dir or Path("out") / f"{case.name}-grid"
    check_out_dir(directory)
    with library_errors(GRID_FLAGS, directory):
        warn(jobs.grid_size(case, csv=csv, large=large))
    with (resumable(f"dvfc certify {scenario} --out {directory} --resume"), library_errors(GRID_FLAGS, directory),
          progress_bar("certify grid", jobs.grid_points(case), "points") as advance):  # fmt: skip
        result = jobs.certify_grid(case, directory, command_provenance(scenario), workers=workers, scheduler=scheduler,
                                   resume=resume, batch_size=batch_size, csv=csv, large=large, progress=advance)
    emit(result, directory / "certificate.json", json_target, show.show_grid)
    raise typer.Exit(0 if result.certified else 1)


@app.command("synthesize")
def synthesize_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_file: Annotated[
        Path | None, typer.Option("--out", help="Scenario file to write (default: out/<name>-synthesized.toml).")
    ] = None,
    json_target: JsonOpt = None,
    resume: Annotated[
        bool, typer.Option(help="Reuse the runs of an interrupted limits search (or --what-would-pass search).")
    ] = False,
    for_campaign: Annotated[
        bool, typer.Option("--for-campaign", help="Gains and integral action that hold on the [dispersion] campaign.")
    ] = False,
    p_fail: Annotated[float, typer.Option(help="--for-campaign: P(fail) the confirmation bounds, in (0, 1).")] = P_FAIL,
    confidence: Annotated[float, typer.Option(help="--for-campaign: its confidence, in (0, 1).")] = CONFIDENCE,
    workers: Annotated[int, typer.Option(min=1, help="--for-campaign: local worker processes.")] = 1,
    what: WhatWouldPassOpt = False,
) -> None:
    """Choose diagonal gains within the [synthesize] bounds that minimise the certified gamma
    (fact 6), reach [synthesize] gamma with the smallest gains, or (objective = "target_speed")
    maximise the envelope's certified target speed (facts 7-8); with --for-campaign, gains and
    integral action that hold on the scenario's campaign; write them as a scenario."""
    from dvfc.analysis import jobs, show
    from dvfc.analysis.synthesize import synthesize_scenario

    if what and not for_campaign:
        raise fail("--what-would-pass: searches the hardware for the synthesis --for-campaign; give --for-campaign")
    case = load_case(scenario)
    check_json_target(json_target)
    target = out_file or Path("out") / f"{case.name}-synthesized.toml"
    check_out_dir(target.parent)
    flags = {"resume": "--resume", "p_fail": "--p-fail", "confidence": "--confidence"}
    again = f"dvfc synthesize {scenario} --out {target} --resume" + (
        f" --for-campaign --p-fail {p_fail:g} --confidence {confidence:g}" if for_campaign else "")  # fmt: skip
    with (resumable(again + (" --what-would-pass" if what else "")), library_errors(flags, target.parent),
          announcing("synthesising the gains") as announce):  # fmt: skip
        if for_campaign:
            result: Any = jobs.synthesize_for_campaign_job(case, target, command_provenance(scenario), p_fail=p_fail,
                                                           confidence=confidence, workers=workers, what=what,
                                                           resume=resume, say=announce)  # fmt: skip
        else:
            result = synthesize_scenario(case, target, command_provenance(scenario), resume=resume, progress=announce)
    emit(result, None, json_target, show.show_campaign_design if for_campaign else show.show_synthesis)
    if for_campaign and result.scenario_file is None and not what:
        hint(f"dvfc synthesize {scenario} --for-campaign --what-would-pass")
    raise typer.Exit(0 if (result.scenario_file is not None if for_campaign else result.written) else 1)


@app.command("margins")
def margins_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
    workers: Annotated[int, typer.Option(min=1, help="Local worker processes (one search per parameter).")] = 1,
    scheduler: SchedulerOpt = None,
    resume: Annotated[bool, typer.Option(help="Reuse the runs of an interrupted search in --out.")] = False,
    what: WhatWouldPassOpt = False,
) -> None:
    """Measure where the loop as implemented stops holding: latency, camera rate, payload
    mass, pixel noise and torque-limit scale, each by bisection on the nonlinear loop; and
    the linear margins of the sampled loop linearised at rest (fact 14). Exit 0 done, 1 no
    margin (the scenario's own run fails), 2 bad input."""
    from dvfc.analysis import jobs, show
    from dvfc.analysis.margins import planned_runs, runs_done

    case = load_case(scenario)
    check_json_target(json_target)
    directory = out_dir or Path("out") / f"{case.name}-margins"
    check_out_dir(directory)
    again = f"dvfc margins {scenario} --out {directory} --resume"
    with (resumable(again + (" --what-would-pass" if what else "")), library_errors({"resume": "--resume"}, directory),
          progress_bar("margins", planned_runs(), "runs") as advance):  # fmt: skip
        result = jobs.margins(case, directory, command_provenance(scenario), workers=workers, scheduler=scheduler,
                              resume=resume, what=what, poll=lambda: advance(runs_done(directory)), say=warn)
    if result.margins is None:
        warn(f"no margins: {result.no_margins}")
        if what:
            emit(result, directory / "margins.json", json_target, show.show_margins)
        elif case.scenario.dispersion:
            hint(f"dvfc margins {scenario} --out {directory} --what-would-pass")
        raise typer.Exit(1)
    emit(result, directory / "margins.json", json_target, show.show_margins)


@app.command("verify")
def verify_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
) -> None:
    """Check every claim of the paper (Lemmas 1-2, Theorems 1-2, the passivity remarks, the
    Lyapunov derivative) on simulated trajectories; measure the image loop's gap."""
    from dvfc.analysis import show
    from dvfc.analysis.results import verification_result

    case = load_case(scenario)
    check_json_target(json_target)
    warn_fewer_than_six(case)
    warn_windows(case)
    directory = prepare_out_dir(out_dir) if out_dir is not None else None
    with status("simulating and checking the claims"):
        result = verification_result(case, command_provenance(scenario))
    emit(result, directory / "verification.json" if directory else None, json_target, show.show_verification)
    raise typer.Exit(0 if result.passed else 1)


CAMPAIGN_FLAGS = {"runs": "--runs", "confidence": "--confidence", "p_fail": "--p", "quantile": "--quantile",
                  "resume": "--resume"}
"""The campaign's job arguments (:func:`dvfc.analysis.jobs.campaign`) as the command line names them."""


@app.command("campaign")
def campaign_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    runs: Annotated[int, typer.Option(help="Runs to make (at least 1).")] = 100,
    confidence: Annotated[float, typer.Option(help="Confidence of the statements, in (0, 1).")] = CONFIDENCE,
    p_fail: Annotated[float, typer.Option("--p", help="P(fail) for the zero-failure run count, in (0, 1).")] = P_FAIL,
    quantile: Annotated[float, typer.Option(help="Quantile of the tracking error bounded, in (0, 1).")] = QUANTILE,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the campaign's seed sequence.")] = 0,
    search: Annotated[int, typer.Option(min=0, help="Runs of the worst-case search (0: none).")] = 0,
    workers: Annotated[int, typer.Option(min=1, help="Local worker processes.")] = 1,
    scheduler: SchedulerOpt = None,
    batch_size: Annotated[int, typer.Option(min=1, help="Runs per batch (one Parquet file each).")] = 25,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted campaign in --out.")] = False,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
    what: WhatWouldPassOpt = False,
) -> None:
    """Run the scenario's [dispersion] as a campaign of independent runs of the loop as implemented,
    each judged by the margins criterion; state the failure probability with its confidence.
    Exit 0 no failure, 1 some run fails, 2 bad input."""
    from dvfc.analysis import jobs, show

    case = load_case(scenario)
    check_json_target(json_target)
    directory = out_dir or Path("out") / f"{case.name}-campaign"
    check_out_dir(directory)  # the campaign creates it once its arguments are checked
    again = f"dvfc campaign {scenario} --runs {runs} --seed {seed} --out {directory} --resume"
    searched = f"{again} --p {p_fail:g} --confidence {confidence:g} --what-would-pass"
    with (resumable(searched if what else again), library_errors(CAMPAIGN_FLAGS, directory),
          progress_bar("campaign", runs, "runs") as advance):  # fmt: skip
        result = jobs.campaign(case, directory, command_provenance(scenario), runs, seed=seed, confidence=confidence,
                               p_fail=p_fail, quantile=quantile, search=search, batch_size=batch_size, workers=workers,
                               scheduler=scheduler, resume=resume, what=what, progress=advance, say=warn)
    emit(result, directory / "summary.json", json_target, show.show_campaign)
    if result.failures:
        if not what:
            hint(searched)
        raise typer.Exit(1)


@app.command("export")
def export_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Folder of the exported C code.")] = None,
    json_target: JsonOpt = None,
    check: Annotated[bool, typer.Option("--check", help="Compile, replay a simulated run, compare.")] = False,
) -> None:
    """Export the controller as C (dvfc_controller.h/.c over CasADi's generated step)."""
    from dvfc.analysis import jobs, show

    case = load_case(scenario)
    check_json_target(json_target)
    directory = out_dir or Path("out") / case.name / "controller"
    check_out_dir(directory)
    with library_errors({}, directory), status("exporting" + (", compiling and checking" if check else "")):
        result = jobs.export(case, directory, check=check)
    emit(result, None, json_target, show.show_export)
    if not result.passed:
        say("check failed: the compiled step differs from the Python step", err)
        raise typer.Exit(1)

