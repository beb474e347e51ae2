"""One MCAP file of a recording: a channel per signal group, blocks encoded whole, statistics.

Metadata written (all values are strings; see docs/data-format.md):

``ambdaq.session``            start time, ambdaq version, command, host, devices, split part
``ambdaq.device.<name>``      device identity (URL, kind, profile, sample rate ...)
``ambdaq.calibration.<name>`` calibration the device reported
``ambdaq.statistics``         per topic: JSON with samples, drops, device, first/last seq, rate
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..drivers.signals import Event, SampleBlock, SignalGroup
from ..errors import BadInputError
from .mcapfile import BlockWriter
from .schema import (CDR_LE_HEADER, EVENT_SCHEMA_NAME, EVENT_SCHEMA_TEXT, MESSAGE_HEADER_SIZE, MESSAGE_OPCODE,
                     TopicLayout, encode_event)

PROFILE = "ambdaq"


@dataclass
class TopicStats:
    """Samples and lost samples of one topic, counted from the device's sequence numbers."""

    device: str
    samples: int = 0
    drops: int = 0
    first_seq: int | None = None
    last_seq: int | None = None
    first_time: int | None = None
    last_time: int | None = None

    def as_json(self) -> str:
        span = (self.last_time - self.first_time) * 1e-9 if self.samples > 1 else 0.0
        rate = (self.samples - 1) / span if span > 0 else 0.0
        return json.dumps(
            {"device": self.device, "samples": self.samples, "drops": self.drops, "first_seq": self.first_seq,
             "last_seq": self.last_seq, "rate_hz": round(rate, 3)}
        )


@dataclass
class _Device:
    name: str
    groups: list[SignalGroup]
    layouts: list[TopicLayout]
    channels: list[int]
    row_dtype: np.dtype
    last_seq: int | None = None
    stats: list[TopicStats] = field(default_factory=list)


def count_drops(seq: np.ndarray, last_seq: int | None) -> int:
    """Samples lost before and inside ``seq`` (uint32, wrapping), given the previous block's last."""
    s = seq.astype(np.int64)
    if last_seq is not None:
        s = np.concatenate(([last_seq], s))
    if s.shape[0] < 2:
        return 0
    gaps = (np.diff(s) - 1) % (1 << 32)
    return int(gaps.sum())


class RecordingWriter:
    """Writes a recording's devices into one MCAP file.

    Parameters
    ----------
    path : Path
        Output file; created, never overwritten (the caller checks).
    compression : {"zstd", "lz4", "none"}
        Chunk compression.
    chunk_size : int
        Uncompressed chunk size limit, in bytes.
    """

    def __init__(self, path: Path, *, compression: str = "zstd", chunk_size: int = 4 << 20) -> None:
        self.path = Path(path)
        self._file = open(self.path, "xb")
        self._w = BlockWriter(self._file, compression=compression, chunk_size=chunk_size, profile=PROFILE)
        self._devices: dict[str, _Device] = {}
        self._topics: dict[str, str] = {}
        self.first_time: int | None = None
        self.last_time: int | None = None
        self._event_channels: dict[str, int] = {}
        self._event_schema: int | None = None
        self.event_counts: dict[str, int] = {}

    def add_device(self, name: str, groups: list[SignalGroup], identity: dict[str, str], calibration: dict[str, str]) -> None:
        """Register a device's signal groups as channels and store its identity and calibration."""
        layouts = [TopicLayout(g) for g in groups]
        channels = []
        for layout in layouts:
            topic = layout.group.topic
            if topic in self._topics:
                raise BadInputError(f"topic {topic} is produced by both {self._topics[topic]} and {name}")
            self._topics[topic] = name
            sid = self._w.add_schema(layout.schema_name, "ros2msg", layout.schema_text.encode())
            channels.append(self._w.add_channel(topic, sid, "cdr", {"device": name, "units": ",".join(layout.group.units)}))
        row = []
        for i, layout in enumerate(layouts):
            row += layout.record_dtype(prefix=f"{i}.")
        self._devices[name] = _Device(
            name, list(groups), layouts, channels, np.dtype(row), stats=[TopicStats(name) for _ in groups]
        )
        self._w.add_metadata(f"ambdaq.device.{name}", identity)
        self._w.add_metadata(f"ambdaq.calibration.{name}", calibration)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name, data)

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time: int) -> None:
        self._w.add_attachment(name, media_type, data, log_time)

    def write(self, device: str, block: SampleBlock) -> None:
        """Encode and append one block of ``device``; every topic gets one message per instant."""
        dev = self._devices[device]
        n = len(block)
        if n == 0:
            return
        log_time = block.host_time_ns.astype(np.uint64)
        rows = np.empty(n, dtype=dev.row_dtype)
        drops = count_drops(block.seq, dev.last_seq)
        dev.last_seq = int(block.seq[-1])
        for i, (layout, cid, st) in enumerate(zip(dev.layouts, dev.channels, dev.stats)):
            p = f"{i}."
            rows[p + "opcode"] = MESSAGE_OPCODE
            rows[p + "length"] = MESSAGE_HEADER_SIZE - 9 + layout.payload_size
            rows[p + "channel"] = cid
            rows[p + "sequence"] = block.seq
            rows[p + "log_time"] = log_time
            rows[p + "publish_time"] = log_time
            rows[p + "cdr_header"] = CDR_LE_HEADER
            rows[p + "device_time"] = block.device_time_ns
            rows[p + "seq"] = block.seq
            rows[p + "status"] = 0 if block.status is None else block.status
            rows[p + "values"] = block.values[layout.group.topic]
            st.samples += n
            st.drops += drops
            if st.first_seq is None:
                st.first_seq, st.first_time = int(block.seq[0]), int(log_time[0])
            st.last_seq, st.last_time = int(block.seq[-1]), int(log_time[-1])
        sizes = [MESSAGE_HEADER_SIZE + lay.payload_size for lay in dev.layouts]
        offsets = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        self._w.add_messages(
            rows.view(np.uint8).reshape(n, dev.row_dtype.itemsize),
            [(cid, int(off), size) for cid, off, size in zip(dev.channels, offsets, sizes)],
            log_time,
        )
        if self.first_time is None:
            self.first_time = int(log_time[0])
        self.last_time = int(log_time[-1])

    def write_event(self, topic: str, device: str, log_time: int, event: Event) -> None:
        """Append one event (fault, error frame, bus-state change, reconnect) on ``topic``."""
        if topic not in self._event_channels:
            if self._event_schema is None:
                self._event_schema = self._w.add_schema(EVENT_SCHEMA_NAME, "ros2msg", EVENT_SCHEMA_TEXT.encode())
            self._event_channels[topic] = self._w.add_channel(topic, self._event_schema, "cdr", {})
        n = self.event_counts.get(topic, 0)
        self.event_counts[topic] = n + 1
        payload = encode_event(event.device_time_ns, device, event.kind, event.code, event.text)
        self._w.add_message(self._event_channels[topic], n, log_time, payload)

    def flush(self) -> None:
        """Close the open chunk so everything written so far is on disk."""
        self._w.close_chunk()

    @property
    def bytes_written(self) -> int:
        return self._file.tell()

    def statistics(self) -> dict[str, TopicStats]:
        return {g.topic: st for dev in self._devices.values() for g, st in zip(dev.groups, dev.stats)}

    def close(self) -> None:
        """Write the statistics metadata and the summary, and close the file."""
        if self._file.closed:
            return
        try:
            self._w.close_chunk()
            self._w.add_metadata("ambdaq.statistics", {t: st.as_json() for t, st in self.statistics().items()})
            self._w.finish()
        finally:
            self._file.close()
