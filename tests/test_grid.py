"""Gain-grid sweeps: each grid point equals the single-point certificate; a sweep killed
with SIGKILL and resumed, a multi-process sweep and a Dask LocalCluster sweep all give
the same file as an uninterrupted sweep."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import tomli_w
from typer.testing import CliRunner

import dvfc.analysis.cli as cli_module
import dvfc.analysis.console as console_module
import dvfc.analysis.grid as grid
import dvfc.analysis.jobs as jobs_module
from dvfc.analysis.certify import GainPoint, certify
from dvfc.analysis.cli import app
from dvfc.analysis.grid import BYTES_PER_POINT, POINTS, GridSpec, axis_value, gain_map, read_points, run_sweep
from dvfc.models.lie import SE3
from dvfc.models.loop import PlantWeights, Weights

from helpers import scenario_dict

REFERENCE = SE3.from_xyz_rpy([0.0, 0.0, 0.35], [0.0, 0.0, 0.0])
runner = CliRunner()


def small_grid(gamma_bound=None) -> GridSpec:
    axes = (
        ("k_c", np.geomspace(0.5, 10, 6)),
        ("k_e_r", np.array([1.0, 5.0, 20.0])),
        ("k_e_p", np.array([2.0, 10.0])),
        ("w_pc", np.array([1.0, 4.0])),
    )
    design = GainPoint(np.full(6, 20.0), np.full(6, 3.0), np.full(6, 10.0), Weights(4, 1, 4, 1))
    return GridSpec.around(design, REFERENCE, axes, gamma_bound)


def test_grid_points_equal_single_point_certificates(tmp_path):
    spec = small_grid()
    run_sweep(spec, tmp_path, batch_size=7)
    rows = read_points(tmp_path).to_pylist()
    assert [row["index"] for row in rows] == list(range(spec.size))
    for row in rows:
        i = row["index"]
        d = spec.designs(i, i + 1)
        cert = certify(
            GainPoint(d["k_xi"][0], d["k_c"][0], d["k_e"][0], Weights(*d["w"][0])), REFERENCE, with_sdp=False
        )
        assert row["certified"] == cert.certified
        if cert.certified:
            assert row["gamma"] == pytest.approx(cert.gamma, rel=1e-9)


def test_local_processes_equal_in_process(tmp_path):
    spec = small_grid()
    for name, workers in (("a", 1), ("b", 2)):
        (tmp_path / name).mkdir()
        run_sweep(spec, tmp_path / name, batch_size=5, workers=workers)
    assert read_points(tmp_path / "a").equals(read_points(tmp_path / "b"))


@pytest.mark.slow
def test_dask_local_cluster_equals_local_sweep(tmp_path):
    spec = small_grid()
    for name, options in (("local", {}), ("dask", {"scheduler": "local", "workers": 2})):
        (tmp_path / name).mkdir()
        run_sweep(spec, tmp_path / name, batch_size=10, **options)
    assert read_points(tmp_path / "local").equals(read_points(tmp_path / "dask"))


def write_grid_scenario(tmp_path: Path, gamma: float | None = None, k_c_num: int = 400) -> Path:
    def edit(data):
        data["grid"] = {
            "k_c": {"start": 0.5, "stop": 10.0, "num": k_c_num, "spacing": "log"},
            "k_e_r": {"start": 1.0, "stop": 20.0, "num": 50},
            "w_pc": [1.0, 2.0, 4.0, 8.0],
        }
        if gamma is not None:
            data["certify"] = {"gamma": gamma}

    path = tmp_path / "grid.toml"
    path.write_text(tomli_w.dumps(scenario_dict(edit)))
    return path


def cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "dvfc.analysis", "certify", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.mark.slow
def test_sigkill_and_resume_equals_uninterrupted(tmp_path):
    """Real processes killed with SIGKILL at three moments of the sweep, each time resumed:
    the final dataset equals an uninterrupted sweep's, point for point."""
    scenario = write_grid_scenario(tmp_path)
    reference = tmp_path / "reference"
    assert cli(str(scenario), "--out", str(reference), "--batch-size", "500").wait() in (0, 1)
    out = tmp_path / "killed"
    state = out / "sweep.json"
    total = 400 * 50 * 4
    kills = 0
    for fraction in (0.2, 0.5, 0.8):
        args = [str(scenario), "--out", str(out), "--batch-size", "500"] + (["--resume"] if state.exists() else [])
        proc = cli(*args)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if state.exists():
                try:
                    done = json.loads(state.read_text())["done"]
                except (json.JSONDecodeError, KeyError):
                    done = 0
                if done >= fraction * total:
                    proc.send_signal(signal.SIGKILL)
                    kills += 1
                    break
            time.sleep(0.005)
        proc.wait()
    assert kills >= 1
    assert cli(str(scenario), "--out", str(out), "--batch-size", "500", "--resume").wait() in (0, 1)
    assert read_points(out).equals(read_points(reference))
    assert json.loads((out / "certificate.json").read_text())["summary"]["points"] == total


@pytest.mark.slow
def test_resume_of_another_grid_is_refused(tmp_path):
    scenario = write_grid_scenario(tmp_path)
    out = tmp_path / "out"
    assert cli(str(scenario), "--out", str(out)).wait() in (0, 1)
    other = tmp_path / "other.toml"
    other.write_text(scenario.read_text().replace("num = 50", "num = 49"))
    proc = cli(str(other), "--out", str(out), "--resume")
    assert proc.wait() == 2 and "another scenario or grid" in proc.stderr.read()


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_and_says_how_to_resume(tmp_path):
    """SIGINT mid-sweep: exit status 130, one line naming --resume, and the resumed sweep
    equals an uninterrupted one."""
    scenario = write_grid_scenario(tmp_path)
    out = tmp_path / "interrupted"
    proc = cli(str(scenario), "--out", str(out), "--batch-size", "200")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        state = out / "sweep.json"
        if state.exists() and json.loads(state.read_text() or "{}").get("done", 0) > 0:
            proc.send_signal(signal.SIGINT)
            break
        time.sleep(0.005)
    code, stderr = proc.wait(), proc.stderr.read()
    assert code == 130, stderr
    assert "--resume" in stderr
    assert cli(str(scenario), "--out", str(out), "--resume").wait() in (0, 1)
    reference = tmp_path / "reference"
    assert cli(str(scenario), "--out", str(reference)).wait() in (0, 1)
    assert read_points(out).equals(read_points(reference))


DESIGN = GainPoint(np.full(6, 20.0), np.full(6, 3.0), np.full(6, 10.0), Weights(4, 1, 4, 1))


def test_gain_map_cell_is_the_single_point_certificate():
    """Every cell of the map is the single-point certificate of its gains (the other gains
    at the design), and the axes run x = first axis along the columns."""
    k_c, k_xi = np.array([0.5, 3.0, 8.0]), np.array([5.0, 20.0])
    m = gain_map(DESIGN, REFERENCE, [("k_c", k_c), ("k_xi", k_xi)])
    assert m.gamma.shape == (2, 3) and m.x_axis == "k_c" and m.y_axis == "k_xi"
    for row, kx in enumerate(k_xi):
        for col, kc in enumerate(k_c):
            single = certify(GainPoint(np.full(6, kx), np.full(6, kc), DESIGN.k_e, DESIGN.weights), REFERENCE,
                             with_sdp=False)  # fmt: skip
            assert m.certified[row, col] == single.certified
            if single.certified:
                assert m.gamma[row, col] == pytest.approx(single.gamma, rel=1e-12)


def test_weighted_grid_cell_is_the_weighted_single_point_certificate():
    """With generalized-plant weights (docs/math.md, fact 17) every grid cell is the single-point
    certificate for the same weights, and its margin is ``lambda_min`` of that point's literal ``P``."""
    plant = PlantWeights((0.5, 0.5, 0.9, 0.3, 0.3, 0.3), (0.4,) * 6, 1.5, 0.8, 0.6, 2.0)
    design = replace(DESIGN, plant=plant)
    k_c, k_xi = np.array([0.5, 3.0, 8.0]), np.array([0.3, 5.0, 20.0])
    m = gain_map(design, REFERENCE, [("k_c", k_c), ("k_xi", k_xi)])
    for row, kx in enumerate(k_xi):
        for col, kc in enumerate(k_c):
            point = GainPoint(np.full(6, kx), np.full(6, kc), DESIGN.k_e, DESIGN.weights, plant)
            single = certify(point, REFERENCE, with_sdp=False)
            assert m.certified[row, col] == single.certified
            if single.certified:
                assert m.gamma[row, col] == pytest.approx(single.gamma, rel=1e-12)
    assert not m.certified[0].any() and m.certified.any()  # k_xi = 0.3 < S_xi^2/2 = 0.405 on joint 3


def test_gain_map_best_is_the_smallest_certified_gamma():
    m = gain_map(DESIGN, REFERENCE)
    best = m.best()
    assert best["gamma"] == np.nanmin(np.where(m.certified, m.gamma, np.nan))
    assert m.x[0] == pytest.approx(axis_value(DESIGN, "k_c") / 10) and m.y[-1] == pytest.approx(10 * 10.0)


def test_gain_map_subsamples_long_axes():
    m = gain_map(DESIGN, REFERENCE, [("k_c", np.geomspace(0.1, 10, 1000))], resolution=50)
    assert m.y_axis is None and len(m.x) == 50 and m.x[0] == 0.1 and m.x[-1] == 10


class InjectedError(Exception):
    """A failure injected into the sweep at a chosen point."""


def crash_on(call: int, function):
    """``function`` that raises :class:`InjectedError` on its ``call``-th call instead of running."""
    calls = []

    def wrapped(*args, **kwargs):
        calls.append(1)
        if len(calls) == call:
            raise InjectedError
        return function(*args, **kwargs)

    return wrapped


@pytest.mark.parametrize("window", ["after the batch file, before the state", "while the batch file is written"])
def test_crash_between_data_write_and_state_save_resumes_exactly(tmp_path, monkeypatch, window):
    """A failure injected on the third batch after its file reached the disk but before
    ``sweep.json`` recorded it, or while the file is written (deterministic, unlike a kill):
    the folder then holds at most a whole extra batch, never a partial file, and the resumed
    sweep equals an uninterrupted one."""
    spec = small_grid()
    (tmp_path / "reference").mkdir()
    run_sweep(spec, tmp_path / "reference", batch_size=7)
    out = tmp_path / "crashed"
    out.mkdir()
    with monkeypatch.context() as patch:
        if window.startswith("after"):
            patch.setattr(grid, "_record", crash_on(3, grid._record))
        else:
            patch.setattr(pq, "write_table", crash_on(3, pq.write_table))
        with pytest.raises(InjectedError):
            run_sweep(spec, out, batch_size=7)
    state = json.loads((out / "sweep.json").read_text())
    files = sorted(f.name for f in (out / grid.POINTS).iterdir())
    extra = ["part-000000000014.parquet"] if window.startswith("after") else []
    assert state["done"] == 14 and files == ["part-000000000000.parquet", "part-000000000007.parquet", *extra]
    run_sweep(spec, out, batch_size=7, resume=True)
    assert read_points(out).equals(read_points(tmp_path / "reference"))


def test_storage_is_within_the_printed_estimate(tmp_path):
    """1e5 points of three axes stored as Parquet take at most ``BYTES_PER_POINT`` bytes a point
    on disk, the estimate printed before a sweep (CSV and JSON Lines side by side took about
    310), and pandas-style readers see one dataset."""
    axes = (("k_c", np.geomspace(0.5, 10, 50)), ("k_e_p", np.linspace(1, 20, 50)), ("k_e_r", np.linspace(1, 20, 40)))
    spec = GridSpec.around(DESIGN, REFERENCE, axes)
    run_sweep(spec, tmp_path)
    size = sum(f.stat().st_size for f in (tmp_path / POINTS).iterdir())
    assert size / spec.size <= BYTES_PER_POINT, size / spec.size
    table = read_points(tmp_path)
    assert table.num_rows == spec.size and table.column_names[:4] == ["index", "k_c", "k_e_p", "k_e_r"]


def test_named_points_are_the_smallest_gamma_and_the_cheapest_meeting_the_requirement(tmp_path):
    """With ``[certify] gamma``: the point labelled smallest gamma has the smallest certified gamma
    of the grid, the one labelled cheapest has the smallest |[k_xi; k_c; k_e]| among the points
    certified with gamma <= the requirement; both read from the stored points."""
    scenario = write_grid_scenario(tmp_path, gamma=1.0, k_c_num=40)
    result = runner.invoke(app, ["certify", str(scenario), "--out", str(tmp_path / "out"), "--json", "-"])
    assert result.exit_code == 1, result.output
    named = {p["label"]: p for p in json.loads(result.stdout)["points"]}
    rows = read_points(tmp_path / "out")
    ok = rows.filter(rows["certified"])
    assert named["smallest certified gamma"]["gamma"] == pytest.approx(min(ok["gamma"].to_pylist()), rel=1e-9)
    cheapest = named["cheapest meeting gamma <= 1 (smallest |K|)"]
    indices = ok["index"].to_numpy()
    d = grid_designs(scenario, indices)
    norms = np.linalg.norm(np.hstack([d["k_xi"], d["k_c"], d["k_e"]]), axis=1)
    assert cheapest["index"] == int(indices[np.argmin(norms)]) and cheapest["gamma"] <= 1.0


def grid_designs(scenario: Path, indices: np.ndarray) -> dict[str, np.ndarray]:
    """The gains of the grid points ``indices`` of a scenario's sweep."""
    case = cli_module.load_case(scenario)
    grid = GridSpec.around(case.point, case.reference, case.scenario.grid.axes())
    rows = [grid.designs(int(i), int(i) + 1) for i in indices]
    return {k: np.concatenate([r[k] for r in rows]) for k in ("k_xi", "k_c", "k_e")}


def test_progress_lines_without_a_terminal(tmp_path, monkeypatch):
    """Standard error not a terminal (CI, nohup): plain progress lines, here one per batch, the
    expected size before the sweep, and a CSV export on request."""
    monkeypatch.setattr(console_module, "PROGRESS_EVERY", 0.0)
    scenario = write_grid_scenario(tmp_path, k_c_num=40)
    out = tmp_path / "out"
    result = runner.invoke(app, ["certify", str(scenario), "--out", str(out), "--batch-size", "2000", "--csv"])
    assert result.exit_code in (0, 1), result.output
    lines = result.stderr.splitlines()
    assert lines[0].startswith("grid: 8,000 points, about 0.16 MB on disk (Parquet")
    progress = [line for line in lines if line.startswith("certify grid: ")]
    assert progress[0].startswith("certify grid: 2,000 / 8,000 points (25%)") and len(progress) == 4, lines
    assert len((out / "points.csv").read_text().splitlines()) == 1 + 8000


def test_large_grids_are_refused_by_size_on_disk(tmp_path, monkeypatch):
    """Above the byte limit the sweep needs --large, and says how large it would be."""
    monkeypatch.setattr(jobs_module, "MAX_GRID_BYTES", 10_000)
    result = runner.invoke(app, ["certify", str(write_grid_scenario(tmp_path, k_c_num=40)), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "8,000 points, about 0 MB on disk" in result.stderr


def test_new_sweep_replaces_an_older_larger_one(tmp_path):
    """A sweep started (not resumed) in a directory holding an older, larger sweep leaves none
    of the older batch files behind: its points equal those of a sweep in an empty directory."""
    spec = small_grid()
    smaller = GridSpec.around(DESIGN, REFERENCE, (("k_c", np.geomspace(0.5, 10, 3)), ("k_e_r", np.array([1.0, 5.0]))))
    for name in ("reused", "fresh"):
        (tmp_path / name).mkdir()
    run_sweep(spec, tmp_path / "reused", batch_size=7)
    run_sweep(smaller, tmp_path / "reused", batch_size=7)
    run_sweep(smaller, tmp_path / "fresh", batch_size=7)
    assert read_points(tmp_path / "reused").equals(read_points(tmp_path / "fresh"))
