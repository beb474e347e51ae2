"""``fleet scan`` on 1 worker against 2 workers (this machine has 2 cores): files/s, MB/s and the
scaling ratio.

A simulated fleet is generated once (``ambdaq sim fleet``: MACHINES machines x DAYS days of
SECONDS s at 30,000 rpm); each phase scans it into a new dataset with ``ambdaq fleet scan
--workers N`` in its own process, timed by the scan itself (from the first task submitted to the
last row written: the LocalCluster's start-up, 2-4 s, is reported beside it, not in it).

    python benchmarks/bench_fleet.py [--machines 10 --days 8 --seconds 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def scan(folder: Path, workers: int) -> tuple[dict, float]:
    ds = Path(tempfile.mkdtemp()) / "fleet.parquet"
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "ambdaq", "fleet", "scan", str(folder), "-o", str(ds),
                          "--workers", str(workers), "--json"], capture_output=True, text=True, check=True)
    return json.loads(res.stdout), time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--machines", type=int, default=10)
    ap.add_argument("--days", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=2.0)
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp()) / "plant"
    subprocess.run([sys.executable, "-m", "ambdaq", "sim", "fleet", "--machines", str(args.machines), "--days",
                    str(args.days), "--duration", str(args.seconds), "-o", str(folder)], check=True)
    files = sorted(folder.rglob("*.mcap"))
    mb = sum(f.stat().st_size for f in files) / 1e6
    print(f"fleet: {len(files)} recordings, {mb:.1f} MB ({args.seconds:g} s each at 10 kHz)")
    rates = {}
    for workers in (1, 2):
        report, wall = scan(folder, workers)
        assert report["scanned"] == len(files) and not report["errors"], report
        s = report["seconds"]
        rates[workers] = len(files) / s
        print(f"{workers} worker{'s' if workers > 1 else ' '}: {s:6.2f} s scanning ({wall:5.2f} s with the cluster's "
              f"start-up): {len(files) / s:6.2f} files/s, {mb / s:6.1f} MB/s")
    print(f"scaling 2 workers / 1 worker: {rates[2] / rates[1]:.2f}")


if __name__ == "__main__":
    main()
