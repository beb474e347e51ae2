"""Writing throughput: simulator to MCAP, unpaced, every spindle topic, default compression (zstd).

Baseline, measured in the same run: the same messages, already encoded, written one at a time
through the official ``mcap.writer.Writer.add_message`` with the same compression.

    python benchmarks/bench_write.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from mcap.writer import CompressionType, IndexType, Writer

from ambdaq.mcap.mcapfile import McapFile
from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.sim.source import SimSource
from ambdaq.speed import SpeedProfile

from _common import best_of, row


def record(out: Path, seconds: float, truth: bool, fsync: bool = True, index: bool = True) -> None:
    out.unlink(missing_ok=True)
    src = SimSource("spindle", speed=SpeedProfile(30000.0, 30000.0), truth=truth)
    Recorder([src], out, RecordOptions(duration_s=seconds, fsync=fsync, index=index)).run()


def official_writer(src: Path, out: Path, limit: int, index: bool = True) -> tuple[int, float]:
    """Copy the first ``limit`` messages of ``src`` (an indexed file) through Writer.add_message, with
    every index or none: (count, best time in s)."""
    f = McapFile(src)
    msgs = []
    for ci in sorted(f.summary.chunk_indexes, key=lambda c: c.message_start_time):
        records = f.chunk_records(ci)
        for cid in ci.message_index_offsets:
            for log_time, off in f.message_index(ci, cid):
                start = int(off) + 31
                length = int.from_bytes(records[int(off) + 1 : int(off) + 9], "little") - 22
                msgs.append((cid, int(log_time), records[start : start + length]))
        if len(msgs) >= limit:
            break
    msgs.sort(key=lambda m: m[1])
    msgs = msgs[:limit]

    def write() -> None:
        with open(out, "wb") as fh:
            w = Writer(fh, compression=CompressionType.ZSTD, index_types=IndexType.ALL if index else IndexType.NONE)
            w.start(profile="ambdaq")
            for sid, schema in f.summary.schemas.items():
                w.register_schema(schema.name, schema.encoding, schema.data)
            for cid, ch in f.summary.channels.items():
                w.register_channel(ch.topic, ch.message_encoding, ch.schema_id)
            for i, (cid, t, data) in enumerate(msgs):
                w.add_message(cid, log_time=t, data=data, publish_time=t, sequence=i)
            w.finish()

    return len(msgs), best_of(write, repeat=2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per run (10 kHz)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.mcap"
        record(out, 0.1, False)  # warm up: numba cache, imports
        for truth, label in ((False, "6 topics"), (True, "8 topics incl. /truth")):
            topics = 8 if truth else 6
            t = best_of(lambda: record(out, args.seconds, truth))
            ours = args.seconds * 10_000 / t
            n, t_off = official_writer(out, Path(tmp) / "official.mcap", limit=600_000)
            theirs = n / topics / t_off
            print(row(f"ambdaq sim -> MCAP ({label})", ours, "instants/s", f"{ours * topics:,.0f} msgs/s"))
            print(row(f"Writer.add_message, same messages ({label})", theirs, "instants/s", "baseline"))
            print(f"ratio ambdaq / add_message ({label}): {ours / theirs:.1f}x (target >= 5x, >= 200,000 instants/s)")
        # --no-index against the official writer without indexes either (out: the last indexed run's)
        n, t_off = official_writer(out, Path(tmp) / "official.mcap", limit=600_000, index=False)
        bare = Path(tmp) / "bare.mcap"
        ours = args.seconds * 10_000 / best_of(lambda: record(bare, args.seconds, True, index=False))
        theirs = n / 8 / t_off
        print(row("ambdaq sim -> MCAP, --no-index (8 topics)", ours, "instants/s"))
        print(row("Writer.add_message, no indexes, same messages", theirs, "instants/s", "baseline"))
        print(f"ratio ambdaq / add_message, no indexes: {ours / theirs:.1f}x (target >= 5x)")
        t_sync = best_of(lambda: record(out, args.seconds, False, fsync=True))
        t_nosync = best_of(lambda: record(out, args.seconds, False, fsync=False))
        print(row("ambdaq sim -> MCAP, fsync after every flush", args.seconds * 10_000 / t_sync, "instants/s"))
        print(row("ambdaq sim -> MCAP, --no-fsync", args.seconds * 10_000 / t_nosync, "instants/s", "baseline"))
        print(f"ratio fsync / no fsync: {t_nosync / t_sync:.2f}x (the cost of syncing every 0.5 s)")


if __name__ == "__main__":
    main()
