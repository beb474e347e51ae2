"""Fast reading of ambdaq recordings into numpy arrays.

>>> rec = load("run.mcap", topics=["/amb/gap"])            # doctest: +SKIP
>>> rec                                                      # doctest: +SKIP
<Recording run.mcap: 1 topic, 10.000 s; /amb/gap 100000 samples at 10000 Hz>
>>> gap = rec["/amb/gap"]                                    # doctest: +SKIP
>>> gap.time, gap["front_x"], gap.nominal_rate               # doctest: +SKIP  (s, m, Hz)
>>> gap.to_pandas()                                          # doctest: +SKIP  (needs the pandas extra)

A :class:`Recording` is a read-only mapping of topic to :class:`TopicData`.

Whole chunks are decompressed and decoded through their message indexes with one strided copy
per field; nothing is decoded message by message.
"""

from __future__ import annotations

import json

import os
import threading
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from ..drivers.signals import FIELD_TYPES, HEADER_FIELDS, SignalGroup
from ..errors import BadInputError
from .foreign import foreign_topics, load_foreign
from .mcapfile import McapFile, message_view
from .schema import TopicLayout, parse_schema

READ_THREADS = max(2, os.cpu_count() or 2)  # chunks decompressed and copied at once
HUGE_PAGE = 2 << 20  # x86-64 and arm64 Linux transparent huge pages, bytes


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

    def to_pandas(self):
        """The fields as a pandas DataFrame indexed by ``time`` (s); ``df.attrs`` holds the topic, the
        units of each column and the nominal rate.  pandas is the ``pandas`` extra."""
        try:
            import pandas as pd
        except ImportError:
            raise BadInputError("to_pandas needs pandas, the pandas extra: pip install 'ambdaq[pandas]'") from None
        df = pd.DataFrame(self.fields, index=pd.Index(self.time, name="time"))
        df.attrs = {"topic": self.topic, "units": dict(self.units), "time_unit": "s", "nominal_rate_hz": self.nominal_rate}
        return df


@dataclass(repr=False)
class Recording(Mapping):
    """Topics loaded from a recording, plus its metadata: a read-only mapping of topic to
    :class:`TopicData`."""

    path: Path
    topics: dict[str, TopicData]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    def __getitem__(self, topic: str) -> TopicData:
        try:
            return self.topics[topic]
        except KeyError:
            raise NotInRecording(f"{self.path}: no topic {topic}; topics: {', '.join(self.topics)}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self.topics)

    def __len__(self) -> int:
        return len(self.topics)

    def __contains__(self, topic: object) -> bool:
        return topic in self.topics

    def __repr__(self) -> str:
        span = max((t.duration for t in self.topics.values()), default=0.0)
        parts = "; ".join(f"{t.topic} {len(t)} samples at {t.nominal_rate:g} Hz" for t in self.topics.values())
        return f"<Recording {self.path.name}: {len(self)} topic{'s' if len(self) != 1 else ''}, {span:.3f} s; {parts}>"


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
    fields, each row viewed as its field's type once the rows are in place), all carved from one allocation that starts on a huge page.
    numpy asks the kernel for huge pages on allocations of 4 MiB and more, so the first write
    faults 2 MiB in at a time rather than 4 KiB; separate 2.4 MB header arrays were under that
    threshold (with no huge pages at all, bench_read.py's load took 1.4x as long)."""
    size = 8 * n * (2 + fields) + 4 * n * 2
    block = np.empty(size + HUGE_PAGE, dtype=np.uint8)  # starts on a huge page, so all of it can be one
    block = block[-block.ctypes.data % HUGE_PAGE :][:size]
    parts, at = {}, 0
    for name, dtype, shape in (("log_time", np.int64, (n,)), ("device_time", np.int64, (n,)),
                               ("values", np.uint64 if typed else np.float64, (fields, n)), ("seq", np.uint32, (n,)), ("status", np.uint32, (n,))):
        nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
        parts[name] = block[at : at + nbytes].view(dtype).reshape(shape)
        at += nbytes
    return parts


def load(
    path: str | Path | McapFile,
    topics: list[str] | tuple[str, ...] | None = None,
    *,
    start: float | None = None,
    end: float | None = None,
    threads: int = READ_THREADS,
) -> Recording:
    """Load topics of an ambdaq recording as numpy arrays.

    Parameters
    ----------
    path : str, Path or McapFile
        MCAP file written by ambdaq (or any file using its fixed-layout schemas), or one already
        opened (whose summary a caller has read: it is not read again).
    topics : list of str, optional
        Topics to load; default all ambdaq topics in the file.
    start, end : float, optional
        Time window, in s since the first message of the file.
    threads : int
        Chunks decompressed at once (zstd lets go of the GIL); 1 where the caller is already
        parallel over files, one process per core (``fleet scan``).

    Returns
    -------
    Recording
        ``rec[topic]`` is a :class:`TopicData`; ``rec.metadata`` holds the file's metadata.

    Raises
    ------
    BadInputError
        Not an MCAP file, truncated (``ambdaq recover`` rebuilds it), corrupted, or a topic
        that is missing or not in ambdaq's layout.
    """
    f = path if isinstance(path, McapFile) else McapFile(path)
    available = ambdaq_channels(f)
    foreign = foreign_topics(f, set(available))
    if topics is None:  # ambdaq's topics; in a file of another writer, every topic a decoder reads
        wanted, others = dict(available), [] if available else list(foreign)
        if not wanted and not others:
            raise BadInputError(f"{f.path}: no topic ambdaq or an official decoder reads (topics: "
                                f"{', '.join(sorted(c.topic for c in f.summary.channels.values())) or 'none'})")
    else:
        wanted, others = {}, []
        for t in topics:
            if t in available:
                wanted[t] = available[t]
            elif t in foreign:
                others.append(t)
            else:
                known = ", ".join(sorted({*available, *foreign})) or "none"
                raise BadInputError(f"{f.path}: no ambdaq topic {t}; topics: {known}")
    stats = f.summary.statistics
    t0 = stats.message_start_time if stats is not None and stats.message_count else min(
        (ci.message_start_time for ci in f.summary.chunk_indexes), default=0
    )
    lo = None if start is None else t0 + int(start * 1e9)
    hi = None if end is None else t0 + int(end * 1e9)
    chunks = sorted(f.summary.chunk_indexes, key=lambda ci: ci.message_start_time)
    chunks = [ci for ci in chunks if (lo is None or ci.message_end_time >= lo) and (hi is None or ci.message_start_time <= hi)]
    by_id = {cid: (topic, TopicLayout(group)) for topic, (cid, group) in wanted.items()}
    # sizes from the message index headers, so each field is copied once, into place
    counts = {cid: 0 for cid in by_id}
    plan = []
    for ci in chunks:
        here = {cid: f.message_index(ci, cid) for cid in ci.message_index_offsets if cid in by_id}
        if here:
            plan.append((ci, here))
            for cid, idx in here.items():
                counts[cid] += idx.shape[0]
    out = {cid: _topic_arrays(counts[cid], len(layout.group.fields), bool(layout.group.types))
           for cid, (_topic, layout) in by_id.items()}
    jobs, pos = [], {cid: 0 for cid in by_id}
    for ci, here in plan:  # where each chunk's messages go in the output, known before any is read
        jobs.append((ci, {cid: (idx, pos[cid]) for cid, idx in here.items()}))
        for cid, idx in here.items():
            pos[cid] += idx.shape[0]

    dtypes = {cid: layout.message_dtype for cid, (_topic, layout) in by_id.items()}
    largest = max((ci.uncompressed_size for ci, _ in jobs), default=0)
    local = threading.local()
    unordered: set[int] = set()  # channels with a message logged before the one in front of it

    def read_chunk(job) -> None:
        """Decompress one chunk (into this thread's buffer) and copy its fields into place: both
        release the GIL, so chunks are read on every core at once."""
        ci, places = job
        if not hasattr(local, "buffer"):
            local.buffer = np.empty(largest, dtype=np.uint8)  # numpy asks for huge pages from 4 MiB
        records = f.chunk_records(ci, local.buffer)
        for cid, (idx, p) in places.items():
            try:
                view = message_view(records, idx, dtypes[cid], cid)
            except BadInputError as err:
                raise BadInputError(f"{f.path}: chunk at byte {ci.chunk_start_offset}: {err} ({by_id[cid][0]}); "
                                    f"try: ambdaq recover") from None
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
    for cid in by_id:  # where one chunk's messages meet the next's
        starts = np.array([places[cid][1] for _, places in jobs if cid in places and places[cid][1] > 0], dtype=np.int64)
        if starts.size and np.any(out[cid]["log_time"][starts] < out[cid]["log_time"][starts - 1]):
            unordered.add(cid)
    result = {}
    metadata = f.metadata()
    for cid, (topic, layout) in by_id.items():
        cols = out[cid]
        lt = cols["log_time"]
        if cid in unordered:
            order = np.argsort(lt, kind="stable")
            cols = {k: v[..., order] for k, v in cols.items()}
            lt = cols["log_time"]
        if lo is not None or hi is not None:
            a = 0 if lo is None else int(np.searchsorted(lt, lo, "left"))
            b = lt.shape[0] if hi is None else int(np.searchsorted(lt, hi, "right"))
            cols = {k: v[..., a:b] for k, v in cols.items()}
            lt = cols["log_time"]
        g = layout.group
        result[topic] = TopicData(
            topic=topic,
            nominal_rate=0.0,
            log_time=lt,
            start_ns=t0,
            device_time=cols["device_time"],
            seq=cols["seq"],
            status=cols["status"],
            fields={name: cols["values"][i].view(FIELD_TYPES[t])
                    for i, (name, t) in enumerate(zip(g.fields, g.field_types))},
            units=dict(zip(g.fields, g.units)),
            names=_device_names(metadata, topic, g.fields),
        )
        declared = _nominal_rate(metadata, topic)
        result[topic].nominal_rate = declared if declared is not None else result[topic].sample_rate
    for topic, cols in (load_foreign(f, others, lo, hi) if others else {}).items():
        n = cols["log_time"].shape[0]
        data = TopicData(topic=topic, nominal_rate=0.0, log_time=cols["log_time"], start_ns=t0,
                         device_time=cols["device_time"], seq=cols["seq"], status=np.zeros(n, dtype=np.uint32),
                         fields=cols["fields"], units={k: "" for k in cols["fields"]}, skipped=cols["skipped"])
        data.nominal_rate = data.sample_rate
        result[topic] = data
    return Recording(f.path, result, metadata)


def loaded(source: str | Path | McapFile | Recording, topics: list[str]) -> Recording:
    """``source`` itself if it is a :class:`Recording` that holds ``topics``, else ``load(source,
    topics)``: a workflow takes either, so a caller running several on one file reads it once.

    Parameters
    ----------
    source : str, Path, McapFile or Recording
        A recording's path, the file opened, or the recording already loaded.
    topics : list of str
        Topics the caller needs.

    Raises
    ------
    BadInputError
        A topic is missing (from the file, or from what was loaded).
    """
    if not isinstance(source, Recording):
        return load(source, topics=topics)
    missing = [t for t in topics if t not in source]
    if missing:
        raise BadInputError(f"{source.path}: no ambdaq topic {missing[0]} loaded; topics: {', '.join(source) or 'none'}")
    return source


def source_path(source: str | Path | Recording) -> Path:
    """The file a recording's path or a loaded :class:`Recording` came from (for messages)."""
    return source.path if isinstance(source, Recording) else Path(source)


__all__ = ["Recording", "TopicData", "load", "loaded", "source_path"]
