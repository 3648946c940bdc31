"""One case: a scenario read, validated and built once, for every job of a command.

A :class:`Case` holds the validated scenario, its closed loop, initial state and simulation
settings, and the gain point the certificates are computed at. Every job (simulate, certify,
verify, margins, report) takes the case; workers receive it by value (pickled as the validated
scenario, so a worker builds the same loop without reading the file again).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np

from dvfc.analysis.certify import GainPoint
from dvfc.analysis.output import provenance
from dvfc.analysis.scenario import DEFAULT_SCENARIO, Scenario, build, design_before, gain_point, load
from dvfc.analysis.simulate import Settings
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop, Mode
from dvfc.models.robot import spans_the_task


@dataclass(frozen=True)
class Case:
    """A scenario built once: ``scenario`` (validated), ``base`` (its folder, for relative
    paths), ``path`` (its file, None when built from a dictionary), ``mode`` (the ``e_e``
    override of the command line, None: the scenario's)."""

    scenario: Scenario
    base: Path
    path: Path | None = None
    mode: Mode | None = None
    check_view: bool = True
    built: tuple[ClosedLoop, np.ndarray, Settings] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "built", build(self.scenario, self.base, mode=self.mode, check_view=self.check_view))

    @classmethod
    def load(cls, path: str | Path = DEFAULT_SCENARIO, *, mode: Mode | None = None, check_view: bool = True) -> Case:
        """Read, validate and build the scenario file ``path`` (:class:`~dvfc.analysis.scenario.ScenarioError`
        naming the field on bad input)."""
        scenario, base = load(path)
        return cls(scenario, base, Path(path), mode, check_view)

    def __reduce__(self):
        """Pickled as the validated scenario (JSON): a worker process builds its loop once, however
        many tasks of the same case it runs (:func:`_unpickled`)."""
        return (_unpickled, (self.scenario.model_dump_json(), self.base, self.path, self.mode, self.check_view))

    def with_scenario(self, scenario: Scenario) -> Case:
        """The same case with another validated scenario (other gains, say), built anew."""
        return Case(scenario, self.base, None, self.mode, self.check_view)

    def provenance(self, command: list[str]) -> dict:
        """Versions, the scenario's SHA-256 (of its file, or of its validated JSON when built
        from a dictionary), ``command`` and the date (:func:`dvfc.analysis.output.provenance`)."""
        content = None if self.path is not None else self.scenario.model_dump_json().encode()
        return provenance(self.path, command, content)

    def with_gains(self, **gains: float | list[float]) -> Case:
        """The same case with some ``[gains]`` entries replaced (``k_xi``, ``k_c``, ``k_e``),
        validated and built anew."""
        data = self.scenario.model_dump()
        data["gains"].update(gains)
        return self.with_scenario(Scenario.model_validate(data))

    def before(self) -> Case | None:
        """The case of the design the scenario's gains were synthesised from (``[synthesized_from]``,
        :func:`~dvfc.analysis.scenario.design_before`), built; None without one."""
        scenario = design_before(self.scenario)
        return None if scenario is None else self.with_scenario(scenario)

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def loop(self) -> ClosedLoop:
        """The closed loop (36), (42) (or the reduced planar one)."""
        return self.built[0]

    @property
    def s0(self) -> np.ndarray:
        """The initial state."""
        return self.built[1]

    @property
    def settings(self) -> Settings:
        """How the loop is simulated, and as what it is implemented."""
        return self.built[2]

    @property
    def planar(self) -> bool:
        """The reduced planar loop (:mod:`dvfc.models.planar`) rather than the paper's."""
        return self.scenario.loop == "planar"

    @property
    def reference(self) -> SE3:
        """The desired relative pose ``g_d``."""
        return self.scenario.reference.se3()

    @property
    def theorems_do_not_apply(self) -> str | None:
        """Why Theorems 1-2 do not apply to the case's loop (the paper's, on an arm with fewer
        than six joints: ``J_b pinv(J_b) != I``), or None."""
        n = self.loop.robot.n
        if self.planar or spans_the_task(n):
            return None
        return f"n = {n} < 6 joints: J_b pinv(J_b) != I, so Theorems 1-2 do not apply to the paper's loop on this arm"

    @property
    def criterion(self) -> tuple[float, float] | None:
        """The scenario's pinned ``[criterion]`` as ``(position m, angle deg)``, or None: what fact 29's
        tracking error at rest is judged against where no other bound is at hand."""
        pinned = self.scenario.criterion
        return None if pinned is None else (pinned.position, pinned.angle_deg)

    @cached_property
    def point(self) -> GainPoint:
        """The scenario's gains and weights as a certifier point."""
        return gain_point(self.scenario, self.loop.robot.n)


@lru_cache(maxsize=4)
def _unpickled(scenario: str, base: Path, path: Path | None, mode: Mode | None, check_view: bool) -> Case:
    """The case of a pickled one, built once per process (its symbolic loop and compiled
    functions are then reused by every task that receives it)."""
    return Case(Scenario.model_validate_json(scenario), base, path, mode, check_view)
