"""Mapping a device's clock to the host clock, estimated online (offset and drift).

Every clock pair is (device time, host time it arrived): a sync message stamped by the device as
it left, or failing that the last sample of a block.  Arrival = departure + latency, and latency
is never negative, so the fastest pairs lie on a line ``host = device + offset + drift * device``
and every other pair lies above it.  We estimate that line as Moon, Skelly and Towsley do for
one-way delay (IEEE INFOCOM 1999): the line below every pair of the last ``SPAN_S`` seconds that is
closest to them in total, which is the edge of their lower convex hull straddling their mean
device time.  Jitter only ever lifts points off the hull, so it cannot pull the line up.

The line itself is the fastest arrival, one one-way latency after the true instant; where the
driver measures that latency (half the least round trip of a time exchange, as NTP does) it is
subtracted (:attr:`ClockMap.latency_ns`).  The pairs' height above the line is the latency beyond
the fastest; its 10th percentile is reported as the map's uncertainty.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

SPAN_S = 10.0  # fit over the last 10 s of pairs
SETTLE_S = 2.0  # pairs spanning this long before drift is estimated
REFIT_S = 0.25  # refit every quarter second of device time


@dataclass(frozen=True)
class ClockFit:
    """The present estimate: drift (ppm), offset at the first pair (ns), uncertainty (ns)."""

    drift_ppm: float
    offset_ns: float
    uncertainty_ns: float
    points: int
    latency_ns: int = 0


def lower_hull_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Intercept and slope of the line below all (x, y) closest to them in total.

    That line supports the lower convex hull on the edge whose x-range contains mean(x).

    Parameters
    ----------
    x : ndarray
        Sorted abscissae (s).
    y : ndarray
        Ordinates (ns).
    """
    hull: list[int] = []
    for i in range(x.shape[0]):  # Andrew's monotone chain, lower part
        while len(hull) >= 2:
            o, a = hull[-2], hull[-1]
            if (x[a] - x[o]) * (y[i] - y[o]) - (y[a] - y[o]) * (x[i] - x[o]) <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    xm = float(np.mean(x))
    for a, b in zip(hull[:-1], hull[1:]):
        if x[a] <= xm <= x[b] and x[b] > x[a]:
            slope = (y[b] - y[a]) / (x[b] - x[a])
            return float(y[a] - slope * x[a]), float(slope)
    return float(np.min(y)), 0.0


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
        self._settled = False
        self.latency_ns = 0  # one-way latency of the fastest pairs, subtracted when known

    @property
    def ready(self) -> bool:
        """Whether any pair has been seen."""
        return self._d0 is not None

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
            return  # pairs must advance in device time
        self._x.append(x)
        self._y.append(float(int(host_ns) - self._h0 - dd))
        while self._x[0] < x - SPAN_S:
            self._x.popleft()
            self._y.popleft()
        if not self._settled:
            self._settled = x - self._x[0] >= SETTLE_S
            if not self._settled:
                self._a, self._b = min(self._y), 0.0  # offset only, from the fastest pair
                return
        if x >= self._next_fit:
            self._next_fit = x + REFIT_S
            self._a, self._b = lower_hull_line(np.asarray(self._x), np.asarray(self._y))

    def to_host(self, device_ns: np.ndarray) -> np.ndarray:
        """Host times (int64 ns) of device times ``device_ns`` (int64 ns)."""
        if self._d0 is None:
            raise RuntimeError("no clock pair yet")
        dd = np.asarray(device_ns, dtype=np.int64) - self._d0
        return self._h0 + dd + np.round(self._a + self._b * (dd * 1e-9) - self.latency_ns).astype(np.int64)

    def fit(self) -> ClockFit:
        """The present estimate; uncertainty: 10th percentile of the pairs' height above the line."""
        x, y = np.asarray(self._x), np.asarray(self._y)
        above = y - (self._a + self._b * x) if x.size else np.array([np.nan])
        # host = device (1 + b): b is in ns per s of device time, i.e. ppm * 1e3
        return ClockFit(self._b * 1e-3, self._a - self.latency_ns, float(np.percentile(above, 10)), int(x.size),
                        self.latency_ns)
