"""Raw CAN devices described by a DBC file (decoded by cantools): sensors and conditioners that
send their own frames, with no CANopen.

Each DBC message the rig file asks for is one topic (``/<device>/<Message>``; a multiplexed message
is one topic per multiplexer value, ``/<device>/<Message>/m<k>``, holding the signals of that value
and the ones common to all), with the signals as fields, in the DBC's own units, scaled and
byte-ordered as the DBC says.  A sample is one received frame, timed by its bus time stamp on the
host clock.  A message whose DBC has a rolling counter signal names it in the rig file; its frames'
counter gives the sequence number, so a lost frame is counted and a repeated one dropped as a
duplicate (a counter of N bits sees fewer than 2**N lost in a row; more look like fewer).  Without a counter, frames are numbered as they arrive
and a loss cannot be seen: the recording's metadata says which.

Frames of identifiers the DBC does not describe are counted, and recorded raw to ``/can/raw``
(identifier, length, flags and the eight data bytes) when the rig file asks.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import AmbdaqWarning, BadInputError
from ..interfaces import Source
from ..signals import SampleBlock, SignalGroup, ros_field, ros_type
from .bus import CanHub
from ..rows import RowQueue

MAX_DBC_BYTES = 16 << 20  # opendbc's largest files are about 1 MB
MAX_TOKEN = 1 << 16  # a 50 MB string once cost cantools 10.7 GB and 50 s; 64 KB costs it about 13 MB
_LONG_TOKEN = re.compile(r'"[^"]{%d,}"|[^\s"]{%d,}' % (MAX_TOKEN + 1, MAX_TOKEN + 1))
RAW_TOPIC = "/can/raw"
RAW_FIELDS = ("arbitration_id", "dlc", "extended", *(f"b{i}" for i in range(8)))


def load_dbc(path: str | Path):
    """The cantools database of DBC file ``path``; a missing or malformed file is one
    :class:`BadInputError` line naming the file and, where cantools says, the line."""
    try:
        import cantools
    except ImportError:
        raise BadInputError("DBC devices need cantools: pip install 'ambdaq[dbc]'") from None
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such DBC file")
    size = path.stat().st_size
    if size > MAX_DBC_BYTES:
        raise BadInputError(f"{path}: {size / 1e6:.1f} MB, more than the {MAX_DBC_BYTES >> 20} MB a DBC file is read "
                            "to (the largest real ones are a few MB)")
    try:
        text = path.read_bytes()[:MAX_DBC_BYTES].decode("cp1252", errors="replace")
    except OSError as err:
        raise BadInputError(f"{path}: {err.strerror or err}") from None
    long = _LONG_TOKEN.search(text)
    if long is not None:
        line = text.count("\n", 0, long.start()) + 1
        raise BadInputError(f"{path}: line {line}: a string or word of {len(long.group()):,} characters (at most "
                            f"{MAX_TOKEN:,}; cantools takes some 200 bytes of memory per character)")
    strict = None  # why cantools' checks refused it, where they did
    for checked in (True, False):  # cantools' strict checks (overlapping signals, a signal past the frame ...)
        try:
            db = cantools.database.load_string(text, database_format="dbc", strict=checked)
        except (cantools.database.errors.ParseError, cantools.database.UnsupportedDatabaseFormatError,
                UnicodeDecodeError, ValueError, KeyError, IndexError, TypeError) as err:
            said = (str(err).splitlines()[0] if str(err) else type(err).__name__).removeprefix("DBC: ").strip('"')
            if checked:
                strict = said
                continue
            raise BadInputError(f"{path}: not a valid DBC file: {said}") from None
        if strict is not None:
            warnings.warn(f"{path}: read with cantools' checks relaxed (strict=False), as cantools reads it: "
                          f"{strict}", AmbdaqWarning, stacklevel=2)
        return db
    raise AssertionError("unreachable")


@dataclass
class DbcRequest:
    """What to record of a DBC device (a rig file's ``dbc``, ``messages``, ``counters``, ``raw``).

    Parameters
    ----------
    path : Path
        The DBC file.
    messages : tuple of str
        Message names to record; empty: every message of the DBC.
    counters : dict of str to str
        Message name -> its rolling counter signal.
    raw : bool
        Record frames of identifiers the DBC does not describe to ``/can/raw``.
    rates : dict of str to float
        Message name -> its rate in Hz, for a message whose DBC gives no cycle time.
    rate : float, optional
        The rate in Hz of every other message without a cycle time; None: such messages are
        recorded as their frames come.
    """

    path: Path
    messages: tuple[str, ...] = ()
    counters: dict[str, str] = field(default_factory=dict)
    raw: bool = False
    rates: dict[str, float] = field(default_factory=dict)
    rate: float | None = None


ROUND_LIMIT = 1 << 53  # the largest integer float64 holds exactly


def _field_type(signal) -> str:
    """The recorded type of a DBC signal: ``int64``/``uint64`` for an unscaled integer signal
    longer than 53 bits (float64 would round its values past 2**53), else ``float64``."""
    if signal.is_float or signal.scale != 1 or signal.offset != 0 or signal.length <= 53:
        return "float64"
    return "int64" if signal.is_signed else "uint64"


class _Stream:
    """Rows of one topic as the bus thread decodes them: (seq, time ns, values)."""

    def __init__(self, group: SignalGroup, counter: str | None, counter_bits: int, rate_hz: float | None,
                 rate_source: str = "", names: dict[str, str] | None = None,
                 choices: dict[str, dict[str, str]] | None = None) -> None:
        self.group = group
        self.rate_hz = rate_hz
        self.rate_source = rate_source
        self.names = names or {}  # field -> the DBC's signal name
        self.choices = choices or {}  # field -> its value table (value -> text)
        self.counter = counter
        self.modulus = 1 << counter_bits if counter else 0
        self.queue = RowQueue(float("inf"))  # a message a DBC describes may never come: the bus's silence ends it
        self.received = 0  # frames, or the unwrapped counter
        self.last_counter: int | None = None
        self.rounded = 0  # recorded integer values beyond 2**53 in float64 fields, which hold them rounded

    def add(self, t_ns: int, values: list[float], counter: int | None, rounded: int = 0) -> None:
        """One frame's row; ``rounded``: how many of its values float64 holds only rounded."""
        if counter is None:
            seq = self.received
            self.received += 1
        else:  # unwrap the rolling counter: the same value again is a repeat (a duplicate the
            # recorder drops and counts), any other the frames since the last one
            step = counter + 1 if self.last_counter is None else (counter - self.last_counter) % self.modulus
            self.last_counter = counter
            self.received += step
            seq = self.received - 1
        self.queue.rows.append((seq, t_ns, values, rounded))


def _pages(tree: list, path: tuple = ()) -> dict[tuple, list[str]]:
    """Every way through a message's signal tree (cantools' ``signal_tree``: names, and for each
    multiplexer ``{name: {value: subtree}}``): the (multiplexer, value) pairs taken -> the signals
    a frame of them carries.  A plain message has one page, ``()``; cascaded multiplexers
    (SG_MUL_VAL_) nest, independent ones at one level combine."""
    plain = [n for n in tree if isinstance(n, str)]
    muxes = [n for n in tree if isinstance(n, dict)]
    pages: dict[tuple, list[str]] = {path: plain + [next(iter(m)) for m in muxes]}
    for mux in muxes:
        (name, by_value), = mux.items()
        pages = {p + sub_path: names + sub_names for p, names in pages.items()
                 for value, subtree in sorted(by_value.items())
                 for sub_path, sub_names in _pages(subtree, ((name, value),)).items()}
    return pages


def _path(tree: list, decoded: dict) -> tuple | None:
    """The page of ``_pages`` a decoded frame is on (None: a multiplexer value the DBC lacks)."""
    path: tuple = ()
    for mux in (n for n in tree if isinstance(n, dict)):
        (name, by_value), = mux.items()
        value = decoded.get(name)
        subtree = by_value.get(int(value)) if value is not None else None
        if subtree is None:
            return None
        rest = _path(subtree, decoded)
        if rest is None:
            return None
        path += ((name, int(value)),) + rest
    return path


def _field_names(path: Path, msg, signals) -> dict[str, str]:
    """Each signal's field name in the form ROS 2 requires (:func:`ros_field`); two signals of one
    message that would share a field are refused, naming both."""
    out: dict[str, str] = {}
    taken: dict[str, str] = {}
    for sig in signals:
        name = ros_field(sig.name)
        if taken.setdefault(name, sig.name) != sig.name:
            raise BadInputError(f"{path}: message {msg.name}: signals {taken[name]} and {sig.name} would both be field "
                                f"{name} (ROS 2 field names are lower case)")
        out[sig.name] = name
    return out


class DbcReceiver:
    """Decodes the DBC's frames on the bus thread into one :class:`_Stream` per topic, and counts
    (or keeps) the frames of unknown identifiers."""

    def __init__(self, hub: CanHub, db, request: DbcRequest, device: str) -> None:
        self.hub, self.db, self.request = hub, db, request
        names = request.messages or tuple(m.name for m in db.messages)
        prefix = f"/{device}"
        self.streams: dict[tuple[int, int | None], _Stream] = {}
        self.decoders: dict[int, tuple] = {}
        for name in names:
            try:
                msg = db.get_message_by_name(name)
            except KeyError:
                raise BadInputError(f"{request.path}: no message {name!r} "
                                    f"(it has {', '.join(m.name for m in db.messages)})") from None
            counter = request.counters.get(name)
            bits = 0
            if counter is not None:
                sig = next((s for s in msg.signals if s.name == counter), None)
                if sig is None or sig.scale != 1 or sig.offset != 0 or sig.is_signed or sig.is_float:
                    raise BadInputError(f"{request.path}: message {name} has no unsigned integer signal "
                                        f"{counter!r} to count frames by")
                bits = sig.length
            by_name = {s.name: s for s in msg.signals}
            muxes = {s.name for s in msg.signals if s.is_multiplexer}
            keys = {path: [by_name[n] for n in names if n not in muxes and n != counter]
                    or [by_name[m] for m, _v in path]  # a page of no signal of its own: its multiplexer's value
                    for path, names in _pages(msg.signal_tree).items()}
            rate, source = self._rate(msg, request)
            fields = _field_names(request.path, msg, list({s.name: s for sig in keys.values() for s in sig}.values()))
            for key, signals in keys.items():
                topic = f"{prefix}/{name}" + "".join(f"/m{v}" for _m, v in key)
                group = SignalGroup(topic, f"Dbc{ros_type(name)}" + "".join(f"M{v}" for _m, v in key),
                                    tuple(fields[s.name] for s in signals), tuple(s.unit or "" for s in signals),
                                    tuple(_field_type(s) for s in signals))
                paged = len(keys) > 1  # a page comes when its frame does: its rate is measured, and the
                # message's counter counts the message's frames, not the page's
                self.streams[(msg.frame_id, key)] = _Stream(
                    group, None if paged else counter, 0 if paged else bits, None if paged else rate,
                    f"a page of {name}, measured ({source.split(':')[0]} is the message's)" if paged else source,
                    {fields[s.name]: s.name for s in signals},
                    {fields[s.name]: {f"{int(v)}": str(t) for v, t in s.choices.items()} for s in signals if s.choices})
            self.decoders[msg.frame_id] = (msg, counter, {k: [s.name for s in sig] for k, sig in keys.items()})
        self.unknown = 0
        self.undecodable = 0
        self.raw_stream = _Stream(SignalGroup(RAW_TOPIC, "RawFrame", RAW_FIELDS,
                                              ("", "byte", "", *("byte",) * 8)), None, 0, None) if request.raw else None
        known = {(m.frame_id, m.is_extended_frame) for m in db.messages}
        for frame_id, (msg, _counter, _fields) in self.decoders.items():
            hub.on_frame(frame_id, self._on_frame(frame_id), extended=msg.is_extended_frame)
        hub.on_unknown(lambda msg: self._on_unknown(msg, known))

    @staticmethod
    def _rate(msg, request: DbcRequest) -> tuple[float | None, str]:
        """A message's rate in Hz and where it comes from: its DBC's cycle time, else the rig
        file's ``rates`` or ``rate``, else none (its frames are recorded as they come)."""
        cycle = msg.cycle_time
        if cycle is not None and cycle != 0:
            if not (isinstance(cycle, (int, float)) and math.isfinite(cycle) and 0 < cycle <= 3_600_000):
                raise BadInputError(f"{request.path}: message {msg.name}: GenMsgCycleTime {cycle} is not a cycle time "
                                    "in ms (0 < cycle <= 3,600,000)")
            return 1000.0 / cycle, f"GenMsgCycleTime {cycle:g} ms"
        given = request.rates.get(msg.name, request.rate)
        if given is not None:
            return float(given), "the rig file"
        return None, "none declared: recorded as its frames come (ambdaq info measures the rate)"

    def _on_frame(self, frame_id: int):
        msg, counter, fields = self.decoders[frame_id]
        streams, tree = self.streams, msg.signal_tree

        def on_frame(data: bytearray, timestamp: float) -> None:  # on the bus thread
            try:
                decoded = msg.decode(bytes(data), decode_choices=False)
            except Exception:  # cantools raises DecodeError, ValueError, KeyError ... on a bad frame
                self.undecodable += 1
                return
            key = _path(tree, decoded)
            names = fields.get(key)
            if names is None or any(n not in decoded for n in names):
                self.undecodable += 1  # a multiplexer value the DBC does not define
                return
            stream = streams[(frame_id, key)]
            values = [decoded[n] for n in names]
            # an integer beyond 2**53 in a float64 field (an integer scale on a long signal) is
            # recorded rounded: counted, never silent; int64/uint64 fields hold it exactly
            stream.add(int(round(timestamp * 1e9)), values, None if counter is None else int(decoded[counter]),
                       sum(1 for v, t in zip(values, stream.group.field_types)
                           if t == "float64" and isinstance(v, int) and abs(v) > ROUND_LIMIT))

        return on_frame

    def _on_unknown(self, msg, known: set[tuple[int, bool]]) -> None:
        if (msg.arbitration_id, msg.is_extended_id) in known:
            return  # a DBC message the rig file did not ask for
        self.unknown += 1
        if self.raw_stream is not None:
            data = bytes(msg.data) + bytes(8 - len(msg.data))
            self.raw_stream.add(int(round(msg.timestamp * 1e9)),
                                [float(msg.arbitration_id), float(msg.dlc), float(msg.is_extended_id), *data], None)


BUS_SILENT_S = 2.0
"""Seconds without any frame on the bus after which a DBC device's recording ends: a DBC
describes more messages than one bus carries, so one message that never comes ends nothing (its
topic is said to be never received); a bus with no frame at all is gone."""


class DbcMessageSource(Source):
    """One topic of a DBC device, as a recorder source (see the module docstring).  Its duration is
    the host clock's: a message's declared cycle is what it should do, not what it does (a page of
    a multiplexed message comes when its frame does)."""

    duration_in_samples = False

    def __init__(self, receiver: DbcReceiver, stream: _Stream, *, name: str, url: str) -> None:
        self.receiver, self.stream = receiver, stream
        self.name, self.url = name, url
        self.sample_rate = stream.rate_hz

    def signal_groups(self) -> list[SignalGroup]:
        return [self.stream.group]

    def identity(self) -> dict[str, str]:
        db_path = self.receiver.request.path
        rate = {} if self.sample_rate is None else {"sample_rate_hz": f"{self.sample_rate:g}"}
        stream = self.stream
        named = {f: n for f, n in stream.names.items() if f != n}
        return {"url": self.url, "kind": "dbc", "dbc": db_path.name, "topic": stream.group.topic, **rate,
                "rate_source": stream.rate_source,
                "sequence": (f"rolling counter {stream.counter} ({stream.modulus})"
                             if stream.counter else "arrival order: losses cannot be seen"),
                **({"signals": json.dumps(named)} if named else {}),
                **({"value_tables": json.dumps(stream.choices)} if stream.choices else {})}

    def device_calibration(self) -> dict[str, str]:
        return {"scaling": f"as {self.receiver.request.path.name} says"}

    def start(self, n_samples: int | None) -> None:
        self.stream.queue.rows.clear()
        self.stream.queue.start(n_samples)

    def read(self) -> SampleBlock | None:
        hub = self.receiver.hub

        def failure() -> str | None:
            if hub.failure is not None:
                return f"{self.name} ({self.url}): {hub.failure}"
            silent = hub.silent_s()
            if silent > BUS_SILENT_S:
                return f"{self.name} ({self.url}): no frame at all on the bus for {silent:.1f} s: the bus went silent"
            return None

        taken = self.stream.queue.take(failure, lambda silent: f"{self.name} ({self.url}): silent for {silent:.1f} s")
        if taken is None:
            return None
        got, seq = taken
        self.stream.rounded += sum(r[3] for r in got)  # of the rows recorded, not of every frame seen
        t = np.array([r[1] for r in got], dtype=np.int64)
        return hub.sample_block(t, seq, {self.stream.group.topic: self.stream.group.values_array([r[2] for r in got])})

    def clock_pairs(self) -> list[tuple[int, int]] | None:
        return self.receiver.hub.take_clock_pairs(self)

    def link_statistics(self) -> dict[str, str]:
        r = self.receiver
        rounded = {"int64_values_rounded": str(self.stream.rounded)} if self.stream.rounded else {}
        return r.hub.statistics() | {"unknown_frames": str(r.unknown), "undecodable_frames": str(r.undecodable)} | rounded

    def events(self):
        return self.receiver.hub.take_events()

    def _close(self) -> None:
        self.stream.queue.closed.set()
        self.receiver.hub.release()
