"""Packaging: the metadata an installer reads without warnings."""

from __future__ import annotations

import tomllib
from pathlib import Path

PYPROJECT = tomllib.loads((Path(__file__).parent.parent / "pyproject.toml").read_text())


def test_license_is_an_spdx_expression():
    """PEP 639: ``project.license`` as a table is deprecated (setuptools warns on every
    install); an SPDX string needs setuptools >= 77 to build."""
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause"
    assert "setuptools>=77" in PYPROJECT["build-system"]["requires"]
