"""Recordings are standard MCAP: the official reader and ROS 2 decoder read exactly what we wrote."""

import json
from pathlib import Path

import numpy as np
import pytest
from damage import without_data_crc
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

SPINDLE_TOPICS = {"/amb/gap", "/amb/current", "/amb/error", "/amb/ff", "/amb/accel", "/amb/rotor",
                  "/truth/runout", "/truth/position"}


@pytest.mark.long  # the official reader decodes ambdaq's files by default in test_differential.py
def test_official_decoder_reads_every_message_with_our_values(spindle_file):
    rec = load(spindle_file)
    seen = {t: [] for t in SPINDLE_TOPICS}
    with open(spindle_file, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            seen[channel.topic].append((message.log_time, decoded))
    assert set(seen) == SPINDLE_TOPICS
    for topic, msgs in seen.items():
        data = rec[topic]
        assert len(msgs) == len(data) == 20000  # one message per sample instant, 2 s at 10 kHz
        stamps = np.array([t for t, _ in msgs])
        np.testing.assert_array_equal(stamps, data.log_time)
        for name in data.fields:
            np.testing.assert_array_equal(np.array([getattr(d, name) for _, d in msgs]), data[name])
        np.testing.assert_array_equal(np.array([d.seq for _, d in msgs]), data.seq)
        np.testing.assert_array_equal(np.array([d.device_time for _, d in msgs]), data.device_time)


def test_layout_is_the_contract(spindle_file):
    rec = load(spindle_file)
    gap = rec["/amb/gap"]
    assert list(gap.fields) == ["front_x", "front_y", "rear_x", "rear_y", "axial"]
    assert set(gap.units.values()) == {"m"}
    assert rec["/amb/accel"].units["front_x"] == "m/s^2"
    assert rec["/amb/current"].units["rear_y"] == "A"
    assert rec["/amb/rotor"].units == {"angle": "rad", "speed": "rad/s", "keyphasor": "1"}
    # SI: gaps are tens of micrometres, the rotor runs at 30,000 rpm = 3141.6 rad/s
    assert 1e-6 < np.abs(gap["front_x"]).max() < 1e-4
    np.testing.assert_allclose(rec["/amb/rotor"]["speed"], 30000 * 2 * np.pi / 60)
    # log_time is the host clock, 100 us apart; device time and seq count the samples
    np.testing.assert_array_equal(np.diff(gap.log_time), 100_000)
    np.testing.assert_array_equal(gap.device_time, np.arange(20000) * 100_000)
    np.testing.assert_array_equal(gap.seq, np.arange(20000))
    assert abs(gap.sample_rate - 10_000) < 1e-6


def test_session_device_calibration_and_statistics_are_stored(spindle_file):
    meta = McapFile(spindle_file).metadata()
    assert meta["ambdaq.session"]["ambdaq_version"]
    assert meta["ambdaq.device.rig"]["profile"] == "spindle"
    assert meta["ambdaq.device.rig"]["sample_rate_hz"] == "10000"
    assert meta["ambdaq.calibration.rig"]["gap_sensor_gain_v_per_m"] == "10000"
    stats = {t: json.loads(v) for t, v in meta["ambdaq.statistics"].items()}
    assert set(stats) == SPINDLE_TOPICS
    assert all(s["samples"] == 20000 and s["drops"] == 0 for s in stats.values())


def test_schemas_are_ros2msg_with_cdr(spindle_file):
    with open(spindle_file, "rb") as fh:
        summary = make_reader(fh).get_summary()
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
        assert schema.name.startswith("ambdaq_msgs/msg/")
        assert b"int64 device_time" in schema.data
    assert summary.statistics.message_count == 20000 * len(SPINDLE_TOPICS)
    assert all(ci.compression == "zstd" for ci in summary.chunk_indexes)


def test_chunks_are_cut_at_the_chunk_size_between_sample_instants(spindle_file):
    """The generator hands the writer one 7 MB block per simulated second; the writer cuts it so
    no chunk passes CHUNK_SIZE by more than one instant's records (712 bytes: the reader's speed
    and a damaged chunk's loss depend on it), and each chunk starts on a whole instant."""
    from ambdaq.mcap.mcapfile import CHUNK_SIZE

    f = McapFile(spindle_file)
    chunks = f.summary.chunk_indexes
    sizes = [ci.uncompressed_size for ci in chunks]
    row = 7 * (31 + 60) + (31 + 44)  # seven 5-field topics and /amb/rotor's 3 fields, per instant
    assert sum(sizes) == 20000 * row
    assert max(sizes) <= CHUNK_SIZE + row and len(chunks) >= -(-sum(sizes) // (CHUNK_SIZE + row))
    gap_channel = next(cid for cid, ch in f.summary.channels.items() if ch.topic == "/amb/gap")
    for ci in chunks:  # every chunk holds each topic's messages of the same instants
        assert ci.uncompressed_size % row == 0
        assert f.message_index(ci, gap_channel).shape[0] == ci.uncompressed_size // row


@pytest.fixture(scope="module")
def foxglove(tmp_path_factory):
    """``foxglove(path)``: what Foxglove reads of a file (tests/mcap_reader_check/read.js, @mcap/core
    from npm): which of its readers it takes, each topic's messages and the sum of their first
    field."""
    import subprocess

    from conftest import npm_installed

    folder = npm_installed(tmp_path_factory, Path(__file__).parent / "mcap_reader_check", ("read.js",))

    def read(path):
        r = subprocess.run(["node", "read.js", str(path)], cwd=folder, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout)

    return read


def test_foxglove_s_own_reader_opens_every_message_and_refuses_a_file_without_message_indexes(
        spindle_file, foxglove, tmp_path):
    """What Foxglove opens an indexed file with (@mcap/core's McapIndexedReader, from npm): every
    message of a recording, each topic's count as the summary says, in log-time order.  And why a
    file without indexes has none at all (docs/data-format.md): the same reader refuses a file
    whose chunks have no message indexes but are listed in chunk indexes (written by the official
    Python writer so)."""
    from mcap.writer import CompressionType, IndexType, Writer

    got = foxglove(spindle_file)
    f = McapFile(spindle_file)
    counts = f.summary.statistics.channel_message_counts
    assert got["reader"] == "indexed" and got["ordered"]
    assert got["counts"] == {ch.topic: counts[cid] for cid, ch in f.summary.channels.items() if counts.get(cid)}
    bare = tmp_path / "without_message_indexes.mcap"
    with open(bare, "wb") as fh:
        w = Writer(fh, index_types=IndexType.ALL & ~IndexType.MESSAGE, compression=CompressionType.ZSTD)
        w.start()
        channel = w.register_channel("/t", "json", w.register_schema("t", "jsonschema", b"{}"))
        for i in range(10):
            w.add_message(channel, log_time=1000 + i, publish_time=1000 + i, data=b"{}")
        w.finish()
    assert "without message indexes" in foxglove(bare)["error"]


@pytest.fixture(scope="module")
def unindexed_file(tmp_path_factory) -> Path:
    """The first 0.5 s of ``spindle_file``'s recording (the same command, the same seeds: the
    same samples) written with --no-index."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    out = tmp_path_factory.mktemp("rec") / "spindle_no_index.mcap"
    result = CliRunner().invoke(
        cli, ["sim", "generate", "--duration", "0.5", "--rpm", "30000", "--truth", "--no-index", "-q", "-o", str(out)],
        catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out


def test_a_file_without_indexes_holds_the_same_samples_in_less_than_parquet_s_size(spindle_file, unindexed_file,
                                                                                   tmp_path):
    """--no-index: no Message Index after any chunk and no Chunk Index in the summary (the official
    reader's view of the file), every sample as the indexed file holds it, and the file smaller
    than zstd Parquet of the same columns (what a user would otherwise keep them in)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from mcap.records import MessageIndex
    from mcap.stream_reader import StreamReader

    with open(unindexed_file, "rb") as fh:
        assert make_reader(fh).get_summary().chunk_indexes == []
    from ambdaq.daq.info import describe

    assert describe(unindexed_file)["indexed"] is False and describe(spindle_file)["indexed"] is True
    assert describe(unindexed_file)["chunks"] == len(McapFile(unindexed_file).chunks) >= 1
    with open(unindexed_file, "rb") as fh:
        assert not any(isinstance(r, MessageIndex) for r in StreamReader(fh, skip_magic=False).records)
    ours, indexed = load(unindexed_file), load(spindle_file)
    columns = {}
    for topic, data in ours.items():
        ref, n = indexed[topic], len(data)
        assert n == 5000
        np.testing.assert_array_equal(data.log_time - ours.start_ns, ref.log_time[:n] - indexed.start_ns)
        np.testing.assert_array_equal(data.device_time, ref.device_time[:n])
        np.testing.assert_array_equal(data.seq, ref.seq[:n])
        for name in data.fields:
            np.testing.assert_array_equal(data[name], ref[name][:n])
            columns[f"{topic}/{name}"] = data[name]
        columns.update({f"{topic}/log_time": data.log_time, f"{topic}/device_time": data.device_time,
                        f"{topic}/seq": data.seq, f"{topic}/status": data.status})
    parquet = tmp_path / "same.parquet"
    pq.write_table(pa.table(columns), parquet, compression="zstd")
    indexed_size = spindle_file.stat().st_size * n / 20000  # the indexed file's share of these samples
    assert unindexed_file.stat().st_size < parquet.stat().st_size < indexed_size


def test_the_official_reader_and_foxglove_read_every_sample_of_a_file_without_indexes(unindexed_file, foxglove):
    """The official reader (streaming the file: it has no chunk index to seek by) decodes every
    message with the values load gives; Foxglove takes its stream reader (the file has no chunk
    indexes) and reads every message, each topic's first field summing to what load holds."""
    import math

    rec = load(unindexed_file)
    seen = {t: [] for t in SPINDLE_TOPICS}
    with open(unindexed_file, "rb") as fh:
        for _schema, channel, message, decoded in make_reader(
                fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(log_time_order=False):
            seen[channel.topic].append((message.log_time, decoded))
    for topic, msgs in seen.items():
        data = rec[topic]
        assert len(msgs) == len(data) == 5000
        order = np.argsort([t for t, _ in msgs], kind="stable")
        first = next(iter(data.fields))
        np.testing.assert_array_equal(np.array([getattr(msgs[i][1], first) for i in order]), data[first])
        np.testing.assert_array_equal(np.array([msgs[i][0] for i in order]), data.log_time)
    got = foxglove(unindexed_file)
    assert got["reader"] == "stream"
    assert got["counts"] == {t: 5000 for t in SPINDLE_TOPICS}
    for topic in SPINDLE_TOPICS:
        x = rec[topic][next(iter(rec[topic].fields))]
        # Foxglove's side adds in file order; a sum of n terms differs from the exact one by at
        # most n * eps * sum |x| (recursive summation)
        bound = len(x) * np.finfo(float).eps * float(np.abs(x).sum())
        assert abs(got["sums"][topic] - math.fsum(x)) <= bound


@pytest.mark.parametrize("index", [False, True])
def test_records_that_begin_rows_they_do_not_keep_are_read_by_the_records(tmp_path, index):
    """A chunk is read in place where its first records (without message indexes) or its message
    indexes' counts and first entries say it is rows; one whose later records hold the same sizes
    in another order (as no ambdaq file does) is read again with its fields copied out, found by
    its message indexes or by walking its records: every value under its own channel's name,
    never under the other's."""
    import struct

    from ambdaq.mcap.mcapfile import BlockWriter
    from ambdaq.mcap.schema import CDR_LE_HEADER, TopicLayout
    from ambdaq.drivers.signals import SignalGroup

    path = tmp_path / "swapped.mcap"
    with open(path, "wb") as fh:
        w = BlockWriter(fh, profile="ambdaq", index=index)
        ids = {}
        for topic in ("/a", "/b"):
            layout = TopicLayout(SignalGroup(topic, "Pair", ("x", "y"), ("m", "m")))
            sid = w.add_schema(layout.schema_name, "ros2msg", layout.schema_text.encode())
            ids[topic] = w.add_channel(topic, sid, "cdr", {"device": "d"})

        def record(topic, i):
            sign = 1.0 if topic == "/a" else -1.0
            payload = struct.pack("<IqIIdd", CDR_LE_HEADER, i, i, 0, sign * i, sign * 10 * i)
            return struct.pack("<BQHIQQ", 5, 22 + len(payload), ids[topic], i, 1000 + i, 1000 + i) + payload

        w.add_chunk_records(record("/a", 0) + record("/b", 0) + record("/a", 1) + record("/b", 1)
                            + record("/b", 2) + record("/a", 2))
        w.finish()
    rec = load(path)
    for topic, sign in (("/a", 1.0), ("/b", -1.0)):
        np.testing.assert_array_equal(rec[topic]["x"], sign * np.arange(3))
        np.testing.assert_array_equal(rec[topic]["y"], sign * 10 * np.arange(3))
        np.testing.assert_array_equal(rec[topic].seq, np.arange(3))


def test_a_damaged_record_of_a_file_without_indexes_is_one_line_and_recover_keeps_the_rest(
        unindexed_file, tmp_path, run_cli):
    """With no chunk index, the chunks are found by walking the records: a record length damaged
    so that it runs past the data section stops the walk, which is said (exit 2, naming
    recover), never a file read as if it ended there; recover, which finds chunks by their
    headers, not the length fields, keeps every sample, with the indexes or, asked, without."""
    import struct

    chunks = McapFile(unindexed_file).chunks
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(unindexed_file.read_bytes())
    struct.pack_into("<Q", data, chunks[0].chunk_start_offset + 1, len(data))
    damaged.write_bytes(bytes(data))
    r = run_cli("info", damaged)  # the data section's CRC sees it first
    assert r.exit_code == 2 and "fails its CRC-32" in r.output and "ambdaq recover" in r.output
    damaged.write_bytes(without_data_crc(data))  # as a writer without that CRC leaves it: the walk stops
    r = run_cli("info", damaged)
    assert r.exit_code == 2 and "runs past the data section" in r.output and "ambdaq recover" in r.output
    assert len(r.output.strip().splitlines()) == 1
    original = load(unindexed_file)
    for index in ("--index", "--no-index"):  # the indexes written back, or kept out as recorded
        fixed = tmp_path / f"fixed{index}.mcap"
        r = run_cli("recover", damaged, "-o", fixed, index)
        assert r.exit_code == 0, r.output
        f = McapFile(fixed)
        assert len(f.chunks) == len(chunks) and bool(f.summary.chunk_indexes) == (index == "--index")
        ours = load(fixed)
        for topic, data in original.items():
            for name in data.fields:
                np.testing.assert_array_equal(ours[topic][name], data[name])


def test_a_file_without_a_summary_is_read_by_walking_it(unindexed_file, tmp_path, run_cli):
    """A valid MCAP file need not have a summary (its footer's summary start 0; the official
    stream reader reads it): info, export, plot and load read it by walking its records, with the
    same samples as the file with one, and info says so; only a damaged file names recover."""
    import struct

    from damage import data_end

    data = unindexed_file.read_bytes()
    bare = tmp_path / "bare.mcap"
    bare.write_bytes(data[: data_end(data) + 13] + struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + data[:8])
    r = run_cli("info", bare)
    assert r.exit_code == 0 and "no summary: read by walking its records" in r.output, r.output
    assert "recover" not in r.output
    original, walked = load(unindexed_file), load(bare)
    for topic, got in original.items():
        for name in got.fields:
            np.testing.assert_array_equal(walked[topic][name], got[name])
    r = run_cli("export", bare, "--format", "csv", "--topic", "/amb/gap", "-o", tmp_path / "gap.csv")
    assert r.exit_code == 0, r.output
    r = run_cli("plot", bare, "--topic", "/amb/gap", "--field", "front_x", "-o", tmp_path / "gap.png")
    assert r.exit_code == 0 and (tmp_path / "gap.png").stat().st_size > 10_000, r.output
