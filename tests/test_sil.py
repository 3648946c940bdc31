"""Software in the loop (analysis/sil.py): the program driving the plant sample by sample is the loop
the sampled simulator runs (docs/math.md, fact 22), and hands the program the images of the schedule."""

from __future__ import annotations

import numpy as np
import pytest

import dvfc
from dvfc.analysis.controller import Status
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario
from dvfc.analysis.sil import compare_with_sampled, software_in_the_loop

from helpers import CELL


def by_the_virtual_machine(path):
    case = dvfc.load(path)
    data = case.scenario.model_dump()
    data["simulation"]["jit"] = False
    return case.with_scenario(Scenario.model_validate(data))


@pytest.mark.slow
@pytest.mark.parametrize("path", [DEFAULT_SCENARIO, CELL], ids=["default", "cell"])
def test_software_in_the_loop_is_the_sampled_simulator_bit_for_bit(path):
    """Over 1 s (500 samples) the program's Python step driving the plant sample by sample and the
    sampled simulator give the same joints and held torques to the bit, on the default example and on
    the cell (its plant errors, friction, integral action, jitter, dropped frames and outliers): the
    simulator's controller is the program's update (``sample_update``), its images read as the
    program reads them, and the plant and camera are the simulator's own. The torques are not all zero
    (peak above 10 N m)."""
    case = by_the_virtual_machine(path)
    comparison = compare_with_sampled(case, software_in_the_loop(case, duration=1.0))
    assert comparison.samples == 100 and comparison.peak_torque > 10
    assert comparison.max_position_difference == comparison.max_speed_difference == 0.0
    assert comparison.max_torque_difference == 0.0


def test_sil_hands_the_program_the_images_of_the_schedule():
    """Over 0.1 s at 500 Hz, 60 Hz, 20 ms latency: images captured at samples 0, 9, 17 arrive at 10,
    19, 27 (the first control sample at or after each camera tick, plus 10 periods), each once."""
    case = dvfc.load(DEFAULT_SCENARIO)
    run = software_in_the_loop(case, duration=0.06)
    arrived = np.flatnonzero(run.captures >= 0)
    assert arrived.tolist() == [10, 19, 27] and run.captures[arrived].tolist() == [0, 9, 17]
    assert run.status == "ok" and len(run.q) == len(run.tau) + 1 == 31


@pytest.mark.slow
def test_an_implausible_image_is_dropped_by_the_simulator_as_by_the_program():
    """Wrong detections 10,000 px off (each point of each image with probability 0.3) give an ``e_e`` (21)
    beyond the standoff: the program drops such an image as a lost frame (status 1), and the sampled
    simulator, reading images as the program does, drops the same ones: over 0.3 s of the default the two
    loops are the same to the bit, some images dropped and some used."""
    case = by_the_virtual_machine(DEFAULT_SCENARIO)
    data = case.scenario.model_dump()
    data["implementation"]["outliers"] = {"probability": 0.3, "size": 1e4}
    case = case.with_scenario(Scenario.model_validate(data))
    run = software_in_the_loop(case, duration=0.3)
    comparison = compare_with_sampled(case, run)
    assert comparison.max_position_difference == comparison.max_torque_difference == 0.0
    controller = dvfc.controller(case)
    arrivals = np.flatnonzero(run.captures >= 0)
    statuses = [controller.evaluate(run.states[k], run.t[k], run.q[k], run.qd[k], run.features[k],
                                    int(run.captures[k])).status for k in arrivals]  # fmt: skip
    dropped = sum(status is Status.IMAGE_REJECTED for status in statuses)
    assert 0 < dropped < len(statuses), statuses


def test_a_point_behind_the_camera_stops_both_loops_with_the_same_stop():
    """A target placed behind the camera (0.3 m back along its optical axis): the program-in-the-loop run
    and the sampled simulator both end at the first capture, with the one stop they share
    (:class:`~dvfc.analysis.simulate.Stop`): ``behind_camera``, the same words, not ``out_of_view``."""
    data = dvfc.load(DEFAULT_SCENARIO).scenario.model_dump()
    for key in ("xyz", "rpy"):
        data["target"].pop(key)
    data["target"]["relative_to_camera"] = {"xyz": [0.0, 0.0, -0.3], "rpy": [0.0, 0.0, 0.0]}
    data.pop("start")
    data["simulation"] |= {"duration": 0.02, "jit": False}
    case = dvfc.Case(Scenario.model_validate(data), DEFAULT_SCENARIO.parent, None, None, False)
    sil = software_in_the_loop(case)
    sampled = dvfc.simulate(case)
    assert sil.status == sampled.status == "behind_camera", (sil.status, sampled.status)
    assert sil.message == sampled.message == "a feature point is behind the camera at t = 0 s"
