"""The simulated AMB controller's XCP slave (ASAM MCD-1 XCP 1.x) on TCP, on SxI or on CAN.

Measurement and calibration systems (CANape, INCA, pyxcp) reach an embedded controller through
XCP; this is the simulated spindle controller's, on the same rig and coefficient banks as its
serial port.  Its memory is :mod:`.xcp_memory`'s.  The protocol layer (ASAM XCP Part 2)
answers, in Intel byte order, byte address granularity, MAX_CTO 255 and MAX_DTO 1024 (on CAN 8):

- standard: CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID (type 1: the A2L's
  ASAP2 name), SET_REQUEST (STORE_CAL_REQ), GET_SEED, UNLOCK, SET_MTA, UPLOAD, SHORT_UPLOAD,
  BUILD_CHECKSUM (XCP_CRC_32);
- calibration: DOWNLOAD, SHORT_DOWNLOAD, SET_CAL_PAGE, GET_CAL_PAGE, GET_PAG_PROCESSOR_INFO;
- DAQ (dynamic lists): GET_DAQ_PROCESSOR_INFO, GET_DAQ_RESOLUTION_INFO, GET_DAQ_EVENT_INFO,
  GET_DAQ_CLOCK, FREE_DAQ, ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY, SET_DAQ_PTR, WRITE_DAQ,
  SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST, START_STOP_SYNCH; or, with ``static_daq``, the
  static configuration of many ECUs: ``STATIC_LISTS`` lists of ``STATIC_ODTS`` ODTs of
  ``STATIC_ENTRIES`` entries each, described by GET_DAQ_LIST_INFO and emptied by CLEAR_DAQ_LIST,
  FREE_DAQ and the ALLOC commands unknown; an ODT with no entry is not sent;

and refuses any other command with ERR_CMD_UNKNOWN, as a slave that lacks it does.

Resources: CAL/PAG is protected (seed & key, the ``ambdaq-sim`` algorithm of
:mod:`ambdaq.drivers.xcp.keys` keyed with the banks' unlock key); a wrong key is answered
ERR_ACCESS_LOCKED and ends the session, as the standard asks.  DAQ is open.

DAQ: one event channel, ``control`` (event 0), every control period (100 us at 10 kHz).  Each
DTO is PID (absolute ODT number), then on a list's first ODT a 4-byte timestamp in 1 us ticks
of the controller's own clock, then the ODT's entries.  DTOs are queued for the socket by a
sender thread; when the master falls behind by more than ``DAQ_QUEUE_S`` the newest are
dropped and counted (:attr:`XcpSlave.overruns`), and the gaps show in ``control_period``.

The transport layers (ASAM XCP Part 3) are :mod:`.xcp_transport`'s: TCP and SxI frame each
packet LEN CTR PACKET, and the slave's CTR counts every packet it sends, responses and DTOs alike;
on CAN a packet is one classic frame, master to slave on CAN_ID_MASTER and slave to master on
CAN_ID_SLAVE.
"""

from __future__ import annotations

import os
import queue
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ...drivers.coefbank import crc32
from ...drivers.signals import SampleBlock
from ...drivers.xcp.keys import sim_key
from ...drivers.xcp.wire import (ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY, BUILD_CHECKSUM, CHECKSUM_CRC_32, CLEAR_DAQ_LIST,
                                 CONNECT, DISCONNECT, DOWNLOAD, ERR_CMD_SYNCH, ERR_CMD_SYNTAX, ERR_CMD_UNKNOWN,
                                 ERR_DAQ_CONFIG, ERR_SEQUENCE, FREE_DAQ, GET_CAL_PAGE,
                                 GET_COMM_MODE_INFO, GET_DAQ_CLOCK, GET_DAQ_EVENT_INFO, GET_DAQ_LIST_INFO,
                                 GET_DAQ_PROCESSOR_INFO, GET_DAQ_RESOLUTION_INFO, GET_ID, GET_PAG_PROCESSOR_INFO,
                                 GET_SEED, GET_STATUS, PID_ERR, PID_RES, RES_CALPAG, RES_DAQ, SET_CAL_PAGE,
                                 SET_DAQ_LIST_MODE, SET_DAQ_PTR, SET_MTA, SET_REQUEST, SHORT_DOWNLOAD, SHORT_UPLOAD,
                                 START_STOP_DAQ_LIST, START_STOP_SYNCH, SYNCH, UNLOCK, UPLOAD, WRITE_DAQ)
from ...errors import DeviceError
from ..profiles import profile
from .banks import CoefficientBanks
from .rig_server import DeviceClock, RigServer
from .xcp_memory import (ERR_ACCESS_LOCKED, ERR_OUT_OF_RANGE, MEASUREMENT_BASE, STATUS_BASE,
                         CalibrationConstants, CalibrationPages, ControllerParameters, MeasurementMap, Refused,
                         asap2_name)
from .xcp_transport import (HEADER, MAX_CTO, MAX_DTO, READ_WAIT_S, CanTransport, PtyLink, StreamTransport,
                            TcpLink)

CAN_ID_MASTER, CAN_ID_SLAVE = 0x7F1, 0x7F2  # the simulated slave's XCP-on-CAN identifiers
SEED_BYTES = 16
EVENT_NAME = b"control"
EVENT_CYCLE, EVENT_UNIT_100US = 1, 5  # one control period: 1 x 100 us
TIMESTAMP_MODE = 0x30 | 0x08 | 0x04  # unit 1 us, fixed (every first ODT), 4 bytes
DAQ_PROPERTIES = 0x01 | 0x02 | 0x10  # dynamic configuration, prescaler, timestamps
MAX_DAQ_LISTS, MAX_ODT_ENTRY_SIZE = 16, 255
STATIC_LISTS, STATIC_ODTS, STATIC_ENTRIES = 3, 16, 7  # static configuration: lists, ODTs per list, entries per ODT
DAQ_QUEUE_S = 2.0



@dataclass
class DaqList:
    """One dynamic DAQ list: its ODTs' entries (size, address), mode and state."""

    odts: list[list[tuple[int, int] | None]] = field(default_factory=list)
    timestamp: bool = False
    prescaler: int = 1
    selected: bool = False
    running: bool = False
    first_pid: int = 0


class XcpSlave:
    """The XCP slave of ``server``'s controller; :meth:`serve_tcp` or :meth:`serve_pty` puts it on
    a transport.

    Parameters
    ----------
    server : RigServer
        The running rig.
    banks : CoefficientBanks
        The controller's coefficient banks (shared with its other ports).
    clock : DeviceClock
        The controller's clock, which stamps the DTOs.
    static_daq : bool
        Static DAQ lists (fixed room, GET_DAQ_LIST_INFO, CLEAR_DAQ_LIST) instead of dynamic ones.
    """

    def __init__(self, server: RigServer, banks: CoefficientBanks, clock: DeviceClock, *,
                 static_daq: bool = False) -> None:
        self.server = server
        self.static_daq = static_daq
        self.memory = MeasurementMap(server)
        self.pages = CalibrationPages(banks)
        self.constants = CalibrationConstants(server.rig.calibration())
        self.parameters = ControllerParameters(server.rig, profile(server.rig.profile).firmware.parameters)
        self.banks = banks
        self.clock = clock
        self.url = ""
        self._closers: list = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sender = threading.Thread(target=self._send_loop, name="xcp-daq", daemon=True)
        blocks_per_s = server.rig.params.sample_rate / server.block
        self._out: queue.Queue[tuple[list, np.ndarray]] = queue.Queue(maxsize=int(DAQ_QUEUE_S * blocks_per_s))
        self._tx = threading.Lock()  # the link and CTR: responses and DTOs share them
        self._link: StreamTransport | CanTransport | None = None
        self._ctr = 0
        self.overruns = 0  # DTO blocks dropped because the master fell behind
        self._reset_session()

    def _reset_session(self) -> None:
        self._connected = False
        self._mta = 0
        self._upload_text: bytes | None = None  # after GET_ID / GET_DAQ_EVENT_INFO: uploads read this
        self._seed = b""
        self._protected = RES_CALPAG
        self._daq: list[DaqList] = self._fresh_lists()
        self._ptr: tuple[int, int, int] | None = None
        self._plan: list | None = None  # the running lists' DTO layout
        self.parameters.forget()

    def _fresh_lists(self) -> list[DaqList]:
        """The DAQ lists a new session finds: none (dynamic), or the static ones, empty."""
        if not self.static_daq:
            return []
        return [DaqList(odts=[[None] * STATIC_ENTRIES for _ in range(STATIC_ODTS)]) for _ in range(STATIC_LISTS)]

    def serve_tcp(self, port: int) -> None:
        """XCP on TCP on 127.0.0.1:``port`` (0: a free one); :attr:`url` says where."""
        try:
            listener = socket.create_server(("127.0.0.1", port))
        except OSError as err:
            raise DeviceError(f"XCP on TCP cannot listen on 127.0.0.1:{port}: {err.strerror or err}") from None
        self.url = f"xcp+tcp://127.0.0.1:{listener.getsockname()[1]}"
        self._thread = threading.Thread(target=self._serve_tcp, args=(listener,), name="xcp-slave", daemon=True)

    def serve_pty(self, pty) -> None:
        """XCP on SxI on ``pty`` (its master; LEN and CTR words, no checksum); :attr:`url` says where."""
        self.url = f"xcp+sxi://{pty.path}"
        self._thread = threading.Thread(target=self._serve_link, args=(StreamTransport(PtyLink(pty.master)),),
                                        name="xcp-slave", daemon=True)

    def serve_can(self, channel: str, url_bus: str) -> None:
        """XCP on CAN on python-can's virtual ``channel`` (CAN_ID_MASTER, CAN_ID_SLAVE); the
        master reaches it at ``url_bus`` (``virtual/CHANNEL?``, or the SLCAN adapter's
        ``slcan/dev/pts/N?open_delay=0&``: a URL up to its next option)."""
        import can

        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.url = f"xcp+can://{url_bus}id_master=0x{CAN_ID_MASTER:X}&id_slave=0x{CAN_ID_SLAVE:X}"
        self._closers.append(bus.shutdown)
        self._thread = threading.Thread(target=self._serve_link, args=(CanTransport(bus, CAN_ID_MASTER, CAN_ID_SLAVE),),
                                        name="xcp-slave", daemon=True)

    def start(self) -> None:
        self.server.subscribe(self._on_block)
        self._thread.start()
        self._sender.start()

    def stop(self) -> None:
        self.server.unsubscribe(self._on_block)
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._sender.join(timeout=1.0)
        for close in self._closers:
            close()

    # --- transport ------------------------------------------------------------------------------

    def _serve_tcp(self, listener: socket.socket) -> None:
        listener.settimeout(READ_WAIT_S)
        with listener:
            while not self._stop.is_set():
                try:
                    conn, _addr = listener.accept()
                except (socket.timeout, OSError):
                    continue
                with conn:
                    self._serve_link(StreamTransport(TcpLink(conn)))

    def _serve_link(self, link: StreamTransport | CanTransport) -> None:
        """One link's packets in, responses out, until it closes (a line or a bus never does)."""
        with self._tx:
            self._link, self._ctr = link, 0
        while not self._stop.is_set():
            packets = link.packets()
            if packets is None:
                break
            for packet in packets:
                reply = self.command(packet)
                if reply is None:
                    continue
                with self._tx:
                    try:
                        link.send(reply, self._ctr)
                    except OSError:
                        self._stop_daq()
                    self._ctr = (self._ctr + 1) & 0xFFFF
        with self._tx:
            self._link = None
        self._reset_session()

    def _send_loop(self) -> None:
        """Send the queued DTOs, numbering them as they go (the CTR of every packet the slave sends)."""
        while not self._stop.is_set():
            try:
                rows, included = self._out.get(timeout=0.1)
            except queue.Empty:
                continue
            with self._tx:
                if self._link is None or not self._plan:
                    continue
                try:
                    self._link.send_dtos(rows, included, self._ctr)
                except OSError:
                    self._stop_daq()  # the master is gone: a slave stops its DAQ
                self._ctr = (self._ctr + int(included.sum())) & 0xFFFF

    # --- DAQ --------------------------------------------------------------------------------------

    def _on_block(self, block: SampleBlock) -> None:
        """Every control period of ``block``, as the running DAQ lists sample it, queued to send."""
        plan = self._plan
        if not plan:
            return
        n = len(block)
        images = self.memory.images(block.seq, block.values)
        ticks = (self.clock.at(block.device_time_ns) // 1000).astype("<u4").view(np.uint8).reshape(n, 4)
        seq = block.seq.astype(np.int64)
        rows, included = [], []
        for prescaler, pid, stamped, index in plan:
            width = HEADER.size + 1 + 4 * stamped + index.shape[0]
            row = np.empty((n, width), dtype=np.uint8)
            row[:, 0:2] = np.frombuffer(struct.pack("<H", width - HEADER.size), np.uint8)
            row[:, 4] = pid
            if stamped:
                row[:, 5:9] = ticks
            row[:, width - index.shape[0] :] = images[:, index]
            rows.append(row)
            included.append(seq % prescaler == 0)
        try:
            self._out.put_nowait((rows, np.stack(included, axis=1)))
        except queue.Full:
            self.overruns += 1

    def _arm(self) -> None:
        """The DTO layout of the running lists: per ODT its list's prescaler, its PID, whether it
        carries the timestamp, and its bytes' indexes into the RAM image."""
        plan = []
        for daq in self._daq:
            if not daq.running:
                continue
            for j, entries in enumerate(daq.odts):
                if self.static_daq and not any(entries):
                    continue  # a static list's ODT with no entry is not sent
                index = [np.arange(a - MEASUREMENT_BASE, a - MEASUREMENT_BASE + s) for s, a in filter(None, entries)]
                plan.append((daq.prescaler, daq.first_pid + j, daq.timestamp and j == 0,
                             np.concatenate(index) if index else np.zeros(0, dtype=np.int64)))
        self._plan = plan or None

    # --- commands ---------------------------------------------------------------------------------

    def command(self, packet: bytes) -> bytes | None:
        """The response to one command packet (ASAM XCP Part 2); None for none."""
        if not packet:
            return None
        pid = packet[0]
        if pid == CONNECT:
            self._connected = True
            # RESOURCE: CAL/PAG and DAQ; COMM_MODE_BASIC: Intel, byte granularity, GET_COMM_MODE_INFO
            cto, dto = self._limits()
            return struct.pack("<BBBBHBB", PID_RES, RES_CALPAG | RES_DAQ, 0x80, cto, dto, 0x01, 0x01)
        if not self._connected:
            return None  # a slave that is not connected answers nothing but CONNECT
        try:
            handler = self._HANDLERS.get(pid)
            if handler is None:
                return bytes([PID_ERR, ERR_CMD_UNKNOWN])
            return handler(self, packet)
        except Refused as err:
            return bytes([PID_ERR, err.code])
        except (IndexError, struct.error):
            return bytes([PID_ERR, ERR_OUT_OF_RANGE if pid != SET_MTA else ERR_CMD_SYNTAX])

    def _limits(self) -> tuple[int, int]:
        """MAX_CTO and MAX_DTO of the link the master is on."""
        link = self._link
        return (link.max_cto, link.max_dto) if link is not None else (MAX_CTO, MAX_DTO)

    def _disconnect(self, _p: bytes) -> bytes:
        self._stop_daq()
        self._connected = False
        self._protected = RES_CALPAG
        return bytes([PID_RES])

    def _get_status(self, _p: bytes) -> bytes:
        session = 0x40 if self._plan else 0x00  # DAQ_RUNNING
        return struct.pack("<BBBBH", PID_RES, session, self._protected, 0x00, 0x0000)

    def _synch(self, _p: bytes) -> bytes:
        return bytes([PID_ERR, ERR_CMD_SYNCH])

    def _get_comm_mode_info(self, _p: bytes) -> bytes:
        return struct.pack("<BBBBBBBB", PID_RES, 0, 0x00, 0, 0, 0, 0, 0x10)

    def _get_id(self, p: bytes) -> bytes:
        if p[1] != 1:  # only the ASAP2 name (the A2L's project)
            return struct.pack("<BBHI", PID_RES, 0, 0, 0)
        self._upload_text = asap2_name(self.server.rig.profile).encode()
        return struct.pack("<BBHI", PID_RES, 0, 0, len(self._upload_text))

    def _set_request(self, p: bytes) -> bytes:
        if p[1] & 0x01:  # STORE_CAL_REQ
            if self._protected & RES_CALPAG:
                raise Refused(ERR_ACCESS_LOCKED, "calibration is locked")
            self.pages.store()
        return bytes([PID_RES])

    def _get_seed(self, p: bytes) -> bytes:
        mode, resource = p[1], p[2]
        if mode != 0 or resource not in (RES_CALPAG, RES_DAQ):
            raise Refused(ERR_OUT_OF_RANGE, "seed: mode 0 for CAL/PAG or DAQ")
        if not self._protected & resource:
            return bytes([PID_RES, 0])
        self._seed_for = resource
        self._seed = os.urandom(SEED_BYTES)
        return bytes([PID_RES, len(self._seed)]) + self._seed

    def _unlock(self, p: bytes) -> bytes:
        key = p[2 : 2 + p[1]]
        if not self._seed or key != sim_key(self._seed_for, self._seed, self.banks.key):
            self._seed = b""
            self._connected = False  # a wrong key ends the session (ASAM XCP Part 2, UNLOCK)
            return bytes([PID_ERR, ERR_ACCESS_LOCKED])
        self._protected &= ~self._seed_for
        self._seed = b""
        if self._seed_for == RES_CALPAG:
            self.banks.unlock(self.banks.key)
        return bytes([PID_RES, self._protected])

    def _set_mta(self, p: bytes) -> bytes:
        _res, _ext, self._mta = struct.unpack_from("<HBI", p, 1)
        self._upload_text = None
        if self._mta == STATUS_BASE:
            self.pages.snapshot_status()
        return bytes([PID_RES])

    def _read(self, address: int, n: int) -> bytes:
        if self.pages.owns(address):
            return self.pages.read(address, n)
        if self.constants.owns(address):
            return self.constants.read(address, n)
        if self.parameters.owns(address):
            return self.parameters.read(address, n)
        return self.memory.read(address, n)

    def _upload(self, p: bytes) -> bytes:
        n = p[1]
        if n > self._limits()[0] - 1:
            raise Refused(ERR_OUT_OF_RANGE, "upload longer than MAX_CTO - 1")
        if self._upload_text is not None:
            data, self._upload_text = self._upload_text[:n], self._upload_text[n:]
            return bytes([PID_RES]) + data
        data = self._read(self._mta, n)
        self._mta += n
        return bytes([PID_RES]) + data

    def _short_upload(self, p: bytes) -> bytes:
        n, _res, _ext, address = struct.unpack_from("<BBBI", p, 1)
        if n > self._limits()[0] - 1:
            raise Refused(ERR_OUT_OF_RANGE, "upload longer than MAX_CTO - 1")
        if address == STATUS_BASE:
            self.pages.snapshot_status()
        return bytes([PID_RES]) + self._read(address, n)

    def _build_checksum(self, p: bytes) -> bytes:
        (size,) = struct.unpack_from("<I", p, 4)
        crc = crc32(self._read(self._mta, size))
        self._mta += size
        return struct.pack("<BBHI", PID_RES, CHECKSUM_CRC_32, 0, crc)

    def _write(self, address: int, data: bytes) -> None:
        unlocked = not self._protected & RES_CALPAG
        if self.parameters.owns(address):
            self.parameters.write(address, data, unlocked)
        else:
            self.pages.write(address, data, unlocked)

    def _download(self, p: bytes) -> bytes:
        n = p[1]
        data = p[2 : 2 + n]
        if len(data) != n:
            raise Refused(ERR_CMD_SYNTAX, "download shorter than its count")
        self._write(self._mta, data)
        self._mta += n
        return bytes([PID_RES])

    def _short_download(self, p: bytes) -> bytes:
        n, _res, _ext, address = struct.unpack_from("<BBBI", p, 1)
        self._write(address, p[8 : 8 + n])
        return bytes([PID_RES])

    def _set_cal_page(self, p: bytes) -> bytes:
        mode, segment, page = p[1], p[2], p[3]
        if mode & 0x01 and self._protected & RES_CALPAG:
            raise Refused(ERR_ACCESS_LOCKED, "calibration is locked")
        self.pages.set_page(mode, segment, page)
        if mode & 0x01:
            self._protected |= RES_CALPAG  # every switch unlocks anew, as the banks do
        return bytes([PID_RES])

    def _get_cal_page(self, p: bytes) -> bytes:
        mode = p[1]
        page = self.pages.ecu_page if mode & 0x01 else self.pages.xcp_page
        return bytes([PID_RES, 0, 0, page])

    def _get_pag_processor_info(self, _p: bytes) -> bytes:
        return bytes([PID_RES, 1, 0x00])  # one segment, no freeze

    def _get_daq_processor_info(self, _p: bytes) -> bytes:
        # key byte 0: absolute ODT number as PID, address extension free, default optimisation
        if self.static_daq:
            return struct.pack("<BBHHBB", PID_RES, DAQ_PROPERTIES & ~0x01, STATIC_LISTS, 1, 0, 0x00)
        return struct.pack("<BBHHBB", PID_RES, DAQ_PROPERTIES, MAX_DAQ_LISTS, 1, 0, 0x00)

    def _get_daq_list_info(self, p: bytes) -> bytes:
        (daq,) = struct.unpack_from("<H", p, 2)
        if not self.static_daq or daq >= STATIC_LISTS:
            raise Refused(ERR_OUT_OF_RANGE, f"no static DAQ list {daq}")
        return struct.pack("<BBBBH", PID_RES, 0x04, STATIC_ODTS, STATIC_ENTRIES, 0)  # a DAQ list, no fixed event

    def _clear_daq_list(self, p: bytes) -> bytes:
        (daq,) = struct.unpack_from("<H", p, 2)
        d = self._daq[daq]
        d.running = d.selected = False
        d.odts = [[None] * len(entries) for entries in d.odts]
        self._arm()
        return bytes([PID_RES])

    def _get_daq_resolution_info(self, _p: bytes) -> bytes:
        return struct.pack("<BBBBBBH", PID_RES, 1, MAX_ODT_ENTRY_SIZE, 1, 0, TIMESTAMP_MODE, 1)

    def _get_daq_event_info(self, p: bytes) -> bytes:
        (event,) = struct.unpack_from("<H", p, 2)
        if event != 0:
            raise Refused(ERR_OUT_OF_RANGE, f"no event channel {event}")
        self._upload_text = EVENT_NAME
        return struct.pack("<BBBBBBB", PID_RES, 0x04, 0xFF, len(EVENT_NAME), EVENT_CYCLE, EVENT_UNIT_100US, 0xFF)

    def _get_daq_clock(self, _p: bytes) -> bytes:
        step, _rows = self.server.sample_at(time.time_ns())
        ticks = (self.clock.at(int(step) * self.server.rig.params.period_ns) // 1000) & 0xFFFFFFFF
        return struct.pack("<BBBBI", PID_RES, 0, 0, 0, ticks)

    def _stop_daq(self) -> None:
        for d in self._daq:
            d.running = False
        self._plan = None

    def _free_daq(self, _p: bytes) -> bytes:
        if self.static_daq:
            raise Refused(ERR_CMD_UNKNOWN, "static DAQ lists")
        self._stop_daq()
        self._daq, self._ptr = [], None
        return bytes([PID_RES])

    def _alloc_daq(self, p: bytes) -> bytes:
        if self.static_daq:
            raise Refused(ERR_CMD_UNKNOWN, "static DAQ lists")
        (count,) = struct.unpack_from("<H", p, 2)
        if self._daq or count > MAX_DAQ_LISTS:
            raise Refused(ERR_SEQUENCE if self._daq else ERR_OUT_OF_RANGE, "ALLOC_DAQ once after FREE_DAQ")
        self._daq = [DaqList() for _ in range(count)]
        return bytes([PID_RES])

    def _alloc_odt(self, p: bytes) -> bytes:
        if self.static_daq:
            raise Refused(ERR_CMD_UNKNOWN, "static DAQ lists")
        (daq,), count = struct.unpack_from("<H", p, 2), p[4]
        self._daq[daq].odts = [[] for _ in range(count)]
        return bytes([PID_RES])

    def _alloc_odt_entry(self, p: bytes) -> bytes:
        if self.static_daq:
            raise Refused(ERR_CMD_UNKNOWN, "static DAQ lists")
        (daq,), odt, count = struct.unpack_from("<H", p, 2), p[4], p[5]
        self._daq[daq].odts[odt] = [None] * count
        return bytes([PID_RES])

    def _set_daq_ptr(self, p: bytes) -> bytes:
        (daq,), odt, entry = struct.unpack_from("<H", p, 2), p[4], p[5]
        if entry >= len(self._daq[daq].odts[odt]):
            raise IndexError(entry)
        self._ptr = (daq, odt, entry)
        return bytes([PID_RES])

    def _write_daq(self, p: bytes) -> bytes:
        _bit, size, _ext, address = struct.unpack_from("<BBBI", p, 1)
        if self._ptr is None:
            raise Refused(ERR_SEQUENCE, "WRITE_DAQ before SET_DAQ_PTR")
        if not (MEASUREMENT_BASE <= address and address + size <= self.memory.end) or size > MAX_ODT_ENTRY_SIZE:
            raise Refused(ERR_OUT_OF_RANGE, f"no measurement at 0x{address:08X}+{size}")
        daq, odt, entry = self._ptr
        entries = self._daq[daq].odts[odt]
        entries[entry] = (size, address)
        self._ptr = (daq, odt, entry + 1)
        odt_bytes = 1 + 4 * (odt == 0) + sum(s for s, _a in filter(None, entries))
        if odt_bytes > self._limits()[1]:
            raise Refused(ERR_DAQ_CONFIG, f"ODT {odt} longer than MAX_DTO")
        return bytes([PID_RES])

    def _set_daq_list_mode(self, p: bytes) -> bytes:
        mode, daq, event, prescaler, _priority = struct.unpack_from("<BHHBB", p, 1)
        if event != 0:
            raise Refused(ERR_OUT_OF_RANGE, f"no event channel {event}")
        d = self._daq[daq]
        d.timestamp, d.prescaler = bool(mode & 0x10), max(1, prescaler)
        return bytes([PID_RES])

    def _start_stop_daq_list(self, p: bytes) -> bytes:
        mode, (daq,) = p[1], struct.unpack_from("<H", p, 2)
        d = self._daq[daq]
        d.first_pid = sum(len(x.odts) for x in self._daq[:daq])
        if d.first_pid + len(d.odts) > 0xFC:
            raise Refused(ERR_DAQ_CONFIG, "more ODTs than PIDs")
        if mode == 0:
            d.running = False
        elif mode == 1:
            d.running = True
        elif mode == 2:
            d.selected = True
        self._arm()
        return bytes([PID_RES, d.first_pid])

    def _start_stop_synch(self, p: bytes) -> bytes:
        mode = p[1]
        for d in self._daq:
            if mode == 0:
                d.running = False
            elif d.selected:
                d.running, d.selected = mode == 1, False
        self._arm()
        return bytes([PID_RES])

    _HANDLERS = {
        DISCONNECT: _disconnect, GET_STATUS: _get_status, SYNCH: _synch, GET_COMM_MODE_INFO: _get_comm_mode_info,
        GET_ID: _get_id, SET_REQUEST: _set_request, GET_SEED: _get_seed, UNLOCK: _unlock, SET_MTA: _set_mta,
        UPLOAD: _upload, SHORT_UPLOAD: _short_upload, BUILD_CHECKSUM: _build_checksum, DOWNLOAD: _download,
        SHORT_DOWNLOAD: _short_download, SET_CAL_PAGE: _set_cal_page, GET_CAL_PAGE: _get_cal_page,
        GET_PAG_PROCESSOR_INFO: _get_pag_processor_info, GET_DAQ_PROCESSOR_INFO: _get_daq_processor_info,
        GET_DAQ_RESOLUTION_INFO: _get_daq_resolution_info, GET_DAQ_EVENT_INFO: _get_daq_event_info,
        GET_DAQ_CLOCK: _get_daq_clock, FREE_DAQ: _free_daq, ALLOC_DAQ: _alloc_daq, ALLOC_ODT: _alloc_odt,
        ALLOC_ODT_ENTRY: _alloc_odt_entry, SET_DAQ_PTR: _set_daq_ptr, WRITE_DAQ: _write_daq,
        SET_DAQ_LIST_MODE: _set_daq_list_mode, START_STOP_DAQ_LIST: _start_stop_daq_list,
        START_STOP_SYNCH: _start_stop_synch, GET_DAQ_LIST_INFO: _get_daq_list_info, CLEAR_DAQ_LIST: _clear_daq_list,
    }
