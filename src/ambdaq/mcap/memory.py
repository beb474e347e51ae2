"""Memory for what ``load`` returns: taken from the kernel once, then used again.

A recording's columns are hundreds of megabytes, and fresh memory costs the kernel's page faults
and zeroing (and, for huge pages, at times a compaction stall): on bench_read.py's file, inflating
the chunks into fresh memory took 1.2x as long as into memory already used (110 against 91 ms),
and single loads spread from 140 to 670 ms.  A process that reads file after file (``fleet
scan``, a script over a folder) pays that on every file unless the memory of a recording it is
done with is used again, as pyarrow's memory pool does for Parquet.

A block is free again when nothing but this pool refers to the array that owns its memory: every
array ``load`` hands out is a view whose ``base`` is that array (numpy resolves a view of a view
to the array that owns the memory), so a live array, a memoryview of one or a field of one holds
a reference to it, and ``sys.getrefcount`` sees it.  The pool keeps at most :data:`KEEP` bytes: a long-lived process holds
that much after its last load, no more.
"""

from __future__ import annotations

import sys
import threading

import numpy as np

HUGE_PAGE = 2 << 20
"""x86-64 and arm64 Linux transparent huge pages, bytes: numpy asks the kernel for them on
allocations of 4 MiB and more, so the first write faults 2 MiB in at a time rather than 4 KiB
(with no huge pages at all, bench_read.py's load took 1.4x as long)."""
GRAIN = 16 << 20
"""Blocks are sized in steps of this many bytes, so that files of nearly one size share them."""
KEEP = 1 << 30
"""Bytes of blocks the pool keeps, in use or free (the newest first)."""

Block = tuple[np.ndarray, int, int]
"""The array that owns a block's memory, where its huge-page-aligned part starts, that part's size."""


def _references(blocks: list[Block]) -> list[int]:
    """``sys.getrefcount`` of each block's owner, taken the one way the pool takes it: what an idle
    block shows depends on the interpreter (borrowed references, comprehension scopes), so it is
    measured once, by this same function, on a block no one else holds (:class:`_Pool`)."""
    return [sys.getrefcount(owner) for owner, _start, _size in blocks]


class _Pool:
    def __init__(self) -> None:
        self._blocks: list[Block] = []  # newest first
        self._lock = threading.Lock()
        self._idle = _references([(np.empty(1, dtype=np.uint8), 0, 1)])[0]

    def take(self, nbytes: int) -> np.ndarray:
        """``nbytes`` of memory (uint8) that starts on a huge page: a block no array refers to any
        more, or a fresh one (kept for later only where it fits :data:`KEEP`)."""
        with self._lock:
            free = [i for i, ((_owner, _start, size), refs) in enumerate(zip(self._blocks, _references(self._blocks)))
                    if nbytes <= size <= nbytes + nbytes // 4 + GRAIN and refs == self._idle]
            if free:  # the smallest that fits, so that a larger block stays for a larger request
                owner, start, size = block = self._blocks.pop(min(free, key=lambda i: self._blocks[i][2]))
                self._blocks.insert(0, block)
                return owner[start : start + nbytes]
            size = -(-nbytes // GRAIN) * GRAIN if nbytes >= GRAIN else nbytes
            owner = np.empty(size + HUGE_PAGE, dtype=np.uint8)
            start = -owner.ctypes.data % HUGE_PAGE
            kept, total = [], 0
            for block in [(owner, start, size), *self._blocks]:  # the newest blocks stay, up to KEEP bytes
                if total + block[2] <= KEEP:
                    kept.append(block)
                    total += block[2]
            self._blocks = kept
            return owner[start : start + nbytes]

    def release(self) -> int:
        """Let go of every block no array refers to; the bytes let go."""
        with self._lock:
            refs = _references(self._blocks)
            gone = sum(b[2] for b, r in zip(self._blocks, refs) if r == self._idle)
            self._blocks = [b for b, r in zip(self._blocks, refs) if r != self._idle]
            return gone

    @property
    def kept(self) -> int:
        """Bytes of the blocks the pool keeps, in use or free."""
        return sum(b[2] for b in self._blocks)


_POOL = _Pool()


def take(nbytes: int) -> np.ndarray:
    """``nbytes`` of memory for a load's columns (uint8, starting on a huge page), used before
    where a block is free (see the module's docstring).

    Parameters
    ----------
    nbytes : int
        Size, in bytes.
    """
    return _POOL.take(nbytes)


def release_memory() -> int:
    """Give back to the system the memory ``load`` keeps for the next load (at most :data:`KEEP`
    bytes, of recordings no array refers to any more); returns the bytes given back.  Arrays still
    held keep theirs."""
    return _POOL.release()


def kept() -> int:
    """Bytes the pool keeps now (blocks in use by arrays, and free ones), at most :data:`KEEP`."""
    return _POOL.kept


__all__ = ["HUGE_PAGE", "KEEP", "kept", "release_memory", "take"]
