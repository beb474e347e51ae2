"""The recorder: reads sample blocks from one or more devices and writes them to MCAP.

Each device is read on its own thread into a queue; the calling thread maps device clocks to the
host clock, encodes and writes.  A chunk is closed and flushed at least every
``flush_interval`` seconds of wall time, so a killed recorder loses at most that much data.
Ctrl-C (or SIGTERM) stops the devices and finishes the file cleanly.
"""

from __future__ import annotations

import platform
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

from .. import __version__
from ..drivers.signals import Event, SampleBlock, SignalGroup
from ..errors import AmbdaqError, BadInputError, DeviceError
from .clock import ClockMap
from .writer import RecordingWriter, TopicStats


QUEUE_BLOCKS = 64  # blocks in flight between device threads and the writer


class Source(Protocol):
    """What the recorder needs of a device (see :class:`ambdaq.drivers.sim.SimSource`)."""

    name: str
    sample_rate: float

    def signal_groups(self) -> list[SignalGroup]: ...
    def identity(self) -> dict[str, str]: ...
    def calibration(self) -> dict[str, str]: ...
    def start(self, n_samples: int | None) -> None: ...
    def read(self) -> SampleBlock | None: ...
    def close(self) -> None: ...

    # optional, used when present: ``events() -> list[Event]`` (faults, bus events),
    # ``link_statistics() -> dict[str, str]`` (frames, CRC errors ...) and
    # ``clock_pairs() -> list[(device_ns, host_ns)]`` (sync messages stamped as they left the
    # device: better clock pairs than block arrival times)


@dataclass(frozen=True)
class RecordOptions:
    """How to record.

    Parameters
    ----------
    duration_s : float or None
        Recording length, in s of device time; ``None`` records until stopped.
    split_size : int or None
        Start a new file when the present one reaches this many bytes.
    split_duration_s : float or None
        Start a new file after this many seconds of data.
    compression : str
        Chunk compression: "zstd", "lz4" or "none".
    flush_interval_s : float
        Longest wall time between chunk flushes, in s (bounds the loss after a crash).
    chunk_size : int
        Uncompressed chunk size limit, in bytes.
    reconnect : bool
        Reopen a device that is lost instead of ending the recording.
    """

    duration_s: float | None = None
    split_size: int | None = None
    split_duration_s: float | None = None
    compression: str = "zstd"
    flush_interval_s: float = 0.5
    chunk_size: int = 4 << 20
    reconnect: bool = False


@dataclass
class Progress:
    """Figures shown while recording."""

    elapsed_s: float
    samples: int
    drops: int
    rate_hz: float


@dataclass
class RecordResult:
    """Summary of a finished recording."""

    files: list[Path]
    duration_s: float
    samples: int
    drops: int
    stopped_by_user: bool
    topics: dict[str, dict] = field(default_factory=dict)
    clocks: dict[str, dict] = field(default_factory=dict)
    events: int = 0

    alignment_us: float | None = None

    def as_dict(self) -> dict:
        return {
            "files": [str(f) for f in self.files],
            "duration_s": round(self.duration_s, 6),
            "samples": self.samples,
            "drops": self.drops,
            "events": self.events,
            "stopped_by_user": self.stopped_by_user,
            "topics": self.topics,
            "clocks": self.clocks,
            "alignment_us": self.alignment_us,
        }


def split_names(output: Path, split: bool) -> Callable[[int], Path]:
    """File name for part ``i``: the output itself, or ``NAME_000.mcap`` ... when splitting."""
    if not split:
        return lambda i: output
    return lambda i: output.with_name(f"{output.stem}_{i:03d}{output.suffix or '.mcap'}")


class _Reader(threading.Thread):
    """Reads one device into the shared queue until it ends, fails or is stopped.

    With ``reconnect``, a device that is lost is marked by a ``disconnect`` event, reopened every
    second (its ``reconnect()``) and marked again by a ``reconnect`` event; the samples missed in
    between are counted as drops from the sequence numbers, never filled in.
    """

    def __init__(self, source: Source, q: queue.Queue, stop: threading.Event, reconnect: bool = False) -> None:
        super().__init__(name=f"read-{source.name}", daemon=True)
        self.source, self.q, self.stop, self.reconnect = source, q, stop, reconnect

    def _reopen(self, err: DeviceError) -> bool:
        lost = time.monotonic()
        self.q.put((self.source, Event(0, "disconnect", 0, str(err))))
        while not self.stop.wait(1.0):
            try:
                self.source.reconnect()
            except AmbdaqError:
                continue
            self.q.put((self.source, Event(0, "reconnect", 0, f"reconnected after {time.monotonic() - lost:.1f} s")))
            return True
        return False

    def run(self) -> None:
        try:
            while not self.stop.is_set():
                try:
                    block = self.source.read()
                except DeviceError as err:
                    if self.reconnect and hasattr(self.source, "reconnect") and self._reopen(err):
                        continue
                    raise
                if block is None:
                    break
                # bounded queue: a source faster than the writer (unpaced simulation) waits;
                # after a stop the recorder drains the queue until every reader has ended
                self.q.put((self.source, block))
        except Exception as err:  # report, the main thread decides
            self.q.put((self.source, err))
        self.q.put((self.source, None))


class Recorder:
    """Record ``sources`` into ``output`` (see :class:`RecordOptions`).

    Parameters
    ----------
    sources : list of Source
        Devices, already opened.
    output : Path
        Output file (``NAME_000.mcap`` ... when splitting).
    options : RecordOptions
        Duration, splitting, compression.
    command : str
        The command line, stored in the session metadata.
    rig_file : Path, optional
        The rig file, attached to every part.
    overwrite : bool
        Replace existing output files.
    """

    def __init__(
        self,
        sources: list[Source],
        output: Path,
        options: RecordOptions,
        *,
        command: str = "",
        rig_file: Path | None = None,
        overwrite: bool = False,
    ) -> None:
        if not sources:
            raise BadInputError("nothing to record: give --device or --rig")
        names = [s.name for s in sources]
        if len(set(names)) != len(names):
            raise BadInputError(f"device names must be unique, got {', '.join(names)}")
        self.sources = sources
        self.options = options
        self.command = command
        self.rig_file = rig_file
        self._split = options.split_size is not None or options.split_duration_s is not None
        self._name = split_names(Path(output), self._split)
        self._overwrite = overwrite
        if not overwrite and self._name(0).exists():
            raise BadInputError(f"{self._name(0)} exists: choose another -o or pass --overwrite")

    def _new_writer(self, index: int, start_ns: int) -> RecordingWriter:
        path = self._name(index)
        if path.exists():
            if not self._overwrite:
                raise BadInputError(f"{path} exists: choose another -o or pass --overwrite")
            path.unlink()
        w = RecordingWriter(path, compression=self.options.compression, chunk_size=self.options.chunk_size)
        w.add_metadata(
            "ambdaq.session",
            {
                "start_time": datetime.fromtimestamp(start_ns / 1e9, timezone.utc).isoformat(),
                "ambdaq_version": __version__,
                "command": self.command,
                "host": platform.node(),
                "devices": ",".join(s.name for s in self.sources),
                "part": str(index),
                "requested_duration_s": "" if self.options.duration_s is None else f"{self.options.duration_s:g}",
            },
        )
        for s in self.sources:
            w.add_device(s.name, s.signal_groups(), s.identity(), s.calibration())
        if self.rig_file is not None:
            w.add_attachment(self.rig_file.name, "application/toml", self.rig_file.read_bytes(), start_ns)
        return w

    def run(self, on_progress: Callable[[Progress], None] | None = None, progress_interval_s: float = 0.5) -> RecordResult:
        """Record until the duration is reached, every device ends, or the user stops."""
        opts = self.options
        q: queue.Queue = queue.Queue(maxsize=QUEUE_BLOCKS)
        stop = threading.Event()
        self._start_ns = time.time_ns()
        for s in self.sources:
            s.start(None if opts.duration_s is None else int(round(opts.duration_s * s.sample_rate)))
        readers = [_Reader(s, q, stop, opts.reconnect) for s in self.sources]
        self._totals: dict[str, TopicStats] = {}
        self._files: list[Path] = []
        self._clocks: dict[str, ClockMap] = {}
        self._priming: dict[str, list[SampleBlock]] = {}
        self._host_clocked: set[str] = set()
        self._events = 0
        self._open_part(self._start_ns)
        t0 = time.monotonic()
        last_flush = last_progress = t0
        live = len(readers)
        failure: Exception | None = None
        # Ctrl-C and SIGTERM only raise a flag: the loop stops between blocks, never mid-write
        user_stop = threading.Event()
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, lambda signum, frame: user_stop.set())
        for r in readers:
            r.start()
        try:
            while live and not user_stop.is_set():
                try:
                    source, item = q.get(timeout=0.1)
                except queue.Empty:
                    source, item = None, None
                if isinstance(item, Exception):
                    failure = item
                    break
                if isinstance(item, Event):
                    self._writer.write_event(item.topic, source.name, time.time_ns(), item)
                    self._events += 1
                elif item is None and source is not None:
                    live -= 1
                elif item is not None:
                    self._ingest(source, item)
                    self._write_events(source)
                now = time.monotonic()
                if now - last_flush >= opts.flush_interval_s:
                    self._writer.flush()
                    last_flush = now
                if on_progress is not None and now - last_progress >= progress_interval_s:
                    last_progress = now
                    on_progress(self._progress(now - t0))
        finally:
            stop.set()
            for s in self.sources:
                s.close()
            for sig, old in handlers.items():
                signal.signal(sig, old)
            deadline = time.monotonic() + 5.0
            while any(r.is_alive() for r in readers) and time.monotonic() < deadline:
                self._drain(q)
                time.sleep(0.005)
            self._drain(q)
            for name in list(self._priming):
                self._flush_priming(name)
            for s in self.sources:
                self._write_events(s)
            self._close_part()
        if failure is not None:
            where = ", ".join(str(f) for f in self._files)
            raise DeviceError(f"{failure} (after {time.monotonic() - t0:.1f} s; recording finished cleanly: {where})") \
                from failure
        samples, drops = self._counts(self._totals)
        rate = max(s.sample_rate for s in self.sources)
        return RecordResult(
            files=list(self._files),
            duration_s=samples / rate,
            samples=samples,
            drops=drops,
            stopped_by_user=user_stop.is_set(),
            topics={t: {"samples": st.samples, "drops": st.drops} for t, st in self._totals.items()},
            clocks=self._clock_report(),
            events=self._events,
            alignment_us=self._alignment_us(),
        )

    def _alignment_us(self) -> float | None:
        """Estimated worst alignment between two devices: root sum square of the two largest map
        uncertainties (devices stamped on the host clock count as exact), in us."""
        u = sorted((c["uncertainty_us"] for c in self._clock_report().values() if c["uncertainty_us"] == c["uncertainty_us"]),
                   reverse=True)
        if len(u) < 2:
            return None
        return float((u[0] ** 2 + u[1] ** 2) ** 0.5)

    def _clock_report(self) -> dict[str, dict]:
        out = {}
        for name, cm in self._clocks.items():
            fit = cm.fit()
            out[name] = {"drift_ppm": round(float(fit.drift_ppm), 3), "offset_ns": round(float(fit.offset_ns)),
                         "uncertainty_us": round(fit.uncertainty_ns * 1e-3, 3), "points": fit.points,
                         "latency_us": round(fit.latency_ns * 1e-3, 3)}
        for name in self._host_clocked:
            out[name] = {"host_clock": True, "uncertainty_us": 0.0}
        return out

    def _close_part(self) -> None:
        """Clock fits and link statistics go into the part's metadata, then it is finished."""
        for name, rep in self._clock_report().items():
            self._writer.add_metadata(f"ambdaq.clock.{name}", {k: str(v) for k, v in rep.items()})
        alignment = self._alignment_us()
        if alignment is not None:
            self._writer.add_metadata("ambdaq.alignment", {"estimated_worst_us": f"{alignment:.1f}"})
        for s in self.sources:
            stats = getattr(s, "link_statistics", None)
            if stats is not None:
                self._writer.add_metadata(f"ambdaq.link.{s.name}", stats())
        self._merge(self._totals, self._writer)
        self._writer.close()

    def _write_events(self, source) -> None:
        events = getattr(source, "events", None)
        if events is None:
            return
        for ev in events():
            cm = self._clocks.get(source.name)
            if ev.device_time_ns and cm is not None and cm.ready:
                t = int(cm.to_host(np.array([ev.device_time_ns]))[0])
            else:
                t = time.time_ns()
            self._writer.write_event(ev.topic, source.name, t, ev)
            self._events += 1

    def _open_part(self, start_ns: int) -> None:
        """Close the present part (if any) and start the next one at ``start_ns``."""
        if self._files:
            self._close_part()
        self._writer = self._new_writer(len(self._files), start_ns)
        self._files.append(self._writer.path)
        self._part_start_ns = start_ns

    def _write(self, device: str, block: SampleBlock) -> None:
        """Write ``block``, cutting it at the exact sample where a split falls."""
        if not self._split:
            self._writer.write(device, block)
            return
        o = self.options
        pos, n = 0, len(block)
        while pos < n:
            end = min(n, pos + 1000)  # the size limit is checked at least every 1000 samples
            if o.split_duration_s is not None:
                boundary = self._part_start_ns + int(round(o.split_duration_s * 1e9))
                cut = int(np.searchsorted(block.host_time_ns, boundary, "left"))
                if cut <= pos:
                    self._open_part(boundary)
                    continue
                end = min(end, cut)
            if o.split_size is not None and self._writer.bytes_written >= o.split_size:
                self._open_part(int(block.host_time_ns[pos]))
            self._writer.write(device, block.slice(pos, end))
            pos = end

    def _drain(self, q: queue.Queue) -> None:
        """Blocks already read when the recording stopped are written, not lost."""
        while True:
            try:
                source, item = q.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, SampleBlock) and len(item):
                self._ingest(source, item)

    def _ingest(self, source, block: SampleBlock) -> None:
        """Map a block to the host clock and write it.

        Blocks that say when they arrived feed the device's online clock map (offset and drift).
        A device's first blocks wait until its drift is estimated (3 s of pairs), so the whole file is
        mapped through a fitted line; in-process sources without arrival times start their clock
        at 0 when the recording starts, so their mapping is the start offset.
        """
        device = source.name
        if block.host_time_ns is not None:  # the device's times are host times (CAN bus stamps)
            self._host_clocked.add(device)
            self._write(device, block)
            return
        if block.received_ns is None:
            host = block.device_time_ns + self._start_ns
            self._write(device, SampleBlock(block.device_time_ns, block.seq, block.values, host, status=block.status))
            return
        cm = self._clocks.setdefault(device, ClockMap())
        pairs = getattr(source, "clock_pairs", None)
        for d, h in pairs() if pairs is not None else [(int(block.device_time_ns[-1]), block.received_ns)]:
            cm.update(d, h)
        latency = getattr(source, "clock_latency_ns", None)
        if latency is not None and latency() is not None:
            cm.latency_ns = latency()
        self._priming.setdefault(device, []).append(block)
        if cm.settled:
            self._flush_priming(device)

    def _flush_priming(self, device: str) -> None:
        cm = self._clocks[device]
        for b in self._priming.pop(device, []):
            self._write(device, SampleBlock(b.device_time_ns, b.seq, b.values, cm.to_host(b.device_time_ns),
                                            b.received_ns, b.status))

    @staticmethod
    def _counts(stats: dict[str, TopicStats]) -> tuple[int, int]:
        """Samples (of the longest device) and drops (summed over devices, not topics)."""
        per_device: dict[str, tuple[int, int]] = {}
        for st in stats.values():
            per_device[st.device] = (max(per_device.get(st.device, (0, 0))[0], st.samples),
                                     max(per_device.get(st.device, (0, 0))[1], st.drops))
        return max((v[0] for v in per_device.values()), default=0), sum(v[1] for v in per_device.values())

    @staticmethod
    def _merge(totals: dict[str, TopicStats], writer: RecordingWriter) -> None:
        for topic, st in writer.statistics().items():
            acc = totals.setdefault(topic, TopicStats(st.device))
            acc.samples += st.samples
            acc.drops += st.drops

    def _progress(self, elapsed: float) -> Progress:
        totals = {t: TopicStats(st.device, st.samples, st.drops) for t, st in self._totals.items()}
        self._merge(totals, self._writer)
        samples, drops = self._counts(totals)
        return Progress(elapsed, samples, drops, samples / elapsed if elapsed > 0 else 0.0)


def print_progress(p: Progress, stream=None) -> None:
    """One status line, redrawn in place on a terminal."""
    stream = sys.stderr if stream is None else stream
    text = f"recording {p.elapsed_s:7.1f} s  {p.samples:>10d} samples  {p.drops:>6d} drops  {p.rate_hz:10.0f} samples/s"
    end = "\r" if stream.isatty() else "\n"
    stream.write(text + end)
    stream.flush()
