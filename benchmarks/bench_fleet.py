"""``fleet scan`` on 1 worker against 2 workers (this machine has 2 cores): files/s, MB/s and the
scaling ratio.

A simulated fleet is generated once (``ambdaq sim fleet``: MACHINES machines x DAYS days of
SECONDS s at 30,000 rpm); each phase scans it into a new dataset with ``ambdaq fleet scan
--workers N`` in its own process, timed by the scan itself (from the first file handed out to the
last row written: the LocalCluster's start-up, 2-4 s, and the workers' imports, about 0.5 s, are
reported beside it, not in it).  Then 2,000 files of one byte each (old: truncated, scanned as rows
with their error) on 2 workers: what a folder of broken files costs per file.

    python benchmarks/bench_fleet.py [--machines 10 --days 16 --seconds 2 --rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
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
    ap.add_argument("--days", type=int, default=16)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp()) / "plant"
    subprocess.run([sys.executable, "-m", "ambdaq", "sim", "fleet", "--machines", str(args.machines), "--days",
                    str(args.days), "--duration", str(args.seconds), "-o", str(folder)], check=True)
    files = sorted(folder.rglob("*.mcap"))
    mb = sum(f.stat().st_size for f in files) / 1e6
    print(f"fleet: {len(files)} recordings, {mb:.1f} MB ({args.seconds:g} s each at 10 kHz)")
    ratios = []
    for r in range(args.rounds):  # interleaved, so a change of the host's load touches both
        seconds = {}
        for workers in (1, 2):
            report, wall = scan(folder, workers)
            assert report["scanned"] == len(files) and not report["errors"], report
            s = seconds[workers] = report["seconds"]
            print(f"round {r + 1}, {workers} worker{'s' if workers > 1 else ' '}: {s:6.2f} s scanning ({wall:5.2f} s "
                  f"with the cluster's start-up, {report['warm_s']:.2f} s of it the workers' imports): "
                  f"{len(files) / s:6.2f} files/s, {mb / s:6.1f} MB/s")
        ratios.append(seconds[1] / seconds[2])
    print(f"scaling 2 workers / 1 worker: {', '.join(f'{x:.2f}' for x in ratios)} (median {statistics.median(ratios):.2f})")
    tiny = Path(tempfile.mkdtemp()) / "tiny"
    tiny.mkdir()
    old = time.time() - 3600
    for i in range(2000):
        (tiny / f"f{i:05d}.mcap").write_bytes(b"x")
        os.utime(tiny / f"f{i:05d}.mcap", (old, old))
    report, wall = scan(tiny, 2)
    assert report["scanned"] == 2000 and len(report["errors"]) == 2000, report
    print(f"2,000 one-byte files, 2 workers: {report['seconds']:.2f} s scanning, "
          f"{report['seconds'] / 2000 * 1e3:.2f} ms per file (each a row with its error)")


if __name__ == "__main__":
    main()
