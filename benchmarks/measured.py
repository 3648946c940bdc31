"""Run every benchmark and write what it printed to ``docs/measured.md``: the numbers the docs
quote, each a ratio against a baseline measured in the same run, with the machine they ran on."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = ("startup", "simulate", "certify", "margins", "campaign", "report", "controller_step")
"""The benchmarks of ``benchmarks/``, in the order they are run and written."""


def main() -> int:
    parts = [
        "# Measured",
        "",
        f"Written by `make bench` on {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}: measurements, each against a baseline measured in the same run.",
    ]
    for name in BENCHMARKS:
        script = ROOT / "benchmarks" / f"{name}.py"
        print(f"bench: {script.relative_to(ROOT)}", file=sys.stderr, flush=True)
        run = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True)
        sys.stdout.write(run.stdout)
        if run.returncode != 0:
            sys.stderr.write(run.stderr[-3000:])
            return run.returncode
        parts += ["", f"## `benchmarks/{name}.py`", "", (script.read_text().split('"""')[1]).strip(), "", "```",
                  run.stdout.rstrip(), "```"]  # fmt: skip
    target = ROOT / "docs" / "measured.md"
    target.write_text("\n".join(parts) + "\n")
    print(f"written: {target.relative_to(ROOT)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
