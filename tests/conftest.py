"""Shared builders: the paper's idealised UR5 scenario, edited as a TOML dictionary."""

from __future__ import annotations

import copy
import tomllib
import zlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build
from dvfc.analysis.simulate import Settings, Simulator, Trajectory
from dvfc.models.loop import ClosedLoop

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
    for section in ("start", "criterion"):
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


@pytest.fixture
def rng(request: pytest.FixtureRequest) -> np.random.Generator:
    """A generator seeded by the test's own id: what a test draws does not depend on which tests ran
    before it, so a failure reproduces with ``-k``."""
    return np.random.default_rng([20261122, zlib.crc32(request.node.nodeid.encode())])
