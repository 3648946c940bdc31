"""Gain windows per joint (docs/math.md, "Gain windows") and the storage identity of the loop as
implemented (fact 11): each property on the default UR5 and on a light wrist."""

from __future__ import annotations

import json
import tomllib
from functools import cached_property
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from dvfc.analysis.case import Case
from dvfc.analysis.cli import app
from dvfc.analysis.sampled import as_implemented
from dvfc.analysis.verify import IMPLEMENTED_TOL, implemented, implemented_storage
from dvfc.analysis.windows import HOLD_MARGIN, gain_windows, held_eigenvalues

runner = CliRunner()
CIRCLE = Path(__file__).parents[1] / "examples" / "ur5_circle.toml"
LIGHT_WRIST = Path(__file__).parent / "data" / "light_wrist6.urdf"


def write(tmp_path: Path, edit=None) -> Path:
    """The default example (``examples/ur5_circle.toml``: 500 Hz hold), 0.05 s, not compiled, with
    ``edit`` applied."""
    data = tomllib.loads(CIRCLE.read_text())
    data["simulation"].update(duration=0.05, jit=False)
    if edit is not None:
        edit(data)
    path = tmp_path / "s.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def light_wrist(data):
    data["robot"].pop("model")
    data["robot"]["urdf"] = str(LIGHT_WRIST)


@pytest.fixture(scope="module")
def default_mass(tmp_path_factory):
    case = Case.load(write(tmp_path_factory.mktemp("default")))
    robot = case.loop.robot
    return np.asarray(robot.function("M", robot.mass_matrix)(case.s0[: robot.n], 0)), case.point.k_xi


def test_the_hold_limit_is_where_the_held_map_reaches_its_margin(default_mass):
    """At each joint's limit (the others as given) the held map ``I - h M^-1 K_xi`` has its most
    negative eigenvalue at ``-(1 - margin)``: within 1e-9 below, beyond it just above. The
    default's wrist 3 (0.017 kg m^2) has the limit about ``(2 - margin) m / h`` = 16 at 500 Hz."""
    mass, k_xi = default_mass
    windows = gain_windows(mass, k_xi, 500.0, None)
    m_inv, h = np.linalg.inv(mass), 1 / 500
    assert 15.0 < windows.upper[5] < 17.0 and not windows.alone[5]
    for i, limit in enumerate(windows.upper):
        if windows.alone[i]:
            continue
        at, beyond = k_xi.copy(), k_xi.copy()
        at[i], beyond[i] = limit, limit * (1 + 1e-6)
        assert abs(held_eigenvalues(m_inv, at, h)[-1] - (2 - HOLD_MARGIN)) <= 1e-9
        assert held_eigenvalues(m_inv, beyond, h)[-1] > 2 - HOLD_MARGIN
    assert windows.warning() is None and 1 - windows.held > HOLD_MARGIN - 1


def test_the_lower_limit_is_the_certificates_at_the_required_gamma(default_mass):
    """Without ``[certify] gamma`` the requirement is ``k_xi > 1/2``; at gamma = 1 it is
    ``1/2 + 1/2 = 1``, and a gain of 0.9 is reported as breaking it; without a hold (the ideal
    continuous loop) there is no upper limit."""
    mass, k_xi = default_mass
    low = k_xi.copy()
    low[0] = 0.9
    assert gain_windows(mass, low, None, None).warning() is None
    windows = gain_windows(mass, low, None, 1.0)
    assert np.all(windows.lower == 1.0) and windows.upper is None
    assert "joint 1 k_xi = 0.9 not above the L2 certificate's 1 (gamma = 1)" in windows.warning()


@pytest.mark.parametrize(
    ("edit", "joints"),
    [(lambda d: d["gains"].update(k_xi=[20.0, 20.0, 20.0, 5.0, 5.0, 20.0]), ["joint 6"]),
     (light_wrist, ["joint 5", "joint 6"])],
    ids=["ur5-wrist-at-20", "light-wrist"],
)  # fmt: skip
def test_a_gain_outside_its_window_is_reported_before_the_run(tmp_path, edit, joints):
    """``simulate`` says in one line, before running, which gain breaks its hold limit (the
    run itself then stops or not: the warning comes first); ``pose`` shows the same windows."""
    path = write(tmp_path, edit)
    result = runner.invoke(app, ["simulate", str(path), "--out", str(tmp_path / "o")])
    first = result.stderr.splitlines()[0]
    assert first.startswith("warning: gain outside its window:"), result.stderr
    assert all(f"{j} k_xi" in first and "hold limit" in first for j in joints), first
    view = json.loads(runner.invoke(app, ["pose", str(path), "--json", "-"]).stdout)["gain_windows"]
    assert [i + 1 for i, inside in enumerate(view["inside"]) if not inside] == [int(j[-1]) for j in joints]


def test_gains_inside_their_windows_give_no_warning(tmp_path):
    result = runner.invoke(app, ["pose", str(write(tmp_path)), "--json", "-"])
    assert result.exit_code == 0 and "gain outside" not in result.stderr
    assert all(json.loads(result.stdout)["gain_windows"]["inside"])


class PerturbedTorque:
    """A law whose torque carries 0.5 N m on every joint that its input ``u_xi`` does not."""

    @cached_property
    def tau(self):
        return super().tau + 0.5


def test_the_implemented_storage_identity_holds_and_fails_when_the_torque_is_perturbed(tmp_path):
    """Fact 11 on the default's sampled run (500 Hz, 60 Hz camera, 20 ms latency, image e_e):
    residual 1.4e-6 (RK4 truncation), within the bound; with the law's torque perturbed by a
    term its input ``u_xi`` does not carry the identity is off by ``int xi^T 0.5`` (> 1e-3)."""
    case = Case.load(write(tmp_path, lambda d: d["simulation"].update(duration=0.5)))
    loop, settings = case.loop, case.settings
    traj = as_implemented(loop, settings).run(case.s0)
    assert traj.status == "ok" and implemented_storage(traj) <= 2e-6
    claim = next(c for c in implemented(loop, case.s0, settings, traj) if c.reference == "docs/math.md, fact 11")
    assert claim.status == "PASS"
    perturbed = type("Perturbed", (PerturbedTorque, type(loop)), {})
    wrong = perturbed(**{f: getattr(loop, f) for f in loop.__dataclass_fields__})
    bad = as_implemented(wrong, settings).run(case.s0)
    assert implemented_storage(bad) > 1e-3 > IMPLEMENTED_TOL
    claim = next(c for c in implemented(wrong, case.s0, settings, bad) if c.reference == "docs/math.md, fact 11")
    assert claim.status == "FAIL"


def test_synthesis_refuses_in_one_line_when_a_joints_window_is_empty_within_its_box(tmp_path):
    """On the light wrist at 500 Hz, ``[synthesize] k_xi = [1, 100]`` for every joint: the ideal loop
    alone would take a wrist-3 gain whose held torque diverges (run peak ~1e254 x the limit); within
    the windows' margins wrist 3 needs ``1.1 x 1/2 <= k_xi,6 <= 0.8 x 0.487`` (its hold limit alone,
    ``1.95 / (h (M^-1)_66)``), empty: exit 1, nothing written, one status line naming the joint."""
    path = write(tmp_path, lambda d: (light_wrist(d), d.update(synthesize={"k_xi": [1.0, 100.0]})))
    target = tmp_path / "out" / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(path), "--out", str(target), "--json", "-"])
    record = json.loads(result.stdout)
    assert result.exit_code == 1 and not target.exists() and record["scenario_file"] is None
    assert record["status"].startswith("infeasible: joint 6: no k_xi in [1, 100]") and "\n" not in record["status"]
    assert "0.8 x its hold limit alone 0.4867" in record["status"]


def test_synthesis_defaults_to_the_windows_and_says_when_one_is_empty(tmp_path):
    """Without ``[synthesize] k_xi`` the box is the gain windows: on the light wrist at 500 Hz
    wrist 3's hold limit (0.474, effective inertia 4.9e-4 kg m^2) lies below the certificate's
    1/2, so no design exists and none is written (exit 1); per-joint intervals are read as given
    and a wrong count is one line naming the field (exit 2)."""
    path = write(tmp_path, light_wrist)
    target = tmp_path / "out" / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(path), "--out", str(target), "--json", "-"])
    record = json.loads(result.stdout)
    assert result.exit_code == 1 and not target.exists()
    (lo6, hi6) = record["bounds"]["k_xi"][5]
    assert hi6 < 0.5 and lo6 == pytest.approx(hi6)
    wrong = write(tmp_path, lambda d: d.update(synthesize={"k_xi": [[1.0, 2.0]] * 5}))
    result = runner.invoke(app, ["synthesize", str(wrong), "--out", str(target)])
    assert result.exit_code == 2 and "synthesize.k_xi: 5 intervals for 6 joints" in result.stderr


@pytest.mark.slow
def test_a_light_wrist_weight_opens_the_window_and_synthesis_writes_a_certified_design(tmp_path):
    """Fact 17 on the light wrist at 500 Hz: with wrist 3's output and torque weights 0.5
    (``[performance]``), its certificate bound drops from 1/2 to ``0.5^2/2 = 0.125``, below its
    hold limit, and ``synthesize`` writes a design certified for that plant, with fact 14
    certifying the sampled loop and its run within the URDF limits (re-checked before writing)."""
    light = [1.0] * 5 + [0.5]
    path = write(tmp_path, lambda d: (light_wrist(d), d.update(performance={"output": {"xi": light},
                                                                              "disturbance": {"tau_d": light}})))
    target = tmp_path / "out" / "syn.toml"
    result = runner.invoke(app, ["synthesize", str(path), "--out", str(target), "--json", "-"])
    assert result.exit_code == 0 and target.exists(), result.output
    record = json.loads(result.stdout)
    lo6, hi6 = record["bounds"]["k_xi"][5]
    assert lo6 == pytest.approx(0.125) and hi6 < 0.5
    assert record["implemented"]["certified"] and record["point"]["weights_of_plant"]["output"]["xi"] == light


@pytest.mark.slow
def test_the_default_example_is_certified_for_the_loop_as_implemented_and_at_its_target_speed():
    """``examples/ur5_circle.toml`` as shipped: fact 14 certifies the sampled loop with its integral
    state (rho 0.9405 over 50 ms, local) and the envelope of the same design without ``K_I`` (facts
    7, 10, 20.4; ideal continuous loop) certifies a target speed above the target's own
    2 pi 0.05 / 4 = 0.0785 m/s, visibility included."""
    result = runner.invoke(app, ["certify", str(CIRCLE), "--json", "-", "--no-lower-bounds"])
    assert result.exit_code == 0, result.output
    point = json.loads(result.stdout)["points"][0]
    implemented, envelope = point["implemented"], point["envelope"]["without_integral"]
    assert implemented["certified"] and implemented["rho"] < 0.95
    assert envelope["max_target_speed"] > 2 * np.pi * 0.05 / 4 and envelope["visible"] is True
