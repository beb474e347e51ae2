"""Runs a rig simulation in real time and hands every block to the simulated devices."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..signals import SampleBlock


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

    Subscribers get every block (``callback(block)``) on the server's thread; they must be quick
    (encode and queue for their transport).  Rig time 0 is the moment :meth:`start` is called,
    so ``wall_time_ns(rig_time)`` is when a sample instant happened on the host clock.
    """

    def __init__(self, rig, *, block_s: float = 0.01) -> None:
        self.rig = rig
        self.block = max(1, int(round(block_s * rig.params.sample_rate)))
        self._subs: list[Callable[[SampleBlock], None]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
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
        self.start_wall_ns = time.time_ns()
        self.start_mono = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="rig-server", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        rate = self.rig.params.sample_rate
        while not self._stop.is_set():
            block = self.rig.run(self.block)
            due = self.start_mono + self.rig.step_index / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            with self._lock:
                subs = list(self._subs)
            for cb in subs:
                cb(block)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
