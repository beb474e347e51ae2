"""Live 10 kHz spindle over a pseudo-terminal: lost frames and the recorder's CPU.

``ambdaq sim serve`` runs the simulated rig in one process; ``ambdaq record`` records its
controller over the PTY in another.  The recorder's CPU time (user + system, from ``wait4``) over
the recording's wall time is its share of one core; the simulator's share is printed beside it,
measured in the same run, as the baseline.  Target: zero lost frames, recorder <= 25 % of a core.

    python benchmarks/bench_serial_soak.py [--minutes 10]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ambdaq.mcap.mcapfile import McapFile

from _common import row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    args = ap.parse_args()
    seconds = args.minutes * 60
    serve = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--rpm", "30000",
                              "--duration", str(seconds + 60)], stdout=subprocess.PIPE, text=True)
    try:
        pty = serve.stdout.readline().split()[1]
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "soak.mcap"
            t0 = time.monotonic()
            rec = subprocess.Popen([sys.executable, "-m", "ambdaq", "record", "--device", f"serial://{pty}",
                                    "--duration", str(seconds), "--json", "-q", "-o", str(out)],
                                   stdout=subprocess.PIPE, text=True)
            _pid, status, usage = os.wait4(rec.pid, 0)
            wall = time.monotonic() - t0
            summary = json.loads(rec.stdout.read())
            link = McapFile(out).metadata()["ambdaq.link.controller"]
        with open(f"/proc/{serve.pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        tick = os.sysconf("SC_CLK_TCK")
        serve_cpu = (int(fields[11]) + int(fields[12])) / tick
    finally:
        serve.terminate()
        serve.wait(timeout=30)
    cpu = usage.ru_utime + usage.ru_stime
    print(row("recorded samples", summary["samples"], "samples", f"{seconds:.0f} s at 10 kHz"))
    print(row("lost samples (seq gaps)", summary["drops"], "samples"))
    print(row("lost frames / CRC / COBS rejections", int(link["lost_frames"]), "frames",
              f"crc {link['crc_errors']}, cobs {link['cobs_errors']}"))
    print(f"recorder CPU: {cpu:.1f} s over {wall:.1f} s wall = {100 * cpu / wall:.1f} % of one core "
          f"(target <= 25 %); simulator process (baseline, same run): {100 * serve_cpu / wall:.1f} %")


if __name__ == "__main__":
    main()
