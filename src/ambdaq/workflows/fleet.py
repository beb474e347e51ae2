"""A fleet's recordings as one table: one row per recording (or split part), computed in parallel on
Dask (docs/fleet.md), for any machine.

:func:`scan_recording` is one file's row, made by the same library calls as the single-file
commands (``runout identify``: :func:`~.runout.identify_recordings`; ``iso vibration``:
:func:`~.iso_vibration.evaluate`), so the fleet has no second implementation of either.  A
machine's axes and bearings are its own (the recording's :class:`~ambdaq.machines.machine.Machine`):
a row holds them as lists, ``axes`` (per gap axis: 1X, runout per harmonic) and ``bearings`` (per
radial bearing: orbit, ratio, zone), so a spindle's five axes and a blower's ``de``/``nde``/``thrust``
sit in one dataset.  :func:`read` gives the rows flat, a column per machine axis
(``onex_<axis>_um``, ``runout_<axis>_<k>x_um``, ``vibration_<bearing>_um`` ...).

:func:`scan` runs it as Dask tasks on whatever cluster the caller's client reaches and writes each
row where its task runs, to a Parquet dataset partitioned by machine
(``DATASET/machine=M/<key>.parquet``, one small file per recording, written to a temporary name and
renamed, so an interrupted scan leaves only whole rows).  A second scan skips every file whose size
and modification time are unchanged, and re-reads (by SHA-256) one whose time moved.
"""

from __future__ import annotations

import hashlib
import math
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..analysis.runout import harmonic_fit
from ..documents.coefficients import file_sha256
from ..mcap.mcapfile import MAGIC
from ..mcap.reader import READ_THREADS
from ..daq.recording import Recording
from ..errors import AmbdaqError, BadInputError
from ..units import RAD_S_TO_RPM
from .iso_vibration import evaluate
from .runout import identify_recordings

HARMONICS = (1, 2, 3, 4)  # the runout orders kept per axis: Ro et al.'s largest
BAND_RPM = 1000.0  # iso vibration's default speed band
WRITING_S = 60.0  # a file without its footer that changed this recently is being written, not truncated
COEFFICIENTS_KEY = "active_coefficients_sha256"  # in a device's identity: the coefficient file it runs
PARTITION = "machine"
TASKS_PER_WORKER = 8  # a scan's files are cut into this many tasks per worker: balance against scheduling
AXIS_FIELDS = ("onex_um", "onex_deg", *(f"runout_{k}x_{u}" for k in HARMONICS for u in ("um", "deg")))
"""What a row says of each gap axis (beside its name and bearing): the 1X vector from the
key-phasor, and the sensor runout per harmonic (``runout identify``)."""
BEARING_FIELDS = ("vibration_um", "ratio")  # and "zone": the worst band of ``iso vibration`` per bearing
TOUCHDOWN_NUMBERS = ("speed_rpm", "on_bearing_s", "peak_ratio", "amplifier_at_limit", "impact_speed_m_s", "energy_j")
TOUCHDOWN_TEXT = ("peak_at", "whirl")
"""What a row says of each rotor drop a snapshot file holds (``ambdaq.touchdown``, :mod:`ambdaq.acquisition.touchdowns`),
beside its time and whether the rotor levitated again."""


def _counts(rec: Recording) -> tuple[int, int]:
    """Drops and duplicates summed over the recording's devices (each device's are on all its topics)."""
    per_device: dict[str, tuple[int, int]] = {}
    for topic in rec.metadata.get("ambdaq.statistics", {}):
        s = rec.statistics(topic)
        per_device[s["device"]] = (int(s.get("drops", 0)), int(s.get("duplicates", 0)))
    return sum(d for d, _ in per_device.values()), sum(u for _, u in per_device.values())


def _touchdowns(rec: Recording) -> list[dict]:
    """The rotor drop a snapshot file characterised (its ``ambdaq.touchdown``), as a row's list."""
    from dataclasses import asdict

    from ..acquisition.touchdowns import recorded_drop

    drop = recorded_drop(rec.metadata)
    if drop is None:
        return []
    found = asdict(drop.touchdown)
    return [{"time": datetime.fromtimestamp(drop.contact_ns / 1e9, timezone.utc), "relevitated": found["relevitated"],
             "began_before": found["began_before"], **{k: math.nan if found[k] is None else found[k]
                                                       for k in TOUCHDOWN_NUMBERS},
             **{k: found[k] for k in TOUCHDOWN_TEXT}}]


def empty_row(path: Path) -> dict:
    """A row with only the file's identity: what an unreadable file gets, beside its error."""
    st = path.stat()
    row = {c: None if c in TEXT or c == "start" else 0 if c in INTEGER else math.nan for c in columns()}
    row.update({"path": str(path.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns, PARTITION: "unknown",
                "axes": [], "bearings": [], "touchdowns": []})
    return row


def scan_recording(path: str | Path, read_threads: int = READ_THREADS) -> dict:
    """One recording's row (what ``fleet scan`` stores; the columns are in docs/fleet.md).

    Parameters
    ----------
    path : str or Path
        An ambdaq MCAP recording (or split part).
    read_threads : int
        Chunks decompressed at once (:class:`~ambdaq.daq.recording.Recording`).

    Returns
    -------
    dict
        The row. A file that cannot be read has its identity and ``error``; what one recording
        cannot give (runout of a run-up, zones without a clearance) is NaN or None with a ``note``.
    """
    path = Path(path)
    row = empty_row(path)
    notes = []
    try:
        row["sha256"] = file_sha256(path)
        rec = Recording(path, threads=read_threads)
        machine = rec.machine
        row[PARTITION] = rec.machine_id
        row["start"] = rec.session.get("start_time") or None
        row["part"] = rec.session.get("part") or None
        row["drops"], row["duplicates"] = _counts(rec)
        row["coefficients_sha256"] = next((d.identity[COEFFICIENTS_KEY] for d in rec.devices.values()
                                           if d.identity.get(COEFFICIENTS_KEY)), None)
        row["touchdowns"] = _touchdowns(rec)
        # read once, for the 1X here and the runout and zones below (without current: no runout)
        rec.load_roles(["gap", "rotor", "current"])
        gap, rot = rec.together("gap", "rotor")
        n = len(gap)
        row["samples"] = len(gap)
        row["duration_s"] = rec.duration_s  # first to last message, as info and the record summary say
        rpm = rot["speed"][:n] * RAD_S_TO_RPM
        row["rpm_min"], row["rpm_max"] = float(rpm.min()), float(rpm.max())
        axes = list(machine.axes)
        bearing_of = {a: b.name for b in machine.bearings for a in (b.x, b.y)}
        one_x = harmonic_fit(np.column_stack([gap[a][:n] for a in axes]), rot["angle"][:n], (1,))[0] * 1e6
        per_axis = {a: {"axis": a, "bearing": bearing_of.get(a), "onex_um": float(abs(v)),
                        "onex_deg": float(np.degrees(np.angle(v))),
                        **{f"runout_{k}x_{u}": math.nan for k in HARMONICS for u in ("um", "deg")}}
                    for a, v in zip(axes, one_x)}
        try:  # what `ambdaq runout identify FILE` writes
            if not rec.has_role("current"):
                raise BadInputError(f"{path}: no coil currents (/amb/current) in the recording")
            ident = identify_recordings([rec], list(HARMONICS), "fit", uncertainty=False)  # not a column
            for axis, weights in ident.coef.weights.items():
                for k, (a, b) in zip(HARMONICS, weights):
                    v = complex(a, b) * 1e6
                    per_axis[axis][f"runout_{k}x_um"] = abs(v)
                    per_axis[axis][f"runout_{k}x_deg"] = float(np.degrees(np.angle(v)))
            notes += ident.warnings
        except BadInputError as err:
            notes.append(f"runout: {err}")
        row["axes"] = list(per_axis.values())
        try:  # what `ambdaq iso vibration FILE` grades
            grades, info = evaluate([rec], cmin_m=None, band_rpm=BAND_RPM)
            row["cmin_um"] = info["cmin_um"]
            worst = {}
            for g in grades:
                if g.bearing not in worst or g.ratio > worst[g.bearing].ratio:
                    worst[g.bearing] = g
            row["bearings"] = [{"bearing": b.name, "vibration_um": worst[b.name].max_um, "ratio": worst[b.name].ratio,
                                "zone": worst[b.name].zone} for b in machine.bearings if b.name in worst]
            row["zone"] = max((b["zone"] for b in row["bearings"]), default=None)
        except BadInputError as err:
            notes.append(f"zone: {err}")
    except AmbdaqError as err:
        row["error"] = str(err)
    except Exception as err:  # a damaged file must not stop the fleet: its row says what broke
        row["error"] = f"{type(err).__name__}: {err}"
    row["note"] = "; ".join(notes) or None
    return row


TEXT = ("path", "sha256", "part", "coefficients_sha256", "zone", "error", "note")  # string columns
INTEGER = ("size", "mtime_ns", "samples", "drops", "duplicates")


def schema():
    """The dataset's columns and types (every part file has all of them, whatever its row holds)."""
    import pyarrow as pa

    fields = []
    for name in columns():
        if name == PARTITION:
            continue  # the partition is the folder
        if name == "start":
            kind = pa.timestamp("us", tz="UTC")
        elif name in TEXT:
            kind = pa.string()
        elif name in INTEGER:
            kind = pa.int64()
        elif name == "axes":
            kind = pa.list_(pa.struct([("axis", pa.string()), ("bearing", pa.string()),
                                       *((f, pa.float64()) for f in AXIS_FIELDS)]))
        elif name == "bearings":
            kind = pa.list_(pa.struct([("bearing", pa.string()), *((f, pa.float64()) for f in BEARING_FIELDS),
                                       ("zone", pa.string())]))
        elif name == "touchdowns":
            kind = pa.list_(pa.struct([("time", pa.timestamp("us", tz="UTC")), ("relevitated", pa.bool_()),
                                       ("began_before", pa.bool_()),
                                       *((f, pa.float64()) for f in TOUCHDOWN_NUMBERS),
                                       *((f, pa.string()) for f in TOUCHDOWN_TEXT)]))
        else:
            kind = pa.float64()
        fields.append(pa.field(name, kind))
    return pa.schema(fields)


def columns():
    """The row's columns, in order."""
    yield from ("path", "size", "mtime_ns", "sha256", PARTITION, "start", "duration_s", "part", "rpm_min", "rpm_max",
                "samples", "drops", "duplicates", "coefficients_sha256", "cmin_um", "zone", "error", "note", "axes",
                "bearings", "touchdowns")


def _key(path: str) -> str:
    """A recording's file name in the dataset, from its path."""
    return hashlib.blake2b(path.encode(), digest_size=10).hexdigest()


def has_footer(path: Path) -> bool:
    """The file ends with the MCAP magic: its writer finished it."""
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        if fh.tell() < len(MAGIC):
            return False
        fh.seek(-len(MAGIC), os.SEEK_END)
        return fh.read() == MAGIC


def warm() -> None:
    """Import and compile what a row needs (numpy, scipy, numba's kernels, pyarrow) in the process
    that runs it: once per worker, before its first file, so no file's time holds it."""
    import pyarrow.parquet  # noqa: F401

    harmonic_fit(np.zeros((64, 2)), np.linspace(0.0, 12.0, 64), HARMONICS)


@dataclass
class ScanReport:
    """What a scan did."""

    scanned: list[str] = field(default_factory=list)  # paths whose rows were written
    unchanged: int = 0  # skipped: the dataset has their row and they did not change
    writing: list[str] = field(default_factory=list)  # skipped: no footer yet and recently modified
    errors: list[tuple[str, str]] = field(default_factory=list)  # (path, error), rows written
    interrupted: bool = False
    seconds: float = 0.0  # from the first file handed out to the last row written
    warm_s: float = 0.0  # the workers' imports and compilation before that (Dask's start-up beside it)
    bytes_read: int = 0


def recordings(inputs: Iterable[str]) -> list[Path]:
    """The MCAP files named by folders (searched recursively) and globs, in order, each once."""
    import glob

    out: dict[Path, None] = {}
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(p.rglob("*.mcap"))
        else:
            found = sorted(Path(g) for g in glob.glob(item, recursive=True))
        if not found:
            raise BadInputError(f"{item}: no recordings (.mcap) there")
        out.update((f.resolve(), None) for f in found if f.is_file())
    return list(out)


BALANCING_FILE = "_balancing.json"
"""The balancing records a scan found, in the dataset's folder: the ISO 21940-11 grade each states,
by the SHA-256 of the run it assessed. Its leading underscore and its suffix keep it out of every
reader of the Parquet dataset (pyarrow, pandas, Dask and DuckDB skip it)."""
ASSESSED = ("reference", "run")  # a record's run whose unbalance its grade is (balance influence; correct, forces)


def balancing_records(inputs: Iterable[str]) -> list[Path]:
    """The sealed balancing records (``balance ... --record``) among the folders (searched
    recursively) and globs of ``inputs``: every .json file there whose format is a balancing
    record's, each once (coefficient, plant and other files are passed over)."""
    import glob

    from .balancing import RECORD_FORMAT

    out: dict[Path, None] = {}
    for item in inputs:
        p = Path(item)
        found = sorted(p.rglob("*.json")) if p.is_dir() else sorted(Path(g) for g in glob.glob(item, recursive=True))
        for f in found:
            if f.suffix == ".json" and f.is_file() and f'"format": "{RECORD_FORMAT}"' in _head(f):
                out[f.resolve()] = None
    return list(out)


def _head(path: Path) -> str:
    """A file's first 4 kB as text: where a sealed document states its format (a plant file of tens of
    MB is not read whole to be passed over)."""
    with open(path, "rb") as fh:
        return fh.read(4096).decode("utf-8", errors="replace")


def add_balancing(dataset: Path, records: list[Path]) -> list[tuple[str, str]]:
    """Keep the grade of each record in ``dataset``'s BALANCING_FILE (added to what it holds, written
    whole and renamed) by the SHA-256 of the run it assessed; returns (path, error) for the records
    that cannot be read (a broken seal, no grade), which are left out."""
    import json

    from .balancing import load_record

    target = dataset / BALANCING_FILE
    held = json.loads(target.read_text()) if target.exists() else {}
    errors = []
    for path in records:
        try:
            rec = load_record(path)
        except AmbdaqError as err:
            errors.append((str(path), str(err)))
            continue
        assessed = next((r for r in rec["runs"] if r.get("role") in ASSESSED), None)
        if assessed is None or rec["grade_mm_s"] is None:
            errors.append((str(path), "no run it grades, or no grade (balance ... --max-rpm states one)"))
            continue
        held[str(assessed["sha256"])] = {"record": str(path), "method": rec["method"], "grade_mm_s": rec["grade_mm_s"],
                                         "grade_std_mm_s": rec["grade_std_mm_s"], "grade": rec["grade"],
                                         "max_rpm": rec["max_rpm"]}
    if held:
        dataset.mkdir(parents=True, exist_ok=True)
        part = target.with_suffix(".part")
        part.write_text(json.dumps(held, indent=1, sort_keys=True))
        part.replace(target)
    return errors


def _with_balancing(df, dataset: Path):
    """``df`` with each row's balance grade where a record graded its recording (``balance_grade_mm_s``,
    ``balance_grade_std_mm_s``, ``balance_grade``, ``balance_record``), and the latest grade its
    machine had at that row's start (``latest_balance_grade_mm_s``, ``latest_balance_grade``)."""
    import json

    target = dataset / BALANCING_FILE
    held = json.loads(target.read_text()) if target.exists() else {}
    rows = [held.get(sha) if isinstance(sha, str) else None for sha in df["sha256"]]
    for col, key in (("balance_grade_mm_s", "grade_mm_s"), ("balance_grade_std_mm_s", "grade_std_mm_s")):
        df[col] = [math.nan if r is None or r[key] is None else float(r[key]) for r in rows]
    df["balance_grade"] = [None if r is None else r["grade"] for r in rows]
    df["balance_record"] = [None if r is None else r["record"] for r in rows]
    by_machine = df.groupby(PARTITION, sort=False)  # rows in time order within each machine (read's sort)
    df["latest_balance_grade_mm_s"] = by_machine["balance_grade_mm_s"].ffill()
    latest = by_machine["balance_grade"].ffill()
    df["latest_balance_grade"] = latest.astype(object).where(latest.notna(), None)  # None, as balance_grade's
    return df


def _part_file(dataset: Path, machine: str, path: str) -> Path:
    """Where a recording's row lives: its machine's partition, a name from its path."""
    return dataset / f"{PARTITION}={machine}" / f"{_key(path)}.parquet"


def index(dataset: Path) -> dict[str, dict]:
    """The rows a dataset holds, by path: their size, time, hash, and the file that holds each."""
    if not dataset.exists():
        return {}
    table = _dataset(dataset).to_table(columns=["path", "size", "mtime_ns", "sha256", PARTITION])
    return {r["path"]: {**r, "file": _part_file(dataset, str(r[PARTITION]), r["path"])} for r in table.to_pylist()}


def check_layout(dataset: Path) -> None:
    """Refuse (BadInputError) a dataset whose rows another ambdaq version laid out (:func:`_dataset`):
    its first file's schema only, before a scan starts a cluster."""
    if dataset.exists():
        _dataset(dataset)


def _dataset(dataset: Path):
    """The Parquet dataset, refused where its rows are not laid out as this version writes them
    (an older ambdaq's): a column read under a layout it was not written in is a wrong number."""
    import pyarrow.dataset as ds

    d = ds.dataset(dataset, format="parquet", partitioning="hive", exclude_invalid_files=True)
    if d.files and [(f.name, f.type) for f in d.schema if f.name != PARTITION] != [(f.name, f.type) for f in schema()]:
        raise BadInputError(f"{dataset}: its rows are laid out as another ambdaq version wrote them; "
                            "scan into a new dataset folder")
    return d


def _replace(table, target: Path) -> None:
    """Write ``table`` to ``target`` under a temporary name and rename it: a reader (or a crash)
    never sees half of it (readers of the dataset skip names that start with a dot)."""
    import pyarrow.parquet as pq

    tmp = target.parent / f".{target.name}.tmp"
    pq.write_table(table, tmp)
    os.replace(tmp, target)


def scan_into(paths: list[str], dataset: str, old_files: list[str | None], read_threads: int) -> list[dict]:
    """One Dask task: each recording's row (:func:`scan_recording`) written where the task runs, as
    its own Parquet file under its machine's partition (the row it replaces goes). What goes back
    to the client is what it reports (path, size, machine, error), not the rows.

    Parameters
    ----------
    paths : list of str
        The recordings.
    dataset : str
        The dataset folder, reachable by the worker (on a cluster: a shared filesystem).
    old_files : list of str or None
        The part file of each recording's previous row, if it has one.
    read_threads : int
        Chunks each file decompresses at once.
    """
    import pyarrow as pa

    done = []
    for path, old_file in zip(paths, old_files):
        row = scan_recording(path, read_threads)
        target = _part_file(Path(dataset), row[PARTITION], row["path"])
        target.parent.mkdir(parents=True, exist_ok=True)
        data = dict(row, start=None if row["start"] is None else datetime.fromisoformat(row["start"]))
        _replace(pa.Table.from_pylist([data], schema=schema()), target)
        if old_file is not None and Path(old_file) != target:
            Path(old_file).unlink(missing_ok=True)
        done.append({"path": row["path"], "size": row["size"], PARTITION: row[PARTITION], "error": row["error"]})
    return done


def scan(paths: list[Path], dataset: Path, client, *, on_row: Callable[[dict, int, int], None] | None = None,
         now: float | None = None) -> ScanReport:
    """Scan ``paths`` into ``dataset`` on the Dask cluster of ``client`` (one task per file).

    Parameters
    ----------
    paths : list of Path
        Recordings.
    dataset : Path
        The Parquet dataset (a folder), created or added to.
    client : distributed.Client
        Where the tasks run (a LocalCluster's or a scheduler's).
    on_row : callable, optional
        Called with (report, done, total) as each row is written (a progress bar): the row's path,
        size, machine and error.
    now : float, optional
        The time (s since the epoch) against which "recently modified" is judged; default: now.

    Returns
    -------
    ScanReport
        Interrupted (Ctrl-C) scans return what was written, with ``interrupted`` set.
    """
    from distributed import as_completed

    t0 = time.monotonic()
    client.run(warm)  # every worker, before the first file (a cluster's workers: each once)
    report_warm = time.monotonic() - t0
    t0 = time.monotonic()
    now = time.time() if now is None else now
    report = ScanReport(warm_s=report_warm)
    known = index(dataset)
    todo = []
    for p in paths:
        st = p.stat()
        old = known.get(str(p))
        if old is not None and old["size"] == st.st_size and old["mtime_ns"] == st.st_mtime_ns:
            report.unchanged += 1
            continue
        if not has_footer(p) and now - st.st_mtime < WRITING_S:
            report.writing.append(str(p))
            continue
        if old is not None and old["size"] == st.st_size and old["sha256"] == file_sha256(p):
            _touch(old, st.st_mtime_ns)  # only its time moved: same content, same row
            report.unchanged += 1
            continue
        todo.append(p)
    # each task writes its rows where it runs: the client only hands out paths and counts. Tasks of
    # a few files each (TASKS_PER_WORKER per worker): per-task scheduling shares the client's CPU
    # with the workers on a small machine, and a file takes milliseconds
    workers = max(1, len(client.scheduler_info().get("workers", {})))
    per_task = max(1, math.ceil(len(todo) / (workers * TASKS_PER_WORKER)))
    batches = [todo[i:i + per_task] for i in range(0, len(todo), per_task)]
    # a worker reads a file on one thread: the workers are parallel over files (docs/performance.md)
    threads = 1
    futures = client.map(scan_into, [[str(p) for p in b] for b in batches], [str(dataset.resolve())] * len(batches),
                         [[None if (o := known.get(str(p))) is None else str(o["file"]) for p in b] for b in batches],
                         [threads] * len(batches), pure=False)
    # Ctrl-C (or SIGTERM) only raises a flag: the rows being written are finished, then the scan stops
    stop = [False]
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, lambda signum, frame: stop.__setitem__(0, True))
    try:
        for fut in as_completed(futures):  # woken by each result, never a polling sleep
            for done in fut.result():
                report.scanned.append(done["path"])
                report.bytes_read += done["size"]
                if done["error"]:
                    report.errors.append((done["path"], done["error"]))
                if on_row is not None:
                    on_row(done, len(report.scanned), len(todo))
            if stop[0]:
                break
    finally:
        for sig, old in handlers.items():
            signal.signal(sig, old)
    if stop[0]:
        report.interrupted = True
        client.cancel(futures)
    report.seconds = time.monotonic() - t0
    return report


def _touch(old: dict, mtime_ns: int) -> None:
    """Record a file's new modification time in its row (its content, by hash, is unchanged)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(old["file"])
    row = dict(table.to_pylist()[0], mtime_ns=mtime_ns)
    _replace(pa.Table.from_pylist([row], schema=table.schema), old["file"])


def read(dataset: Path, machine: str | None = None):
    """The dataset as a pandas DataFrame (the machine column from the partition), sorted by machine and
    start; only ``machine``'s rows if given.  Each row's axes and bearings are flat columns named
    after them (:func:`flat`), and its balance grades beside them (:func:`_with_balancing`)."""
    import pyarrow.dataset as ds

    if not dataset.exists():
        raise BadInputError(f"{dataset}: no such dataset (ambdaq fleet scan writes it)")
    d = _dataset(dataset)
    table = d.to_table(filter=None if machine is None else ds.field(PARTITION) == machine)
    df = table.to_pandas()
    if machine is not None and df.empty:
        known = sorted(set(d.to_table(columns=[PARTITION]).column(PARTITION).to_pylist()))
        raise BadInputError(f"{dataset}: no machine {machine!r} (machines: {', '.join(known)})")
    df[PARTITION] = df[PARTITION].astype(str)
    return _with_balancing(flat(df.sort_values([PARTITION, "start", "path"]).reset_index(drop=True)), dataset)


def flat(df):
    """Rows with their ``axes`` and ``bearings`` lists as columns: ``onex_<axis>_um``,
    ``runout_<axis>_<k>x_um`` ... per gap axis, ``vibration_<bearing>_um``, ``ratio_<bearing>``,
    ``zone_<bearing>`` per bearing (NaN or None where a machine has no such axis or bearing)."""
    import pandas as pd

    extra: dict[str, list] = {}
    n = len(df)
    for i, (axes, bearings) in enumerate(zip(df["axes"], df["bearings"])):
        cells = {}
        for a in axes if axes is not None else []:
            for f in AXIS_FIELDS:
                kind, _, rest = f.partition("_")  # onex_um -> onex_<axis>_um
                cells[f"{kind}_{a['axis']}_{rest}"] = a[f]
        for b in bearings if bearings is not None else []:
            cells[f"vibration_{b['bearing']}_um"] = b["vibration_um"]
            cells[f"ratio_{b['bearing']}"] = b["ratio"]
            cells[f"zone_{b['bearing']}"] = b["zone"]
        for k, v in cells.items():
            extra.setdefault(k, [math.nan if not k.startswith("zone_") else None] * n)[i] = v
    return pd.concat([df, pd.DataFrame(extra, index=df.index)], axis=1) if extra else df


def axes_of(df) -> list[str]:
    """The gap axes the rows hold (``onex_<axis>_um`` columns of :func:`read`), in column order."""
    return [c[len("onex_"):-len("_um")] for c in df.columns if c.startswith("onex_") and c.endswith("_um")]


def bearings_of(df) -> list[str]:
    """The radial bearings the rows hold (``vibration_<bearing>_um`` columns), in column order."""
    return [c[len("vibration_"):-len("_um")] for c in df.columns if c.startswith("vibration_") and c.endswith("_um")]


@dataclass(frozen=True)
class TouchdownSummary:
    """One machine's rotor drops on record (ISO 14839-5): how many, how hard, and whether its
    touchdown bearings are due for inspection (more than the limit asks, by count or energy)."""

    machine: str
    count: int
    energy_j: float  # the sum of the drops' impact energies, where known (NaN: none known)
    worst_ratio: float  # the largest excursion over Cmin
    last: str  # the last drop's time
    inspect: bool


def touchdowns(df, *, count_limit: int, energy_limit_j: float | None = None) -> list[TouchdownSummary]:
    """Per machine of ``df`` (:func:`read`'s rows), its drops on record and whether its touchdown
    bearings need inspecting: ``count_limit`` drops or more, or (given) a summed impact energy of
    ``energy_limit_j`` J or more."""
    out = []
    for machine, rows in df.groupby(PARTITION):
        events = [t for ts in rows["touchdowns"] if ts is not None for t in ts]
        if not events:
            continue
        energy = [t["energy_j"] for t in events if t["energy_j"] is not None and math.isfinite(t["energy_j"])]
        total = float(sum(energy)) if energy else math.nan
        out.append(TouchdownSummary(str(machine), len(events), total, float(max(t["peak_ratio"] for t in events)),
                                    str(max(t["time"] for t in events)),
                                    len(events) >= count_limit
                                    or (energy_limit_j is not None and total >= energy_limit_j)))
    return out


@dataclass(frozen=True)
class Movement:
    """A machine whose figure moved between its first and its last recordings."""

    machine: str
    figure: str
    first: float
    last: float
    first_start: str
    last_start: str

    @property
    def change(self) -> float:
        return self.last - self.first


def moved(df, figures: list[str], threshold_um: float) -> list[Movement]:
    """Machines whose figures (columns in um) changed by more than ``threshold_um`` from their first
    readable recording to their last."""
    out = []
    good = df[df["error"].isna()]
    for machine, rows in good.groupby(PARTITION):
        rows = rows.sort_values("start")
        for fig in figures:
            vals = rows[fig].dropna()
            if len(vals) < 2:
                continue
            first, last = float(vals.iloc[0]), float(vals.iloc[-1])
            if abs(last - first) > threshold_um:
                out.append(Movement(str(machine), fig, first, last, str(rows.loc[vals.index[0], "start"]),
                                    str(rows.loc[vals.index[-1], "start"])))
    return out


__all__ = ["HARMONICS", "ScanReport", "Movement", "TouchdownSummary", "touchdowns", "axes_of", "bearings_of", "flat",
           "add_balancing", "balancing_records", "check_layout", "has_footer", "index", "moved", "read",
           "recordings", "scan", "scan_into", "scan_recording"]
