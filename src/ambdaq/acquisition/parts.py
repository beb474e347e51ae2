"""The files of a recording as a sink of its acquisition: one file, or parts cut on the host clock
(``--split-duration``) or by size (``--split-size``), each holding exactly its stretch of every
device.

Parts are cut at ``start + k * split_duration`` (or where a part reached ``split_size``); each
sample goes to the part its time falls in, and so does each sample period a device never sent: a
lost period is due where its ``seq`` puts it between the samples around it (evenly spaced), so a
run of losses across a part's start is counted partly in each part.  A part stays open until every device has written a
sample past its end (or ended), so a device whose samples arrive late (a serial line whose clock
map is still settling) still lands in the right file.  Every open file's chunk is closed and handed
to the OS at least every ``flush_interval`` seconds of wall time, and forced to the disk (fsync)
on a thread of its own right after, so a killed recorder loses at most that much data and a power
cut that much plus the time the disk takes to sync (docs/data-format.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..drivers.signals import Event, SampleBlock
from .acquisition import Acquisition, Sink
from .files import RecordingFiles
from .sequence import Verdict
from .writer import RecordingWriter

SIZE_CHECK = 1000  # samples between two looks at the size of the newest part (--split-size)


def split_names(output: Path, split: bool) -> Callable[[int], Path]:
    """File name for part ``i``: the output itself, or ``NAME_000.mcap`` ... when splitting."""
    if not split:
        return lambda i: output
    return lambda i: output.with_name(f"{output.stem}_{i:03d}{output.suffix or '.mcap'}")


@dataclass
class _Part:
    """One output file and the stretch of host time it holds: [start_ns, end_ns)."""

    index: int
    writer: RecordingWriter
    start_ns: int
    end_ns: int | None  # None: the newest part, open-ended until a split decides its end
    earliest_ns: int | None = None  # its earliest sample's time, which a clock map can put before start_ns


def _due_before(x_ns: int, from_ns: int, span: float, steps: float, count: int) -> int:
    """How many of ``count`` periods due at from + j span / steps (j = 1 .. count) are due before
    host time ``x_ns`` (exact in integers where the arguments are)."""
    q = (x_ns - from_ns) * steps
    return 0 if q <= 0 else int(min(max(-(-q // span) - 1, 0), count))


@dataclass
class _Tail:
    """The ``missing`` periods a device never sent after its last sample at host time ``last_ns``,
    ``rate_hz`` of them a second; ``counted`` of them already in a part."""

    last_ns: int
    rate_hz: float
    missing: int
    counted: int = 0

    def due_before(self, t_ns: int) -> int:
        """How many of those not yet counted are due before host time ``t_ns``."""
        return max(_due_before(t_ns, self.last_ns, 1e9, self.rate_hz, self.missing) - self.counted, 0)


class FileParts(Sink):
    """Writes the judged samples and the events into the recording's file or parts.

    Parameters
    ----------
    files : RecordingFiles
        Opens and finishes each file.
    output : Path
        The file (``NAME_000.mcap`` ... when splitting).
    split_size : int or None
        Start a new file when the present one reaches this many bytes.
    split_duration_s : float or None
        Start a new file every this many seconds on the host clock, from the recording's start.
    flush_interval_s : float
        Longest wall time between chunk flushes (and disk syncs), in s.
    """

    def __init__(self, files: RecordingFiles, output: Path, *, split_size: int | None = None,
                 split_duration_s: float | None = None, flush_interval_s: float = 0.5) -> None:
        self.files = files
        self.split_size, self.split_duration_s, self.flush_interval_s = split_size, split_duration_s, flush_interval_s
        self.name = split_names(Path(output), split_size is not None or split_duration_s is not None)
        self.paths: list[Path] = []  # every file opened, in order
        self._parts: list[_Part] = []
        self._ended: set[str] = set()
        self._last: dict[str, int] = {}  # host time of each device's last sample handed to a part, ns
        self._tails: dict[str, _Tail] = {}  # periods an ended device never sent, not yet counted in a part
        self._last_flush = 0.0

    @property
    def bytes_written(self) -> int:
        """Bytes in the open files."""
        return sum(p.writer.bytes_written for p in self._parts)

    def next_split_s(self, now_ns: int) -> float | None:
        """Seconds to the next file of a recording split by duration, else None."""
        if self.split_duration_s is None:
            return None
        period = self.split_duration_s * 1e9
        since = now_ns - self.acq.start_ns
        return ((since // period + 1) * period - since) * 1e-9

    # --- the sink --------------------------------------------------------------------------------

    def start(self, acquisition: Acquisition) -> None:
        self.acq = acquisition
        self._rates = {s.name: s.sample_rate for s in acquisition.sources}
        self._last_flush = acquisition.t0
        self._open(acquisition.start_ns)

    def block(self, device: str, block: SampleBlock, verdict: Verdict) -> None:
        """The judged block's kept samples, each into the part its time falls in."""
        n, t = len(block), block.host_time_ns
        before = self._last.get(device)
        pos = 0
        while pos < n:
            part = self._part_for(int(t[pos]))
            end = n if part.end_ns is None else pos + int(np.searchsorted(t[pos:], part.end_ns, "left"))
            end = max(end, pos + 1)
            if self.split_size is not None and part.end_ns is None:
                end = min(end, pos + SIZE_CHECK)
            sl = slice(pos, end)
            keep = verdict.keep[sl]
            piece = block.slice(pos, end)
            counts = verdict.counts(device, sl, block.seq, t)
            counts.drops -= self._lost_before(device, part, int(verdict.lost[pos]),
                                              int(t[pos - 1]) if pos else before, int(t[pos]))
            part.writer.write(device, piece if keep.all() else piece.select(keep), counts)
            if keep.any():
                first = int(t[sl][keep].min())
                part.earliest_ns = first if part.earliest_ns is None else min(part.earliest_ns, first)
            if self.split_size is not None and part.end_ns is None and part.writer.bytes_written >= self.split_size:
                part.end_ns = int(t[end - 1]) + 1
            pos = end
        if n:
            self._last[device] = int(t[-1])
        if self._tails:
            self._count_tails()
        self._close_finished()

    def _lost_before(self, device: str, part: _Part, lost: int, prev_ns: int | None, now_ns: int) -> int:
        """Of the ``lost`` periods ``device`` never sent between its samples at host times
        ``prev_ns`` and ``now_ns`` (the latter in ``part``), those due before ``part`` began are
        counted as drops of the open parts they were due in; returns how many.  The j-th of them is
        due at prev + j (now - prev) / (lost + 1)."""
        if not lost or prev_ns is None or prev_ns >= part.start_ns or now_ns <= prev_ns:
            return 0
        span = now_ns - prev_ns
        moved = 0
        for earlier in self._parts:
            if earlier is part or earlier.end_ns is None:
                break
            k = (_due_before(earlier.end_ns, prev_ns, span, lost + 1, lost)
                 - _due_before(earlier.start_ns, prev_ns, span, lost + 1, lost))
            if k:
                earlier.writer.lost_at_end(device, k)
                moved += k
        return moved

    def event(self, device: str, t_ns: int, event: Event) -> None:
        self._part_for(t_ns).writer.write_event(event.topic, device, t_ns, event)

    def device_ended(self, device: str, missing: int) -> None:
        """The ``missing`` periods ``device`` never sent after its last sample are drops of the parts
        they were due in: the j-th at last + j / rate on the host clock (a device with no sample
        kept, or no rate, has them all in the part the recording starts in)."""
        if missing:
            last, rate = self.acq.last_time(device), self._rates.get(device)
            if last is None or not rate:
                self._parts[0].writer.lost_at_end(device, missing)
            else:
                self._tails[device] = _Tail(last, rate, missing)
                self._count_tails()
        self._ended.add(device)
        self._close_finished()

    def _count_tails(self) -> None:
        """Each ended device's missing periods due in a part whose end is known are counted there;
        the rest wait for the parts still to come (or, at the close, go to the last part)."""
        for device, tail in list(self._tails.items()):
            for part in self._parts:
                if part.end_ns is None:
                    break
                k = tail.due_before(part.end_ns)
                if k:
                    part.writer.lost_at_end(device, k)
                    tail.counted += k
            if tail.counted == tail.missing:
                del self._tails[device]

    def tick(self, now: float) -> None:
        if now - self._last_flush >= self.flush_interval_s:
            for part in self._parts:
                part.writer.flush()
            self._last_flush = now

    def close(self) -> None:
        for device, tail in self._tails.items():  # due after the last part's start: the recording ended there
            self._parts[-1].writer.lost_at_end(device, tail.missing - tail.counted)
        self._tails.clear()
        for part in self._parts:
            self._finish(part)
        self._parts.clear()

    def abort(self) -> None:
        for part in self._parts:
            part.writer.close()
            part.writer.path.unlink(missing_ok=True)
        self._parts.clear()

    # --- inside ----------------------------------------------------------------------------------

    def _open(self, start_ns: int) -> _Part:
        index = len(self.paths)
        end = None
        if self.split_duration_s is not None:
            end = self.acq.start_ns + int(round((index + 1) * self.split_duration_s * 1e9))
        part = _Part(index, self.files.open(self.name(index), start_ns, str(index)), start_ns, end)
        self.paths.append(part.writer.path)
        self._parts.append(part)
        return part

    def _part_for(self, t_ns: int) -> _Part:
        """The part that holds host time ``t_ns``, opening parts up to it (split by duration);
        a time before the oldest open part goes to that part."""
        while True:
            newest = self._parts[-1]
            if newest.end_ns is None or t_ns < newest.end_ns:
                break
            self._open(newest.end_ns)
        for part in self._parts:
            if part.end_ns is None or t_ns < part.end_ns:
                return part
        return self._parts[-1]

    def _close_finished(self) -> None:
        """Close every part but the newest once each device has passed its end or ended."""
        while len(self._parts) > 1:
            oldest = self._parts[0]
            if any(name not in self._ended and ((last := self.acq.last_time(name)) is None or last < oldest.end_ns)
                   for name in self.acq.names):
                return
            self._finish(self._parts.pop(0))

    def _finish(self, part: _Part) -> None:
        """Its host-time span, clock fits and link statistics go into the part's metadata, then it is
        finished.  The span starts at its earliest sample where that is before the part's start: a
        time before the oldest open part goes to that part (:meth:`_part_for`), and a device's
        clock map, fitted online, can put its first samples a millisecond or two before the
        recording's start under load (a span that did not hold them would be a wrong statement)."""
        start = part.start_ns if part.earliest_ns is None else min(part.start_ns, part.earliest_ns)
        self.files.finish(part.writer, "ambdaq.part", {
            "index": str(part.index), "start_ns": str(start),
            "end_ns": "" if part.end_ns is None else str(part.end_ns)})


__all__ = ["FileParts", "split_names"]
