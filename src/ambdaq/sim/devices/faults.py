"""Faults on purpose: a byte stream that damages what goes through it (the serial path's resilience),
and a controller fault at a set time (``sim://PROFILE?fault=SECONDS``: rehearsing what a fault does
to a recording, e.g. a snapshot's ``fault`` trigger)."""

from __future__ import annotations

import random
import threading

from .controller import FdPort, SimController

INJECTED_FAULT = (0x2310, 2, "injected fault: amplifier over-current")  # code (CiA 402's), severity, text


class FaultyPort(FdPort):
    """A device port that flips bits, truncates frames, injects garbage and stalls on request.

    Parameters
    ----------
    fd : int
        The device's end of the line.
    flip : float
        Probability that a written frame gets one bit flipped.
    truncate : float
        Probability that a frame is cut short (its tail and delimiter never sent).
    garbage : float
        Probability that random bytes precede a frame.
    seed : int
        Seed of the damage.
    """

    def __init__(self, fd: int, *, flip: float = 0.0, truncate: float = 0.0, garbage: float = 0.0,
                 seed: int = 0) -> None:
        super().__init__(fd)
        self.flip, self.truncate, self.garbage = flip, truncate, garbage
        self.rng = random.Random(seed)
        self.stalled = threading.Event()
        self.damaged = 0

    def write(self, data: bytes) -> None:
        if self.stalled.is_set():
            return  # a hung device: nothing leaves it
        frame = bytearray(data)
        r = self.rng.random()
        if r < self.flip:
            frame[self.rng.randrange(len(frame) - 1)] ^= 1 << self.rng.randrange(8)
            self.damaged += 1
        elif r < self.flip + self.truncate:
            frame = frame[: self.rng.randrange(1, len(frame) - 1)]
            self.damaged += 1
        elif r < self.flip + self.truncate + self.garbage:
            frame = bytearray(self.rng.randbytes(self.rng.randrange(1, 40))) + frame
            self.damaged += 1
        super().write(bytes(frame))


class ScheduledFault:
    """Makes ``controller`` report :data:`INJECTED_FAULT` ``after_s`` seconds after :meth:`start`."""

    def __init__(self, controller: SimController, after_s: float) -> None:
        code, severity, text = INJECTED_FAULT
        self._timer = threading.Timer(after_s, controller.fault, (code, severity, f"{text} (at {after_s:g} s)"))
        self._timer.daemon = True

    def start(self) -> None:
        self._timer.start()

    def stop(self) -> None:
        self._timer.cancel()
