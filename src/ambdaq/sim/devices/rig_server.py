"""Runs a rig simulation in real time and hands every block to the simulated devices."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...drivers.signals import SampleBlock

LEAD_BLOCKS = 5  # blocks computed ahead of the wall clock: a rig thread starved for up to 50 ms still has
# the sample a SYNC asks for
LATE_WAIT_S = 0.15  # beyond that a SYNC's sample is waited for, as long as a reply can still be matched
# to its SYNC by the counter it echoes (240 SYNCs: 300 ms at 800 Hz); a real device always has its
# sample, so a simulator that fell behind must not show up as a dropped cycle


@dataclass(frozen=True)
class DeviceClock:
    """A device's own clock: ``offset_ns + rig_time * (1 + drift_ppm * 1e-6)``.

    Parameters
    ----------
    offset_ns : int
        Device time at rig time 0, in ns.
    drift_ppm : float
        Rate error against the host clock, in parts per million.
    """

    offset_ns: int = 0
    drift_ppm: float = 0.0

    def at(self, rig_time_ns: np.ndarray | int) -> np.ndarray | int:
        """Device time (ns) at rig time ``rig_time_ns`` (ns)."""
        t = np.asarray(rig_time_ns, dtype=np.int64)
        out = self.offset_ns + t + np.round(t * (self.drift_ppm * 1e-6)).astype(np.int64)
        return out if out.ndim else int(out)


class RigServer:
    """Steps ``rig`` in blocks of ``block_s`` seconds, paced to the wall clock, in its own thread.

    Subscribers get every block (``callback(block)``) on the server's thread when the wall clock
    reaches its end; they must be quick (encode and queue for their transport).  Blocks are
    computed a block ahead of the wall clock, so devices sampling on an external trigger (a CAN
    SYNC) can read the rig's sample at any instant up to now with :meth:`sample_at`.  Rig time 0 is the moment
    :meth:`start` is called: sample k happened at ``start_wall_ns + k * period``.
    """

    def __init__(self, rig, *, block_s: float = 0.01) -> None:
        self.rig = rig
        self.block = max(1, int(round(block_s * rig.params.sample_rate)))
        self._subs: list[Callable[[SampleBlock], None]] = []
        self._lock = threading.Lock()
        self._computed = threading.Condition(self._lock)  # notified when a block joins the history
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._recent: deque[SampleBlock] = deque(maxlen=256)  # 2.56 s of history
        self._pending: deque[SampleBlock] = deque()  # computed, not yet published
        self._boundary: deque[tuple[Callable, threading.Event, list]] = deque()  # run between blocks
        self.start_wall_ns = 0
        self.start_mono = 0.0

    def subscribe(self, callback: Callable[[SampleBlock], None]) -> None:
        with self._lock:
            self._subs.append(callback)

    def unsubscribe(self, callback: Callable[[SampleBlock], None]) -> None:
        with self._lock:
            if callback in self._subs:
                self._subs.remove(callback)

    def start(self) -> None:
        """Start the rig's clock; the first block is computed first, so compiling the physics
        kernel never makes the rig late."""
        for _ in range(LEAD_BLOCKS + 1):  # the computed horizon leads the wall clock
            self._compute()
        self.start_wall_ns = time.time_ns()
        self.start_mono = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="rig-server", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        rate = self.rig.params.sample_rate
        while not self._stop.is_set():
            block = self._pending.popleft()
            due = self.start_mono + (int(block.seq[-1]) + 1) / rate  # the end of this block
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            with self._lock:
                subs = list(self._subs)
            for cb in subs:
                cb(block)
            self._compute()

    def at_boundary(self, change: Callable, timeout: float = 1.0) -> int:
        """Apply ``change(rig)`` between two control periods, on the server's thread, so no period
        runs half old, half new; returns the index of the first sample computed after it.

        Parameters
        ----------
        change : callable
            Takes the rig; must be quick.
        timeout : float
            How long to wait for the server's thread, in s; ``TimeoutError`` after it, and then
            the change is withdrawn: it is never applied later.
        """
        done, box = threading.Event(), []
        item = (change, done, box)
        with self._lock:
            self._boundary.append(item)
        if self._thread is None:  # not running: this is a boundary too
            self._apply_boundary()
        if not done.wait(timeout):
            with self._lock:
                if item in self._boundary:
                    self._boundary.remove(item)
                    raise TimeoutError("the rig did not reach a control-period boundary")
            done.wait()  # taken by the loop just now: it is being applied
        return box[0]

    def _apply_boundary(self) -> None:
        while True:
            with self._lock:
                if not self._boundary:
                    return
                change, done, box = self._boundary.popleft()
            change(self.rig)
            box.append(self.rig.step_index)
            done.set()

    def _compute(self) -> None:
        self._apply_boundary()
        block = self.rig.run(self.block)
        with self._computed:
            self._recent.append(block)
            self._computed.notify_all()
        self._pending.append(block)

    def sample_at(self, wall_ns: int) -> tuple[int, dict[str, np.ndarray]]:
        """The rig's sample at host time ``wall_ns`` (ns): its step index and one row per group.
        A step not computed yet is waited for, up to LATE_WAIT_S."""
        step = (wall_ns - self.start_wall_ns) // self.rig.period_ns
        with self._computed:
            if not self._recent:
                raise LookupError("the rig has produced nothing yet")
            self._computed.wait_for(lambda: step <= int(self._recent[-1].seq[-1]) or self._stop.is_set(),
                                    timeout=LATE_WAIT_S)
            if step > int(self._recent[-1].seq[-1]):
                raise LookupError(f"rig step {step} is not computed yet (the rig is late)")
            for b in reversed(self._recent):
                first = int(b.seq[0])
                if first <= step:
                    i = int(step - first)
                    return first + i, {t: v[i] for t, v in b.values.items()}
        raise LookupError(f"rig step {step} is older than the history kept")

    def stop(self) -> None:
        self._stop.set()
        with self._computed:
            self._computed.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
