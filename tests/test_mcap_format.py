"""Recordings are standard MCAP: the official reader and ROS 2 decoder read exactly what we wrote."""

import json
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.daq.mcapfile import McapFile

SPINDLE_TOPICS = {"/amb/gap", "/amb/current", "/amb/error", "/amb/ff", "/amb/accel", "/amb/rotor",
                  "/truth/runout", "/truth/position"}


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
    from ambdaq.daq.mcapfile import CHUNK_SIZE

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


def test_foxglove_s_own_reader_opens_every_message_and_refuses_a_file_without_message_indexes(
        spindle_file, tmp_path_factory, tmp_path):
    """What Foxglove opens an indexed file with (@mcap/core's McapIndexedReader, from npm): every
    message of a recording, each topic's count as the summary says, in log-time order.  And why the
    Message Indexes stay in ambdaq's files although they are 36 % of them (docs/performance.md):
    the same reader refuses a file whose chunks have none (written by the official Python writer
    without them)."""
    import subprocess

    from mcap.writer import CompressionType, IndexType, Writer

    from conftest import npm_installed

    folder = npm_installed(tmp_path_factory, Path(__file__).parent / "mcap_reader_check", ("read.js",))

    def read(path):
        r = subprocess.run(["node", "read.js", str(path)], cwd=folder, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout)

    got = read(spindle_file)
    f = McapFile(spindle_file)
    counts = f.summary.statistics.channel_message_counts
    assert got["ordered"] and got["counts"] == {ch.topic: counts[cid] for cid, ch in f.summary.channels.items()
                                                if counts.get(cid)}
    bare = tmp_path / "without_message_indexes.mcap"
    with open(bare, "wb") as fh:
        w = Writer(fh, index_types=IndexType.ALL & ~IndexType.MESSAGE, compression=CompressionType.ZSTD)
        w.start()
        channel = w.register_channel("/t", "json", w.register_schema("t", "jsonschema", b"{}"))
        for i in range(10):
            w.add_message(channel, log_time=1000 + i, publish_time=1000 + i, data=b"{}")
        w.finish()
    assert "without message indexes" in read(bare)["error"]
