"""Fast reading of ambdaq recordings into numpy arrays.

>>> rec = load("run.mcap", topics=["/amb/gap"])            # doctest: +SKIP
>>> gap = rec["/amb/gap"]
>>> gap.time, gap["front_x"]                                 # s, m

Whole chunks are decompressed and decoded through their message indexes with one strided copy
per field; nothing is decoded message by message.
"""

from __future__ import annotations

import json

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..drivers.signals import SignalGroup
from ..errors import BadInputError
from .mcapfile import McapFile, gather_payloads
from .schema import TopicLayout, parse_schema


@dataclass
class TopicData:
    """One topic's samples.

    Attributes
    ----------
    topic : str
        MCAP topic.
    log_time : ndarray of int64
        Host time of each sample, in ns (MCAP log_time).
    time : ndarray of float64
        Seconds since the first sample of the recording.
    device_time : ndarray of int64
        Device clock, in ns.
    seq : ndarray of uint32
        Device sequence numbers.
    fields : dict of str to ndarray of float64
        One array per signal, SI units (see ``units``).
    units : dict of str to str
        SI unit of each field.
    """

    topic: str
    log_time: np.ndarray
    time: np.ndarray
    device_time: np.ndarray
    seq: np.ndarray
    status: np.ndarray
    fields: dict[str, np.ndarray]
    units: dict[str, str]

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.fields[name]
        except KeyError:
            raise BadInputError(f"{self.topic} has no field {name!r}; fields: {', '.join(self.fields)}") from None

    def __len__(self) -> int:
        return int(self.log_time.shape[0])

    @property
    def sample_rate(self) -> float:
        """Mean sample rate, in Hz."""
        if len(self) < 2:
            return 0.0
        return (len(self) - 1) / ((self.log_time[-1] - self.log_time[0]) * 1e-9)


@dataclass
class Recording:
    """Topics loaded from a recording, plus its metadata."""

    path: Path
    topics: dict[str, TopicData]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    def __getitem__(self, topic: str) -> TopicData:
        try:
            return self.topics[topic]
        except KeyError:
            raise BadInputError(f"{self.path}: no topic {topic}; topics: {', '.join(self.topics)}") from None

    def __contains__(self, topic: str) -> bool:
        return topic in self.topics

    def nominal_rate(self, topic: str) -> float:
        """The sample rate the device that streams ``topic`` declares (its control rate), in Hz;
        the measured ``TopicData.sample_rate`` when the recording does not say."""
        try:
            device = json.loads(self.metadata["ambdaq.statistics"][topic])["device"]
            return float(self.metadata[f"ambdaq.device.{device}"]["sample_rate_hz"])
        except (KeyError, ValueError, TypeError):
            return self[topic].sample_rate


def _prefetch(fn, items: list, depth: int = 2):
    """``fn(item)`` for each item in order, the next ``depth`` computed ahead on a worker thread
    (decompression releases the GIL, so it overlaps the decoding of the present chunk)."""
    with ThreadPoolExecutor(max_workers=depth) as pool:
        pending = deque(pool.submit(fn, it) for it in items[:depth])
        for it in items[depth:]:
            done = pending.popleft().result()
            pending.append(pool.submit(fn, it))
            yield done
        while pending:
            yield pending.popleft().result()


def ambdaq_channels(f: McapFile) -> dict[str, tuple[int, SignalGroup]]:
    """Channels of ``f`` that carry ambdaq's fixed-layout schema: topic -> (channel id, group)."""
    out = {}
    for cid, ch in f.summary.channels.items():
        schema = f.summary.schemas.get(ch.schema_id)
        if schema is None or schema.encoding != "ros2msg" or ch.message_encoding != "cdr":
            continue
        group = parse_schema(schema.name, schema.data.decode(errors="replace"))
        if group is not None:
            out[ch.topic] = (cid, SignalGroup(ch.topic, group.type_name, group.fields, group.units))
    return out


def load(
    path: str | Path,
    topics: list[str] | tuple[str, ...] | None = None,
    *,
    start: float | None = None,
    end: float | None = None,
) -> Recording:
    """Load topics of an ambdaq recording as numpy arrays.

    Parameters
    ----------
    path : str or Path
        MCAP file written by ambdaq (or any file using its fixed-layout schemas).
    topics : list of str, optional
        Topics to load; default all ambdaq topics in the file.
    start, end : float, optional
        Time window, in s since the first message of the file.

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
    f = McapFile(path)
    available = ambdaq_channels(f)
    if topics is None:
        wanted = dict(available)
        if not wanted:
            raise BadInputError(f"{f.path}: no ambdaq topics in this file (topics: {', '.join(sorted(c.topic for c in f.summary.channels.values())) or 'none'})")
    else:
        wanted = {}
        for t in topics:
            if t not in available:
                others = ", ".join(sorted(available)) or "none"
                raise BadInputError(f"{f.path}: no ambdaq topic {t}; topics: {others}")
            wanted[t] = available[t]
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
    out = {}
    for cid, (topic, layout) in by_id.items():
        dt = layout.payload_dtype
        out[cid] = {name: np.empty(counts[cid], dtype=dt.fields[name][0]) for name in dt.names if name != "cdr_header"}
        out[cid]["log_time"] = np.empty(counts[cid], dtype=np.int64)
    pos = {cid: 0 for cid in by_id}
    for (ci, here), records in zip(plan, _prefetch(f.chunk_records, [ci for ci, _ in plan])):
        for cid, idx in here.items():
            layout = by_id[cid][1]
            view = gather_payloads(records, idx["offset"], layout.payload_dtype)
            n = view.shape[0]
            dst = out[cid]
            p = pos[cid]
            for name in dst:
                if name == "log_time":
                    dst[name][p : p + n] = idx["log_time"]
                else:
                    dst[name][p : p + n] = view[name]
            pos[cid] = p + n
    result = {}
    for cid, (topic, layout) in by_id.items():
        cols = out[cid]
        lt = cols["log_time"]
        if lt.shape[0] > 1 and np.any(np.diff(lt) < 0):
            order = np.argsort(lt, kind="stable")
            cols = {k: v[order] for k, v in cols.items()}
            lt = cols["log_time"]
        if lo is not None or hi is not None:
            a = 0 if lo is None else int(np.searchsorted(lt, lo, "left"))
            b = lt.shape[0] if hi is None else int(np.searchsorted(lt, hi, "right"))
            cols = {k: v[a:b] for k, v in cols.items()}
            lt = cols["log_time"]
        g = layout.group
        result[topic] = TopicData(
            topic=topic,
            log_time=lt,
            time=(lt - t0) * 1e-9,
            device_time=cols["device_time"],
            seq=cols["seq"],
            status=cols["status"],
            fields={name: cols[name] for name in g.fields},
            units=dict(zip(g.fields, g.units)),
        )
    return Recording(Path(path), result, f.metadata())


__all__ = ["Recording", "TopicData", "load"]
