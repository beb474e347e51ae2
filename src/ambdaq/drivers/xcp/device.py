"""An AMB controller, or any ECU, over ASAM XCP with ambdaq as the master (:mod:`.master`):
measurements from its A2L file recorded through DAQ lists, parameters read and written by
UPLOAD/DOWNLOAD, and ``ambdaq push`` into a calibration page (docs/hardware.md, "XCP").

Recording: the measurements asked for (``--measure``, a rig file's ``measurements``; by default
those an ``ambdaq`` annotation places) go on the DAQ event their A2L names (FIXED_EVENT_LIST,
else the URL's ``event=N``, else DEFAULT_EVENT_LIST, else the slave's only event), one DAQ list
per event (:mod:`.daq`), sporadic and cyclic events alike.  Each event is one source of the
recording; a measurement without an annotation goes to the topic ``/xcp/<event name>``.  A
sample's time is its DTO timestamp; its ``seq`` is a control-period counter where one is named
(``counter=NAME`` or ``role=counter``), else its arrival index.  Loss is counted from the
transport's counter (Ethernet, SxI) and the slave's overload indication, and the device's
metadata says where neither exists (CAN).

Pushing (:class:`~ambdaq.drivers.interfaces.BankPort`, the same rules as every controller):
seed & key for CAL/PAG (the algorithm by name, :mod:`.keys`); the image is downloaded into the
inactive page of segment 0 (``coefficient_bank``: u32 length + image); the device's CRC-32 of
it comes from BUILD_CHECKSUM (XCP_CRC_32); the host's CRC-32 and its push record go to
``push_record``; SET_CAL_PAGE (ECU) to that page is the commit, which the controller does at a
control-period boundary or refuses (its reason in ``bank_status``); the push log and layout are
read from ``bank_status``; ``store=1`` then asks STORE_CAL_REQ (non-volatile memory).

Parameters (:class:`~ambdaq.drivers.interfaces.Parameters`): the A2L's numeric ``VALUE`` and
``VAL_BLK`` characteristics of every type, physical values through their linear conversion,
checked against their limits and the type's range first.  A download needs CAL/PAG unlocked
where the slave protects it: with the key of a push in the same session, else
``$AMBDAQ_UNLOCK_KEY``.  What the controller can do (:class:`~ambdaq.drivers.interfaces.Capabilities`)
is what its A2L says: coefficient banks if it describes ``coefficient_bank``, a speed set-point
and a test-signal input if a parameter's ``ambdaq`` annotation names that role (:mod:`.a2l`).
"""

from __future__ import annotations

import fnmatch
import json
from contextlib import contextmanager
import os
import struct
from collections.abc import Callable

import numpy as np

from ...errors import BadInputError, DeviceError
from ..can.bus import MAX_LOAD, bus_load
from ..interfaces import UNLOCK_KEY_ENV, CalibrationPages, Capabilities, Controller, ExcitationSpec, Source
from ..rows import RowQueue
from ..signals import FIELD_TYPES, SampleBlock, SignalGroup, field_problem, ros_field, ros_type
from .a2l import TYPES, A2lFile, A2lMeasurement, A2lParameter, Conversion
from .checksum import checksum
from .daq import DaqListPlan, DtoAssembler, Element, plan_lists, unwrap_timestamps
from .keys import KeyAlgorithm
from .master import RESOURCES, EventChannel, XcpMaster, XcpRefused
from .wire import RES_CALPAG, RES_DAQ
from .transport import Link

LENGTH = struct.Struct("<I")
SILENT_S = 2.0  # a cyclic event silent this long: the device is lost
UNWRAP_MIN_S = 0.1  # a timestamp that wraps faster than this cannot be unwrapped by arrival times
EVENT_TOPIC = "/xcp"

LinkFactory = Callable[[], Link]


def _event_topic(event: EventChannel) -> tuple[str, str]:
    """Topic and message type of an event's measurements that no annotation places."""
    word = ros_field(event.name or f"event_{event.number}")
    return f"{EVENT_TOPIC}/{word}", "Xcp" + ros_type(word.title())


def _capabilities(a2l: A2lFile, control_rate_hz: Callable[[], float]) -> Capabilities:
    """What the A2L says the controller can do (its parameters' ``ambdaq`` roles, :mod:`.a2l`);
    a role that cannot be read is a BadInputError naming the parameter."""
    speed, excitation = None, None
    for param in a2l.writable.values():
        role = param.role.get("role")
        if role == "speed" and param.count == 1:
            speed = param.name
        elif role == "test-signal":
            try:
                if param.count != 3 or param.role["unit"] not in ("m", "V"):
                    raise ValueError("3 values and unit m or V")
                excitation = ExcitationSpec(param.name, tuple(param.role["axes"].split(",")), param.role["unit"],
                                            float(param.role["min_amplitude"]), float(param.role["max_amplitude"]),
                                            control_rate_hz())
            except (KeyError, ValueError) as err:
                raise BadInputError(f"A2L file {a2l.path}: {param.name}: a test-signal parameter needs 3 values and "
                                    f"axes=, unit=m|V, min_amplitude=, max_amplitude= in its ambdaq annotation "
                                    f"({type(err).__name__}: {err})") from None
    return Capabilities(banks="coefficient_bank" in a2l.blobs, excitation=excitation, speed_parameter=speed)


def ask_slave(url: str, link: LinkFactory) -> dict[str, str]:
    """Who answers XCP at ``url``: CONNECT, GET_ID (the A2L project), GET_STATUS, every DAQ event
    with its name and cycle, and the optional commands (:data:`~.master.OPTIONAL`) it lacks;
    DeviceError if nothing does.  The session ends with DISCONNECT."""
    master = XcpMaster(link(), url)
    try:
        got = master.connect()
        if got.optional_comm_mode:
            master.get_comm_mode_info()
        out = {"url": url, "asap2_name": _identifier(master), "max_cto": str(got.max_cto), "max_dto": str(got.max_dto),
               "byte_order": "INTEL" if got.byte_order == "<" else "MOTOROLA",
               "resources": ",".join(k for k, bit in RESOURCES.items() if got.resources & bit),
               "protected": ",".join(k for k, bit in RESOURCES.items() if master.get_status()[1] & bit)}
        if got.resources & RES_DAQ:
            try:
                events = master.daq_processor().max_event
            except DeviceError:  # lacking GET_DAQ_PROCESSOR_INFO or _RESOLUTION_INFO: the events still answer
                events = 256
            for n in range(min(events, 256)):
                try:
                    e = master.event_channel(n)
                except XcpRefused:  # MAX_EVENT_CHANNEL may count more than the slave created
                    break
                if "GET_DAQ_EVENT_INFO" in master.lacking:
                    break
                out[f"event_{n}"] = f"{e.name} ({_cycle_text(e)})"
        out["lacks"] = ", ".join(master.lacking) or "none of the optional commands asked"
        master.disconnect()
    finally:
        master.close()
    return out


MAX_UPLOAD = 64 << 20  # an A2L uploaded by GET_ID larger than the files ambdaq reads is refused


def upload_a2l(url: str, link: LinkFactory) -> bytes:
    """The A2L file the slave at ``url`` holds (GET_ID type 4, uploaded), for a slave that writes
    its own (XCPlite does); DeviceError where it offers none."""
    master = XcpMaster(link(), url)
    try:
        with xcp_errors(url, "upload the A2L (GET_ID 4)"):
            master.connect()
            r = master.command(0xFA, 4, expect=8)  # GET_ID, type 4: the ASAM MC2 file to upload
            (length,) = master.unpack("I", r, 4)
            if not 0 < length <= MAX_UPLOAD:
                raise DeviceError(f"{url}: the slave offers an A2L of {length} bytes by GET_ID (1 byte to "
                                  f"{MAX_UPLOAD >> 20} MB are read)")
            text = bytes(r[8 : 8 + length]) if r[1] & 0x01 else master.upload(length)
            master.disconnect()
    finally:
        master.close()
    return text


def _physical_values(raw: bytes, datatype: str, byte_order: str, conversion: Conversion | None) -> np.ndarray:
    """``raw`` bytes of ``datatype`` values in ``byte_order`` as physical values (float64): through
    ``conversion`` where it is linear, else raw."""
    kind, size = TYPES[datatype]
    x = np.frombuffer(raw, dtype=f"{byte_order}{kind}{size}").astype(np.float64)
    return x * conversion.factor + conversion.offset if conversion is not None and conversion.linear else x


def field_type(m: A2lMeasurement) -> str:
    """The recorded type of ``m``: ``int64``/``uint64`` for an A_INT64 or A_UINT64 whose recorded
    value is its raw integer (an identical conversion, one ambdaq does not compute, a BIT_MASK),
    so that float64 does not round it past 2**53; ``float64`` for everything else."""
    kind, size = TYPES[m.datatype]
    c = m.conversion
    if kind == "f" or size != 8 or (c.computed and not (c.linear and c.factor == 1 and c.offset == 0)):
        return "float64"
    return "uint64" if kind == "u" or m.bit_mask is not None else "int64"


def _cycle_text(event: EventChannel) -> str:
    return f"every {event.cycle_ns / 1e3:g} us" if event.cycle_ns else "sporadic"


def _identifier(master: XcpMaster) -> str:
    """The ASAM MC2 name GET_ID gives, or "" where the slave lacks or refuses it."""
    try:
        got = master.get_id(1)
    except XcpRefused:
        return ""
    return "" if got is None else got.decode("latin-1").rstrip("\0")


class _Stream:
    """One DAQ list's samples: the rows the receive thread assembled, decoded to topics."""

    def __init__(self, plan: DaqListPlan, groups: list[SignalGroup], columns: list[np.ndarray],
                 fields: list[Element], tick_ns: int, url: str) -> None:
        self.plan, self.groups, self.columns, self.fields = plan, groups, columns, fields
        cyclic = plan.event.cycle_ns > 0
        self.rows = RowQueue(SILENT_S if cyclic else float("inf"))
        self.sample_rate = 1e9 / plan.event.cycle_ns / plan.prescaler if cyclic else None
        self.tick_ns, self.url = tick_ns, url
        wrap_s = (1 << (8 * plan.timestamp)) * tick_ns / 1e9 if plan.timestamp else 0.0
        self.timed = wrap_s >= UNWRAP_MIN_S
        self._last: tuple[int, int, int] | None = None
        self._pairs: list[tuple[int, int]] = []
        self._dtype = plan.dtype()
        index = {e: k for k, e in enumerate(plan.elements)}
        self._cols = [f"e{index[e]}" for e in fields]
        self.rounded = 0  # scaled 64-bit integers beyond 2**53, which float64 holds rounded
        self.implausible = 0  # samples dropped: their timestamp cannot be the slave's clock

    def read(self, failure: Callable[[], str | None]) -> SampleBlock | None:
        while True:
            taken = self.rows.take(failure, lambda s: f"{self.url}: no DAQ data on event {self.plan.event.name!r} "
                                                      f"for {s:.1f} s")
            if taken is None:
                return None
            rows, seq = taken
            arrival = np.array([r[1] for r in rows], dtype=np.int64)
            if not self.timed:
                device = arrival.copy()
                break
            raw = np.array([r[2] for r in rows], dtype=np.int64)
            device, plausible, self._last = unwrap_timestamps(raw, arrival, self.tick_ns, self.plan.timestamp,
                                                              self._last)
            if plausible.all():
                break
            self.implausible += int(np.count_nonzero(~plausible))
            if plausible.any():
                rows = [r for r, ok in zip(rows, plausible) if ok]
                seq, arrival, device = seq[plausible], arrival[plausible], device[plausible]
                break
        k = int(np.argmin(arrival - device))
        self._pairs.append((int(device[k]), int(arrival[k])))
        payload = np.frombuffer(b"".join(r[3] for r in rows), dtype=self._dtype)
        values = [self._physical(e.measurement, payload[col]) for e, col in zip(self.fields, self._cols)]
        return SampleBlock(device, (seq & 0xFFFFFFFF).astype(np.uint32),
                           {g.topic: g.values_from_columns([values[c] for c in cols])
                            for g, cols in zip(self.groups, self.columns)},
                           received_ns=int(arrival[-1]))

    def _physical(self, m: A2lMeasurement, raw: np.ndarray) -> np.ndarray:
        """The recorded values of ``m`` from its raw DTO values: exact integers for a 64-bit
        integer recorded raw (:func:`field_type`), float64 physical values otherwise."""
        if m.bit_mask is not None:
            shift = (m.bit_mask & -m.bit_mask).bit_length() - 1
            raw = (raw.astype(np.uint64) & np.uint64(m.bit_mask)) >> np.uint64(shift)
        kind = field_type(m)
        if kind != "float64":
            return raw.astype(FIELD_TYPES[kind])
        if raw.dtype.kind in "iu" and raw.dtype.itemsize == 8:  # scaled: the raw value float64 rounds, counted
            self.rounded += int(np.count_nonzero(np.abs(raw.astype(np.float64)) > 2.0 ** 53))
        x = raw.astype(np.float64)
        c = m.conversion
        if c.linear:
            return x * c.factor + c.offset
        if c.kind == "TAB_INTP" and c.table:
            inputs, outputs = zip(*c.table)
            y = np.interp(x, inputs, outputs)  # ASAM MCD-2 MC, COMPU_TAB: linear between the points
            if c.default is not None:
                y[(x < inputs[0]) | (x > inputs[-1])] = c.default
            return y
        return x  # recorded raw; the conversion is named in the device's metadata

    def clock_pairs(self) -> list[tuple[int, int]]:
        pairs, self._pairs = self._pairs, []
        return pairs

    def identity(self) -> dict[str, str]:
        raw = {e.field: f"{e.measurement.name} ({e.measurement.conversion.kind})" for e in self.fields
               if not e.measurement.conversion.computed}
        verbal = {e.field: dict(e.measurement.conversion.verbal) for e in self.fields
                  if e.measurement.conversion.verbal}
        out = {"event": self.plan.event.name, "event_number": str(self.plan.event.number),
               "event_cycle": _cycle_text(self.plan.event),
               "measurements": json.dumps({e.field: e.measurement.name for e in self.fields}),
               "seq": f"counter {self.plan.counter.measurement.name}" if self.plan.counter else "arrival index",
               "time": "DTO timestamp" if self.timed else "host arrival"}
        if self.sample_rate:
            out["sample_rate_hz"] = f"{self.sample_rate:g}"
        if raw:
            out["raw_fields"] = json.dumps(raw)
        if verbal:
            out["value_tables"] = json.dumps(verbal)
        return out


class XcpController(Controller, CalibrationPages):
    """The controller reached through ``link``, described by ``a2l``.

    Parameters
    ----------
    url : str
        Its device URL (for messages and metadata).
    link : callable
        Opens the transport (:mod:`.transport`).
    a2l : A2lFile
        Its A2L file.
    name : str
        Device name in the recording.
    record : bool
        Whether DAQ lists are planned (False for ``controller`` and ``push``, which need none).
    measure : list of str, optional
        A2L names or globs to record (default: those an ``ambdaq`` annotation places).
    counter : str, optional
        The measurement that counts control periods (each sample's seq); default: the one
        annotated ``role=counter``, if any.
    event : int, optional
        The DAQ event for measurements whose A2L fixes none.
    key_algorithm : callable
        The seed & key algorithm (:mod:`.keys`).
    store : bool
        After a push, ask the controller to store the page in non-volatile memory.
    prescaler : int
        Sample every this many events (where the slave has a prescaler).
    bus_bitrate : int, optional
        On CAN: the bus's bit rate, to refuse DAQ lists the bus cannot carry (above 80 % load).
    """

    def __init__(self, url: str, link: LinkFactory, a2l: A2lFile, *, name: str = "controller", record: bool = True,
                 measure: list[str] | None = None, counter: str | None = None, event: int | None = None,
                 key_algorithm: KeyAlgorithm, store: bool = False, prescaler: int = 1,
                 bus_bitrate: int | None = None) -> None:
        self.url, self.a2l, self.name, self.store = url, a2l, name, store
        self.key_algorithm = key_algorithm
        if not 1 <= prescaler <= 255:
            raise BadInputError(f"{url}: prescaler must be 1..255, not {prescaler}")
        chosen = self._select(measure, counter) if record else []
        self._key: str | None = None
        self._page: int | None = None  # the calibration page reads and writes go to (on_page)
        self._streaming = False
        self._session_over = False
        self._streams: list[_Stream] = []
        self._plans: list[DaqListPlan] = []
        self._sources: list[XcpEventSource] = []
        self._master = XcpMaster(link(), url)
        try:
            with self._errors("connect"):
                self.info = self._master.connect()
                if self.info.optional_comm_mode:
                    self._master.get_comm_mode_info()
                self.project = _identifier(self._master) or a2l.project
            self._constants = {n: ",".join(repr(float(v)) for v in self._read_values(p)[0])
                               for n, p in a2l.constants.items()}
            if record:
                self._plan(chosen, counter, event, prescaler, bus_bitrate)
            self._capabilities = _capabilities(a2l, self._control_rate)
        except BaseException:
            self._master.close()
            raise
        self.sample_rate = self._streams[0].sample_rate if self._streams else None
        # an event's cycle is declared, not kept (the ECU task may run slower or skip): a duration
        # is counted in control periods only where a counter numbers them, else by the host clock
        self.duration_in_samples = bool(self._streams) and self._streams[0].plan.counter is not None

    # --- choosing and planning --------------------------------------------------------------------

    def _select(self, measure: list[str] | None, counter: str | None) -> list[A2lMeasurement]:
        a2l = self.a2l
        if measure:
            names: list[str] = []
            for pattern in measure:
                found = [n for n in a2l.measurements if fnmatch.fnmatchcase(n, pattern)]
                if not found:
                    raise BadInputError(f"{self.url}: no measurement of {a2l.path.name} matches {pattern!r} "
                                        f"(ambdaq xcp list {a2l.path} lists them)")
                names += [n for n in found if n not in names]
        else:
            names = [n for n, m in a2l.measurements.items() if {"topic", "field"} <= set(m.note)]
            if not names:
                raise BadInputError(f"{self.url}: say what to record of {a2l.path.name}'s {len(a2l.measurements)} "
                                    "measurements: --measure NAME_OR_GLOB (or measurements in the rig file); "
                                    f"ambdaq xcp list {a2l.path} lists them")
        chosen = []
        for n in names:
            m = a2l.measurements[n]
            why = m.problem() or (None if m.address >= 0 else "it has no ECU_ADDRESS")
            if why:
                raise BadInputError(f"{self.url}: measurement {n} ({m.line}): {why}")
            if n != counter and m.note.get("role") != "counter":
                chosen.append(m)
        return chosen

    def _counter(self, name: str | None, event: int, on_event: Callable[[A2lMeasurement], int]) -> Element | None:
        if name is None:
            annotated = [m for m in self.a2l.measurements.values() if m.note.get("role") == "counter"]
            found = next((m for m in annotated if on_event(m) == event), None)
        else:
            found = self.a2l.measurements.get(name)
            if found is None:
                raise BadInputError(f"{self.url}: the A2L has no counter measurement {name!r}")
            if on_event(found) != event:
                return None
        if found is None:
            return None
        if TYPES.get(found.datatype, ("f", 0))[0] not in "iu" or found.count != 1 or found.bit_mask is not None:
            raise BadInputError(f"{self.url}: counter {found.name} is a {found.datatype}; a counter is one unsigned "
                                "or signed integer")
        return Element(found, 0, "")

    def _plan(self, chosen: list[A2lMeasurement], counter: str | None, event: int | None, prescaler: int,
              bus_bitrate: int | None) -> None:
        master, url = self._master, self.url
        if not self.info.resources & RES_DAQ:
            raise DeviceError(f"{url}: the slave offers no DAQ (CONNECT's resources)")
        processor = master.daq_processor(self.a2l.daq)
        if prescaler > 1 and not processor.prescaler:
            raise BadInputError(f"{url}: the slave has no DAQ prescaler (GET_DAQ_PROCESSOR_INFO): drop prescaler=")
        channels: dict[int, EventChannel] = {}

        def channel(n: int) -> EventChannel:
            if n not in channels:
                try:
                    channels[n] = master.event_channel(n, self.a2l.events)
                except XcpRefused as err:
                    raise DeviceError(f"{url}: event {n}: the slave answered {err}") from None
            return channels[n]

        def on_event(m: A2lMeasurement) -> int:
            if m.fixed_events:
                if event is not None and event not in m.fixed_events:
                    raise BadInputError(f"{url}: {m.name} is fixed to event(s) {list(m.fixed_events)} by its A2L, "
                                        f"not event {event}")
                return m.fixed_events[0]
            if event is not None:
                return event
            if m.default_events:
                return m.default_events[0]
            if processor.max_event == 1:
                return 0
            raise BadInputError(f"{url}: {m.name} names no DAQ event in its A2L and the slave has "
                                f"{processor.max_event or 'several'}: give event=N (ambdaq devices --ask-xcp URL "
                                "lists them)")

        by_event: dict[int, list[A2lMeasurement]] = {}
        for m in chosen:
            by_event.setdefault(on_event(m), []).append(m)
        counters = {e: self._counter(counter, e, on_event) for e in by_event}
        if counter is not None and not any(counters.values()):
            raise BadInputError(f"{url}: counter {counter} is on no event of the measurements recorded")
        layout: dict[int, list[Element]] = {}
        streams: dict[int, tuple[list[SignalGroup], list[np.ndarray], list[Element]]] = {}
        taken: dict[str, dict[str, str]] = {}  # topic -> field -> measurement
        for e, ms in by_event.items():
            ch = channel(e)
            if not ch.daq:
                raise BadInputError(f"{url}: event {ch.name!r} takes no DAQ lists")
            by_topic: dict[tuple[str, str], list[Element]] = {}
            for m in ms:
                if m.note.get("field") and (problem := field_problem(m.note["field"])) is not None:
                    raise BadInputError(f"{url}: {m.name}'s ambdaq annotation: {problem}")
                if {"topic", "field"} <= set(m.note) and m.count == 1:
                    key, fields = (m.note["topic"], m.note.get("type") or _event_topic(ch)[1]), [m.note["field"]]
                else:
                    key = _event_topic(ch)
                    base = m.note.get("field") or ros_field(m.name)
                    fields = [base] if m.count == 1 else [f"{base}_{i}" for i in range(m.count)]
                for i, f in enumerate(fields):
                    held = taken.setdefault(key[0], {})
                    if f in held:
                        raise BadInputError(f"{url}: {m.name} and {held[f]} would both be field {f} of {key[0]}: "
                                            "record one of them, or annotate another field")
                    held[f] = m.name
                    by_topic.setdefault(key, []).append(Element(m, i, f))
            for topic in by_topic:
                for other, (groups, _c, _f) in streams.items():
                    if any(g.topic == topic[0] for g in groups):
                        raise BadInputError(f"{url}: topic {topic[0]} gets measurements of events "
                                            f"{channels[other].name!r} and {ch.name!r}; a topic is one event's")
            groups, columns, fields_in_order, k = [], [], [], 0
            for (topic, type_name), elements in by_topic.items():
                groups.append(SignalGroup(topic, type_name, tuple(x.field for x in elements),
                                          tuple(x.measurement.unit for x in elements),
                                          tuple(field_type(x.measurement) for x in elements)))
                columns.append(np.arange(k, k + len(elements)))
                fields_in_order += elements
                k += len(elements)
            counter_element = counters[e]
            layout[e] = ([counter_element] if counter_element else []) + fields_in_order
            streams[e] = (groups, columns, fields_in_order)
        declared = self.a2l.daq.lists if self.a2l.daq is not None else ()
        static = None if processor.dynamic else [  # a bounded look, whatever MAX_DAQ a slave claims
            info for n in range(processor.min_daq, min(processor.max_daq, processor.min_daq + 256))
            if (info := master.daq_list_info(n, declared)) is not None]
        plans = plan_lists(layout, channels, processor, self.info.max_dto, prescaler=prescaler, counters=counters,
                           url=url, static_lists=static)
        if bus_bitrate is not None:
            for plan in plans:
                self._check_bus_load(plan, bus_bitrate)
        self._processor = processor
        self._plans = plans
        self._streams = [_Stream(p, *streams[p.event.number], processor.timestamp_ns, url) for p in plans]
        self._assembler = DtoAssembler(plans, [s.rows.rows for s in self._streams], processor, self.info.byte_order,
                                       lambda: self._master.link.lost_packets,
                                       8 if not self._master.link.has_counter else 0)
        self._sources = [XcpEventSource(self, s) for s in self._streams[1:]]

    def _check_bus_load(self, plan: DaqListPlan, bitrate: int) -> None:
        """Refuse a DAQ list whose DTOs would load the CAN bus above MAX_LOAD (ASAM XCP Part 3,
        CAN: one frame per ODT)."""
        if not plan.event.cycle_ns:
            return
        frames = [min(8, n) for n in plan.lengths]
        event_hz = 1e9 / plan.event.cycle_ns
        load = bus_load(frames, event_hz / plan.prescaler, bitrate)
        if load > MAX_LOAD:
            fits = int(np.ceil(bus_load(frames, event_hz, bitrate) / MAX_LOAD))
            raise BadInputError(f"{self.url}: {len(plan.elements)} measurements every {plan.prescaler} event(s) "
                                f"are {len(frames)} frames per sample, {load:.0%} of the {bitrate:,} bit/s bus; "
                                f"give prescaler={fits} or more, or fewer measurements")

    def _control_rate(self) -> float:
        """The rate of event 0, the controller's control period (the test signal's rate)."""
        if self._streams and self._streams[0].sample_rate:
            return self._streams[0].sample_rate * self._plans[0].prescaler
        with self._errors("read event 0"):
            e = self._master.event_channel(0, self.a2l.events)
        return 1e9 / e.cycle_ns if e.cycle_ns else 0.0

    def event_sources(self) -> list["XcpEventSource"]:
        """The sources of the DAQ lists on the other events (the controller itself records the first)."""
        return list(self._sources)

    # --- errors -----------------------------------------------------------------------------------

    def _errors(self, what: str) -> "_Errors":
        return xcp_errors(self.url, what)

    # --- Source -----------------------------------------------------------------------------------

    def signal_groups(self) -> list[SignalGroup]:
        return list(self._streams[0].groups) if self._streams else []

    def identity(self) -> dict[str, str]:
        base = {"url": self.url, "kind": "xcp controller", "model": self.project, "a2l": self.a2l.path.name,
                "a2l_sha256": self.a2l.sha256, "loss_detection": self._loss_detection()}
        if self._master.lacking:  # what the A2L's IF_DATA XCP answered in the slave's stead
            base["optional_commands_lacking"] = ", ".join(self._master.lacking)
        return {**base, **(self._streams[0].identity() if self._streams else {})}

    def _loss_detection(self) -> str:
        ways = []
        if self._master.link.has_counter:
            ways.append("transport counter (CTR)")
        if self._streams and self._processor.overload != "none":
            ways.append(f"overload indication ({self._processor.overload})")
        if any(p.counter for p in self._plans):
            ways.append("control-period counter")
        return ", ".join(ways) or "none: XCP on CAN has no transport counter and no counter measurement was named"

    def device_calibration(self) -> dict[str, str]:
        """The controller's calibration constants (A2L FLOAT64 characteristics, read at open)."""
        return dict(self._constants)

    def link_statistics(self) -> dict[str, str]:
        link, master = self._master.link, self._master
        out = {"transport_packets": str(link.received), "transport_lost_packets": str(link.lost_packets),
               "transport_duplicates": str(link.duplicates), "transport_malformed": str(link.malformed),
               "overload_events": str(master.overload_events)}
        if self._streams:
            out["dto_unknown"] = str(self._assembler.unknown)
            for s in self._streams:
                state = self._assembler.states[s.plan.number]
                key = ros_field(s.plan.event.name or str(s.plan.event.number))
                out[f"{key}_samples_discarded"] = str(state.incomplete)
                out[f"{key}_dto_wrong_length"] = str(state.malformed)
                out[f"{key}_dto_overload"] = str(state.overloads)
                out[f"{key}_samples_implausible_time"] = str(s.implausible)
                if s.rounded:
                    out[f"{key}_int64_values_rounded"] = str(s.rounded)
        return out

    def start(self, n_samples: int | None) -> None:
        self._streams[0].rows.start(n_samples)
        self._start_daq()

    def _start_daq(self) -> None:
        """Configure every DAQ list (ASAM XCP Part 2, dynamic or static DAQ configuration) and start them."""
        if self._streaming:
            return
        m = self._master
        with self._errors("DAQ setup"):
            if self._processor.dynamic:
                m.free_daq()
                m.alloc_daq(len(self._plans))
                for p in self._plans:
                    m.alloc_odt(p.number, len(p.odts))
                for p in self._plans:
                    for j, odt in enumerate(p.odts):
                        m.alloc_odt_entry(p.number, j, len(odt))
            else:  # static lists: their room is there, what a last user left in them is cleared
                for p in self._plans:
                    m.clear_daq_list(p.number)
            for p in self._plans:
                for j, odt in enumerate(p.odts):
                    if odt:  # an ODT of the timestamp alone has no entry to point at
                        m.set_daq_ptr(p.number, j, 0)
                    for e in odt:
                        m.write_daq(e.measurement.size, e.measurement.extension, e.address)
                m.set_daq_list_mode(p.number, p.event.number, timestamp=self._processor.timestamps,
                                    prescaler=p.prescaler)
                p.first_pid = m.select_daq_list(p.number)
            self._assembler.selected()
            m.on_dto = self._assembler.on_dto
            m.start_stop_synch(1)
        self._streaming = True

    def read(self) -> SampleBlock | None:
        return self._streams[0].read(lambda: self._master.failure)

    def clock_pairs(self) -> list[tuple[int, int]] | None:
        return self._streams[0].clock_pairs()

    # --- Controller -----------------------------------------------------------------------------

    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    def parameter_names(self) -> list[str]:
        return list(self.a2l.parameters)

    def _parameter(self, name: str, *, write: bool = False) -> A2lParameter:
        found = (self.a2l.writable if write else self.a2l.parameters).get(name)
        if found is None:
            known = ", ".join((self.a2l.writable if write else self.a2l.parameters)) or "none"
            what = "writable numeric parameter" if write else "numeric parameter (VALUE or VAL_BLK)"
            raise DeviceError(f"{self.url}: the A2L describes no {what} {name!r} (it has: {known})")
        problems = [c.problem for c in (found.conversion, *(r.conversion for r in found.record if r.conversion))
                    if c.problem]
        if problems:
            raise DeviceError(f"{self.url}: {name}: its conversion cannot be read: {problems[0]}")
        return found

    @contextmanager
    def on_page(self, page: int):
        self._page = page
        try:
            yield
        finally:
            self._page = None

    def copy_page(self, parameter: str, source: int, target: int) -> None:
        """COPY_CAL_PAGE of the segment that holds ``parameter``, checked against the A2L's pages."""
        param = self._parameter(parameter)
        segment = self.a2l.segment_of(param)
        if segment is None:
            raise DeviceError(f"{self.url}: no MEMORY_SEGMENT of the A2L holds {parameter}, so it has no pages to copy")
        for page in (source, target):
            if page not in segment.pages:
                raise DeviceError(f"{self.url}: segment {segment.name} has pages {sorted(segment.pages)}, not {page}")
        if not segment.pages[target]:
            raise DeviceError(f"{self.url}: page {target} of segment {segment.name} is not writable over XCP "
                              "(its A2L: XCP_WRITE_ACCESS_NOT_ALLOWED)")
        with self._errors(f"copy page {source} to {target} of segment {segment.name}"):
            self._master.copy_cal_page((segment.number, source), (segment.number, target))

    @contextmanager
    def _paged(self, param: A2lParameter, write: bool):
        """The page :meth:`on_page` chose presented for XCP access to ``param``'s segment while
        ``param`` is read or written (GET_CAL_PAGE, SET_CAL_PAGE for XCP), then the one before."""
        page = self._page
        if page is None:
            yield
            return
        segment = self.a2l.segment_of(param)
        if segment is None:
            raise DeviceError(f"{self.url}: no MEMORY_SEGMENT of the A2L holds {param.name}, so its page cannot "
                              "be chosen")
        if page not in segment.pages:
            raise DeviceError(f"{self.url}: segment {segment.name} has pages {sorted(segment.pages)}, not {page}")
        if write and not segment.pages[page]:
            raise DeviceError(f"{self.url}: page {page} of segment {segment.name} is not writable over XCP "
                              "(its A2L: XCP_WRITE_ACCESS_NOT_ALLOWED)")
        with self._errors(f"choose page {page} of segment {segment.name}"):
            before = self._master.get_cal_page(0x02, segment.number)
            self._master.set_cal_page(0x02, segment.number, page)
        try:
            yield
        finally:
            with self._errors(f"give back page {before} of segment {segment.name}"):
                self._master.set_cal_page(0x02, segment.number, before)

    def _read_values(self, param: A2lParameter) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The parameter's physical values, and for a record with its own axes (STD_AXIS) each
        axis's points (``x``, ``y``)."""
        if param.record:
            return self._read_record(param)
        kind, size = TYPES[param.datatype]
        with self._paged(param, False), self._errors(f"read {param.name}"):
            raw = self._master.read(param.extension, param.address, size * param.count)
        return _physical_values(raw, param.datatype, param.byte_order, param.conversion), {}

    def _read_record(self, param: A2lParameter) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """A CURVE or MAP stored with its axis points (ASAM MCD-2 MC RECORD_LAYOUT): the record is
        read as large as it can be, then walked item by item in memory order, each aligned; in a
        compact record each item follows the points in use (NO_AXIS_PTS), in a static one the
        room for every point. A count beyond MaxAxisPoints, or one that follows the points it
        counts in a compact record, is refused: the layout cannot then be decided."""
        def aligned(offset: int, align: int) -> int:
            return offset + (-(param.address + offset)) % align

        largest = 0
        for item in param.record:
            largest = aligned(largest, item.align) + TYPES[item.datatype][1] * item.count
        with self._paged(param, False), self._errors(f"read {param.name}"):
            raw = self._master.read(param.extension, param.address, largest)
        used = [next((r.count for r in param.record if r.kind == "AXIS_PTS" and r.axis == a), 1) for a in range(2)]
        counted: set[int] = set()
        offset, values, axes = 0, np.zeros(0), {}
        for item in param.record:
            size = TYPES[item.datatype][1]
            offset = aligned(offset, item.align)
            if item.kind == "AXIS_PTS":
                n = used[item.axis]
            elif item.kind == "FNC_VALUES":
                n = used[0] * used[1]
            else:
                n = item.count
            sized_by = {item.axis} if item.kind == "AXIS_PTS" else {0, 1} if item.kind == "FNC_VALUES" else set()
            if not param.static and any(r.kind == "NO_AXIS_PTS" and r.axis in sized_by and r.axis not in counted
                                        for r in param.record):
                raise DeviceError(f"{self.url}: {param.name}: its record gives a count of axis points after the "
                                  "points it counts; ambdaq cannot place them")
            data = raw[offset : offset + size * n]
            if item.kind == "NO_AXIS_PTS":
                count = int(_physical_values(data, item.datatype, param.byte_order, None)[0])
                most = next(r.count for r in param.record if r.kind == "AXIS_PTS" and r.axis == item.axis)
                if not 1 <= count <= most:
                    raise DeviceError(f"{self.url}: {param.name}: the ECU holds {count} points on axis "
                                      f"{'xy'[item.axis]}, its A2L at most {most}")
                used[item.axis] = count
                counted.add(item.axis)
            elif item.kind == "AXIS_PTS":
                axes["xy"[item.axis]] = _physical_values(data, item.datatype, param.byte_order, item.conversion)
            elif item.kind == "FNC_VALUES":
                if param.static and used[1] > 1 and used[0] < item.count // used[1]:
                    raise DeviceError(f"{self.url}: {param.name}: a static MAP using fewer x points than it has room "
                                      "for: where each row's values lie is not decided by its A2L")
                values = _physical_values(data, item.datatype, param.byte_order, param.conversion)
            offset += size * (item.count if param.static and item.kind != "NO_AXIS_PTS" else n)
        if not any(r.kind == "FNC_VALUES" for r in param.record):  # an AXIS_PTS: its points are its values
            return axes.pop("x"), axes
        return values, axes

    def read_param(self, name: str) -> np.ndarray:
        return self._read_values(self._parameter(name))[0]

    def read_axes(self, name: str) -> dict[str, np.ndarray]:
        return self._read_values(self._parameter(name))[1]

    def write_param(self, name: str, values) -> None:
        """Download ``values`` (physical) to parameter ``name`` after checking their number, the
        A2L's limits and the type's range; unlocks CAL/PAG first if it is protected (the push's
        key, else $AMBDAQ_UNLOCK_KEY)."""
        param = self._parameter(name, write=True)
        values = np.atleast_1d(np.asarray(values, dtype=float))
        if values.shape != (param.count,):
            raise DeviceError(f"{self.url}: {name} takes {param.count} value(s), not {values.size}")
        if not np.all(np.isfinite(values)) or np.any(values < param.lower) or np.any(values > param.upper):
            raise DeviceError(f"{self.url}: {name}: values must be finite and within {param.lower:g} .. {param.upper:g} "
                              "(the A2L's limits)")
        c = param.conversion
        if not c.linear or c.factor == 0:
            raise DeviceError(f"{self.url}: {name}: its conversion {c.kind} cannot be inverted; ambdaq writes "
                              "parameters with linear conversions")
        raw = (values - c.offset) / c.factor
        kind, size = TYPES[param.datatype]
        if kind in "iu":
            raw = np.round(raw)
            info = np.iinfo(f"{kind}{size}")
            if np.any(raw < info.min) or np.any(raw > info.max):
                raise DeviceError(f"{self.url}: {name}: a {param.datatype} holds {info.min} .. {info.max} raw")
        data = raw.astype(f"{param.byte_order}{kind}{size}").tobytes()
        if self._calibration_locked(f"write {name}"):
            key = self._key or os.environ.get(UNLOCK_KEY_ENV)
            if not key:
                raise DeviceError(f"{self.url}: writing {name} over XCP needs calibration unlocked (seed & key): "
                                  f"set {UNLOCK_KEY_ENV}")
            self._key = key
            self._answer_seed(key)
        with self._paged(param, True), self._errors(f"write {name}"):
            self._master.write(param.extension, param.address, data)
            self._verify(param, data)

    def _verify(self, param: A2lParameter, data: bytes) -> None:
        """What the slave holds after a write: the bytes read back, and where the A2L names its
        segment's checksum, BUILD_CHECKSUM in that algorithm against the host's.  A speed set-point
        (``role=speed``) reads the present speed by that role's definition (:mod:`.a2l`), so it is not
        read back."""
        if param.role.get("role") == "speed":
            return
        held = self._master.read(param.extension, param.address, len(data))
        if held != data:
            raise DeviceError(f"{self.url}: {param.name}: wrote {data.hex()}, the slave holds {held.hex()}")
        segment = self.a2l.segment_of(param)
        if segment is None or not segment.checksum:
            return
        try:
            kind, value = self._master.build_checksum(param.extension, param.address, len(data))
        except XcpRefused as err:
            if err.error_name == "ERR_CMD_UNKNOWN":
                return  # the slave has no BUILD_CHECKSUM: the readback is the check
            raise
        if kind != segment.checksum:
            raise DeviceError(f"{self.url}: BUILD_CHECKSUM answers {kind}, where the A2L declares {segment.checksum} "
                              f"for segment {segment.name}")
        try:
            expected = checksum(kind, data, self.info.byte_order)
        except ValueError:
            return  # an algorithm ambdaq does not compute (XCP_USER_DEFINED): the readback is the check
        if value != expected:
            raise DeviceError(f"{self.url}: {param.name}: the slave's {kind} is {value:#x}, the host's {expected:#x}")

    # --- BankPort -------------------------------------------------------------------------------

    def _blob(self, name: str) -> tuple[int, int]:
        if name not in self.a2l.blobs:
            raise DeviceError(f"{self.url}: the A2L describes no {name!r}, so this controller takes no push over XCP "
                              "(ambdaq's coefficient-bank convention, docs/hardware.md)")
        return self.a2l.blobs[name]

    def _pages(self) -> tuple[int, int]:
        """(active, inactive) page of segment 0: the ECU's page runs."""
        active = int(self._master.get_cal_page(0x01, 0))
        return active, 1 - active

    def _page_image(self, page: int) -> tuple[int, int]:
        """Length and device-computed CRC-32 (BUILD_CHECKSUM, XCP_CRC_32) of the image on ``page``."""
        base, size = self._blob("coefficient_bank")
        self._master.set_cal_page(0x02, 0, page)
        (length,) = LENGTH.unpack(self._master.read(0, base, 4))
        if not 0 < length <= size - 4:
            return 0, 0
        kind, value = self._master.build_checksum(0, base + 4, length)
        if kind != "XCP_CRC_32":
            raise DeviceError(f"{self.url}: BUILD_CHECKSUM answers {kind}, not XCP_CRC_32")
        return length, value

    def _calibration_locked(self, what: str) -> bool:
        with self._errors(what):
            return bool(self._master.get_status()[1] & RES_CALPAG)

    def unlock(self, key: str) -> None:
        self._key = key
        if self._calibration_locked("unlock"):
            self._answer_seed(key)

    def _answer_seed(self, key: str) -> None:
        """GET_SEED and UNLOCK for CAL/PAG with ``key`` (calibration is locked)."""
        with self._errors("unlock"):
            seed = self._master.get_seed(RES_CALPAG)
            answer = self.key_algorithm(RES_CALPAG, seed, key)
        try:
            with self._errors("unlock"):
                self._master.unlock(answer)
        except DeviceError:
            self._session_over = True  # a slave refusing a key ends the session (ASAM XCP Part 2, UNLOCK)
            raise DeviceError(f"{self.url}: unlock refused: wrong key for calibration (seed & key)") from None

    def write_bank(self, image: bytes) -> None:
        base, size = self._blob("coefficient_bank")
        if len(image) + 4 > size:
            raise DeviceError(f"{self.url}: a {len(image)}-byte image does not fit the {size}-byte calibration page")
        with self._errors("write the inactive page"):
            _active, inactive = self._pages()
            self._master.set_cal_page(0x02, 0, inactive)
            self._master.write(0, base, LENGTH.pack(len(image)) + image)

    def bank_status(self) -> dict:
        base, size = self._blob("bank_status")
        with self._errors("read the bank status"):
            (length,) = LENGTH.unpack(self._master.read(0, base, 4))  # SET_MTA at its start takes the snapshot
            if not 0 < length <= size - 4:
                raise DeviceError(f"{self.url}: bank_status holds no status (length {length})")
            try:
                status = json.loads(self._master.read(0, base + 4, length))
            except ValueError:
                raise DeviceError(f"{self.url}: bank_status is not JSON") from None
            active, inactive = self._pages()
            a_len, a_crc = self._page_image(active)
            i_len, i_crc = self._page_image(inactive)
        status.update(active_bank=active, active_crc32=f"{a_crc:08x}", active_length=a_len,
                      inactive_crc32=f"{i_crc:08x}", inactive_length=i_len)
        return status

    def commit_bank(self, crc: int, record: dict) -> int:
        base, size = self._blob("push_record")
        body = json.dumps({**record, "crc32": f"{crc:08x}"}).encode()
        if len(body) + 4 > size:
            raise DeviceError(f"{self.url}: the push record ({len(body)} bytes) does not fit push_record")
        with self._errors("write the push record"):
            _active, inactive = self._pages()
            self._master.write(0, base, LENGTH.pack(len(body)) + body)
        try:
            with self._errors("switch the page"):
                self._master.set_cal_page(0x01, 0, inactive)
        except DeviceError as err:
            reason = self.bank_status().get("last_refusal") or str(err)
            raise DeviceError(f"{self.url}: the controller refused the page switch: {reason}") from None
        status = self.bank_status()
        if self.store:  # the switch locked calibration again: storing needs it unlocked
            self.unlock(self._key)
            with self._errors("store the page (STORE_CAL_REQ)"):
                self._master.set_request(0x01, 0)
        return int(status.get("last_effective_sample", -1))

    def read_bank(self, which: str, length: int) -> bytes:
        base, _size = self._blob("coefficient_bank")
        with self._errors(f"read the {which} page"):
            active, inactive = self._pages()
            self._master.set_cal_page(0x02, 0, active if which == "active" else inactive)
            return self._master.read(0, base + 4, length)

    def _close(self) -> None:
        for s in self._streams:
            s.rows.closed.set()
        try:
            if not self._session_over and not self._master.failure:
                if self._streaming:
                    with self._errors("DAQ stop"):
                        self._master.start_stop_synch(0)
                with self._errors("disconnect"):
                    self._master.disconnect()
        except DeviceError:
            pass
        finally:
            self._master.close()


def xcp_errors(url: str, what: str) -> "_Errors":
    """A context in which a negative response, a timeout or a lost link while doing ``what``
    with the slave at ``url`` is one DeviceError line naming both."""
    return _Errors(url, what)


class _Errors:

    def __init__(self, url: str, what: str) -> None:
        self.url, self.what = url, what

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, err, tb) -> bool:
        if isinstance(err, XcpRefused):
            raise DeviceError(f"{self.url}: {self.what}: the controller answered {err}") from None
        if isinstance(err, DeviceError) and f": {self.what}: " not in str(err):
            text = str(err)
            text = text[len(self.url) + 2:] if text.startswith(f"{self.url}: ") else text
            raise DeviceError(f"{self.url}: {self.what}: {text}") from None
        return False


class XcpEventSource(Source):
    """The DAQ list of one more event of an :class:`XcpController`: its own source (its own
    times and samples), on the controller's session."""

    def __init__(self, controller: XcpController, stream: _Stream) -> None:
        self._controller, self._stream = controller, stream
        self.name = f"{controller.name}.{ros_field(stream.plan.event.name or str(stream.plan.event.number))}"
        self.sample_rate = stream.sample_rate
        self.duration_in_samples = stream.plan.counter is not None  # as the controller's own list

    def signal_groups(self) -> list[SignalGroup]:
        return list(self._stream.groups)

    def identity(self) -> dict[str, str]:
        return {"url": self._controller.url, "kind": "xcp event", "model": self._controller.project,
                "loss_detection": self._controller._loss_detection(), **self._stream.identity()}

    def device_calibration(self) -> dict[str, str]:
        return {}

    def start(self, n_samples: int | None) -> None:
        self._stream.rows.start(n_samples)
        self._controller._start_daq()

    def read(self) -> SampleBlock | None:
        return self._stream.read(lambda: self._controller._master.failure)

    def clock_pairs(self) -> list[tuple[int, int]] | None:
        return self._stream.clock_pairs()

    def _close(self) -> None:
        self._stream.rows.closed.set()
