"""Shared test helpers: the paper's idealised UR5 scenario edited as a TOML dictionary, built and run;
scenario files written for the command line; the robots made for the tests (a limited Jaco2, a
five-joint arm). Test files import them from here, never from one another or from ``conftest``
(which holds the fixtures)."""

from __future__ import annotations

import copy
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import replace
from importlib.metadata import distribution
from pathlib import Path

import casadi as cs
import numpy as np
import tomli_w

from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build
from dvfc.analysis.simulate import Settings, Simulator, Trajectory
from dvfc.models.loop import ClosedLoop
from dvfc.models.robot import Robot

IDEAL_SCENARIO = DEFAULT_SCENARIO.parent / "ur5_paper_ideal.toml"
"""The paper's idealised loop on the UR5 (the identities hold on it); the default scenario is
the loop as a real UR5 runs it."""
DEFAULT = tomllib.loads(IDEAL_SCENARIO.read_text())


CELL = Path(__file__).parent.parent / "examples" / "ur5_cell.toml"


def cell_with_default_design() -> tuple[Scenario, Path]:
    """``examples/ur5_cell.toml``'s plant, errors and dispersions with the default example's design: its
    gains, no integral action, the paper's constant start, the criterion its own envelope's (the cell as
    docs/math.md, facts 18-21, measured it). Returns ``(scenario, base folder)``."""
    data = tomllib.loads(CELL.read_text())
    data["gains"] = {"k_xi": [20.0, 20.0, 20.0, 5.0, 5.0, 1.5], "k_c": [3.0] * 6, "k_e": 10.0}
    for section in ("start", "criterion", "synthesized_from"):
        data.pop(section, None)
    return Scenario.model_validate(data), CELL.parent


def default_dict_without_integral() -> dict:
    """The default example's TOML dictionary with the paper's law (42): its integral action dropped
    (docs/math.md, fact 20), for the statements made of the law without ``K_I`` (the envelope, the
    start, fact 14 without ``z_I``)."""
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    del data["gains"]["k_i_factor"]
    return data


def default_without_integral() -> tuple[Scenario, Path]:
    """:func:`default_dict_without_integral` validated; returns ``(scenario, base folder)``."""
    return Scenario.model_validate(default_dict_without_integral()), DEFAULT_SCENARIO.parent


def default_from_the_papers_start(duration: float) -> tuple[ClosedLoop, np.ndarray, Settings]:
    """:func:`default_without_integral` from the paper's start (constant reference, the ``[observer]``
    error) over ``duration`` by the virtual machine: the fast transient the planned start removes."""
    spec, base = default_without_integral()
    data = spec.model_dump()
    data["start"] = {"reference": "constant", "duration": 2.0, "observer": "scenario"}
    loop, s0, settings = build(Scenario.model_validate(data), base)
    return loop, s0, replace(settings, duration=duration, dt=0.01, jit=False)


def scenario_dict(edit: Callable[[dict], None] | None = None) -> dict:
    data = copy.deepcopy(DEFAULT)
    data["simulation"]["jit"] = False
    if edit is not None:
        edit(data)
    return data


def build_loop(edit: Callable[[dict], None] | None = None, **loop_changes) -> tuple[ClosedLoop, np.ndarray, Settings]:
    """The idealised scenario's loop after ``edit`` of its TOML dictionary."""
    loop, s0, settings = build(Scenario.model_validate(scenario_dict(edit)), DEFAULT_SCENARIO.parent)
    if loop_changes:
        loop = replace(loop, **loop_changes)
    return loop, s0, settings


def run(loop: ClosedLoop, s0: np.ndarray, settings: Settings, **changes) -> Trajectory:
    return Simulator(loop, replace(settings, **changes)).run(s0)


def torque_noise(seed: int, rms: float = 2.0) -> Callable[[dict], None]:
    """An edit adding band-limited joint-torque noise (5 Hz) to the default scenario."""

    def edit(data: dict) -> None:
        data["disturbance"] = {"torque": [{"kind": "noise", "rms": rms, "bandwidth": 5.0, "seed": seed}]}

    return edit


def static_target(data: dict) -> None:
    data["target"]["motion"] = {"kind": "static"}


# --- scenario files for the command line -----------------------------------------------------


def write(tmp_path: Path, edit=None, name="s.toml") -> Path:
    """The idealised scenario, shortened to 0.2 s, after ``edit``, written to ``tmp_path / name``."""

    def short(data):
        data["simulation"]["duration"] = 0.2
        if edit is not None:
            edit(data)

    data = scenario_dict(short)
    path = tmp_path / name
    path.write_text(tomli_w.dumps(data))
    return path


def setter(path: str, value):
    """An edit setting the dotted key ``path`` to ``value`` (its tables made as needed)."""

    def edit(data):
        *parents, key = path.split(".")
        node = data
        for p in parents:
            node = node.setdefault(p, {})
        node[key] = value

    return edit


# --- arms of the tests' own ----------------------------------------------------------------------

JACO2_CAMERA = "j2s6s200_end_effector"
Q_STAR = np.array([3.1, 2.9, 1.2, 3.1, 3.0, 3.1])
"""A configuration of the limited Jaco2 below within its limits (joints 1, 4, 6 continuous)."""


def limited_jaco2(folder: Path) -> Path:
    """example-robot-data's Kinova Jaco2 (j2s6s200) with joints 2 and 3 limited to 0.15 rad either
    side of 2.9 and 1.2 rad (and joint 5 to its own [0.52, 5.76])."""
    urdf = Path(distribution("example-robot-data").locate_file(
        "cmeel.prefix/share/example-robot-data/robots/kinova_description/robots/kinova.urdf"))  # fmt: skip
    root = ET.parse(urdf).getroot()
    for joint in root.findall("joint"):
        centre = {"j2s6s200_joint_2": 2.9, "j2s6s200_joint_3": 1.2}.get(joint.get("name"))
        if centre is not None:
            joint.find("limit").set("lower", repr(centre - 0.15))
            joint.find("limit").set("upper", repr(centre + 0.15))
    path = folder / "jaco2.urdf"
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


def camera_at(robot: Robot, q: np.ndarray) -> np.ndarray:
    """``g_wc(q)`` by the arm's forward kinematics."""
    return np.asarray(cs.Function("g", [robot.q], [robot.camera_pose.as_matrix()])(q))


def on_urdf(urdf: Path):
    """An edit running the scenario on ``urdf`` (the UR5's camera frame)."""

    def edit(data: dict) -> None:
        data["robot"].pop("model")
        data["robot"].update(urdf=str(urdf), camera_frame="tool0")

    return edit


def as_a_ur5_runs_it(data: dict) -> None:
    """An edit giving the idealised scenario the default example's gains and implementation."""
    default = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["gains"], data["implementation"] = default["gains"], default["implementation"]


Q0 = scenario_dict()["robot"]["q0"]
"""The idealised scenario's start."""

FIVE_JOINTS = Path(__file__).parent / "data" / "light_wrist5.urdf"


def five_joints(data: dict) -> None:
    """An edit running the scenario on a 5-joint arm, the target 0.35 m ahead of its camera, compiled (its run
    from rest does not converge: certify and verify run it to 40 s)."""
    on_urdf(FIVE_JOINTS)(data)
    as_a_ur5_runs_it(data)
    data["simulation"]["jit"] = True
    data["robot"]["q0"] = Q0[:5]
    data["gains"] = {"k_xi": 2.0, "k_c": 3.0, "k_e": 10.0}
    for key in ("xyz", "rpy"):
        data["target"].pop(key)
    data["target"]["relative_to_camera"] = {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}
