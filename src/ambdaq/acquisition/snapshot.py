"""Snapshot recording (``ambdaq record --snapshot``): the last seconds of every device in memory, and a
file around each trigger, as rosbag2's snapshot mode and an AMB controller's fault buffer keep them.

:class:`Snapshots` is a sink of the acquisition (:mod:`.acquisition`): it takes every judged block on
the host clock and every event.  Each device's samples wait in a ring (:class:`_Ring`) that holds at
least the ``pre_s`` seconds before its newest sample and is bounded in bytes.  When a trigger fires
at host time T (:mod:`.triggers`), a file is opened that gets every device's samples and events in
[T - pre, T + post): what the ring holds at once, the rest as it arrives; it is finished when every
device has passed T + post (or ended).  A trigger that fires while a file is still being written and
before its end extends that file to its own T + post (its cause is added), so a burst of faults is
one file.  Each file is a complete recording: its drops are counted within its span, and its
``ambdaq.snapshot`` metadata says what fired, when, and the span.
"""

from __future__ import annotations

import queue
import time
from collections import deque
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from ..drivers.signals import Event, SampleBlock, SignalGroup
from ..errors import BadInputError
from .acquisition import Acquisition, Sink
from .files import RecordingFiles
from .sequence import SampleCounts, Verdict
from .touchdowns import RECORD as DROP_RECORD, TAIL_S, DropRecords, DropSamples
from .triggers import Firing, Trigger
from .writer import RecordingWriter

SEGMENT_S = 0.2  # received blocks are joined into segments of this span, so a ring is a few hundred arrays
LATE_S = 0.5  # kept beyond pre_s: a trigger judged on one device's samples or events that arrive late
# (a serial line's latency, a clock map's correction) still finds the other devices' pre_s in memory
GATHER_BLOCKS = 256  # ... or of this many blocks, so a device that sends one sample a block costs little
HELD_OVERHEAD = 2048  # bytes counted for each held segment or block beside its arrays (9 array headers, objects)


def sample_bytes(groups: list[SignalGroup]) -> int:
    """Bytes one held sample takes: its fields (float64), device and host time (int64), seq and
    status (uint32), and its loss counts (int64 lost, int32 duplicates, two flags)."""
    return 8 * sum(len(g.fields) for g in groups) + 8 + 8 + 4 + 4 + 8 + 4 + 1 + 1


@dataclass(frozen=True)
class SnapshotOptions:
    """``--snapshot``.

    Parameters
    ----------
    pre_s : float
        Seconds kept before a trigger, in s.
    post_s : float
        Seconds written after it, in s.
    max_bytes : int
        Most bytes the rings may hold (all devices together).
    triggers : list of Trigger
        Parsed, not yet armed.
    cmin_m : float, optional
        Minimum clearance for the excursion and touchdown triggers, in m; default: the devices'
        calibration.
    """

    pre_s: float
    post_s: float
    max_bytes: int
    triggers: list[Trigger]
    cmin_m: float | None = None


def drop_bound(drops: DropRecords, rate_hz: float, options: SnapshotOptions) -> int:
    """The most bytes the snapshot files hold at once for their drops (:class:`DropSamples`), the gap's
    device sampling at ``rate_hz`` (Hz): a file keeps them from its first contact (and ``TAIL_S``
    and one ring segment before it) to its span's end, ``pre_s + post_s``; a file still being
    finished and the next overlap by at most ``pre_s`` and ``LATE_S``."""
    span = 2 * options.pre_s + options.post_s + LATE_S + TAIL_S + SEGMENT_S
    return int(np.ceil(rate_hz * span)) * drops.bytes_per_sample


def memory_bound(rated: list[tuple[float, list[SignalGroup]]], options: SnapshotOptions) -> int:
    """The most bytes the rings will hold for devices of known sample rate (Hz) and signal groups:
    ``pre_s`` and ``LATE_S`` plus two segments of samples each (a ring keeps the segment that reaches
    back past them and gathers the next), the overhead of those segments (at worst one per
    ``GATHER_BLOCKS`` samples) and of the blocks being gathered; devices with no rate are bounded by
    ``max_bytes`` alone."""
    total = 0
    for rate, groups in rated:
        span = options.pre_s + LATE_S + 2 * SEGMENT_S
        samples = int(np.ceil(rate * span))
        segments = int(np.ceil(span / SEGMENT_S)) + samples // GATHER_BLOCKS + 1
        total += samples * sample_bytes(groups) + (segments + GATHER_BLOCKS) * HELD_OVERHEAD
    return total


@dataclass
class _Held:
    """Kept samples of one device on the host clock, with what was lost just before each."""

    block: SampleBlock
    lost: np.ndarray  # int64: samples lost just before this one
    duplicates: np.ndarray  # int32: duplicates dropped just before this one
    wrapped: np.ndarray  # bool
    restarted: np.ndarray  # bool

    @classmethod
    def judged(cls, block: SampleBlock, verdict: Verdict) -> "_Held":
        """The kept samples of ``block``; what happened at a dropped duplicate goes to the next kept sample
        (or the last, at the block's end)."""
        keep = verdict.keep
        kept = block if keep.all() else block.select(keep)
        if kept.status is None:
            kept = SampleBlock(kept.device_time_ns, kept.seq, kept.values, kept.host_time_ns, kept.received_ns,
                               np.zeros(len(kept), dtype=np.uint32))
        idx = np.flatnonzero(keep)

        def attributed(a: np.ndarray, dtype) -> np.ndarray:
            if keep.all():
                return a.astype(dtype, copy=False)
            c = np.cumsum(a.astype(np.int64))
            upto = c[idx]
            out = np.diff(upto, prepend=0)
            if out.size:
                out[-1] += c[-1] - upto[-1]
            return out.astype(dtype)

        return cls(kept, attributed(verdict.lost, np.int64), attributed(~keep, np.int32),
                   attributed(verdict.wrapped, np.int64) > 0, attributed(verdict.restarted, np.int64) > 0)

    def __len__(self) -> int:
        return len(self.block)

    @property
    def nbytes(self) -> int:
        b = self.block
        arrays = [b.device_time_ns, b.seq, b.host_time_ns, b.status, self.lost, self.duplicates, self.wrapped,
                  self.restarted, *b.values.values()]
        return sum(a.nbytes for a in arrays) + HELD_OVERHEAD

    def slice(self, start: int, stop: int) -> "_Held":
        return _Held(self.block.slice(start, stop), self.lost[start:stop], self.duplicates[start:stop],
                     self.wrapped[start:stop], self.restarted[start:stop])

    def owned(self) -> "_Held":
        """A copy of every array that is a view, so what is held is exactly what is counted and a
        piece of a long block can be let go without the rest."""
        def own(a: np.ndarray) -> np.ndarray:
            return a if a.base is None else a.copy()

        b = self.block
        return _Held(SampleBlock(own(b.device_time_ns), own(b.seq), {k: own(v) for k, v in b.values.items()},
                                 own(b.host_time_ns), b.received_ns, own(b.status)),
                     own(self.lost), own(self.duplicates), own(self.wrapped), own(self.restarted))

    @staticmethod
    def join(parts: list["_Held"]) -> "_Held":
        if len(parts) == 1:
            return parts[0]
        b = [p.block for p in parts]
        block = SampleBlock(np.concatenate([x.device_time_ns for x in b]), np.concatenate([x.seq for x in b]),
                            {k: np.concatenate([x.values[k] for x in b]) for k in b[0].values},
                            np.concatenate([x.host_time_ns for x in b]), b[-1].received_ns,
                            np.concatenate([x.status for x in b]))
        return _Held(block, *(np.concatenate([getattr(p, a) for p in parts])
                              for a in ("lost", "duplicates", "wrapped", "restarted")))

    def counts(self, device: str, first_in_file: bool) -> SampleCounts:
        """Its counts as written to a file; the losses before a file's first sample are outside the file."""
        lost = self.lost[1:] if first_in_file else self.lost
        dups = self.duplicates[1:] if first_in_file else self.duplicates
        b = self.block
        return SampleCounts(device, samples=len(self), drops=int(lost.sum()), duplicates=int(dups.sum()),
                            wraps=int(np.count_nonzero(self.wrapped)), restarts=int(np.count_nonzero(self.restarted)),
                            first_seq=int(b.seq[0]), last_seq=int(b.seq[-1]),
                            first_time=int(b.host_time_ns[0]), last_time=int(b.host_time_ns[-1]))


class _Ring:
    """One device's held samples: joined segments, then the blocks of the segment being gathered."""

    def __init__(self) -> None:
        self.segments: deque[_Held] = deque()
        self.gathering: list[_Held] = []
        self.nbytes = 0
        self.newest_ns: int | None = None

    def add(self, held: _Held) -> None:
        t = held.block.host_time_ns
        self.newest_ns = int(t[-1])
        span = int(SEGMENT_S * 1e9)
        if t[-1] - t[0] >= span:  # a long block: segments of its own, so its oldest part can go first
            self._seal()
            cuts = np.searchsorted(t, t[0] + span * np.arange(1, (t[-1] - t[0]) // span + 1), "left")
            for a, b in zip([0, *cuts.tolist()], [*cuts.tolist(), len(held)]):
                if b > a:
                    piece = held.slice(a, b).owned()
                    self.segments.append(piece)
                    self.nbytes += piece.nbytes
            return
        held = held.owned()
        self.gathering.append(held)
        self.nbytes += held.nbytes
        first = int(self.gathering[0].block.host_time_ns[0])
        if self.newest_ns - first >= span or len(self.gathering) >= GATHER_BLOCKS:
            self._seal()

    def _seal(self) -> None:
        """The blocks gathered so far become one segment."""
        if not self.gathering:
            return
        joined = _Held.join(self.gathering)
        self.nbytes += joined.nbytes - sum(h.nbytes for h in self.gathering)
        self.segments.append(joined)
        self.gathering = []

    def all(self) -> list[_Held]:
        return [*self.segments, *self.gathering]

    def after(self, t_ns: int, end_ns: int) -> list[_Held]:
        """Held samples with host time in (t_ns, end_ns), oldest first; searched from the newest, so
        catching a snapshot up with the last block costs one look, not the whole ring."""
        out = []
        for h in reversed(self.all()):
            t = h.block.host_time_ns
            if t[-1] <= t_ns:
                break
            if t[0] >= end_ns:
                continue
            a, b = int(np.searchsorted(t, t_ns, "right")), int(np.searchsorted(t, end_ns, "left"))
            if b > a:
                out.append(h if (a, b) == (0, len(h)) else h.slice(a, b))
        return out[::-1]

    def evict_before(self, t_ns: int) -> None:
        """Drop the segments that end before ``t_ns``."""
        while self.segments and self.segments[0].block.host_time_ns[-1] < t_ns:
            self.nbytes -= self.segments.popleft().nbytes

    def oldest_ns(self) -> int | None:
        return int(self.segments[0].block.host_time_ns[0]) if self.segments else None


@dataclass
class _Capture:
    """One snapshot file being written: [start_ns, end_ns) of every device."""

    writer: RecordingWriter
    start_ns: int
    end_ns: int
    firings: list[Firing]
    done: dict[str, int] = field(default_factory=dict)  # device -> host time of its last sample written
    first_ns: int | None = None  # host time of the earliest sample written (after start_ns where the recording began later)
    drop: DropSamples | None = None  # what it holds of the gap's device, as its drop needs it


class Snapshots(Sink):
    """The rings, the triggers and the snapshot files of one recording (see the module docstring).

    Parameters
    ----------
    options : SnapshotOptions
        Pre and post time, memory, triggers (armed by the caller).
    files : RecordingFiles
        Opens each snapshot file with the session's metadata and devices, and finishes it.
    output : Path
        What the files are named after (:func:`snapshot_name`).
    on_snapshot : callable, optional
        Called with (path, firing) when a snapshot file is opened.
    flush_interval_s : float
        Longest wall time between the open files' chunk flushes, in s.
    drops : DropRecords, optional
        Characterises the rotor drop in each file as it is finished (:mod:`.touchdowns`): the
        file then holds ``ambdaq.touchdown``.
    """

    def __init__(self, options: SnapshotOptions, files: RecordingFiles, output: Path,
                 on_snapshot: Callable[[Path, Firing], None] | None = None, flush_interval_s: float = 0.5,
                 drops: DropRecords | None = None) -> None:
        self.options = options
        self._pre_ns, self._post_ns = int(options.pre_s * 1e9), int(options.post_s * 1e9)
        self._files, self._output, self._on_snapshot = files, Path(output), on_snapshot
        self._drops = drops if drops is not None and drops.possible else None
        self._flush_interval_s, self._last_flush = flush_interval_s, 0.0
        self._rings: dict[str, _Ring] = {}
        self._events: deque[tuple[str, int, Event]] = deque()
        self._ended: set[str] = set()
        self._open: list[_Capture] = []
        self._manual: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.files: list[Path] = []
        self.finished_bytes = 0
        self.peak_bytes = 0
        self.drop_peak_bytes = 0  # bytes the open files held of their drops (DropSamples), at most
        self.evicted_early = 0  # segments dropped for the byte limit before they were pre_s old

    def trigger(self, cause: str = "manual") -> None:
        """Fire the manual trigger now (thread- and signal-safe: SimpleQueue.put): a key press,
        SIGUSR1, a notebook's call.  It fires at the acquisition thread's next tick."""
        self._manual.put(cause)

    # --- the sink ----------------------------------------------------------------------------------

    def start(self, acquisition: Acquisition) -> None:
        self._rings = {d: _Ring() for d in acquisition.names}
        self._last_flush = acquisition.t0

    def block(self, device: str, block: SampleBlock, verdict: Verdict) -> None:
        """A judged block on the host clock: held, shown to the triggers, written to the open snapshots."""
        held = _Held.judged(block, verdict)
        if not len(held):
            return
        self._rings[device].add(held)
        for trigger in self.options.triggers:
            for firing in trigger.on_block(device, held.block):
                self.fire(firing)
        for cap in self._open:
            self._catch_up(cap, device)
        self._evict()
        self._close_passed()

    def event(self, device: str, t_ns: int, event: Event) -> None:
        """An event at host time ``t_ns``: held, shown to the triggers, written to the snapshots it falls in."""
        self._events.append((device, t_ns, event))
        for cap in self._open:
            if cap.start_ns <= t_ns < cap.end_ns:
                cap.writer.write_event(event.topic, device, t_ns, event)
        for trigger in self.options.triggers:
            for firing in trigger.on_event(device, t_ns, event):
                self.fire(firing)

    def device_ended(self, device: str, missing: int) -> None:
        """The periods it never sent are outside every snapshot's span: not counted in a file."""
        self._ended.add(device)
        self._close_passed()

    def tick(self, now: float) -> None:
        self._take_manual()
        if now - self._last_flush >= self._flush_interval_s:
            for cap in self._open:
                cap.writer.flush()
            self._last_flush = now

    def close(self) -> None:
        """Fire what was asked for last, then finish every snapshot still open with what arrived."""
        self._take_manual()
        while self._open:
            self._finish_capture(self._open.pop(0))

    def abort(self) -> None:
        """Nothing was recorded: no snapshot file was opened."""

    def fire(self, firing: Firing) -> None:
        """Open a snapshot around ``firing`` or, if one still being written has not reached its end,
        extend that one."""
        for cap in self._open:
            if cap.start_ns <= firing.t_ns < cap.end_ns:
                old_end, cap.end_ns = cap.end_ns, max(cap.end_ns, firing.t_ns + self._post_ns)
                cap.firings.append(firing)
                for device, t, ev in self._events:
                    if old_end <= t < cap.end_ns:
                        cap.writer.write_event(ev.topic, device, t, ev)
                break
        else:
            path = snapshot_name(self._output, firing, lambda p: p.exists() or p in self.files)
            start = firing.t_ns - self._pre_ns
            end = firing.t_ns + self._post_ns
            cap = _Capture(self._files.open(path, start, f"snapshot {len(self.files)}"), start, end, [firing],
                           drop=None if self._drops is None else self._drops.samples(end))
            self.files.append(path)
            self._open.append(cap)
            for device, t, ev in self._events:
                if cap.start_ns <= t < cap.end_ns:
                    cap.writer.write_event(ev.topic, device, t, ev)
            if self._on_snapshot is not None:
                self._on_snapshot(path, firing)
        for device in self._rings:
            self._catch_up(cap, device)

    def _take_manual(self) -> None:
        """Fire what :meth:`trigger` was asked for since the last look."""
        while True:
            try:
                how = self._manual.get_nowait()
            except queue.Empty:
                return
            self.fire(Firing(time.time_ns(), "manual", f"manual trigger ({how})"))

    # --- figures ------------------------------------------------------------------------------------------

    @property
    def held_bytes(self) -> int:
        """Bytes the rings hold now."""
        return sum(r.nbytes for r in self._rings.values())

    @property
    def bytes_written(self) -> int:
        """Bytes in the snapshot files, finished and open."""
        return self.finished_bytes + sum(c.writer.bytes_written for c in self._open)

    # --- inside -------------------------------------------------------------------------------------------

    def _catch_up(self, cap: _Capture, device: str) -> None:
        """Write ``device``'s held samples that fall in the snapshot and are not in it yet."""
        for piece in self._rings[device].after(cap.done.get(device, cap.start_ns - 1), cap.end_ns):
            cap.writer.write(device, piece.block, piece.counts(device, device not in cap.done))
            cap.done[device] = int(piece.block.host_time_ns[-1])
            first = int(piece.block.host_time_ns[0])
            cap.first_ns = first if cap.first_ns is None else min(cap.first_ns, first)
            if cap.drop is not None and device == self._drops.device:
                cap.drop.add(piece.block)

    def _evict(self) -> None:
        for ring in self._rings.values():
            if ring.newest_ns is not None:
                ring.evict_before(ring.newest_ns - self._pre_ns - int(LATE_S * 1e9))
        held = self.held_bytes
        while held > self.options.max_bytes:  # the byte limit: the oldest segment of any device goes first
            oldest = min((r for r in self._rings.values() if r.segments), key=lambda r: r.oldest_ns(), default=None)
            if oldest is None:
                break
            held -= oldest.segments[0].nbytes
            oldest.nbytes -= oldest.segments.popleft().nbytes
            self.evicted_early += 1
        self.peak_bytes = max(self.peak_bytes, held)
        self.drop_peak_bytes = max(self.drop_peak_bytes, sum(c.drop.nbytes for c in self._open if c.drop is not None))
        newest = max((r.newest_ns for r in self._rings.values() if r.newest_ns is not None), default=None)
        while self._events and newest is not None and self._events[0][1] < newest - self._pre_ns - LATE_S * 1e9:
            self._events.popleft()

    def _close_passed(self) -> None:
        """Finish the snapshots every device still recording has passed the end of."""
        for cap in list(self._open):
            if all(d in self._ended or (r.newest_ns is not None and r.newest_ns >= cap.end_ns)
                   for d, r in self._rings.items()):
                self._open.remove(cap)
                self._finish_capture(cap)

    def _finish_capture(self, cap: _Capture) -> None:
        first = cap.firings[0]
        held = first.t_ns if cap.first_ns is None else cap.first_ns  # the earliest sample written
        when = datetime.fromtimestamp(first.t_ns / 1e9, timezone.utc).isoformat(timespec="microseconds")
        meta = {"cause": first.cause, "trigger_time": when, "trigger_ns": str(first.t_ns),
                "triggers": "; ".join(f"{f.cause} at {f.t_ns}: {f.detail}" for f in cap.firings),
                "pre_s": f"{self.options.pre_s:g}", "post_s": f"{self.options.post_s:g}",
                "start_ns": str(cap.start_ns), "end_ns": str(cap.end_ns),
                # what the file holds before the trigger: less than pre_s where the recording (or
                # the device) began after start_ns
                "pre_held_s": f"{max(0, first.t_ns - max(cap.start_ns, held)) / 1e9:g}"}
        drop = self._drops.record(cap.drop) if cap.drop is not None else None
        if drop is not None:
            cap.writer.add_metadata(DROP_RECORD, drop)
        self._files.finish(cap.writer, "ambdaq.snapshot", meta)
        self.finished_bytes += cap.writer.path.stat().st_size


def snapshot_name(output: Path, firing: Firing, taken: Callable[[Path], bool]) -> Path:
    """``NAME_<UTC time of the trigger, ms>_<cause>.mcap`` beside ``output``; ``_2`` ... if taken."""
    stamp = datetime.fromtimestamp(firing.t_ns / 1e9, timezone.utc).strftime("%Y%m%dT%H%M%S.%f")[:-3] + "Z"
    base = f"{output.stem}_{stamp}_{firing.cause}"
    path = output.with_name(base + (output.suffix or ".mcap"))
    k = 2
    while taken(path):
        path = output.with_name(f"{base}_{k}{output.suffix or '.mcap'}")
        k += 1
    return path


def check_memory(bound: int, options: SnapshotOptions) -> None:
    """BadInputError (exit 2, before recording) if ``pre_s`` of the devices (and the files' drops)
    need more than ``max_bytes``."""
    if bound > options.max_bytes:
        raise BadInputError(f"--snapshot {options.pre_s:g}s of these devices needs up to {bound / 1e6:.0f} MB, more "
                            f"than --snapshot-memory {options.max_bytes / 1e6:.0f} MB: give a shorter snapshot "
                            "or more memory")


__all__ = ["SnapshotOptions", "Snapshots", "drop_bound", "memory_bound", "sample_bytes", "snapshot_name", "check_memory"]
