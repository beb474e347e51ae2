"""Real DBC files as their projects ship them (``../shared/corpus/dbc``, none with a cycle time):
recorded as they are, every value what was sent, every file read back by the official MCAP reader
and ROS 2 decoder under field names ROS 2 accepts, the DBC's own names and value tables kept.

The sender is the test's own: cantools encodes the frames and python-can puts them on its virtual
bus, which ambdaq records in this process (no ambdaq code on the sending side).
"""

from __future__ import annotations

import json
import subprocess
from contextlib import contextmanager
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from conftest import npm_installed

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile
from ambdaq.drivers.signals import ros_field

cantools = pytest.importorskip("cantools")
can = pytest.importorskip("can")
pytestmark = pytest.mark.realtime

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "dbc"
FILES = sorted(p.name for p in CORPUS.glob("*.dbc"))
ROSMSG_CHECK = Path(__file__).parent / "rosmsg_check"


def _ways(tree: list) -> list[dict]:
    """Every assignment of multiplexer values a message's signal tree allows (cantools'
    ``signal_tree``), each in tree order: cascaded multiplexers nest, independent ones combine."""
    ways: list[dict] = [{}]
    for node in tree:
        if isinstance(node, dict):
            (name, by_value), = node.items()
            ways = [{**w, name: v, **sub} for w in ways for v, subtree in by_value.items() for sub in _ways(subtree)]
    return ways


def _frames(db) -> list[tuple]:
    """Three frames per message and multiplexer page, each signal at a value of its own range:
    (topic suffix, frame id, data, FD, the values cantools decodes from the data, 29-bit id)."""
    out = []
    for msg in db.messages:
        for way in _ways(msg.signal_tree):
            for k in range(3):
                values = dict(way)
                for s in msg.signals:
                    if s.name in way:
                        continue
                    raw_max = (1 << (s.length - (1 if s.is_signed else 0))) - 1
                    raw = min(raw_max, 3 + 5 * k) * (-1 if s.is_signed and k == 2 else 1)
                    values[s.name] = raw * s.scale + s.offset if not s.is_float else 1.5 * (k + 1)
                data = msg.encode(values, scaling=True, strict=False)
                suffix = msg.name + "".join(f"/m{v}" for v in way.values())
                out.append((suffix, msg.frame_id, data, msg.is_fd, msg.decode(data, decode_choices=False),
                            msg.is_extended_frame))
    return out


CASCADED = """VERSION ""
NS_ :
BS_:
BU_:
BO_ 2147485000 Cascade: 8 Vector__XXX
 SG_ Mode M : 0|8@1+ (1,0) [0|0] "" Vector__XXX
 SG_ Level m1 : 8|8@1+ (0.5,0) [0|0] "mm" Vector__XXX
 SG_ SubMode m2M : 8|8@1+ (1,0) [0|0] "" Vector__XXX
 SG_ Pressure m0 : 16|16@1- (0.1,0) [0|0] "bar" Vector__XXX
 SG_ Flow m1 : 32|16@1+ (0.01,0) [0|0] "l/min" Vector__XXX
SG_MUL_VAL_ 2147485000 Level Mode 1-1;
SG_MUL_VAL_ 2147485000 SubMode Mode 2-2;
SG_MUL_VAL_ 2147485000 Pressure SubMode 0-0;
SG_MUL_VAL_ 2147485000 Flow SubMode 1-1;
"""
"""Cascaded multiplexing (SG_MUL_VAL_), written here (the corpus has none): Mode 1 carries Level;
Mode 2 carries SubMode, which selects Pressure (0) or Flow (1)."""


def _sent_by_topic(frames: list[tuple], device: str) -> dict[str, list[dict]]:
    """What was sent of each topic of ``device`` (``/DEVICE/MESSAGE[/PAGE]``), decoded by cantools,
    from ``_frames``' rows."""
    out: dict[str, list[dict]] = {}
    for suffix, _id, _data, _fd, decoded, _ext in frames:
        out.setdefault(f"/{device}/{suffix}", []).append(decoded)
    return out


@contextmanager
def sending(channel: str, frames: list[tuple[int, bytes, bool]], period_s: float):
    """``frames`` (frame id, data, CAN FD) sent in turn, every ``period_s``, on python-can's virtual
    ``channel`` by a thread of the test's own while the block runs (cantools encoded them: no
    ambdaq code on the sending side)."""
    stop = threading.Event()

    def send() -> None:
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        try:
            while not stop.is_set():
                for frame_id, data, fd, *extended in frames:  # the format: as given, else what the id needs
                    bus.send(can.Message(arbitration_id=frame_id, data=data, is_fd=fd,
                                         is_extended_id=extended[0] if extended else frame_id > 0x7FF))
                time.sleep(period_s)
        finally:
            bus.shutdown()

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        yield
    finally:
        stop.set()
        sender.join(timeout=5)


@pytest.fixture(scope="session")
def foxglove_parser(tmp_path_factory):
    """Foxglove's own ros2msg parser (@foxglove/rosmsg from the npm registry, run by Node)."""
    return npm_installed(tmp_path_factory, ROSMSG_CHECK, ("parse.js",)) / "parse.js"


def _foxglove_reads_every_schema(out: Path, parser: Path) -> None:
    """Every schema of the recording parses with Foxglove's parser, into the fields ambdaq loads,
    of the types the recording holds."""
    rec, summary = load(out), McapFile(out).summary
    schemas = [{"name": s.name, "text": s.data.decode()} for s in summary.schemas.values() if s.encoding == "ros2msg"]
    r = subprocess.run(["node", str(parser)], input=json.dumps(schemas), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    parsed = {p["name"]: p for p in json.loads(r.stdout)}
    assert not [p for p in parsed.values() if "error" in p], parsed
    for channel in summary.channels.values():
        if channel.topic not in rec:
            continue
        data = rec[channel.topic]
        kinds = {"f": "float64", "i": "int64", "u": "uint64"}
        want = [("device_time", "int64"), ("seq", "uint32"), ("status", "uint32")] + [
            (f, kinds[data[f].dtype.kind]) for f in data.fields]
        got = [(d["name"], d["type"]) for d in parsed[summary.schemas[channel.schema_id].name]["fields"]]
        assert got == want, channel.topic


def _record_and_check(path: Path, tmp_path, run_cli, via: str = "virtual", parser: Path | None = None) -> None:
    """Send every frame of ``path``'s messages while ambdaq records it as a DBC device: on a
    virtual bus in this process (``via="virtual"``), or from another process through the simulated
    SLCAN adapter, read by python-can's slcan interface (``via="slcan"``). Each row must be one
    frame's values, the official decoder must read them, and Foxglove's parser (``parser``) every
    schema."""
    db = cantools.database.load_file(str(path))
    frames = _frames(db)
    out = tmp_path / "corpus.mcap"
    if via == "slcan":
        listing = tmp_path / "frames.json"
        listing.write_text(json.dumps([[frame_id, data.hex(), fd, ext] for _s, frame_id, data, fd, _d, ext in frames]))
        sender = subprocess.Popen([sys.executable, str(Path(__file__).with_name("slcan_sender.py")), str(listing), "8"],
                                  stdout=subprocess.PIPE, text=True)
        try:
            tty = sender.stdout.readline().strip()
            r = run_cli("record", "--device", f"can://slcan{tty}?open_delay=0&dbc={path}", "--duration", "1", "-q",
                        "-o", out)
        finally:
            sender.kill()
            sender.wait(timeout=10)
    else:
        channel = f"corpus-{path.name}"
        with sending(channel, [(frame_id, data, fd, ext) for _s, frame_id, data, fd, _d, ext in frames], 0.01):
            r = run_cli("record", "--device", f"can://virtual/{channel}?dbc={path}", "--duration", "1", "-q", "-o", out)
    assert r.exit_code == 0, r.output
    rec = load(out)
    meta = McapFile(out).metadata()
    sent_by_topic = _sent_by_topic(frames, path.stem)
    assert set(rec) == set(sent_by_topic)
    for topic, sent in sent_by_topic.items():
        got = rec[topic]
        assert len(got) > 10, topic
        device = meta[f"ambdaq.device.{path.stem}.{topic.removeprefix(f'/{path.stem}/').replace('/', '.')}"]
        # no GenMsgCycleTime in these files; a page's rate is measured whatever its message declares
        assert device["rate_source"].startswith("none declared") or "measured (none declared" in device["rate_source"]
        original = {f: json.loads(device.get("signals", "{}")).get(f, f) for f in got.fields}
        # each row is one of the frames sent, all its signals from that one frame
        rows = np.column_stack([got[f] for f in got.fields])
        wanted = np.array([[float(d[original[f]]) for f in got.fields] for d in sent])
        for row in rows:
            assert np.any(np.all(row == wanted, axis=1)), (topic, row, wanted)
        # the DBC's value tables are kept beside the numbers, and export --labels writes their text
        tables = json.loads(device.get("value_tables", "{}"))
        for sig in db.get_message_by_name(topic.split("/")[2]).signals:
            if sig.choices and ros_field(sig.name) in got.fields:
                assert tables[ros_field(sig.name)] == {str(int(v)): str(t) for v, t in sig.choices.items()}
        if tables:
            csv = tmp_path / f"{topic.strip('/').replace('/', '_')}.csv"
            r = run_cli("export", out, "--format", "csv", "--topic", topic, "--labels", "-o", csv)
            assert r.exit_code == 0, r.output
            import pandas as pd

            table = pd.read_csv(csv, keep_default_na=False)
            for f, choices in tables.items():
                by_value = {float(k): v for k, v in choices.items()}
                assert list(table[f"{f}_label"]) == [by_value.get(v, "") for v in got[f]], f
    # the official reader and ROS 2 decoder read every topic, under ROS 2 field names
    with open(out, "rb") as fh:
        decoded = {}
        for _schema, channel_, _message, ros in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            decoded.setdefault(channel_.topic, []).append(ros)
    for topic in sent_by_topic:
        got = rec[topic]
        assert len(decoded[topic]) == len(got)
        for f in got.fields:
            assert [getattr(m, f) for m in decoded[topic]] == list(got[f]), (topic, f)
    if parser is not None:
        _foxglove_reads_every_schema(out, parser)


def _file_and_transport() -> list:
    """Every shipped DBC on every transport; the default suite takes each file once, on the virtual
    bus and the SLCAN adapter in turn (so both transports and every file are in it), and ``-m long``
    the other half."""
    ways = []
    for i, name in enumerate(FILES):
        for j, via in enumerate(("virtual", "slcan")):
            marks = () if (i + j) % 2 == 0 else pytest.mark.long
            ways.append(pytest.param(name, via, id=f"{name}-{via}", marks=marks))
    return ways


@pytest.mark.parametrize("name, via", _file_and_transport())
def test_a_shipped_dbc_records_every_value_it_was_sent(name, via, tmp_path, run_cli, foxglove_parser):
    """In this process on a virtual bus, and from another process through an SLCAN adapter on a
    pseudo-terminal (CAN FD frames as SLCAN ``d``/``D`` lines); the schemas (the same either way)
    parsed by Foxglove's parser once."""
    _record_and_check(CORPUS / name, tmp_path, run_cli, via, foxglove_parser if via == "virtual" else None)


def test_cascaded_multiplexing_records_each_page(tmp_path, run_cli):
    """Three pages (Mode 1; Mode 2 with SubMode 0; Mode 2 with SubMode 1), a topic each:
    /cascade/Cascade/m1, /m2/m0, /m2/m1 (a bus thread's KeyError had once ended such a run empty)."""
    path = tmp_path / "cascade.dbc"
    path.write_text(CASCADED)
    _record_and_check(path, tmp_path, run_cli)
    assert set(load(tmp_path / "corpus.mcap")) == {"/cascade/Cascade/m1", "/cascade/Cascade/m2/m0",
                                                   "/cascade/Cascade/m2/m1"}


def test_the_rig_file_gives_a_rate_the_dbc_does_not(tmp_path, run_cli):
    """motohawk.dbc declares no cycle time; the rig file's `rates` gives ExampleMessage 50 Hz: the
    recording says where its rate came from, and holds every frame that came in its second of host
    time (sent every 5 ms: a declared rate is what a message should do, not a count to cut at)."""
    path = CORPUS / "motohawk.dbc"
    db = cantools.database.load_file(str(path))
    msg = db.get_message_by_name("ExampleMessage")
    data = msg.encode({"Enable": 1, "AverageRadius": 0.5, "Temperature": 250.1}, strict=False)
    channel = "corpus-rates"
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[[device]]\nname = "moto"\nurl = "can://virtual/{channel}"\ndbc = "{path}"\n'
                   'rates = {{ ExampleMessage = 50 }}\n'.replace("{{", "{").replace("}}", "}"))
    with sending(channel, [(msg.frame_id, data, False)], 0.005):
        r = run_cli("record", "--rig", rig, "--duration", "1", "--json", "-o", tmp_path / "m.mcap")
    assert r.exit_code == 0, r.output
    device = McapFile(tmp_path / "m.mcap").metadata()["ambdaq.device.moto.ExampleMessage"]
    assert device["rate_source"] == "the rig file" and device["sample_rate_hz"] == "50"
    assert 100 <= len(load(tmp_path / "m.mcap")["/moto/ExampleMessage"]) <= 210  # 1 s of frames 5 ms apart


def test_a_garbled_slcan_line_is_counted_and_the_recording_goes_on(tmp_path, run_cli):
    """An SLCAN adapter (the simulated one, on a pseudo-terminal, read by python-can's slcan
    interface) that sends lines with bytes over 0x7F between motohawk.dbc's frames: each such line
    is counted in the link statistics and skipped; the frames before and after are recorded."""
    import os
    import pty

    from ambdaq.sim.devices.slcan import SimSlcanAdapter

    path = CORPUS / "motohawk.dbc"
    msg = cantools.database.load_file(str(path)).get_message_by_name("ExampleMessage")
    master, slave = pty.openpty()
    adapter = SimSlcanAdapter(master, "garbled-slcan")
    adapter.start()
    port = os.ttyname(slave)
    stop = threading.Event()
    garbled = []

    def send() -> None:
        bus = can.Bus(interface="virtual", channel="garbled-slcan")
        k = 0
        try:
            while not stop.is_set():
                bus.send(can.Message(arbitration_id=msg.frame_id, is_extended_id=False,
                                     data=msg.encode({"Enable": k % 2, "AverageRadius": 0.1 * (k % 10),
                                                      "Temperature": 250.0}, strict=False)))
                if k in (50, 100, 150):  # once the recording runs
                    adapter.send_line(b"t1F3\xff\xfe\x80\r")
                    garbled.append(time.time_ns())
                k += 1
                time.sleep(0.005)
        finally:
            bus.shutdown()

    sender = threading.Thread(target=send, daemon=True)
    try:
        sender.start()
        out = tmp_path / "g.mcap"
        r = run_cli("record", "--device", f"can://slcan{port}?open_delay=0&dbc={path}", "--duration", "1.5", "-q",
                    "-o", out)
    finally:
        stop.set()
        sender.join(timeout=5)
        adapter.stop()
        os.close(slave)
        os.close(master)
    assert r.exit_code == 0, r.output
    got = load(out)["/motohawk/ExampleMessage"]
    link = McapFile(out).metadata()["ambdaq.link.motohawk.ExampleMessage"]
    assert int(link["malformed_frames"]) == len([t for t in garbled if got.log_time[0] < t < got.log_time[-1]]) > 0
    assert got.log_time[-1] > max(garbled) and len(got) > 100  # it went on after the last garbled line
    assert set(got["temperature"]) == {250.0}


def test_a_64_bit_integer_is_recorded_exactly_as_int64(tmp_path, run_cli):
    """signed.dbc's s64 carries 2**60 + 1 and -(2**62) - 3, which float64 cannot hold: the field is
    int64 in the schema and holds both exactly, in ambdaq's reader and in the official ROS 2
    decoder; nothing was rounded, so the link statistics count nothing."""
    path = CORPUS / "signed.dbc"
    msg = cantools.database.load_file(str(path)).get_message_by_name("Message64")
    exact = {(1 << 60) + 1, -(1 << 62) - 3}
    frames = [(msg.frame_id, msg.encode({"s64": v}), False) for v in sorted(exact)]
    assert {msg.decode(d)["s64"] for _i, d, _fd in frames} == exact  # cantools decodes them exactly
    out = tmp_path / "s64.mcap"
    with sending("corpus-int64", frames, 0.005):
        r = run_cli("record", "--device", f"can://virtual/corpus-int64?dbc={path}", "--duration", "0.5", "-q",
                    "-o", out)
    assert r.exit_code == 0, r.output
    got = load(out)["/signed/Message64"]["s64"]
    assert got.dtype == np.int64 and len(got) > 10 and set(got.tolist()) == exact
    assert "int64_values_rounded" not in McapFile(out).metadata()["ambdaq.link.signed.Message64"]
    with open(out, "rb") as fh:
        official = [m.s64 for _s, c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                    .iter_decoded_messages(topics=["/signed/Message64"])]
    assert official == got.tolist()

def test_an_extended_frame_is_not_the_standard_message_of_the_same_number(tmp_path, run_cli):
    """motohawk.dbc's ExampleMessage is the 11-bit frame 0x1F0; a 29-bit frame 0x000001F0 on the
    same bus is another frame (ISO 11898): it is not decoded as ExampleMessage, and is recorded
    among the unknown frames, its format with it."""
    path = CORPUS / "motohawk.dbc"
    msg = cantools.database.load_file(str(path)).get_message_by_name("ExampleMessage")
    assert msg.frame_id == 0x1F0 and not msg.is_extended_frame
    ours = msg.encode({"Enable": 1, "AverageRadius": 0.5, "Temperature": 250.1})
    theirs = msg.encode({"Enable": 0, "AverageRadius": 1.7, "Temperature": 240.0})
    out = tmp_path / "ext.mcap"
    with sending("corpus-extended", [(0x1F0, ours, False, False), (0x1F0, theirs, False, True)], 0.005):
        r = run_cli("record", "--device", f"can://virtual/corpus-extended?dbc={path}&raw=1", "--duration", "0.5",
                    "-q", "-o", out)
    assert r.exit_code == 0, r.output
    rec = load(out)
    got = rec["/motohawk/ExampleMessage"]
    assert len(got) > 10 and set(got["average_radius"]) == {0.5} and set(got["enable"]) == {1.0}
    raw = rec["/can/raw"]
    assert len(raw) > 10 and set(raw["arbitration_id"]) == {0x1F0} and set(raw["extended"]) == {1.0}


HEADER_CLASH = '''VERSION ""
BO_ 256 Health: 3 Vector__XXX
 SG_ Status : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ SEQ : 8|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ HU_date_year : 16|8@1+ (1,2000) [2000|2255] "" Vector__XXX
'''


def test_signals_named_like_the_message_header_keep_their_values_and_names(tmp_path, run_cli):
    """Signals named ``Status`` and ``SEQ`` would be fields ``status`` and ``seq``, members every
    message already has: they are recorded as ``status_value`` and ``seq_value`` (never in place of
    the sample's own), the official decoder reads them, and the DBC's names come back in the Python
    API and ``export --device-names``."""
    path = tmp_path / "health.dbc"
    path.write_text(HEADER_CLASH)
    msg = cantools.database.load_file(str(path)).get_message_by_name("Health")
    data = msg.encode({"Status": 7, "SEQ": 200, "HU_date_year": 2026})
    out = tmp_path / "h.mcap"
    with sending("corpus-header-clash", [(msg.frame_id, data, False)], 0.005):
        r = run_cli("record", "--device", f"can://virtual/corpus-header-clash?dbc={path}", "--duration", "0.5", "-q",
                    "-o", out)
    assert r.exit_code == 0, r.output
    got = load(out)["/health/Health"]
    assert list(got.fields) == ["status_value", "seq_value", "hu_date_year"]
    assert got.names == {"status_value": "Status", "seq_value": "SEQ", "hu_date_year": "HU_date_year"}
    assert set(got["status_value"]) == {7} and set(got["seq_value"]) == {200} and set(got["hu_date_year"]) == {2026}
    np.testing.assert_array_equal(np.diff(got.seq.astype(np.int64)), 1)  # the sample's own sequence number
    with open(out, "rb") as fh:
        official = [(m.seq, m.status_value, m.seq_value) for _s, _c, _m, m in
                    make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    assert official == [(int(s), 7, 200) for s in got.seq]
    csv = tmp_path / "h.csv"
    r = run_cli("export", out, "--format", "csv", "--device-names", "-o", csv)
    assert r.exit_code == 0, r.output
    assert csv.read_text().splitlines()[0] == "time [s],log_time_ns [ns],device_time_ns [ns],seq,Status,SEQ,HU_date_year"


PAGES = """VERSION ""
NS_ :
BS_:
BU_: BMS
BO_ 768 CellVoltages: 8 BMS
 SG_ Page M : 0|8@1+ (1,0) [0|5] "" Vector__XXX
 SG_ Cell_a m0 : 8|16@1+ (0.001,0) [0|65.535] "V" Vector__XXX
 SG_ Cell_b m1 : 8|16@1+ (0.001,0) [0|65.535] "V" Vector__XXX
 SG_ Cell_c m2 : 8|16@1+ (0.001,0) [0|65.535] "V" Vector__XXX
 SG_ Cell_d m3 : 8|16@1+ (0.001,0) [0|65.535] "V" Vector__XXX
 SG_ Cell_e m4 : 8|16@1+ (0.001,0) [0|65.535] "V" Vector__XXX
 SG_ Cell_f m5 : 8|16@1+ (0.001,0) [0|65.535] "V" Vector__XXX
BO_ 769 PackState: 2 BMS
 SG_ SoC : 0|8@1+ (0.5,0) [0|100] "%" Vector__XXX
BO_ 770 Fault: 1 BMS
 SG_ Code : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 100000;
BA_ "GenMsgCycleTime" BO_ 768 100;
BA_ "GenMsgCycleTime" BO_ 769 100000;
BA_ "GenMsgCycleTime" BO_ 770 10;
"""
"""A battery-management DBC as such projects write them: a multiplexed message whose six pages share
its 100 ms cycle, a message declared every 100 s, and a fault message declared every 10 ms that a
healthy pack never sends."""


def test_every_page_is_on_record_whatever_the_declared_cycle(tmp_path, run_cli):
    """Every page of a multiplexed message is recorded whenever its frame comes (a page once waited
    for the declared cycle divided among six pages, and most held nothing after seconds, with "0
    drops in all"); a message declared every 100 s records each frame that comes; a message
    that never comes ends nothing, and is named as never received in the summary and by info."""
    path = tmp_path / "bms.dbc"
    path.write_text(PAGES)
    db = cantools.database.load_file(str(path))
    cells, pack = db.get_message_by_name("CellVoltages"), db.get_message_by_name("PackState")
    frames = [(cells.frame_id, cells.encode({"Page": k, f"Cell_{'abcdef'[k]}": 3.3 + 0.1 * k}), False)
              for k in range(6)] + [(pack.frame_id, pack.encode({"SoC": 81.5}), False)]
    out = tmp_path / "bms.mcap"
    with sending("corpus-pages", frames, 0.02):
        r = run_cli("record", "--device", f"can://virtual/corpus-pages?dbc={path}", "--duration", "2", "--json",
                    "-o", out)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["never_received"] == ["/bms/Fault"]
    rec = load(out)
    for k in range(6):
        page = rec[f"/bms/CellVoltages/m{k}"]
        assert len(page) >= 20 and np.allclose(page[f"cell_{'abcdef'[k]}"], 3.3 + 0.1 * k, atol=5e-4), k  # 1 mV counts
    assert len(rec["/bms/PackState"]) >= 20 and set(rec["/bms/PackState"]["so_c"]) == {81.5}
    assert len(rec["/bms/Fault"]) == 0
    assert "never received" in run_cli("info", out).output
    r = run_cli("record", "--device", f"can://virtual/corpus-pages-quiet?dbc={path}", "--duration", "4", "-o",
                tmp_path / "quiet.mcap")  # nothing on the bus at all for 2 s: said as such
    assert r.exit_code == 1 and "the bus went silent" in r.output, r.output


def test_a_dbc_that_cantools_reads_only_unchecked_is_read_with_a_warning(tmp_path, run_cli):
    """A DBC with one message whose signals overlap (cantools refuses the whole file with its checks
    on) is read as cantools reads it with them relaxed, with one warning line naming what was
    relaxed; its other messages are recorded, every value as sent."""
    path = tmp_path / "overlap.dbc"
    path.write_text('VERSION ""\nBO_ 256 Good: 2 Vector__XXX\n SG_ Level : 0|16@1+ (0.1,0) [0|0] "mm" Vector__XXX\n'
                    'BO_ 257 Overlap: 2 Vector__XXX\n SG_ A : 0|12@1+ (1,0) [0|0] "" Vector__XXX\n'
                    ' SG_ B : 8|8@1+ (1,0) [0|0] "" Vector__XXX\n')
    with pytest.raises(Exception):
        cantools.database.load_file(str(path), strict=True)
    good = cantools.database.load_file(str(path), strict=False).get_message_by_name("Good")
    out = tmp_path / "o.mcap"
    with sending("corpus-overlap", [(good.frame_id, good.encode({"Level": 12.3}), False)], 0.01):
        r = run_cli("record", "--device", f"can://virtual/corpus-overlap?dbc={path}", "--duration", "0.5", "-q",
                    "-o", out)
    assert r.exit_code == 0, r.output
    warned = [line for line in r.output.splitlines() if line.startswith("ambdaq: warning:")]
    assert len(warned) == 1 and "relaxed" in warned[0] and "overlapping" in warned[0], r.output
    got = load(out)["/overlap/Good"]
    assert len(got) > 5 and np.allclose(got["level"], 12.3)


MORE = sorted((CORPUS.parent / "dbc-more").glob("*.dbc"))


@pytest.mark.parametrize("path", MORE, ids=[p.name for p in MORE])
def test_a_dbc_of_a_car_or_radar_project_records_what_was_sent(path, tmp_path, run_cli):
    """Each DBC of ../shared/corpus/dbc-more as shipped (opendbc's car and radar files, cantools'
    J1939, cascaded and extended multiplexing, a 217-message vehicle): read whole, and eight of its
    messages (the multiplexed ones first, then those with the most signals) recorded from a rig
    file while the test sends their frames, every page a topic, every row one frame's values."""
    db = cantools.database.load_file(str(path), strict=False)
    chosen = sorted(db.messages, key=lambda m: (not m.is_multiplexed(), -len(m.signals), m.name))[:8]
    names = {m.name for m in chosen}
    frames = [f for f in _frames(db) if f[0].split("/")[0] in names]
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[[device]]\nname = "car"\nurl = "can://virtual/more-{path.stem}"\ndbc = "{path}"\n'
                   f"messages = {json.dumps(sorted(names))}\n")
    out = tmp_path / "more.mcap"
    with sending(f"more-{path.stem}", [(frame_id, data, fd, ext) for _s, frame_id, data, fd, _d, ext in frames], 0.01):
        r = run_cli("record", "--rig", rig, "--duration", "0.5", "-q", "-o", out)
    assert r.exit_code == 0, r.output
    rec = load(out)
    meta = McapFile(out).metadata()
    sent_by_topic = _sent_by_topic(frames, "car")
    assert set(rec) == set(sent_by_topic)
    for topic, sent in sent_by_topic.items():
        got = rec[topic]
        assert len(got) > 5, topic
        device = meta[f"ambdaq.device.car.{topic.removeprefix('/car/').replace('/', '.')}"]
        original = {f: json.loads(device.get("signals", "{}")).get(f, f) for f in got.fields}
        rows = np.column_stack([got[f] for f in got.fields]) if got.fields else np.empty((len(got), 0))
        wanted = np.array([[float(d[original[f]]) for f in got.fields] for d in sent])
        for row in rows:
            assert np.any(np.all(row == wanted, axis=1)), (topic, row)
