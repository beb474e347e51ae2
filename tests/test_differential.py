"""Every reading path against the official reader, on files written every way a user can write
or receive them (issue 37).

hypothesis draws a file: who writes it (a simulated rig of each profile through the recorder, split
or not; several devices of random rates, block sizes and integer or float fields through ambdaq's
writer; the official MCAP writer with ambdaq's schema and with JSON and protobuf topics; a file of
``../shared/corpus/mcap``), its chunk compression, message indexes, chunk size, and whether it is
cut where a killed writer would leave it and recovered.  Each is then read by every path ambdaq
has and compared, value for value and bit for bit, with what the official reader and decoders
(``tests/official.py``, no ambdaq code) decode from the same file:

- ``load`` of every topic, of a subset, of the same file twice, and of this file while the arrays
  of another load are held (they must not change);
- ``TopicData.to_pandas()``; ``export`` to CSV (read back by pandas, exact round trip), Parquet
  (pyarrow) and MF4 (asammdf);
- ``info``'s message counts; ``recover``'s output; a fleet row's sample count.

The default suite runs :data:`DEFAULT_EXAMPLES` examples, derandomized (the same on every run);
``pytest -m soak tests/test_differential.py`` runs :data:`SOAK_EXAMPLES` random ones (and the
hypothesis seed it used is printed on a failure).  A failing example's recipe is printed in full.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from official import Topic, as_array, message_counts, official, same_bits

from ambdaq.daq import load
from ambdaq.daq.info import describe
from ambdaq.acquisition.recover import recover
from ambdaq.errors import BadInputError

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "mcap"
PROFILES = ("spindle", "cone", "base-motion", "lorentz")
CODECS = ("zstd", "lz4", "none")
DEFAULT_EXAMPLES = int(os.environ.get("AMBDAQ_DIFFERENTIAL_EXAMPLES", "10"))
SOAK_EXAMPLES = 400
CORPUS_FILES = sorted(p.relative_to(CORPUS).as_posix() for p in CORPUS.rglob("*.mcap")) if CORPUS.is_dir() else []


@dataclass
class Recipe:
    """How one file is written (printed in full when an example fails)."""

    writer: str  # "sim", "devices", "official", "corpus"
    compression: str = "zstd"
    index: bool = True
    chunk_kib: int = 4096
    profile: str = "spindle"
    seconds: float = 0.1
    seed: int = 0
    split: bool = False
    devices: list[tuple[int, int, int, int]] = field(default_factory=list)  # (rate Hz, fields, int fields, block)
    chunking: bool = True  # official writer: chunks, or messages outside chunks
    crcs: bool = True  # official writer: chunk and data CRCs
    corpus: str = ""
    cut: float | None = None  # cut at this fraction of the file (a killed writer), then recovered
    summary: bool = True  # False: the summary left out (a valid MCAP: the footer's summary start 0)


@st.composite
def recipes(draw) -> Recipe:
    writer = draw(st.sampled_from(["sim", "sim", "devices", "official"]))  # the corpus: its own test, below
    r = Recipe(writer, compression=draw(st.sampled_from(CODECS)), index=draw(st.booleans()),
               chunk_kib=draw(st.sampled_from([16, 64, 256, 4096])), seed=draw(st.integers(0, 2**16)))
    if writer == "sim":
        r.profile = draw(st.sampled_from(PROFILES))
        r.seconds = draw(st.sampled_from([0.05, 0.1, 0.2]))
        r.split = draw(st.booleans())
    elif writer == "devices":
        r.devices = draw(st.lists(st.tuples(st.sampled_from([50, 100, 1000, 10000]), st.integers(1, 6),
                                            st.integers(0, 2), st.integers(1, 400)), min_size=1, max_size=4))
    elif writer == "official":
        r.chunking, r.crcs = draw(st.booleans()), draw(st.booleans())
        r.compression = draw(st.sampled_from(["zstd", "lz4", "none"]))
    else:
        r.corpus = draw(st.sampled_from(CORPUS_FILES))
    if writer in ("sim", "devices") and draw(st.integers(0, 3)) == 0:
        r.cut = draw(st.floats(0.3, 0.95))
    elif draw(st.integers(0, 4)) == 0:
        r.summary = False
    return r


# --- writing ------------------------------------------------------------------------------------

T0 = 1_780_000_000_000_000_000


def write(r: Recipe, folder: Path) -> list[Path]:
    """The file(s) ``r`` describes, in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    if r.writer == "corpus":
        target = folder / Path(r.corpus).name
        shutil.copyfile(CORPUS / r.corpus, target)
        return [target]
    path = folder / "rec.mcap"
    if r.writer == "sim":
        from ambdaq.acquisition.recorder import Recorder, RecordOptions
        from ambdaq.sim.source import SimSource
        from ambdaq.speed import SpeedProfile

        speed = SpeedProfile(12000.0, 12000.0) if r.profile in ("spindle", "cone") else SpeedProfile(0.0, 0.0)
        src = SimSource(r.profile, seed=r.seed, speed=speed, truth=r.seed % 2 == 0)
        options = RecordOptions(duration_s=r.seconds, fsync=False, compression=r.compression, index=r.index,
                                chunk_size=r.chunk_kib << 10, split_size=(96 << 10) if r.split else None)
        result = Recorder([src], path, options).run()
        paths = [Path(p) for p in result.files]
    elif r.writer == "devices":
        _devices(r, path)
        paths = [path]
    else:
        _official_writer(r, path)
        paths = [path]
    if not r.summary:
        paths = [_without_summary(p) for p in paths]
    if r.cut is not None:  # as a killed writer leaves it: no summary, no footer, a chunk cut short
        cut = paths[0].with_name("cut.mcap")
        data = paths[0].read_bytes()
        cut.write_bytes(data[: int(len(data) * r.cut)])
        fixed = paths[0].with_name("recovered.mcap")
        recover(cut, fixed, index=r.index)
        paths = [fixed]
    return paths


def _without_summary(path: Path) -> Path:
    """``path`` as a writer that writes no summary leaves it (MCAP allows it): the data section up
    to and with Data End, then a Footer whose summary start and CRC are 0, and the magic."""
    import struct

    from damage import data_end

    data = path.read_bytes()
    end = data_end(data) + 13
    bare = path.with_name(f"bare-{path.name}")
    bare.write_bytes(data[:end] + struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + data[:8])
    return bare


def _devices(r: Recipe, path: Path) -> None:
    """Several devices of their own rates and block sizes, float and 64-bit integer fields, their
    blocks interleaved on the host clock, through ambdaq's writer."""
    from ambdaq.acquisition.writer import RecordingWriter
    from ambdaq.drivers.signals import SampleBlock, SignalGroup

    rng = np.random.default_rng(r.seed)
    w = RecordingWriter(path, fsync=False, compression=r.compression, chunk_size=r.chunk_kib << 10, index=r.index)
    plans = []
    for d, (rate, floats, ints, block) in enumerate(r.devices):
        names = tuple(f"f{k}" for k in range(floats)) + tuple(f"n{k}" for k in range(ints))
        types = ("float64",) * floats + tuple(("int64", "uint64")[k % 2] for k in range(ints))
        group = SignalGroup(f"/dev{d}/values", f"Values{d}", names, ("m",) * floats + ("",) * ints,
                            types if ints else ())
        w.add_device(f"dev{d}", [group], {"url": f"synthetic://dev{d}", "sample_rate_hz": str(rate)}, {})
        plans.append((d, rate, group, block, names, types))
    total = int(0.3 * max(p[1] for p in plans))
    done = {d: 0 for d, *_ in plans}
    while any(done[d] < int(0.3 * rate) for d, rate, *_ in plans):
        for d, rate, group, block, names, types in plans:
            n = min(block, int(0.3 * rate) - done[d])
            if n <= 0:
                continue
            k = np.arange(done[d], done[d] + n)
            host = T0 + k * (1_000_000_000 // rate) + d * 13
            rows = np.zeros(n, dtype=[(nm, "<f8" if t == "float64" else "<i8" if t == "int64" else "<u8")
                                      for nm, t in zip(names, types)])
            for nm, t in zip(names, types):
                if t == "float64":
                    values = rng.standard_normal(n) * 10.0 ** rng.integers(-9, 9)
                    values[rng.random(n) < 0.01] = np.nan
                    rows[nm] = values
                elif t == "int64":
                    rows[nm] = rng.integers(-2**63, 2**63 - 1, n, dtype=np.int64)
                else:
                    rows[nm] = rng.integers(0, 2**64 - 1, n, dtype=np.uint64)
            values = rows if any(t != "float64" for t in types) else rows.view("<f8").reshape(n, len(names))
            w.write(f"dev{d}", SampleBlock(k * (1_000_000_000 // rate), k.astype(np.uint32), {group.topic: values}, host))
            done[d] += n
    assert total > 0
    w.close()


def _official_writer(r: Recipe, path: Path) -> None:
    """The official Python writer: ambdaq's own schema (ros2msg, the fixed CDR layout) beside a JSON
    topic and a protobuf one, chunked or not, with or without its CRCs and indexes."""
    from google.protobuf.timestamp_pb2 import Timestamp
    from google.protobuf.wrappers_pb2 import DoubleValue
    from mcap.writer import CompressionType, IndexType, Writer

    from ambdaq.mcap.schema import TopicLayout
    from ambdaq.drivers.signals import SignalGroup

    rng = np.random.default_rng(r.seed)
    compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[r.compression]
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=r.chunk_kib << 10, compression=compression, use_chunking=r.chunking,
                   enable_crcs=r.crcs, enable_data_crcs=r.crcs,
                   index_types=IndexType.ALL if r.index else IndexType.NONE)
        w.start(profile="", library="the official writer")
        layout = TopicLayout(SignalGroup("/amb/gap", "Gap", ("front_x", "front_y"), ("m", "m")))
        gap = w.register_channel("/amb/gap", "cdr", w.register_schema(layout.schema_name, "ros2msg",
                                                                      layout.schema_text.encode()), {"device": "rig"})
        js = w.register_channel("/json/pose", "json", w.register_schema(
            "Pose", "jsonschema", json.dumps({"type": "object"}).encode()))
        pb_schema = {}
        from mcap_protobuf.schema import build_file_descriptor_set

        for cls in (Timestamp, DoubleValue):
            pb_schema[cls] = w.register_schema(cls.DESCRIPTOR.full_name, "protobuf",
                                               build_file_descriptor_set(cls).SerializeToString())
        stamp = w.register_channel("/pb/stamp", "protobuf", pb_schema[Timestamp])
        value = w.register_channel("/pb/value", "protobuf", pb_schema[DoubleValue])
        for k in range(int(rng.integers(50, 600))):
            t = T0 + k * 100_000
            x = rng.standard_normal(2) * 1e-5
            payload = np.zeros(1, dtype=[("cdr", "<u4"), ("device_time", "<i8"), ("seq", "<u4"), ("status", "<u4"),
                                         ("x", "<f8"), ("y", "<f8")])
            payload[0] = (0x00000100, k * 100_000, k, 0, x[0], x[1])
            w.add_message(gap, log_time=t, data=payload.tobytes(), publish_time=t, sequence=k)
            if k % 3 == 0:
                w.add_message(js, log_time=t + 1, data=json.dumps({"pose": {"x": float(x[0]), "n": k, "ok": k % 2 == 0},
                                                                  "ranges": [k, -k][: 1 + k % 2]}).encode(),
                              publish_time=t, sequence=k)
            if k % 5 == 0:
                w.add_message(stamp, log_time=t + 2, data=Timestamp(seconds=k, nanos=k * 7).SerializeToString(),
                              publish_time=t, sequence=k)
                w.add_message(value, log_time=t + 3, data=DoubleValue(value=float(x[1])).SerializeToString(),
                              publish_time=t, sequence=k)
        w.finish()


# --- comparing ----------------------------------------------------------------------------------


def _canonical(columns: dict[str, np.ndarray]) -> np.ndarray:
    """An order of the rows by log time, ties by their values (messages with one log time may come
    in any order from two readers)."""
    keys = [np.ascontiguousarray(c).view(np.uint64 if c.dtype.itemsize == 8 else np.uint32)
            for name, c in sorted(columns.items()) if name != "@log_time" and c.dtype.itemsize in (4, 8)]
    return np.lexsort([*reversed(keys), columns["@log_time"]])


def compare_topic(topic: str, data, ref: Topic, ambdaq_layout: bool) -> list[str]:
    """Where a loaded topic differs from the official reader's (empty: nowhere)."""
    wrong = []
    if len(data) != ref.count:
        return [f"{topic}: {len(data)} samples, the official reader {ref.count}"]
    theirs = {"@log_time": np.array(ref.log_time, dtype=np.int64)}
    mine = {"@log_time": np.asarray(data.log_time, dtype=np.int64)}
    if ambdaq_layout:  # ambdaq's schema: the header members are TopicData's own columns
        for name, col in (("device_time", data.device_time), ("seq", data.seq), ("status", data.status)):
            mine[name] = np.asarray(col)
            theirs[name] = as_array(ref.values[name], np.asarray(col))
    else:  # another writer's: publish time and sequence
        mine["@publish_time"], theirs["@publish_time"] = np.asarray(data.device_time), np.array(ref.publish_time,
                                                                                                dtype=np.int64)
        mine["@sequence"] = np.asarray(data.seq)
        theirs["@sequence"] = np.array(ref.sequence, dtype=np.int64).astype(np.uint32)
    expected = set(ref.values) - (set(mine) if ambdaq_layout else set())
    got = set(data.fields)
    if got != expected:
        wrong.append(f"{topic}: fields {sorted(got ^ expected)[:5]} differ")
    for name in got & expected:
        mine[name] = np.asarray(data.fields[name])
        theirs[name] = as_array(ref.values[name], mine[name])
    a, b = _canonical(mine), _canonical(theirs)
    for name in mine:
        if name in theirs and not same_bits(mine[name][a], theirs[name][b]):
            bad = int(np.sum(mine[name][a] != theirs[name][b]))
            wrong.append(f"{topic}.{name}: {bad} of {len(data)} values differ")
    return wrong


def compare_load(rec, ref: dict[str, Topic], topics: list[str] | None = None) -> list[str]:
    wrong = []
    own = set(rec._fixed)
    for topic in topics or ref:
        if topic not in rec:
            if topic in ref and ref[topic].values:
                wrong.append(f"{topic}: not loaded")
            continue
        if topic not in ref:  # a topic with no message the official reader decodes: none here either
            if len(rec[topic]):
                wrong.append(f"{topic}: {len(rec[topic])} samples, the official reader decodes none")
            continue
        wrong += compare_topic(topic, rec[topic], ref[topic], topic in own)
    return wrong


def check_exports(rec, ref: dict[str, Topic], out: Path, with_mf4: bool) -> list[str]:
    """CSV, Parquet and MF4 of ``rec`` read back by pandas, pyarrow and asammdf against ``ref``."""
    import pandas as pd
    import pyarrow.parquet as pq

    from ambdaq.daq.export import export, topic_filename
    from ambdaq.daq.mdf import channel_prefix

    wrong = []
    export(rec, "csv", out / "csv")
    export(rec, "parquet", out / "pq")
    for topic in rec:
        data = rec[topic]
        csv = pd.read_csv(out / "csv" / f"{topic_filename(topic)}.csv")  # pandas 3 parses floats exactly
        csv.columns = [c.split(" [")[0] for c in csv.columns]  # the header's "front_x [m]" as the field's name
        table = pq.read_table(out / "pq" / f"{topic_filename(topic)}.parquet")
        for name, col in data.fields.items():
            if not same_bits(csv[name].to_numpy(dtype=col.dtype), np.asarray(col)):
                wrong.append(f"csv {topic}.{name} differs")
            if not same_bits(table.column(name).to_numpy(), np.asarray(col)):
                wrong.append(f"parquet {topic}.{name} differs")
        if not np.array_equal(csv["log_time_ns"].to_numpy(), data.log_time):
            wrong.append(f"csv {topic} log_time differs")
    if with_mf4:
        import asammdf

        export(rec, "mf4", out / "rec.mf4")
        with asammdf.MDF(out / "rec.mf4") as mdf:
            for topic in rec:
                data = rec[topic]
                if not len(data):
                    continue
                for name, col in data.fields.items():
                    if not same_bits(mdf.get(f"{channel_prefix(topic)}.{name}").samples, np.asarray(col)):
                        wrong.append(f"mf4 {topic}.{name} differs")
    return wrong


def differences(r: Recipe, folder: Path, held, paths: list[Path] | None = None) -> list[str]:
    """Every reading path of the file(s) ``r`` writes (or of ``paths``) against the official
    reader; ``held``: the arrays of a load made before, which must not change."""
    wrong = []
    folder.mkdir(parents=True, exist_ok=True)
    for path in paths or write(r, folder):
        ref = official(path)
        counts, info = message_counts(path), describe(path)
        listed = {t["topic"]: t["messages"] for t in info["topics"]}
        for topic in counts.keys() | listed.keys():
            if listed.get(topic, 0) != counts.get(topic, 0):
                wrong.append(f"info: {topic} {listed.get(topic)} messages, the official reader {counts.get(topic, 0)}")
        try:
            rec = load(path)
        except BadInputError as err:
            if any(t.values for t in ref.values()):  # a file with decodable topics must load
                wrong.append(f"{path.name}: load refused it: {err}")
            continue
        wrong += compare_load(rec, ref)
        topics = list(rec)
        if len(topics) > 1:  # a subset, read again
            subset = topics[::2]
            wrong += compare_load(load(path, topics=subset), ref, subset)
        again = load(path)
        wrong += compare_load(again, ref)
        for topic in topics:
            for name in rec[topic].fields:
                if np.shares_memory(rec[topic][name], again[topic][name]):
                    wrong.append(f"two loads share {topic}.{name}")
                    break
            frame = rec[topic].to_pandas()
            for name, col in rec[topic].fields.items():
                if not same_bits(frame[name].to_numpy(), np.asarray(col)):
                    wrong.append(f"to_pandas {topic}.{name} differs")
        wrong += check_exports(rec, ref, folder / f"export-{path.stem}", with_mf4=r.seed % 3 == 0)
        if r.cut is None:  # recover of an intact file: the same messages
            fixed = folder / f"recovered-{path.name}"
            recover(path, fixed, index=r.index)
            if message_counts(fixed) != counts:
                wrong.append(f"recover changed the counts: {message_counts(fixed)} != {counts}")
        if r.writer == "sim" and r.profile == "spindle" and r.seed % 4 == 1 and len(topics):
            from ambdaq.workflows.fleet import scan_recording

            row = scan_recording(path, read_threads=1)
            if row.get("error") is None and row["samples"] != counts.get("/amb/gap"):
                wrong.append(f"fleet row: {row['samples']} samples, /amb/gap holds {counts.get('/amb/gap')}")
    for (topic, name), (array, copy) in held.items():
        if not same_bits(array, copy):
            wrong.append(f"an array held from an earlier load changed: {topic}.{name}")
    return wrong


def _held(tmp: Path) -> dict:
    """Arrays of a load kept through the example (and copies of what they held)."""
    from ambdaq.acquisition.recorder import Recorder, RecordOptions
    from ambdaq.sim.source import SimSource

    path = tmp / "held.mcap"
    if not path.exists():
        Recorder([SimSource("spindle", seed=99)], path, RecordOptions(duration_s=0.1, fsync=False)).run()
    rec = load(path)
    return {(t, n): (rec[t][n], np.array(rec[t][n], copy=True)) for t in rec for n in rec[t].fields}


def _run(r: Recipe, tmp_path_factory) -> None:
    folder = tmp_path_factory.mktemp("diff")
    held = _held(tmp_path_factory.getbasetemp())
    wrong = differences(r, folder, held)
    assert not wrong, f"{r}\n" + "\n".join(wrong[:20])


EXAMPLES = [  # every writer, codec, index choice, split and recovery at least once, whatever is drawn
    Recipe("sim", "lz4", True, 64, "spindle", 0.1, 1),
    Recipe("sim", "none", False, 4096, "cone", 0.1, 2, split=True),
    Recipe("sim", "zstd", False, 16, "base-motion", 0.2, 3, cut=0.6),
    Recipe("sim", "zstd", True, 16, "lorentz", 0.05, 8, cut=0.8),
    Recipe("devices", "lz4", False, 16, devices=[(10000, 3, 2, 37), (100, 1, 1, 5), (1000, 4, 0, 400)], seed=4),
    Recipe("devices", "none", True, 64, devices=[(50, 2, 2, 1)], seed=5, cut=0.7),
    Recipe("official", "zstd", True, 16, chunking=True, crcs=True, seed=6),
    Recipe("official", "lz4", False, 64, chunking=True, crcs=False, seed=7),
    Recipe("official", "none", False, 16, chunking=False, crcs=False, seed=9),
    Recipe("sim", "lz4", False, 64, "spindle", 0.1, 10, summary=False),
    Recipe("devices", "zstd", True, 16, devices=[(1000, 2, 1, 50), (100, 1, 0, 7)], seed=11, summary=False),
]


def _examples(test):
    for r in reversed(EXAMPLES):
        test = example(r=r)(test)
    return test


@settings(max_examples=DEFAULT_EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large])
@given(r=recipes())
@_examples
def test_every_reading_path_equals_the_official_reader(r, tmp_path_factory):
    _run(r, tmp_path_factory)


@pytest.mark.soak
@settings(max_examples=SOAK_EXAMPLES, deadline=None, print_blob=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large])
@given(r=recipes())
def test_soak_every_reading_path_equals_the_official_reader(r, tmp_path_factory):
    _run(r, tmp_path_factory)


@pytest.mark.parametrize("name", CORPUS_FILES)
def test_every_corpus_file_reads_as_the_official_reader_reads_it(name, tmp_path_factory):
    """Each of the 54 foreign files, as shipped (rosbag2's C++ and Go writers, the conformance
    variants of every optional feature): whatever a decoder reads loads as the official reader
    decodes it, info counts every message, and a file with nothing ambdaq reads is one line."""
    _run(Recipe("corpus", corpus=name, seed=1), tmp_path_factory)


@pytest.mark.soak
@settings(max_examples=int(os.environ.get("AMBDAQ_KILLED_EXAMPLES", "40")), deadline=None, print_blob=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(codec=st.sampled_from(CODECS), index=st.booleans(), after=st.floats(0.5, 2.5),
       profile=st.sampled_from(PROFILES))
def test_soak_a_killed_writer_is_recovered_to_what_the_official_reader_reads(codec, index, after, profile,
                                                                             tmp_path_factory):
    """``sim generate`` killed with SIGKILL at a random moment: ``recover`` keeps a file whose every
    reading path equals the official reader's."""
    import signal
    import subprocess
    import sys
    import time

    folder = tmp_path_factory.mktemp("killed")
    path = folder / "killed.mcap"
    cmd = [sys.executable, "-m", "ambdaq", "sim", "generate", "--profile", profile, "--duration", "600",
           "--compression", codec, "-q", "-o", str(path)] + ([] if index else ["--no-index"])
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(after)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    if not path.exists() or path.stat().st_size < 64:
        return  # killed before its first chunk: nothing to recover
    fixed = folder / "fixed.mcap"
    recover(path, fixed, index=index)
    r = Recipe("corpus", compression=codec, index=index, seed=1)
    wrong = differences(r, folder / "read", {}, paths=[fixed])
    assert not wrong, f"{codec} index={index} killed after {after:.2f} s\n" + "\n".join(wrong[:20])
