"""CAN through a network gateway in another process: every EDS of the corpus, as shipped, a device
built from it behind a socketcand gateway (``tests/eds_gateway.py``), recorded by python-can's
``socketcand`` interface with the bus's own SYNC master. Each recorded value is the one the device
put in that SYNC's TPDOs, and the gateway's clock, 37.25 s off the host's, is mapped, not trusted."""

from __future__ import annotations

import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile
from ambdaq.errors import BadInputError

sys.path.insert(0, str(Path(__file__).parent))
from eds_gateway import recordable, value_of  # noqa: E402

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "corpus"
EDS_FILES = sorted([*CORPUS.glob("eds/*.eds"), *CORPUS.glob("eds-more/*.eds")])
NODE, RATE, OFFSET_S = 9, 100, 37.25
SIGNALS_PER_TPDO, TPDOS = 2, 2


@contextmanager
def raw_mode_client(server):
    """The connection of the client a hand-written hostile gateway serves: ambdaq's reachability
    check accepted and closed first, then socketcand's handshake (hi, open, rawmode) answered."""
    conn, _ = server.accept()  # ambdaq's reachability check: greeted, as socketcand greets every client
    conn.sendall(b"< hi >")
    conn.close()
    conn, _ = server.accept()
    with conn:
        conn.sendall(b"< hi >")
        conn.recv(100)  # < open can0 >
        conn.sendall(b"< ok >")
        conn.recv(100)  # < rawmode >
        conn.sendall(b"< ok >")
        time.sleep(0.1)
        yield conn


@pytest.fixture
def gateway(request):
    proc = subprocess.Popen([sys.executable, str(Path(__file__).parent / "eds_gateway.py"), str(request.param), str(NODE),
                             str(RATE), str(OFFSET_S)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        yield request.param, int(proc.stdout.readline())
    finally:
        proc.stdin.close()
        proc.wait(timeout=10)


@pytest.mark.skipif(not EDS_FILES, reason="../shared/corpus/eds/ is not beside the clone")
@pytest.mark.parametrize("gateway", [pytest.param(p, id=p.name, marks=() if p.name == "e35.eds" else pytest.mark.long)
                                     for p in EDS_FILES], indirect=True)  # a vendor's file; every one: -m long
def test_every_corpus_eds_through_a_gateway_in_another_process(gateway, tmp_path, run_cli):
    eds, port = gateway
    objects = recordable(eds, SIGNALS_PER_TPDO * TPDOS)
    assert objects, f"{eds.name} has no TPDO-mappable numeric object"
    (tmp_path / eds.name).write_bytes(eds.read_bytes())
    signals = "".join(f'''[[device.signal]]
object = "0x{index:04X}.{sub}"
topic = "/dev/pd"
field = "o{index:04x}_{sub}"
factor = 1
tpdo = {k // SIGNALS_PER_TPDO + 1}
''' for k, (index, sub, _t) in enumerate(objects))
    rig = tmp_path / "rig.toml"
    rig.write_text(f'''name = "gateway"
[[device]]
name = "dev"
url = "can://socketcand/can0?host=127.0.0.1&port={port}&node={NODE}&sync=external"
eds = "{eds.name}"
mapping = "configure"
{signals}''')
    before = time.time_ns()
    out = tmp_path / "gw.mcap"
    r = run_cli("record", "--rig", rig, "--duration", "2", "--json", "-o", out)
    assert r.exit_code == 0, r.output
    after = time.time_ns()
    pd = load(out)["/dev/pd"]
    assert len(pd) > RATE  # two seconds at 100 Hz, less what the start of the stream takes
    # which SYNC each row answers: the counter the device put into its first object (one row per SYNC)
    index, sub, data_type = objects[0]
    counters = np.arange(1, 241)
    first = {value_of(c, index, sub, data_type): c for c in counters}
    counter = np.array([first[v] for v in pd[f"o{index:04x}_{sub}"].tolist()])
    assert np.all(np.diff(counter) % 240 == np.diff(pd.seq.astype(np.int64)) % 240)  # seq steps as the SYNC counter
    for index, sub, data_type in objects:  # every object holds that same SYNC's value, exactly
        expected = [value_of(int(c), index, sub, data_type) for c in counter]
        assert pd[f"o{index:04x}_{sub}"].tolist() == expected, f"0x{index:04X}.{sub}"
    with open(out, "rb") as fh:  # and the official reader and ROS 2 decoder read the same
        official = [m for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                    .iter_decoded_messages(topics=["/dev/pd"])]
    assert [m.seq for m in official] == pd.seq.tolist()
    for field in pd.fields:
        assert [getattr(m, field) for m in official] == pd[field].tolist(), field
    # time: the gateway stamps 37.25 s ahead of the host; the recording is on the host clock
    assert before < pd.log_time[0] and pd.log_time[-1] < after
    # each interval is the gateway's between its SYNCs (the master's period, give or take its own
    # jitter), moved at most by a refinement of the clock map's offset: 0.5 ms on loopback
    np.testing.assert_allclose(np.diff(pd.log_time), np.diff(pd.device_time), atol=0.5e6)
    assert abs(np.median(np.diff(pd.device_time)) * 1e-9 - 1.0 / RATE) < 1e-4
    assert np.all(pd.device_time - pd.log_time > (OFFSET_S - 0.05) * 1e9)  # the gateway's own clock is kept
    device = McapFile(out).metadata()["ambdaq.device.dev"]
    assert device["sync"] == "external"
    # a reply a loaded host delivers after the window is dropped and counted, never kept: what is
    # kept above is right whatever the count, and the gateway's clock was never doubted
    link = McapFile(out).metadata()["ambdaq.link.dev"]
    # (how many a host drops is its load, not ambdaq: 103 of 200 cycles once in a starved fresh clone,
    # whose kept rows were all right; the rows kept are counted above)
    assert link["implausible_time"] == "0" and int(link["late_replies"]) + int(link["ambiguous_cycles"]) < 2 * RATE, link


def test_a_sync_from_ambdaq_through_a_gateway_is_refused(tmp_path, run_cli):
    """The gateway returns none of ambdaq's frames and stamps the rest on its clock: a SYNC ambdaq
    sends could not be timed against the replies. One line, exit 2, nothing written."""
    if not EDS_FILES:
        pytest.skip("../shared/corpus/eds/ is not beside the clone")
    from socketcand_gateway import SimSocketcand

    server = SimSocketcand("refused-gateway")
    server.start()
    try:
        eds = EDS_FILES[0]
        out = tmp_path / "x.mcap"
        r = run_cli("record", "--device", f"can://socketcand/can0?host=127.0.0.1&port={server.port}&node={NODE}"
                    f"&eds={eds}&sync=100", "--duration", "1", "-o", out)
    finally:
        server.stop()
    assert r.exit_code == 2 and "sync=external" in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert not out.exists()


def test_dbc_frames_through_a_gateway_are_on_the_host_clock(tmp_path, run_cli):
    """A DBC device behind the gateway: the frames' values as cantools encoded them, their times
    mapped from the gateway's clock (37.25 s ahead) to the host's."""
    import threading

    import can
    import cantools

    from socketcand_gateway import SimSocketcand

    path = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "dbc" / "motohawk.dbc"
    if not path.is_file():
        pytest.skip("../shared/corpus/dbc/motohawk.dbc is not beside the clone")
    msg = cantools.database.load_file(str(path)).get_message_by_name("ExampleMessage")
    data = msg.encode({"Enable": 1, "AverageRadius": 0.5, "Temperature": 250.1})
    channel = f"gateway-dbc-{time.monotonic_ns()}"
    server = SimSocketcand(channel, clock_offset_s=OFFSET_S)
    server.start()
    stop = threading.Event()

    def send() -> None:
        bus = can.Bus(interface="virtual", channel=channel)
        while not stop.wait(0.01):
            bus.send(can.Message(arbitration_id=msg.frame_id, data=data, is_extended_id=False))
        bus.shutdown()

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    before = time.time_ns()
    try:
        out = tmp_path / "g.mcap"
        r = run_cli("record", "--device", f"can://socketcand/can0?host=127.0.0.1&port={server.port}&dbc={path}",
                    "--duration", "1.5", "-q", "-o", out)
    finally:
        stop.set()
        sender.join(2)
        server.stop()
    after = time.time_ns()
    assert r.exit_code == 0, r.output
    got = load(out)["/motohawk/ExampleMessage"]
    assert len(got) > 50 and set(got["temperature"]) == {msg.decode(data)["Temperature"]}
    assert before < got.log_time[0] and got.log_time[-1] < after  # the host's clock, not the gateway's
    assert np.all(got.device_time - got.log_time > (OFFSET_S - 0.05) * 1e9)


@pytest.mark.parametrize("ending", ["garbage", "close"])
def test_a_hostile_gateway_is_counted_or_one_line_and_the_file_keeps_every_good_frame(tmp_path, run_cli, ending):
    """A gateway that sends 60 good frames, then a byte over 0x7F (counted as a malformed line, the
    recording goes on) or closes the connection (one line, exit 1): the file is finished and holds
    every frame from the recording's start to the last, each as sent."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        with raw_mode_client(server) as conn:
            for i in range(60):
                conn.sendall(f"< frame 1F0 {time.time():.6f} {i:02X}02030405060708 >".encode())
                time.sleep(0.01)
            if ending == "garbage":
                conn.sendall(b"< frame \xff\xfe >")
                time.sleep(1.5)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    dbc = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "dbc" / "motohawk.dbc"
    if not dbc.is_file():
        pytest.skip("../shared/corpus/dbc/motohawk.dbc is not beside the clone")
    out = tmp_path / "h.mcap"
    r = run_cli("record", "--device", f"can://socketcand/can0?host=127.0.0.1&port={port}&dbc={dbc}",
                "--duration", "2", "-q", "-o", out)
    thread.join(5)
    server.close()
    if ending == "garbage":
        assert r.exit_code == 0, r.output
        assert McapFile(out).metadata()["ambdaq.link.motohawk.ExampleMessage"]["malformed_frames"] == "1"
    else:
        assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output  # which says where the file is
        assert "the gateway closed the connection" in r.output and "finished cleanly" in r.output
    import cantools

    msg = cantools.database.load_file(str(dbc)).get_message_by_name("ExampleMessage")
    got = load(out)["/motohawk/ExampleMessage"]["temperature"].tolist()
    expected = [msg.decode(bytes([i, 2, 3, 4, 5, 6, 7, 8]))["Temperature"] for i in range(60)]
    # the frames from the recording's start (a loaded host starts it after the first ones) to the last
    assert len(got) >= 40 and got == expected[len(expected) - len(got):]


def test_a_time_stamp_that_cannot_be_the_gateways_clock_is_not_recorded(tmp_path, run_cli):
    """Among a DBC device's frames a gateway sends one stamped an hour ahead and one stamped
    "nan": neither is recorded or used for the clock (counted as implausible_time), every other
    frame is, and the recording stays on the host clock."""
    import socket
    import threading

    import cantools

    dbc = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "dbc" / "motohawk.dbc"
    if not dbc.is_file():
        pytest.skip("../shared/corpus/dbc/motohawk.dbc is not beside the clone")
    msg = cantools.database.load_file(str(dbc)).get_message_by_name("ExampleMessage")
    frames = [msg.encode({"Enable": 1, "AverageRadius": 0.5, "Temperature": 230 + 0.2 * i}) for i in range(150)]
    sent = [msg.decode(data)["Temperature"] for data in frames]  # each frame's own value
    assert len(set(sent)) == 150
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        with raw_mode_client(server) as conn:
            for i in range(150):
                stamp = {70: f"{time.time() + 3600:.6f}", 71: "nan"}.get(i, f"{time.time():.6f}")
                conn.sendall(f"< frame {msg.frame_id:03X} {stamp} {frames[i].hex().upper()} >".encode())
                time.sleep(0.01)
            time.sleep(1.0)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    out = tmp_path / "t.mcap"
    before = time.time_ns()
    r = run_cli("record", "--device", f"can://socketcand/can0?host=127.0.0.1&port={port}&dbc={dbc}",
                "--duration", "2.2", "-q", "-o", out)
    thread.join(5)
    server.close()
    assert r.exit_code == 0, r.output
    got = load(out)["/motohawk/ExampleMessage"]
    kept = got["temperature"].tolist()
    assert sent[70] not in kept and sent[71] not in kept and len(kept) >= 100
    # every other one, in order, none missing between the first and the last recorded (the recording
    # may start after the gateway's first frames and, on a loaded machine, end before its last)
    expected = [t for i, t in enumerate(sent) if i not in (70, 71)]
    start = expected.index(kept[0])
    assert kept == expected[start:start + len(kept)]
    assert McapFile(out).metadata()["ambdaq.link.motohawk.ExampleMessage"]["implausible_time"] == "2"
    assert before < got.log_time[0] and got.log_time[-1] < time.time_ns()


@pytest.mark.parametrize("clock", ["twice as fast", "walks 0.9 s a frame"])  # half as fast: tests/test_clock.py
def test_a_gateway_clock_that_cannot_be_a_clock_is_refused_never_squeezed(clock, tmp_path, run_cli):
    """A gateway whose time stamps run at twice the host's rate, walk 0.9 s per 10 ms frame, or run
    at half the rate, cannot be timing its frames by a crystal (which keeps within 1,000 ppm): once
    its drift is fitted (3 s of its time) the recording stops with one line naming the device and
    its clock's drift (exit 1); the file is finished and flags the frames timed before by the offset
    alone (the device's clock metadata says why), and a workflow refuses to compute from them."""
    import socket
    import threading

    import cantools

    dbc = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "dbc" / "motohawk.dbc"
    if not dbc.is_file():
        pytest.skip("../shared/corpus/dbc/motohawk.dbc is not beside the clone")
    msg = cantools.database.load_file(str(dbc)).get_message_by_name("ExampleMessage")
    data = msg.encode({"Enable": 1, "AverageRadius": 0.5, "Temperature": 230.0}).hex().upper()
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    stop = threading.Event()

    def serve() -> None:
        with raw_mode_client(server) as conn:
            t0, k = time.time(), 0
            while not stop.is_set():
                now = time.time()
                stamp = {"twice as fast": t0 + 2 * (now - t0), "walks 0.9 s a frame": t0 + 0.9 * k,
                         "half as fast": t0 + 0.5 * (now - t0)}[clock]
                try:
                    conn.sendall(f"< frame {msg.frame_id:03X} {stamp:.6f} {data} >".encode())
                except OSError:
                    return
                k += 1
                time.sleep(0.01)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    out = tmp_path / "c.mcap"
    try:
        r = run_cli("record", "--device", f"can://socketcand/can0?host=127.0.0.1&port={port}&dbc={dbc}",
                    "--duration", "12", "-q", "-o", out)
    finally:
        stop.set()
        thread.join(5)
        server.close()
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
    assert "time stamps cannot be its clock" in r.output and "motohawk.ExampleMessage" in r.output, r.output
    meta = McapFile(out).metadata()  # finished, and it says why
    assert "refused" in meta["ambdaq.clock.motohawk.ExampleMessage"]
    assert "ppm against the host's" in meta["ambdaq.clock.motohawk.ExampleMessage"]["refused"]
    rec = load(out)
    from ambdaq.daq.quality import require_complete

    with pytest.raises(BadInputError, match="could not be its clock"):
        require_complete(rec, ["/motohawk/ExampleMessage"], "a fit")


@pytest.mark.parametrize("after", ["silent", "greets once"])
def test_a_gateway_that_never_finishes_its_handshake_is_one_line(after, tmp_path, run_cli):
    """A gateway that accepts the connection and never says '< hi >', or greets the first client
    and then answers nothing: one line naming it after the handshake's timeout, exit 1, no file
    (it hung the recording until the peer closed)."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    held = []

    def serve() -> None:
        for k in range(3):
            try:
                conn, _ = server.accept()
            except OSError:
                return
            held.append(conn)  # kept open, and silent
            if after == "greets once" and k == 0:
                conn.sendall(b"< hi >")

    threading.Thread(target=serve, daemon=True).start()
    t0 = time.monotonic()
    dbc = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "dbc" / "motohawk.dbc"
    r = run_cli("record", "--device", f"can://socketcand/can0?host=127.0.0.1&port={port}&dbc={dbc}", "--duration",
                "1", "-q", "-o", tmp_path / "g.mcap")
    server.close()
    for conn in held:
        conn.close()
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
    assert f"127.0.0.1:{port}" in r.output and ("said nothing" in r.output or "handshake" in r.output), r.output
    assert time.monotonic() - t0 < 15 and not (tmp_path / "g.mcap").exists()
