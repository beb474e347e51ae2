"""Rows that a receive thread decodes and a device's reader thread hands to the recorder: the
wait, the silence limit and the cut at the samples asked for, once for every device whose
samples arrive one by one (CANopen, DBC and EDS devices on a CAN bus; XCP DAQ)."""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Callable

import numpy as np

from ..errors import DeviceError

BLOCK_S = 0.1  # hand rows to the recorder every 100 ms


class RowQueue:
    """Rows ``(seq, time ns, values...)`` appended by the receive thread, taken in blocks by the reader.

    Parameters
    ----------
    silent_after_s : float
        Seconds without a row after which the device is lost (DeviceError).
    """

    def __init__(self, silent_after_s: float) -> None:
        self.rows: deque = deque()
        self.closed = threading.Event()
        self.silent_after_s = silent_after_s
        self._first: int | None = None
        self._remaining: int | None = None
        self._failed: str | None = None  # a failure seen with rows still to hand over
        self.last_row = time.monotonic()

    def start(self, n_samples: int | None) -> None:
        """Count ``n_samples`` sequence numbers from the first row taken (None: no end)."""
        self._remaining = n_samples
        self.last_row = time.monotonic()

    def take(self, failure: Callable[[], str | None], silence: Callable[[float], str]) -> tuple[list, np.ndarray] | None:
        """The rows since the last call (at least one) and their sequence numbers, cut at the
        samples asked for; None when closed or done.

        Parameters
        ----------
        failure : callable
            The reason the device is lost, or None; checked every BLOCK_S.
        silence : callable
            The message for ``silent_after_s`` seconds (its argument) without a row.
        """
        while True:
            if self._failed is not None:
                raise DeviceError(self._failed)
            if self.closed.wait(BLOCK_S):
                return None
            reason = failure()
            n = len(self.rows)
            if n:  # the rows that came before a failure are kept: it is reported on the next call
                rows = [self.rows.popleft() for _ in range(n)]
                self.last_row = time.monotonic()
                self._failed = reason
                break
            if reason is not None:
                raise DeviceError(reason)
            silent = time.monotonic() - self.last_row
            if silent > self.silent_after_s:
                raise DeviceError(silence(silent))
        seq = np.array([r[0] for r in rows], dtype=np.int64)
        if self._first is None:
            self._first = int(seq[0])
        if self._remaining is not None:
            keep = seq < self._first + self._remaining
            if not keep.any():
                return None
            rows = [r for r, k in zip(rows, keep) if k]
            seq = seq[keep]
        return rows, seq
