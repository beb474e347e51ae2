"""Mapping a device's clock to the host clock, estimated online (offset and drift).

Every clock pair is (device time, host time it arrived): a sync message stamped by the device as
it left, or failing that the last sample of a block.  Arrival = departure + latency, and latency
is never negative, so the fastest pairs lie on a line ``host = device + offset + drift * device``
and every other pair lies above it.

We estimate that floor from the last ``SPAN_S`` seconds of pairs in two robust steps: the fastest
pair of each ``BIN_S`` bin of device time (jitter only lifts pairs, so a bin's minimum is the
floor plus a little), then the Theil-Sen line through those minima (slope: the median of the
slopes between every two bins, Theil 1950 and Sen 1968; intercept: the median of what is left).
A bin whose every pair was delayed (a scheduler stall, a burst after a full buffer) is an outlier
the medians ignore.  On recorded heartbeat pairs of two simulated controllers this halves the
worst misalignment of the lower-hull edge at the pairs' mean (Moon, Skelly and Towsley, INFOCOM
1999), which rests on the two fastest pairs alone; see docs/protocol.md.

The line itself is one fastest one-way latency after the true instant; where the driver measures
that latency (half the least round trip of a time exchange, as NTP does) it is subtracted
(:attr:`ClockMap.latency_ns`).  The 95th percentile of the bin minima's distance from the line is
reported as the map's spread.

A time written with one fit is never rewritten, but the fits that come after it (two-sided: pairs
from before and after it) are better estimates.  Each refit measures how far it would move the
times written in the last ``SPAN_S`` seconds: the largest such move over the recording is the
map's *revision*, what a loaded host (every pair lifted for a while) cost the samples written
while it lasted.  The map's uncertainty is the larger of its spread and its revision.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

MAX_DRIFT_PPM = 1000.0
"""The most a device's clock may run fast or slow against the host's: a quartz crystal stays within
about +-100 ppm over temperature and age (an RC oscillator can reach +-1 %, and is not a clock to
time samples by).  A drift beyond this fitted over a whole ``SPAN_S`` window, or beyond
``NO_CLOCK_PPM`` as soon as it is fitted (``SETTLE_S`` of pairs), is not a clock: the map refuses it
(:attr:`ClockMap.problem`).  Beyond this over a shorter window it is *suspect*
(:attr:`ClockMap.suspect`): a host too loaded to read the device in time lifts every pair for
seconds and fakes a slow clock (-1,800 ppm over 3 s with a core burnt beside an in-process rig),
so the samples are timed by the offset alone while it lasts, and the recording's clock metadata
says so."""
NO_CLOCK_PPM = 10_000.0  # 1 %: not even an RC oscillator; no loaded host fakes it over 3 s of pairs
SPAN_S = 10.0  # fit over the last 10 s of pairs
SETTLE_S = 3.0  # pairs spanning this long before drift is estimated
BIN_S = 0.25  # the fastest pair of each bin of device time
REFIT_S = 0.25  # refit every quarter second of device time


@dataclass(frozen=True)
class ClockFit:
    """The present estimate: drift (ppm), offset at the first pair (ns), uncertainty (ns: the
    larger of the fastest pairs' spread about the line and the revision), revision (ns)."""

    drift_ppm: float
    offset_ns: float
    uncertainty_ns: float
    points: int
    latency_ns: int = 0
    revision_ns: float = 0.0


def floor_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Theil-Sen line through the per-bin minima of (x, y): intercept, slope and spread.

    Parameters
    ----------
    x : ndarray
        Device times (s), ascending.
    y : ndarray
        Host minus device time of the same pairs (ns).

    Returns
    -------
    intercept : float
        Line value at x = 0 (ns).
    slope : float
        ns per s of device time (ppm * 1e3).
    spread : float
        95th percentile of the bin minima's distance from the line (ns).
    """
    k = np.floor(x / BIN_S).astype(np.int64)
    edges = np.flatnonzero(np.diff(k)) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [x.shape[0]]))
    at = np.array([s + int(np.argmin(y[s:e])) for s, e in zip(starts, ends)])
    bx, by = x[at], y[at]
    if bx.shape[0] < 2:
        return float(by.min()), 0.0, 0.0
    i, j = np.triu_indices(bx.shape[0], 1)
    slope = float(np.median((by[j] - by[i]) / (bx[j] - bx[i])))
    intercept = float(np.median(by - slope * bx))
    return intercept, slope, float(np.percentile(np.abs(by - intercept - slope * bx), 95))


class ClockMap:
    """Online device-to-host clock map (see the module docstring)."""

    def __init__(self) -> None:
        self._d0: int | None = None
        self._h0 = 0
        self._x: deque[float] = deque()  # device time since the first pair, s
        self._y: deque[float] = deque()  # (host - h0) - (device - d0), ns
        self._next_fit = 0.0
        self._a = 0.0  # y = a + b x
        self._b = 0.0
        self._spread = float("nan")  # of the bin minima about the line, once settled
        self._settled = False
        self._latency = 0  # one-way latency of the fastest pairs, subtracted when known
        self._written: deque[tuple[int, int]] = deque()  # (device ns, host ns written) of the last SPAN_S
        self._revision = 0.0  # the most a refit moved a written time, ns
        self.backwards = 0  # pairs whose device time ran back (dropped: a clock does not)
        self.problem: str | None = None  # why these are not a clock's times, once they are not
        self.suspect: str | None = None  # a drift beyond a crystal's over less than a whole window, while it is

    @property
    def ready(self) -> bool:
        """Whether any pair has been seen."""
        return self._d0 is not None

    @property
    def span_s(self) -> float:
        """Device time the pairs so far cover, s."""
        return self._x[-1] - self._x[0] if self._x else 0.0

    @property
    def settled(self) -> bool:
        """Whether drift is estimated (pairs spanning ``SETTLE_S`` seconds)."""
        return self._settled

    def update(self, device_ns: int, host_ns: int) -> None:
        """Add one (device time, host arrival time) pair, both in ns."""
        if self._d0 is None:
            self._d0, self._h0 = int(device_ns), int(host_ns)
        dd = int(device_ns) - self._d0
        x = dd * 1e-9
        if self._x and x <= self._x[-1]:
            self.backwards += x < self._x[-1]  # pairs must advance in device time
            return
        self._x.append(x)
        self._y.append(float(int(host_ns) - self._h0 - dd))
        while self._x[0] < x - SPAN_S:
            self._x.popleft()
            self._y.popleft()
        if not self._settled:
            self._settled = x - self._x[0] >= SETTLE_S
            if not self._settled:
                self._a, self._b = min(self._y), 0.0  # offset only, from the fastest pair so far
                self._measure_revision()
                return
        if x >= self._next_fit:
            self._next_fit = x + REFIT_S
            self._a, self._b, self._spread = floor_line(np.asarray(self._x), np.asarray(self._y))
            ppm = abs(self._b) * 1e-3
            said = f"its clock runs {self._b * -1e-3:+,.0f} ppm against the host's"
            whole = self.span_s >= SPAN_S - BIN_S  # pairs fill the window: a host's stall is outvoted
            if self.problem is None and ppm > MAX_DRIFT_PPM and (whole or ppm > NO_CLOCK_PPM):
                self.problem = said
            self.suspect = (f"{said} over {self.span_s:.1f} s of pairs (a host too loaded to read it in time, "
                            "or a clock that is not one)") if ppm > MAX_DRIFT_PPM and self.problem is None else None
            if self.suspect is not None:
                # a drift no crystal has is not used to time samples: offset only, from the fastest
                # pair, until the pairs say otherwise (a loaded host's -1,500 ppm over 3 s had moved
                # a 1 s part's boundary by 1.5 ms, 14 samples at 10 kHz)
                self._a, self._b = min(self._y), 0.0
            while self._written and self._written[0][0] < device_ns - SPAN_S * 1e9:
                self._written.popleft()
            self._measure_revision()

    def _measure_revision(self) -> None:
        """The revision: the farthest the map as it now stands puts a time written in the last
        ``SPAN_S`` from where it was written.  Measured against the written times themselves, so
        moves add up: a first offset that two faster pairs each lowered by 1 ms has moved the
        first samples by 2 ms (measured step by step, the revision had said 1 ms, and a 1.5 s span
        on a slow host was 5.8 ms off with 3.9 ms stated)."""
        if self._written:
            d, h = np.array(self._written, dtype=np.int64).T
            self._revision = max(self._revision, float(np.abs(self.to_host(d) - h).max()))

    @property
    def latency_ns(self) -> int:
        """One-way latency of the fastest pairs (ns), subtracted from every time mapped."""
        return self._latency

    @latency_ns.setter
    def latency_ns(self, value: int) -> None:
        # a better round trip moves every later time by the change: times already written count it
        # in the revision, as a refit's move (a first round trip 3 ms slow on a loaded host, then a
        # fast one, had moved a 1.5 s span by 2.9 ms with a revision of 11 us stated)
        self._latency = int(value)
        self._measure_revision()

    def written(self, device_ns: int, host_ns: int) -> None:
        """Note that the sample at ``device_ns`` was written at ``host_ns`` (both ns; one per block
        is enough): later refits measure how far they would move it (the revision)."""
        self._written.append((int(device_ns), int(host_ns)))

    def to_host(self, device_ns: np.ndarray) -> np.ndarray:
        """Host times (int64 ns) of device times ``device_ns`` (int64 ns)."""
        if self._d0 is None:
            raise RuntimeError("no clock pair yet")
        dd = np.asarray(device_ns, dtype=np.int64) - self._d0
        return self._h0 + dd + np.round(self._a + self._b * (dd * 1e-9) - self.latency_ns).astype(np.int64)

    def fit(self) -> ClockFit:
        """The present estimate; uncertainty: the larger of the bin minima's spread about the line
        and the revision (NaN until settled)."""
        # host = device (1 + b): b is in ns per s of device time, i.e. ppm * 1e3
        return ClockFit(self._b * 1e-3, self._a - self.latency_ns, max(self._spread, self._revision), len(self._x),
                        self.latency_ns, self._revision)
