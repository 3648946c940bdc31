"""Property-based tests (hypothesis): certificate soundness on random gain points and
rotations, and reproducibility of results."""

from __future__ import annotations

import json

import casadi as cs
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from dvfc.analysis.certify import GainPoint, certify
from dvfc.analysis.cli import app
from dvfc.models.lie import SE3
from dvfc.models.loop import Weights

import reference as ref
from helpers import setter, write

REFERENCE = SE3.from_xyz_rpy([0.01, 0.02, 0.35], [0.2, -0.1, 0.3])
gain = st.floats(0.6, 50.0)
weight = st.floats(0.2, 8.0)
unit_quaternion = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(
    st.lists(gain, min_size=6, max_size=6),
    st.lists(gain, min_size=6, max_size=6),
    st.lists(gain, min_size=6, max_size=6),
    st.lists(weight, min_size=4, max_size=4),
    st.lists(unit_quaternion, min_size=1, max_size=4),
)
def test_certificate_is_sound_at_every_rotation(k_xi, k_c, k_e, w, quaternions):
    """Whenever a point is certified at gamma, Theorem 2's P(gamma), built by the independent
    NumPy reference, is positive semidefinite at any rotation R_ec (drawn at random),
    isotropic K_e or not."""
    point = GainPoint(np.array(k_xi), np.array(k_c), np.array(k_e), Weights(*w))
    cert = certify(point, REFERENCE, with_sdp=False)
    if not cert.certified:
        assert cert.gamma is None and cert.reason
        return
    pose = np.asarray(cs.DM(REFERENCE.as_matrix()))
    design = ref.Design(point.k_xi, point.k_c, point.k_e, w, pose[:3, 3], pose[:3, :3])
    for q in quaternions:
        r = Rotation.from_quat(np.array(q) / np.linalg.norm(q)).as_matrix()
        p = ref.p_matrix(design.a(r), design.weight, cert.gamma)
        assert ref.lambda_min(p) >= -ref.round_off(p)


def strip_timing(data: dict) -> dict:
    data["summary"].pop("seconds", None)
    data["summary"].pop("wall_time", None)
    data["provenance"].pop("date")
    data["provenance"].pop("command")
    data.pop("outputs", None)
    return data


@pytest.mark.slow
def test_same_scenario_and_seed_give_identical_results(tmp_path):
    """Two runs of simulate and of certify on the same scenario (with seeded torque noise)
    give identical JSON apart from timing and the date, and the measured nonlinear lower bound
    (a CVODES run from rest) to 1e-7 relative: the first run in a process with an empty compile
    cache has given it 7e-9 apart from the second, a measurement's reproducibility, not a
    certificate's."""
    noise = setter("disturbance.torque", [{"kind": "noise", "rms": 1.0, "bandwidth": 5.0, "seed": 11}])
    scenario = write(tmp_path, noise)
    runner = CliRunner()
    for command in ("simulate", "certify"):
        args = [command, str(scenario), "--json", "-", "--out"]
        runs = [
            strip_timing(json.loads(runner.invoke(app, [*args, str(tmp_path / f"{command}{i}")]).stdout))
            for i in range(2)
        ]
        if command == "certify":
            measured = [r["points"][0].pop("gamma_lower_nonlinear") for r in runs]
            assert measured[0] == pytest.approx(measured[1], rel=1e-7)
        assert runs[0] == runs[1]
        assert runs[0]["provenance"]["scenario_sha256"] and runs[0]["provenance"]["toolkit"]["dvfc"]


def test_time_budget_stops_the_run(tmp_path):
    """A run over its wall-clock budget stops with that status and exit 1, not a hang."""
    scenario = write(tmp_path, setter("simulation.time_budget", 1e-6))
    result = CliRunner().invoke(app, ["simulate", str(scenario), "--out", str(tmp_path / "o"), "--json", "-"])
    assert result.exit_code == 1
    assert json.loads(result.stdout)["summary"]["status"] == "time_budget"
