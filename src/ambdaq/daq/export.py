"""Export recordings to CSV, NPZ, Parquet or MDF 4 (``ambdaq export``).

Every format carries, per topic, ``time`` (s since the first sample), ``log_time_ns``,
``device_time_ns``, ``seq`` and one column per field in SI units. A CSV header names each column's
unit after it as asammdf's CSV export and most DAQ software write it (``time [s]``,
``front_x [m]``; a column without a unit, such as ``seq``, bare); Parquet, NPZ and MDF 4 keep the
plain names and carry the units in their own metadata.
CSV and Parquet write one file per topic (``OUT/amb_gap.csv`` ...; a single topic may be written
to ``OUT.csv`` directly); NPZ writes one archive with keys ``<topic>/<column>``; MDF 4 one file, a
channel group per topic (:mod:`.mdf`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import BadInputError
from ..output import check_output
from ..mcap.reader import TopicData
from .recording import Recording

FORMATS = ("csv", "npz", "parquet", "mf4")


TIME_UNITS = {"time": "s", "log_time_ns": "ns", "device_time_ns": "ns"}


def _columns(t: TopicData, tables: dict[str, dict[str, str]] | None = None,
             device_names: bool = False) -> dict[str, np.ndarray]:
    cols = {"time": t.time, "log_time_ns": t.log_time, "device_time_ns": t.device_time, "seq": t.seq}
    for name, values in t.fields.items():
        column = _column(t, name, device_names)
        cols[column] = values
        table = (tables or {}).get(name)
        if table:  # the text beside the number: "" where the value has none in the table
            find = labeller(table)
            cols[f"{column}_label"] = np.array([find(v) for v in values.tolist()], dtype=str)
    return cols


def _column(t: TopicData, name: str, device_names: bool) -> str:
    """A field's column: its recorded name, or with ``device_names`` the device's own."""
    return t.names.get(name, name) if device_names else name


def labeller(table: dict[str, str]):
    """The text a value table (a recording's ``value_tables`` entry) gives a raw value: keys are a
    value (a DBC choice, an A2L COMPU_VTAB entry), an inclusive range ``"LO..HI"`` (an A2L
    COMPU_VTAB_RANGE; a fractional raw value with LO <= x < HI, as ASAM MCD-2 MC reads ranges of
    floats) or ``"default"`` (its DEFAULT_VALUE); "" where none applies."""
    exact, ranges = {}, []
    for key, text in table.items():
        lo, sep, hi = key.partition("..")
        if sep:
            ranges.append((float(lo), float(hi), text))
        elif key != "default":  # an integer key stays an int: a 64-bit value is matched exactly
            exact[int(key) if key.lstrip("-").isdigit() else float(key)] = text
    default = table.get("default", "")

    def find(value: float | int) -> str:
        if value in exact:
            return exact[value]
        v = float(value)
        whole = v.is_integer()
        for lo, hi, text in ranges:
            if lo <= v <= hi if whole else lo <= v < hi:
                return text
        return default

    return find


def value_tables(rec: Recording) -> dict[str, dict[str, dict[str, str]]]:
    """Per topic and field, the value table its device declared (a DBC's choices, an A2L's
    TAB_VERB): ``{topic: {field: {"raw value": "text"}}}``, from the recording's devices."""
    import json

    out: dict[str, dict[str, dict[str, str]]] = {}
    for device in rec.devices.values():
        tables = device.identity.get("value_tables")
        if tables:
            for topic in device.topics:
                out[topic] = json.loads(tables)
    return out


def topic_filename(topic: str) -> str:
    """``/amb/gap`` -> ``amb_gap``."""
    return topic.strip("/").replace("/", "_")


def export(rec: Recording, fmt: str, out: Path, *, overwrite: bool = False,
           labels: dict[str, dict[str, dict[str, str]]] | None = None, push_log: list[dict] | None = None,
           device_names: bool = False) -> list[Path]:
    """Write the topics of ``rec`` to ``out`` in ``fmt``; returns the files written.

    Parameters
    ----------
    rec : Recording
        Loaded topics (see :func:`ambdaq.daq.load`).
    fmt : {"csv", "npz", "parquet", "mf4"}
        Output format.
    out : Path
        A file (npz, or csv/parquet with one topic) or a directory (csv/parquet, several topics).
    overwrite : bool
        Replace existing files.
    labels : dict, optional
        Value tables (:func:`value_tables`): each field that has one gets a ``<field>_label``
        column with the text of its value (CSV, Parquet and NPZ; MDF 4 keeps the tables in its
        attached metadata).
    push_log : list of dict, optional
        MDF 4: the calibration history to attach (:func:`~ambdaq.daq.mdf.write_mf4`).
    device_names : bool
        CSV, Parquet and NPZ: name each field's column by the device's own name where it differs
        (a DBC signal's, :attr:`TopicData.names`), not by the recorded ROS 2 name.
    """
    if fmt not in FORMATS:
        raise BadInputError(f"format must be one of {', '.join(FORMATS)}, not {fmt!r}")
    out = Path(out)
    if fmt == "mf4":  # one file of every topic, a channel group each (daq/mdf.py)
        from .mdf import write_mf4

        return [write_mf4(rec, check_output(out if out.suffix.lower() == ".mf4" else out.with_suffix(".mf4"),
                                            overwrite), push_log)]
    if fmt == "npz":
        target = out if out.suffix == ".npz" else out.with_suffix(".npz")
        check_output(target, overwrite)
        arrays = {f"{t.topic}/{name}": col for t in rec.topics.values()
                  for name, col in _columns(t, (labels or {}).get(t.topic), device_names).items()}
        np.savez(target, **arrays)
        return [target]
    single = len(rec.topics) == 1 and out.suffix == f".{fmt}"
    if single:
        targets = {next(iter(rec.topics)): out}
    else:
        if out.suffix:
            raise BadInputError(f"{out}: several topics need a directory for {fmt} export (or pick one --topic)")
        out.mkdir(parents=True, exist_ok=True)
        targets = {t: out / f"{topic_filename(t)}.{fmt}" for t in rec.topics}
    for target in targets.values():
        check_output(target, overwrite)
    if fmt == "parquet":
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise BadInputError("Parquet export needs pyarrow, the parquet extra: pip install 'ambdaq[parquet]'") from None
    for topic, target in targets.items():
        t = rec.topics[topic]
        cols = _columns(t, (labels or {}).get(topic), device_names)
        if fmt == "csv":
            units = {**TIME_UNITS, **{_column(t, k, device_names): u for k, u in t.units.items()}}
            _write_csv(target, cols, units)
        else:
            pq.write_table(pa.table(cols), target)
    return list(targets.values())


def _write_csv(path: Path, cols: dict[str, np.ndarray], units: dict[str, str]) -> None:
    """CSV with each column's unit in its header (``front_x [m]``), integer columns kept integer
    (ns time stamps do not survive float64) and floats written with 17 significant digits, which
    read back as the same float64 (9 had rounded a 10-digit integer such as a ROS stamp's seconds)."""
    names = list(cols)
    table = np.empty(len(cols["time"]), dtype=[(n, cols[n].dtype) for n in names])
    for n in names:
        table[n] = cols[n]
    fmts = ["%.9f" if n == "time" else "%s" if cols[n].dtype.kind == "U" else "%.17g" if cols[n].dtype.kind == "f"
            else "%d" for n in names]
    np.savetxt(path, table, delimiter=",", fmt=fmts, header=",".join(f"{n} [{units[n]}]" if units.get(n) else n for n in names), comments="")
