"""The XCP master's protocol layer (ASAM MCD-1 XCP Part 2): commands and their responses, in the
slave's byte order, over a :mod:`.transport` link.

ambdaq speaks XCP itself rather than through pyxcp, whose compiled response and DAQ handling
a slave's bytes reach: with 1 MB of garbage after CONNECT it ended the process with SIGSEGV,
and a one-byte DTO with SIGABRT (docs/hardware.md, "XCP").  Here every response is length-checked
before it is unpacked, and what does not parse is one :class:`~ambdaq.errors.DeviceError` line.
pyxcp stays the independent master the tests read the same slaves with.

One receive thread reads the link: responses (PID 0xFF, 0xFE) go to the waiting command, events
(0xFD) and service requests (0xFC) are counted and kept, every other packet is a DTO handed to
the DAQ sink (:mod:`.daq`).  One command is outstanding at a time.
"""

from __future__ import annotations

import queue
import struct
import threading
from dataclasses import dataclass

from ...errors import DeviceError
from .transport import Link
from .wire import (ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY, BUILD_CHECKSUM, CHECKSUM_TYPES, CLEAR_DAQ_LIST, CONNECT,
                   COPY_CAL_PAGE, DISCONNECT, DOWNLOAD, ERR_CMD_UNKNOWN, EV_CMD_PENDING, EV_DAQ_OVERLOAD,
                   EV_SESSION_TERMINATED, FREE_DAQ, GET_CAL_PAGE, GET_COMM_MODE_INFO, GET_DAQ_EVENT_INFO,
                   GET_DAQ_LIST_INFO, GET_DAQ_PROCESSOR_INFO, GET_DAQ_RESOLUTION_INFO, GET_ID, GET_SEED, GET_STATUS,
                   PID_ERR, PID_EV, PID_SERV, RES_CALPAG, RES_DAQ, RES_PGM, RES_STIM, SERV_TEXT,
                   SET_CAL_PAGE, SET_DAQ_LIST_MODE, SET_DAQ_PTR, SET_MTA, SET_REQUEST,
                   START_STOP_DAQ_LIST, START_STOP_SYNCH, TIME_UNITS_NS, UNLOCK, UPLOAD, WRITE_DAQ,
                   XCP_ERRORS)

TIMEOUT_S = 1.0  # a command unanswered this long is a timeout (ASAM XCP Part 2's T1, 1 s as slaves commonly set it)
PENDING_S = 5.0  # how long EV_CMD_PENDING may extend it, in all
DISCONNECT_S = 0.5  # how long the DISCONNECT of a session ended by an error waits for its answer

RESOURCES = {"calpag": RES_CALPAG, "daq": RES_DAQ, "stim": RES_STIM, "pgm": RES_PGM}

OPTIONAL = {GET_COMM_MODE_INFO: "GET_COMM_MODE_INFO", GET_ID: "GET_ID", GET_DAQ_PROCESSOR_INFO: "GET_DAQ_PROCESSOR_INFO", GET_DAQ_RESOLUTION_INFO: "GET_DAQ_RESOLUTION_INFO",
            GET_DAQ_EVENT_INFO: "GET_DAQ_EVENT_INFO", GET_DAQ_LIST_INFO: "GET_DAQ_LIST_INFO"}
"""The commands ambdaq asks that ASAM XCP Part 2 makes optional and whose answers an A2L can give
instead (its IF_DATA XCP): a slave that answers one with ERR_CMD_UNKNOWN is asked no more, and the
master says so (:attr:`XcpMaster.lacking`)."""



class XcpRefused(DeviceError):
    """A negative response: ``code`` and its name (:data:`XCP_ERRORS`)."""

    def __init__(self, code: int) -> None:
        self.code = code
        name, meaning = XCP_ERRORS.get(code, (f"error 0x{code:02X}", "not an error code of ASAM XCP"))
        self.error_name = name
        super().__init__(f"{name} ({meaning})")


@dataclass(frozen=True)
class SlaveInfo:
    """What CONNECT answered (Part 2, CONNECT)."""

    resources: int
    byte_order: str  # "<" Intel, ">" Motorola
    address_granularity: int  # bytes per address unit
    max_cto: int
    max_dto: int
    protocol_version: int
    transport_version: int
    optional_comm_mode: bool


@dataclass(frozen=True)
class DaqProcessor:
    """GET_DAQ_PROCESSOR_INFO and GET_DAQ_RESOLUTION_INFO (Part 2)."""

    dynamic: bool
    prescaler: bool
    timestamps: bool
    overload: str  # "none", "pid" (the PID's most significant bit), "event" (EV_DAQ_OVERLOAD)
    max_daq: int
    max_event: int
    min_daq: int
    address_extension: str  # "free", "odt" (one per ODT), "daq" (one per DAQ list)
    identification: int  # 0 absolute PID, 1 relative ODT + DAQ byte, 2 + DAQ word, 3 + fill + DAQ word
    granularity: int  # bytes: an ODT entry's size is a multiple of it
    max_entry_size: int  # in granules
    timestamp_size: int  # bytes, 0 for none
    timestamp_fixed: bool
    timestamp_ns: int  # one tick, in ns


@dataclass(frozen=True)
class DaqListInfo:
    """GET_DAQ_LIST_INFO (Part 2) of a static DAQ list: its number, whether it is predefined (its
    entries fixed) or tied to one event (``fixed_event``, else None), its room (ODTs, entries per ODT)."""

    number: int
    predefined: bool
    fixed_event: int | None
    daq: bool  # a DAQ (not only STIM) list
    max_odt: int
    max_odt_entries: int


@dataclass(frozen=True)
class EventChannel:
    """GET_DAQ_EVENT_INFO (Part 2): a DAQ event channel's name, cycle (0 ns: sporadic) and lists."""

    number: int
    name: str
    cycle_ns: int
    max_lists: int
    daq: bool


class XcpMaster:
    """One session with the slave on ``link``.

    Parameters
    ----------
    link : Link
        The transport (:mod:`.transport`), opened.
    url : str
        The device URL, for messages.
    on_dto : callable, optional
        ``on_dto(arrival_ns, packet)`` for every DTO, on the receive thread.
    """

    def __init__(self, link: Link, url: str, on_dto=None) -> None:
        self.link, self.url = link, url
        self.on_dto = on_dto
        self.info: SlaveInfo | None = None
        self.order = "<"
        self.failure: str | None = None
        self.overload_events = 0
        self.service_texts: list[str] = []
        self.unexpected = 0  # packets that were neither an awaited response nor a DTO of a list
        self.lacking: list[str] = []  # optional commands the slave answered ERR_CMD_UNKNOWN (OPTIONAL)
        self._connected = False
        self._responses: queue.Queue[bytes] = queue.Queue()
        self._pending = threading.Event()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive, name="xcp-rx", daemon=True)
        self._thread.start()

    # --- the receive thread ---------------------------------------------------------------------

    def _receive(self) -> None:
        try:
            while not self._stop.is_set():
                got = self.link.receive()
                if got is None:
                    if not self._stop.is_set():
                        self.failure = f"{self.url}: the slave closed the connection"
                    return
                for arrival, packet in got:
                    self._dispatch(arrival, packet)
        except DeviceError as err:
            self.failure = str(err)
        except Exception as err:  # a bug here must end the session with a line, not hang it
            self.failure = f"{self.url}: receive failed ({type(err).__name__}: {err})"
        finally:
            self._responses.put(b"")  # wake a waiting command

    def _dispatch(self, arrival: int, packet: bytes) -> None:
        pid = packet[0]
        if pid >= PID_ERR:
            self._responses.put(packet)
        elif pid == PID_EV:
            code = packet[1] if len(packet) > 1 else -1
            if code == EV_CMD_PENDING:
                self._pending.set()
            elif code == EV_DAQ_OVERLOAD:
                self.overload_events += 1
            elif code == EV_SESSION_TERMINATED:
                self.failure = f"{self.url}: the slave terminated the session (EV_SESSION_TERMINATED)"
        elif pid == PID_SERV:
            if len(packet) > 2 and packet[1] == SERV_TEXT and len(self.service_texts) < 100:
                self.service_texts.append(packet[2:].split(b"\0")[0].decode("latin-1")[:200])
        elif self.on_dto is not None:
            self.on_dto(arrival, packet)
        else:
            self.unexpected += 1

    # --- commands -------------------------------------------------------------------------------

    def command(self, *body: int | bytes, expect: int = 1, timeout_s: float = TIMEOUT_S) -> bytes:
        """Send one command (bytes and byte values), return its positive response of at least
        ``expect`` bytes; :class:`XcpRefused` for a negative one, DeviceError for none."""
        packet = b"".join(bytes([b]) if isinstance(b, int) else b for b in body)
        if self.info is not None and len(packet) > self.info.max_cto:
            raise DeviceError(f"{self.url}: a {len(packet)}-byte command exceeds the slave's MAX_CTO {self.info.max_cto}")
        with self._lock:
            if self.failure:
                raise DeviceError(self.failure)
            while not self._responses.empty():  # a late answer to a command that timed out
                self._responses.get_nowait()
            self._pending.clear()
            self.link.send(packet)
            waited = 0.0
            while True:
                try:
                    response = self._responses.get(timeout=timeout_s)
                    break
                except queue.Empty:
                    waited += timeout_s
                    if self._pending.is_set() and waited < PENDING_S:
                        self._pending.clear()
                        continue
                    raise DeviceError(f"{self.url}: no answer to command 0x{packet[0]:02X} (timeout)") from None
        if not response:
            raise DeviceError(self.failure or f"{self.url}: the link closed")
        if response[0] == PID_ERR:
            raise XcpRefused(response[1] if len(response) > 1 else 0x31)
        if len(response) < expect:
            raise DeviceError(f"{self.url}: a {len(response)}-byte response to command 0x{packet[0]:02X}, "
                              f"where at least {expect} are due")
        return response

    def optional(self, code: int, *body: int | bytes, expect: int = 1) -> bytes | None:
        """An optional command (:data:`OPTIONAL`): its response, or None where the slave lacks it
        (ERR_CMD_UNKNOWN, remembered in :attr:`lacking`, not asked again)."""
        name = OPTIONAL[code]
        if name in self.lacking:
            return None
        try:
            return self.command(code, *body, expect=expect)
        except XcpRefused as err:
            if err.code != ERR_CMD_UNKNOWN:
                raise
            self.lacking.append(name)
            return None

    def _u16(self, value: int) -> bytes:
        return struct.pack(self.order + "H", value)

    def _u32(self, value: int) -> bytes:
        return struct.pack(self.order + "I", value)

    def unpack(self, fmt: str, data: bytes, offset: int = 0) -> tuple:
        return struct.unpack_from(self.order + fmt, data, offset)

    def connect(self) -> SlaveInfo:
        r = self.command(CONNECT, 0x00, expect=8)
        basic = r[2]
        order = ">" if basic & 0x01 else "<"
        (max_dto,) = struct.unpack_from(order + "H", r, 4)
        info = SlaveInfo(r[1], order, 1 << ((basic >> 1) & 0x03), r[3], max_dto, r[6], r[7], bool(basic & 0x80))
        if info.max_cto < 8 or info.max_dto < 8:
            raise DeviceError(f"{self.url}: the slave answered CONNECT with MAX_CTO {info.max_cto}, MAX_DTO "
                              f"{info.max_dto} (at least 8 each)")
        if info.address_granularity != 1:
            raise DeviceError(f"{self.url}: the slave's address granularity is {info.address_granularity} bytes; "
                              "ambdaq speaks to byte-addressed slaves (ADDRESS_GRANULARITY_BYTE)")
        self.info, self.order = info, order
        self.link.max_packet = max(info.max_cto, info.max_dto)
        self._connected = True
        return info

    def disconnect(self) -> None:
        """End the session (DISCONNECT): a slave that serves one master at a time takes the next."""
        self._connected = False
        self.command(DISCONNECT)

    def get_status(self) -> tuple[int, int]:
        """Session status and resource protection bits."""
        r = self.command(GET_STATUS, expect=3)
        return r[1], r[2]

    def get_comm_mode_info(self) -> None:
        self.optional(GET_COMM_MODE_INFO, expect=1)

    def get_id(self, kind: int) -> bytes | None:
        """GET_ID of ``kind`` (1: the ASAM MC 2 file name without extension, 4: the A2L file):
        in the response, or uploaded; None where the slave lacks GET_ID."""
        r = self.optional(GET_ID, kind, expect=8)
        if r is None:
            return None
        (length,) = self.unpack("I", r, 4)
        if r[1] & 0x01:
            return bytes(r[8 : 8 + length])
        return self.upload(length)

    def upload(self, length: int) -> bytes:
        """UPLOAD ``length`` bytes from the MTA, MAX_CTO - 1 per command."""
        out = bytearray()
        step = self.info.max_cto - 1
        while len(out) < length:
            n = min(step, length - len(out))
            r = self.command(UPLOAD, n, expect=1 + n)
            out += r[1 : 1 + n]
        return bytes(out)

    def set_mta(self, extension: int, address: int) -> None:
        self.command(SET_MTA, 0, 0, extension, self._u32(address))

    def read(self, extension: int, address: int, length: int) -> bytes:
        """``length`` bytes at ``address`` in address space ``extension``."""
        if length <= 0:
            return b""
        self.set_mta(extension, address)
        return self.upload(length)

    def write(self, extension: int, address: int, data: bytes) -> None:
        """DOWNLOAD ``data`` at ``address``, MAX_CTO - 2 bytes per command, each answered before
        the next (no block mode)."""
        self.set_mta(extension, address)
        step = self.info.max_cto - 2
        for i in range(0, len(data), step):
            chunk = data[i : i + step]
            self.command(DOWNLOAD, len(chunk), chunk)

    def build_checksum(self, extension: int, address: int, length: int) -> tuple[str, int]:
        """The slave's checksum of ``length`` bytes at ``address``: its type's name and value."""
        self.set_mta(extension, address)
        r = self.command(BUILD_CHECKSUM, 0, 0, 0, self._u32(length), expect=8)
        (value,) = self.unpack("I", r, 4)
        return CHECKSUM_TYPES.get(r[1], f"type 0x{r[1]:02X}"), value

    def get_seed(self, resource: int) -> bytes:
        """The slave's seed for ``resource``, all its parts."""
        r = self.command(GET_SEED, 0, resource, expect=2)
        remaining, seed = r[1], bytearray(r[2:])
        if remaining == 0:
            return b""  # the resource is not protected
        seed = seed[:remaining]
        while len(seed) < remaining:
            r = self.command(GET_SEED, 1, resource, expect=2)
            seed += r[2 : 2 + r[1]]
        return bytes(seed[:remaining])

    def unlock(self, key: bytes) -> int:
        """UNLOCK with ``key`` (in parts of MAX_CTO - 2); the protection status left."""
        step, left, r = self.info.max_cto - 2, len(key), b""
        for i in range(0, len(key), step):
            r = self.command(UNLOCK, left, key[i : i + step], expect=2)
            left -= len(key[i : i + step])
        return r[1]

    def set_request(self, mode: int, session_id: int = 0) -> None:
        self.command(SET_REQUEST, mode, self._u16(session_id))

    def set_cal_page(self, mode: int, segment: int, page: int) -> None:
        self.command(SET_CAL_PAGE, mode, segment, page)

    def get_cal_page(self, mode: int, segment: int) -> int:
        return self.command(GET_CAL_PAGE, mode, segment, expect=4)[3]

    def copy_cal_page(self, src: tuple[int, int], dst: tuple[int, int]) -> None:
        self.command(COPY_CAL_PAGE, src[0], src[1], dst[0], dst[1])

    # --- DAQ --------------------------------------------------------------------------------------

    def daq_processor(self, declared=None) -> DaqProcessor:
        """GET_DAQ_PROCESSOR_INFO and GET_DAQ_RESOLUTION_INFO; where the slave lacks either
        (optional in ASAM XCP), what ``declared`` (the A2L's IF_DATA XCP DAQ block,
        :class:`~.a2l.A2lDaq`) says instead, as ASAM MCD-2 MC makes the A2L the description of a
        slave.  DeviceError where neither says."""
        r = self.optional(GET_DAQ_PROCESSOR_INFO, expect=8)
        res = self.optional(GET_DAQ_RESOLUTION_INFO, expect=8)
        if (r is None or res is None) and declared is None:
            lacks = " and ".join(n for n in ("GET_DAQ_PROCESSOR_INFO", "GET_DAQ_RESOLUTION_INFO") if n in self.lacking)
            raise DeviceError(f"{self.url}: the slave lacks {lacks} (optional in ASAM XCP) and the A2L declares no "
                              "IF_DATA XCP DAQ block to read instead")
        if r is not None:
            props, key = r[1], r[7]
            max_daq, max_event = self.unpack("HH", r, 2)
            dynamic, prescaler, timestamps = bool(props & 0x01), bool(props & 0x02), bool(props & 0x10)
            overload, min_daq = {0: "none", 1: "pid", 2: "event"}.get(props >> 6, "none"), r[6]
            extension, identification = {0: "free", 1: "odt", 3: "daq"}.get((key >> 4) & 0x03, "daq"), key >> 6
        else:
            d = declared
            dynamic, prescaler, timestamps = d.dynamic, False, d.timestamp_size > 0
            overload, min_daq, max_daq, max_event = d.overload, d.min_daq, d.max_daq, d.max_event
            extension, identification = d.address_extension, d.identification
        if res is not None:
            mode = res[5]
            (ticks,) = self.unpack("H", res, 6)
            unit = mode >> 4
            if unit not in TIME_UNITS_NS:
                raise DeviceError(f"{self.url}: GET_DAQ_RESOLUTION_INFO names timestamp unit {unit}, which ASAM XCP "
                                  "1.x does not define")
            size, fixed, tick_ns = mode & 0x07, bool(mode & 0x08), TIME_UNITS_NS[unit] * max(ticks, 1)
            granularity, max_entry = res[1], res[2]
        else:
            size, fixed, tick_ns = declared.timestamp_size, declared.timestamp_fixed, declared.timestamp_ns
            granularity, max_entry = declared.granularity, declared.max_entry_size
        if size not in (0, 1, 2, 4):
            raise DeviceError(f"{self.url}: a {size}-byte DAQ timestamp (0, 1, 2 or 4)")
        if granularity not in (1, 2, 4, 8):
            raise DeviceError(f"{self.url}: ODT entry granularity {granularity} (1, 2, 4 or 8)")
        return DaqProcessor(dynamic=dynamic, prescaler=prescaler, timestamps=timestamps, overload=overload,
                            max_daq=max_daq, max_event=max_event, min_daq=min_daq, address_extension=extension,
                            identification=identification, granularity=granularity, max_entry_size=max_entry,
                            timestamp_size=size, timestamp_fixed=fixed, timestamp_ns=tick_ns)

    def event_channel(self, number: int, declared=()) -> EventChannel:
        """GET_DAQ_EVENT_INFO of event ``number``; where the slave lacks it, the A2L's EVENT of that
        number among ``declared`` (:class:`~.a2l.A2lEvent`), else an event named ``event_N`` whose
        cycle is not known (sporadic)."""
        r = self.optional(GET_DAQ_EVENT_INFO, 0, self._u16(number), expect=7)
        if r is None:
            e = next((e for e in declared if e.number == number), None)
            return EventChannel(number, e.name if e is not None else f"event_{number}",
                                e.cycle_ns if e is not None else 0, 255, True)
        props, max_lists, name_length, cycle, unit = r[1], r[2], r[3], r[4], r[5]
        name = self.upload(name_length).decode("latin-1") if name_length else ""
        if cycle and unit not in TIME_UNITS_NS:
            raise DeviceError(f"{self.url}: event {number} names time unit {unit}, which ASAM XCP 1.x does not define")
        return EventChannel(number, name.rstrip("\0"), cycle * TIME_UNITS_NS.get(unit, 0), max_lists, bool(props & 0x04))

    def daq_list_info(self, number: int, declared=()) -> DaqListInfo | None:
        """GET_DAQ_LIST_INFO of static list ``number``; where the slave lacks it, the A2L's DAQ_LIST
        of that number among ``declared`` (:class:`~.a2l.A2lDaqList`), else None."""
        r = self.optional(GET_DAQ_LIST_INFO, 0, self._u16(number), expect=6)
        if r is None:
            d = next((d for d in declared if d.number == number), None)
            return None if d is None else DaqListInfo(number, d.predefined, d.fixed_event, d.daq, d.max_odt,
                                                      d.max_odt_entries)
        props = r[1]
        (fixed,) = self.unpack("H", r, 4)
        return DaqListInfo(number, bool(props & 0x01), fixed if props & 0x02 else None, bool(props & 0x04) or
                           not props & 0x0C, r[2], r[3])

    def clear_daq_list(self, number: int) -> None:
        self.command(CLEAR_DAQ_LIST, 0, self._u16(number))

    def free_daq(self) -> None:
        self.command(FREE_DAQ)

    def alloc_daq(self, count: int) -> None:
        self.command(ALLOC_DAQ, 0, self._u16(count))

    def alloc_odt(self, daq: int, count: int) -> None:
        self.command(ALLOC_ODT, 0, self._u16(daq), count)

    def alloc_odt_entry(self, daq: int, odt: int, count: int) -> None:
        self.command(ALLOC_ODT_ENTRY, 0, self._u16(daq), odt, count)

    def set_daq_ptr(self, daq: int, odt: int, entry: int) -> None:
        self.command(SET_DAQ_PTR, 0, self._u16(daq), odt, entry)

    def write_daq(self, size: int, extension: int, address: int) -> None:
        self.command(WRITE_DAQ, 0xFF, size, extension, self._u32(address))

    def set_daq_list_mode(self, daq: int, event: int, *, timestamp: bool, prescaler: int) -> None:
        self.command(SET_DAQ_LIST_MODE, 0x10 if timestamp else 0x00, self._u16(daq), self._u16(event), prescaler, 0)

    def select_daq_list(self, daq: int) -> int:
        """START_STOP_DAQ_LIST (select): the list's first PID."""
        return self.command(START_STOP_DAQ_LIST, 0x02, self._u16(daq), expect=2)[1]

    def start_stop_synch(self, mode: int) -> None:
        """0: stop all, 1: start the selected lists, 2: stop them."""
        self.command(START_STOP_SYNCH, mode)

    def close(self) -> None:
        """End the session and release the link: a session still open is ended with DISCONNECT
        however the command ends (an error, Ctrl-C, a peer's garbage), since a slave that serves one
        master at a time answers no other CONNECT until it hears one.  Where the link still frames
        answers, DISCONNECT is asked and its answer awaited briefly; where it does not, it is sent
        all the same.  Safe to call twice."""
        if self._connected:
            self._connected = False
            try:
                if self.failure is None:
                    self.command(DISCONNECT, timeout_s=DISCONNECT_S)
                else:
                    self.link.send(bytes([DISCONNECT]))
            except (DeviceError, OSError):
                pass  # the slave is gone or refuses: nothing more to end
        self._stop.set()
        self.link.close()
        self._thread.join(timeout=2)
