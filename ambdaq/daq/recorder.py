"""The recorder: reads sample blocks from one or more devices and writes them to MCAP.

Each device is read on its own thread into a queue; the calling thread maps device clocks to the
host clock, judges every sample's ``seq`` (:mod:`.sequence`), cuts the stream into parts on the
host clock, encodes and writes.  Every open file's chunk is closed and handed to the OS at least
every ``flush_interval`` seconds of wall time, and forced to the disk (fsync) on a thread of its
own right after, so a killed recorder loses at most that much data and a power cut that much
plus the time the disk takes to sync (docs/data-format.md).  Ctrl-C (or SIGTERM) stops the
devices and finishes the files cleanly; a second one stops waiting for the devices.
"""

from __future__ import annotations

import gc
import platform
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from .. import __version__
from ..drivers.interfaces import Source
from ..drivers.signals import Event, SampleBlock
from ..errors import AmbdaqError, BadInputError, DeviceError
from ..machines.machine import RECORD as MACHINE_RECORD, Machine
from .clock import ClockMap
from .mcapfile import CHUNK_SIZE
from .output import check_output
from .sequence import SampleCounts, SequenceTracker, Verdict
from .snapshot import SnapshotOptions, Snapshots, check_memory, memory_bound, snapshot_name
from .triggers import Device, Firing
from .writer import RecordingWriter


QUEUE_BLOCKS = 64  # blocks in flight between device threads and the writer
STOP_WAIT_S = 0.5  # after a stop, how long the devices' last blocks are waited for
PROVISIONAL_S = 0.5  # a device's first blocks wait for this much of its clock pairs (an offset from more than one)


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
        Start a new file every this many seconds on the host clock, from the recording's start.
    compression : str
        Chunk compression: "zstd", "lz4" or "none".
    flush_interval_s : float
        Longest wall time between chunk flushes (and disk syncs), in s.
    chunk_size : int
        Uncompressed chunk size limit, in bytes.
    reconnect : bool
        Reopen a device that is lost instead of ending the recording.
    fsync : bool
        Force each flushed chunk to the disk: a power cut then loses at most ``flush_interval_s``
        plus the time the disk takes to sync; without it, whatever the OS still held.
    snapshot : SnapshotOptions, optional
        Keep the last seconds in memory and write a file around each trigger instead of one
        recording (:mod:`.snapshot`).
    start_ns : int, optional
        The recording's start on the host clock, ns since the epoch; default: now.  Only for
        sources that share the host clock without stamping it (a generated recording dated in a
        simulated past: ``sim fleet``).
    """

    duration_s: float | None = None
    split_size: int | None = None
    split_duration_s: float | None = None
    compression: str = "zstd"
    flush_interval_s: float = 0.5
    chunk_size: int = CHUNK_SIZE
    reconnect: bool = False
    fsync: bool = True
    snapshot: SnapshotOptions | None = None
    start_ns: int | None = None



def machine_of(sources: list[Source], table: dict | None = None, where: str = "[machine]") -> Machine:
    """The machine ``sources`` are on: what they declare (their signal groups, their calibration's
    ``machine.*`` and ``rotor.*``) with a rig file's ``[machine]`` ``table`` over it."""
    topics = {g.topic: g.fields for s in sources for g in s.signal_groups()}
    return Machine.describe(topics, [s.calibration() for s in sources], table, where)


def _freeze_heap() -> None:
    """Collect once, then leave every object that exists now out of the collector's full passes
    until the recording ends (``gc.freeze``).  After numpy, scipy, numba and canopen are loaded a
    full collection walks about 150,000 objects with the GIL held: 90-100 ms here, in which no
    device thread runs (measured: 64-148 CAN samples of a simulated rig lost at the start of a
    recording).  Objects made during the recording are collected as usual."""
    gc.collect()
    gc.freeze()


@dataclass(frozen=True)
class Progress:
    """Figures shown while recording: each device's counts (samples received, including those
    waiting for the device's clock map; losses as judged when written), the bytes in the files,
    and the seconds to the next file when the recording splits by duration."""

    elapsed_s: float
    devices: dict[str, SampleCounts]
    file_bytes: int = 0
    next_split_s: float | None = None
    snapshots: int | None = None  # snapshot files opened so far (None: not a snapshot recording)

    @property
    def samples(self) -> int:
        """The samples of the device with the most."""
        return max((c.samples for c in self.devices.values()), default=0)

    @property
    def drops(self) -> int:
        """Summed over devices."""
        return sum(c.drops for c in self.devices.values())

    @property
    def duplicates(self) -> int:
        """Summed over devices."""
        return sum(c.duplicates for c in self.devices.values())

    @property
    def rate_hz(self) -> float:
        """:attr:`samples` over the time elapsed since the start, in samples/s."""
        return self.samples / self.elapsed_s if self.elapsed_s > 0 else 0.0


@dataclass
class RecordResult:
    """Summary of a finished recording.

    ``duration_s`` is the longest time any device covered: its sample periods (samples plus
    drops) over its sample rate, or the host clock's time where no device's duration is counted
    in samples (:attr:`Source.duration_in_samples`); ``samples`` is the most any device wrote; ``drops`` and
    ``duplicates`` are summed over devices (a device's count is the same on each of its topics);
    ``devices`` has each device's own.
    """

    files: list[Path]
    duration_s: float
    samples: int
    drops: int
    duplicates: int
    stopped_by_user: bool
    topics: dict[str, dict] = field(default_factory=dict)
    clocks: dict[str, dict] = field(default_factory=dict)
    events: int = 0
    alignment_us: float | None = None
    snapshot: dict | None = None  # a snapshot recording's memory figures and triggers fired
    devices: dict[str, dict] = field(default_factory=dict)  # per device: samples, drops, duplicates

    def counts_line(self) -> str:
        """What each device wrote and lost, in words: the totals mean different things (``samples``
        is the most any device wrote, ``drops`` the sum), so with several devices each is named."""
        dups = f", {self.duplicates} duplicates dropped" if self.duplicates else ""
        if len(self.devices) <= 1:
            return f"{self.samples} samples, {self.drops} drops{dups}"
        if len(self.devices) <= 4:
            return "; ".join(f"{name} {d['samples']} samples, {d['drops']} drops"
                             + (f", {d['duplicates']} duplicates dropped" if d["duplicates"] else "")
                             for name, d in self.devices.items())
        worst = max(self.devices, key=lambda n: self.devices[n]["drops"])
        fewest = min(d["samples"] for d in self.devices.values())
        return (f"{len(self.devices)} devices, {fewest} to {self.samples} samples each, {self.drops} drops in all"
                + (f" (most: {worst}, {self.devices[worst]['drops']})" if self.drops else "") + dups)

    def as_dict(self) -> dict:
        return {
            "files": [str(f) for f in self.files],
            "duration_s": round(self.duration_s, 6),
            "samples": self.samples,
            "drops": self.drops,
            "duplicates": self.duplicates,
            "events": self.events,
            "stopped_by_user": self.stopped_by_user,
            "devices": self.devices,
            "topics": self.topics,
            "clocks": self.clocks,
            "alignment_us": self.alignment_us,
            "snapshot": self.snapshot,
        }


def split_names(output: Path, split: bool) -> Callable[[int], Path]:
    """File name for part ``i``: the output itself, or ``NAME_000.mcap`` ... when splitting."""
    if not split:
        return lambda i: output
    return lambda i: output.with_name(f"{output.stem}_{i:03d}{output.suffix or '.mcap'}")


@dataclass(frozen=True)
class _Ended:
    """A reader's last word: its device finished what it was asked for (``complete``) or stopped."""

    complete: bool


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
        complete = False
        try:
            while not self.stop.is_set():
                try:
                    block = self.source.read()
                except DeviceError as err:
                    if self.reconnect and self.source.can_reconnect and self._reopen(err):
                        continue
                    raise
                if block is None:
                    complete = not self.stop.is_set()
                    break
                # bounded queue: a source faster than the writer (unpaced simulation) waits;
                # after a stop the recorder drains the queue until every reader has ended
                self.q.put((self.source, block))
        except Exception as err:  # report, the main thread decides
            self.q.put((self.source, err))
        self.q.put((self.source, _Ended(complete)))


@dataclass
class _Part:
    """One output file and the stretch of host time it holds: [start_ns, end_ns)."""

    index: int
    writer: RecordingWriter
    start_ns: int
    end_ns: int | None  # None: the newest part, open-ended until a split decides its end


class Recorder:
    """Record ``sources`` into ``output`` (see :class:`RecordOptions`).

    Parameters
    ----------
    sources : list of Source
        Devices, already opened; the recorder closes them.
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
    machine_table : dict, optional
        The rig file's ``[machine]`` table: the machine description over what the devices declare
        (:meth:`~ambdaq.machines.machine.Machine.describe`), written into every file.

    Notes
    -----
    Parts are cut on the host clock at ``start + k * split_duration`` (or where a part reached
    ``split_size``); each sample goes to the part its time falls in, so a part holds exactly its
    stretch of every device.  A part stays open until every device has written a sample past its
    end (or ended), so a device whose samples arrive late (a serial line whose clock map is still
    settling) still lands in the right file.
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
        machine_table: dict | None = None,
    ) -> None:
        if not sources:
            raise BadInputError("nothing to record: give --device or --rig")
        names = [s.name for s in sources]
        if len(set(names)) != len(names):
            raise BadInputError(f"device names must be unique, got {', '.join(names)}")
        self.sources = sources
        self.machine = machine_of(sources, machine_table, f"{rig_file}: [machine]" if rig_file else "[machine]")
        self.options = options
        self.command = command
        self.rig_file = rig_file
        self._split = options.split_size is not None or options.split_duration_s is not None
        self._name = split_names(Path(output), self._split)
        self._overwrite = overwrite
        self._on_block: Callable[[str, SampleBlock], None] | None = None
        self._output = Path(output)
        self._manual: queue.SimpleQueue[str] = queue.SimpleQueue()
        snap = options.snapshot
        if snap is not None:
            if self._split:
                raise BadInputError("--snapshot writes a file per trigger: it takes no --split-size or --split-duration")
            armed = [Device(s.name, s.signal_groups()) for s in sources]
            for trigger in snap.triggers:
                trigger.arm(armed, self.machine, snap.cmin_m)
            if all(s.sample_rate for s in sources):
                self.snapshot_bound = memory_bound([(s.sample_rate, s.signal_groups()) for s in sources], snap)
            else:  # frames as they come: only the byte limit holds them
                self.snapshot_bound = snap.max_bytes
            check_memory(self.snapshot_bound, snap)
        else:
            check_output(self._name(0), overwrite)

    # --- parts ---------------------------------------------------------------------------------

    def _new_writer(self, path: Path, start_ns: int, part: str) -> RecordingWriter:
        if check_output(path, self._overwrite).exists():
            path.unlink()
        w = RecordingWriter(path, compression=self.options.compression, chunk_size=self.options.chunk_size,
                            fsync=self.options.fsync)
        try:
            w.add_metadata(
                "ambdaq.session",
                {
                    "start_time": datetime.fromtimestamp(start_ns / 1e9, timezone.utc).isoformat(),
                    "ambdaq_version": __version__,
                    "command": self.command,
                    "host": platform.node(),
                    "devices": ",".join(s.name for s in self.sources),
                    "part": part,
                    "requested_duration_s": "" if self.options.duration_s is None else f"{self.options.duration_s:g}",
                },
            )
            for s in self.sources:
                w.add_device(s.name, s.signal_groups(), s.identity(), s.calibration())
            w.add_metadata(MACHINE_RECORD, self.machine.record())
            if self.rig_file is not None:
                w.add_attachment(self.rig_file.name, "application/toml", self.rig_file.read_bytes(), start_ns)
            w.flush()  # the devices and the session on disk from the start: a crash keeps who recorded what
        except BaseException:
            w.close()
            raise
        return w

    def _open_part(self, start_ns: int) -> _Part:
        index = len(self._files)
        end = None
        if self.options.split_duration_s is not None:
            end = self._start_ns + int(round((index + 1) * self.options.split_duration_s * 1e9))
        part = _Part(index, self._new_writer(self._name(index), start_ns, str(index)), start_ns, end)
        self._files.append(part.writer.path)
        self._parts.append(part)
        return part

    def _part_for(self, t_ns: int) -> _Part:
        """The part that holds host time ``t_ns``, opening parts up to it (split by duration);
        a time before the oldest open part goes to that part."""
        while True:
            newest = self._parts[-1]
            if newest.end_ns is None or t_ns < newest.end_ns:
                break
            self._open_part(newest.end_ns)
        for part in self._parts:
            if part.end_ns is None or t_ns < part.end_ns:
                return part
        return self._parts[-1]

    def _close_finished_parts(self) -> None:
        """Close every part but the newest once each device has passed its end or ended."""
        while len(self._parts) > 1:
            oldest = self._parts[0]
            if any(name not in self._ended and (self._last_time.get(name) is None
                                                or self._last_time[name] < oldest.end_ns)
                   for name in self._names):
                return
            self._finish_part(self._parts.pop(0))

    def _finish_part(self, part: _Part) -> None:
        """Its host-time span, clock fits and link statistics go into the part's metadata, then it is
        finished."""
        self._finish_file(part.writer, "ambdaq.part", {
            "index": str(part.index), "start_ns": str(part.start_ns),
            "end_ns": "" if part.end_ns is None else str(part.end_ns)})

    def _finish_file(self, w: RecordingWriter, kind: str, span: dict[str, str]) -> None:
        """``span`` under ``kind`` (``ambdaq.part``, ``ambdaq.snapshot``), the clock fits and link
        statistics go into the file's metadata; its counts into the recording's; then it is closed."""
        w.add_metadata(kind, span)
        for name, rep in self._clock_report().items():
            w.add_metadata(f"ambdaq.clock.{name}", {k: str(v) for k, v in rep.items()})
        alignment = self._alignment_us()
        if alignment is not None:
            w.add_metadata("ambdaq.alignment", {"estimated_worst_us": f"{alignment:.1f}"})
        for s in self.sources:
            stats = s.link_statistics()
            if stats:
                w.add_metadata(f"ambdaq.link.{s.name}", stats)
        if self._snapshots is None:  # a snapshot recording counts every sample once, as it is judged
            for name, counts in w.counts.items():
                self._totals[name].add(counts)
        w.close()

    # --- the run ---------------------------------------------------------------------------------

    def run(self, on_progress: Callable[[Progress], None] | None = None, progress_interval_s: float = 0.5,
            on_stopping: Callable[[list[Path]], None] | None = None,
            on_block: Callable[[str, SampleBlock], None] | None = None,
            on_snapshot: Callable[[Path, Firing], None] | None = None) -> RecordResult:
        """Record until the duration is reached, every device ends, or the user stops.

        Parameters
        ----------
        on_progress : callable, optional
            Called with a :class:`Progress` every ``progress_interval_s`` seconds.
        progress_interval_s : float
            In s.
        on_stopping : callable, optional
            Called once, at once, when the user stops (Ctrl-C, SIGTERM), with the files being
            finished.
        on_block : callable, optional
            Called with (device, block) for every block as it is received, before its clock is
            mapped, on the recorder's thread (the live view keeps a reference; it must be quick).
        on_snapshot : callable, optional
            A snapshot recording calls it with (file, firing) when a trigger opens a file.
        """
        self._on_block = on_block
        opts = self.options
        q: queue.Queue = queue.Queue(maxsize=QUEUE_BLOCKS)
        stop = threading.Event()
        self._start_ns = time.time_ns() if opts.start_ns is None else opts.start_ns
        self._names = [s.name for s in self.sources]
        self._files: list[Path] = []
        self._parts: list[_Part] = []
        self._totals = {name: SampleCounts(name) for name in self._names}
        self._trackers = {name: SequenceTracker() for name in self._names}
        self._last_time: dict[str, int | None] = {name: None for name in self._names}
        self._ended: set[str] = set()
        self._clocks: dict[str, ClockMap] = {}
        self._held: dict[str, list[SampleBlock]] = {}  # a device's first blocks, before its map has PROVISIONAL_S
        self._host_clocked: set[str] = set()
        self._events = 0
        self._snapshots: Snapshots | None = None
        if opts.snapshot is not None:
            self._snapshots = Snapshots(
                opts.snapshot, self._names,
                lambda f: snapshot_name(self._output, f, lambda p: p.exists() or p in self._files),
                self._new_writer, lambda w, meta: self._finish_file(w, "ambdaq.snapshot", meta), on_snapshot)
            self._files = self._snapshots.files  # the files so far, for a user who stops
        by_samples = {s.name: s.sample_rate is not None and s.duration_in_samples for s in self.sources}
        due = {s.name: int(round(opts.duration_s * s.sample_rate)) if by_samples[s.name] and opts.duration_s is not None
               else None for s in self.sources}
        # frames as they come (no nominal rate, e.g. a CAN bus's unknown frames) and samples at a
        # rate only declared (an XCP event): recorded for the duration by the host clock, then closed
        by_time = [s for s in self.sources if not by_samples[s.name]]
        readers = [_Reader(s, q, stop, opts.reconnect) for s in self.sources]
        failure: Exception | None = None
        # Ctrl-C and SIGTERM only raise a flag: the loop stops between blocks, never mid-write; a
        # second one stops the wait for the devices' last blocks
        signals = [0]
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            def on_signal(signum, frame) -> None:
                signals[0] += 1

            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, on_signal)
            if self._snapshots is not None:  # the manual trigger; SimpleQueue.put is safe in a handler
                handlers[signal.SIGUSR1] = signal.signal(signal.SIGUSR1, lambda signum, frame: self.trigger("SIGUSR1"))
        t0 = time.monotonic()
        _freeze_heap()
        try:
            if self._snapshots is None:
                self._open_part(self._start_ns)
            for s in self.sources:
                s.start(due[s.name])
        except BaseException:  # nothing recorded: every device is closed, no empty file is left
            gc.unfreeze()
            self._close_sources()
            for part in self._parts:
                part.writer.close()
                part.writer.path.unlink(missing_ok=True)
            for sig, old in handlers.items():
                signal.signal(sig, old)
            raise
        try:
            for r in readers:
                r.start()
            last_flush = last_progress = t0
            live = len(readers)
            while live and not signals[0]:
                try:
                    source, item = q.get(timeout=0.1)
                except queue.Empty:
                    source, item = None, None
                if isinstance(item, Exception):
                    failure = item
                    break
                if isinstance(item, _Ended):
                    live -= 1
                    self._end_device(source.name, due[source.name] if item.complete else None)
                else:
                    self._take(source, item)
                now = time.monotonic()
                if by_time and opts.duration_s is not None and now - t0 >= opts.duration_s:
                    for s in by_time:
                        s.close()  # its reader ends: the block it was reading is written
                    by_time = []
                self._take_manual()
                if now - last_flush >= opts.flush_interval_s:
                    for part in self._parts:
                        part.writer.flush()
                    if self._snapshots is not None:
                        self._snapshots.flush()
                    last_flush = now
                if on_progress is not None and now - last_progress >= progress_interval_s:
                    last_progress = now
                    on_progress(self._progress(now - t0))
            if signals[0] and on_stopping is not None:
                on_stopping(list(self._files))
        finally:
            stop.set()
            closer = threading.Thread(target=self._close_sources, name="close-devices", daemon=True)
            closer.start()
            # what the devices read until they stopped is written, not lost
            deadline = time.monotonic() + STOP_WAIT_S
            while any(r.is_alive() for r in readers) and time.monotonic() < deadline and signals[0] < 2:
                self._drain(q)
                time.sleep(0.005)
            self._drain(q)
            for name in list(self._held):
                self._flush_held(name)
            for s in self.sources:
                self._write_events(s)
            for part in self._parts:
                self._finish_part(part)
            self._parts.clear()
            if self._snapshots is not None:
                self._take_manual()
                self._snapshots.close()
            while closer.is_alive() and signals[0] < 2:
                closer.join(0.1)
            for sig, old in handlers.items():
                signal.signal(sig, old)
            gc.unfreeze()
        if failure is not None:
            where = ", ".join(str(f) for f in self._files)
            raise DeviceError(f"{failure} (after {time.monotonic() - t0:.1f} s; recording finished cleanly: {where})") \
                from failure
        rate = {s.name: s.sample_rate for s in self.sources if by_samples[s.name]}
        rated = [(t.samples + t.drops) / rate[n] for n, t in self._totals.items() if n in rate]
        topics = {}
        for s in self.sources:
            for g in s.signal_groups():
                topics[g.topic] = {k: v for k, v in self._totals[s.name].as_dict().items()
                                   if k in ("samples", "drops", "duplicates", "wraps", "restarts")}
        return RecordResult(
            files=list(self._files),
            duration_s=max(rated) if rated else time.monotonic() - t0,
            samples=max(t.samples for t in self._totals.values()),
            drops=sum(t.drops for t in self._totals.values()),
            duplicates=sum(t.duplicates for t in self._totals.values()),
            stopped_by_user=bool(signals[0]),
            topics=topics,
            clocks=self._clock_report(),
            events=self._events,
            alignment_us=self._alignment_us(),
            devices={n: {k: getattr(t, k) for k in ("samples", "drops", "duplicates")} for n, t in self._totals.items()},
            snapshot=None if self._snapshots is None else {
                "pre_s": opts.snapshot.pre_s, "post_s": opts.snapshot.post_s,
                "memory_bound_bytes": self.snapshot_bound, "memory_peak_bytes": self._snapshots.peak_bytes,
                "evicted_early": self._snapshots.evicted_early, "files": len(self._snapshots.files)},
        )

    def trigger(self, cause: str = "manual") -> None:
        """Fire the manual trigger of a snapshot recording now (thread- and signal-safe): a key press,
        SIGUSR1, a notebook's call."""
        self._manual.put(cause)

    def _take_manual(self) -> None:
        """Fire what :meth:`trigger` was asked for since the last look (a snapshot recording's)."""
        if self._snapshots is None:
            return
        while True:
            try:
                how = self._manual.get_nowait()
            except queue.Empty:
                return
            self._snapshots.fire(Firing(time.time_ns(), "manual", f"manual trigger ({how})"))

    def _close_sources(self) -> None:
        for s in self.sources:
            try:
                s.close()
            except Exception:  # a device that fails to close must not keep the others open
                pass

    def _end_device(self, name: str, due: int | None) -> None:
        """``name`` has ended; if it delivered the ``due`` periods it was asked for, the ones it
        never sent after its last sample are drops of its last part."""
        self._flush_held(name)
        if due is not None:
            missing = self._trackers[name].missing_after(due)
            if missing and self._snapshots is not None:
                self._totals[name].drops += missing
            elif missing:
                part = self._part_for(self._last_time[name] or self._start_ns)
                part.writer.counts[name].drops += missing
        self._ended.add(name)
        if self._snapshots is not None:
            self._snapshots.device_ended(name)
        self._close_finished_parts()

    def _take(self, source, item) -> None:
        if isinstance(item, Event):
            self._write_event(source.name, time.time_ns(), item)
        elif item is not None:
            if self._on_block is not None:  # as received: a live view need not wait for the clock map
                self._on_block(source.name, item)
            self._ingest(source, item)
            self._write_events(source)

    def _drain(self, q: queue.Queue) -> None:
        """Blocks already read when the recording stopped are written, not lost."""
        while True:
            try:
                source, item = q.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, SampleBlock) and len(item):
                self._ingest(source, item)

    # --- clocks ----------------------------------------------------------------------------------

    def _ingest(self, source, block: SampleBlock) -> None:
        """Map a block to the host clock and write it.

        Blocks that say when they arrived feed the device's online clock map (offset and drift).
        The first ``PROVISIONAL_S`` of a device wait for an offset from more than one pair; then
        every block is written at once, until the drift is estimated (3 s of pairs) through the
        offset alone, from the fastest pair so far.  Holding them the whole 3 s had cost a
        process killed in its first seconds every sample of such a device; how far later fits
        move those early times is measured and reported (the map's revision, :mod:`.clock`).  In-process
        sources without arrival times start their clock at 0 when the recording starts, so their
        mapping is the start offset.
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
        pairs = source.clock_pairs()
        for d, h in pairs if pairs is not None else [(int(block.device_time_ns[-1]), block.received_ns)]:
            cm.update(d, h)
        latency = source.clock_latency_ns()
        if latency is not None:
            cm.latency_ns = latency
        self._held.setdefault(device, []).append(block)
        if cm.span_s >= PROVISIONAL_S or cm.settled:  # the first half second waits for an offset from more than one pair
            self._flush_held(device)

    def _flush_held(self, device: str) -> None:
        """Write ``device``'s held blocks through its clock map as it is now."""
        cm = self._clocks.get(device)
        for b in self._held.pop(device, []):
            self._write_mapped(device, cm, b)

    def _write_mapped(self, device: str, cm: ClockMap, block: SampleBlock) -> None:
        host = cm.to_host(block.device_time_ns)
        last = self._last_time[device]
        if last is not None:
            # a refit that moves the device's time back would put the block's first samples at
            # or before the last one written: those (and only those) go just after it, 1 ns
            # apart, so time never runs back and every other sample keeps its best estimate
            host = np.maximum(host, last + 1 + np.arange(host.shape[0], dtype=np.int64))
        cm.written(int(block.device_time_ns[-1]), int(host[-1]))
        self._write(device, SampleBlock(block.device_time_ns, block.seq, block.values, host, block.received_ns,
                                        block.status))

    # --- writing ---------------------------------------------------------------------------------

    def _write(self, device: str, block: SampleBlock) -> None:
        """Judge the block's samples and write the kept ones, each into the part its time falls in."""
        n = len(block)
        if n == 0:
            return
        t = block.host_time_ns
        verdict = self._trackers[device].admit(block.seq, t)
        if self._snapshots is not None:
            self._totals[device].add(verdict.counts(device, slice(0, n), block.seq, t))
            self._snapshots.write(device, block, verdict)
        else:
            self._write_parts(device, block, verdict)
        kept = np.flatnonzero(verdict.keep)
        if kept.size:
            self._last_time[device] = int(t[kept[-1]])
        self._close_finished_parts()

    def _write_parts(self, device: str, block: SampleBlock, verdict: Verdict) -> None:
        """The judged block's kept samples, each into the part its time falls in."""
        n, t = len(block), block.host_time_ns
        pos = 0
        while pos < n:
            part = self._part_for(int(t[pos]))
            end = n if part.end_ns is None else pos + int(np.searchsorted(t[pos:], part.end_ns, "left"))
            end = max(end, pos + 1)
            if self.options.split_size is not None and part.end_ns is None:
                end = min(end, pos + 1000)  # the size limit is checked at least every 1000 samples
            sl = slice(pos, end)
            part.writer.counts[device].add(verdict.counts(device, sl, block.seq, t))
            keep = verdict.keep[sl]
            piece = block.slice(pos, end)
            part.writer.write(device, piece if keep.all() else piece.select(keep))
            if (self.options.split_size is not None and part.end_ns is None
                    and part.writer.bytes_written >= self.options.split_size):
                part.end_ns = int(t[end - 1]) + 1
            pos = end

    def _write_events(self, source: Source) -> None:
        for ev in source.events():
            cm = self._clocks.get(source.name)
            if ev.device_time_ns and cm is not None and cm.ready:
                t = int(cm.to_host(np.array([ev.device_time_ns]))[0])
            else:
                t = time.time_ns()
            self._write_event(source.name, t, ev)

    def _write_event(self, device: str, t_ns: int, ev: Event) -> None:
        if self._snapshots is not None:
            self._snapshots.write_event(device, t_ns, ev)
        else:
            self._part_for(t_ns).writer.write_event(ev.topic, device, t_ns, ev)
        self._events += 1

    # --- reports ---------------------------------------------------------------------------------

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
                         "uncertainty_us": round(fit.uncertainty_ns * 1e-3, 3),
                         "revision_us": round(fit.revision_ns * 1e-3, 3), "points": fit.points,
                         "latency_us": round(fit.latency_ns * 1e-3, 3)}
        for name in self._host_clocked:
            out[name] = {"host_clock": True, "uncertainty_us": 0.0}
        return out

    def _progress(self, elapsed: float) -> Progress:
        now = {name: SampleCounts(name) for name in self._names}
        for name, total in self._totals.items():
            now[name].add(total)
            for part in self._parts:
                now[name].add(part.writer.counts[name])
        # a device's first blocks held for its clock map are recorded: they count as they arrive
        for name, blocks in self._held.items():
            now[name].samples += sum(len(b) for b in blocks)
        next_split = None
        if self.options.split_duration_s is not None:
            period = self.options.split_duration_s * 1e9
            since = time.time_ns() - self._start_ns
            next_split = ((since // period + 1) * period - since) * 1e-9
        if self._snapshots is not None:
            return Progress(elapsed, now, self._snapshots.bytes_written, None, len(self._snapshots.files))
        return Progress(elapsed, now, sum(part.writer.bytes_written for part in self._parts), next_split)


def print_progress(p: Progress, stream=None) -> None:
    """One status line, redrawn in place on a terminal."""
    stream = sys.stderr if stream is None else stream
    text = (f"recording {p.elapsed_s:7.1f} s  {p.samples:>10d} samples  {p.drops:>6d} drops  "
            f"{p.duplicates:>4d} duplicates  {p.rate_hz:10.0f} samples/s")
    if p.snapshots is not None:
        text += f"  {p.snapshots} snapshots"
    end = "\r" if stream.isatty() else "\n"
    stream.write(text + end)
    stream.flush()
