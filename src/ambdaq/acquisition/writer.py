"""One MCAP file of a recording: a channel per signal group, blocks encoded whole, statistics.

Metadata written (all values are strings; see docs/data-format.md):

``ambdaq.session``            start time, ambdaq version, command, host, devices, split part
``ambdaq.part``               the part's index and the host-time span it holds, [start_ns, end_ns) (end
                              empty for the last part)
``ambdaq.device.<name>``      device identity (URL, kind, profile, sample rate ...)
``ambdaq.calibration.<name>`` calibration the device reported
``ambdaq.statistics``         per topic: JSON with the device's samples, drops, duplicates, wraps,
                              restarts in this file (:class:`~ambdaq.acquisition.sequence.SampleCounts`),
                              first/last seq, rate
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..drivers.signals import Event, SampleBlock, SignalGroup
from ..errors import BadInputError, DeviceError
from ..mcap.mcapfile import CHUNK_SIZE, BlockWriter
from .sequence import SampleCounts
from ..mcap.schema import (CDR_LE_HEADER, EVENT_SCHEMA_NAME, EVENT_SCHEMA_TEXT, MESSAGE_HEADER_SIZE, MESSAGE_OPCODE,
                     TopicLayout, encode_event)

PROFILE = "ambdaq"


@dataclass
class _Device:
    name: str
    groups: list[SignalGroup]
    layouts: list[TopicLayout]
    channels: list[int]
    row_dtype: np.dtype


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
    fsync : bool
        Force every flushed chunk to the disk (on a thread of its own), and the finished file.
    index : bool
        Write message and chunk indexes (:class:`~.mcapfile.BlockWriter`).
    """

    def __init__(self, path: Path, *, compression: str = "zstd", chunk_size: int = CHUNK_SIZE, fsync: bool = True,
                 index: bool = True) -> None:
        self.path = Path(path)
        self._file = _RecordingFile(self.path)
        self._fsync = fsync
        self._sync_wanted = threading.Event()
        self._closing = False
        self._syncer = threading.Thread(target=self._sync_loop, name=f"fsync-{self.path.name}", daemon=True)
        self._syncer.start()
        self._w = BlockWriter(self._file, compression=compression, chunk_size=chunk_size, profile=PROFILE, index=index)
        self._devices: dict[str, _Device] = {}
        self._topics: dict[str, str] = {}
        self.first_time: int | None = None
        self.last_time: int | None = None
        self._event_channels: dict[str, int] = {}
        self._event_schema: int | None = None
        self.event_counts: dict[str, int] = {}
        self.counts: dict[str, SampleCounts] = {}  # per device: what the file holds and lost (daq/sequence.py)

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
        self._devices[name] = _Device(name, list(groups), layouts, channels, np.dtype(row))
        self.counts[name] = SampleCounts(name)
        self.add_metadata(f"ambdaq.device.{name}", identity)
        self.add_metadata(f"ambdaq.calibration.{name}", calibration)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name, {k: _text(v) for k, v in data.items()})

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time: int) -> None:
        self._w.add_attachment(name, media_type, data, log_time)

    def write(self, device: str, block: SampleBlock, counts: SampleCounts | None = None) -> None:
        """Encode and append one block of ``device``; every topic gets one message per instant.

        Parameters
        ----------
        device : str
            A device added with :meth:`add_device`.
        block : SampleBlock
            Its samples to write, on the host clock.
        counts : SampleCounts, optional
            What the block's stretch of the device holds and lost (its samples, the drops and
            duplicates judged in it: :class:`~.sequence.Verdict`), added to the file's counts;
            default: its samples, nothing lost (a block no one judged).
        """
        n = len(block)
        if counts is None and n:
            counts = SampleCounts(device, n, first_seq=int(block.seq[0]), last_seq=int(block.seq[-1]),
                                  first_time=int(block.host_time_ns[0]), last_time=int(block.host_time_ns[-1]))
        if counts is not None:
            self.counts[device].add(counts)
        dev = self._devices[device]
        if n == 0:
            return
        log_time = block.host_time_ns.astype(np.uint64)
        rows = np.empty(n, dtype=dev.row_dtype)
        for i, (layout, cid) in enumerate(zip(dev.layouts, dev.channels)):
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
        """Close the open chunks and hand them to the OS (a killed process loses nothing written so
        far), then have it forced to the disk on the sync thread (a power cut loses nothing
        written before that sync ends)."""
        self._w.close_chunks()
        if self._fsync:
            self._sync_wanted.set()

    def _sync_loop(self) -> None:
        """fsync whenever a flush asks, off the recording thread: a slow disk delays the sync, never
        the recording (POSIX: fsync covers every write made before it was called)."""
        while True:
            self._sync_wanted.wait()
            self._sync_wanted.clear()
            if self._closing:
                return
            try:
                os.fsync(self._file.fileno())
            except (OSError, ValueError):  # the file is being closed
                return

    def lost_at_end(self, device: str, periods: int) -> None:
        """``device`` never sent ``periods`` sample periods it was asked for after its last sample
        in this file: they count as its drops here."""
        self.counts[device].drops += periods

    @property
    def bytes_written(self) -> int:
        return self._file.tell()

    def statistics(self) -> dict[str, SampleCounts]:
        """Per topic: its device's counts in this file."""
        return {g.topic: self.counts[dev.name] for dev in self._devices.values() for g in dev.groups}

    def close(self) -> None:
        """Write the statistics metadata and the summary, sync the file to the disk and close it."""
        if self._file.closed:
            return
        try:
            self._w.close_chunks()
            self._w.add_metadata("ambdaq.statistics", {t: st.as_json() for t, st in self.statistics().items()})
            self._w.finish()
            self._file.flush()
            if self._fsync:
                os.fsync(self._file.fileno())
        finally:
            self._closing = True
            self._sync_wanted.set()
            self._syncer.join()
            self._file.close()


class _RecordingFile:
    """The file a recording is written to, whose write errors name it: a full disk, a file-size
    limit or a pulled USB stick is one line saying which file (DeviceError, exit 1), where the OS's
    own error names nothing ("[Errno 28] No space left on device")."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._f = open(path, "xb")

    def _named(self, err: OSError) -> DeviceError:
        return DeviceError(f"{self.path}: cannot write the recording: {err.strerror or err}; what was flushed before "
                           "is in the file (ambdaq recover reads it)")

    def write(self, data) -> int:
        try:
            return self._f.write(data)
        except OSError as err:
            raise self._named(err) from None

    def flush(self) -> None:
        try:
            self._f.flush()
        except OSError as err:
            raise self._named(err) from None

    def close(self) -> None:
        try:
            self._f.close()
        except OSError as err:  # its last buffered bytes could not be written; the handle is released
            raise self._named(err) from None

    def tell(self) -> int:
        return self._f.tell()

    def fileno(self) -> int:
        return self._f.fileno()

    @property
    def closed(self) -> bool:
        return self._f.closed


def _text(value: str) -> str:
    """``value`` as MCAP metadata holds it, UTF-8: a path or command line with bytes that are no
    UTF-8 (a file name from another system) keeps them as backslash escapes."""
    return value.encode("utf-8", "backslashreplace").decode("utf-8")
