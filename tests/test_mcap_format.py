"""Recordings are standard MCAP: the official reader and ROS 2 decoder read exactly what we wrote."""

import json

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
