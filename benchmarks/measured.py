"""Run the benchmarks and write what they printed to ``docs/measured.md``: the numbers the docs quote, each a
ratio against a baseline measured in the same run, with the machine they ran on and when.

    python benchmarks/measured.py            every benchmark (``make bench``): the file written anew
    python benchmarks/measured.py NAME ...   these benchmarks: their sections replaced, the others kept
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET = ROOT / "docs" / "measured.md"
BENCHMARKS = ("startup", "simulate", "certify", "margins", "campaign", "cost", "report", "controller_step")
"""The benchmarks of ``benchmarks/``, in the order they are run and written."""

HEADING = "## `benchmarks/{name}.py`"


def measure(name: str) -> str | None:
    """The section of benchmark ``name``: its description and what it printed, stamped with when and where it
    ran; None (its error on standard error) when it failed."""
    script = ROOT / "benchmarks" / f"{name}.py"
    print(f"bench: {script.relative_to(ROOT)}", file=sys.stderr, flush=True)
    run = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True)
    sys.stdout.write(run.stdout)
    if run.returncode != 0:
        sys.stderr.write(run.stderr[-3000:])
        return None
    stamp = (f"Measured on {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {os.cpu_count()} cores, "
             f"Python {platform.python_version()}.")  # fmt: skip
    description = script.read_text().split('"""')[1].strip()
    return "\n".join([HEADING.format(name=name), "", description, "", stamp, "", "```", run.stdout.rstrip(), "```"])


def kept() -> dict[str, str]:
    """The sections of the current ``docs/measured.md``, by benchmark."""
    if not TARGET.exists():
        return {}
    sections = {}
    for part in TARGET.read_text().split("\n## `benchmarks/")[1:]:
        name = part.split(".py`", 1)[0]
        sections[name] = ("## `benchmarks/" + part).rstrip()
    return sections


def main(names: list[str]) -> int:
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        print(f"error: no benchmark {unknown[0]!r} (one of {', '.join(BENCHMARKS)})", file=sys.stderr)
        return 2
    sections = kept() if names else {}
    for name in names or BENCHMARKS:
        if (section := measure(name)) is None:
            return 1
        sections[name] = section
    parts = ["# Measured", "Written by `make bench` (or `python benchmarks/measured.py NAME ...` for some): "
             "measurements, each against a baseline measured in the same run; each section says when and where."]
    parts += [text for name in BENCHMARKS if (text := sections.get(name)) is not None]
    TARGET.write_text("\n\n".join(parts) + "\n")
    print(f"written: {TARGET.relative_to(ROOT)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
