"""Command-line start-up: ``ambdaq --help``, ``--version`` and ``devices`` against ``python -c pass``,
and how soon ``ambdaq sim serve`` has its controller on a pseudo-terminal.

Baseline, measured in the same run: the interpreter starting and doing nothing.  Subcommands are
imported only when they run (cli/main.py), so the help and the version load no numerical library.

    python benchmarks/bench_startup.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

from _common import best_of, row

COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "ambdaq --help": [sys.executable, "-m", "ambdaq", "--help"],
    "ambdaq --version": [sys.executable, "-m", "ambdaq", "--version"],
    "ambdaq devices": [sys.executable, "-m", "ambdaq", "devices"],
    "ambdaq info --help": [sys.executable, "-m", "ambdaq", "info", "--help"],
}


def serve_ready() -> float:
    """Seconds from starting ``ambdaq sim serve`` to the line that names its controller's port
    (what a test or a script waits for before it records)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--rpm", "30000", "--duration", "30"],
                            stdout=subprocess.PIPE, text=True)
    try:
        proc.stdout.readline()
        return time.perf_counter() - t0
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    times = {name: best_of(lambda cmd=cmd: subprocess.run(cmd, capture_output=True, check=True), args.repeat)
             for name, cmd in COMMANDS.items()}
    times["ambdaq sim serve: controller ready"] = best_of(serve_ready, args.repeat)
    base = times["python -c pass"]
    for name, t in times.items():
        print(row(name, t * 1000, "ms", "baseline" if name == "python -c pass" else f"{t / base:.1f}x the baseline"))


if __name__ == "__main__":
    main()
