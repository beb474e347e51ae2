"""CURVEs and MAPs that store their axis points in their own record (A2L STD_AXIS), read by
``controller param`` from a slave whose memory the test lays out byte by byte from the record
layouts (ASAM MCD-2 MC RECORD_LAYOUT: items in position order, each aligned to its type, a compact
record packing each item after the points in use, a STATIC_RECORD_LAYOUT keeping room for all)."""

from __future__ import annotations

import socket
import struct
import threading

import pytest
from xcp_tcp import commands

A2L = """ASAP2_VERSION 1 71
/begin PROJECT RECORDS ""
  /begin MODULE M ""
    /begin MOD_COMMON "" BYTE_ORDER MSB_LAST ALIGNMENT_BYTE 1 ALIGNMENT_WORD 2 ALIGNMENT_LONG 4
      ALIGNMENT_FLOAT32_IEEE 4 ALIGNMENT_FLOAT64_IEEE 8 /end MOD_COMMON
    /begin COMPU_METHOD CM.GAIN "" LINEAR "%6.3" "A/m" COEFFS_LINEAR 0.01 0 /end COMPU_METHOD
    /begin COMPU_METHOD CM.RPM "" LINEAR "%6.0" "rpm" COEFFS_LINEAR 10 0 /end COMPU_METHOD
    /begin RECORD_LAYOUT RL.CURVE.COMPACT
      NO_AXIS_PTS_X 1 UBYTE
      AXIS_PTS_X 2 SWORD INDEX_INCR DIRECT
      FNC_VALUES 3 UWORD COLUMN_DIR DIRECT
    /end RECORD_LAYOUT
    /begin RECORD_LAYOUT RL.MAP.STATIC
      NO_AXIS_PTS_X 1 UWORD
      NO_AXIS_PTS_Y 2 UWORD
      AXIS_PTS_X 3 FLOAT32_IEEE INDEX_INCR DIRECT
      AXIS_PTS_Y 4 FLOAT32_IEEE INDEX_INCR DIRECT
      FNC_VALUES 5 FLOAT32_IEEE ROW_DIR DIRECT
      STATIC_RECORD_LAYOUT
    /end RECORD_LAYOUT
    /begin RECORD_LAYOUT RL.MAP.INTERLEAVED
      AXIS_PTS_Y 4 UBYTE INDEX_INCR DIRECT
      NO_AXIS_PTS_X 1 UBYTE
      AXIS_PTS_X 2 UBYTE INDEX_INCR DIRECT
      NO_AXIS_PTS_Y 3 UBYTE
      FNC_VALUES 5 SWORD COLUMN_DIR DIRECT
    /end RECORD_LAYOUT
    /begin RECORD_LAYOUT RL.AXIS.COUNTED
      NO_AXIS_PTS_X 1 UWORD
      AXIS_PTS_X 2 SLONG INDEX_INCR DIRECT
    /end RECORD_LAYOUT
    /begin AXIS_PTS speed_axis "a shared speed axis" 0x6000 NO_INPUT_QUANTITY RL.AXIS.COUNTED 0 CM.RPM 6 0 100000
    /end AXIS_PTS
    /begin CHARACTERISTIC gain_curve "gain against speed" CURVE 0x2000 RL.CURVE.COMPACT 0 CM.GAIN 0 600
      /begin AXIS_DESCR STD_AXIS speed CM.RPM 8 0 100000 /end AXIS_DESCR
    /end CHARACTERISTIC
    /begin CHARACTERISTIC bias_map "bias current" MAP 0x3000 RL.MAP.STATIC 0 NO_COMPU_METHOD -10 10
      /begin AXIS_DESCR STD_AXIS speed NO_COMPU_METHOD 3 0 1000 /end AXIS_DESCR
      /begin AXIS_DESCR STD_AXIS temp NO_COMPU_METHOD 2 -50 150 /end AXIS_DESCR
    /end CHARACTERISTIC
    /begin CHARACTERISTIC small_map "few points in use" MAP 0x4001 RL.MAP.INTERLEAVED 0 NO_COMPU_METHOD -100 100
      /begin AXIS_DESCR STD_AXIS a NO_COMPU_METHOD 4 0 255 /end AXIS_DESCR
      /begin AXIS_DESCR STD_AXIS b NO_COMPU_METHOD 3 0 255 /end AXIS_DESCR
    /end CHARACTERISTIC
    /begin CHARACTERISTIC broken_curve "more points than it has room for" CURVE 0x5000 RL.CURVE.COMPACT 0 CM.GAIN 0 600
      /begin AXIS_DESCR STD_AXIS speed CM.RPM 4 0 100000 /end AXIS_DESCR
    /end CHARACTERISTIC
  /end MODULE
/end PROJECT
"""


def memory() -> dict[int, int]:
    """The ECU's bytes, laid out by hand from the layouts above (little-endian, MSB_LAST)."""
    image = {}

    def put(address: int, data: bytes) -> None:
        image.update({address + i: b for i, b in enumerate(data)})

    # gain_curve, compact, 5 of 8 points: n (UBYTE) at 0x2000; the SWORD axis aligned to 0x2002,
    # 5 points to 0x200C; the UWORD values right after the 5 points in use (not the 8 there is room for)
    put(0x2000, struct.pack("<B", 5))
    put(0x2002, struct.pack("<5h", 0, 300, 1200, 2400, 3000))  # x 10 rpm per count
    put(0x200C, struct.pack("<5H", 100, 150, 220, 310, 400))  # x 0.01 A/m per count
    # bias_map, static, all 3 x 2 points: counts, then float32 x, y, and the 6 values
    put(0x3000, struct.pack("<HH", 3, 2))
    put(0x3004, struct.pack("<3f", 0.0, 500.0, 1000.0))
    put(0x3010, struct.pack("<2f", -25.0, 100.0))
    put(0x3018, struct.pack("<6f", 1.5, 1.25, 1.0, 2.0, 1.75, 1.5))
    # small_map at the odd address 0x4001, items by position (not by their order in the layout):
    # n_x = 2, x points (2 of 4), n_y = 2, y points (2 of 3), then SWORD values aligned to an even address
    put(0x4001, bytes([2, 10, 20, 2, 7, 9]))
    put(0x4008, struct.pack("<4h", -3, 4, -5, 6))  # 0x4007 is odd: one pad byte
    put(0x5000, struct.pack("<B", 9))  # broken_curve: 9 points in use where the A2L gives room for 4
    put(0x6000, struct.pack("<H", 3))  # speed_axis: 3 of 6 points, the SLONGs aligned to 0x6004
    put(0x6004, struct.pack("<3i", 100, 200, 400))
    return image


class MemorySlave:
    """An XCP-on-TCP slave with CAL/PAG that answers SET_MTA and UPLOAD from :func:`memory`."""

    def __init__(self) -> None:
        self.memory, self.mta, self.ctr = memory(), 0, 0
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        with conn:
            for cmd in commands(conn):
                reply = self._answer(cmd)
                conn.sendall(struct.pack("<HH", len(reply), self.ctr & 0xFFFF) + reply)
                self.ctr += 1

    def _answer(self, cmd: bytes) -> bytes:
        code = cmd[0]
        if code == 0xFF:  # CONNECT: CAL/PAG, Intel, byte granularity, MAX_CTO 64, MAX_DTO 64
            return struct.pack("<BBBBHBB", 0xFF, 0x01, 0x00, 64, 64, 1, 1)
        if code == 0xFD:  # GET_STATUS: nothing protected
            return struct.pack("<BBBBH", 0xFF, 0, 0, 0, 0)
        if code == 0xF6:  # SET_MTA: reserved x2, extension, address
            self.mta = struct.unpack_from("<I", cmd, 4)[0]
            return b"\xff"
        if code == 0xF5:  # UPLOAD n bytes from the MTA, which moves on
            data = bytes(self.memory.get(self.mta + i, 0) for i in range(cmd[1]))
            self.mta += cmd[1]
            return b"\xff" + data
        if code == 0xFA:  # GET_ID: not offered
            return bytes([0xFE, 0x20])
        return bytes([0xFE, 0x20])  # ERR_CMD_UNKNOWN


@pytest.fixture
def slave(tmp_path):
    a2l = tmp_path / "records.a2l"
    a2l.write_text(A2L)
    server = MemorySlave()
    return f"xcp+tcp://127.0.0.1:{server.port}", a2l


def test_a_compact_curve_reads_the_points_in_use(slave, run_cli):
    url, a2l = slave
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "gain_curve")
    assert r.exit_code == 0, r.output
    assert r.output.splitlines() == ["gain_curve = 1 1.5 2.2 3.1 4", "gain_curve.x = 0 3000 12000 24000 30000"]


def test_a_static_map_reads_values_and_both_axes(slave, run_cli):
    url, a2l = slave
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "bias_map")
    assert r.exit_code == 0, r.output
    assert r.output.splitlines() == ["bias_map = 1.5 1.25 1 2 1.75 1.5", "bias_map.x = 0 500 1000", "bias_map.y = -25 100"]


def test_items_in_position_order_aligned_from_an_odd_address(slave, run_cli):
    url, a2l = slave
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "small_map")
    assert r.exit_code == 0, r.output
    assert r.output.splitlines() == ["small_map = -3 4 -5 6", "small_map.x = 10 20", "small_map.y = 7 9"]


def test_a_count_beyond_the_room_is_refused(slave, run_cli):
    url, a2l = slave
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "broken_curve")
    assert r.exit_code == 1 and "9 points on axis x, its A2L at most 4" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1


def test_a_record_with_its_own_axes_is_read_not_written(slave, run_cli):
    url, a2l = slave
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "gain_curve", "1", "2", "3", "4", "5", "--yes")
    assert r.exit_code == 1 and "no writable numeric parameter 'gain_curve'" in r.output, r.output


def test_axis_points_with_their_count_in_the_record(slave, run_cli):
    url, a2l = slave
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "speed_axis")
    assert r.exit_code == 0, r.output
    assert r.output.splitlines() == ["speed_axis = 1000 2000 4000"]
