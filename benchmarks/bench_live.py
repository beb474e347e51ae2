"""The recorder's CPU and lost samples with and without ``--live`` and one connected Foxglove client.

Each phase runs ``ambdaq record --device sim://spindle --rpm 30000 --duration SECONDS -q --json``
in its own process (the rig's simulation included: the baseline is the same command without
``--live``, so the ratio is what the live view adds); the live phase has one client connected the
whole time (tests/live_client/client.js: @foxglove/ws-protocol under Node, subscribed to the
sampled and the derived topics). CPU is the child process's user + system time.

    python benchmarks/bench_live.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLIENT = Path(__file__).resolve().parent.parent / "tests" / "live_client"
TOPICS = ["/amb/gap", "/amb/current", "/amb/error", "/amb/rotor", "/live/1x", "/live/speed", "/live/orbit/front"]


def client_dir() -> Path:
    d = Path(tempfile.mkdtemp(prefix="ambdaq-live-client-"))
    for name in ("package.json", "client.js"):
        shutil.copy(CLIENT / name, d / name)
    subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--loglevel=error"], cwd=d, check=True)
    return d


def run(seconds: float, live: bool, client: Path | None) -> tuple[float, dict, int]:
    """CPU seconds of the recording process, its summary, and messages the client received."""
    out = Path(tempfile.mkdtemp()) / "b.mcap"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [sys.executable, "-m", "ambdaq", "record", "--device", "sim://spindle", "--rpm", "30000", "--duration",
           str(seconds), "-o", str(out), "--json"] + (["--live", "0"] if live else [])
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    received, node_cpu = 0, 0.0
    if live:
        for line in proc.stderr:
            if "live view on ws://127.0.0.1:" in line:
                port = int(line.split("ws://127.0.0.1:")[1].split()[0])
                break
        mid = resource.getrusage(resource.RUSAGE_CHILDREN)  # the recorder is not reaped yet: not in it
        viewer = subprocess.run(["node", "client.js", f"ws://127.0.0.1:{port}", str(seconds), *TOPICS], cwd=client,
                                capture_output=True, text=True)
        done = resource.getrusage(resource.RUSAGE_CHILDREN)
        node_cpu = (done.ru_utime - mid.ru_utime) + (done.ru_stime - mid.ru_stime)
        received = len(viewer.stdout.splitlines())
    stdout, _ = proc.communicate()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    # the node client is a child too: its CPU is taken out, the recorder's is what is left
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime) - node_cpu
    return cpu, json.loads(stdout), received


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    client = client_dir()
    base_cpu, base, _ = run(args.seconds, False, None)
    t = time.time()
    live_cpu, live, received = run(args.seconds, True, client)
    print(f"{'':<34} {'CPU s':>8} {'% core':>7} {'samples':>9} {'drops':>6}")
    print(f"{'record (baseline)':<34} {base_cpu:>8.2f} {100 * base_cpu / args.seconds:>6.0f}% {base['samples']:>9} "
          f"{base['drops']:>6}")
    print(f"{'record --live, one client':<34} {live_cpu:>8.2f} {100 * live_cpu / args.seconds:>6.0f}% "
          f"{live['samples']:>9} {live['drops']:>6}")
    print(f"ratio {live_cpu / base_cpu:.2f}; the client received {received:,} messages "
          f"({received / args.seconds:,.0f}/s) in {time.time() - t:.0f} s")


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
