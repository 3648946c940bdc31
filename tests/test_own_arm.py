"""A user's own arm: strict JSON outputs, joint position limits, a readable verify table,
arms with fewer than six joints, and consistent figures of runs that stop."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from dvfc.analysis.cli import app

from test_cli import setter, write

runner = CliRunner()


def strict_load(path: Path) -> object:
    """``path`` parsed by a strict JSON parser: NaN and infinities are errors."""

    def refuse(constant: str) -> None:
        raise ValueError(f"{path.name}: {constant} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.mark.parametrize("command", ["simulate", "certify", "verify"])
def test_every_output_file_is_strict_json(command, tmp_path):
    """An uncertified design (k_xi <= 1/2): its claims without a number are null, not NaN."""
    out = tmp_path / "out"
    scenario = write(tmp_path, setter("gains.k_xi", 0.5))
    result = runner.invoke(app, [command, str(scenario), "--out", str(out), "--json", str(tmp_path / "o.json")])
    assert result.exit_code in (0, 1), result.output
    files = [tmp_path / "o.json", *out.glob("*.json")]
    assert len(files) > 1
    for path in files:
        strict_load(path)
