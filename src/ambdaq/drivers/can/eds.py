"""Any CANopen device from its vendor's EDS: the objects a rig file names, in TPDOs on SYNC.

The rig file names the EDS, the node and the objects to record, each as a topic and field with
its scaling to SI units (``factor``, ``offset``, ``unit``; by default the EDS's own ``Factor``
and ``Unit``).  With ``mapping = "configure"`` ambdaq maps them into the device's TPDOs by SDO
(canopen's ``pdo`` API: disable, map, transmission type 1 = every SYNC, enable), packed in order
or into the TPDO each signal names; with ``mapping = "existing"`` it reads the device's TPDO
mapping and records it as it is.  A mapping the EDS forbids (unknown object, not PDO-mappable,
more than 64 bits in a TPDO, more TPDOs than the device has) is refused before anything is
written to the device.

A sample is one SYNC cycle: every synchronous TPDO of the device arrived. Such a device does not
echo the SYNC counter, so a reply is matched to its SYNC by time, as CiA 301 has it: ambdaq sets
the device's synchronous window (0x1007) to half a SYNC period, inside which the device sends its
synchronous PDOs or not at all, and takes a reply whose bus time stamp falls inside the window
after exactly one SYNC as that SYNC's. A reply inside no window, or inside two (the host's SYNC
thread can send two SYNCs closer than a period when it runs late), is not kept
(``late_replies`` in the link statistics; its cycle counts as lost). This needs the interface's
bus time stamps: python-can's ``slcan`` interface stamps a frame when it reads it, so an EDS
device is refused there.

A device that ignores its window, or whose EDS has no 0x1007, can answer a SYNC a whole period
late, inside the next SYNC's window, where time alone would file it under the wrong SYNC. A
device answers its SYNCs in order, one TPDO each, so such a lag shows as a SYNC without a reply
followed, once the device catches up, by a SYNC with two (both in its window, or one in it and one
after it closed). Rows are therefore held for HOLD_CYCLES SYNCs before they are handed on; a second
reply of one TPDO after one SYNC withdraws every held row back to the first SYNC that had none
since the last such withdrawal (``ambiguous_cycles``; they count as lost): while the host's SYNCs
run late, a lagging reply can fall outside every window and leave a second SYNC unanswered
inside one lag run, and the run reaches back to the first.
A lag longer than the hold cannot be withdrawn: it is counted (``unverified_cycles``) and an
event names the cycles. A late reply whose successor is lost leaves no trace at all; only a
device that keeps its synchronous window rules that out, and the metadata says whether it does.
"""

from __future__ import annotations

import logging
import math
import queue
import re
import struct
import time
import warnings
from collections import defaultdict, deque
from dataclasses import dataclass, replace
from pathlib import Path

import canopen
import numpy as np
from canopen import objectdictionary as od

from ...errors import BadInputError, DeviceError
from ..interfaces import Source
from ..rigfile import check_keys
from ..signals import FIELD_TYPES, Event, SampleBlock, SignalGroup, field_problem, ros_field, ros_type
from .bus import CanHub
from ..rows import RowQueue

SIGNAL_KEYS = ("object", "topic", "field", "factor", "offset", "unit", "tpdo")  # a [[device.signal]] table
MAX_TPDOS = 4  # CiA 301 default TPDOs 0x1800..0x1803
MAX_EDS_BYTES = 8 << 20  # vendor EDS files are tens to hundreds of kB
HEARTBEAT_MS = 100
HOLD_CYCLES = 16
"""SYNC cycles a complete row is held before it is handed on: the longest run of one-period-late
replies that is withdrawn when the device catches up (0.04 s at 400 Hz)."""
NMT_STATES = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
_STRUCT = {od.BOOLEAN: "?", od.INTEGER8: "b", od.UNSIGNED8: "B", od.INTEGER16: "h", od.UNSIGNED16: "H",
           od.INTEGER32: "i", od.UNSIGNED32: "I", od.REAL32: "f", od.INTEGER64: "q", od.UNSIGNED64: "Q",
           od.REAL64: "d"}


def load_eds(path: str | Path, node_id: int) -> od.ObjectDictionary:
    """The object dictionary of EDS file ``path``; a missing or malformed file is one
    :class:`BadInputError` line naming the file (and the line, where the parser says)."""
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such EDS file")
    if path.stat().st_size > MAX_EDS_BYTES:
        raise BadInputError(f"{path}: {path.stat().st_size / 1e6:.1f} MB, more than the {MAX_EDS_BYTES >> 20} MB an "
                            "EDS file is read to")
    # canopen logs what it finds odd in a file (a missing section, an unknown data type) through
    # Python's logging, which would print beside ambdaq's one line: what matters of it for the
    # objects ambdaq uses is checked below and where they are used (check_mapping, _read_mapping)
    quiet = logging.getLogger("canopen")
    handlers, propagate = quiet.handlers[:], quiet.propagate
    quiet.handlers, quiet.propagate = [logging.NullHandler()], False
    try:
        with warnings.catch_warnings():  # canopen 2.4 calls the deprecated logger.warn
            warnings.simplefilter("ignore", DeprecationWarning)
            found = canopen.import_od(str(path), node_id)
    except Exception as err:  # configparser, int() and KeyError failures inside canopen's EDS reader
        text = " ".join(str(err).split())[:200] or type(err).__name__
        raise BadInputError(f"{path}: not a valid EDS file ({type(err).__name__}: {text})") from None
    finally:
        quiet.handlers, quiet.propagate = handlers, propagate
    if not list(found):
        raise BadInputError(f"{path}: no objects (is it an EDS file?)")
    return found


def _recordable(var: od.ODVariable, path: Path) -> None:
    """Refuse an object whose data type or EDS factor ambdaq cannot record, naming it."""
    where = f"{path}: object 0x{var.index:04X}.{var.subindex} ({var.name})"
    if var.data_type not in _STRUCT:
        raise BadInputError(f"{where} has data type 0x{var.data_type:04X}, which ambdaq cannot record from a PDO")
    if not math.isfinite(float(var.factor or 1.0)):
        raise BadInputError(f"{where} has the factor {var.factor} in the EDS")


@dataclass(frozen=True)
class EdsSignal:
    """One recorded object: where it is, where it goes, how it scales (SI = raw * factor + offset)."""

    index: int
    subindex: int
    name: str
    topic: str
    field: str
    factor: float
    offset: float
    unit: str
    tpdo: int | None
    var: od.ODVariable

    @property
    def field_type(self) -> str:
        """``int64``/``uint64`` for an unscaled INTEGER64/UNSIGNED64 object (float64 would round
        it past 2**53), else ``float64``."""
        if self.factor != 1 or self.offset != 0 or self.var.data_type not in (od.INTEGER64, od.UNSIGNED64):
            return "float64"
        return "int64" if self.var.data_type == od.INTEGER64 else "uint64"


def _variable(d: od.ObjectDictionary, ref, where: str) -> od.ODVariable:
    """The variable ``ref`` names: ``"0x6078"``, ``"0x2210.2"`` or ``"0x2210sub2"``, or an EDS name:
    an object's, a sub-object's (``Temperature``), or both (``Driver temperature.Temperature``).  A
    name several objects carry is refused with the candidates, as is a missing sub-index."""
    text = str(ref)
    m = re.fullmatch(r"(0x[0-9A-Fa-f]{1,4})(?:(?:\.|sub)(\d+|0x[0-9A-Fa-f]+))?", text)
    if m:
        index, sub = int(m.group(1), 16), int(m.group(2) or "0", 0)
        if index not in d:
            raise BadInputError(f"{where}: no object 0x{index:04X} in the EDS")
        obj = d[index]
        if isinstance(obj, od.ODVariable):
            if sub:
                raise BadInputError(f"{where}: object 0x{index:04X} ({obj.name}) has no sub-indices: give 0x{index:04X}")
            return obj
        subs = sorted(v.subindex for v in obj.values())
        if sub not in subs:
            raise BadInputError(f"{where}: object 0x{index:04X} ({obj.name}) has no sub-index {sub} (it has "
                                f"{', '.join(map(str, subs))})")
        return obj[sub]
    found = []
    for index in d:
        obj = d[index]
        if isinstance(obj, od.ODVariable):
            if obj.name == text:
                found.append(obj)
            continue
        found += [v for v in obj.values() if text in (v.name, f"{obj.name}.{v.name}")]
    if not found:
        if text in d.names:  # a record or array by its own name
            obj = d[text]
            raise BadInputError(f"{where}: {text} is object 0x{obj.index:04X}, which has sub-objects: name one "
                                f"({', '.join(f'0x{obj.index:04X}.{v.subindex}' for v in obj.values())})")
        raise BadInputError(f"{where}: no object named {text!r} in the EDS")
    if len(found) > 1:
        shown = ", ".join(f"0x{v.index:04X}.{v.subindex}" for v in found[:6]) + (" ..." if len(found) > 6 else "")
        raise BadInputError(f"{where}: {len(found)} objects of the EDS are named {text!r} ({shown}): give the index")
    return found[0]


class _AbortOn(canopen.SdoAbortedError):
    """canopen's SDO abort, naming the object it was about (canopen's says only the code)."""

    def __init__(self, code: int, where: str) -> None:
        super().__init__(code)
        self.where = where

    def __str__(self) -> str:
        return f"{super().__str__()} (on {self.where})"


def _aborts_name_their_object(sdo, dictionary: od.ObjectDictionary) -> None:
    """Have the SDO client's uploads and downloads (canopen's PDO API makes them too) raise
    aborts that name the object and sub-index."""
    for method in ("upload", "download"):
        call = getattr(sdo, method)

        def named(index, subindex, *args, _call=call, _what=method, **kwargs):
            try:
                return _call(index, subindex, *args, **kwargs)
            except _AbortOn:
                raise
            except canopen.SdoAbortedError as err:
                try:
                    obj = dictionary[index]
                    name = obj.name if isinstance(obj, od.ODVariable) else f"{obj.name}: {obj[subindex].name}"
                except KeyError:
                    name = "not in the EDS"
                raise _AbortOn(err.code, f"{_what} of 0x{index:04X}.{subindex}, {name}") from None

        setattr(sdo, method, named)


def parse_signals(d: od.ObjectDictionary, entries, device: str, where: str) -> list[EdsSignal]:
    """The rig file's ``[[device.signal]]`` tables, checked against the EDS."""
    if not isinstance(entries, list) or not entries:
        raise BadInputError(f"{where}: mapping = \"configure\" needs [[device.signal]] tables")
    out = []
    for i, e in enumerate(entries):
        at = f"{where}: signal {i + 1}"
        if not isinstance(e, dict) or "object" not in e:
            raise BadInputError(f"{at}: needs object = \"0xINDEX[.SUB]\" (or the EDS name)")
        check_keys(e, SIGNAL_KEYS, at)
        var = _variable(d, e["object"], at)
        if "factor" not in e and not math.isfinite(float(var.factor or 1.0)):
            raise BadInputError(f"{at}: object 0x{var.index:04X}.{var.subindex} ({var.name}) has the factor "
                                f"{var.factor} in the EDS: give factor = ... in the rig file")
        try:
            factor = float(e.get("factor", var.factor or 1.0))
            offset = float(e.get("offset", 0.0))
        except (TypeError, ValueError):
            raise BadInputError(f"{at}: factor and offset must be numbers") from None
        if not (np.isfinite(factor) and np.isfinite(offset)):
            raise BadInputError(f"{at}: factor and offset must be finite")
        tpdo = e.get("tpdo")
        if tpdo is not None and (not isinstance(tpdo, int) or not 1 <= tpdo <= MAX_TPDOS):
            raise BadInputError(f"{at}: tpdo must be 1..{MAX_TPDOS}")
        field = str(e.get("field", ros_field(var.name)))
        if (problem := field_problem(field)) is not None:
            raise BadInputError(f"{at}: {problem}")
        out.append(EdsSignal(var.index, var.subindex, var.name, str(e.get("topic", f"/{device}")), field, factor, offset,
                             str(e.get("unit", var.unit or "")), tpdo, var))
    return out


def mapping_capacity(d: od.ObjectDictionary, n: int) -> int:
    """How many objects TPDO ``n`` (1..4) can carry, as its EDS describes it (CiA 301): the highest
    sub-index of its mapping record 0x1A00 + n - 1, no more than its sub-index 0's upper limit
    where the EDS gives one; 0 where the device has no such TPDO (no 0x1800 + n - 1 or no mapping
    record)."""
    comm, mapping = 0x1800 + n - 1, 0x1A00 + n - 1
    if comm not in d or mapping not in d:
        return 0
    record = d[mapping]
    subs = getattr(record, "subindices", {})
    highest = max((k for k in subs if k > 0), default=0)
    limit = getattr(subs.get(0), "max", None)
    return min(highest, int(limit)) if isinstance(limit, (int, float)) and limit >= 0 else highest


def check_mapping(signals: list[EdsSignal], d: od.ObjectDictionary, path: Path) -> list[list[EdsSignal]]:
    """The signals packed into TPDOs, each into the first whose room is left (64 bits, and the
    entries its mapping record holds: :func:`mapping_capacity`), or into the one it names; refused
    in one line naming the object and the TPDO where it does not fit or the EDS forbids it, before
    anything is written to the device."""
    tpdos: list[list[EdsSignal]] = [[] for _ in range(MAX_TPDOS)]
    capacity = [mapping_capacity(d, n + 1) for n in range(MAX_TPDOS)]
    for s in signals:
        where = f"{path}: object 0x{s.index:04X}.{s.subindex} ({s.name})"
        if not s.var.pdo_mappable:
            raise BadInputError(f"{where} is not PDO-mappable")
        _recordable(s.var, path)
        bits = 8 * struct.calcsize("<" + _STRUCT[s.var.data_type])
        if s.tpdo is not None:
            n = s.tpdo - 1
            if not capacity[n]:
                raise BadInputError(f"{where}: the device has no TPDO{s.tpdo} (no objects 0x{0x1800 + n:04X} and "
                                    f"0x{0x1A00 + n:04X} in the EDS)")
            if len(tpdos[n]) >= capacity[n]:
                raise BadInputError(f"{where} does not fit TPDO{s.tpdo}: its mapping record 0x{0x1A00 + n:04X} holds "
                                    f"{capacity[n]} objects")
            if _bits(tpdos[n]) + bits > 64:
                raise BadInputError(f"{where} does not fit TPDO{s.tpdo}: it would carry {_bits(tpdos[n]) + bits} bits; "
                                    "a CAN frame holds 64")
            tpdos[n].append(s)
            continue
        n = next((k for k, t in enumerate(tpdos) if _bits(t) + bits <= 64 and len(t) < capacity[k]), None)
        if n is None:
            room = ", ".join(f"TPDO{k + 1} {capacity[k]} objects" for k in range(MAX_TPDOS) if capacity[k]) or "none"
            raise BadInputError(f"{where} does not fit: the TPDOs are full (64 bits each; {room})")
        tpdos[n].append(s)
    return tpdos


def _bits(signals: list[EdsSignal]) -> int:
    return sum(8 * struct.calcsize("<" + _STRUCT[s.var.data_type]) for s in signals)


class EdsDevice(Source):
    """A CANopen device from its EDS (see the module docstring).

    Parameters
    ----------
    hub : CanHub
        The bus.
    node_id : int
        CANopen node id (1..127).
    eds : Path
        The vendor's EDS file.
    object_dictionary : ObjectDictionary
        It, loaded.
    signals : list of EdsSignal, or None
        The rig file's signals: their names and scaling for the objects they name.
    tpdos : list of list of EdsSignal, or None
        The signals packed into TPDOs (:func:`check_mapping`), to be mapped by SDO; None: record
        the device's TPDO mapping as it is.
    sync_hz : float or None
        SYNC rate, Hz, when ambdaq produces SYNC; None: another master does (the rate is measured).
    name, url : str
        Device name in recordings, its URL.
    """

    def __init__(self, hub: CanHub, node_id: int, eds: Path, object_dictionary: od.ObjectDictionary,
                 signals: list[EdsSignal] | None, tpdos: list[list[EdsSignal]] | None, *, sync_hz: float | None,
                 name: str, url: str) -> None:
        self.hub, self.node_id, self.eds, self.name, self.url = hub, node_id, eds, name, url
        self.node = canopen.RemoteNode(node_id, object_dictionary)
        self.node.sdo.RESPONSE_TIMEOUT = 0.5
        _aborts_name_their_object(self.node.sdo, object_dictionary)
        hub.network.add_node(self.node)
        self.external = sync_hz is None
        self.sample_rate = self._measure_sync() if self.external else sync_hz
        try:
            self.identity_words = [self._identity(i) for i in (1, 2, 4)]
            if tpdos is not None:
                self._configure(tpdos)
            self.tpdos = self._read_mapping(signals)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            hub.network.nodes.pop(node_id, None)
            raise DeviceError(f"CANopen node {node_id} ({eds.name}): {err}") from None
        if not self.tpdos:
            hub.network.nodes.pop(node_id, None)
            raise DeviceError(f"CANopen node {node_id} ({eds.name}): no TPDO is mapped and sent on SYNC")
        by_topic: dict[str, list[EdsSignal]] = defaultdict(list)
        for _cob, _fmt, sigs in self.tpdos:
            for s in sigs:
                by_topic[s.topic].append(s)
        self.groups = [SignalGroup(t, "Eds" + ros_type(t),
                                   tuple(s.field for s in sigs), tuple(s.unit for s in sigs),
                                   tuple(s.field_type for s in sigs))
                       for t, sigs in by_topic.items()]
        self._order = [s for _c, _f, sigs in self.tpdos for s in sigs]
        self._columns = {t: [self._order.index(s) for s in sigs] for t, sigs in by_topic.items()}
        self._rows = RowQueue(max(1.0, 20 / self.sample_rate))  # (cycle, time ns, raw values)
        self._parts: list = [None] * len(self.tpdos)
        self._replied = [-1] * len(self.tpdos)  # per TPDO: the newest cycle it answered
        # per TPDO: the first cycle it left unanswered since its last lag was resolved (a second reply
        # after one SYNC): a lag run can leave more than one SYNC unanswered (the host's SYNCs
        # running late file a lagging reply outside every window), and it reaches back to the first
        self._silent = [-1] * len(self.tpdos)
        self._resolved = [-1] * len(self.tpdos)  # per TPDO: the cycle of its last second reply
        self._held: deque[tuple[int, int, list]] = deque()  # complete rows, HOLD_CYCLES before handed on
        self._handed = -1  # the newest cycle handed on
        self._withdrawn = -1  # the newest cycle withdrawn (a late row for it must not come back)
        self.late_replies = self.ambiguous_cycles = self.unverified_cycles = 0
        self.window_ns = int(0.5e9 / self.sample_rate)  # the synchronous window: half a SYNC period
        dictionary = self.node.object_dictionary
        self.window_on_device = 0x1007 in dictionary and dictionary[0x1007].writable  # set in start()
        self._events: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._nmt_state: int | None = None

    # --- set-up -------------------------------------------------------------------------------------

    def _measure_sync(self) -> float:
        """The rate of another master's SYNC, Hz, from what the bus carries for half a second."""
        t0 = time.monotonic()
        first = self.hub.cycle
        while first.count < 0 and time.monotonic() - t0 < 1.0:
            time.sleep(0.01)
            first = self.hub.cycle
        time.sleep(0.5)
        last = self.hub.cycle
        if first.count < 0 or last.count - first.count < 2:
            raise DeviceError(f"CANopen node {self.node_id}: no SYNC from another master on "
                              f"{self.hub.interface}/{self.hub.channel} (sync=external) within "
                              f"{time.monotonic() - t0:.1f} s")
        return round((last.count - first.count) * 1e9 / (last.time_ns - first.time_ns), 1)

    def _identity(self, sub: int) -> int | None:
        """0x1018's vendor id (1), product code (2) or serial number (4); the last two are optional
        in CiA 301, and a device that aborts their upload has none (None)."""
        try:
            return struct.unpack("<I", self.node.sdo.upload(0x1018, sub))[0]
        except canopen.SdoAbortedError:
            if sub == 1:
                raise
            return None

    def _configure(self, tpdos: list[list[EdsSignal]]) -> None:
        """Map ``tpdos`` by SDO with canopen's pdo API: each TPDO disabled, mapped, synchronous on
        every SYNC, enabled; unused TPDOs disabled."""
        self.node.nmt.send_command(0x80)  # PRE-OPERATIONAL: PDO mapping may change
        self.node.tpdo.read()
        for n, sigs in enumerate(tpdos):
            if 0x1800 + n not in self.node.object_dictionary:
                continue
            pdo = self.node.tpdo[n + 1]
            pdo.clear()
            for s in sigs:
                pdo.add_variable(s.index, s.subindex)
            pdo.trans_type = 1
            pdo.cob_id = 0x180 + 0x100 * n + self.node_id  # CiA 301 default COB-IDs
            pdo.enabled = bool(sigs)
            pdo.save()

    def _read_mapping(self, wanted: list[EdsSignal] | None) -> list[tuple[int, struct.Struct, list[EdsSignal]]]:
        """The device's enabled synchronous TPDOs as (COB-ID, layout, signals), read back by SDO;
        with a configured mapping, the rig file's names and scaling for each object."""
        self.node.tpdo.read()
        named = {(s.index, s.subindex): s for s in wanted or ()}
        out = []
        seen: set[tuple[int, int]] = set()
        for n in range(1, MAX_TPDOS + 1):
            if 0x1800 + n - 1 not in self.node.object_dictionary:
                continue
            pdo = self.node.tpdo[n]
            if not pdo.enabled or not pdo.map or not 1 <= (pdo.trans_type or 0) <= 240:
                continue
            sigs = []
            for v in pdo.map:
                s = named.get((v.index, v.subindex))
                if s is None:
                    var = v.od
                    _recordable(var, self.eds)
                    s = EdsSignal(v.index, v.subindex, var.name, f"/{self.name}", ros_field(var.name),
                                  float(var.factor or 1.0), 0.0, var.unit or "", n, var)
                if (v.index, v.subindex) in seen:  # mapped in an earlier TPDO too: a field that says which PDO
                    s = replace(s, field=f"{s.field}_tpdo{n}", tpdo=n)
                seen.add((v.index, v.subindex))
                sigs.append(s)
            out.append((pdo.cob_id, struct.Struct("<" + "".join(_STRUCT[s.var.data_type] for s in sigs)), sigs))
        return out

    # --- recorder source ----------------------------------------------------------------------------

    def signal_groups(self) -> list[SignalGroup]:
        return self.groups

    def identity(self) -> dict[str, str]:
        vendor, product, serial = self.identity_words
        return {"url": self.url, "kind": "eds", "eds": self.eds.name, "vendor_id": f"0x{vendor:08X}",
                "product_code": "none (0x1018.2 aborted)" if product is None else f"0x{product:08X}",
                "serial": "none (0x1018.4 aborted)" if serial is None else str(serial), "node_id": str(self.node_id),
                "sample_rate_hz": f"{self.sample_rate:g}", "sync": "external" if self.external else "ambdaq",
                "synchronous_window_us": f"{self.window_ns / 1000:g}" + ("" if self.window_on_device else
                                                                          " (host only: the device has no 0x1007)"),
                "tpdos": "; ".join(f"0x{cob:03X}: " + ", ".join(f"0x{s.index:04X}.{s.subindex}" for s in sigs)
                                   for cob, _f, sigs in self.tpdos)}

    def device_calibration(self) -> dict[str, str]:
        return {s.field: f"{s.factor:g} {s.unit} per count + {s.offset:g} (0x{s.index:04X}.{s.subindex} {s.name})"
                for _c, _f, sigs in self.tpdos for s in sigs}

    def start(self, n_samples: int | None) -> None:
        self._rows.start(n_samples)
        self.hub.register_stream(self.name, [fmt.size for _c, fmt, _s in self.tpdos], self.sample_rate,
                                 external=self.external)
        self.hub.check_load()
        for i, (cob, fmt, _s) in enumerate(self.tpdos):
            self.hub.on_frame(cob, self._on_tpdo(i, fmt))
        self.hub.add_sync_listener(self._hand_on)
        self.hub.on_frame(0x700 + self.node_id, self._on_heartbeat)
        self.node.emcy.add_callback(self._on_emcy)
        od_ = self.node.object_dictionary
        try:
            if 0x1017 in od_:
                self.node.sdo[0x1017].raw = HEARTBEAT_MS
            if self.window_on_device:  # CiA 301 synchronous window, us
                if 0x1006 in od_ and od_[0x1006].writable:
                    self.node.sdo[0x1006].raw = int(round(1e6 / self.sample_rate))
                self.node.sdo[0x1007].raw = self.window_ns // 1000
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise DeviceError(f"CANopen node {self.node_id}: setting its heartbeat and SYNC window failed: {err}") from None
        self.node.nmt.send_command(0x01)  # OPERATIONAL
        self._rows.last_row = time.monotonic()
        self.hub.start_sync()

    def _on_tpdo(self, i: int, fmt: struct.Struct):
        last = len(self._parts) - 1

        def on_tpdo(data: bytearray, timestamp: float) -> None:  # on the bus thread
            if len(data) != fmt.size:
                return  # never recorded: a cycle with it is a drop
            t_ns = int(timestamp * 1e9)
            cycle, before = self.hub.cycle_at(t_ns)
            if cycle is None:
                self.late_replies += 1
                self._parts[i] = None
                return
            c = cycle.count
            if c == self._replied[i]:
                # a second reply since SYNC c, in its window or after it: one of the two answers an
                # earlier SYNC (the device was a SYNC behind)
                self._parts[i] = None
                self._withdraw(self._silent[i], c)
                self._resolved[i] = c
                return
            if 0 <= self._replied[i] < c - 1 and (self._silent[i] <= self._resolved[i]
                                                   or self._silent[i] < c - HOLD_CYCLES):
                self._silent[i] = c - 1  # the first since the last lag resolved (one past the hold is moot)
            self._replied[i] = c  # a reply came after SYNC c, kept or not: a second one is a lag
            self.hub.answered = c
            if t_ns - cycle.time_ns > self.window_ns or (before is not None and t_ns - before.time_ns <= self.window_ns):
                # outside every synchronous window, or inside two (SYNCs the host sent late, closer
                # than a window apart): whose reply it is, is unknown
                self.late_replies += 1
                self._parts[i] = None
                return
            self._parts[i] = (cycle, fmt.unpack(data))
            if i < last:
                return
            parts, self._parts = self._parts, [None] * len(self._parts)
            if any(p is None or p[0].count != c for p in parts) or c <= self._withdrawn:
                return  # part of this cycle was lost, late, or its window had two replies: a drop
            self._held.append((c, cycle.time_ns, [v for p in parts for v in p[1]]))

        return on_tpdo

    def _hand_on(self, cycle) -> None:
        """A SYNC went out (bus thread): rows HOLD_CYCLES older are handed to the reader."""
        held, rows = self._held, self._rows.rows
        while held and held[0][0] <= cycle.count - HOLD_CYCLES:
            row = held.popleft()
            rows.append(row)
            self._handed = row[0]

    def _withdraw(self, silent: int, doubled: int) -> None:
        """A TPDO answered SYNC ``doubled`` twice: since the window of ``silent`` went without its
        reply, every reply may have been the SYNC before's. Held rows of those cycles are dropped;
        rows already handed on are counted and named in an event."""
        self._withdrawn = max(self._withdrawn, doubled)
        kept = [r for r in self._held if not silent < r[0] <= doubled]
        self.ambiguous_cycles += len(self._held) - len(kept)
        self._held = deque(kept)
        if self._handed > silent:
            lost = self._handed - silent
            self.unverified_cycles += lost
            self._events.put(Event(time.time_ns(), "late-replies", lost,
                                   f"node {self.node_id}: SYNC cycles {silent + 1}..{self._handed} were recorded "
                                   f"before the device caught up; each may hold the SYNC before's data"))

    def _on_heartbeat(self, data: bytearray, timestamp: float) -> None:
        state = data[0] & 0x7F if data else None
        if state != self._nmt_state:
            self._nmt_state = state
            self._events.put(Event(int(timestamp * 1e9), "nmt", state or 0,
                                   f"node {self.node_id} {NMT_STATES.get(state, f'state 0x{state:02X}')}"))

    def _on_emcy(self, err) -> None:
        self._events.put(Event(0, "fault", err.code, f"EMCY 0x{err.code:04X} {err.get_desc()} (register 0x{err.register:02X})"))

    def read(self) -> SampleBlock | None:
        taken = self._rows.take(
            lambda: None if self.hub.failure is None else f"{self.name} ({self.url}): {self.hub.failure}",
            lambda silent: f"{self.name} ({self.url}): no process data from node {self.node_id} for {silent:.1f} s")
        if taken is None:
            return None
        rows, cycles = taken
        raw = list(zip(*(r[2] for r in rows)))  # per object, its raw values (Python numbers, exact)
        si = [np.array(v, dtype=FIELD_TYPES[s.field_type]) if s.field_type != "float64"
              else np.array(v, dtype=np.float64) * s.factor + s.offset for s, v in zip(self._order, raw)]
        t = np.array([r[1] for r in rows], dtype=np.int64)
        return self.hub.sample_block(t, cycles, {g.topic: g.values_from_columns([si[c] for c in self._columns[g.topic]])
                                                 for g in self.groups})

    def clock_pairs(self) -> list[tuple[int, int]] | None:
        return self.hub.take_clock_pairs(self)

    def events(self) -> list[Event]:
        return self.hub.take_events(self._events)

    def link_statistics(self) -> dict[str, str]:
        return self.hub.statistics() | {"late_replies": str(self.late_replies),
                                        "ambiguous_cycles": str(self.ambiguous_cycles),
                                        "unverified_cycles": str(self.unverified_cycles)}

    def _close(self) -> None:
        self.hub.remove_sync_listener(self._hand_on)
        self._rows.closed.set()
        try:
            self.node.nmt.send_command(0x80)  # PRE-OPERATIONAL: TPDOs stop
        except Exception:  # the bus may be gone already
            pass
        self.hub.release()
