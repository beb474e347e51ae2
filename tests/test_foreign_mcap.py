"""MCAP files ambdaq did not write (rosbag2's, ``../shared/corpus/mcap``, as shipped): ``load``,
``export`` and ``plot`` take every topic the official ROS 2 decoder reads, each numeric field a
column by its path, checked against what the official reader decodes message by message."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "mcap"


def official(path: Path, topic: str) -> list:
    with open(path, "rb") as fh:
        return [m for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=[topic], log_time_order=True)]


@pytest.mark.parametrize("name", sorted(p.name for p in CORPUS.glob("*.mcap")))
def test_every_topic_of_a_rosbag2_file_loads(name):
    path = CORPUS / name
    rec = load(path)
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert set(rec) == {c.topic for c in summary.channels.values()}
    for topic, data in rec.items():
        assert len(data) == (summary.statistics.channel_message_counts.get(
            next(cid for cid, c in summary.channels.items() if c.topic == topic), 0))


def test_a_log_topic_holds_what_the_official_decoder_reads(tmp_path, run_cli):
    path = CORPUS / "talker.mcap"
    msgs = official(path, "/rosout")
    got = load(path, topics=["/rosout"])["/rosout"]
    assert list(got.fields) == ["stamp.sec", "stamp.nanosec", "level", "line"]
    for column, value in (("stamp.sec", lambda m: m.stamp.sec), ("stamp.nanosec", lambda m: m.stamp.nanosec),
                          ("level", lambda m: m.level), ("line", lambda m: m.line)):
        np.testing.assert_array_equal(got[column], [value(m) for m in msgs])  # integers below 2^53: exact
    assert set(got.skipped) == {"file (str)", "function (str)", "msg (str)", "name (str)"}
    r = run_cli("export", path, "--format", "csv", "--topic", "/rosout", "-o", tmp_path / "rosout.csv")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(tmp_path / "rosout.csv")))
    assert [int(float(row["stamp.sec"])) for row in rows] == [m.stamp.sec for m in msgs]  # 10 digits, exact
    assert [int(float(row["stamp.nanosec"])) for row in rows] == [m.stamp.nanosec for m in msgs]
    r = run_cli("plot", path, "--topic", "/rosout", "--field", "level", "-o", tmp_path / "level.png")
    assert r.exit_code == 0 and (tmp_path / "level.png").stat().st_size > 1000, r.output


def test_nested_arrays_of_records_become_columns_by_path():
    path = CORPUS / "only_topics.mcap"
    msgs = official(path, "/parameter_events")
    got = load(path, topics=["/parameter_events"])["/parameter_events"]
    np.testing.assert_array_equal(got["new_parameters[0].value.type"], [m.new_parameters[0].value.type for m in msgs])
    np.testing.assert_array_equal(got["new_parameters[0].value.bool_value"],
                                  [float(m.new_parameters[0].value.bool_value) for m in msgs])
    assert "node (str)" in got.skipped


def test_a_topic_of_strings_exports_its_times_and_says_what_it_left_out(tmp_path, run_cli):
    r = run_cli("export", CORPUS / "multiple_files_0.mcap", "--format", "csv", "-o", tmp_path / "chatter.csv")
    assert r.exit_code == 0, r.output
    assert "/chatter: not exported (not numbers): data (str)" in r.output
    rows = list(csv.DictReader(open(tmp_path / "chatter.csv")))
    assert len(rows) == 1324 and list(rows[0]) == ["time [s]", "log_time_ns [ns]", "device_time_ns [ns]", "seq"]


def _stream_messages(data: bytes) -> list:
    """The messages the official stream reader reads from ``data`` before it stops."""
    import io

    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    got = []
    try:
        for record in StreamReader(io.BytesIO(data), skip_magic=False).records:
            if isinstance(record, Message):
                got.append((record.channel_id, record.log_time, bytes(record.data)))
    except Exception:  # noqa: BLE001 - the official reader stops however it stops at damage
        pass
    return got


@pytest.mark.parametrize("name", ["multiple_files_0.mcap", "talker.mcap", "only_topics.mcap"])
def test_recover_keeps_what_the_official_stream_reader_reads(name, tmp_path, run_cli):
    """Each rosbag2 file (its schemas and channels inside its chunks) cut at ten offsets and with a
    byte flipped at ten others: `recover` keeps every message the official stream reader reads of
    a cut file, never a message that differs from the original's, and says per topic what it kept."""
    import json

    original = (CORPUS / name).read_bytes()
    intact = {(c, t, d) for c, t, d in _stream_messages(original)}
    for k, frac in enumerate(np.linspace(0.3, 0.97, 10)):
        cut = original[: int(len(original) * frac)]
        (tmp_path / "cut.mcap").write_bytes(cut)
        r = run_cli("recover", tmp_path / "cut.mcap", "-o", tmp_path / f"cut{k}.mcap", "--json")
        assert r.exit_code == 0, r.output
        kept = _stream_messages((tmp_path / f"cut{k}.mcap").read_bytes())
        readable = _stream_messages(cut)
        assert len(kept) == len(readable), (frac, len(kept), len(readable))
        assert set(kept) <= intact
        assert sum(t.get("messages", t.get("samples", 0)) for t in json.loads(r.stdout)["topics"].values()) == len(kept)
    rng = np.random.default_rng(11)
    for k, at in enumerate(rng.integers(8, len(original) - 8, 10)):
        flipped = bytearray(original)
        flipped[at] ^= 0xFF
        (tmp_path / "flip.mcap").write_bytes(bytes(flipped))
        r = run_cli("recover", tmp_path / "flip.mcap", "-o", tmp_path / f"flip{k}.mcap")
        assert r.exit_code in (0, 2), r.output  # 2: the flip hit the magic, it is no MCAP file then
        if r.exit_code == 0:
            assert set(_stream_messages((tmp_path / f"flip{k}.mcap").read_bytes())) <= intact


def test_a_file_without_chunks_or_summary_recovers(tmp_path, run_cli):
    """The official writer without chunking (messages in the data section), cut before its summary:
    `recover` keeps the whole messages before the cut, as the official stream reader reads them,
    and `load` reads the JSON topic's numbers from the result."""
    import json

    from mcap.writer import Writer

    path = tmp_path / "plain.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, use_chunking=False)
        w.start()
        channel = w.register_channel("/pose", "json", w.register_schema("Pose", "jsonschema", b"{}"))
        for i in range(100):
            w.add_message(channel, log_time=10**9 + i * 10**7, publish_time=10**9 + i * 10**7, sequence=i,
                          data=json.dumps({"x": i, "y": [i, 2 * i], "name": "pose"}).encode())
        w.finish()
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    r = run_cli("recover", cut, "-o", tmp_path / "fixed.mcap")
    assert r.exit_code == 0, r.output
    readable = _stream_messages(cut.read_bytes())
    assert 0 < len(readable) < 100 and _stream_messages((tmp_path / "fixed.mcap").read_bytes()) == readable
    got = load(tmp_path / "fixed.mcap")["/pose"]
    np.testing.assert_array_equal(got["x"], np.arange(len(readable)))
    np.testing.assert_array_equal(got["y[1]"], 2 * np.arange(len(readable)))
    assert got.skipped == ("name (str)",)


def test_a_protobuf_file_of_foxglove_s_sdk_holds_what_the_official_decoder_reads(tmp_path, run_cli):
    """Protobuf, as Foxglove's SDK writes it (its own Rust writer, an independent one): every
    numeric field of a Pose and a Log a column by its path, each equal to the official protobuf
    decoder's; the strings listed as skipped; info, export and plot take the file."""
    import foxglove
    from foxglove.channels import LogChannel, PoseChannel
    from foxglove.messages import Log, LogLevel, Pose, Quaternion, Vector3
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders

    path = tmp_path / "sdk.mcap"
    ctx = foxglove.Context()
    writer = foxglove.open_mcap(str(path), context=ctx)
    pose, log = PoseChannel("/robot/pose", context=ctx), LogChannel("/log", context=ctx)
    for i in range(200):
        t = 1_700_000_000_000_000_000 + i * 10_000_000
        pose.log(Pose(position=Vector3(x=0.1 * i, y=-2.5, z=np.sin(i)), orientation=Quaternion(x=0, y=0, z=0, w=1)),
                 log_time=t)
        log.log(Log(message=f"step {i}", level=LogLevel.Warning if i % 7 == 0 else LogLevel.Info, name="n", file="f",
                    line=i), log_time=t)
    writer.close()
    with open(path, "rb") as fh:
        msgs = {}
        for _s, c, _m, m in make_reader(fh, decoder_factories=[ProtobufDecoders()]).iter_decoded_messages(
                log_time_order=True):
            msgs.setdefault(c.topic, []).append(m)
    rec = load(path)
    got = rec["/robot/pose"]
    assert list(got.fields) == ["position.x", "position.y", "position.z", "orientation.x", "orientation.y",
                                "orientation.z", "orientation.w"] and len(got) == 200
    for column in got.fields:  # float64 in protobuf and in the column: equal, not close
        part, name = column.split(".")
        np.testing.assert_array_equal(got[column], [getattr(getattr(m, part), name) for m in msgs["/robot/pose"]])
    logs = rec["/log"]
    np.testing.assert_array_equal(logs["level"], [m.level for m in msgs["/log"]])
    np.testing.assert_array_equal(logs["line"], [m.line for m in msgs["/log"]])
    assert set(logs.skipped) == {"message (str)", "name (str)", "file (str)"}
    info = run_cli("info", path)
    assert info.exit_code == 0 and "/robot/pose" in info.output
    r = run_cli("export", path, "--format", "csv", "--topic", "/robot/pose", "-o", tmp_path / "pose.csv")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(tmp_path / "pose.csv")))
    assert [float(row["position.z"]) for row in rows] == [m.position.z for m in msgs["/robot/pose"]]
    r = run_cli("plot", path, "--topic", "/robot/pose", "--field", "position.z", "-o", tmp_path / "z.png")
    assert r.exit_code == 0 and (tmp_path / "z.png").stat().st_size > 1000, r.output


FIXED = """uint8 flag
float64 value
int32 count
geometry_msgs/Vector3 v
float32[3] arr
uint64 big
int8 LIMIT=3
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""


def test_a_fixed_layout_topic_of_another_writer_is_read_in_blocks_with_the_official_decoder_s_values(tmp_path):
    """A ros2msg topic whose every member is a number, a fixed array or a nested type of such, written
    by the official ROS 2 writer (mcap-ros2-support) beside one with a string: the fixed one is read
    in blocks (CDR alignment: a uint8 then a float64 at 8, a float32 array after three float64, a
    uint64 past 2**53, exact), every value the official decoder's; the other message by message."""
    from mcap_ros2.writer import Writer

    path = tmp_path / "fixed.mcap"
    n = 3000
    with open(path, "wb") as fh:
        w = Writer(fh)
        fixed = w.register_msgdef("my_pkg/msg/Mixed", FIXED)
        note = w.register_msgdef("my_pkg/msg/Note", "string text\nfloat64 value\n")
        for i in range(n):
            w.write_message("/mixed", fixed, {"flag": i % 2, "value": i * 0.25 - 7, "count": -i, "arr": [0.5, 1.5, i / 3],
                                              "v": {"x": np.sin(i), "y": 2.0, "z": -3.5}, "big": 2**63 + 7 * i},
                            log_time=10_000 + 1000 * i, publish_time=5 + i, sequence=i)
            if i % 10 == 0:
                w.write_message("/note", note, {"text": f"n{i}", "value": i}, log_time=10_000 + 1000 * i)
        w.finish()
    msgs = official(path, "/mixed")
    rec = load(path)
    got = rec["/mixed"]
    assert list(got.fields) == ["flag", "value", "count", "v.x", "v.y", "v.z", "arr[0]", "arr[1]", "arr[2]", "big"]
    assert len(got) == n and got["big"].dtype == np.uint64  # the block reader's: 64-bit integers exact
    assert got["big"].tolist() == [m.big for m in msgs]
    for column, value in (("flag", lambda m: m.flag), ("value", lambda m: m.value), ("count", lambda m: m.count),
                          ("v.x", lambda m: m.v.x), ("v.z", lambda m: m.v.z), ("arr[2]", lambda m: m.arr[2])):
        # float32 widened to float64 as the official decoder's Python float is: equal, not close
        np.testing.assert_array_equal(got[column], [value(m) for m in msgs])
    np.testing.assert_array_equal(got.seq, np.arange(n))
    np.testing.assert_array_equal(got.device_time, 5 + np.arange(n))
    notes = rec["/note"]  # a string: the official decoder's path
    assert notes.skipped == ("text (str)",) and notes["value"].tolist() == list(range(0, n, 10))
    window = load(path, topics=["/mixed"], start=0.5e-3, end=1.0e-3)["/mixed"]  # the same window either path
    assert window["count"].tolist() == [-i for i in range(500, 1001)]


def test_a_file_of_another_writer_without_chunk_indexes_loads_every_message(tmp_path):
    """The official writer without indexes (the MCAP specification makes them optional): its
    chunks are found by walking the file.  ambdaq 0.1 loaded no sample of such a file and said
    nothing."""
    import struct

    from mcap.writer import CompressionType, IndexType, Writer

    path = tmp_path / "no_indexes.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, index_types=IndexType.NONE, compression=CompressionType.ZSTD, chunk_size=512)
        w.start("ros2", "test")
        sid = w.register_schema("pkg/msg/Pair", "ros2msg", b"float64 x\nint32 n")
        cid = w.register_channel("/pair", "cdr", sid)
        for i in range(100):  # CDR: the encapsulation header, the float64, the int32
            w.add_message(cid, log_time=1000 + i, publish_time=1000 + i, data=struct.pack("<4sdi", b"\0\1\0\0", i / 2, i))
        w.finish()
    with open(path, "rb") as fh:
        assert make_reader(fh).get_summary().chunk_indexes == []
    pair = load(path)["/pair"]
    np.testing.assert_array_equal(pair["x"], np.arange(100) / 2)
    np.testing.assert_array_equal(pair["n"], np.arange(100))
    np.testing.assert_array_equal(pair.log_time, 1000 + np.arange(100))
