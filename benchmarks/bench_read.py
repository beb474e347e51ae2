"""Reading throughput: MCAP to numpy with ``ambdaq.daq.load``, every topic.

Baseline, measured in the same run on the same file: the official reader's
``iter_decoded_messages`` with the official ROS 2 decoder (``mcap_ros2.decoder.DecoderFactory``).

    python benchmarks/bench_read.py [--seconds 3]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.daq.recorder import Recorder, RecordOptions
from ambdaq.drivers.devices import open_device

from _common import best_of, row


def official(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for _s, _c, _m, decoded in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            n += 1
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated seconds in the file (10 kHz)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for truth, label, topics in ((False, "6 topics", 6), (True, "8 topics incl. /truth", 8)):
            path = Path(tmp) / f"read_{topics}.mcap"
            src = open_device("sim://spindle", speed="30000", truth=truth, paced=False)
            Recorder([src], path, RecordOptions(duration_s=args.seconds)).run()
            instants = int(args.seconds * 10_000)
            load(path)
            ours = instants / best_of(lambda: load(path), repeat=5)
            theirs = instants / best_of(lambda: official(path), repeat=1)
            print(row(f"ambdaq.daq.load ({label})", ours, "instants/s", f"{ours * topics:,.0f} msgs/s"))
            print(row(f"iter_decoded_messages ({label})", theirs, "instants/s", "baseline"))
            print(f"ratio load / official decoder ({label}): {ours / theirs:.0f}x "
                  "(target >= 20x, >= 1,000,000 instants/s)")


if __name__ == "__main__":
    main()
