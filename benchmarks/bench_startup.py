"""Command-line start-up: ``ambdaq --help``, ``--version`` and ``devices`` against ``python -c pass``.

Baseline, measured in the same run: the interpreter starting and doing nothing.  Subcommands are
imported only when they run (cli/main.py), so the help and the version load no numerical library.

    python benchmarks/bench_startup.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import subprocess
import sys

from _common import best_of, row

COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "ambdaq --help": [sys.executable, "-m", "ambdaq", "--help"],
    "ambdaq --version": [sys.executable, "-m", "ambdaq", "--version"],
    "ambdaq devices": [sys.executable, "-m", "ambdaq", "devices"],
    "ambdaq info --help": [sys.executable, "-m", "ambdaq", "info", "--help"],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    times = {name: best_of(lambda cmd=cmd: subprocess.run(cmd, capture_output=True, check=True), args.repeat)
             for name, cmd in COMMANDS.items()}
    base = times["python -c pass"]
    for name, t in times.items():
        print(row(name, t * 1000, "ms", "baseline" if name == "python -c pass" else f"{t / base:.1f}x the baseline"))


if __name__ == "__main__":
    main()
