"""Exact accounting of a device's sequence numbers: what was lost, repeated, wrapped or restarted.

Every sample a device sends carries a ``seq`` (uint32) that counts its sample periods.  Between
two samples written one after the other, ``step = (seq - last) mod 2**32`` says what happened:

=====================  ===============================================================================
step                   meaning
=====================  ===============================================================================
1                      the next sample
2 .. 2**31 - 1         ``step - 1`` samples lost in between (``drops``); if ``seq < last`` the counter
                       also passed 2**32 - 1 (``wraps``)
0                      the same sample again (``duplicates``): dropped, never written twice
2**31 .. 2**32 - 1     behind the last one: with a later time the device restarted its count
                       (``restarts``: written, no loss counted across it); with a time not after the
                       last one it is a late copy of a sample already past (``duplicates``: dropped)
=====================  ===============================================================================

When the device was asked for a number of sample periods (``--duration``) and delivered its last
one, the periods after the last sample written that never came are ``drops`` too
(:meth:`SequenceTracker.missing_after`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

WRAP = 1 << 32
HALF = 1 << 31
COUNTS = ("samples", "drops", "duplicates", "wraps", "restarts")


@dataclass
class SampleCounts:
    """What happened to one device's samples in one file (or a whole recording).

    Attributes
    ----------
    device : str
        The device that numbers the samples.
    samples : int
        Samples written.
    drops : int
        Samples lost: gaps in ``seq`` and, for a recording of a set length, the periods missing
        after the last sample.
    duplicates : int
        Samples received again or out of order, dropped.
    wraps : int
        Times ``seq`` passed 2**32 - 1.
    restarts : int
        Times ``seq`` went back while time went on (the device restarted its count).
    first_seq, last_seq : int or None
        ``seq`` of the first and last sample written.
    first_time, last_time : int or None
        Their host times, in ns.
    """

    device: str
    samples: int = 0
    drops: int = 0
    duplicates: int = 0
    wraps: int = 0
    restarts: int = 0
    first_seq: int | None = None
    last_seq: int | None = None
    first_time: int | None = None
    last_time: int | None = None

    def add(self, other: "SampleCounts") -> None:
        """Add the counts of ``other``, a later stretch of the same device."""
        for name in COUNTS:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        if self.first_seq is None:
            self.first_seq, self.first_time = other.first_seq, other.first_time
        if other.last_seq is not None:
            self.last_seq, self.last_time = other.last_seq, other.last_time

    def as_dict(self) -> dict:
        """The counts, first and last ``seq``, and the mean rate over the samples' own span (Hz)."""
        span = (self.last_time - self.first_time) * 1e-9 if self.samples > 1 else 0.0
        return {"device": self.device, **{name: getattr(self, name) for name in COUNTS},
                "first_seq": self.first_seq, "last_seq": self.last_seq,
                "rate_hz": round((self.samples - 1) / span, 3) if span > 0 else 0.0}

    def as_json(self) -> str:
        return json.dumps(self.as_dict())


@dataclass(frozen=True)
class Verdict:
    """What :meth:`SequenceTracker.admit` found for each sample of a block.

    Attributes
    ----------
    keep : ndarray of bool
        Write this sample (``False``: a duplicate, dropped).
    lost : ndarray of int64
        Samples lost just before this one.
    wrapped, restarted : ndarray of bool
        The counter wrapped, or restarted, just before this sample.
    """

    keep: np.ndarray
    lost: np.ndarray
    wrapped: np.ndarray
    restarted: np.ndarray

    def counts(self, device: str, sl: slice, seq: np.ndarray, time_ns: np.ndarray) -> SampleCounts:
        """The counts of the samples in ``sl`` (kept ones give first/last ``seq`` and time)."""
        keep = self.keep[sl]
        out = SampleCounts(device, samples=int(np.count_nonzero(keep)), drops=int(self.lost[sl].sum()),
                           duplicates=int(keep.shape[0] - np.count_nonzero(keep)),
                           wraps=int(np.count_nonzero(self.wrapped[sl])),
                           restarts=int(np.count_nonzero(self.restarted[sl])))
        kept = np.flatnonzero(keep)
        if kept.size:
            first, last = sl.start + int(kept[0]), sl.start + int(kept[-1])
            out.first_seq, out.first_time = int(seq[first]), int(time_ns[first])
            out.last_seq, out.last_time = int(seq[last]), int(time_ns[last])
        return out


class SequenceTracker:
    """Follows one device's ``seq`` across a recording and judges each new sample (see the module
    docstring)."""

    def __init__(self) -> None:
        self.last_seq: int | None = None
        self.last_time: int | None = None
        self.advance = 0  # sum of the forward steps: the span of seq covered, less one
        self.written = 0
        self.restarts = 0

    def admit(self, seq: np.ndarray, time_ns: np.ndarray) -> Verdict:
        """Judge the samples of one block: ``seq`` (uint32) and host times ``time_ns`` (int64 ns),
        in order of arrival."""
        n = seq.shape[0]
        s = seq.astype(np.int64)
        prev = s[0] if self.last_seq is None else self.last_seq
        raw = np.diff(s, prepend=prev)
        step = raw % WRAP
        if self.last_seq is None and n:
            step[0] = 1
        if np.all((step >= 1) & (step < HALF)):  # the usual case: every sample after the last
            self.advance += int(step.sum()) - (1 if self.last_seq is None else 0)
            self.written += n
            if n:
                self.last_seq, self.last_time = int(s[-1]), int(time_ns[-1])
            return Verdict(np.ones(n, dtype=bool), step - 1, raw < 0, np.zeros(n, dtype=bool))
        keep = np.zeros(n, dtype=bool)
        lost = np.zeros(n, dtype=np.int64)
        wrapped = np.zeros(n, dtype=bool)
        restarted = np.zeros(n, dtype=bool)
        for i in range(n):
            keep[i], lost[i], wrapped[i], restarted[i] = self._one(int(s[i]), int(time_ns[i]))
        return Verdict(keep, lost, wrapped, restarted)

    def _one(self, seq: int, t: int) -> tuple[bool, int, bool, bool]:
        if self.last_seq is None:
            self.last_seq, self.last_time, self.written = seq, t, 1
            return True, 0, False, False
        step = (seq - self.last_seq) % WRAP
        if step == 0 or (step >= HALF and t <= self.last_time):
            return False, 0, False, False
        wrapped, restarted = False, step >= HALF
        if restarted:
            self.restarts += 1
        else:
            self.advance += step
            wrapped = seq < self.last_seq
        self.last_seq, self.last_time = seq, t
        self.written += 1
        return True, 0 if restarted else step - 1, wrapped, restarted

    def missing_after(self, due: int) -> int:
        """Of ``due`` sample periods asked for, counted from the first sample, how many came
        neither as a sample nor as a counted gap: the tail the device never sent (0 if the count
        restarted, when the span says nothing)."""
        if not self.written or self.restarts:
            return 0
        return max(0, due - (self.advance + 1))

