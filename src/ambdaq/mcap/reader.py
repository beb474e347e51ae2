"""Fast reading of ambdaq's fixed-layout topics into numpy arrays (what a
:class:`~ambdaq.daq.recording.Recording` loads a topic with).

Whole chunks are inflated on every core; a device whose chunks are rows of its records has its
fields handed out as strided views of them, others are copied out with one strided copy per
field; nothing is decoded message by message.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..drivers.signals import FIELD_TYPES, HEADER_FIELDS, SignalGroup
from ..errors import BadInputError
from . import memory
from .chunk_rows import Row, first_row, row_layout, rows_hold, walked
from .mcapfile import McapFile, message_view
from .schema import TopicLayout, parse_schema

READ_THREADS = max(2, os.cpu_count() or 2)  # chunks decompressed and copied at once


class NotInRecording(BadInputError, KeyError):
    """A topic or field a recording does not have: one line on the command line (exit 2), and a
    KeyError to Python, so that ``rec.get(topic)`` and ``topic in rec`` work as for any mapping."""

    __str__ = Exception.__str__


@dataclass
class TopicData:
    """One topic's samples.

    Attributes
    ----------
    topic : str
        MCAP topic.
    nominal_rate : float
        The sample rate the device that streams the topic declares (its control rate), in Hz;
        the measured :attr:`sample_rate` when the recording does not say.
    log_time : ndarray of int64
        Host time of each sample, in ns (MCAP log_time).
    start_ns : int
        Host time of the recording's first message (of any topic), in ns: where :attr:`time` starts.
    device_time : ndarray of int64
        Device clock, in ns.
    seq : ndarray of uint32
        Device sequence numbers.
    fields : dict of str to ndarray
        One array per signal, SI units (see ``units``): float64, or int64 / uint64 for a 64-bit
        integer signal, exact.
    units : dict of str to str
        SI unit of each field ("" for a topic of another writer, whose units its schema does not give).
    skipped : tuple of str
        What a topic of another writer carries that is not a number (:mod:`.foreign`), by path.
    names : dict of str to str
        The device's own name of each field whose recorded name differs (a DBC signal's:
        ``hu_date_year`` -> ``HU_date_year``), from the device's metadata; empty where none does.
    """

    topic: str
    nominal_rate: float
    log_time: np.ndarray
    start_ns: int
    device_time: np.ndarray
    seq: np.ndarray
    status: np.ndarray
    fields: dict[str, np.ndarray]
    units: dict[str, str]
    skipped: tuple[str, ...] = ()
    names: dict[str, str] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.fields[name]
        except KeyError:
            raise NotInRecording(f"{self.topic} has no field {name!r}; fields: {', '.join(self.fields)}") from None

    def __iter__(self) -> Iterator[str]:
        """The field names, as a mapping's keys (``list(gap)``, ``dict(gap)``)."""
        return iter(self.fields)

    def keys(self):
        return self.fields.keys()

    def __len__(self) -> int:
        return int(self.log_time.shape[0])

    @cached_property
    def time(self) -> np.ndarray:
        """Seconds since the first message of the recording (float64), computed when first asked:
        a caller that plots one topic does not pay for the others'."""
        return (self.log_time - self.start_ns) * 1e-9

    @property
    def sample_rate(self) -> float:
        """Mean sample rate, in Hz."""
        if len(self) < 2:
            return 0.0
        return (len(self) - 1) / ((self.log_time[-1] - self.log_time[0]) * 1e-9)

    @property
    def duration(self) -> float:
        """From the first sample to the last, in s."""
        if not len(self):
            return 0.0
        first, last = (float(self.log_time[i] - self.start_ns) * 1e-9 for i in (0, -1))
        return last - first  # as self.time[-1] - self.time[0], without computing self.time

    def __repr__(self) -> str:
        fields = ", ".join(f"{k} [{u}]" for k, u in self.units.items())
        return (f"<TopicData {self.topic}: {len(self)} samples, {self.duration:.3f} s at {self.nominal_rate:g} Hz; "
                f"{fields}>")

    def as_role(self, fields: "Mapping[str, str]") -> "TopicData":
        """The same samples with only the fields of ``fields`` (axis -> recorded field), named after
        the axes: a role's view of a device's topic (no copy)."""
        missing = [f for f in fields.values() if f not in self.fields]
        if missing:
            raise NotInRecording(f"{self.topic} has no field {missing[0]!r}; fields: {', '.join(self.fields)}")
        return TopicData(self.topic, self.nominal_rate, self.log_time, self.start_ns, self.device_time, self.seq,
                         self.status, {a: self.fields[f] for a, f in fields.items()},
                         {a: self.units.get(f, "") for a, f in fields.items()}, self.skipped,
                         {a: self.names.get(f, f) for a, f in fields.items() if self.names.get(f, f) != a})

    def between(self, t0: float | None = None, t1: float | None = None) -> "TopicData":
        """The samples from ``t0`` to before ``t1`` (s since the recording's first message, as
        :attr:`time`; None: from the first or to the last), as views of these arrays.

        Parameters
        ----------
        t0, t1 : float or None
            In s.
        """
        lo = 0 if t0 is None else int(np.searchsorted(self.log_time, self.start_ns + round(t0 * 1e9), "left"))
        hi = len(self) if t1 is None else int(np.searchsorted(self.log_time, self.start_ns + round(t1 * 1e9), "left"))
        s = slice(lo, max(lo, hi))
        return TopicData(self.topic, self.nominal_rate, self.log_time[s], self.start_ns, self.device_time[s],
                         self.seq[s], self.status[s], {k: v[s] for k, v in self.fields.items()}, dict(self.units),
                         self.skipped, dict(self.names))

    def to_pandas(self, index: str = "seconds"):
        """The fields as a pandas DataFrame; ``df.attrs`` holds the topic, the units of each column
        and the nominal rate.  pandas is the ``pandas`` extra.

        Parameters
        ----------
        index : {"seconds", "timedelta", "datetime"}
            ``time`` in s since the recording's first message (float), the same as a
            ``TimedeltaIndex`` (what ``df.resample("1ms")`` takes), or the host time of each sample
            as a UTC ``DatetimeIndex``.
        """
        pd = _pandas()
        df = pd.DataFrame(self.fields, index=_time_index(pd, self, index))
        df.attrs = {"topic": self.topic, "units": dict(self.units), "time_unit": "s", "nominal_rate_hz": self.nominal_rate}
        return df


INDEXES = ("seconds", "timedelta", "datetime")


def _pandas():
    try:
        import pandas as pd
    except ImportError:
        raise BadInputError("to_pandas needs pandas, the pandas extra: pip install 'ambdaq[pandas]'") from None
    return pd


def _time_index(pd, data: TopicData, index: str):
    """``data``'s samples as a pandas index of kind ``index`` (:meth:`TopicData.to_pandas`)."""
    if index == "seconds":
        return pd.Index(data.time, name="time")
    if index == "timedelta":
        return pd.TimedeltaIndex(pd.to_timedelta(data.log_time - data.start_ns, unit="ns"), name="time")
    if index == "datetime":
        return pd.DatetimeIndex(pd.to_datetime(data.log_time, unit="ns", utc=True), name="time")
    raise BadInputError(f"index must be one of {', '.join(INDEXES)}, not {index!r}")


def _nominal_rate(metadata: dict[str, dict[str, str]], topic: str) -> float | None:
    """The sample rate (Hz) the device that streams ``topic`` declares, or None if the file does not say."""
    try:
        device = json.loads(metadata["ambdaq.statistics"][topic])["device"]
        return float(metadata[f"ambdaq.device.{device}"]["sample_rate_hz"])
    except (KeyError, ValueError, TypeError):
        return None


def _device_names(metadata: dict[str, dict[str, str]], topic: str, fields: tuple[str, ...]) -> dict[str, str]:
    """The device's own names of ``topic``'s fields where they differ: a DBC device's ``signals``
    (one topic per device, so a field names one signal)."""
    try:
        device = json.loads(metadata["ambdaq.statistics"][topic])["device"]
        named = json.loads(metadata[f"ambdaq.device.{device}"].get("signals", "{}"))
    except (KeyError, ValueError, TypeError):
        return {}
    return {f: str(n) for f, n in named.items() if f in fields and n != f} if isinstance(named, dict) else {}


def ambdaq_channels(f: McapFile) -> dict[str, tuple[int, SignalGroup]]:
    """Channels of ``f`` that carry ambdaq's fixed-layout schema: topic -> (channel id, group)."""
    out = {}
    for cid, ch in f.summary.channels.items():
        schema = f.summary.schemas.get(ch.schema_id)
        if schema is None or schema.encoding != "ros2msg" or ch.message_encoding != "cdr":
            continue
        group = parse_schema(schema.name, schema.data.decode(errors="replace"))
        if group is not None:
            out[ch.topic] = (cid, SignalGroup(ch.topic, group.type_name, group.fields, group.units, group.types))
    return out


def _topic_arrays(n: int, fields: int, typed: bool) -> dict[str, np.ndarray]:
    """One topic's output arrays for ``n`` samples: the header columns and one (fields, samples)
    array whose rows are the fields (float64; raw 8-byte words where the topic has integer
    fields, each row viewed as its field's type once the rows are in place), all carved from one
    block of :mod:`.memory` (separate 2.4 MB header arrays were under numpy's huge-page
    threshold)."""
    size = 8 * n * (2 + fields) + 4 * n * 2
    block = memory.take(size)
    parts, at = {}, 0
    for name, dtype, shape in (("log_time", np.int64, (n,)), ("device_time", np.int64, (n,)),
                               ("values", np.uint64 if typed else np.float64, (fields, n)), ("seq", np.uint32, (n,)), ("status", np.uint32, (n,))):
        nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
        parts[name] = block[at : at + nbytes].view(dtype).reshape(shape)
        at += nbytes
    return parts


def _fields(view: np.ndarray, group: SignalGroup) -> dict[str, np.ndarray]:
    """One array per field of the records ``view`` (strided views, no copy)."""
    values = view["values"]
    if values.dtype.names:
        return {name: values[name].view(FIELD_TYPES[t]) for name, t in zip(group.fields, group.field_types)}
    return {name: values[:, i] for i, name in enumerate(group.fields)}


@dataclass(frozen=True)
class _Chunk:
    """A chunk that holds a wanted channel, as planned before any chunk is read.

    ``records``: every channel in it -> its message index, or, where the chunk has none and its
    rows are implied by its first records, its count of records (one per row).  ``rows``: its
    rows (:data:`~.chunk_rows.Row`), None where they are not rows.  ``implied``: the rows were
    read from the first records (no message index), so every row is checked as it is inflated."""

    index: object  # the summary's ChunkIndex
    records: dict
    rows: Row | None
    implied: bool


@dataclass(frozen=True)
class _Job:
    """One chunk to read: where each wanted channel's records in it go (its message index or
    count, and the position of its first record in that channel's output), and where the chunk
    itself is inflated (``at``: its byte offset in its device's buffer, read in place; None: into
    a thread's buffer, its fields copied out)."""

    chunk: _Chunk
    places: dict
    at: int | None

    @property
    def rows(self) -> Row | None:
        """The rows its records are checked and viewed by (read in place, or implied)."""
        return self.chunk.rows if self.at is not None or self.chunk.implied else None


def _plan(f: McapFile, wanted: dict[int, object], message_sizes: dict[int, int], lo: int | None, hi: int | None,
          not_rows: frozenset[int], threads: int) -> list[_Chunk]:
    """The chunks in the window ``lo``..``hi`` (ns) that hold a wanted channel, in time order,
    with each one's records and rows (see :class:`_Chunk`); ``not_rows`` are chunks known not to
    be the rows they look like."""
    chunks = sorted(f.chunks, key=lambda ci: ci.message_start_time)
    chunks = [ci for ci in chunks if (lo is None or ci.message_end_time >= lo) and (hi is None or ci.message_start_time <= hi)]
    unindexed = [ci for ci in chunks if not ci.message_index_offsets and ci.uncompressed_size
                 and ci.chunk_start_offset not in not_rows]
    first_rows = {}
    if unindexed:
        with ThreadPoolExecutor(max_workers=threads) as pool:  # zstd lets go of the GIL
            heads = pool.map(lambda ci: first_row(f, ci, message_sizes), unindexed)
            first_rows = {ci.chunk_start_offset: rows for ci, rows in zip(unindexed, heads)}
    plan = []
    for ci in chunks:
        if ci.message_index_offsets:
            if any(cid in wanted for cid in ci.message_index_offsets):
                here = {cid: f.message_index(ci, cid) for cid in ci.message_index_offsets}
                rows = row_layout(ci.uncompressed_size, here, message_sizes)
                plan.append(_Chunk(ci, here, None if ci.chunk_start_offset in not_rows else rows, False))
        elif ci.uncompressed_size:
            rows = first_rows.get(ci.chunk_start_offset)
            if rows is None:  # not rows: its records walked for an index
                here = walked(f, ci)
                if here.keys() & wanted.keys():
                    plan.append(_Chunk(ci, here, None, False))
            elif any(cid in wanted for cid, _at in rows[0]):
                n = ci.uncompressed_size // rows[1]  # each channel's count: one record per row
                plan.append(_Chunk(ci, {cid: n for cid, _at in rows[0]}, rows, True))
    return plan


def _read_in_place(plan: list[_Chunk], wanted: dict[int, object], message_sizes: dict[int, int]) -> dict[Row, list[int]]:
    """The wanted channels read in place, by the rows they lie in: a channel whose every chunk is
    rows of one layout, where the wanted records fill half of each row or more (else copying them
    out keeps less memory)."""
    layouts: dict[int, set] = {cid: set() for cid in wanted}
    for chunk in plan:
        for cid in chunk.records.keys() & wanted.keys():
            layouts[cid].add(chunk.rows)
    in_place: dict[Row, list[int]] = {}
    for cid, seen in layouts.items():
        if len(seen) == 1 and None not in seen:
            in_place.setdefault(next(iter(seen)), []).append(cid)
    return {rows: cids for rows, cids in in_place.items() if 2 * sum(message_sizes[c] for c in cids) >= rows[1]}


def _jobs(plan: list[_Chunk], wanted: dict[int, object], in_place: dict[Row, list[int]]
          ) -> tuple[list[_Job], dict[int, int], dict[Row, int]]:
    """Where each chunk's records go, known before any is read: the jobs in time order, each
    channel's count of records, and the bytes of each in-place device's buffer."""
    filled = {rows: 0 for rows in in_place}
    counts = {cid: 0 for cid in wanted}
    jobs = []
    for chunk in plan:
        places = {}
        for cid, idx in chunk.records.items():
            if cid in wanted:
                places[cid] = (idx, counts[cid])
                counts[cid] += idx if chunk.implied else idx.shape[0]
        if chunk.rows in in_place:
            jobs.append(_Job(chunk, places, filled[chunk.rows]))
            filled[chunk.rows] += chunk.index.uncompressed_size
        else:
            jobs.append(_Job(chunk, places, None))
    return jobs, counts, filled


def read_fixed(f: McapFile, wanted: dict[str, tuple[int, SignalGroup]], fixed: dict[str, tuple[int, SignalGroup]],
               t0: int, lo: int | None, hi: int | None, metadata: dict[str, dict[str, str]],
               threads: int = READ_THREADS, not_rows: frozenset[int] = frozenset()) -> dict[str, TopicData]:
    """Read fixed-layout topics of ``f`` in one pass over its chunks.

    A device whose chunks are all rows of the same records (what ambdaq writes: one chunk, one
    device, one row per sample instant) has its chunks inflated one after the other into one
    buffer, and its fields come back as strided views of it: nothing is copied after zstd, so
    ``load`` takes little more than the inflation itself.  Other chunks (another writer's, those of
    ambdaq before 0.2) are inflated into a reused buffer and each field copied out.  Either way
    every record is checked against its message index (:func:`~.mcapfile.message_view`); a chunk
    without one (``--no-index``) by the rows its first records begin, every row checked against
    the first as it is inflated, or, where they are not rows, by walking its records.
    Read in place, a device's order is judged from its message indexes' log times (a contiguous
    pass, half the time of one over the records' at their stride): message_view has checked them
    against the records at both ends, and a damaged entry can only make ordered records look
    unordered, which costs a sort by the records' own times, never a wrong sample.

    Parameters
    ----------
    f : McapFile
        The file, opened.
    wanted : dict of str to (int, SignalGroup)
        Topic -> its channel id and group (:func:`ambdaq_channels`).
    fixed : dict of str to (int, SignalGroup)
        Every fixed-layout channel of the file (:func:`ambdaq_channels`): what a row may hold.
    t0 : int
        Host time where the recording's ``time`` starts, ns.
    lo, hi : int or None
        Host-time window, ns (None: open).
    metadata : dict
        The file's metadata (declared rates, the devices' own field names).
    threads : int
        Chunks decompressed at once (zstd lets go of the GIL); 1 where the caller is already
        parallel over files (``fleet scan``).
    not_rows : frozenset of int
        Chunks (by their offset) that looked like rows and are not: their fields are copied out,
        found by their message indexes or, without any, by walking their records.
    """
    by_id = {cid: (topic, TopicLayout(group)) for topic, (cid, group) in wanted.items()}
    dtypes = {cid: layout.message_dtype for cid, (_topic, layout) in by_id.items()}
    message_sizes = {cid: TopicLayout(group).message_dtype.itemsize for cid, group in fixed.values()}
    plan = _plan(f, by_id, message_sizes, lo, hi, not_rows, threads)
    in_place = _read_in_place(plan, by_id, message_sizes)
    placed = {cid for cids in in_place.values() for cid in cids}
    jobs, counts, sizes = _jobs(plan, by_id, in_place)
    buffers = {rows: memory.take(size) for rows, size in sizes.items()}
    out = {cid: _topic_arrays(counts[cid], len(layout.group.fields), bool(layout.group.types))
           for cid, (_topic, layout) in by_id.items() if cid not in placed}
    largest = max((job.chunk.index.uncompressed_size for job in jobs if job.at is None), default=0)
    local = threading.local()
    unordered: set[int] = set()  # channels with a message logged before the one in front of it
    looked_like_rows: set[int] = set()  # chunks that are not the rows they seemed (read again, copied)

    def read_chunk(job: _Job) -> None:
        """Decompress one chunk (into its place in its device's buffer, or into this thread's
        buffer, and then copy its fields into place): both release the GIL, so chunks are read on
        every core at once."""
        ci, rows, implied, at = job.chunk.index, job.rows, job.chunk.implied, job.at
        if at is not None:
            records = buffers[rows][at : at + ci.uncompressed_size]
        else:
            if not hasattr(local, "buffer"):
                local.buffer = np.empty(largest, dtype=np.uint8)  # numpy asks for huge pages from 4 MiB
            records = local.buffer[: ci.uncompressed_size]
        f.inflate_into(ci, records)  # every byte of records written and checked, or BadInputError
        if implied and not rows_hold(records, rows):
            looked_like_rows.add(ci.chunk_start_offset)
            return
        for cid, (idx, p) in job.places.items():
            try:
                if implied:  # every row checked: the records lie where the rows put them
                    view = np.ndarray(shape=(idx,), dtype=dtypes[cid], buffer=records, offset=dict(rows[0])[cid],
                                      strides=(rows[1],))
                else:
                    view = message_view(records, idx, dtypes[cid], cid)
                    if at is not None and view.shape[0] > 1 and view.strides[0] != rows[1]:
                        looked_like_rows.add(ci.chunk_start_offset)
                        return
            except BadInputError as err:
                raise BadInputError(f"{f.path}: chunk at byte {ci.chunk_start_offset}: {err} ({by_id[cid][0]}); "
                                    f"try: ambdaq recover") from None
            if at is not None:  # read where it lies; in order where its index is (below)
                times = view["log_time"] if implied else idx["log_time"]
                if times.shape[0] > 1 and np.any(times[1:] < times[:-1]):
                    unordered.add(cid)
                continue
            n = view.shape[0]
            cols = out[cid]
            cols["log_time"][p : p + n] = times = view["log_time"]  # the record's, which the index repeats
            if n > 1 and np.any(times[1:] < times[:-1]):
                unordered.add(cid)
            for name in HEADER_FIELDS:
                cols[name][p : p + n] = view[name]
            values = view["values"]
            if values.dtype.names:  # integer fields: each field's 8 bytes into its row, unconverted
                for i, name in enumerate(values.dtype.names):
                    np.copyto(cols["values"][i, p : p + n], values[name].view(np.uint64))
            else:  # one call for every field: numpy walks the records once, writing each field's row
                np.copyto(cols["values"][:, p : p + n].T, values)

    with ThreadPoolExecutor(max_workers=threads) as pool:
        for _ in pool.map(read_chunk, jobs):  # in order; an error in any chunk surfaces here
            pass
    if looked_like_rows:  # planned again once, those chunks' fields copied out
        return read_fixed(f, wanted, fixed, t0, lo, hi, metadata, threads, not_rows | looked_like_rows)

    columns: dict[int, dict[str, np.ndarray]] = {}  # per channel: the header columns and field:<name>
    for rows, cids in in_place.items():
        places, stride = rows
        n = buffers[rows].shape[0] // stride
        for cid, at in places:
            if cid not in cids:
                continue
            view = np.ndarray(shape=(n,), dtype=dtypes[cid], buffer=buffers[rows], offset=at, strides=(stride,))
            columns[cid] = {"log_time": view["log_time"].view(np.int64), **{h: view[h] for h in HEADER_FIELDS}}
            columns[cid].update({"field:" + k: v for k, v in _fields(view, by_id[cid][1].group).items()})
    for cid, cols in out.items():
        g = by_id[cid][1].group
        columns[cid] = {"log_time": cols["log_time"], **{h: cols[h] for h in HEADER_FIELDS}}
        columns[cid].update({"field:" + name: cols["values"][i].view(FIELD_TYPES[t])
                             for i, (name, t) in enumerate(zip(g.fields, g.field_types))})
    for job in jobs:  # where one chunk's messages meet the next's
        for cid, (_idx, p) in job.places.items():
            if p > 0 and columns[cid]["log_time"][p] < columns[cid]["log_time"][p - 1]:
                unordered.add(cid)
    return {topic: _topic_data(topic, layout.group, columns[cid], cid in unordered, t0, lo, hi, metadata)
            for cid, (topic, layout) in by_id.items()}


def _topic_data(topic: str, g: SignalGroup, cols: dict[str, np.ndarray], unordered: bool, t0: int, lo: int | None,
                hi: int | None, metadata: dict[str, dict[str, str]]) -> TopicData:
    """One topic's columns as its :class:`TopicData`: sorted by log time where they were not in
    order, cut to the window ``lo``..``hi`` (ns), at the rate its device declared (else the one
    its samples show)."""
    if unordered:
        order = np.argsort(cols["log_time"], kind="stable")
        cols = {k: v[order] for k, v in cols.items()}
    if lo is not None or hi is not None:
        lt = cols["log_time"]
        a = 0 if lo is None else int(np.searchsorted(lt, lo, "left"))
        b = lt.shape[0] if hi is None else int(np.searchsorted(lt, hi, "right"))
        cols = {k: v[a:b] for k, v in cols.items()}
    data = TopicData(topic=topic, nominal_rate=0.0, log_time=cols["log_time"], start_ns=t0,
                     device_time=cols["device_time"], seq=cols["seq"], status=cols["status"],
                     fields={name: cols["field:" + name] for name in g.fields}, units=dict(zip(g.fields, g.units)),
                     names=_device_names(metadata, topic, g.fields))
    declared = _nominal_rate(metadata, topic)
    data.nominal_rate = declared if declared is not None else data.sample_rate
    return data


__all__ = ["NotInRecording", "READ_THREADS", "TopicData", "ambdaq_channels", "read_fixed"]
