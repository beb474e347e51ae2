"""Reading a recording into numpy: ``ambdaq.daq.load`` against what a user would otherwise pick.

One 30 s spindle recording with ground truth (300,000 instants, 8 topics, 38 fields) is written
unpaced.  Baselines, measured in the same run:

* pyarrow reading **the same values** (every column ``load`` returns: log time, device time,
  seq, status and the fields of each topic) from a zstd Parquet file, into numpy arrays:
  repeated reads in one process (rounds alternating the two readers), and the first read in a
  fresh process (what a script that reads one file pays; pyarrow's first read warms its thread
  and memory pools);
* the official MCAP reader's ``iter_decoded_messages`` with the official ROS 2 decoder, on the
  first 3 s of the same recording (it decodes one message per Python call).

* the limit: the codec alone inflating the same chunks into a reused buffer (``zstandard``'s
  ``stream_reader``; lz4's ``decompress``; for uncompressed chunks a copy of the records; no ambdaq
  code), on one thread and on two, the work ``load`` cannot avoid; zstd (the default), lz4 and
  none, indexed, and zstd without indexes;
* ``load`` repeated with and without the memory it keeps between loads (``daq/memory.py``): what
  the pool pays on a process that reads file after file.

Then how the chunk compression and size trade file size, write speed and read speed.

    python benchmarks/bench_read.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile
from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.acquisition.writer import RecordingWriter
from ambdaq.sim.source import SimSource
from ambdaq.speed import SpeedProfile
from ambdaq.drivers.signals import SampleBlock, SignalGroup

from _common import best_of, row


ROUNDS = 7


def official(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for _s, _c, _m, _decoded in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            n += 1
    return n


def columns(rec) -> dict[str, np.ndarray]:
    """Every array ``load`` returns, by name: what the Parquet file holds too."""
    out = {}
    for topic, d in rec.items():
        out.update({f"{topic}/log_time": d.log_time, f"{topic}/device_time": d.device_time,
                    f"{topic}/seq": d.seq, f"{topic}/status": d.status})
        out.update({f"{topic}/{k}": v for k, v in d.fields.items()})
    return out


def first_read(setup: str, path: Path) -> float:
    """Seconds the first ``read(path)`` takes in a new Python process after ``setup`` imported it."""
    code = (f"import sys, time; sys.path.insert(0, {str(Path(__file__).parent)!r}); {setup}\n"
            f"t = time.perf_counter(); read({str(path)!r}); print(time.perf_counter() - t)")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    return float(out.split()[-1])


def inflate(path: Path, threads: int) -> float:
    """Best of 3 (s): the chunks' codec alone inflating every chunk of ``path`` into one reused
    buffer per thread, no ambdaq code: zstd's ``stream_reader``, lz4's ``decompress`` (new bytes,
    lz4 inflates into nothing else), for an uncompressed chunk a copy of its records."""
    import lz4.frame
    import zstandard
    from concurrent.futures import ThreadPoolExecutor

    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:  # the chunks as the official reader finds them, still compressed
        frames = [(r.compression, r.data, r.uncompressed_size) for r in StreamReader(f, emit_chunks=True).records
                  if isinstance(r, Chunk)]
    largest = max(size for *_, size in frames)
    buffers = {}

    def one(frame) -> None:
        import threading

        buf = buffers.setdefault(threading.get_ident(), bytearray(largest))
        codec, packed, size = frame
        if codec == "zstd":
            reader, got, view = zstandard.ZstdDecompressor().stream_reader(packed), 0, memoryview(buf)
            while got < size:
                got += reader.readinto(view[got:size])
        elif codec == "lz4":
            lz4.frame.decompress(packed)
        else:
            np.copyto(np.frombuffer(buf, dtype=np.uint8, count=size), np.frombuffer(packed, dtype=np.uint8))

    with ThreadPoolExecutor(max_workers=threads) as pool:
        return best_of(lambda: list(pool.map(one, frames)), repeat=3)


def parquet_read(path: Path) -> dict[str, np.ndarray]:
    table = pq.read_table(path)
    return {name: col.to_numpy() for name, col in zip(table.column_names, table.columns)}


def rewrite(rec, path: Path, compression: str, chunk_size: int, index: bool = True) -> float:
    """Write ``rec``'s samples again, as one device's, through the recorder's writer; returns the
    seconds it took (encoding, compression, the file; no simulation)."""
    path.unlink(missing_ok=True)
    t = time.perf_counter()
    w = RecordingWriter(path, compression=compression, chunk_size=chunk_size, fsync=False, index=index)
    d0 = next(iter(rec.values()))
    w.add_device("rig", [SignalGroup(d.topic, d.topic.strip("/").replace("/", "_"), tuple(d.fields),
                                     tuple(d.units.values())) for d in rec.values()], {}, {})
    step = 10_000
    for a in range(0, len(d0), step):
        b = min(a + step, len(d0))
        w.write("rig", SampleBlock(d0.device_time[a:b], d0.seq[a:b],
                                   {t: np.stack([d.fields[f][a:b] for f in d.fields], axis=1) for t, d in rec.items()},
                                   d0.log_time[a:b]))
    w.close()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds in the file (10 kHz)")
    args = ap.parse_args()
    instants = int(args.seconds * 10_000)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        path = tmp / "run.mcap"
        src = SimSource("spindle", speed=SpeedProfile(30000.0, 30000.0), truth=True)
        Recorder([src], path, RecordOptions(duration_s=args.seconds, fsync=False)).run()
        rec = load(path)
        cols = columns(rec)
        values_mb = sum(v.nbytes for v in cols.values()) / 1e6
        parquet = tmp / "run.parquet"
        pq.write_table(pa.table(cols), parquet, compression="zstd")
        # rounds alternate the two readers, so a busy moment of the machine falls on both
        rounds = [(best_of(lambda: load(path), repeat=3), best_of(lambda: parquet_read(parquet), repeat=3))
                  for _ in range(ROUNDS)]
        t_load, t_pq = (min(r[i] for r in rounds) for i in (0, 1))
        ratios = sorted(a / b for a, b in rounds)
        print(f"{instants:,} instants, {len(cols)} columns, {values_mb:.1f} MB of values")
        print(row("ambdaq.daq.load, zstd MCAP (default)", t_load * 1e3, "ms",
                  f"{path.stat().st_size / 1e6:.1f} MB file, {values_mb / t_load:.0f} MB/s"))
        print(row("pyarrow read_table + to_numpy, zstd Parquet", t_pq * 1e3, "ms",
                  f"{parquet.stat().st_size / 1e6:.1f} MB file, baseline"))
        print(f"ratio load / Parquet read time: best/best {t_load / t_pq:.2f}, per round "
              f"{ratios[0]:.2f}-{ratios[-1]:.2f}, median {ratios[len(ratios) // 2]:.2f} (target <= 1)")
        # the same samples without indexes (--no-index): the file against Parquet's
        bare = tmp / "run_no_index.mcap"
        rewrite(rec, bare, "zstd", 4 << 20, index=False)
        print(f"file sizes: indexed {path.stat().st_size / 1e6:.1f} MB ({path.stat().st_size / parquet.stat().st_size:.2f}x"
              f" Parquet), --no-index {bare.stat().st_size / 1e6:.1f} MB ({bare.stat().st_size / parquet.stat().st_size:.2f}x"
              f" Parquet), Parquet {parquet.stat().st_size / 1e6:.1f} MB (target <= 1)")
        # like against like: load on one thread against the codec on one, on two against two; rounds
        # alternate them, so a busy moment of the machine falls on both
        for codec in ("lz4", "none"):
            rewrite(rec, tmp / f"run_{codec}.mcap", codec, 4 << 20)
        for name, f in (("zstd, indexed", path), ("zstd, --no-index", bare), ("lz4, indexed", tmp / "run_lz4.mcap"),
                        ("none, indexed", tmp / "run_none.mcap")):
            pairs = {n: [(best_of(lambda: load(f, threads=n), repeat=3), inflate(f, n)) for _ in range(3)]
                     for n in (1, 2)}
            for n, runs in pairs.items():
                t_ours, t_zstd = min(a for a, _ in runs), min(b for _, b in runs)
                print(row(f"ambdaq.daq.load, {name}, on {n} thread{'s' if n > 1 else ''}", t_ours * 1e3, "ms"))
                print(row(f"{name.split(',')[0]} alone inflating its chunks on {n} thread{'s' if n > 1 else ''}",
                          t_zstd * 1e3, "ms", "limit"))
                ratios = sorted(a / b for a, b in runs)
                print(f"ratio load / inflation, {name}, on {n}: best/best {t_ours / t_zstd:.2f}, per round "
                      f"{ratios[0]:.2f}-{ratios[-1]:.2f}{' (target <= 1.5)' if name.startswith('zstd') else ''}")

        # the memory kept between loads (daq/memory.py) against fresh memory for every load
        import ambdaq.mcap.memory as memory

        pooled = [best_of(lambda: load(path), repeat=3) for _ in range(3)]
        take = memory._POOL.take
        memory._POOL.take = lambda nbytes: np.empty(nbytes, dtype=np.uint8)
        try:
            fresh = [best_of(lambda: load(path), repeat=3) for _ in range(3)]
        finally:
            memory._POOL.take = take
        print(row("ambdaq.daq.load again, memory kept between loads", min(pooled) * 1e3, "ms"))
        print(row("ambdaq.daq.load again, fresh memory each load", min(fresh) * 1e3, "ms", "baseline"))
        print(f"ratio fresh / kept: {min(fresh) / min(pooled):.2f}")

        # a script that reads one file: the first read in a fresh process (the file in the page
        # cache), each reader's imports done before the clock starts
        first = [(first_read("from ambdaq.daq import load as read", path),
                  first_read("from bench_read import parquet_read as read", parquet)) for _ in range(ROUNDS)]
        f_load, f_pq = (min(r[i] for r in first) for i in (0, 1))
        print(row("first read in a fresh process: ambdaq.daq.load", f_load * 1e3, "ms"))
        print(row("first read in a fresh process: pyarrow", f_pq * 1e3, "ms", "baseline"))
        print(f"ratio first-read times: best/best {f_load / f_pq:.2f}, median "
              f"{sorted(a / b for a, b in first)[ROUNDS // 2]:.2f}")

        short = tmp / "short.mcap"
        src = SimSource("spindle", speed=SpeedProfile(30000.0, 30000.0), truth=True)
        Recorder([src], short, RecordOptions(duration_s=3.0, fsync=False)).run()
        ours = 30_000 / best_of(lambda: load(short), repeat=5)
        theirs = 30_000 / best_of(lambda: official(short), repeat=1)
        print(row("ambdaq.daq.load, 3 s", ours, "instants/s"))
        print(row("iter_decoded_messages, same 3 s", theirs, "instants/s", "baseline"))
        print(f"ratio load / official decoder: {ours / theirs:.0f}x")

        print("\nchunk compression and size (the same samples rewritten; write: encoding and file, no simulation)")
        print(f"{'compression':<20}{'chunk':>8}{'chunks':>8}{'file MB':>10}{'write MB/s':>12}{'load ms':>10}"
              f"{'load / Parquet':>16}")
        for compression, chunk, index in (("zstd", 4 << 20, True), ("zstd", 4 << 20, False), ("zstd", 1 << 20, True),
                                          ("zstd", 2 << 20, True), ("zstd", 8 << 20, True), ("lz4", 4 << 20, True),
                                          ("none", 4 << 20, True)):
            out = tmp / f"re_{compression}_{chunk}_{index}.mcap"
            t_write = min(rewrite(rec, out, compression, chunk, index) for _ in range(2))
            t, t_base = best_of(lambda: load(out), repeat=5), best_of(lambda: parquet_read(parquet), repeat=5)
            chunks = len(McapFile(out).chunks)
            label = compression + ("" if index else ", no index")
            print(f"{label:<20}{chunk >> 10:>6}Ki{chunks:>8}{out.stat().st_size / 1e6:>10.1f}{values_mb / t_write:>12.0f}"
                  f"{t * 1e3:>10.0f}{t / t_base:>16.2f}")


if __name__ == "__main__":
    main()
