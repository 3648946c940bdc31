"""Command line: ``dvfc simulate``.

Exit status: 0 success, 1 the run did not finish cleanly (diverged, time budget,
features lost), 2 bad input (one line on standard error naming the field).
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console, ConsoleDimensions
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

from dvfc.analysis.campaign import (
    CONFIDENCE,
    P_FAIL,
    QUANTILE,
    CampaignSpec,
    shared_simulator,
)
from dvfc.analysis.campaign import (
    campaign as run_campaign_job,
)
from dvfc.analysis.campaign import row as campaign_row
from dvfc.analysis.case import Case
from dvfc.analysis.cell import Design as CellDesign
from dvfc.analysis.cell import Search as CellSearch
from dvfc.analysis.cell import design_text, synthesize_for_campaign
from dvfc.analysis.cell import record as cell_record
from dvfc.analysis.certify import (
    INTEGRAL_COVERAGE,
    NOT_APPLICABLE,
    GainPoint,
)
from dvfc.analysis.export import ExportError, ExportResult, export_controller, exportable, program_digest
from dvfc.analysis.grid import BYTES_PER_POINT, POINTS, GridSpec, export_csv, run_sweep
from dvfc.analysis.hardware import value_text, what_would_pass
from dvfc.analysis.implementation import SubstepChoice
from dvfc.analysis.margins import (
    PARAMETERS,
    MarginError,
    TrackingBound,
    linear_margin_text,
    log_path,
    margins,
    planned_runs,
    runs_done,
    tracking_bound,
)
from dvfc.analysis.multirate import implemented_text
from dvfc.analysis.output import (
    atomic_write,
    interrupt_aware,
    interrupted,
    provenance,
    raise_if_interrupted,
    write_json,
)
from dvfc.analysis.pose import initial_view, solution_record
from dvfc.analysis.results import (
    certificate_result,
    channels_text,
    grid_envelope_for,
    grid_result,
    simulation_result,
    trajectory_arrays,
    verification_result,
)
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, ScenarioError, auto_q0
from dvfc.analysis.synthesize import refuse_unless_synthesisable, synthesize_scenario
from dvfc.analysis.tasks import run_tasks
from dvfc.analysis.windows import case_windows

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    help="Dynamic visual feedback control: simulate, verify, certify.",
)
WIDTH = 200
"""The columns of a table written to a file or a pipe (a terminal's own width otherwise): wide
enough that no column is cut, the same wherever the output goes."""


class FileConsole(Console):
    """A console whose output is not a terminal: ``$COLUMNS`` columns, read at each print, or
    :data:`WIDTH` without it."""

    @property
    def size(self) -> ConsoleDimensions:
        columns = os.environ.get("COLUMNS", "")
        return ConsoleDimensions(int(columns) if columns.isdigit() else WIDTH, super().size.height)

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        Console.size.fset(self, new_size)


def console(stderr: bool = False) -> Console:
    """A console as wide as its terminal, or a :class:`FileConsole` when the output is not one."""
    terminal = Console(stderr=stderr)
    return terminal if terminal.is_terminal else FileConsole(stderr=stderr)


err = console(stderr=True)
out = console()


@app.callback()
def toolkit() -> None:
    """Passivity-based dynamic visual feedback control (Kawai and Fujita): simulate, verify, certify."""


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


def emit(result: dict, saved: Path | None, json_target: str | None, show: Callable[[dict], None]) -> None:
    """Write ``result`` to ``saved`` (atomically) and to ``--json``; show it to a person
    unless the JSON goes to standard output."""
    if saved is not None:
        write_json(saved, result)
    if json_target is not None:
        write_json(json_target, result)
    if json_target != "-":
        show(result)


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
            err.print(f"interrupted: resume with  {command}", markup=False, soft_wrap=True)
            raise typer.Exit(130) from None


def command_provenance(scenario: Path) -> dict:
    """Provenance of this command line on ``scenario``."""
    return provenance(scenario, ["dvfc", *sys.argv[1:]])


def load_case(path: Path, mode: str | None = None, check_view: bool = True) -> Case:
    """Read, validate and build a scenario once for the command, or exit with status 2 and one
    line: every command rejects the same bad input, whether or not it uses the faulty part."""
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
        err.print(f"warning: {why}", markup=False, soft_wrap=True)


def warn_windows(case: Case) -> None:
    """One warning line on standard error, before any run, when a gain ``k_xi,i`` lies outside
    its window (:func:`dvfc.analysis.windows.case_windows`), naming the limit it breaks."""
    windows = case_windows(case)
    if windows is not None and (line := windows.warning()) is not None:
        err.print(f"warning: {line}", markup=False, soft_wrap=True)


def require_six(case: Case, command: str) -> None:
    """Refuse ``command`` (status 2, before any work) when it rests on Theorems 1-2 and they do
    not apply (:attr:`Case.theorems_do_not_apply`)."""
    if (why := case.theorems_do_not_apply) is not None:
        raise fail(f"loop: dvfc {command} needs the paper's equilibrium and Theorems 1-2; {why}")


ScenarioArg = Annotated[Path, typer.Argument(help="Scenario TOML file (default: the built-in UR5 scenario).")]
OutOpt = Annotated[Path | None, typer.Option("--out", help="Output directory (default: out/<scenario name>).")]
JsonOpt = Annotated[str | None, typer.Option("--json", help="Write the JSON summary to FILE, or '-' for stdout.")]
SchedulerOpt = Annotated[str | None, typer.Option(help="Dask scheduler address, or 'local' for a LocalCluster.")]
WhatWouldPassOpt = Annotated[bool, typer.Option(
    "--what-would-pass",
    help="Search the least change of the control rate, camera rate or latency at which synthesize --for-campaign "
         "succeeds (a bisection on each, measured; resumable with --resume).")]  # fmt: skip


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
    case = load_case(scenario, mode.value if mode else None)
    spec, loop, s0, settings = case.scenario, case.loop, case.s0, case.settings
    replayed = None
    if campaign_run is not None or campaign_values is not None:
        replayed = campaign_replay(case, campaign_run, campaign_values, campaign_seed)
        settings, s0 = replayed.run_settings(campaign_run or 0, replayed_values(replayed, campaign_values))
    check_json_target(json_target)
    warn_fewer_than_six(case)
    warn_windows(case)
    directory = prepare_out_dir(out_dir or Path("out") / spec.name)

    with Progress(
        TextColumn("[bold]simulate[/] {task.description}"),
        BarColumn(),
        TextColumn("t = {task.completed:.2f} / {task.total:.2f} s"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    ) as bar:
        task = bar.add_task("compiling" if settings.jit else spec.name, total=settings.duration)
        simulator = as_implemented(loop, settings) if replayed is None else shared_simulator(case).for_run(settings)
        bar.update(task, description=spec.name)
        lines = None if err.is_terminal else ProgressLines(f"simulate {spec.name}", settings.duration, "s")

        def advance(t: float) -> None:
            bar.update(task, completed=t)
            if lines is not None:
                lines(t)

        trajectory = simulator.run(s0, progress=advance)

    outputs = {"trajectory": directory / "trajectory.npz", "summary": directory / "summary.json"}
    result = simulation_result(case, trajectory, outputs, command_provenance(scenario), settings)
    if replayed is not None:
        values = replayed_values(replayed, campaign_values) or replayed.values(campaign_run)
        result["campaign_row"] = campaign_row(replayed, campaign_run or 0, trajectory, settings, values)
    arrays = trajectory_arrays(case, trajectory, settings)
    atomic_write(outputs["trajectory"], lambda h: np.savez_compressed(h, **arrays))
    emit(result, directory / "summary.json", json_target, show)
    if trajectory.status != "ok":
        err.print(f"run stopped: {trajectory.message}", markup=False, soft_wrap=True)
        raise typer.Exit(1)
    if replayed is not None:
        row, which = result["campaign_row"], "worst-case values" if campaign_values else f"run {campaign_run}"
        verdict = "holds" if row["holds"] else "FAILS"
        err.print(f"campaign {which}: {verdict} by the margins criterion ({row['reason']})", markup=False,
                  soft_wrap=True)  # fmt: skip
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
    case = load_case(scenario, check_view=False)
    check_json_target(json_target)
    warn_fewer_than_six(case)
    solution = None
    if solve:
        case, solution = solved_case(case)
    warn_windows(case)
    windows = case_windows(case)
    result = {"scenario": case.name, "solution": solution, **initial_view(case.loop, case.s0),
              "gain_windows": None if windows is None else windows.as_dict()}  # fmt: skip
    emit(result, None, json_target, show_pose)
    if not all(f["in_view"] for f in result["features"]):
        raise typer.Exit(1)


def solved_case(case: Case) -> tuple[Case, dict]:
    """The case started at the configuration ``dvfc pose --solve`` solves for
    (:func:`dvfc.analysis.scenario.auto_q0`), and its record (:func:`dvfc.analysis.pose.solution_record`)."""
    robot = case.loop.robot
    try:
        config = auto_q0(case.scenario, robot, "pose --solve")
        data = case.scenario.model_dump()
        data["robot"]["q0"] = config.q.tolist()
        solved = case.with_scenario(Scenario.model_validate(data))
    except ScenarioError as exc:
        raise fail(str(exc)) from exc
    return solved, solution_record(config, robot.limits)


def show_solution(solution: dict) -> None:
    """The configuration of ``pose --solve``: the line to paste, then its conditioning and errors."""
    limits = "every joint within its position limits" if solution["within_position_limits"] else (
        "joint(s) " + ", ".join(str(j + 1) for j, ok in enumerate(solution["joints_within_limits"]) if not ok)
        + " OUTSIDE their position limits")  # fmt: skip
    out.print(solution["q0_toml"], markup=False, soft_wrap=True)
    out.print(f"sigma_min(J_b) = {solution['sigma_min_body_jacobian']:.4g}, condition number "
              f"{solution['condition_number']:.4g}; pose error {solution['position_error_m']:.2e} m, "
              f"{solution['rotation_error_rad']:.2e} rad; {limits}", markup=False, soft_wrap=True)  # fmt: skip


def show_pose(result: dict) -> None:
    """Human output of ``pose``."""
    if (solution := result["solution"]) is not None:
        show_solution(solution)
    vec = lambda v: "[" + ", ".join(f"{x:.4g}" for x in v) + "]"  # noqa: E731
    for label, key in (("camera g_wc(q0)", "camera_in_world"), ("target g_wo(0)", "target_in_world"),
                       ("target from the camera g(0)", "target_in_camera")):  # fmt: skip
        pose_ = result[key]
        out.print(f"{label}: xyz = {vec(pose_['xyz'])} m, rpy = {vec(pose_['rpy'])} rad", markup=False, soft_wrap=True)
    size = result["image_size"]
    table = Table(title=f"feature points ({result['image_coordinates']}"
                  + (f", image {size[0]:g} x {size[1]:g})" if size else ")"))  # fmt: skip
    for col in ("point", "u [px]", "v [px]", "depth [m]", "in view"):
        table.add_column(Text(col))
    for f in result["features"]:
        table.add_row(str(f["point"]), f"{f['image'][0]:.1f}", f"{f['image'][1]:.1f}", f"{f['depth']:.4g}",
                      "yes" if f["in_view"] else "NO")  # fmt: skip
    out.print(table)
    if (windows := result["gain_windows"]) is not None:
        show_windows(windows)


def show_windows(windows: dict) -> None:
    """The gain windows of ``pose``: per joint ``k_xi``, the window and whether it lies inside."""
    table = Table(title="gain windows of k_xi (lower: " + windows["lower"] + "; upper: "
                  + (windows["upper"] or "none, the ideal continuous loop has no hold") + ")")  # fmt: skip
    for col in ("joint", "k_xi", "lower", "upper", "inside"):
        table.add_column(Text(col))
    for i, (k, (lo, hi), inside) in enumerate(zip(windows["k_xi"], windows["windows"], windows["inside"], strict=True)):
        upper = "-" if hi is None else f"{hi:.4g}" + (" (alone)" if windows["upper_alone"][i] else "")
        table.add_row(str(i + 1), f"{k:.4g}", f"{lo:.4g}", upper, "yes" if inside else "NO")
    out.print(table)


def _worst(ratios: list[float]) -> str:
    """The largest of per-joint ratios to a limit, with its joint and a plain verdict."""
    j = int(np.argmax(ratios))
    verdict = "within the URDF limit" if ratios[j] <= 1 else "EXCEEDS the URDF limit"
    return f"{ratios[j]:.3g} (joint {j + 1}, {verdict})"


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.3e}"


def show(result: dict) -> None:
    """A short human summary of a simulation."""
    s = result["summary"]
    table = Table(title=f"{result['scenario']} ({result['mode']} e_e)", show_header=False)
    f = s["final"]
    r = s["identity_residuals"]
    at = f" (at {s['final_at']:.4g} s, the last sample before the stop)" if s["stopped"] else ""
    rows = [
        ("status", s["status"]),
        ("horizon", f"{s['t_final']:.3g} s in {s['wall_time']:.3g} s wall"
         + (f", stopped at {s['stopped_at']:.4g} s" if s["stopped"] else "")),
        (f"final{at} tracking error g_d^-1 g: position, angle", f"{f['tracking_position']:.3e} m, "
         + ("-" if f["tracking_angle_deg"] is None else f"{f['tracking_angle_deg']:.3g} deg")),
        ("final control error e_c (estimate vs g_d): |p_ec|, |e_R(R_ec)|",
         f"{f['e_c_position']:.3e} m, {_number(f['e_c_rotation'])}"),
        ("final estimation error e_e (g vs estimate): |p_ee|, |e_R(R_ee)|",
         f"{f['e_e_position']:.3e} m, {_number(f['e_e_rotation'])}"),
        ("V(0) -> V(T)", f"{s['V0']:.4g} -> {s['VT']:.4g}"),
        ("max |tau| applied", f"{s['max_torque']:.4g} N m"),
        ("peak |tau| / effort limit", _worst(result["limits"]["torque_commanded_ratio"])),
        ("peak |qd| / velocity limit", _worst(result["limits"]["speed_ratio"])),
        ("joint range / position limits", _worst(result["limits"]["position_ratio"])),
        ("Lemma 2 identity residual", f"{r['passivity']:.2e}"),
        ("(43) identity residual", f"{r['dissipation']:.2e}"),
        ("max |e_e(image) - e_e|", f"{s['image_estimate_gap_max']:.3e}"),
        *([] if (how := result.get("integration")) is None else [("integration", SubstepChoice.from_dict(how).text)]),
    ]
    if (row := result.get("campaign_row")) is not None:
        verdict = f"{'holds' if row['holds'] else 'FAILS'} ({row['reason']})"
        rows.insert(1, ("campaign run, by the margins criterion", verdict))
    for name, value in rows:
        table.add_row(name, str(value))
    out.print(table)
    out.print(f"trajectory: {result['outputs']['trajectory']}\nsummary:    {result['outputs']['summary']}")




MAX_GRID_POINTS = 10**8
MAX_GRID_BYTES = 10**9
"""Grids of more points, or whose results are expected to take more bytes on disk, need ``--large``."""


@app.command("certify")
def certify_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
    workers: Annotated[int, typer.Option(min=1, help="Local worker processes for a grid.")] = 1,
    scheduler: SchedulerOpt = None,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted grid sweep in --out.")] = False,
    large: Annotated[
        bool, typer.Option(help=f"Allow grids of more than {MAX_GRID_POINTS:.0e} points or {MAX_GRID_BYTES:.0e} bytes.")
    ] = False,
    batch_size: Annotated[int, typer.Option(min=1, help="Grid points per batch (one Parquet file each).")] = 20000,
    csv: Annotated[bool, typer.Option("--csv", help="Grid: also export the points as DIR/points.csv.")] = False,
    lower_bounds: Annotated[
        bool, typer.Option(help="Single point: also measure lower bounds on the true L2 gain (linearisation, search).")
    ] = True,
) -> None:
    """Certify Theorem 2 (L2 gain <= gamma) for the scenario's gains, or every point of its
    [grid], over the [certify] region. Exit 0: all certified; 1: some not; 2: bad input."""
    start = time.perf_counter()
    case = load_case(scenario)
    spec, loop, point = case.scenario, case.loop, case.point
    axes = spec.grid.axes() if spec.grid is not None else None
    check_json_target(json_target)
    warn_windows(case)
    if axes is not None and spec.loop == "paper" and loop.robot.n < 6:
        err.print(f"NOT CERTIFIED: {NOT_APPLICABLE.format(n=loop.robot.n)}", markup=False, soft_wrap=True)
        raise typer.Exit(1)
    if axes is not None:
        size = int(np.prod([len(v) for _, v in axes], dtype=np.int64))
        expected = size * BYTES_PER_POINT
        if (size > MAX_GRID_POINTS or expected > MAX_GRID_BYTES) and not large:
            raise fail(f"grid: {size:,} points, about {expected / 1e6:,.0f} MB on disk, exceeds {MAX_GRID_POINTS:.0e} "
                       f"points or {MAX_GRID_BYTES / 1e6:,.0f} MB; pass --large to confirm")  # fmt: skip
        err.print(f"grid: {size:,} points, about {expected / 1e6:,.3g} MB on disk (Parquet, ~{BYTES_PER_POINT} bytes "
                  f"a point{'; plus CSV, about 4x more' if csv else ''})", markup=False, soft_wrap=True)  # fmt: skip
        directory = prepare_out_dir(out_dir or Path("out") / f"{spec.name}-grid")
        how = (workers, scheduler, resume, batch_size, csv)
        sweep(spec, scenario, point, axes, directory, json_target, how, start, grid_envelope_for(case))
        return
    directory = prepare_out_dir(out_dir) if out_dir is not None else None
    with err.status("certifying and measuring lower bounds on the L2 gain"):
        result, cert = certificate_result(case, command_provenance(scenario), lower_bounds=lower_bounds)
    emit(result, directory / "certificate.json" if directory else None, json_target, show_certificate)
    if not cert.certified:
        raise typer.Exit(1)


def show_certificate(result: dict) -> None:
    """Human output of ``certify``: the point, the region, the method and a verdict."""
    p = result["points"][0]
    table = Table(title=f"Theorem 2 certificate: {result['scenario']}", show_header=False)
    fmt = lambda v: "-" if v is None else f"{v:.6g}"  # noqa: E731
    rows = [
        ("k_xi, k_c, k_e", f"{p['gains']['k_xi']}, {p['gains']['k_c']}, {p['gains']['k_e']}"),
        ("w_pc, w_rc, w_pe, w_re", ", ".join(f"{v:g}" for v in p["weights"].values())),
        ("region", result["region"]),
        ("method", p["method"]),
        ("gamma (certified)", fmt(p["gamma"])),
        ("margin lambda_min(P)", fmt(p["margin"])),
        ("gamma_tight (alpha V, fact 4)", f"{fmt(p.get('gamma_tight'))} (alpha = {fmt(p.get('alpha'))})"),
        (
            "gamma_lower: linearisation, nonlinear from rest",
            f"{fmt(p.get('gamma_lower_linear'))}, {fmt(p.get('gamma_lower_nonlinear'))}",
        ),
        ("tightness gamma / gamma_lower", fmt(p.get("tightness"))),
        ("worst gamma found by search", fmt(p["gamma_worst_found"])),
    ]
    for name, value in rows:
        table.add_row(name, str(value))
    out.print(table)
    if p["certified"]:
        channels = channels_text(p, result["loop"] == "planar")
        out.print(f"CERTIFIED: L2 gain <= {p['gamma']:.6g} {channels} over {result['region']}.", markup=False)
    else:
        out.print(f"NOT CERTIFIED: {p['reason']}", markup=False)
    if (integral := p.get("integral")) is not None:  # docs/math.md, facts 20-21
        covered = "; ".join(f"{key.replace('_', ' ')}: {integral[key]}" for key in INTEGRAL_COVERAGE)
        out.print(f"WITH INTEGRAL ACTION (k_i = {integral['k_i']}): {covered}.", markup=False)
    if "implemented" in p:
        out.print(implemented_text(p["implemented"]), markup=False, soft_wrap=True)
    if "envelope" in p:
        show_envelope(p["envelope"])


def inertia_text(e: dict) -> str:
    """The diagonal of the envelope's ``D_M`` (docs/math.md, fact 10), 4 significant figures."""
    return ", ".join(f"{row[i]:.4g}" for i, row in enumerate(e["inertia"]["upper"]))


def show_envelope(e: dict) -> None:
    """Human output of the operating envelope (docs/math.md, facts 7-9)."""
    if e.get("rate") is None:
        out.print(f"Operating envelope: not certified: {e['reason']}", markup=False)
        if (start := e.get("start") or {}).get("until_s") is not None:  # docs/math.md, fact 20.6
            told = f"CERTIFIED: {start['statement']}" if start["inside"] else f"not certified: {start.get('reason')}"
            out.print(f"START (until integral action engages): {told}", markup=False)
        if e.get("friction") is not None:
            out.print(f"ENVELOPE: {e['friction']['statement']}.", markup=False)
        return
    fmt = lambda v, unit="": "-" if v is None else f"{v:.4g}{unit}"  # noqa: E731
    d, b, start = e["disturbance"], e["bounds"], e["start"]
    table = Table(title="Operating envelope (facts 7-9)", show_header=False)
    rows = [
        ("disturbance bounds", f"speed {fmt(d['target_speed'], ' m/s')}, rate {fmt(d['target_rate'], ' rad/s')}, "
                               f"|tau_d| {fmt(d['torque'], ' N m')} (wbar = {fmt(e['wbar'])})"),
        ("decay rate kappa", f"{fmt(e['rate'], ' 1/s')} (gamma' = {fmt(e['gamma_prime'])}, "
                             f"theta_bar = {fmt(e['theta_bar_deg'], ' deg')})"),
        ("inertia (from the URDF, every q)", f"m_lo I <= M(q) <= D_M = diag({inertia_text(e)}) kg m^2 "
                                             f"(lambda_max(B) = {fmt(e['m_hi'])}; fact 10)"),
        ("ultimate V (c_inf)", fmt(e["ultimate_V"])),
        ("ultimate |p_ec|, theta_ec", f"{fmt(b['p_ec'], ' m')}, {fmt(b['theta_ec_deg'], ' deg')}"),
        ("ultimate |p_ee|, theta_ee", f"{fmt(b['p_ee'], ' m')}, {fmt(b['theta_ee_deg'], ' deg')}"),
        ("ultimate |xi|", fmt(b["xi"], " rad/s")),
        ("start V(0) (kinetic part)", f"{fmt(start['V0'])} ({fmt(start.get('kinetic'))}): "
                                      f"{'inside' if start['inside'] else 'NOT inside'} the certified set "
                                      f"(reference {start.get('method', 'constant')})"),
        ("visible, margin to border, min depth", f"{e['visible']}, {fmt(e['image_margin_px'], ' px')}, "
                                                  f"{fmt(e['depth_min'], ' m')}"),
        ("largest target speed with every statement certified (features in view)", fmt(e["max_target_speed"], " m/s")),
        ("largest certified |tau_d|", fmt(e["max_torque"], " N m")),
    ]  # fmt: skip
    for name, value in rows:
        table.add_row(name, value)
    out.print(table)
    out.print(f"ENVELOPE: {e['statement']}. Assumes: {'; '.join(e['assumptions'])}.", markup=False)
    if start.get("method") == "planned":
        told = start.get("statement") or f"not certified: {start.get('reason')}"
        out.print(f"START (fact 16b): {told}. Assumes: {'; '.join(start['assumptions'])}.", markup=False)


PROGRESS_EVERY = 5.0
"""Seconds between progress lines when standard error is not a terminal (CI logs, nohup)."""


class ProgressLines:
    """Progress for a standard error that is not a terminal: one plain line every
    :data:`PROGRESS_EVERY` seconds (and at the end), ``label: done / total unit (percent), rate``."""

    def __init__(self, label: str, total: float, unit: str) -> None:
        self.label, self.total, self.unit, self.every = label, total, unit, PROGRESS_EVERY
        self.start = self.last = time.perf_counter()

    def __call__(self, done: float) -> None:
        now = time.perf_counter()
        if now - self.last < self.every and done < self.total:
            return
        self.last = now
        elapsed = max(now - self.start, 1e-9)
        err.print(f"{self.label}: {done:,.4g} / {self.total:,.4g} {self.unit} ({100 * done / self.total:.0f}%), "
                  f"{done / elapsed:,.3g} {self.unit} a second, {elapsed:.0f} s elapsed", markup=False,
                  soft_wrap=True)  # fmt: skip


def sweep(spec, scenario: Path, point: GainPoint, axes, directory: Path, json_target, how: tuple, start: float,
          envelope=None):
    """Run a grid sweep with progress (a bar on a terminal, lines otherwise); write
    certificate.json (and points.csv with ``csv``); exit 0/1.

    ``how`` is ``(workers, scheduler, resume, batch_size, csv)``.
    """
    workers, scheduler, resume, batch_size, csv = how
    try:
        grid = GridSpec.around(point, spec.reference.se3(), axes, spec.certify.gamma, envelope)
    except ValueError as exc:
        raise fail(str(exc)) from exc
    if resume and not (directory / "sweep.json").exists():
        raise fail(f"--resume: no sweep to resume in {directory}")
    sha = provenance(scenario, [])["scenario_sha256"]
    columns = (
        TextColumn("[bold]certify[/] grid"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    try:
        with (
            resumable(f"dvfc certify {scenario} --out {directory} --resume"),
            Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar,
        ):
            task = bar.add_task("grid", total=grid.size, rate="")
            lines = None if err.is_terminal else ProgressLines("certify grid", grid.size, "points")

            def advance(done: int) -> None:
                elapsed = max(time.perf_counter() - start, 1e-9)
                bar.update(task, completed=done, rate=f"{done / elapsed:,.0f} points/s")
                if lines is not None:
                    lines(done)

            state = run_sweep(grid, directory, batch_size=batch_size, workers=workers, scheduler=scheduler,
                              resume=resume, progress=advance, scenario_sha256=sha)  # fmt: skip
            files = {"points_dataset": str(directory / POINTS)}
            if csv:
                export_csv(directory, directory / "points.csv")
                files["points_csv"] = str(directory / "points.csv")
    except ValueError as exc:
        raise fail(str(exc)) from exc
    result = grid_result(spec, grid, state, files, command_provenance(scenario), time.perf_counter() - start)
    emit(result, directory / "certificate.json", json_target, show_grid)
    if state.certified < grid.size:
        raise typer.Exit(1)


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
    for name, value in (("--p-fail", p_fail), ("--confidence", confidence)):
        if for_campaign and not 0 < value < 1:
            raise fail(f"{name}: {value:g} is not in (0, 1)")
    if what and not for_campaign:
        raise fail("--what-would-pass: searches the hardware for the synthesis --for-campaign; give --for-campaign")
    case = load_case(scenario)
    check_json_target(json_target)
    target = out_file or Path("out") / f"{case.name}-synthesized.toml"
    if for_campaign:
        with library_errors({}, target.parent):
            refuse_unless_synthesisable(case)
        campaign_design(case, scenario, target, json_target, (p_fail, confidence, workers), what, resume)
        return
    check_out_dir(target.parent)
    with (
        resumable(f"dvfc synthesize {scenario} --out {target} --resume"),
        err.status("synthesising the gains") as status,
        library_errors({"resume": "--resume"}, target.parent),
    ):
        record = synthesize_scenario(case, target, command_provenance(scenario), resume=resume,
                                     progress=announcer(status))  # fmt: skip
    emit(record, None, json_target, show_synthesis)
    if record["scenario_file"] is None or ("max_target_speed" in record and record["max_target_speed"] is None):
        raise typer.Exit(1)


def campaign_design(case: Case, scenario: Path, target: Path, json_target: str | None, how: tuple[float, float, int],
                    what: bool, resume: bool) -> None:  # fmt: skip
    """``synthesize --for-campaign`` (:mod:`dvfc.analysis.cell`), ``how = (p_fail, confidence,
    workers)``; with ``what``, the synthesis is the first check of ``--what-would-pass``
    (:mod:`dvfc.analysis.hardware`): exit 0 written, 1 refused, 2 bad input."""
    p_fail, confidence, workers = how
    bound = campaign_of(case, "--for-campaign")
    start = time.perf_counter()
    prepare_out_dir(target.parent)
    log = target.with_name(target.name + ".what_would_pass.jsonl")
    found = None
    if what:
        again = (f"dvfc synthesize {scenario} --for-campaign --what-would-pass --p-fail {p_fail:g} --confidence "
                 f"{confidence:g} --out {target} --resume")  # fmt: skip
        found = hardware_search(case, log, resume, how, again)
        synthesis = found["today"]["synthesis"]  # the synthesis at the scenario's own hardware
        design = CellDesign.of(synthesis["design"]) if synthesis["holds"] else None
    else:
        with err.status("searching gains that hold on the campaign") as status:
            search = CellSearch(workers=workers)
            result = synthesize_for_campaign(case, p_fail=p_fail, confidence=confidence, search=search,
                                             progress=announcer(status))  # fmt: skip
        synthesis, design = cell_record(result), result.design if result.holds else None
    record = {"scenario": case.name, **synthesis, "scenario_file": None}
    if design is not None:
        text = design_text(Path(scenario).read_text(), case, design, bound, name=f"{case.name}-synthesized",
                           source=Path(scenario), target=target)  # fmt: skip
        atomic_write(target, lambda h: h.write(text.encode()))
        record["scenario_file"] = str(target)
    if found is not None:
        record["what_would_pass"] = found
    record |= {"seconds": time.perf_counter() - start, "provenance": command_provenance(scenario)}
    emit(record, None, json_target, show_campaign_design)
    if design is None:
        if found is None:
            hint(f"dvfc synthesize {scenario} --for-campaign --what-would-pass")
        raise typer.Exit(1)


def campaign_of(case: Case, option: str) -> TrackingBound:
    """Refuse ``option`` (exit 2, one line) unless ``case``'s campaign can run (a ``[dispersion]``, an
    ``[implementation]``, the paper's loop); the campaign's criterion."""
    if not case.scenario.dispersion:
        raise fail(f"dispersion: {option} needs a [dispersion] section")
    if case.planar or case.settings.implementation is None:
        raise fail(f"implementation: {option} designs the loop as implemented; add an [implementation]")
    try:
        bound = tracking_bound(case)
        CampaignSpec.of(case, bound)
    except ScenarioError as exc:
        raise fail(str(exc)) from exc
    return bound


def announcer(status) -> Callable[[str], None]:
    """Progress text to a rich ``status`` line, and also a line of its own when standard error is not a
    terminal (CI logs, nohup)."""

    def say(text: str) -> None:
        status.update(text)
        if not err.is_terminal:
            err.print(text, markup=False, soft_wrap=True)

    return say


def hardware_search(case: Case, log: Path, resume: bool, how: tuple[float, float, int], again: str) -> dict:
    """``--what-would-pass`` (:func:`dvfc.analysis.hardware.what_would_pass`) with the full budget of
    ``how = (p_fail, confidence, workers)``, its evaluations in ``log``; progress on standard error;
    Ctrl-C: exit 130 with the command ``again`` that resumes."""
    p_fail, confidence, workers = how
    if resume and not log.exists():
        raise fail(f"--resume: no --what-would-pass search to resume ({log} not found)")
    with resumable(again), err.status("what would pass: the synthesis at the scenario's hardware") as status:
        return what_would_pass(case, p_fail=p_fail, confidence=confidence, search=CellSearch(workers=workers),
                               log=log, resume=resume, progress=announcer(status))  # fmt: skip


def hint(command: str) -> None:
    """The line pointing at ``--what-would-pass`` when nothing passes (standard error)."""
    err.print(f"what would pass: {command} searches the least change of the control rate, camera rate or latency "
              "at which the synthesis for the campaign succeeds", markup=False, soft_wrap=True)  # fmt: skip


def show_what_would_pass(found: dict) -> None:
    """Human output of ``--what-would-pass``: per parameter today's value, the value needed, the bracket
    the bisection ended on and the full-size confirmation; how it was measured."""
    today = found["today"]
    if today["holds"]:
        out.print("what would pass: nothing to change (the synthesis passes at the scenario's hardware)", markup=False)
        return
    table = Table(title=f"What would pass: {found['scenario']} (measured)")
    columns = ("parameter", "today", "needed", "bracket (full size)", "confirmation (full size)", "why it fails below")
    for col in columns:
        table.add_column(col)
    for name, p in found["parameters"].items():
        value = lambda v, u=p["unit"]: value_text(v, u)  # noqa: E731
        if p["needed"] is None:
            needed, bracket = "none in range", f"fails at {value(p['fails_at'])}"
        else:
            needed = value(p["needed"])
            bracket = f"fails at {value(p['fails_at'])}, passes at {value(p['passes_at'])}"
        c = p["confirmation"]
        confirmation = "-" if c is None else (f"{c['failures']} of {c['runs']} fail, P(fail) <= "
                                              f"{c['p_fail_upper']:.3g} at {c['confidence']:.0%}")  # fmt: skip
        table.add_row(name, value(p["today"]), needed, bracket, confirmation, p["fails_because"] or "")
    out.print(table)
    out.print(f"as it is: {today['limits']}", markup=False, soft_wrap=True)
    for key in ("method", "held", "assumption"):
        out.print(f"{key}: {found[key]}", markup=False, soft_wrap=True)
    out.print(f"{found['evaluations']} syntheses ({found['made']} made now, {found['evaluations'] - found['made']} "
              f"from the log), {found['seconds']:.0f} s", markup=False, soft_wrap=True)  # fmt: skip


def show_campaign_design(record: dict) -> None:
    """Human output of ``synthesize --for-campaign``: the design, its checks, the confirmation, the file."""
    if record["scenario_file"] is None:
        out.print(f"NOT SYNTHESIZED: {record['limits']}", markup=False, soft_wrap=True)
        if record.get("what_would_pass") is not None:
            show_what_would_pass(record["what_would_pass"])
        return
    d, c, s, f = record["design"], record["checks"], record["search"], record["confirmation"]
    out.print(
        f"gains: k_xi = {d['k_xi']}\n       k_c = {d['k_c']}\n       k_e = {d['k_e']}\n"
        f"       k_i_factor = {d['k_i_factor']:g} (K_I = k_i_factor K_xi)\n"
        f"inside the gain windows; certified gamma = {c['gamma']:.6g}; loop as implemented with the integral state "
        f"(fact 14, local): rho = {c['rho']:.6g} <= {c['rho_max']:g}, Lyapunov margin {c['lyapunov_margin']:.3g}\n"
        f"search: {s['method']}, {s['candidates']} candidates, surrogate {record['surrogate']:.4g} ({s['surrogate']})\n"
        f"confirmation: {f['statement']}; largest tracking angle {f['max_tracking_angle_deg']:.3g} deg "
        f"(criterion {record['tracking_bound']['angle_deg']:.4g})\n"
        f"scenario written: {record['scenario_file']} ({record['seconds']:.0f} s)",
        markup=False,
        soft_wrap=True,
    )
    if record.get("what_would_pass") is not None:
        show_what_would_pass(record["what_would_pass"])


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
    case = load_case(scenario)
    spec, settings = case.scenario, case.settings
    if settings.implementation is None:
        raise fail("implementation: margins are of the loop as implemented; add an [implementation] section")
    require_six(case, "margins")
    check_json_target(json_target)
    if what:
        campaign_of(case, "--what-would-pass")
    directory = prepare_out_dir(out_dir or Path("out") / f"{spec.name}-margins")
    log = directory / "what_would_pass.jsonl"
    logged = [log_path(directory, n) for n in PARAMETERS] + ([log] if what else [])
    if resume and not any(p.exists() for p in logged):
        raise fail(f"--resume: no margin search to resume in {directory}")
    again = f"dvfc margins {scenario} --out {directory} --resume --what-would-pass"
    columns = (TextColumn("[bold]margins[/]"), BarColumn(), MofNCompleteColumn(), TextColumn("runs"),
               TimeElapsedColumn())  # fmt: skip
    try:
        with (
            resumable(f"dvfc margins {scenario} --out {directory} --resume"),
            Progress(*columns, console=err, transient=True) as bar,
        ):
            task = bar.add_task("margins", total=planned_runs())
            shown = [-1]

            def poll() -> None:
                done = runs_done(directory)
                bar.update(task, completed=done)
                if not err.is_terminal and done != shown[0]:  # CI logs, nohup: a plain line a run
                    shown[0] = done
                    err.print(f"margins: {done} of at most {planned_runs()} runs", markup=False)

            result = margins(
                case,
                directory,
                map_tasks=lambda f, args: run_tasks(f, args, workers, scheduler, poll),
                resume=resume,
            )
    except MarginError as exc:
        err.print(f"no margins: {exc}", markup=False, soft_wrap=True)
        result = {"scenario": spec.name, "margins": None, "no_margins": str(exc)}
    if what:
        result["what_would_pass"] = hardware_search(case, log, resume and log.exists(), (P_FAIL, CONFIDENCE, workers),
                                                    again)  # fmt: skip
    result["provenance"] = command_provenance(scenario)
    if result["margins"] is None:
        if what:
            emit(result, directory / "margins.json", json_target, lambda r: show_what_would_pass(r["what_would_pass"]))
        elif spec.dispersion:
            hint(again.replace(" --resume", ""))
        raise typer.Exit(1)
    emit(result, directory / "margins.json", json_target, show_margins)


def show_margins(result: dict) -> None:
    """Human output of ``margins``: each parameter's breaking point, measured, the horizon its last
    holding run was judged on, and the margin against fact 14's linear one."""
    table = Table(title=f"Margins of the loop as implemented: {result['scenario']} (measured)")
    for col in ("parameter", "margin", "holds at", "breaks at", "range", "horizon, growth", "fact 14", "note"):
        table.add_column(col)
    fmt = lambda v: "-" if v is None else f"{v:.4g}"  # noqa: E731
    for name, m in result["margins"].items():
        value = f"{fmt(m['value'])} {m['unit']}"
        if m["value"] is None and m["holds_at"] is not None:
            value = f"holds throughout (to {fmt(m['holds_at'])} {m['unit']})"
        span = "-" if m.get("range") is None else f"{fmt(m['range'][0])} .. {fmt(m['range'][1])}"
        horizon = horizon_text(m.get("holds_run"))
        note = m.get("breaks_because") or m.get("reason") or ""
        table.add_row(name, value, fmt(m["holds_at"]), fmt(m["breaks_at"]), span, horizon, linear_text(m), note)
    out.print(table)
    for name, m in result["margins"].items():
        if m.get("linear", {}).get("clipped"):
            out.print(f"{name}: {m['linear']['statement']}", markup=False, soft_wrap=True)
    out.print(f"criterion: {result['criterion']}", markup=False, soft_wrap=True)
    own = result["scenario_run"]
    out.print(f"the scenario's own run ({horizon_text(own)}): {own['detail']}", markup=False, soft_wrap=True)
    out.print(linear_margin_text(result), markup=False, soft_wrap=True)
    if result.get("what_would_pass") is not None:
        show_what_would_pass(result["what_would_pass"])


def linear_text(margin: dict) -> str:
    """A measured margin against fact 14's linear one, in a few words (``linear.statement`` in full)."""
    linear = margin.get("linear")
    if linear is None:
        return "-"
    if not linear["checked"]:
        return "not checked"
    if linear["linear_margin"] is None:
        return "stable over its range"
    return f"{'clipped to' if linear['clipped'] else 'within'} {linear['linear_margin']:.4g} {margin['unit']}"


def horizon_text(run: dict | None) -> str:
    """A run's horizon and growth check in words (``-`` for none)."""
    if run is None:
        return "-"
    growth = run["growth"]
    if growth is None:
        return f"{run['horizon']:.4g} s"
    return f"{run['horizon']:.4g} s, envelope x{growth['ratio']:.3g} ({'growing' if growth['growing'] else 'steady'})"


@app.command("verify")
def verify_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: OutOpt = None,
    json_target: JsonOpt = None,
) -> None:
    """Check every claim of the paper (Lemmas 1-2, Theorems 1-2, the passivity remarks, the
    Lyapunov derivative) on simulated trajectories; measure the image loop's gap."""
    case = load_case(scenario)
    check_json_target(json_target)
    warn_fewer_than_six(case)
    warn_windows(case)
    directory = prepare_out_dir(out_dir) if out_dir is not None else None
    with err.status("simulating and checking the claims"):
        result, claims = verification_result(case, command_provenance(scenario))
    failed = result["summary"]["failed"] + result["summary"]["inconclusive"]
    emit(result, directory / "verification.json" if directory else None, json_target, lambda r: show_claims(r, claims))
    if failed:
        raise typer.Exit(1)


def show_grid(result: dict) -> None:
    """Human output of a grid sweep: the named points (each labelled), the region, the count."""
    table = Table(title=f"Theorem 2 over the grid: {result['scenario']}")
    for col in ("point", "gamma", "k_xi", "k_c", "k_e", "w_pc, w_rc, w_pe, w_re", "certified"):
        table.add_column(Text(col))
    for p in result["points"]:
        g = p["gains"]
        gamma = "-" if p["gamma"] is None else f"{p['gamma']:.6g}"
        weights = ", ".join(f"{v:g}" for v in p["weights"].values())
        short = lambda v: Text(", ".join(f"{x:.3g}" for x in v))  # noqa: E731
        table.add_row(Text(p["label"]), gamma, short(g["k_xi"]), short(g["k_c"]), short(g["k_e"]), weights,
                      str(p["certified"]))  # fmt: skip
    out.print(table)
    out.print(
        f"region: {result['region']}; method: exact closed form (fact 3), blockwise-minimum K_e (fact 5)",
        markup=False,
    )
    summary_ = result["summary"]
    stored = result.get("points_csv") or result["points_dataset"]
    out.print(f"{summary_['certified']} of {summary_['points']} points certified; results: {stored}", markup=False)


def show_synthesis(record: dict) -> None:
    """Human output of ``synthesize``: the gains, the certified gamma, the file written, the run
    against the arm's limits (and the limits search: what was searched, what it found)."""
    p = record["point"]
    if p is None:
        out.print(f"NOT SYNTHESIZED: {record['status']}", markup=False, soft_wrap=True)
        _show_limit_search(record)
        return
    g = p["gains"]
    out.print(
        f"gains: k_xi = {g['k_xi']}\n       k_c = {g['k_c']}\n       k_e = {g['k_e']}\n"
        f"weights: {p['weights']}\ncertified gamma = {p['gamma']:.6g} over {record['region']}\n"
        f"scenario written: {record['scenario_file'] or 'none, ' + record['status']}",
        markup=False,
    )
    if "max_target_speed" in record:
        speed = record["max_target_speed"]
        line = (f"NOT CERTIFIED: {record['status']}" if speed is None
                else f"certified max target speed = {speed:.6g} m/s ({p['envelope']['statement']})")  # fmt: skip
        out.print(line, markup=False, soft_wrap=True)
    limits = record.get("limits")
    if limits is not None:
        out.print(f"run of the design ({limits['status']}): peak |tau| / effort limit "
                  f"{_worst(limits['torque_commanded_ratio'])}, peak |qd| / velocity limit "
                  f"{_worst(limits['speed_ratio'])}", markup=False, soft_wrap=True)  # fmt: skip
    if record.get("implemented") is not None:
        out.print(implemented_text(record["implemented"]), markup=False, soft_wrap=True)
    if (start := record.get("start")) is not None and start["lost"]:
        out.print(f"START NOT CERTIFIED: {start['statement']}", markup=False, soft_wrap=True)
    _show_limit_search(record)


def _show_limit_search(record: dict) -> None:
    """The limits search of ``synthesize`` in words (nothing without ``respect_limits``)."""
    search = record.get("limit_search")
    if search is None:
        return
    fmt = lambda v: "-" if v is None else f"{v:.3g}"  # noqa: E731
    top = search["trials"][0]
    out.print(
        f"limits search ({search['runs']} runs, {search['syntheses']} syntheses): {search['family']}, alpha in "
        f"[{search['bracket'][0]:.4g}, 1]; criterion: {search['criterion']}.\n{search['statement']}.\n"
        f"unconstrained optimum (alpha = 1): certified gamma {fmt(top['gamma'])}, peak |tau| / effort limit "
        f"{fmt(top['torque_commanded_ratio'])}, peak |qd| / velocity limit {fmt(top['speed_ratio'])} "
        f"({top['status']}{'; ' + top['sampled'] if top.get('sampled') else ''})",
        markup=False,
        soft_wrap=True,
    )


def show_claims(result: dict, claims: list) -> None:
    """Human output of ``verify``: a table of the claims (each with its place in the paper, its
    status, value and bound) narrow enough for 80 columns, each FAIL or INCONCLUSIVE reason in
    full below it, then a verdict."""
    table = Table(title=f"Claims of the paper on {result['scenario']}")
    table.add_column("claim", ratio=1, overflow="fold")
    table.add_column("status", no_wrap=True, min_width=len("INCONCLUSIVE"))
    table.add_column("value", no_wrap=True)
    table.add_column("bound", max_width=24, overflow="fold")
    colours = {"PASS": "green", "FAIL": "red", "INCONCLUSIVE": "yellow", "MEASURED": "default"}
    for c in claims:
        table.add_row(Text(f"{c.name} ({c.reference})"), Text(c.status, style=colours[c.status]), f"{c.value:.3e}",
                      Text(c.bound))  # fmt: skip
    out.print(table)
    for c in claims:
        if c.status in ("FAIL", "INCONCLUSIVE"):
            out.print(Text(f"{c.status} {c.name}: {c.detail}", style=colours[c.status]))
    summary_ = result["summary"]
    problems = [f"{summary_['failed']} claim(s) FAIL"] if summary_["failed"] else []
    problems += [f"{summary_['inconclusive']} check(s) INCONCLUSIVE"] if summary_["inconclusive"] else []
    verdict = "; ".join(problems) or "every claim holds"
    out.print(f"{verdict} ({summary_['claims']} checked)", markup=False)


def campaign_replay(case: Case, run: int | None, values: Path | None, seed: int) -> CampaignSpec:
    """The campaign of ``case`` for a replay (exit 2 on bad input)."""
    if run is not None and values is not None:
        raise fail("--campaign-run and --campaign-values: give one")
    try:
        return CampaignSpec.of(case, tracking_bound(case), seed)
    except ScenarioError as exc:
        raise fail(str(exc)) from exc


def replayed_values(spec: CampaignSpec, path: Path | None) -> dict[str, np.ndarray] | None:
    """The values of a worst-case file (``--campaign-values``), or None."""
    if path is None:
        return None
    try:
        data = json.loads(path.read_text())["values"]
        values = {k: np.asarray(v, dtype=float) for k, v in data.items()}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise fail(f"--campaign-values: cannot read {path}: {exc}") from exc
    if set(values) != set(spec.dispersion.keys):
        raise fail(f"--campaign-values: {path} has other quantities than the scenario's [dispersion]")
    return values


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
    case = load_case(scenario)
    check_json_target(json_target)
    directory = out_dir or Path("out") / f"{case.name}-campaign"
    again = f"dvfc campaign {scenario} --runs {runs} --seed {seed} --out {directory} --resume"
    searched = f"{again} --p {p_fail:g} --confidence {confidence:g} --what-would-pass"
    check_out_dir(directory)  # the campaign creates it once its arguments are checked
    with resumable(again), run_bar("campaign", runs, "runs") as advance, library_errors(CAMPAIGN_FLAGS, directory):
        result = run_campaign_job(case, directory, runs, seed=seed, confidence=confidence,
                                  p_fail=p_fail, quantile=quantile, search=search, batch_size=batch_size,
                                  workers=workers, scheduler=scheduler, resume=resume, progress=advance)  # fmt: skip
    result["provenance"] = command_provenance(scenario)
    if what:  # the search, before the JSON is written (one document); a campaign without failures: none
        how = (p_fail, confidence, workers)
        log = directory / "what_would_pass.jsonl"
        result["what_would_pass"] = hardware_search(case, log, resume and log.exists(), how, searched) if (
            result["failures"]) else None  # fmt: skip
    emit(result, directory / "summary.json", json_target, show_campaign)
    if result["failures"]:
        if not what:
            hint(searched)
        raise typer.Exit(1)


CAMPAIGN_FLAGS = {"runs": "--runs", "confidence": "--confidence", "p_fail": "--p", "quantile": "--quantile",
                  "resume": "--resume"}
"""The campaign's library arguments (:func:`dvfc.analysis.campaign.campaign`) as the command line names them."""


@contextmanager
def library_errors(flags: dict[str, str], out: Path) -> Iterator[None]:
    """Bad input raised by the library (``"argument: why"``): one line, exit 2, the argument named by
    its option (``flags``), a scenario field as it is, the output folder ``out`` not writable as ``--out``."""
    try:
        yield
    except ScenarioError as exc:
        raise fail(str(exc)) from exc
    except PermissionError as exc:
        raise fail(f"--out: cannot write in {out}: {exc.strerror}") from exc
    except ValueError as exc:
        name, _, why = str(exc).partition(": ")
        raise fail(f"{flags[name]}: {why}" if name in flags else str(exc)) from exc


@contextmanager
def run_bar(name: str, total: int, unit: str) -> Iterator[Callable[[int], None]]:
    """A progress bar of ``total`` ``unit`` on standard error (plain lines when it is not a terminal);
    yields the function that reports how many are done."""
    columns = (TextColumn(f"[bold]{name}[/]"), BarColumn(), MofNCompleteColumn(), TextColumn(unit),
               TimeElapsedColumn(), TimeRemainingColumn())  # fmt: skip
    with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task(unit, total=total)
        lines = None if err.is_terminal else ProgressLines(name, total, unit)

        def advance(done: int) -> None:
            bar.update(task, completed=done)
            if lines is not None:
                lines(done)

        yield advance


def tolerance_text(tolerance: dict) -> str:
    """The tolerance bound's statement with its values (the order statistic of its rank)."""
    if tolerance["rank"] is None:
        return tolerance["statement"]
    return (f"{tolerance['statement']}: position <= {tolerance['tracking_position']:.4g} m, angle <= "
            f"{tolerance['tracking_angle_deg']:.4g} deg, tracking ratio <= {tolerance['tracking_ratio']:.4g} "
            f"({tolerance['note']})")  # fmt: skip


def show_campaign(result: dict) -> None:
    """Human output of ``campaign``: the statement, the tolerance bound, the strongest drivers, the worst runs."""
    out.print(result["statement"], markup=False, soft_wrap=True)
    out.print(f"criterion: {result['criterion']}", markup=False, soft_wrap=True)
    out.print(result["zero_failure"]["statement"], markup=False, soft_wrap=True)
    out.print(f"tolerance: {tolerance_text(result['tolerance'])}", markup=False, soft_wrap=True)
    table = Table(title="Drivers of the closeness to failing (PAWN, Spearman; measured)")
    for name in ("quantity", "entry", "PAWN", "above floor", "spearman", "failure rate per quartile"):
        table.add_column(name)
    for e in result["sensitivity"]:
        rates = " ".join("-" if r is None else f"{r:.2f}" for r in e["failure_rate"])
        above = {True: "yes", False: "no", None: "-"}[e["above_floor"]]
        table.add_row(e["quantity"], e["column"], _number(e["pawn"]), above,
                      _number(e["spearman"]), rates)  # fmt: skip
    out.print(table)
    out.print(f"floor: {result['sensitivity_floor']['note']}", markup=False, soft_wrap=True)
    for w in result["worst"]:
        out.print(f"run {w['run']}: {'holds' if w['holds'] else 'fails'} ({w['reason']}); replay: {w['replay']}",
                  markup=False, soft_wrap=True)  # fmt: skip
    if (found := result.get("worst_case_search")) is not None:
        out.print(f"worst case found ({found['statement']}): closeness to failure {found['worst_closeness']:.4g}; "
                  f"replay: {found['replay']}", markup=False, soft_wrap=True)  # fmt: skip
    if result.get("what_would_pass") is not None:
        show_what_would_pass(result["what_would_pass"])
    elif result["failures"] == 0 and "what_would_pass" in result:
        out.print("what would pass: no run fails, nothing to change", markup=False)


@app.command("export")
def export_command(
    scenario: ScenarioArg = DEFAULT_SCENARIO,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Folder of the exported C code.")] = None,
    json_target: JsonOpt = None,
    check: Annotated[bool, typer.Option("--check", help="Compile, replay a simulated run, compare.")] = False,
) -> None:
    """Export the controller as C (dvfc_controller.h/.c over CasADi's generated step)."""
    case = load_case(scenario)
    check_json_target(json_target)
    try:
        exportable(case)
    except ExportError as exc:
        raise fail(str(exc)) from exc
    directory = prepare_out_dir(out_dir or Path("out") / case.name / "controller")
    with err.status("exporting" + (", compiling and checking" if check else "")):
        try:
            done = export_controller(case, directory, checked=check)
        except ExportError as exc:
            raise fail(str(exc)) from exc
    emit(export_record(done), None, json_target, show_export)
    if done.check is not None and not done.check.passed:
        err.print("check failed: the compiled step differs from the Python step", markup=False, soft_wrap=True)
        raise typer.Exit(1)


def export_record(done: ExportResult) -> dict:
    """The JSON of ``dvfc export`` (docs/cli.md)."""
    e = done.export
    record = {"files": [str(f) for f in e.files], "api": str(e.api), "state_size": e.state_size,
              "sha256": program_digest(e), "check": None, "timing": None}  # fmt: skip
    if done.check is not None:
        record["files"].append(str(done.check.inputs))
        record["check"] = done.check.as_dict()
    if done.timing is not None:
        record["timing"] = {**done.timing.as_dict(), "thread_cpu": done.cpu_timing.as_dict()}
    return record


def show_export(record: dict) -> None:
    """Human output of ``export``."""
    out.print(f"exported: {record['api']} ({len(record['files'])} files, state of {record['state_size']} doubles); "
              f"program SHA-256 {record['sha256']}", markup=False, soft_wrap=True)  # fmt: skip
    if (c := record["check"]) is not None:
        out.print(f"check over {c['samples']} samples: largest torque difference {c['max_abs_torque_difference']:.3g} "
                  f"N m, closed loop {c['closed_loop_max_state_difference']:.3g}", markup=False, soft_wrap=True)
    if (t := record["timing"]) is not None:
        c = t["thread_cpu"]
        out.print(f"step time (measured, {t['calls']} calls with an image): median {t['median_us']:.3g} us, "
                  f"p99.9 {t['p999_us']:.3g} us, max {t['max_us']:.3g} us wall; CPU time p99.9 {c['p999_us']:.3g} us, "
                  f"max {c['max_us']:.3g} us", markup=False, soft_wrap=True)
