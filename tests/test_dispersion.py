"""Plant errors, dispersions and campaigns of the loop as implemented."""

from __future__ import annotations

import copy
import math
import pickle
import tomllib
from dataclasses import replace
from pathlib import Path

import casadi as cs
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from pydantic import ValidationError
from scipy import stats
from typer.testing import CliRunner

from dvfc.analysis import batches as batches_module
from dvfc.analysis import campaign as campaign_module
from dvfc.analysis.calibration import read_calibration
from dvfc.analysis.campaign import (
    CampaignSpec,
    clopper_pearson_upper,
    read_runs,
    run_campaign,
    simulate_run,
    true_pixels,
)
from dvfc.analysis.case import Case
from dvfc.analysis.cli import app
from dvfc.analysis.margins import tracking_bound
from dvfc.analysis.messages import one_line
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, ScenarioError, build_camera
from dvfc.models.camera import Camera
from dvfc.models.errors import PlantErrors, friction_torque, true_features
from dvfc.models.lie import SE3
from dvfc.models.robot import Robot, builtin_urdf, joint_dynamics

BASE = tomllib.loads(DEFAULT_SCENARIO.read_text())


def case_of(edit=None, duration: float = 2.0) -> Case:
    """The default scenario (compiled), ``duration`` s, after ``edit`` of its dictionary."""
    data = copy.deepcopy(BASE)
    data["simulation"]["duration"] = duration
    if edit is not None:
        edit(data)
    return Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent)


def with_dispersion(dispersion: dict):
    def edit(data: dict) -> None:
        data["dispersion"] = dispersion

    return edit


SMALL = {"plant.mount.rpy": {"dist": "normal", "sigma": 0.01, "clip": 3.0},
         "implementation.frame_drop": {"dist": "uniform", "low": 0.0, "high": 0.1}}  # fmt: skip


@pytest.mark.slow
def test_zero_plant_errors_give_the_nominal_run_bit_for_bit():
    case = case_of()
    nominal = as_implemented(case.loop, case.settings).run(case.s0)
    zero = replace(case.settings, errors=PlantErrors.none(case.loop.camera, case.loop.robot.n))
    errors = as_implemented(case.loop, zero).run(case.s0)
    assert set(nominal.signals) == set(errors.signals)
    for name, value in nominal.signals.items():
        assert np.array_equal(value, errors.signals[name]), name


def test_mount_error_features_are_the_true_cameras_and_the_law_keeps_the_nominal_jacobian():
    case = case_of(lambda d: d["simulation"].update(jit=False))
    loop, s0 = case.loop, case.s0
    xyz, rpy = np.array([0.01, -0.02, 0.005]), np.array([0.05, -0.03, 0.08])
    errors = replace(PlantErrors.none(loop.camera, loop.robot.n), mount_xyz=xyz, mount_rpy=rpy)
    sim = as_implemented(loop, replace(case.settings, errors=errors))
    f_true = sim._camera(0.0, s0, np.zeros(2 * loop.camera.m), sim._errors)[0].ravel()
    # independently: the true camera frame g_wc Delta, the points projected by lambda x / z
    n = loop.robot.n
    g_wc = np.asarray(cs.Function("g", [loop.robot.q], [loop.robot.camera_pose.as_matrix()])(s0[:n]))
    g_wo = np.asarray(cs.DM(loop.target.pose(0.0).as_matrix()))
    delta = np.asarray(cs.DM(SE3.from_xyz_rpy(xyz, rpy).as_matrix()))
    seen = np.linalg.solve(g_wc @ delta, g_wo)
    p = (seen[:3, :3] @ loop.camera.points.T).T + seen[:3, 3]
    expected = (loop.camera.focal_length * p[:, :2] / p[:, 2:]).ravel()
    assert np.allclose(f_true, expected, rtol=0, atol=1e-9)
    true_arm = Robot(loop.robot.urdf, loop.robot.frame, loop.robot.mount @ SE3.from_xyz_rpy(xyz, rpy))
    jb = lambda r: np.asarray(cs.Function("j", [r.q], [r.body_jacobian])(s0[:n]))  # noqa: E731
    holds = np.zeros((sim.model.hold.numel(), 1))  # [tau; e_e; V_k; U_k]
    law = np.asarray(sim.evaluate_signals(np.zeros(1), s0[:, None], holds)["body_jacobian"]).reshape(n, 6).T
    assert np.allclose(law, jb(loop.robot), atol=1e-12)
    assert not np.allclose(law, jb(true_arm), atol=1e-3)


def test_distortion_equals_opencv_project_points(rng):
    cv2 = pytest.importorskip("cv2")
    points = np.column_stack([rng.uniform(-0.3, 0.3, (6, 2)), rng.uniform(0.5, 2.0, 6)])
    camera = Camera(800.0, points)
    for _ in range(5):
        k = rng.normal(0, [0.2, 0.05, 0.002, 0.002, 0.01])
        fx, fy, cx, cy = rng.uniform(700, 900), rng.uniform(700, 900), rng.uniform(600, 680), rng.uniform(480, 540)
        parameters = cs.DM(np.concatenate([np.zeros(6), [fx, fy, cx, cy], k, np.zeros(18)]))
        _, pixels, _ = true_features(camera, SE3.identity(), parameters)  # offset = the whole principal point
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
        expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, k)
        assert np.allclose(np.asarray(pixels).ravel(), expected.ravel(), rtol=0, atol=1e-8)


def test_calibration_files_of_both_formats_round_trip(tmp_path):
    cv2 = pytest.importorskip("cv2")
    K = np.array([[812.5, 0, 641.2], [0, 809.75, 515.5], [0, 0, 1]])
    D = np.array([-0.12, 0.031, 0.0007, -0.0004, 0.002])
    ros = {"image_width": 1280, "image_height": 1024, "camera_name": "cell",
           "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()}, "distortion_model": "plumb_bob",
           "distortion_coefficients": {"rows": 1, "cols": 5, "data": D.tolist()}}  # fmt: skip
    (tmp_path / "ros.yaml").write_text(yaml.safe_dump(ros))
    storage = cv2.FileStorage(str(tmp_path / "cv.yaml"), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 1280)
    storage.write("image_height", 1024)
    storage.write("camera_matrix", K)
    storage.write("distortion_coefficients", D.reshape(1, 5))
    storage.release()
    for name in ("ros.yaml", "cv.yaml"):
        c = read_calibration(tmp_path / name)
        assert (c.fx, c.fy, c.principal_point, c.width, c.height) == (812.5, 809.75, (641.2, 515.5), 1280, 1024)
        assert np.array_equal(c.distortion, D)
    section = Scenario.model_validate({**BASE, "camera": {"calibration": "ros.yaml", "width": 1280, "height": 1000}})
    with pytest.raises(ScenarioError, match=r"camera\.height: 1000 px, but the calibration file"):
        build_camera(section.camera, tmp_path, np.zeros((4, 3)))


def test_urdf_friction_parsed_with_sign_and_magnitude(tmp_path):
    text = builtin_urdf("planar2dd").read_text()
    robot = Robot(builtin_urdf("planar2dd"), "camera_link")
    first = robot.joints[0]
    marker = f'<joint name="{first}"'
    assert marker in text
    head, tail = text.split(marker, 1)
    tail = tail.replace("</joint>", '<dynamics damping="0.7" friction="1.5"/></joint>', 1)
    (tmp_path / "arm.urdf").write_text(head + marker + tail)
    viscous, coulomb = joint_dynamics(tmp_path / "arm.urdf", robot.joints)
    assert viscous.tolist() == [0.7] + [0.0] * (robot.n - 1) and coulomb.tolist() == [1.5] + [0.0] * (robot.n - 1)
    parameters = cs.DM(np.concatenate([viscous, coulomb, [0.05]]))
    for speed in (0.4, -0.4):
        qd = np.zeros(robot.n)
        qd[0] = speed
        torque = np.asarray(friction_torque(cs.DM(qd), parameters, robot.n)).ravel()
        assert torque[0] == pytest.approx(0.7 * speed + 1.5 * math.tanh(speed / 0.05))  # opposes the motion
        assert np.sign(torque[0]) == np.sign(speed) and np.all(torque[1:] == 0)


def test_clopper_pearson_equals_scipy_and_the_hand_computation():
    assert clopper_pearson_upper(0, 299, 0.95) == pytest.approx(1 - 0.05 ** (1 / 299), rel=1e-12)
    assert round(clopper_pearson_upper(0, 299, 0.95), 5) == 0.00997
    for k, n in ((1, 20), (3, 100), (7, 50)):
        assert clopper_pearson_upper(k, n, 0.9) == stats.beta.ppf(0.9, k + 1, n - k)
        # the bound p solves P(Binomial(n, p) <= k) = 1 - c
        assert stats.binom.cdf(k, n, clopper_pearson_upper(k, n, 0.9)) == pytest.approx(0.1, abs=1e-9)


@pytest.mark.parametrize(
    ("dispersion", "message"),
    [
        ({"plant.mount.rpy": {"dist": "normal", "sigma": -0.1}}, "sigma"),
        ({"plant.mount.rpy": {"dist": "uniform", "low": 0.1, "high": -0.1}}, "exceeds high"),
        ({"plant.mount.rpy": {"dist": "cauchy", "sigma": 0.1}}, "dist"),
        ({"plant.mount.rp": {"dist": "normal", "sigma": 0.1}}, "did you mean 'plant.mount.rpy'"),
        ({"target.motion.period": {"dist": "normal", "sigma": 0.1}}, "not dispersable"),
        ({"implementation.frame_drop": {"dist": "choice", "values": [0.1, 1.5]}}, "outside"),
    ],
)
def test_bad_dispersion_is_one_line_naming_the_field(dispersion, message):
    data = copy.deepcopy(BASE)
    data["dispersion"] = dispersion
    with pytest.raises(ScenarioError, match=message) as info:
        try:
            Scenario.model_validate(data)
        except ValidationError as exc:
            raise ScenarioError(one_line(exc, Scenario, sections=True)) from exc
    assert "\n" not in str(info.value) and "dispersion" in str(info.value)


def test_frame_drop_probability_outside_unit_interval_is_refused():
    data = copy.deepcopy(BASE)
    data["implementation"]["frame_drop"] = 1.2
    with pytest.raises(Exception, match="frame_drop"):
        Scenario.model_validate(data)


def test_campaign_runs_below_one_exit_2_writing_nothing(tmp_path):
    result = CliRunner().invoke(app, ["campaign", str(DEFAULT_SCENARIO), "--runs", "0", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "--runs" in result.output and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_a_campaign_row_replays_bit_for_bit(tmp_path):
    case = case_of(with_dispersion(SMALL))
    spec = CampaignSpec.of(case, tracking_bound(case), seed=3)
    run_campaign(spec, tmp_path, 4, batch_size=2)
    rows = read_runs(tmp_path).to_pylist()
    again, _ = simulate_run(spec, 3)
    again.pop("wall_time"), rows[3].pop("wall_time")
    assert again == rows[3]


@pytest.mark.slow
def test_one_and_two_workers_give_identical_datasets(tmp_path):
    case = case_of(with_dispersion(SMALL), duration=1.0)
    spec = CampaignSpec.of(case, tracking_bound(case))
    run_campaign(spec, tmp_path / "one", 6, batch_size=3, workers=1)
    run_campaign(spec, tmp_path / "two", 6, batch_size=2, workers=2)
    one, two = (read_runs(tmp_path / d).drop_columns(["wall_time"]) for d in ("one", "two"))
    assert one.equals(two)


@pytest.mark.slow
def test_a_crash_between_a_batch_write_and_the_state_save_resumes_losslessly(tmp_path, monkeypatch):
    case = case_of(with_dispersion(SMALL), duration=1.0)
    spec = CampaignSpec.of(case, tracking_bound(case))
    run_campaign(spec, tmp_path / "whole", 6, batch_size=2)
    real, calls = batches_module.atomic_write, []

    def crashing(path: Path, write) -> None:
        real(path, write)
        calls.append(path.name)
        if path.suffix == ".parquet" and calls.count(path.name) == 1 and len(calls) > 3:  # the second batch written
            raise KeyboardInterrupt

    monkeypatch.setattr(batches_module, "atomic_write", crashing)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(spec, tmp_path / "cut", 6, batch_size=2)
    monkeypatch.setattr(batches_module, "atomic_write", real)
    assert len(list((tmp_path / "cut" / "runs").glob("*.parquet"))) == 2  # written, not recorded as done
    run_campaign(spec, tmp_path / "cut", 6, batch_size=2, resume=True)
    whole, cut = (read_runs(tmp_path / d).drop_columns(["wall_time"]) for d in ("whole", "cut"))
    assert cut.equals(whole)
    assert len(pq.read_table(tmp_path / "cut" / "runs")) == 6


@pytest.mark.slow
def test_a_30_degree_mount_rotation_error_fails_and_ranks_first(tmp_path):
    dispersion = {"plant.mount.rpy": {"dist": "uniform", "low": [0.0, 0.0, 0.0], "high": [0.5236, 0.0, 0.0]},
                  "plant.camera.focal_length": {"dist": "lognormal", "sigma": 0.01}}  # fmt: skip
    # 3 s: past the default's 2 s planned start, so the tracking error judged is the loop's, not the plan's
    case = case_of(with_dispersion(dispersion), duration=3.0)
    spec = CampaignSpec.of(case, tracking_bound(case))
    run_campaign(spec, tmp_path, 12, batch_size=6)
    summary = campaign_module.summarize(spec, read_runs(tmp_path), 0.95, 0.01, 0.9)
    assert summary["failures"] > 0
    assert summary["sensitivity"][0]["quantity"] == "plant.mount.rpy"


def test_true_pixels_are_the_models_features_without_errors_and_shift_with_the_principal_point():
    """The features the plant's camera sees along a run (the report's worst-run figure): with no
    plant error, the model's features about the image centre; with the true principal point
    moved by ``d`` (and nothing else wrong), the same tracks moved by ``d``."""
    case = case_of(lambda d: d["simulation"].update(jit=False), duration=0.2)
    loop = case.loop
    traj = as_implemented(loop, case.settings).run(case.s0)
    none = PlantErrors.none(loop.camera, loop.robot.n)
    model = traj["f"].reshape(len(traj.t), -1, 2) + loop.camera.centre
    assert np.allclose(true_pixels(loop, traj, none), model, rtol=0, atol=1e-9)
    shift = np.array([12.0, -7.0])
    moved = replace(none, principal_point=none.principal_point + shift)
    assert np.allclose(true_pixels(loop, traj, moved), model + shift, rtol=0, atol=1e-9)


@pytest.mark.parametrize("runs", [0, 2.0, "100", True])
def test_report_campaign_runs_is_a_strict_positive_integer(runs):
    """``[report] campaign_runs``: an integer of at least 1, nothing coerced."""
    data = copy.deepcopy(BASE)
    data["report"] = {"campaign_runs": runs}
    with pytest.raises(ValidationError, match="campaign_runs"):
        Scenario.model_validate(data)
    data["report"] = {"campaign_runs": 7}
    assert Scenario.model_validate(data).report.campaign_runs == 7


@pytest.mark.slow
def test_a_worker_builds_one_simulator_for_every_batch_of_a_case():
    """Each batch reaches a worker as a pickled case; the copies of one case share the simulator
    built for the first (no batch rebuilds it)."""
    case = case_of(with_dispersion(SMALL), duration=0.2)
    first, second = (pickle.loads(pickle.dumps(case)) for _ in range(2))
    assert campaign_module.shared_simulator(first) is campaign_module.shared_simulator(second)
    other = case_of(with_dispersion(SMALL), duration=0.3)
    assert campaign_module.shared_simulator(pickle.loads(pickle.dumps(other))) is not (
        campaign_module.shared_simulator(first)
    )


def test_a_batch_whose_runs_have_no_local_error_reads_with_the_others(tmp_path):
    """A batch in which no run has a value in a column (``local_error_q`` of runs that all stopped at their start)
    is written with that column typed as in the others, so that the campaign's batches read as one dataset, the
    missing values null."""
    folder = tmp_path / "runs"
    folder.mkdir()
    pq.write_table(campaign_module.batch_table({"run": [0, 1], "local_error_q": [None, None]}),
                   folder / "part-000000000.parquet")  # fmt: skip
    pq.write_table(campaign_module.batch_table({"run": [2, 3], "local_error_q": [1e-9, None]}),
                   folder / "part-000000001.parquet")  # fmt: skip
    assert campaign_module.read_runs(tmp_path).to_pydict() == {"run": [0, 1, 2, 3],
                                                               "local_error_q": [None, None, 1e-9, None]}  # fmt: skip
