"""Packaging: the metadata an installer reads without warnings."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

PYPROJECT = tomllib.loads((Path(__file__).parent.parent / "pyproject.toml").read_text())


def test_license_is_an_spdx_expression():
    """PEP 639: ``project.license`` as a table is deprecated (setuptools warns on every
    install); an SPDX string needs setuptools >= 77 to build."""
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause"
    assert "setuptools>=77" in PYPROJECT["build-system"]["requires"]


HEAVY = ("cvxpy", "control", "matplotlib", "scipy.stats", "scipy.optimize", "SALib", "dask", "weasyprint", "casadi",
         "pyarrow")  # fmt: skip
"""Libraries ``dvfc --help`` must not load: each costs from a tenth of a second to a second to import."""

SOLVERS_AND_PLOTS = ("cvxpy", "control", "matplotlib", "scipy.stats", "scipy.optimize", "SALib", "weasyprint",
                     "pyarrow")  # fmt: skip
"""Libraries a command loads only when its work needs them (the SDPs, the linearised loop's norms, the figures, the
campaign's statistics, the datasets of campaigns and sweeps), not to parse its options or to build the scenario."""


def loaded_after(code: str) -> set[str]:
    """The top modules of ``HEAVY`` in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    probe = f"{code}\nimport sys\nprint(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return set(done.stdout.split())


def test_help_loads_no_numerical_library():
    """``dvfc --help`` (the whole command tree, every option's default and help) imports none of :data:`HEAVY`."""
    code = ("from typer.testing import CliRunner\nfrom dvfc.reports.cli import app\n"
            "assert CliRunner().invoke(app, ['--help']).exit_code == 0\n"
            "assert CliRunner().invoke(app, ['campaign', '--help']).exit_code == 0")  # fmt: skip
    assert loaded_after(code) == set()


def test_a_commands_jobs_and_scenario_load_no_solver_and_no_plotting():
    """The jobs, their printing and a built scenario (what every analysis command imports before its work) leave
    the SDP solvers, python-control, matplotlib and scipy's statistics and optimisers unloaded."""
    code = "import dvfc.analysis.jobs, dvfc.analysis.show\nimport dvfc\ndvfc.load().loop.robot"
    assert loaded_after(code) & set(SOLVERS_AND_PLOTS) == set()


def test_the_lazy_imports_still_load_what_the_work_needs():
    """A certificate imports the SDP solver it runs (so the test above is about when, not whether)."""
    code = "import numpy as np\nfrom dvfc.analysis.certify import sdp_gamma_of\nsdp_gamma_of(np.eye(2), np.eye(2))"
    assert "cvxpy" in loaded_after(code)
