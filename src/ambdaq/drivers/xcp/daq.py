"""XCP DAQ lists as ambdaq configures them, and the DTOs they bring back decoded by that layout
(ASAM MCD-1 XCP Part 2, "Data acquisition").

ambdaq packs each DAQ list's ODTs itself: one ODT entry per element, in the order measurements
were selected, an ODT filled until the next entry would not fit MAX_DTO (less the identification
field, and the timestamp on the first ODT) or its entries the list's room.  A slave with dynamic
DAQ configuration allocates the lists to fit; on one with static lists each event gets a free list
that holds it (GET_DAQ_LIST_INFO), cleared (CLEAR_DAQ_LIST) and written the same way.  The same plan that is written with WRITE_DAQ is the
one DTO bytes are read by, so a field always holds the bytes of its own address: what the slave
was told is what is decoded, whatever the order or sizes of the measurements.

A sample is the ODTs of one DAQ list in order; it is kept only whole.  An ODT out of order, of the
wrong length, or a sample across which the transport counter shows a lost packet, is discarded
and counted, never joined to another sample's ODTs.  Time is the first ODT's timestamp, in the
unit the slave states (GET_DAQ_RESOLUTION_INFO), unwrapped with the host's arrival times.
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ...errors import BadInputError
from .a2l import TYPES, A2lMeasurement
from .master import DaqListInfo, DaqProcessor, EventChannel

ID_SIZES = {0: 1, 1: 2, 2: 3, 3: 4}  # identification field: absolute PID; ODT + DAQ byte; + DAQ word; + fill + DAQ word
FILL_MAX = 3  # XCP on Ethernet may fill a DTO to a multiple of 4 bytes (Part 3)
MAX_PID = 0xFB  # 0xFC .. 0xFF are the slave's CTOs


@dataclass(frozen=True, eq=False)  # compared and hashed by identity: the plan's own elements
class Element:
    """One recorded value: a measurement's element ``index`` at ``address``, recorded as ``field``."""

    measurement: A2lMeasurement
    index: int
    field: str

    @property
    def address(self) -> int:
        return self.measurement.address + self.index * self.measurement.size


@dataclass
class DaqListPlan:
    """One DAQ list: its number, event, ODTs of elements, and how its DTOs read.

    Attributes
    ----------
    number : int
        The absolute DAQ list number.
    event : EventChannel
        The event it samples on.
    odts : list of list of Element
        Its ODTs' entries.
    header : int
        Bytes of the identification field.
    timestamp : int
        Bytes of the timestamp on its first ODT (0: none).
    counter : Element or None
        The element whose value numbers the samples (a control-period counter), if any.
    """

    number: int
    event: EventChannel
    odts: list[list[Element]]
    header: int
    timestamp: int
    prescaler: int = 1
    counter: Element | None = None
    first_pid: int = 0
    lengths: list[int] = field(default_factory=list)
    offsets: dict[Element, int] = field(default_factory=dict)
    payload: int = 0

    def __post_init__(self) -> None:
        at = 0
        for j, odt in enumerate(self.odts):
            self.lengths.append(self.header + (self.timestamp if j == 0 else 0) + sum(e.measurement.size for e in odt))
            for e in odt:
                self.offsets[e] = at
                at += e.measurement.size
        self.payload = at

    @property
    def elements(self) -> list[Element]:
        return [e for odt in self.odts for e in odt]

    def dtype(self) -> np.dtype:
        """The numpy layout of one sample's payload (its ODTs' entries, headers removed)."""
        names, formats, offsets = [], [], []
        for k, e in enumerate(self.elements):
            kind, size = TYPES[e.measurement.datatype]
            names.append(f"e{k}")
            formats.append(f"{e.measurement.byte_order}{kind}{size}")
            offsets.append(self.offsets[e])
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.payload})


MAX_ALLOC_ENTRIES = 0xFF  # ALLOC_ODT_ENTRY's count is a byte


def _pack(elements: list[Element], processor: DaqProcessor, max_dto: int, header: int, timestamp: int,
          max_entries: int, url: str) -> list[list[Element]]:
    """The ODTs of one list: each element into the first ODT it fits, in bytes (MAX_DTO, less the
    identification field and, on the first, the timestamp) and in entries (``max_entries``)."""
    max_entry = processor.max_entry_size * processor.granularity
    odts: list[list[Element]] = [[]]
    rooms = [max_dto - header - timestamp]  # the first ODT also carries the timestamp
    for e in elements:  # first fit: a small element fills a gap an earlier ODT left
        size = e.measurement.size
        if size % processor.granularity or size > max_entry:
            raise BadInputError(f"{url}: {e.measurement.name} is {size} bytes; the slave's ODT entries are "
                                f"multiples of {processor.granularity} up to {max_entry} bytes")
        fits = [j for j, room in enumerate(rooms) if size <= room and len(odts[j]) < max_entries and (
            processor.address_extension != "odt" or not odts[j]
            or odts[j][0].measurement.extension == e.measurement.extension)]
        if not fits:
            if size > max_dto - header:
                raise BadInputError(f"{url}: {e.measurement.name} ({size} bytes) does not fit a {max_dto}-byte DTO")
            odts.append([])
            rooms.append(max_dto - header)
            fits = [len(odts) - 1]
        odts[fits[0]].append(e)
        rooms[fits[0]] -= size
    return odts


def plan_lists(by_event: dict[int, list[Element]], events: dict[int, EventChannel], processor: DaqProcessor,
               max_dto: int, *, prescaler: int, counters: dict[int, Element | None], url: str,
               static_lists: list[DaqListInfo] | None = None) -> list[DaqListPlan]:
    """Pack each event's elements into one DAQ list's ODTs (the slave's limits checked first).

    A slave with dynamic DAQ configuration gets lists numbered from MIN_DAQ, allocated to fit. A
    static one (``static_lists``: GET_DAQ_LIST_INFO of each configurable list) gives each event the
    first list free for it (its fixed event, or none) whose ODTs and entries per ODT hold the
    elements as packed for it; predefined lists, whose entries are fixed, are not used."""
    header = ID_SIZES[processor.identification]
    timestamp = processor.timestamp_size if (processor.timestamps or processor.timestamp_fixed) else 0
    plans = []
    odt_limit = 0x7C if processor.overload == "pid" else MAX_PID + 1
    taken: set[int] = set()
    for i, (event, elements) in enumerate(by_event.items()):
        name = events[event].name
        if processor.address_extension == "daq" and len({e.measurement.extension for e in elements}) > 1:
            raise BadInputError(f"{url}: the slave takes one address extension per DAQ list, and the measurements on "
                                f"event {name!r} have several")
        if static_lists is None:
            number, odts = processor.min_daq + i, _pack(elements, processor, max_dto, header, timestamp,
                                                        MAX_ALLOC_ENTRIES, url)
        else:
            free = sorted((d for d in static_lists if d.daq and not d.predefined and d.number not in taken
                           and d.fixed_event in (None, event)), key=lambda d: d.fixed_event is None)
            found = None
            for d in free:  # a list fixed to this event first
                odts = _pack(elements, processor, max_dto, header, timestamp, max(d.max_odt_entries, 1), url)
                if len(odts) <= d.max_odt:
                    found = d
                    break
            if found is None:
                room = ", ".join(f"{d.number}: {d.max_odt} ODTs of {d.max_odt_entries} entries" for d in free) or "none"
                raise BadInputError(f"{url}: the slave's DAQ lists are static and none free for event {name!r} holds "
                                    f"its {len(elements)} entries (lists free for it: {room})")
            number = found.number
            taken.add(number)
        if len(odts) > odt_limit:
            raise BadInputError(f"{url}: event {name!r} needs {len(odts)} ODTs, more than the "
                                f"{odt_limit} a DAQ list's identification field can number")
        plans.append(DaqListPlan(number, events[event], odts, header, timestamp, prescaler, counters.get(event)))
    return plans


@dataclass
class ListState:
    """What the receive thread knows of one DAQ list's DTOs: the sample being assembled, the whole
    ones waiting, and what was discarded."""

    plan: DaqListPlan
    rows: deque  # whole samples for the list's source: (seq, arrival ns, raw timestamp, payload bytes)
    partial: list | None = None  # [arrival, timestamp, loss marker, payloads]
    index: int = 0
    counter_last: int | None = None
    counter_base: int = 0
    incomplete: int = 0  # samples discarded: an ODT lost, out of order or across a transport loss
    malformed: int = 0  # DTOs of the wrong length
    overloads: int = 0  # DTOs whose PID flags a slave overload


class DtoAssembler:
    """Whole samples from the DTOs of ``plans``, as the receive thread hands them in.

    Parameters
    ----------
    plans : list of DaqListPlan
        The lists as configured (their first PIDs set after selection).
    rows : list of deque
        Where each list's whole samples go (its source's row queue), in the order of ``plans``.
    processor : DaqProcessor
        How the slave identifies DTOs and flags overload.
    byte_order : str
        The slave's byte order (the DAQ number and timestamp fields).
    loss : callable
        A number that changes whenever the transport loses packets (its lost-packet count).
    padded_to : int
        A DTO may be padded up to this many bytes (CAN: 8); 0 for Ethernet's fill to 4.
    """

    def __init__(self, plans: list[DaqListPlan], rows: list[deque], processor: DaqProcessor, byte_order: str, loss,
                 padded_to: int) -> None:
        self.states = {p.number: ListState(p, r) for p, r in zip(plans, rows)}
        self.mode = processor.identification
        self.overload_pid = processor.overload == "pid"
        self.loss = loss
        self.padded_to = padded_to
        self.unknown = 0  # DTOs of no configured list
        self._daq = struct.Struct(byte_order + "H")
        self._stamp = {1: struct.Struct("B"), 2: struct.Struct(byte_order + "H"), 4: struct.Struct(byte_order + "I")}
        self._by_pid: dict[int, tuple[ListState, int]] = {}

    def selected(self) -> None:
        """The lists' first PIDs are known (absolute identification)."""
        for s in self.states.values():
            for j in range(len(s.plan.odts)):
                self._by_pid[s.plan.first_pid + j] = (s, j)

    def on_dto(self, arrival: int, packet: bytes) -> None:
        pid = packet[0]
        overload = False
        if self.overload_pid and pid & 0x80:
            pid &= 0x7F
            overload = True
        if self.mode == 0:
            found = self._by_pid.get(pid)
            if found is None:
                self.unknown += 1
                return
            state, odt = found
        else:
            n = len(packet)
            if n < ID_SIZES[self.mode]:
                self.unknown += 1
                return
            daq = packet[1] if self.mode == 1 else self._daq.unpack_from(packet, 1 if self.mode == 2 else 2)[0]
            state = self.states.get(daq)
            odt = pid
            if state is None or odt >= len(state.plan.odts):
                self.unknown += 1
                return
        plan = state.plan
        if overload:
            state.overloads += 1
        want = plan.lengths[odt]
        if not want <= len(packet) <= max(want + FILL_MAX, self.padded_to):
            state.malformed += 1
            if state.partial is not None:
                state.incomplete += 1
                state.partial = None
            return
        start = plan.header
        if odt == 0:
            if state.partial is not None:
                state.incomplete += 1
            stamp = self._stamp[plan.timestamp].unpack_from(packet, start)[0] if plan.timestamp else 0
            state.partial = [arrival, stamp, self.loss(), [packet[start + plan.timestamp : want]]]
        else:
            partial = state.partial
            if partial is None or len(partial[3]) != odt or partial[2] != self.loss():
                if partial is not None:
                    state.incomplete += 1
                state.partial = None
                return
            partial[3].append(packet[start:want])
        partial = state.partial
        if len(partial[3]) == len(plan.odts):
            state.partial = None
            payload = b"".join(partial[3])
            state.rows.append((self._seq(state, payload), partial[0], partial[1], payload))

    def _seq(self, state: ListState, payload: bytes) -> int:
        """The sample's number: its counter (unwrapped, divided by the prescaler) or its index."""
        counter = state.plan.counter
        if counter is None:
            state.index += 1
            return state.index - 1
        m = counter.measurement
        kind, size = TYPES[m.datatype]
        (value,) = struct.unpack_from(m.byte_order + {1: "B", 2: "H", 4: "I", 8: "Q"}[size], payload,
                                      state.plan.offsets[counter])
        modulus = 1 << (8 * size)
        if state.counter_last is not None and value < state.counter_last and state.counter_last - value > modulus // 2:
            state.counter_base += modulus  # the counter wrapped
        state.counter_last = value
        return (state.counter_base + value) // state.plan.prescaler


LATE_S = 1.0  # a DTO's timestamp may run ahead of its arrival by this much (a slave's queue, a burst)


def unwrap_timestamps(raw: np.ndarray, arrival_ns: np.ndarray, tick_ns: int, size: int,
                      last: tuple[int, int, int] | None) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int] | None]:
    """Device times in ns from DTO timestamps of ``size`` bytes that count ``tick_ns`` each and wrap,
    and which of them are plausible.

    Between two samples the timestamp advanced by its step modulo the wrap, plus as many whole
    wraps as the host's arrival times say passed (a sporadic event may be silent for longer than
    one wrap: 4.3 s for a 32-bit timestamp in ns).  A sample whose timestamp ran more than
    ``LATE_S`` ahead of the time between the two arrivals cannot be the slave's clock (garbage
    that framed as a DTO): it is marked implausible, and the next sample is timed from the last
    plausible one.

    Parameters
    ----------
    raw : ndarray of int64
        The timestamps as sent, in ticks.
    arrival_ns : ndarray of int64
        Host arrival times, ns.
    tick_ns : int
        One tick, ns.
    size : int
        Timestamp bytes.
    last : (device ns, raw ticks, arrival ns) or None
        The last plausible sample's, None before the first.

    Returns
    -------
    device_ns : ndarray of int64
        Unwrapped device times, ns (meaningless where not plausible).
    plausible : ndarray of bool
    last : tuple or None
        The newest plausible sample's (device ns, raw ticks, arrival ns).
    """
    wrap = (1 << (8 * size)) * tick_ns
    device = np.zeros(raw.shape[0], dtype=np.int64)
    plausible = np.ones(raw.shape[0], dtype=bool)
    late = int(LATE_S * 1e9)
    for k, (r, a) in enumerate(zip(raw.tolist(), arrival_ns.tolist())):
        if last is None:
            last = (r * tick_ns, r, a)
            device[k] = r * tick_ns
            continue
        step = (r - last[1]) * tick_ns % wrap
        host = a - last[2]
        step += max(0, round((host - step) / wrap)) * wrap
        if step - host > late:
            plausible[k] = False
            continue
        device[k] = last[0] + step
        last = (int(device[k]), r, a)
    return device, plausible, last
