"""Start-up: the wall time of `dvfc --help` and of a command's imports (the jobs, their results and their
printing) in a fresh interpreter, each the best of five, against a bare interpreter started in the same run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from timing import best_of

BIN = Path(sys.executable).parent
COMMAND_IMPORTS = "import dvfc.analysis.jobs, dvfc.analysis.show, dvfc.analysis.results"


def main() -> None:
    bare = best_of(lambda: subprocess.run([sys.executable, "-c", "pass"], check=True))
    help_ = best_of(lambda: subprocess.run([str(BIN / "dvfc"), "--help"], check=True, capture_output=True))
    imports = best_of(lambda: subprocess.run([sys.executable, "-c", COMMAND_IMPORTS], check=True))
    print(f"bare interpreter        {bare:6.3f} s (baseline)")
    print(f"dvfc --help             {help_:6.3f} s  {help_ / bare:5.1f}x the baseline")
    print(f"a command's imports     {imports:6.3f} s  {imports / bare:5.1f}x the baseline")


if __name__ == "__main__":
    main()
