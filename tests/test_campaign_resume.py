"""Campaigns on a Dask cluster, and the report's campaign stage interrupted and resumed."""

from __future__ import annotations

import copy
import tomllib
from functools import partial

import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis import campaign as campaign_module
from dvfc.analysis.campaign import read_runs
from dvfc.analysis.case import Case
from dvfc.analysis.cli import app
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.reports import document
from dvfc.reports.document import StageCache, measure_campaign

DISPERSION = {"plant.mount.rpy": {"dist": "normal", "sigma": 0.01, "clip": 3.0},
              "implementation.frame_drop": {"dist": "uniform", "low": 0.0, "high": 0.1},
              "target.motion.radius": {"dist": "uniform", "low": -0.01, "high": 0.01}}  # fmt: skip


def scenario_data(runs: int) -> dict:
    """The default scenario, 1 s, with :data:`DISPERSION` and ``[report] campaign_runs = runs``."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["simulation"]["duration"] = 1.0
    data["dispersion"] = copy.deepcopy(DISPERSION)
    data["report"] = {"campaign_runs": runs}
    return data


@pytest.mark.slow
def test_a_local_dask_cluster_gives_the_datasets_of_one_and_two_local_workers(tmp_path):
    """``dvfc campaign --scheduler local`` (a LocalCluster of two worker processes on this machine)
    writes the dataset of one local worker and of two, run for run (but the wall times)."""
    pytest.importorskip("distributed")
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(tomli_w.dumps(scenario_data(6)))
    runs = {}
    for name, options in (("one", ["--workers", "1"]), ("two", ["--workers", "2"]),
                          ("dask", ["--workers", "2", "--scheduler", "local"])):  # fmt: skip
        command = ["campaign", str(scenario), "--runs", "6", "--batch-size", "2", "--out", str(tmp_path / name)]
        result = CliRunner().invoke(app, [*command, *options])
        assert result.exit_code in (0, 1), result.output  # 1: some run fails the criterion
        runs[name] = read_runs(tmp_path / name).drop_columns(["wall_time"])
    assert runs["one"].equals(runs["two"])
    assert runs["dask"].equals(runs["one"])


@pytest.mark.slow
def test_the_reports_campaign_interrupted_and_resumed_loses_nothing_and_gives_the_same_result(tmp_path, monkeypatch):
    """Ctrl-C in the report's campaign stage after its second batch; the resumed report makes only
    the runs not yet recorded and states what the uninterrupted report does."""
    case = Case(Scenario.model_validate(scenario_data(8)), DEFAULT_SCENARIO.parent)  # 3 batches: 3, 3 and 2 runs
    monkeypatch.setattr(document, "run_campaign", partial(campaign_module.run_campaign, batch_size=3))
    whole = measure_campaign(case, StageCache(tmp_path / "whole", "key", False), None)
    starts, cut, real = [], [], campaign_module.campaign_batch

    def batch(spec, start: int, stop: int) -> dict:
        starts.append(start)
        if len(starts) == 3 and not cut:  # Ctrl-C in the third batch, once
            cut.append(start)
            raise KeyboardInterrupt
        return real(spec, start, stop)

    monkeypatch.setattr(campaign_module, "campaign_batch", batch)
    with pytest.raises(KeyboardInterrupt):
        measure_campaign(case, StageCache(tmp_path / "cut", "key", False), None)
    starts.clear()
    resumed = measure_campaign(case, StageCache(tmp_path / "cut", "key", True), None)
    assert starts == [6]  # the two batches recorded are not made again
    for result in (whole, resumed):
        result["runs"].pop("wall_time")
        result["summary"].pop("wall_time_per_run")
    assert resumed["summary"] == whole["summary"]
    assert resumed["runs"] == whole["runs"]
    assert (resumed["worst"].signals["q"] == whole["worst"].signals["q"]).all()


def test_the_python_campaign_is_the_commands(tmp_path):
    """``dvfc.campaign`` (the curated API) gives the JSON of ``dvfc campaign`` for the same runs and
    seed, every key and value but the provenance and the wall times; its bad arguments are named as the
    library's (``p_fail``), the command's as its options (``--p``)."""
    import json

    import dvfc

    scenario = tmp_path / "scenario.toml"
    scenario.write_text(tomli_w.dumps(scenario_data(3)))
    target = tmp_path / "cli.json"
    result = CliRunner().invoke(app, ["campaign", str(scenario), "--runs", "3", "--out", str(tmp_path / "cli"),
                                      "--json", str(target)])  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    by_command = json.loads(target.read_text())
    by_python = json.loads(json.dumps(dvfc.campaign(dvfc.load(scenario), tmp_path / "py", 3).to_json()))
    drop = lambda r: {k: v for k, v in r.items() if k not in ("provenance", "wall_time_per_run", "dataset")}  # noqa: E731
    assert drop(by_python) == drop(by_command)
    with pytest.raises(ValueError, match=r"^p_fail: 2 is not in \(0, 1\)$"):
        dvfc.campaign(dvfc.load(scenario), tmp_path / "bad", 3, p_fail=2.0)
    assert not (tmp_path / "bad").exists()
    bad = CliRunner().invoke(app, ["campaign", str(scenario), "--p", "2", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and bad.output.strip().endswith("--p: 2 is not in (0, 1)")
    assert not (tmp_path / "bad").exists()
