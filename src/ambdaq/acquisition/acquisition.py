"""Acquisition: devices read on threads of their own, their clocks mapped to the host's, every
sample judged, and what comes of it handed to sinks (python-can's Notifier and its Listeners are
the model).

Each device is read on its own thread into one bounded queue; the calling thread takes the
blocks in the order they arrived, maps device time to host time (:mod:`.clock`), counts sequence
numbers exactly (:mod:`.sequence`: a gap is a drop, a repeat a duplicate, never interpolated) and
hands each judged, host-timed block and each event to every :class:`Sink`: the files of a
recording (:mod:`.parts`), the rings of a snapshot recording (:mod:`.snapshot`), the live view.
What a sink does with it is its own affair; the acquisition keeps the counts of every device.

Ctrl-C (or SIGTERM) stops the devices and lets every sink finish; a second one stops waiting for
the devices.  While it runs, the objects that existed when it started are frozen out of Python's
full garbage collections (``gc.freeze``): with numpy, scipy, numba and canopen loaded, one such
pass holds the GIL for about 100 ms, long enough for device threads (and an in-process simulated
rig) to miss SYNCs.
"""

from __future__ import annotations

import gc
import os
import queue
import signal
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..drivers.interfaces import Source
from ..drivers.signals import Event, SampleBlock
from ..errors import AmbdaqError, DeviceError
from .clock import MAX_DRIFT_PPM, ClockMap
from .sequence import SampleCounts, SequenceTracker, Verdict

QUEUE_BLOCKS = 64  # blocks in flight between device threads and the acquisition's thread
STOP_WAIT_S = 0.5  # after a stop, how long the devices' last blocks are waited for
PROVISIONAL_S = 0.5  # a device's first blocks wait for this much of its clock pairs (an offset from more than one)
TICK_S = 0.1  # the longest the acquisition's thread waits for a block before it looks at the time
REPEAT_GRACE_S = 2.0
"""After a stop by Ctrl-C or SIGTERM, the same signal within this long is taken as the same stop
repeated (a double press), not as an interrupt of what the caller does next (closing the devices,
printing the summary): the files are whole by then.  Later ones reach the handler there was before."""


class ClockRefused(DeviceError):
    """A device whose time stamps cannot be its clock (:attr:`.clock.ClockMap.problem`): its
    samples are not timed by them, and the recording stops with this line."""


class Sink:
    """Takes what an :class:`Acquisition` judged.  Every method runs on the acquisition's thread
    and must be quick; the defaults do nothing."""

    def start(self, acquisition: Acquisition) -> None:
        """The acquisition starts (its ``start_ns`` and devices are set; nothing was received)."""

    def received(self, device: str, block: SampleBlock) -> None:
        """A block as it was received, before its clock is mapped or its samples judged (a live
        view keeps a reference: it need not wait for the clock map)."""

    def block(self, device: str, block: SampleBlock, verdict: Verdict) -> None:
        """A judged block on the host clock (``host_time_ns`` set): ``verdict`` says which samples
        to keep and what was lost before each."""

    def event(self, device: str, t_ns: int, event: Event) -> None:
        """An event of ``device`` at host time ``t_ns``."""

    def device_ended(self, device: str, missing: int) -> None:
        """``device`` has ended; it never sent the last ``missing`` sample periods it was asked for
        (drops after its last sample)."""

    def tick(self, now: float) -> None:
        """Called at least every ``TICK_S`` seconds (``now``: ``time.monotonic()``): flush, time out."""

    def close(self) -> None:
        """The recording has ended: finish."""

    def abort(self) -> None:
        """The recording never started (a device failed to start): remove what was made."""


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
                # bounded queue: a source faster than the sinks (unpaced simulation) waits; after
                # a stop the acquisition drains the queue until every reader has ended
                self.q.put((self.source, block))
        except Exception as err:  # report, the acquisition's thread decides
            self.q.put((self.source, err))
        self.q.put((self.source, _Ended(complete)))


def _after_stop(old, until: float) -> Callable:
    """The handler a stop signal gets back after a stopped run: until ``until`` (monotonic s) the
    signal is the same stop repeated and does nothing; after it, the ``old`` handler again."""

    def handler(signum, frame) -> None:
        if time.monotonic() < until:
            return
        signal.signal(signum, old)  # as before, from now on
        if callable(old):
            old(signum, frame)
        elif old == signal.SIG_DFL:
            os.kill(os.getpid(), signum)

    return handler


def _freeze_heap(sources: list[Source]) -> bool:
    """Where a device is paced by the wall clock: leave every object that exists now out of the
    collector's full passes until the acquisition ends (``gc.freeze``).  After numpy, scipy, numba
    and canopen are loaded a full collection walks about 150,000 objects with the GIL held: 90-100
    ms here, in which no device thread runs (measured: 64-148 CAN samples of a simulated rig lost
    at the start of a recording).  Objects made during the recording are collected as usual.
    Nothing is collected first: that would be the same pause once, at the start (and seconds in a
    process that holds more, as a test runner does); garbage that exists now waits for the end of
    the recording.  A run of unpaced sources only (``sim generate``) loses nothing to a pause and
    is left alone, and so is a heap the host process froze itself (a server that froze what it
    loaded before it forks): ``gc.unfreeze`` would thaw every frozen object, the host's too.
    Returns whether it froze (and is to thaw at the end)."""
    if gc.get_freeze_count() or not any(s.paced for s in sources):
        return False
    gc.freeze()
    return True


class Acquisition:
    """Read ``sources`` until the duration is reached, every device ends, or the user stops, and hand
    what they send to sinks (see the module docstring).

    Parameters
    ----------
    sources : list of Source
        Devices, already opened; the acquisition closes them when it ends.
    duration_s : float or None
        In s of device time (a device with a nominal rate is asked for that many sample periods;
        the others are closed after that much host time); None: until stopped.
    reconnect : bool
        Reopen a device that is lost instead of ending.
    start_ns : int, optional
        The start on the host clock, ns since the epoch; default: now.  Only for sources that
        share the host clock without stamping it (a generated recording dated in a simulated past).
    """

    def __init__(self, sources: list[Source], *, duration_s: float | None = None, reconnect: bool = False,
                 start_ns: int | None = None) -> None:
        self.sources = sources
        self.names = [s.name for s in sources]
        self.duration_s, self.reconnect, self._given_start = duration_s, reconnect, start_ns
        self.start_ns = start_ns if start_ns is not None else time.time_ns()
        self.by_samples = {s.name: s.sample_rate is not None and s.duration_in_samples for s in sources}
        self.due = {s.name: int(round(duration_s * s.sample_rate)) if self.by_samples[s.name] and duration_s is not None
                    else None for s in sources}
        self.totals = {name: SampleCounts(name) for name in self.names}
        self.clocks: dict[str, ClockMap] = {}
        self.refused: dict[str, str] = {}  # devices whose time stamps are no clock, and why
        self.host_clocked: set[str] = set()
        self.events = 0
        self.stopped_by_user = False
        self._trackers = {name: SequenceTracker() for name in self.names}
        self._held: dict[str, list[SampleBlock]] = {}  # a device's first blocks, before its map has PROVISIONAL_S
        self._last_time: dict[str, int | None] = {name: None for name in self.names}
        self._sinks: list[Sink] = []
        self.t0 = time.monotonic()

    # --- the run ---------------------------------------------------------------------------------

    def run(self, sinks: list[Sink], *, on_stopping: Callable[[], None] | None = None,
            signals: dict[int, Callable] | None = None) -> Exception | None:
        """Record into ``sinks`` until the duration, the devices' end or a stop.

        Parameters
        ----------
        sinks : list of Sink
            Where the judged blocks and events go, in order.
        on_stopping : callable, optional
            Called once, at once, when the user stops (Ctrl-C, SIGTERM).
        signals : dict, optional
            More signal handlers to install while running (a snapshot's SIGUSR1), signal -> handler.

        Returns
        -------
        Exception or None
            What a device failed with while it was read (the sinks were closed cleanly first), or
            None.  A device that fails to start raises, with nothing recorded.
        """
        self._sinks = sinks
        q: queue.Queue = queue.Queue(maxsize=QUEUE_BLOCKS)
        stop = threading.Event()
        self.start_ns = self._given_start if self._given_start is not None else time.time_ns()
        by_time = [s for s in self.sources if not self.by_samples[s.name]]  # closed after the duration's host time
        readers = [_Reader(s, q, stop, self.reconnect) for s in self.sources]
        failure: Exception | None = None
        # Ctrl-C and SIGTERM only raise a flag: the loop stops between blocks, never mid-write; a
        # second one stops the wait for the devices' last blocks
        count = [0]
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            def on_signal(signum, frame) -> None:
                count[0] += 1

            for sig, handler in {signal.SIGINT: on_signal, signal.SIGTERM: on_signal, **(signals or {})}.items():
                handlers[sig] = signal.signal(sig, handler)
        self.t0 = time.monotonic()
        thaw = _freeze_heap(self.sources)
        try:
            for sink in sinks:
                sink.start(self)
            started = {}  # a device closed by host time gets the duration from its own start, however long
            for s in self.sources:  # the others took to start (0 rows of a CAN page in 0.5 s on a loaded host)
                s.start(self.due[s.name])
                started[s.name] = time.monotonic()
        except BaseException:  # nothing recorded: every device is closed, nothing empty is left
            if thaw:
                gc.unfreeze()
            self._close_sources()
            for sink in sinks:
                sink.abort()
            for sig, old in handlers.items():
                signal.signal(sig, old)
            raise
        try:
            for r in readers:
                r.start()
            live = len(readers)
            while live and not count[0]:
                try:
                    source, item = q.get(timeout=TICK_S)
                except queue.Empty:
                    source, item = None, None
                if isinstance(item, Exception):
                    failure = item
                    break
                if isinstance(item, _Ended):
                    live -= 1
                    self._end_device(source.name, self.due[source.name] if item.complete else None)
                else:
                    try:
                        self._take(source, item)
                    except ClockRefused as err:
                        failure = err
                        break
                now = time.monotonic()
                if by_time and self.duration_s is not None:
                    due = [s for s in by_time if now - started[s.name] >= self.duration_s]
                    for s in due:
                        s.close()  # its reader ends: the block it was reading is written
                    by_time = [s for s in by_time if s not in due]
                for sink in sinks:
                    sink.tick(now)
            if count[0] and on_stopping is not None:
                on_stopping()
        finally:
            self.stopped_by_user = bool(count[0])
            stop.set()
            closer = threading.Thread(target=self._close_sources, name="close-devices", daemon=True)
            closer.start()
            # what the devices read until they stopped is written, not lost
            deadline = time.monotonic() + STOP_WAIT_S
            while any(r.is_alive() for r in readers) and time.monotonic() < deadline and count[0] < 2:
                self._drain(q)
                time.sleep(0.005)
            self._drain(q)
            for name in list(self._held):
                self._flush_held(name)
            for s in self.sources:
                self._take_events(s)
            for sink in sinks:
                sink.close()
            while closer.is_alive() and count[0] < 2:
                closer.join(0.1)
            until = time.monotonic() + REPEAT_GRACE_S
            for sig, old in handlers.items():
                signal.signal(sig, _after_stop(old, until) if count[0] and sig in (signal.SIGINT, signal.SIGTERM) else old)
            if thaw:
                gc.unfreeze()
        return failure

    @property
    def elapsed_s(self) -> float:
        """Host time since the run began, s."""
        return time.monotonic() - self.t0

    def _close_sources(self) -> None:
        for s in self.sources:
            try:
                s.close()
            except Exception:  # a device that fails to close must not keep the others open
                pass

    def _end_device(self, name: str, due: int | None) -> None:
        """``name`` has ended; if it delivered the ``due`` periods it was asked for, the ones it
        never sent after its last sample are drops."""
        self._flush_held(name)
        missing = self._trackers[name].missing_after(due) if due is not None else 0
        self.totals[name].drops += missing
        for sink in self._sinks:
            sink.device_ended(name, missing)

    def _take(self, source: Source, item) -> None:
        if isinstance(item, Event):
            self._event(source.name, time.time_ns(), item)
        elif item is not None:
            for sink in self._sinks:
                sink.received(source.name, item)
            self._ingest(source, item)
            self._take_events(source)

    def _drain(self, q: queue.Queue) -> None:
        """Blocks already read when the recording stopped are written, not lost."""
        while True:
            try:
                source, item = q.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, SampleBlock) and len(item) and source.name not in self.refused:
                try:
                    self._ingest(source, item)
                except ClockRefused:
                    pass  # said once, where it was found

    # --- clocks ----------------------------------------------------------------------------------

    def _ingest(self, source: Source, block: SampleBlock) -> None:
        """Map a block to the host clock and judge it.

        Blocks that say when they arrived feed the device's online clock map (offset and drift).
        The first ``PROVISIONAL_S`` of a device wait for an offset from more than one pair; then
        every block is judged at once, until the drift is estimated (3 s of pairs) through the
        offset alone, from the fastest pair so far.  Holding them the whole 3 s had cost a
        process killed in its first seconds every sample of such a device; how far later fits
        move those early times is measured and reported (the map's revision, :mod:`.clock`).  In-process
        sources without arrival times start their clock at 0 when the recording starts, so their
        mapping is the start offset.
        """
        device = source.name
        if block.host_time_ns is not None:  # the device's times are host times (CAN bus stamps)
            self.host_clocked.add(device)
            self._judge(device, block)
            return
        if block.received_ns is None:
            host = block.device_time_ns + self.start_ns
            self._judge(device, SampleBlock(block.device_time_ns, block.seq, block.values, host, status=block.status))
            return
        cm = self.clocks.setdefault(device, ClockMap())
        pairs = source.clock_pairs()
        for d, h in pairs if pairs is not None else [(int(block.device_time_ns[-1]), block.received_ns)]:
            cm.update(d, h)
        if cm.problem is not None:  # never squeezed onto the host clock: not recorded, and said
            lost = sum(len(b) for b in self._held.pop(device, [])) + len(block)
            self.refused[device] = cm.problem
            raise ClockRefused(f"{device}: its time stamps cannot be its clock ({cm.problem}; a crystal keeps "
                               f"within {MAX_DRIFT_PPM:,.0f} ppm): its last {lost} samples are not recorded and "
                               "the recording stops")
        latency = source.clock_latency_ns()
        if latency is not None:
            cm.latency_ns = latency
        self._held.setdefault(device, []).append(block)
        if cm.span_s >= PROVISIONAL_S or cm.settled:  # the first half second waits for an offset from more than one pair
            self._flush_held(device)

    def _flush_held(self, device: str) -> None:
        """Judge ``device``'s held blocks through its clock map as it is now."""
        cm = self.clocks.get(device)
        for b in self._held.pop(device, []):
            host = cm.to_host(b.device_time_ns)
            last = self._last_time[device]
            if last is not None:
                # a refit that moves the device's time back would put the block's first samples at
                # or before the last one judged: those (and only those) go just after it, 1 ns
                # apart, so time never runs back and every other sample keeps its best estimate
                host = np.maximum(host, last + 1 + np.arange(host.shape[0], dtype=np.int64))
            cm.written(int(b.device_time_ns[-1]), int(host[-1]))
            self._judge(device, SampleBlock(b.device_time_ns, b.seq, b.values, host, b.received_ns, b.status))

    def _judge(self, device: str, block: SampleBlock) -> None:
        """Judge the block's samples (:class:`~.sequence.SequenceTracker`) and hand it to the sinks."""
        n = len(block)
        if n == 0:
            return
        t = block.host_time_ns
        verdict = self._trackers[device].admit(block.seq, t)
        self.totals[device].add(verdict.counts(device, slice(0, n), block.seq, t))
        kept = np.flatnonzero(verdict.keep)
        if kept.size:
            self._last_time[device] = int(t[kept[-1]])
        for sink in self._sinks:
            sink.block(device, block, verdict)

    def _take_events(self, source: Source) -> None:
        for ev in source.events():
            cm = self.clocks.get(source.name)
            if ev.device_time_ns and cm is not None and cm.ready:
                t = int(cm.to_host(np.array([ev.device_time_ns]))[0])
            else:
                t = time.time_ns()
            self._event(source.name, t, ev)

    def _event(self, device: str, t_ns: int, ev: Event) -> None:
        self.events += 1
        for sink in self._sinks:
            sink.event(device, t_ns, ev)

    # --- what it can tell ------------------------------------------------------------------------

    def last_time(self, device: str) -> int | None:
        """Host time of ``device``'s last sample kept, ns, or None."""
        return self._last_time[device]

    def held_samples(self, device: str) -> int:
        """Samples of ``device`` received and waiting for its clock map."""
        return sum(len(b) for b in self._held.get(device, []))

    def clock_report(self) -> dict[str, dict]:
        """Each device's clock: its map's fit (drift, offset, uncertainty, revision, latency), or that
        it stamps the host clock itself."""
        out = {}
        for name, cm in self.clocks.items():
            fit = cm.fit()
            out[name] = {"drift_ppm": round(float(fit.drift_ppm), 3), "offset_ns": round(float(fit.offset_ns)),
                         "uncertainty_us": round(fit.uncertainty_ns * 1e-3, 3),
                         "revision_us": round(fit.revision_ns * 1e-3, 3), "points": fit.points,
                         "latency_us": round(fit.latency_ns * 1e-3, 3)}
            if cm.backwards:
                out[name]["backwards"] = cm.backwards
            if name in self.refused:
                out[name]["refused"] = self.refused[name]
            elif cm.suspect is not None:
                out[name]["suspect"] = cm.suspect
        for name in self.host_clocked:
            out[name] = {"host_clock": True, "uncertainty_us": 0.0}
        return out

    def alignment_us(self) -> float | None:
        """Estimated worst alignment between two devices: root sum square of the two largest map
        uncertainties (devices stamped on the host clock count as exact), in us."""
        u = sorted((c["uncertainty_us"] for c in self.clock_report().values() if c["uncertainty_us"] == c["uncertainty_us"]),
                   reverse=True)
        if len(u) < 2:
            return None
        return float((u[0] ** 2 + u[1] ** 2) ** 0.5)

    def counts_now(self) -> dict[str, SampleCounts]:
        """Each device's counts so far: judged, and received but waiting for its clock map."""
        now = {}
        for name in self.names:
            c = SampleCounts(name)
            c.add(self.totals[name])
            c.samples += self.held_samples(name)
            now[name] = c
        return now


__all__ = ["Acquisition", "ClockRefused", "PROVISIONAL_S", "QUEUE_BLOCKS", "STOP_WAIT_S", "Sink"]
