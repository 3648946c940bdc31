"""The defaults the command line states in its help (the built-in scenario, a campaign's statistics,
the grid's size limits), held apart from the jobs that use them so that reading them loads no
numerical library: ``dvfc --help`` and a command's option parsing stay light."""

from __future__ import annotations

from pathlib import Path

DEFAULT_SCENARIO = Path(__file__).parent / "scenarios" / "ur5_circle.toml"
"""The built-in default scenario (a copy of ``examples/ur5_circle.toml``)."""

CONFIDENCE, P_FAIL, QUANTILE = 0.95, 0.01, 0.9
"""The defaults of a campaign's statements: the confidence, the P(fail) whose zero-failure run
count is stated, the quantile of the tracking error bounded."""

MAX_GRID_POINTS = 10**8
MAX_GRID_BYTES = 10**9
"""Grids of more points, or whose results are expected to take more bytes on disk, need ``large``."""
