"""XCP: optional is optional, and every session ends with DISCONNECT.

The slave here is a small XCP-on-TCP server written in the test (framing by ``tests/xcp_tcp.py``):
one cyclic 1 ms event, relative ODT identification with a DAQ byte, a 4-byte timestamp in us, and
a ULONG at 0x1000 that counts its ticks.  It serves **one master at a time**, as a slave release
still in the field does: a CONNECT while another master's session is open gets no answer, until
that session ends with DISCONNECT (closing the socket is not enough).  Each case makes it answer
ERR_CMD_UNKNOWN to one of the commands ASAM XCP makes optional; the A2L declares in its IF_DATA
XCP what that command would have said, so the recording must go on from the A2L, say which
command was lacking, and leave the slave free for the next master.
"""

from __future__ import annotations

import json
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from xcp_tcp import commands

from ambdaq.daq import load

pytestmark = pytest.mark.realtime

A2L = """ASAP2_VERSION 1 71
/begin PROJECT OPTIONAL_TEST ""
  /begin MODULE M ""
    /begin MEASUREMENT ticks "counts the event's ticks" ULONG NO_COMPU_METHOD 0 0 0 4294967295
      ECU_ADDRESS 0x1000
      /begin IF_DATA XCP /begin DAQ_EVENT FIXED_EVENT_LIST EVENT 0x0 /end DAQ_EVENT /end IF_DATA
    /end MEASUREMENT
    /begin IF_DATA XCP
      /begin DAQ
        DYNAMIC 0 1 0 OPTIMISATION_TYPE_DEFAULT ADDRESS_EXTENSION_FREE IDENTIFICATION_FIELD_TYPE_RELATIVE_BYTE
        GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE 0xF8 NO_OVERLOAD_INDICATION
        /begin TIMESTAMP_SUPPORTED 0x1 SIZE_DWORD UNIT_1US /end TIMESTAMP_SUPPORTED
        /begin EVENT "tick" "tick" 0x0 DAQ 0xFF 1 6 0 /end EVENT
      /end DAQ
    /end IF_DATA
  /end MODULE
/end PROJECT
"""
OPTIONAL = {0xFB: "GET_COMM_MODE_INFO", 0xFA: "GET_ID", 0xDA: "GET_DAQ_PROCESSOR_INFO",
            0xD9: "GET_DAQ_RESOLUTION_INFO", 0xD7: "GET_DAQ_EVENT_INFO"}
DISCONNECT = 0xFE


class OneMasterSlave:
    """An XCP-on-TCP slave that answers ERR_CMD_UNKNOWN to the commands in ``lacks`` and serves one
    master's session at a time; ``garbage`` makes it send 64 KiB of noise once its DAQ runs."""

    def __init__(self, lacks: set[int] = frozenset(), garbage: bool = False) -> None:
        self.lacks, self.garbage = set(lacks), garbage
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"xcp+tcp://127.0.0.1:{self.listener.getsockname()[1]}"
        self.owner: int | None = None  # the connection whose session is open
        self.log: list[tuple[int, bytes]] = []  # (connection, command) as received
        self.refused = 0  # CONNECTs left unanswered: another master's session was open
        self.lock = threading.Lock()
        self.entries: dict[int, list[tuple[int, int]]] = {}
        self.running: dict[int, bool] = {}
        self._n = 0
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            self._n += 1
            threading.Thread(target=self._serve, args=(conn, self._n), daemon=True).start()

    def close(self) -> None:
        self.listener.close()

    def disconnects(self, who: int | None = None) -> int:
        return sum(1 for c, cmd in self.log if cmd[:1] == bytes([DISCONNECT]) and who in (None, c))

    def _serve(self, conn: socket.socket, me: int) -> None:
        ctr = [0]
        send_lock = threading.Lock()

        def send(packet: bytes) -> None:
            with send_lock:
                conn.sendall(struct.pack("<HH", len(packet), ctr[0] & 0xFFFF) + packet)
                ctr[0] += 1

        try:
            for cmd in commands(conn):
                with self.lock:
                    self.log.append((me, cmd))
                    if cmd[0] == 0xFF and self.owner not in (None, me):
                        self.refused += 1
                        continue  # another master's session is open: no answer
                    if cmd[0] == 0xFF:
                        self.owner = me
                    if cmd[0] == DISCONNECT and self.owner == me:
                        self.owner = None
                        self.running[me] = False
                if cmd[0] in self.lacks:
                    send(bytes([0xFE, 0x20]))  # ERR_CMD_UNKNOWN
                    continue
                send(self._answer(cmd, me))
                if cmd[0] == 0xDD and cmd[1] == 1:  # START_STOP_SYNCH start
                    self.running[me] = True
                    threading.Thread(target=self._stream, args=(send, me, conn), daemon=True).start()
                elif cmd[0] == 0xDD:
                    self.running[me] = False
        except OSError:
            pass
        finally:
            self.running[me] = False
            conn.close()

    def _answer(self, cmd: bytes, me: int) -> bytes:
        code = cmd[0]
        if code == 0xFF:  # CONNECT: DAQ, Intel, byte granularity, MAX_CTO 255, MAX_DTO 1024, optional comm mode
            return struct.pack("<BBBBHBB", 0xFF, 0x04, 0x80, 255, 1024, 1, 1)
        if code == 0xFB:  # GET_COMM_MODE_INFO
            return bytes([0xFF, 0, 0, 0, 0, 0, 0, 0x10])
        if code == 0xFD:  # GET_STATUS
            return struct.pack("<BBBBH", 0xFF, 0, 0, 0, 0)
        if code == 0xFA:  # GET_ID: the name in the response
            name = b"OPTIONAL_TEST"
            return struct.pack("<BBHI", 0xFF, 0x01, 0, len(name)) + name
        if code == 0xDA:  # GET_DAQ_PROCESSOR_INFO: dynamic, timestamps; relative ODT + DAQ byte
            return struct.pack("<BBHHBB", 0xFF, 0x11, 0, 1, 0, 0x40)
        if code == 0xD9:  # GET_DAQ_RESOLUTION_INFO: 4-byte timestamp in 1 us
            return struct.pack("<BBBBBBH", 0xFF, 1, 0xF8, 1, 0xF8, 0x34, 1)
        if code == 0xD7:  # GET_DAQ_EVENT_INFO: "tick", every 1 ms
            return struct.pack("<BBBBBBB", 0xFF, 0x04, 0xFF, 4, 1, 6, 0)
        if code == 0xF5:  # UPLOAD: the event's name
            return b"\xfftick"[: 1 + cmd[1]]
        if code == 0xE1:  # WRITE_DAQ
            self.entries.setdefault(me, []).append((cmd[2], struct.unpack_from("<I", cmd, 4)[0]))
        if code == 0xDE:  # START_STOP_DAQ_LIST select: first PID 0
            return bytes([0xFF, 0])
        return bytes([0xFF])

    def _stream(self, send, me: int, conn: socket.socket) -> None:
        k = 0
        while self.running.get(me):
            memory = {0x1000 + i: b for i, b in enumerate(struct.pack("<I", k))}
            entries = self.entries.get(me, [])
            try:
                send(struct.pack("<BBI", 0, 0, 1000 * k) + bytes(memory.get(a + i, 0) for s, a in entries
                                                                 for i in range(s)))
                if self.garbage and k == 200:
                    conn.sendall(bytes(np.random.default_rng(1).integers(0, 256, 1 << 16, dtype=np.uint8)))
                    return
            except OSError:
                return
            k += 1
            time.sleep(0.001)


@pytest.fixture
def a2l(tmp_path):
    path = tmp_path / "optional.a2l"
    path.write_text(A2L)
    return path


# every optional command lacking at once runs each fallback; each one alone is -m long (the suite's budget)
@pytest.mark.parametrize("lacks", [pytest.param(set(), id="none"),
                                   *(pytest.param({code}, id=name, marks=pytest.mark.long) for code, name in OPTIONAL.items()),
                                   pytest.param(set(OPTIONAL), id="all five")])
def test_a_lacking_optional_command_is_read_from_the_a2l_and_the_slave_is_left_free(lacks, a2l, tmp_path, run_cli):
    slave = OneMasterSlave(lacks)
    try:
        out = tmp_path / "o.mcap"
        r = run_cli("record", "--device", slave.url, "--a2l", a2l, "--measure", "ticks", "--duration", "1",
                    "-o", out)
        assert r.exit_code == 0, r.output
        data = load(out)["/xcp/tick"]
        ticks = data["ticks"].astype(np.int64)
        assert len(ticks) >= 5 and np.all(np.diff(ticks) == 1)  # every tick, each its own value (the rate is the host's sleep)
        # time from the DTO timestamps (1 us ticks, from the slave or its A2L): 1 ms apart exactly
        np.testing.assert_array_equal(np.diff(data.device_time), 1_000_000)
        device = load(out).metadata["ambdaq.device.controller"]
        # asked in this order: GET_COMM_MODE_INFO, GET_ID, GET_DAQ_PROCESSOR_INFO, _RESOLUTION_INFO, _EVENT_INFO
        assert device.get("optional_commands_lacking", "") == ", ".join(OPTIONAL[c] for c in OPTIONAL if c in lacks)
        assert slave.disconnects() == 1 and slave.owner is None
        r = run_cli("devices", "--ask-xcp", slave.url, "--json")  # the next master is answered
        assert r.exit_code == 0 and slave.refused == 0, r.output
        asked = json.loads(r.stdout)["xcp"][0]
        assert asked["lacks"] == (", ".join(OPTIONAL[c] for c in OPTIONAL if c in lacks) or
                                  "none of the optional commands asked")
        if 0xD7 not in lacks:
            assert asked["event_0"] == "tick (every 1000 us)"
    finally:
        slave.close()


def test_every_way_a_session_ends_ends_with_disconnect(a2l, tmp_path, run_cli):
    """A refusal after CONNECT (a prescaler the slave lacks), a peer's garbage while recording, and
    Ctrl-C on a recording each end the session with DISCONNECT; the slave then serves the next
    master (ambdaq 0.2.0 left without one, and that slave answered no other CONNECT)."""
    slave = OneMasterSlave()
    try:
        r = run_cli("record", "--device", f"{slave.url}?prescaler=2", "--a2l", a2l, "--measure", "ticks",
                    "--duration", "1", "-o", tmp_path / "p.mcap")
        assert r.exit_code == 2 and "no DAQ prescaler" in r.output, r.output
        assert slave.disconnects() == 1 and slave.owner is None
        # Ctrl-C: a recording in its own process, interrupted
        proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "record", "--device", slave.url, "--a2l", str(a2l),
                                 "--measure", "ticks", "--duration", "60", "-o", str(tmp_path / "c.mcap")],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 30
        while not any(slave.running.values()) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()
        assert slave.disconnects() == 2 and slave.owner is None
        assert len(load(tmp_path / "c.mcap")["/xcp/tick"]) > 20
    finally:
        slave.close()
    noisy = OneMasterSlave(garbage=True)
    try:
        r = run_cli("record", "--device", noisy.url, "--a2l", a2l, "--measure", "ticks", "--duration", "5",
                    "-o", tmp_path / "g.mcap")
        assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
        deadline = time.monotonic() + 5
        while noisy.disconnects() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert noisy.disconnects() == 1  # sent though the link's framing was lost
    finally:
        noisy.close()
