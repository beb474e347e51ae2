"""The recorder: devices into MCAP files, one file, parts, or snapshots around triggers.

:class:`Recorder` puts an acquisition (:mod:`.acquisition`: the device threads, clock maps and
sequence verdicts) together with its sinks: the recording's files (:mod:`.parts`) or, with
``--snapshot``, the rings and a file around each trigger (:mod:`.snapshot`); the progress the
command line shows; and whatever else the caller hands it (the live view, the Foxglove server).
Every file says the same of itself (:mod:`.files`).  Ctrl-C (or SIGTERM) stops the devices and
finishes the files cleanly; a second one stops waiting for the devices.
"""

from __future__ import annotations

import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..drivers.interfaces import Source
from ..errors import BadInputError, DeviceError
from ..machines.machine import Machine
from .acquisition import Acquisition, Sink
from .files import RecordingFiles
from ..mcap.mcapfile import CHUNK_SIZE, McapFile
from ..output import check_output
from .parts import FileParts, split_names
from .sequence import SampleCounts
from .snapshot import SnapshotOptions, Snapshots, check_memory, drop_bound, memory_bound
from .touchdowns import DropRecords
from .triggers import Device, Firing


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
    index : bool
        Write message and chunk indexes (:class:`~.mcapfile.BlockWriter`).
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
    records : dict, optional
        More metadata records for every file, name -> {key: text}: what the workflow that records
        did to the machine while it ran (``ambdaq.test_signal``: the axis it excited).
    """

    duration_s: float | None = None
    split_size: int | None = None
    split_duration_s: float | None = None
    compression: str = "zstd"
    index: bool = True
    flush_interval_s: float = 0.5
    chunk_size: int = CHUNK_SIZE
    reconnect: bool = False
    fsync: bool = True
    snapshot: SnapshotOptions | None = None
    start_ns: int | None = None
    records: dict[str, dict[str, str]] = field(default_factory=dict)



def machine_from_sources(sources: list[Source], table: dict | None = None, where: str = "[machine]") -> Machine:
    """The machine ``sources`` are on: what they declare (their signal groups, their calibration's
    ``machine.*`` and ``rotor.*``) with a rig file's ``[machine]`` ``table`` over it."""
    topics = {g.topic: g.fields for s in sources for g in s.signal_groups()}
    return Machine.describe(topics, [s.calibration() for s in sources], table, where)


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

    ``duration_s`` is from the first message written to the last, any topic, over all its files
    (what ``ambdaq info`` states of each file and :attr:`.recording.Recording.duration_s` of a
    loaded one: devices start apart, so it is a little more than ``--duration``); of a snapshot
    recording, the host time it watched. ``samples`` is the most any device wrote; ``drops`` and
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

    def never_received(self) -> list[str]:
        """The topics that recorded nothing: a message or page that never came (no drop counts it)."""
        return [t for t, c in self.topics.items() if not c.get("samples")]

    def counts_line(self) -> str:
        """What each device wrote and lost, in words: the totals mean different things (``samples``
        is the most any device wrote, ``drops`` the sum), so with several devices each is named; a
        topic that recorded nothing is named as never received, so that "0 drops" hides none."""
        empty = self.never_received()
        if empty:
            names = ", ".join(empty[:5]) + (f" and {len(empty) - 5} more" if len(empty) > 5 else "")
            return f"{self._counts()}; never received: {len(empty)} of {len(self.topics)} topics ({names})"
        return self._counts()

    def _counts(self) -> str:
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
            "never_received": self.never_received(),
            "clocks": self.clocks,
            "alignment_us": self.alignment_us,
            "snapshot": self.snapshot,
        }


class _Progress(Sink):
    """Calls ``report`` with a :class:`Progress` every ``interval_s`` seconds."""

    def __init__(self, recorder: "Recorder", report: Callable[[Progress], None], interval_s: float) -> None:
        self.recorder, self.report, self.interval_s = recorder, report, interval_s

    def start(self, acquisition: Acquisition) -> None:
        self.last = acquisition.t0

    def tick(self, now: float) -> None:
        if now - self.last >= self.interval_s:
            self.last = now
            self.report(self.recorder.progress())


class Recorder:
    """Record ``sources`` into ``output`` (see :class:`RecordOptions`).

    Parameters
    ----------
    sources : list of Source
        Devices, already opened; the recorder closes them.
    output : Path
        Output file (``NAME_000.mcap`` ... when splitting; what snapshot files are named after).
    options : RecordOptions
        Duration, splitting, compression, snapshots.
    command : str
        The command line, stored in the session metadata.
    rig_file : Path, optional
        The rig file, attached to every part.
    overwrite : bool
        Replace existing output files.
    machine_table : dict, optional
        The rig file's ``[machine]`` table: the machine description over what the devices declare
        (:meth:`~ambdaq.machines.machine.Machine.describe`), written into every file.
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
        self.machine = machine_from_sources(sources, machine_table, f"{rig_file}: [machine]" if rig_file else "[machine]")
        self.options = options
        self.output = Path(output)
        self.acquisition = Acquisition(sources, duration_s=options.duration_s, reconnect=options.reconnect,
                                       start_ns=options.start_ns)
        self.files = RecordingFiles(self.acquisition, self.machine, command=command, rig_file=rig_file,
                                    requested_duration_s=options.duration_s, compression=options.compression, index=options.index,
                                    chunk_size=options.chunk_size, fsync=options.fsync, overwrite=overwrite,
                                    records=options.records)
        split = options.split_size is not None or options.split_duration_s is not None
        snap = options.snapshot
        self.parts: FileParts | None = None
        self.snapshots: Snapshots | None = None
        if snap is not None:
            if split:
                raise BadInputError("--snapshot writes a file per trigger: it takes no --split-size or --split-duration")
            armed = [Device(s.name, s.signal_groups()) for s in sources]
            for trigger in snap.triggers:
                trigger.arm(armed, self.machine, snap.cmin_m)
            if all(s.sample_rate for s in sources):
                self.snapshot_bound = memory_bound([(s.sample_rate, s.signal_groups()) for s in sources], snap)
            else:  # frames as they come: only the byte limit holds them
                self.snapshot_bound = snap.max_bytes
            # a rotor drop's record: kept within a bound stated here, so only from a gap of known rate
            self.touchdowns: DropRecords | None = DropRecords(self.machine, armed, snap.cmin_m)
            gap_rate = next((s.sample_rate for s in sources if s.name == self.touchdowns.device), None)
            if not (self.touchdowns.possible and gap_rate):
                self.touchdowns = None
            self.drop_bound = 0 if self.touchdowns is None else drop_bound(self.touchdowns, gap_rate, snap)
            check_memory(self.snapshot_bound + self.drop_bound, snap)
        else:
            check_output(split_names(self.output, split)(0), overwrite)

    def trigger(self, cause: str = "manual") -> None:
        """Fire the manual trigger of a snapshot recording now (thread- and signal-safe): a key press,
        SIGUSR1, a notebook's call."""
        if self.snapshots is not None:
            self.snapshots.trigger(cause)

    @property
    def paths(self) -> list[Path]:
        """The files opened so far."""
        return self.snapshots.files if self.snapshots is not None else self.parts.paths if self.parts else []

    def progress(self) -> Progress:
        """The figures of the recording so far."""
        acq = self.acquisition
        counts = acq.counts_now()
        if self.snapshots is not None:
            return Progress(acq.elapsed_s, counts, self.snapshots.bytes_written, None, len(self.snapshots.files))
        return Progress(acq.elapsed_s, counts, self.parts.bytes_written, self.parts.next_split_s(time.time_ns()))

    def run(self, on_progress: Callable[[Progress], None] | None = None, progress_interval_s: float = 0.5,
            on_stopping: Callable[[list[Path]], None] | None = None, sinks: list[Sink] = (),
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
        sinks : list of Sink
            More sinks of the acquisition (the live view, the Foxglove server): each sees every
            block as it is received (:meth:`Sink.received`), and what else it asks for.
        on_snapshot : callable, optional
            A snapshot recording calls it with (file, firing) when a trigger opens a file.
        """
        opts = self.options
        if opts.snapshot is not None:
            self.snapshots = Snapshots(opts.snapshot, self.files, self.output, on_snapshot, opts.flush_interval_s,
                                       self.touchdowns)
            store: Sink = self.snapshots
            signals = {signal.SIGUSR1: lambda signum, frame: self.trigger("SIGUSR1")}
        else:
            self.parts = FileParts(self.files, self.output, split_size=opts.split_size,
                                   split_duration_s=opts.split_duration_s, flush_interval_s=opts.flush_interval_s)
            store, signals = self.parts, {}
        extra = [_Progress(self, on_progress, progress_interval_s)] if on_progress is not None else []
        acq = self.acquisition
        failure = acq.run([store, *sinks, *extra], signals=signals,
                          on_stopping=None if on_stopping is None else lambda: on_stopping(list(self.paths)))
        if failure is not None:
            where = ", ".join(str(f) for f in self.paths)
            raise DeviceError(f"{failure} (after {acq.elapsed_s:.1f} s; recording finished cleanly: {where})") \
                from failure
        return self._result()

    def _result(self) -> RecordResult:
        acq = self.acquisition
        totals = acq.totals
        topics = {}
        for s in self.sources:
            for g in s.signal_groups():
                topics[g.topic] = {k: v for k, v in totals[s.name].as_dict().items()
                                   if k in ("samples", "drops", "duplicates", "wraps", "restarts")}
        snap = self.options.snapshot
        return RecordResult(
            files=list(self.paths),
            duration_s=acq.elapsed_s if self.snapshots is not None else _span_s(self.paths),
            samples=max(t.samples for t in totals.values()),
            drops=sum(t.drops for t in totals.values()),
            duplicates=sum(t.duplicates for t in totals.values()),
            stopped_by_user=acq.stopped_by_user,
            topics=topics,
            clocks=acq.clock_report(),
            events=acq.events,
            alignment_us=acq.alignment_us(),
            devices={n: {k: getattr(t, k) for k in ("samples", "drops", "duplicates")} for n, t in totals.items()},
            snapshot=None if self.snapshots is None else {
                "pre_s": snap.pre_s, "post_s": snap.post_s,
                "memory_bound_bytes": self.snapshot_bound, "memory_peak_bytes": self.snapshots.peak_bytes,
                "drop_memory_bound_bytes": self.drop_bound, "drop_memory_peak_bytes": self.snapshots.drop_peak_bytes,
                "evicted_early": self.snapshots.evicted_early, "files": len(self.snapshots.files)},
        )


def _span_s(paths: list[Path]) -> float:
    """From the first message of the files to their last, any topic, s (a recording's duration,
    as ``info`` states it of each file: :attr:`.mcapfile.McapFile.span_ns`)."""
    spans = [McapFile(p).span_ns for p in paths]
    spans = [s for s in spans if s[1] > 0]
    return (max(e for _, e in spans) - min(b for b, _ in spans)) * 1e-9 if spans else 0.0


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
