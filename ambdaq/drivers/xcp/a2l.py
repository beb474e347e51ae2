"""What ambdaq needs of an A2L file (ASAM MCD-2 MC), read by pya2ldb, not by hand.

Measurements: name, address, data type and the linear conversion to physical units, and where
ambdaq records each one (docs/hardware.md, "XCP"):

- an ``ANNOTATION`` labelled ``ambdaq`` with the text ``topic=/amb/gap type=Gap field=front_x``
  (what ``ambdaq sim a2l`` writes);
- else a dotted name ``a.b.c``: field ``c`` of topic ``/a/b``;
- else field NAME of topic ``/xcp``.

Blobs: the ``CHARACTERISTIC``s a controller that takes ``ambdaq push`` over XCP describes
(``coefficient_bank``, ``push_record``, ``bank_status``), by address and size.

What is read is cached by the file's SHA-256 (``$XDG_CACHE_HOME/ambdaq/a2l``, else
``~/.cache/ambdaq/a2l``): pya2ldb takes seconds to import and parse, and an A2L rarely changes.

Constants: the ``CHARACTERISTIC``s of FLOAT64_IEEE values (a ``VALUE`` or a ``VAL_BLK``): the
controller's calibration that is numbers (sensor gain, the rotor model ``rotor.*`` that
``runout identify`` needs, its gains), read from the device when it is opened.

Parameters: those of them that are not ``READ_ONLY``, with their limits; ``controller param``
reads and writes them.  An
``ANNOTATION`` labelled ``ambdaq`` says what ambdaq may use one for: ``role=speed`` (a speed
set-point in rpm that reads the present speed: ``--rpm``) or ``role=test-signal axes=A,B,...
unit=m|V min_amplitude=X max_amplitude=Y`` (the test-signal input of ``frf measure`` and ``iso
stability``: [axis index or -1, amplitude, frequency Hz]).
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import logging
import os
import re
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from ...errors import BadInputError

DATATYPES = {"UBYTE": "U8", "SBYTE": "I8", "UWORD": "U16", "SWORD": "I16", "ULONG": "U32", "SLONG": "I32",
             "A_UINT64": "U64", "A_INT64": "I64", "FLOAT32_IEEE": "F32", "FLOAT64_IEEE": "F64"}
"""A2L data type -> pyxcp's DAQ element type."""
SIZES = {"U8": 1, "I8": 1, "U16": 2, "I16": 2, "U32": 4, "I32": 4, "U64": 8, "I64": 8, "F32": 4, "F64": 8}
"""pyxcp's DAQ element type -> its size in bytes."""
DEFAULT_TOPIC = "/xcp"
CACHE_VERSION = 3  # 3: the parameters (2, at df99feb only, left writable FLOAT64s out of the constants)


@dataclass(frozen=True)
class A2lMeasurement:
    """One measurement: physical value = ``factor`` * raw + ``offset``, in ``unit``.

    Parameters
    ----------
    name : str
        A2L name.
    address : int
        ECU address.
    datatype : str
        pyxcp element type (``U32``, ``F32`` ...).
    unit : str
        Physical unit ("" for counts).
    factor, offset : float
        The linear conversion (A2L ``COMPU_METHOD``).
    topic, type_name, field : str
        Where it is recorded: MCAP topic, message type, field.
    """

    name: str
    address: int
    datatype: str
    unit: str
    factor: float
    offset: float
    topic: str
    type_name: str
    field: str


@dataclass(frozen=True)
class A2lParameter:
    """A writable FLOAT64 characteristic.

    Parameters
    ----------
    name : str
        A2L name.
    address : int
        ECU address of its first value.
    count : int
        Number of values (1 for a ``VALUE``).
    lower, upper : float
        Its limits (every value), in its unit.
    role : dict of str to str
        The words of its ``ambdaq`` annotation (``role``, ``unit``, ``axes`` ...); empty if none.
    """

    name: str
    address: int
    count: int
    lower: float
    upper: float
    role: dict[str, str]


@dataclass(frozen=True)
class A2lFile:
    """An A2L file's project name, measurements by name; blobs and FLOAT64 constants by name
    (address, size in bytes / number of values); writable FLOAT64 parameters by name."""

    path: Path
    sha256: str
    project: str
    measurements: dict[str, A2lMeasurement]
    blobs: dict[str, tuple[int, int]]
    constants: dict[str, tuple[int, int]]
    parameters: dict[str, A2lParameter]


def read_a2l(path: str | Path) -> A2lFile:
    """Read ``path`` (from the cache when its SHA-256 was read before); a file pya2ldb cannot read,
    or with no measurement, is a BadInputError."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise BadInputError(f"A2L file {path}: {err.strerror or err}") from None
    sha = hashlib.sha256(data).hexdigest()
    cached = _cached(path, sha)
    if cached is not None:
        return cached
    found = _parse(path, sha)
    _cache(found)
    return found


def _cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ambdaq" / "a2l"


def _cached(path: Path, sha: str) -> A2lFile | None:
    try:
        d = json.loads((_cache_dir() / f"{sha}.json").read_text())
        if d.pop("version") != CACHE_VERSION:
            return None
        return A2lFile(path, sha, d["project"], {k: A2lMeasurement(**m) for k, m in d["measurements"].items()},
                       {k: tuple(v) for k, v in d["blobs"].items()}, {k: tuple(v) for k, v in d["constants"].items()},
                       {k: A2lParameter(**v) for k, v in d["parameters"].items()})
    except (OSError, ValueError, KeyError, TypeError):
        return None  # none, or one this version cannot read: parse again


def _cache(found: A2lFile) -> None:
    folder = _cache_dir()
    body = {"version": CACHE_VERSION, "project": found.project, "blobs": found.blobs, "constants": found.constants,
            "measurements": {k: asdict(m) for k, m in found.measurements.items()},
            "parameters": {k: asdict(v) for k, v in found.parameters.items()}}
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{found.sha256}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(body))
        tmp.replace(folder / f"{found.sha256}.json")
    except OSError:
        pass  # a cache that cannot be written costs only time


def _parse(path: Path, sha: str) -> A2lFile:
    try:
        from pya2l import import_a2l, model
    except ImportError:
        raise BadInputError("A2L files need the xcp extra: pip install 'ambdaq[xcp]'") from None
    logging.disable(logging.WARNING)  # pya2ldb logs its progress at INFO (to stdout, through rich)
    try:
        session, complaints = _with_output(lambda: import_a2l(str(path), in_memory=True, loglevel="ERROR",
                                                               progress_bar=False))
        _refuse_errors(path, complaints)
        project = session.query(model.Project).first()
        methods = {m.name: m for m in session.query(model.CompuMethod)}
        measurements = {}
        for m in session.query(model.Measurement):
            measurements[m.name] = _measurement(m, methods, path)
        layouts = {r.name: r.fnc_values.datatype if r.fnc_values else "" for r in session.query(model.RecordLayout)}
        blobs, constants, parameters = {}, {}, {}
        for c in session.query(model.Characteristic):
            count = int(c.number.number) if c.number is not None else 1
            blobs[c.name] = (int(c.address), count)
            if c.type in ("VALUE", "VAL_BLK") and layouts.get(c.deposit) == "FLOAT64_IEEE":
                constants[c.name] = (int(c.address), count)
                if not c.read_only:
                    parameters[c.name] = A2lParameter(c.name, int(c.address), count, float(c.lowerLimit),
                                                      float(c.upperLimit), _ambdaq_note(c))
    except BadInputError:
        raise
    except Exception as err:  # the parser's own errors, whatever their class
        raise BadInputError(f"A2L file {path}: cannot be read ({type(err).__name__}: {err})") from None
    finally:
        logging.disable(logging.NOTSET)
    if not measurements:
        raise BadInputError(f"A2L file {path}: no MEASUREMENT (is it an A2L file?)")
    return A2lFile(path, sha, project.name if project else "", measurements, blobs, constants, parameters)


def _with_output(call):
    """``call()`` and what it wrote to file descriptors 1 and 2: pya2ldb's parser (C++) reports
    syntax errors on its standard output, with their line, and goes on."""
    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryFile() as sink:
        saved = [os.dup(1), os.dup(2)]
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            result = call()
        finally:
            ctypes.CDLL(None).fflush(None)  # the C library's buffers, before the descriptors are given back
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
        sink.seek(0)
        return result, sink.read().decode("utf-8", "replace")


def _refuse_errors(path: Path, complaints: str) -> None:
    """The parser's first error, as one line naming the file and the line."""
    for line in complaints.splitlines():
        if "[error]" in line:
            what = line.split("[error]", 1)[1].strip()
            at = re.search(r",(\d+):(\d+)\]", what)
            where = f"line {at.group(1)}: " if at else ""
            token = re.search(r"\[@\d+='(.*?)',", what)
            message = re.sub(r" *:? *\[@.*", "", what) + (f" {token.group(1)!r}" if token else "")
            raise BadInputError(f"A2L file {path}: {where}{message}")


def _measurement(m, methods: dict, path: Path) -> A2lMeasurement:
    datatype = DATATYPES.get(m.datatype)
    if datatype is None:
        raise BadInputError(f"A2L file {path}: measurement {m.name} has data type {m.datatype}, which ambdaq cannot record")
    factor, offset, unit = 1.0, 0.0, ""
    method = methods.get(m.conversion)
    if method is not None:
        unit = method.unit or ""
        kind = method.conversionType
        if kind == "LINEAR":
            factor, offset = float(method.coeffs_linear.a), float(method.coeffs_linear.b)
        elif kind == "RAT_FUNC":
            # raw = (a p^2 + b p + c) / (d p^2 + e p + f); linear when a = d = e = 0: p = (f raw - c) / b
            c = method.coeffs
            if c.a or c.d or c.e or not c.b:
                raise BadInputError(f"A2L file {path}: measurement {m.name}: a RAT_FUNC that is not linear")
            factor, offset = float(c.f) / float(c.b), -float(c.c) / float(c.b)
        elif kind != "IDENTICAL":
            raise BadInputError(f"A2L file {path}: measurement {m.name}: conversion {kind} is not supported "
                                "(IDENTICAL, LINEAR and linear RAT_FUNC are)")
    if m.phys_unit is not None and m.phys_unit.unit:
        unit = m.phys_unit.unit
    topic, type_name, field = _placement(m)
    return A2lMeasurement(m.name, int(m.ecu_address.address), datatype, unit, factor, offset, topic, type_name, field)


def _ambdaq_note(item) -> dict[str, str]:
    """The ``word=value`` pairs of an item's ANNOTATION labelled ``ambdaq`` (empty if none)."""
    for note in item.annotation or ():
        if note.annotation_label is not None and note.annotation_label.label == "ambdaq" and note.annotation_text:
            return dict(p.split("=", 1) for p in " ".join(note.annotation_text.text).split() if "=" in p)
    return {}


def _placement(m) -> tuple[str, str, str]:
    parts = _ambdaq_note(m)
    if {"topic", "type", "field"} <= set(parts):
        return parts["topic"], parts["type"], parts["field"]
    *path, field = m.name.split(".")
    topic = "/" + "/".join(path) if path else DEFAULT_TOPIC
    type_name = "".join(p[:1].upper() + p[1:] for p in re.split(r"[^A-Za-z0-9]+", topic) if p) or "Xcp"
    return topic, type_name, re.sub(r"[^A-Za-z0-9_]", "_", field)
