"""The simulated AMB controller's XCP slave (ASAM MCD-1 XCP 1.x) on XCP-on-TCP.

Measurement and calibration systems (CANape, INCA, pyxcp) reach an embedded controller through
XCP; this is the simulated spindle controller's. The protocol layer (ASAM XCP Part 2) answers,
in Intel byte order, byte address granularity, MAX_CTO 255:

    CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID (type 1: the A2L's
    ASAP2 name), SET_MTA, UPLOAD, SHORT_UPLOAD, BUILD_CHECKSUM (XCP_ADD_11)

and refuses any other command with ERR_CMD_UNKNOWN, as a slave that lacks it does. The transport
layer (ASAM XCP Part 3, Ethernet) frames each packet as LEN (u16) CTR (u16) PACKET.

Memory (see :class:`MeasurementMap`): every field of every signal group the rig streams is a
FLOAT32_IEEE at a fixed address from MEASUREMENT_BASE, in the groups' order; a read returns the
rig's newest sample, as a read of a controller's RAM returns the values of its last control
period.  :func:`a2l_text` writes the A2L file that describes this map.

Not yet (docs/hardware.md): DAQ lists, calibration pages, seed & key, XCP on SxI and CAN.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass

from .rig_server import RigServer

MEASUREMENT_BASE = 0x0001_0000
ASAP2_NAME = "AMBDAQ_SPINDLE"
MAX_CTO = 255
MAX_DTO = 1024
PID_RES, PID_ERR = 0xFF, 0xFE
ERR_CMD_SYNCH, ERR_CMD_UNKNOWN, ERR_CMD_SYNTAX, ERR_OUT_OF_RANGE, ERR_ACCESS_DENIED = 0x00, 0x20, 0x21, 0x22, 0x24
CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID = 0xFF, 0xFE, 0xFD, 0xFC, 0xFB, 0xFA
SET_MTA, UPLOAD, SHORT_UPLOAD, BUILD_CHECKSUM = 0xF6, 0xF5, 0xF4, 0xF3
CHECKSUM_ADD_11 = 0x01
TCP_HEADER = struct.Struct("<HH")


@dataclass(frozen=True)
class Measurement:
    """One measurement variable: ``name`` (A2L), its rig ``topic`` and ``field``, ``address``, ``unit``."""

    name: str
    topic: str
    field: str
    address: int
    unit: str


def measurement_map(rig) -> list[Measurement]:
    """Every field of every signal group ``rig`` streams, a FLOAT32 each from MEASUREMENT_BASE."""
    out = []
    address = MEASUREMENT_BASE
    for group in rig.signal_groups():
        for field, unit in zip(group.fields, group.units):
            out.append(Measurement(f"{group.topic.strip('/').replace('/', '_')}_{field}", group.topic, field,
                                   address, unit))
            address += 4
    return out


class MeasurementMap:
    """The controller's measurement RAM: each rig field a FLOAT32 at its address."""

    def __init__(self, server: RigServer) -> None:
        self.server = server
        self.measurements = measurement_map(server.rig)
        self.end = MEASUREMENT_BASE + 4 * len(self.measurements)
        self._columns = {g.topic: {f: i for i, f in enumerate(g.fields)} for g in server.rig.signal_groups()}

    def read(self, address: int, length: int) -> bytes:
        """``length`` bytes from ``address``; IndexError outside the map."""
        if address < MEASUREMENT_BASE or address + length > self.end:
            raise IndexError(address)
        _step, rows = self.server.sample_at(time.time_ns())
        image = b"".join(struct.pack("<f", float(rows[m.topic][self._columns[m.topic][m.field]]))
                         for m in self.measurements)
        offset = address - MEASUREMENT_BASE
        return image[offset : offset + length]


def a2l_text(measurements: list[Measurement]) -> str:
    """The ASAM MCD-2 MC (A2L) description of the measurement map, for ``measurements``."""
    blocks = []
    for m in measurements:
        blocks.append(f"""    /begin MEASUREMENT {m.name} "{m.topic} {m.field}"
      FLOAT32_IEEE CM_IDENTITY_{_unit_id(m.unit)} 0 0 -1e12 1e12
      ECU_ADDRESS 0x{m.address:08X}
      PHYS_UNIT "{m.unit}"
    /end MEASUREMENT""")
    units = sorted({m.unit for m in measurements})
    methods = "\n".join(f"""    /begin COMPU_METHOD CM_IDENTITY_{_unit_id(u)} "identity, {u}"
      IDENTICAL "%12.6" "{u}"
    /end COMPU_METHOD""" for u in units)
    return f"""ASAP2_VERSION 1 71
/begin PROJECT {ASAP2_NAME} "ambdaq simulated spindle AMB controller"
  /begin MODULE CONTROLLER "measurement map of the XCP slave (ambdaq/sim/devices/xcp.py)"
    /begin MOD_PAR ""
      /begin MEMORY_SEGMENT MEASUREMENT_RAM "" DATA RAM INTERN 0x{MEASUREMENT_BASE:08X} 0x{len(measurements) * 4:X} -1 -1 -1 -1 -1
      /end MEMORY_SEGMENT
    /end MOD_PAR
    /begin MOD_COMMON ""
      BYTE_ORDER MSB_LAST
      ALIGNMENT_FLOAT32_IEEE 4
    /end MOD_COMMON
{methods}
{chr(10).join(blocks)}
  /end MODULE
/end PROJECT
"""


def _unit_id(unit: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in unit) or "none"


class XcpSlave:
    """The XCP-on-TCP slave of ``server``'s controller on 127.0.0.1:``port`` (0: any free port)."""

    def __init__(self, server: RigServer, port: int = 0) -> None:
        self.memory = MeasurementMap(server)
        self._listener = socket.create_server(("127.0.0.1", port))
        self.port = self._listener.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="xcp-slave", daemon=True)
        self._mta = 0
        self._id_pos: int | None = None  # after GET_ID: uploads read the identification from here
        self._connected = False
        self._id = ASAP2_NAME.encode()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._listener.close()
        self._thread.join(timeout=1.0)

    def _serve(self) -> None:
        self._listener.settimeout(0.1)
        while not self._stop.is_set():
            try:
                conn, _addr = self._listener.accept()
            except (socket.timeout, OSError):
                continue
            with conn:
                conn.settimeout(0.1)
                self._session(conn)
            self._connected = False

    def _session(self, conn: socket.socket) -> None:
        """One master's connection: packets in, responses out, until it closes."""
        buf, ctr = b"", 0
        while not self._stop.is_set():
            try:
                chunk = conn.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while len(buf) >= TCP_HEADER.size:
                length, _ctr = TCP_HEADER.unpack_from(buf)
                if len(buf) < TCP_HEADER.size + length:
                    break
                packet, buf = buf[TCP_HEADER.size : TCP_HEADER.size + length], buf[TCP_HEADER.size + length :]
                reply = self.command(packet)
                if reply is not None:
                    conn.sendall(TCP_HEADER.pack(len(reply), ctr) + reply)
                    ctr = (ctr + 1) & 0xFFFF

    def command(self, packet: bytes) -> bytes | None:
        """The response to one command packet (ASAM XCP Part 2); None for none."""
        if not packet:
            return None
        pid = packet[0]
        if pid == CONNECT:
            self._connected = True
            # RESOURCE: none of CAL/PAG, DAQ, STIM, PGM yet; COMM_MODE_BASIC: Intel, byte granularity
            return struct.pack("<BBBBHBB", PID_RES, 0x00, 0x00, MAX_CTO, MAX_DTO, 0x01, 0x01)
        if not self._connected:
            return None  # a slave that is not connected answers nothing but CONNECT
        try:
            if pid == DISCONNECT:
                self._connected = False
                return bytes([PID_RES])
            if pid == GET_STATUS:
                return struct.pack("<BBBBH", PID_RES, 0x00, 0x00, 0x00, 0x0000)
            if pid == SYNCH:
                return bytes([PID_ERR, ERR_CMD_SYNCH])
            if pid == GET_COMM_MODE_INFO:
                return struct.pack("<BBBBBBBB", PID_RES, 0, 0x00, 0, 0, 0, 0, 0x10)
            if pid == GET_ID:
                if packet[1] != 1:  # only the ASAP2 name (the A2L's project)
                    return struct.pack("<BBHI", PID_RES, 0, 0, 0)
                self._id_pos = 0
                return struct.pack("<BBHI", PID_RES, 0, 0, len(self._id))
            if pid == SET_MTA:
                _res, _ext, self._mta = struct.unpack_from("<HBI", packet, 1)
                self._id_pos = None
                return bytes([PID_RES])
            if pid == UPLOAD:
                n = packet[1]
                return bytes([PID_RES]) + self._read_mta(n)
            if pid == SHORT_UPLOAD:
                n, _res, _ext, address = struct.unpack_from("<BBBI", packet, 1)
                if n > MAX_CTO - 1:
                    return bytes([PID_ERR, ERR_OUT_OF_RANGE])
                return bytes([PID_RES]) + self.memory.read(address, n)
            if pid == BUILD_CHECKSUM:
                (size,) = struct.unpack_from("<I", packet, 4)
                data = self.memory.read(self._mta, size)
                self._mta += size
                return struct.pack("<BBHI", PID_RES, CHECKSUM_ADD_11, 0, sum(data) & 0xFF)
        except (IndexError, struct.error):
            return bytes([PID_ERR, ERR_OUT_OF_RANGE if pid != SET_MTA else ERR_CMD_SYNTAX])
        return bytes([PID_ERR, ERR_CMD_UNKNOWN])

    def _read_mta(self, n: int) -> bytes:
        if self._id_pos is not None:  # the identification string
            data = self._id[self._id_pos : self._id_pos + n]
            self._id_pos += len(data)
            return data
        data = self.memory.read(self._mta, n)
        self._mta += n
        return data
