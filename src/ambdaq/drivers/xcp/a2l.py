"""What ambdaq needs of an A2L file (ASAM MCD-2 MC 1.7), read from its block tree
(:mod:`.a2l_syntax`).

Measurements: address and address extension, data type, byte order, bit mask, array size, the
conversion to physical units and the DAQ events the file allows (``IF_DATA XCP`` ``DAQ_EVENT``
``FIXED_EVENT_LIST`` / ``DEFAULT_EVENT_LIST``).  A conversion ambdaq computes (``IDENTICAL``,
``LINEAR``, a linear ``RAT_FUNC``, ``TAB_INTP``) gives physical values; any other (``TAB_VERB``,
whose verbal table, a ``COMPU_VTAB`` or ``COMPU_VTAB_RANGE`` with its ``DEFAULT_VALUE``, is
kept for the recording's metadata, ``TAB_NOINTP``, ``FORM``, a non-linear
``RAT_FUNC``) is recorded as the raw value with the conversion named.  Nothing about a
measurement that is not selected can refuse the file: what ambdaq cannot record is refused when
it is selected (:meth:`A2lMeasurement.problem`).

Where ambdaq records a measurement: an ``ANNOTATION`` labelled ``ambdaq`` with the text
``topic=/amb/gap type=Gap field=front_x`` (what ``ambdaq sim a2l`` writes) places it; else it
goes to the topic of its event (:mod:`.device`).  ``role=counter`` marks a counter of control
periods (each sample's ``seq``).

Characteristics: a ``VALUE`` or ``VAL_BLK`` of a numeric record layout is a parameter (read and,
unless ``READ_ONLY``, written by ``controller param``); those of FLOAT64 values are also the
controller's calibration constants, read when it is opened.  Blobs are every characteristic by
address and size (the coefficient bank of a controller that takes ``ambdaq push`` over XCP).
An ``ambdaq`` annotation on a parameter names its role: ``role=speed`` (``--rpm``) or
``role=test-signal axes=A,B unit=m|V min_amplitude=X max_amplitude=Y``.

Events: the ``IF_DATA XCP`` ``DAQ`` block's ``EVENT``s (name, number, cycle), for listing; what
the slave answers (GET_DAQ_EVENT_INFO) is what a recording uses.

Reading the largest vendor file here (3.9 MB, 3,005 measurements) takes about a second, so
nothing is cached (docs/performance.md, "A2L files").
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from ...errors import AmbdaqWarning, BadInputError
from .a2l_syntax import Block, Text, read_tree

TYPES = {"UBYTE": ("u", 1), "SBYTE": ("i", 1), "UWORD": ("u", 2), "SWORD": ("i", 2), "ULONG": ("u", 4),
         "SLONG": ("i", 4), "A_UINT64": ("u", 8), "A_INT64": ("i", 8), "FLOAT16_IEEE": ("f", 2),
         "FLOAT32_IEEE": ("f", 4), "FLOAT64_IEEE": ("f", 8)}
"""A2L data type -> numpy kind and size in bytes."""
BYTE_ORDERS = {"MSB_LAST": "<", "LITTLE_ENDIAN": "<", "MSB_FIRST": ">", "BIG_ENDIAN": ">"}
"""A2L BYTE_ORDER -> numpy byte order (MSB_FIRST_MSW_LAST and MSB_LAST_MSW_FIRST are not read)."""
KEEP = frozenset({"PROJECT", "MODULE", "MOD_COMMON", "MEASUREMENT", "CHARACTERISTIC", "AXIS_PTS", "COMPU_METHOD", "COMPU_TAB",
                  "COMPU_VTAB", "COMPU_VTAB_RANGE", "RECORD_LAYOUT", "ANNOTATION", "ANNOTATION_TEXT", "IF_DATA",
                  "DAQ_EVENT", "FIXED_EVENT_LIST", "DEFAULT_EVENT_LIST", "DAQ", "EVENT", "INSTANCE", "TYPEDEF_STRUCTURE",
                  "STRUCTURE_COMPONENT", "TYPEDEF_MEASUREMENT", "TYPEDEF_CHARACTERISTIC", "AXIS_DESCR", "MEMORY_SEGMENT", "SEGMENT", "CHECKSUM", "PAGE", "MOD_PAR",
                  "TIMESTAMP_SUPPORTED", "DAQ_LIST"})
DEFAULT_ALIGNMENT = {"UBYTE": 1, "SBYTE": 1, "UWORD": 2, "SWORD": 2, "ULONG": 4, "SLONG": 4, "A_UINT64": 8,
                     "A_INT64": 8, "FLOAT16_IEEE": 2, "FLOAT32_IEEE": 4, "FLOAT64_IEEE": 8}
"""Alignment of each data type in ECU memory where MOD_COMMON does not say (ASAM MCD-2 MC: ALIGNMENT_*)."""
ALIGNMENT_KEYWORDS = {"ALIGNMENT_BYTE": ("UBYTE", "SBYTE"), "ALIGNMENT_WORD": ("UWORD", "SWORD"),
                      "ALIGNMENT_LONG": ("ULONG", "SLONG"), "ALIGNMENT_INT64": ("A_UINT64", "A_INT64"),
                      "ALIGNMENT_FLOAT16_IEEE": ("FLOAT16_IEEE",), "ALIGNMENT_FLOAT32_IEEE": ("FLOAT32_IEEE",),
                      "ALIGNMENT_FLOAT64_IEEE": ("FLOAT64_IEEE",)}
RECORD_AXIS_ITEM = re.compile(r"(NO_AXIS_PTS|AXIS_PTS)_([XYZ45])")
RECORD_ITEM = re.compile(r"FNC_VALUES|IDENTIFICATION|RESERVED|(NO_)?AXIS_PTS_[XYZ45]|(NO_)?RESCALE_[XYZ]|"
                         r"(OFFSET|SHIFT_OP|DIST_OP|SRC_ADDR|AXIS_RESCALE)_[XYZ45]|RIP_ADDR_[WXYZ45]")
"""The items a RECORD_LAYOUT places in memory (ASAM MCD-2 MC, RECORD_LAYOUT)."""


@dataclass(frozen=True)
class Conversion:
    """A COMPU_METHOD as ambdaq applies it: ``kind``; physical = factor * raw + offset where
    ``linear``; ``table`` (raw -> physical, ascending raw) for TAB_INTP, linear between its
    points, its ``default`` outside them or else its end values; ``verbal`` (raw -> text) for
    TAB_VERB, as the value table of a recording's metadata: keys a raw value (COMPU_VTAB), an
    inclusive range ``"LO..HI"`` (COMPU_VTAB_RANGE) or ``"default"`` (DEFAULT_VALUE); ``unit``."""

    kind: str = "IDENTICAL"
    linear: bool = True
    factor: float = 1.0
    offset: float = 0.0
    unit: str = ""
    table: tuple[tuple[float, float], ...] = ()
    verbal: tuple[tuple[str, str], ...] = ()
    default: float | None = None  # TAB_INTP: the value outside the table (DEFAULT_VALUE_NUMERIC), else its ends
    problem: str = ""  # why the file's COMPU_METHOD or its table cannot be read: refused where it is used

    @property
    def computed(self) -> bool:
        """Whether ambdaq turns raw values into physical ones (else they are recorded raw)."""
        return self.linear or self.kind == "TAB_INTP"


@dataclass(frozen=True)
class A2lMeasurement:
    """One measurement.

    Parameters
    ----------
    name : str
        A2L name.
    address : int
        ECU address of its first element.
    extension : int
        Address extension (ECU_ADDRESS_EXTENSION, 0 if none).
    datatype : str
        A2L data type (``UBYTE`` ... ``FLOAT64_IEEE``).
    byte_order : str
        ``<`` (MSB_LAST) or ``>`` (MSB_FIRST); "" where the file's order cannot be read.
    count : int
        Elements (ARRAY_SIZE or the product of MATRIX_DIM), 1 for a scalar.
    bit_mask : int or None
        BIT_MASK: the raw value is ``(raw & mask) >> (trailing zeros of mask)``.
    conversion : Conversion
        Raw to physical.
    unit : str
        Physical unit ("" for counts or a raw value).
    fixed_events, default_events : tuple of int
        The DAQ events its IF_DATA XCP allows (FIXED_EVENT_LIST) or proposes (DEFAULT_EVENT_LIST).
    note : dict of str to str
        The words of its ``ambdaq`` annotation (``topic``, ``type``, ``field``, ``role``).
    line : str
        Where it stands (file and line), for messages.
    """

    name: str
    address: int
    extension: int
    datatype: str
    byte_order: str
    count: int
    bit_mask: int | None
    conversion: Conversion
    unit: str
    fixed_events: tuple[int, ...] = ()
    default_events: tuple[int, ...] = ()
    note: dict[str, str] = field(default_factory=dict)
    line: str = ""

    @property
    def size(self) -> int:
        """Bytes of one element."""
        return TYPES[self.datatype][1] if self.datatype in TYPES else 0

    def problem(self) -> str | None:
        """Why ambdaq cannot record it, or None."""
        if self.conversion.problem:
            return f"its conversion cannot be read: {self.conversion.problem}"
        if self.datatype not in TYPES:
            return f"data type {self.datatype} is not a number ambdaq records"
        if not self.byte_order:
            return "its BYTE_ORDER mixes word and byte orders, which ambdaq does not read"
        if self.count < 1 or self.count > 4096:
            return f"{self.count} elements (1 to 4096 are recorded)"
        if self.bit_mask is not None and (self.bit_mask == 0 or TYPES[self.datatype][0] == "f"):
            return f"BIT_MASK 0x{self.bit_mask:X} on a {self.datatype}"
        return None


@dataclass(frozen=True)
class RecordItem:
    """One item of a CURVE's or MAP's record in ECU memory (ASAM MCD-2 MC, RECORD_LAYOUT), in
    the order of its position: ``kind`` ``NO_AXIS_PTS``, ``AXIS_PTS`` or ``FNC_VALUES`` (or
    ``RESERVED``, bytes skipped), ``axis`` 0 for X and 1 for Y (-1 for the values), ``datatype``,
    ``count`` the most elements it holds (MaxAxisPoints, or their product for the values),
    ``align`` its alignment in bytes (MOD_COMMON's ALIGNMENT_*, or the layout's),
    ``conversion`` an axis's own."""

    kind: str
    axis: int
    datatype: str
    count: int
    align: int
    conversion: "Conversion | None" = None


@dataclass(frozen=True)
class A2lParameter:
    """A numeric characteristic (``VALUE`` or ``VAL_BLK``).

    Parameters
    ----------
    name : str
        A2L name.
    address : int
        ECU address of its first value.
    extension : int
        Address extension.
    datatype : str
        A2L data type of its values (its record layout's FNC_VALUES).
    byte_order : str
        ``<`` or ``>``.
    count : int
        Number of values (1 for a ``VALUE``).
    lower, upper : float
        Its limits (every value), physical.
    conversion : Conversion
        Raw to physical (a write needs it linear).
    read_only : bool
        READ_ONLY: read, never written.
    role : dict of str to str
        The words of its ``ambdaq`` annotation (``role``, ``unit``, ``axes`` ...); empty if none.
    record : tuple of RecordItem
        For a CURVE or MAP whose axis points are stored in its own record (STD_AXIS), the record's
        items in memory order (read only); empty where the values alone are at ``address``.
    static : bool
        The record keeps room for every axis point however many are used (STATIC_RECORD_LAYOUT);
        else it is compact, each item right after the points in use.
    """

    name: str
    address: int
    extension: int
    datatype: str
    byte_order: str
    count: int
    lower: float
    upper: float
    conversion: Conversion
    read_only: bool
    role: dict[str, str]
    record: tuple[RecordItem, ...] = ()
    static: bool = False

    @property
    def size(self) -> int:
        return TYPES[self.datatype][1]


@dataclass(frozen=True)
class A2lSegment:
    """A MEMORY_SEGMENT with its IF_DATA XCP SEGMENT: where it is, its XCP segment number, its
    pages (number -> whether XCP may write them) and its CHECKSUM algorithm ("" if none)."""

    name: str
    address: int
    size: int
    extension: int
    number: int
    pages: dict[int, bool]
    checksum: str

    def holds(self, extension: int, address: int, length: int) -> bool:
        return extension == self.extension and self.address <= address and address + length <= self.address + self.size


@dataclass(frozen=True)
class A2lEvent:
    """An EVENT of the A2L's IF_DATA XCP DAQ block: name, number, cycle in ns (0: sporadic)."""

    name: str
    number: int
    cycle_ns: int


@dataclass(frozen=True)
class A2lDaqList:
    """A static DAQ_LIST of the A2L's IF_DATA XCP DAQ block (ASAM MCD-1 XCP Part 2, the A2ML of
    XCP): its number, type, room, and the event it is fixed to (None: any)."""

    number: int
    daq: bool
    predefined: bool
    max_odt: int
    max_odt_entries: int
    fixed_event: int | None


@dataclass(frozen=True)
class A2lDaq:
    """What the A2L's IF_DATA XCP DAQ block declares of the slave's DAQ processor: what
    GET_DAQ_PROCESSOR_INFO and GET_DAQ_RESOLUTION_INFO would answer, for a slave that lacks them
    (both are optional in ASAM XCP).  Timestamp ``size`` 0: no TIMESTAMP_SUPPORTED."""

    dynamic: bool
    max_daq: int
    max_event: int
    min_daq: int
    address_extension: str  # "free", "odt", "daq"
    identification: int  # 0 absolute, 1 relative byte, 2 relative word, 3 relative word aligned
    granularity: int  # bytes
    max_entry_size: int  # granules
    overload: str  # "none", "pid", "event"
    timestamp_size: int
    timestamp_ns: int
    timestamp_fixed: bool
    lists: tuple[A2lDaqList, ...] = ()


@dataclass(frozen=True)
class A2lFile:
    """An A2L file's project name and what ambdaq reads of it."""

    path: Path
    sha256: str
    project: str
    measurements: dict[str, A2lMeasurement]
    blobs: dict[str, tuple[int, int]]
    parameters: dict[str, A2lParameter]
    events: tuple[A2lEvent, ...] = ()
    segments: tuple[A2lSegment, ...] = ()
    daq: A2lDaq | None = None
    unread: dict[str, str] = field(default_factory=dict)  # characteristics not read: name -> "KIND: why"

    def segment_of(self, param: A2lParameter) -> A2lSegment | None:
        """The calibration segment that holds ``param``, if the A2L describes one."""
        return next((g for g in self.segments if g.holds(param.extension, param.address, param.size * param.count)),
                    None)

    @property
    def constants(self) -> dict[str, A2lParameter]:
        """The FLOAT64 characteristics: the controller's calibration, read at open."""
        return {k: p for k, p in self.parameters.items() if p.datatype == "FLOAT64_IEEE"}

    @property
    def writable(self) -> dict[str, A2lParameter]:
        return {k: p for k, p in self.parameters.items() if not p.read_only and not p.record}


def catalogue(a2l: A2lFile) -> dict:
    """What an A2L file offers, for a listing: measurements, parameters and events, each with its
    type, unit and address (``ambdaq xcp list``)."""
    def where(extension: int, address: int) -> str:
        return f"{extension}:0x{address:X}" if address >= 0 else "-"

    return {
        "file": str(a2l.path), "project": a2l.project,
        "measurements": [{"name": m.name, "type": m.datatype, "count": m.count, "unit": m.unit,
                          "conversion": m.conversion.kind if m.conversion.computed else f"{m.conversion.kind} (raw)",
                          "address": where(m.extension, m.address),
                          "events": list(m.fixed_events or m.default_events), "problem": m.problem() or ""}
                         for m in a2l.measurements.values()],
        "parameters": [{"name": p.name, "type": p.datatype, "count": p.count, "unit": p.conversion.unit,
                        "address": where(p.extension, p.address), "limits": [p.lower, p.upper],
                        "writable": not p.read_only, "problem": ""} for p in a2l.parameters.values()]
        + [{"name": name, "type": why.split(":")[0], "count": 0, "unit": "", "address": "-", "limits": [None, None],
            "writable": False, "problem": f"not read: {why.split(': ', 1)[1]}"} for name, why in a2l.unread.items()],
        "events": [{"number": e.number, "name": e.name, "cycle_ns": e.cycle_ns} for e in a2l.events],
    }


def read_a2l(path: str | Path) -> A2lFile:
    """Read the A2L file ``path`` (and its includes); a file that is not one, or is beyond the
    bounds of :mod:`.a2l_syntax`, is one BadInputError line naming the file and line."""
    path = Path(path)
    root, sha = read_tree(path, KEEP)
    project = next(iter(root.children("PROJECT")), None)
    if project is None:
        raise BadInputError(f"A2L file {path}: no /begin PROJECT (is it an A2L file?)")
    modules = project.children("MODULE")
    nested = next((p for p in project.children("PROJECT") if p.children("MODULE")), None)
    if not modules and nested is not None:  # an /include of a whole A2L file: its PROJECT inside this one
        warnings.warn(f"A2L file {path}: {project.where()}: PROJECT {_word(project, 0, '')} holds no MODULE of its "
                      f"own but includes a whole A2L ({nested.where()}, PROJECT {_word(nested, 0, '')}): its MODULE "
                      "is read", AmbdaqWarning, stacklevel=2)
        modules = nested.children("MODULE")
    if not modules:
        raise BadInputError(f"A2L file {path}: {project.where()}: the PROJECT has no MODULE")
    reader = _ModuleReader(path, modules[0])
    parameters, unread = reader.parameters()
    return A2lFile(path, sha, _word(project, 0, ""), reader.measurements(), reader.blobs(), parameters,
                   reader.events(), reader.segments(), reader.daq(), unread)


def _word(block: Block, index: int, default: str | None = None) -> str:
    if index < len(block.items):
        return block.items[index]
    if default is not None:
        return default
    raise BadInputError(f"A2L file {block.where()}: {block.keyword} has {len(block.items)} values, "
                        f"where at least {index + 1} are due")


def _number(block: Block, token: str, what: str) -> float:
    try:
        value = float(int(token, 0)) if re.fullmatch(r"[+-]?0[xX][0-9a-fA-F]+|[+-]?\d+", token) else float(token)
    except ValueError:
        raise BadInputError(f"A2L file {block.where()}: {block.keyword} {_word(block, 0, '')}: {what} {token!r} "
                            "is not a number") from None
    if not math.isfinite(value):
        raise BadInputError(f"A2L file {block.where()}: {block.keyword} {_word(block, 0, '')}: {what} is {token}")
    return value


def _integer(block: Block, token: str, what: str) -> int:
    value = _number(block, token, what)
    if value != int(value):
        raise BadInputError(f"A2L file {block.where()}: {block.keyword} {_word(block, 0, '')}: {what} {token!r} "
                            "is not an integer")
    return int(value)


ARITY = {"ECU_ADDRESS": 1, "ECU_ADDRESS_EXTENSION": 1, "BYTE_ORDER": 1, "BIT_MASK": 1, "ARRAY_SIZE": 1,
         "MATRIX_DIM": 3, "PHYS_UNIT": 1, "NUMBER": 1, "COEFFS": 6, "COEFFS_LINEAR": 2, "COMPU_TAB_REF": 1,
         "FNC_VALUES": 4, "AXIS_PTS_X": 4, "READ_ONLY": 0, "ANNOTATION_LABEL": 1, "DEFAULT_VALUE_NUMERIC": 1,
         "DEFAULT_VALUE": 1}
"""The optional keywords ambdaq reads and how many words follow each (MATRIX_DIM: up to 3 numbers)."""


def _options(block: Block, start: int) -> dict[str, list[str]]:
    """The optional keywords of :data:`ARITY` in a block's body from ``start`` on, with their words."""
    out: dict[str, list[str]] = {}
    items = block.items
    i = start
    while i < len(items):
        token = items[i]
        n = ARITY.get(token) if not isinstance(token, Text) else None
        if n is None:
            i += 1
            continue
        words = items[i + 1 : i + 1 + n]
        if token == "MATRIX_DIM":  # 1.70 takes one to three dimensions
            k = 0
            while k < len(words) and re.fullmatch(r"\d+", words[k]):
                k += 1
            words = words[:k]
        out[token] = words
        i += 1 + len(words)
    return out


def ambdaq_note(block: Block) -> dict[str, str]:
    """The ``word=value`` pairs of a block's ANNOTATION labelled ``ambdaq`` (empty if none)."""
    for note in block.children("ANNOTATION"):
        label = _options(note, 0).get("ANNOTATION_LABEL", [])
        text = note.child("ANNOTATION_TEXT")
        if label == ["ambdaq"] and text is not None:
            return dict(p.split("=", 1) for p in " ".join(text.items).split() if "=" in p)
    return {}


class _ModuleReader:
    def __init__(self, path: Path, module: Block) -> None:
        self.path, self.module = path, module
        common = module.child("MOD_COMMON")
        order = _options(common, 1).get("BYTE_ORDER", ["MSB_LAST"]) if common is not None else ["MSB_LAST"]
        self.byte_order = BYTE_ORDERS.get(order[0] if order else "MSB_LAST", "")
        self.alignment = self._alignment(common, dict(DEFAULT_ALIGNMENT))
        self.methods = {_word(b, 0): b for b in module.children("COMPU_METHOD")}
        self.tables = {_word(b, 0): b for kind in ("COMPU_TAB", "COMPU_VTAB", "COMPU_VTAB_RANGE")
                       for b in module.children(kind)}
        self.layouts: dict[str, tuple[str, bool]] = {}  # name -> FNC_VALUES type, whether it holds only them
        self.axis_layouts: dict[str, str] = {}  # name -> AXIS_PTS_X type, for a record of axis points alone
        self.records: dict[str, Block] = {}  # name -> the RECORD_LAYOUT, for a record with its own axes
        for layout in module.children("RECORD_LAYOUT"):
            self.records[_word(layout, 0)] = layout
            items = {str(t) for t in layout.items if not isinstance(t, Text) and RECORD_ITEM.fullmatch(str(t))}
            options = _options(layout, 1)
            values, points = options.get("FNC_VALUES", []), options.get("AXIS_PTS_X", [])
            self.layouts[_word(layout, 0)] = (values[1] if len(values) > 1 else "", items == {"FNC_VALUES"})
            if items == {"AXIS_PTS_X"} and len(points) > 1:
                self.axis_layouts[_word(layout, 0)] = points[1]
        self._conversions: dict[str, Conversion] = {}

    @staticmethod
    def _alignment(block: Block | None, base: dict[str, int]) -> dict[str, int]:
        """Alignment in bytes per A2L data type: ``base`` with the block's ALIGNMENT_* keywords."""
        if block is None:
            return base
        items = block.items
        for i, token in enumerate(items[:-1]):
            kind = ALIGNMENT_KEYWORDS.get(str(token)) if not isinstance(token, Text) else None
            if kind is not None:
                for datatype in kind:
                    base[datatype] = max(_integer(block, items[i + 1], str(token)), 1)
        return base

    def _record(self, layout_name: str, axes: list[tuple[int, str]], values: bool
                ) -> tuple[tuple[RecordItem, ...], bool] | None:
        """A record that holds its own axis points, in memory order, and whether it is static:
        a CURVE's or MAP's (``values``: FNC_VALUES too) or an AXIS_PTS's with its count. ``axes``:
        each axis's MaxAxisPoints and conversion. None where the record holds anything else
        (addresses, offsets, shifts: not read)."""
        layout = self.records.get(layout_name)
        if layout is None or not axes or len(axes) > 2:
            return None
        align = self._alignment(layout, dict(self.alignment))
        maxima = [max(n, 1) for n, _c in axes]
        items, i, tokens = [], 0, layout.items
        for k, token in enumerate(tokens[:-1]):  # FIX_NO_AXIS_PTS_X n: that many points, always
            fixed = re.fullmatch(r"FIX_NO_AXIS_PTS_([XY])", str(token)) if not isinstance(token, Text) else None
            if fixed and "XY".index(fixed.group(1)) < len(maxima):
                maxima["XY".index(fixed.group(1))] = max(_integer(layout, tokens[k + 1], str(token)), 1)
        while i < len(tokens):
            token = str(tokens[i]) if not isinstance(tokens[i], Text) else ""
            m = RECORD_AXIS_ITEM.fullmatch(token)
            if token in ("FNC_VALUES", "RESERVED", "IDENTIFICATION") or m:
                if i + 2 >= len(tokens):
                    return None
                position, datatype = _integer(layout, tokens[i + 1], token + " position"), str(tokens[i + 2])
                if token == "RESERVED":  # RESERVED position BYTE|WORD|LONG: bytes skipped
                    datatype = {"BYTE": "UBYTE", "WORD": "UWORD", "LONG": "ULONG"}.get(datatype, "")
                if datatype not in TYPES:
                    return None
                if m:
                    axis = "XY".index(m.group(2)) if m.group(2) in "XY" else 2
                    if axis >= len(axes):
                        return None
                    kind = m.group(1)
                    count = 1 if kind == "NO_AXIS_PTS" else maxima[axis]
                    conversion = self.conversion(axes[axis][1])
                    items.append((position, RecordItem(kind, axis, datatype, count, align[datatype], conversion)))
                elif token == "FNC_VALUES":
                    items.append((position, RecordItem("FNC_VALUES", -1, datatype, math.prod(maxima), align[datatype])))
                else:  # RESERVED and IDENTIFICATION: bytes in the record that are not read
                    items.append((position, RecordItem("RESERVED", -1, datatype, 1, align[datatype])))
                i += 3
                continue
            if RECORD_ITEM.fullmatch(token):
                return None  # addresses, offsets, shifts, rescaling: a record ambdaq does not read
            i += 1
        kinds = {(r.kind, r.axis) for _p, r in items}
        if (("FNC_VALUES", -1) in kinds) != values or any(("AXIS_PTS", a) not in kinds for a in range(len(axes))):
            return None
        static = any(str(t) == "STATIC_RECORD_LAYOUT" for t in tokens if not isinstance(t, Text))
        return tuple(r for _p, r in sorted(items, key=lambda pr: pr[0])), static

    def _order(self, options: dict[str, list[str]]) -> str:
        given = options.get("BYTE_ORDER")
        return BYTE_ORDERS.get(given[0], "") if given else self.byte_order

    def conversion(self, name: str) -> Conversion:
        """The COMPU_METHOD ``name`` as ambdaq applies it (NO_COMPU_METHOD: identity)."""
        if name in self._conversions:
            return self._conversions[name]
        method = self.methods.get(name)
        try:
            found = Conversion() if method is None else self._method(method)
        except BadInputError as err:  # refused where a selected object uses it, never for the whole file
            found = Conversion(_word(method, 2, "?"), False, problem=str(err))
        self._conversions[name] = found
        return found

    def _method(self, b: Block) -> Conversion:
        kind, unit = _word(b, 2, "IDENTICAL"), _word(b, 4, "")
        options = _options(b, 5)
        if kind == "LINEAR":
            a, c = (options.get("COEFFS_LINEAR") or ["1", "0"])[:2]
            return Conversion(kind, True, _number(b, a, "COEFFS_LINEAR a"), _number(b, c, "COEFFS_LINEAR b"), unit)
        if kind == "RAT_FUNC":
            # raw = (a p^2 + b p + c) / (d p^2 + e p + f) (ASAM MCD-2 MC, COMPU_METHOD); linear when
            # a = d = e = 0: p = (f raw - c) / b
            coeffs = options.get("COEFFS", [])
            if len(coeffs) == 6:
                a, bb, c, d, e, f = (_number(b, x, "COEFFS") for x in coeffs)
                if a == d == e == 0 and bb != 0:
                    return Conversion(kind, True, f / bb, -c / bb, unit)
            return Conversion(kind, False, unit="")
        if kind in ("TAB_INTP", "TAB_VERB", "TAB_NOINTP"):
            ref = (options.get("COMPU_TAB_REF") or [""])[0]
            table = self.tables.get(ref)
            if table is None:
                return Conversion(kind, False)
            if kind == "TAB_VERB":
                return Conversion(kind, False, verbal=self._verbal(table))
            n = _integer(table, _word(table, 3, "0"), "number of pairs")
            pairs = table.items[4 : 4 + 2 * n]
            if len(pairs) < 2 * n:
                raise BadInputError(f"A2L file {table.where()}: COMPU_TAB {ref}: fewer pairs than its count, {n}")
            if kind == "TAB_NOINTP" or _word(table, 2, "") != "TAB_INTP":
                return Conversion("TAB_NOINTP", False)  # the table's own type says it does not interpolate
            points = sorted((_number(table, pairs[i], "value"), _number(table, pairs[i + 1], "value"))
                            for i in range(0, len(pairs) - 1, 2))
            default = _options(table, 4 + 2 * n).get("DEFAULT_VALUE_NUMERIC")
            return Conversion(kind, False, unit=unit, table=tuple(points),
                              default=_number(table, default[0], "DEFAULT_VALUE_NUMERIC") if default else None)
        if kind == "IDENTICAL":
            return Conversion(kind, True, unit=unit)
        return Conversion(kind, False)  # FORM and what else a vendor writes: recorded raw, named

    @staticmethod
    def _verbal(table: Block) -> tuple[tuple[str, str], ...]:
        """A COMPU_VTAB (name, long name, TAB_VERB, n, n pairs value "text") or COMPU_VTAB_RANGE
        (name, long name, n, n triples min max "text"), either with an optional DEFAULT_VALUE
        (ASAM MCD-2 MC 1.7): its entries as value-table keys and texts."""
        ranges = table.keyword == "COMPU_VTAB_RANGE"
        at, width = (3, 3) if ranges else (4, 2)
        n = _integer(table, _word(table, at - 1, "0"), "number of entries")
        items = table.items[at : at + width * n]
        if len(items) < width * n or any(isinstance(t, Text) for k, t in enumerate(items) if k % width != width - 1):
            raise BadInputError(f"A2L file {table.where()}: {table.keyword} {_word(table, 0, '')}: fewer entries "
                                f"than its count, {n}")
        out = []
        for i in range(0, len(items) - width + 1, width):
            values = [_number(table, v, "value") for v in items[i : i + width - 1]]
            # written exactly (":g" would make 100000000 "1e+08", another key than the raw value's)
            key = "..".join(str(int(v)) if float(v).is_integer() else repr(float(v)) for v in values)
            out.append((key, str(items[i + width - 1])))
        default = _options(table, at + width * n).get("DEFAULT_VALUE")
        return tuple(out) + ((("default", default[0]),) if default else ())

    def _measurement(self, b: Block, name: str, where: tuple[int, int] | None, events: Block) -> A2lMeasurement:
        """A MEASUREMENT, or a TYPEDEF_MEASUREMENT placed by an INSTANCE at ``where`` (extension,
        address): both begin name, long name, type, conversion, resolution, accuracy, limits."""
        datatype, method = _word(b, 2, ""), _word(b, 3, "NO_COMPU_METHOD")
        options = _options(b, 8)
        if where is None:
            address = _integer(b, options["ECU_ADDRESS"][0], "ECU_ADDRESS") if options.get("ECU_ADDRESS") else -1
            ext = _integer(b, (options.get("ECU_ADDRESS_EXTENSION") or ["0"])[0], "ECU_ADDRESS_EXTENSION")
        else:
            ext, address = where
        count = 1
        for key in ("ARRAY_SIZE", "MATRIX_DIM"):
            for token in options.get(key, [])[:3]:
                count *= max(_integer(b, token, key), 1)
        mask = _integer(b, options["BIT_MASK"][0], "BIT_MASK") if options.get("BIT_MASK") else None
        conversion = self.conversion(method)
        unit = (options.get("PHYS_UNIT") or [conversion.unit])[0] if conversion.computed else ""
        fixed, default = _daq_events(events)
        return A2lMeasurement(name, address, ext, datatype, self._order(options), count, mask, conversion, unit,
                              fixed, default, ambdaq_note(events), events.where())

    def _instances(self):
        """Each leaf of every INSTANCE (ASAM MCD-2 MC 1.7 typedefs): (name, the TYPEDEF_MEASUREMENT or
        TYPEDEF_CHARACTERISTIC block, extension, address, the INSTANCE block), structures unfolded
        (``instance.component``), at most 8 deep."""
        typedefs = {_word(t, 0): t for kind in ("TYPEDEF_STRUCTURE", "TYPEDEF_MEASUREMENT", "TYPEDEF_CHARACTERISTIC")
                    for t in self.module.children(kind)}

        def unfold(name: str, type_name: str, address: int, depth: int):
            t = typedefs.get(type_name)
            if t is None or depth > 8:
                return
            if t.keyword != "TYPEDEF_STRUCTURE":
                yield name, t, address
                return
            for c in t.children("STRUCTURE_COMPONENT"):  # component name, type, offset
                if len(c.items) >= 3:
                    yield from unfold(f"{name}.{c.items[0]}", c.items[1], address + _integer(c, c.items[2], "offset"),
                                      depth + 1)

        for inst in self.module.children("INSTANCE"):  # INSTANCE name "long" typedef address [options]
            options = _options(inst, 4)
            ext = _integer(inst, (options.get("ECU_ADDRESS_EXTENSION") or ["0"])[0], "ECU_ADDRESS_EXTENSION")
            for name, t, address in unfold(_word(inst, 0), _word(inst, 2), _integer(inst, _word(inst, 3), "address"), 0):
                yield name, t, ext, address, inst

    def measurements(self) -> dict[str, A2lMeasurement]:
        out = {}
        for b in self.module.children("MEASUREMENT"):
            out[_word(b, 0)] = self._measurement(b, _word(b, 0), None, b)
        for name, t, ext, address, inst in self._instances():
            if t.keyword == "TYPEDEF_MEASUREMENT":
                out[name] = self._measurement(t, name, (ext, address), inst)
        return out

    def _characteristics(self):
        """(name, block, address, extension, options, count, kind, record layout, conversion, lower,
        upper) of every CHARACTERISTIC and every TYPEDEF_CHARACTERISTIC an INSTANCE places."""
        def row(b: Block, name: str, address: int, ext: int | None, at: int):
            # CHARACTERISTIC: name "long" type address layout maxdiff conversion lower upper;
            # TYPEDEF_CHARACTERISTIC: the same without the address (``at`` says where the layout is)
            options = _options(b, at + 5)
            count = 1
            for key in ("NUMBER", "MATRIX_DIM"):
                for token in options.get(key, [])[:3]:
                    count *= max(_integer(b, token, key), 1)
            if ext is None:
                ext = _integer(b, (options.get("ECU_ADDRESS_EXTENSION") or ["0"])[0], "ECU_ADDRESS_EXTENSION")
            return (name, b, address, ext, options, count, _word(b, 2), _word(b, at), _word(b, at + 2),
                    _word(b, at + 3), _word(b, at + 4))

        for b in self.module.children("CHARACTERISTIC"):
            yield row(b, _word(b, 0), _integer(b, _word(b, 3), "address"), None, 4)
        for name, t, ext, address, _inst in self._instances():
            if t.keyword == "TYPEDEF_CHARACTERISTIC":
                yield row(t, name, address, ext, 3)

    def blobs(self) -> dict[str, tuple[int, int]]:
        return {name: (address, count) for name, _b, address, _e, _o, count, *_rest in self._characteristics()}

    def parameters(self) -> tuple[dict[str, A2lParameter], dict[str, str]]:
        """The characteristics and axis points ambdaq reads and writes, and every other one with
        the reason it is not read (``name -> "KIND: why"``): none is left out in silence."""
        out, unread = {}, {}
        for name, b, address, ext, options, count, kind, layout, method, lower, upper in self._characteristics():
            datatype, only_values = self.layouts.get(layout, ("", False))
            axes = b.children("AXIS_DESCR")  # STD_AXIS: Attribute InputQuantity Conversion MaxAxisPoints ...
            record = self._record(layout, [(_integer(a, _word(a, 3), "MaxAxisPoints"), _word(a, 2, "NO_COMPU_METHOD"))
                                           for a in axes], True) \
                if kind in ("CURVE", "MAP") and not only_values and all(_word(a, 0, "") == "STD_AXIS" for a in axes) \
                else None
            if record is not None:  # axis points in its own record (STD_AXIS): read, never written
                order = self._order(options)
                values = next(r for r in record[0] if r.kind == "FNC_VALUES")
                if order:
                    out[name] = A2lParameter(name, address, ext, values.datatype, order, values.count,
                                             _number(b, lower, "lower limit"), _number(b, upper, "upper limit"),
                                             self.conversion(method), True, ambdaq_note(b), *record)
                else:
                    unread[name] = f"{kind}: its byte order is not one ambdaq reads"
                continue
            dims = {"CURVE": 1, "MAP": 2, "CUBOID": 3, "CUBE_4": 4, "CUBE_5": 5}.get(kind)
            axes = b.children("AXIS_DESCR")
            if dims is not None and only_values and len(axes) == dims:
                # its axes are not in its record (FIX_AXIS, COM_AXIS ...): MaxAxisPoints of each axis values
                count = 1
                for axis in axes:  # Attribute InputQuantity Conversion MaxAxisPoints ...
                    count *= max(_integer(axis, _word(axis, 3), "MaxAxisPoints"), 1)
            elif dims is not None:
                unread[name] = (f"{kind}: {len(axes)} AXIS_DESCR of its {dims}, its size is not known" if len(axes) != dims
                                else f"{kind}: its axis points are in a record layout ambdaq does not read ({layout})")
                continue
            elif kind not in ("VALUE", "VAL_BLK"):
                unread[name] = f"{kind}: not a number ambdaq reads or writes" + (" (text)" if kind == "ASCII" else "")
                continue
            order = self._order(options)
            if datatype not in TYPES or not order:
                unread[name] = (f"{kind}: record layout {layout} is not one value of a plain type"
                                if datatype not in TYPES else f"{kind}: its byte order is not one ambdaq reads")
                continue
            out[name] = A2lParameter(name, address, ext, datatype, order, count, _number(b, lower, "lower limit"),
                                     _number(b, upper, "upper limit"), self.conversion(method), "READ_ONLY" in options,
                                     ambdaq_note(b))
        for b in self.module.children("AXIS_PTS"):
            # AXIS_PTS name "long" address InputQuantity layout MaxDiff conversion MaxAxisPoints lower upper
            datatype = self.axis_layouts.get(_word(b, 4, ""), "")
            options = _options(b, 10)
            if not self._order(options) or len(b.items) < 10:
                unread[_word(b, 0)] = ("AXIS_PTS: its byte order is not one ambdaq reads" if len(b.items) >= 10
                                       else f"AXIS_PTS: {len(b.items)} of its 10 values")
                continue
            record: tuple = ()
            if datatype not in TYPES:  # its count in the record beside the points: read, never written
                found = self._record(_word(b, 4), [(_integer(b, _word(b, 7), "MaxAxisPoints"), _word(b, 6))], False)
                if found is None:
                    unread[_word(b, 0)] = f"AXIS_PTS: record layout {_word(b, 4)} is not one ambdaq reads"
                    continue
                record = found
                datatype = next(r.datatype for r in found[0] if r.kind == "AXIS_PTS")
            ext = _integer(b, (options.get("ECU_ADDRESS_EXTENSION") or ["0"])[0], "ECU_ADDRESS_EXTENSION")
            out[_word(b, 0)] = A2lParameter(_word(b, 0), _integer(b, _word(b, 2), "address"), ext, datatype,
                                            self._order(options), _integer(b, _word(b, 7), "MaxAxisPoints"),
                                            _number(b, _word(b, 8), "lower limit"), _number(b, _word(b, 9), "upper limit"),
                                            self.conversion(_word(b, 6)), "READ_ONLY" in options or bool(record),
                                            ambdaq_note(b), *record)
        return out, unread

    def segments(self) -> tuple[A2lSegment, ...]:
        """The calibration segments; one the file describes badly is left out (it is needed only to
        choose a page, which is then refused for want of it)."""
        out = []
        for par in self.module.children("MOD_PAR"):
            for seg in par.children("MEMORY_SEGMENT"):
                # MEMORY_SEGMENT name "long" PrgType MemoryType Attribute Address Size offset x5
                for data in seg.children("IF_DATA"):
                    for xcp in data.children("SEGMENT") if data.items[:1] == ["XCP"] else ():
                        # SEGMENT index pages address_extension compression encryption
                        try:
                            pages = {}
                            for page in xcp.children("PAGE"):  # PAGE index ecu_access xcp_read xcp_write
                                pages[_integer(page, _word(page, 0), "page")] = \
                                    _word(page, 3) != "XCP_WRITE_ACCESS_NOT_ALLOWED"
                            check = xcp.child("CHECKSUM")
                            out.append(A2lSegment(_word(seg, 0), _integer(seg, _word(seg, 5), "address"),
                                                  _integer(seg, _word(seg, 6), "size"),
                                                  _integer(xcp, _word(xcp, 2), "address extension"),
                                                  _integer(xcp, _word(xcp, 0), "segment"), pages,
                                                  _word(check, 0, "") if check is not None else ""))
                        except BadInputError:
                            continue
        return tuple(out)

    def daq(self) -> A2lDaq | None:
        """The module's IF_DATA XCP DAQ block (:class:`A2lDaq`), where it has one that reads."""
        for data in self.module.children("IF_DATA"):
            if data.items[:1] == ["XCP"]:
                try:
                    found = _daq(data)
                except BadInputError:
                    continue
                if found is not None:
                    return found
        return None

    def events(self) -> tuple[A2lEvent, ...]:
        out = []
        for data in self.module.children("IF_DATA"):
            if data.items[:1] != ["XCP"]:
                continue
            for daq in data.children("DAQ"):
                for e in daq.children("EVENT"):
                    # EVENT "name" "short name" number DAQ|STIM|DAQ_STIM max_lists cycle unit priority
                    if len(e.items) >= 7:
                        cycle, unit = _integer(e, e.items[5], "cycle"), _integer(e, e.items[6], "time unit")
                        out.append(A2lEvent(str(e.items[0]), _integer(e, e.items[2], "event number"),
                                            cycle * 10 ** unit if 0 <= unit <= 9 else 0))
        return tuple(out)


_IDENTIFICATION = {"IDENTIFICATION_FIELD_TYPE_ABSOLUTE": 0, "IDENTIFICATION_FIELD_TYPE_RELATIVE_BYTE": 1,
                   "IDENTIFICATION_FIELD_TYPE_RELATIVE_WORD": 2, "IDENTIFICATION_FIELD_TYPE_RELATIVE_WORD_ALIGNED": 3}
_GRANULARITY = {"GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE": 1, "GRANULARITY_ODT_ENTRY_SIZE_DAQ_WORD": 2,
                "GRANULARITY_ODT_ENTRY_SIZE_DAQ_DWORD": 4, "GRANULARITY_ODT_ENTRY_SIZE_DAQ_DLONG": 8}
_TIMESTAMP_SIZE = {"NO_TIME_STAMP": 0, "SIZE_BYTE": 1, "SIZE_WORD": 2, "SIZE_DWORD": 4}
_TIME_UNIT = {f"UNIT_{n}{u}": 10 ** (k + 3 * j) for j, u in enumerate(("NS", "US", "MS")) for k, n in
              enumerate(("1", "10", "100"))} | {"UNIT_1S": 10**9}
"""XCP's DAQ_TIMESTAMP_UNIT_* as the A2ML of XCP spells them, in ns."""


def _daq(data: Block) -> A2lDaq | None:
    """The IF_DATA XCP DAQ block's declaration (:class:`A2lDaq`), or None where it has none."""
    daq = data.child("DAQ")
    if daq is None or len(daq.items) < 9:
        return None
    words = daq.items
    (count, events, minimum), entry = (_integer(daq, w, "DAQ count") for w in words[1:4]), 0xFF
    flags = set(words[4:])
    for w in words[7:]:
        if re.fullmatch(r"0[xX][0-9a-fA-F]+|\d+", w):
            entry = _integer(daq, w, "MAX_ODT_ENTRY_SIZE_DAQ")
            break
    stamp = daq.child("TIMESTAMP_SUPPORTED")
    size, tick_ns, fixed = 0, 1, False
    if stamp is not None and stamp.items:
        ticks = _integer(stamp, stamp.items[0], "timestamp ticks")
        size = next((v for k, v in _TIMESTAMP_SIZE.items() if k in stamp.items), 0)
        tick_ns = ticks * next((v for k, v in _TIME_UNIT.items() if k in stamp.items), 1)
        fixed = "TIMESTAMP_FIXED" in stamp.items
    lists = []
    for b in daq.children("DAQ_LIST"):
        kv = {b.items[i]: b.items[i + 1] for i in range(1, len(b.items) - 1)}
        lists.append(A2lDaqList(_integer(b, b.items[0], "DAQ list number"), kv.get("DAQ_LIST_TYPE", "DAQ") != "STIM",
                                "PREDEFINED" in b.items, _integer(b, kv.get("MAX_ODT", "0"), "MAX_ODT"),
                                _integer(b, kv.get("MAX_ODT_ENTRIES", "0"), "MAX_ODT_ENTRIES"),
                                _integer(b, kv["EVENT_FIXED"], "EVENT_FIXED") if "EVENT_FIXED" in kv else None))
    return A2lDaq(
        dynamic=words[0] == "DYNAMIC", max_daq=count, max_event=events, min_daq=minimum,
        address_extension="odt" if "ADDRESS_EXTENSION_ODT" in flags else "daq" if "ADDRESS_EXTENSION_DAQ" in flags
        else "free",
        identification=next((v for k, v in _IDENTIFICATION.items() if k in flags), 0),
        granularity=next((v for k, v in _GRANULARITY.items() if k in flags), 1), max_entry_size=entry,
        overload="pid" if "OVERLOAD_INDICATION_PID" in flags else "event" if "OVERLOAD_INDICATION_EVENT" in flags
        else "none",
        timestamp_size=size, timestamp_ns=tick_ns, timestamp_fixed=fixed, lists=tuple(lists))


def _daq_events(b: Block) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """A measurement's IF_DATA XCP DAQ_EVENT lists: (fixed, default) event numbers."""
    fixed: list[int] = []
    default: list[int] = []
    for data in b.children("IF_DATA"):
        if data.items[:1] != ["XCP"]:
            continue
        for lists in data.children("DAQ_EVENT"):
            target = None
            for token in lists.items:
                if token in ("FIXED_EVENT_LIST", "DEFAULT_EVENT_LIST", "VARIABLE"):
                    target = {"FIXED_EVENT_LIST": fixed, "DEFAULT_EVENT_LIST": default}.get(token)
                elif token != "EVENT" and target is not None:
                    target.append(_integer(lists, token, "event number"))
            for sub in lists.blocks:  # the 1.7 form: /begin FIXED_EVENT_LIST EVENT n ... /end
                target = {"FIXED_EVENT_LIST": fixed, "DEFAULT_EVENT_LIST": default}.get(sub.keyword)
                if target is not None:
                    target.extend(_integer(sub, t, "event number") for t in sub.items if t != "EVENT")
    return tuple(fixed), tuple(default)
