"""What a chunk's records are where they are rows: one row of Message records per sample instant,
the same channels in the same order in every row (how ambdaq writes a device's chunks,
:meth:`~.mcapfile.BlockWriter.add_messages`), which :func:`~.reader.read_fixed` then hands out as
strided views.  Learned from a chunk's message indexes, or, where it has none (``--no-index``),
from its first records and checked row by row as it is inflated; a chunk that is not rows is
described by walking its records.
"""

from __future__ import annotations

import struct

import numpy as np
from mcap.records import ChunkIndex

from ..errors import BadInputError
from .mcapfile import McapFile, message_indexes_of
from .schema import MESSAGE_OPCODE

Row = tuple[tuple[tuple[int, int], ...], int]
"""A chunk of rows: each channel's record offset in the row, in row order, and the row's size (bytes)."""


def row_layout(size: int, here: dict[int, np.ndarray], message_sizes: dict[int, int]) -> Row | None:
    """What the message indexes ``here`` (every channel of a chunk of ``size`` uncompressed bytes)
    say of its records, where they are rows: every channel a fixed-layout one with as many messages
    as the others, each channel's first record where the one before it in the row ends, and the
    chunk exactly that many rows long (how the writer leaves a device's chunks,
    :meth:`~.mcapfile.BlockWriter.add_messages`).  ``None`` for any other chunk.  The stride is
    proven against the records as each chunk is read (:func:`~.mcapfile.message_view`)."""
    counts = {idx.shape[0] for idx in here.values()}
    if not here or len(counts) != 1 or 0 in counts or any(cid not in message_sizes for cid in here):
        return None
    firsts = {cid: int(idx["offset"][0]) for cid, idx in here.items()}
    places, at = [], 0
    for cid in sorted(here, key=firsts.__getitem__):
        if firsts[cid] != at:
            return None
        places.append((cid, at))
        at += message_sizes[cid]
    return (tuple(places), at) if size == counts.pop() * at else None


def first_row(f: McapFile, ci: ChunkIndex, message_sizes: dict[int, int]) -> Row | None:
    """The layout of a chunk without message indexes, from its first records, where they begin a
    run of rows that fills it: fixed-layout Message records of distinct channels up to the first
    channel seen again, and the chunk a whole number of such rows.  Only the head of the chunk is
    inflated; every row is checked against the first when the chunk is read (:func:`rows_hold`).
    ``None`` for any other chunk."""
    size = ci.uncompressed_size
    for want in (16 << 10, 1 << 20, size):
        head = f.chunk_head(ci, want)
        places, at, seen = [], 0, set()
        while at + 11 <= len(head):
            op, length, cid = struct.unpack_from("<BQH", head, at)
            if cid in seen:
                break
            if op != MESSAGE_OPCODE or message_sizes.get(cid) != 9 + length:
                return None
            seen.add(cid)
            places.append((cid, at))
            at += 9 + length
        else:
            if len(head) < size:
                continue  # the first row runs past what was inflated
        return (tuple(places), at) if places and at <= size and size % at == 0 else None
    return None


def walked(f: McapFile, ci: ChunkIndex) -> dict[int, np.ndarray]:
    """Each channel's (log time, offset) in a chunk without message indexes whose records are not
    rows, found by walking its records: what its message indexes would have said."""
    records = f.chunk_records(ci)
    found, end = message_indexes_of(records)
    if end != len(records):
        raise BadInputError(f"{f.path}: chunk at byte {ci.chunk_start_offset}: a record runs past its end")
    return found


def rows_hold(records: np.ndarray, rows: Row) -> bool:
    """Whether every row of a chunk without message indexes holds the records its first row
    holds: each record's opcode, length and channel (its first 11 bytes, read as two overlapping
    8-byte words at bytes 0 and 3) as in row 0."""
    places, stride = rows
    n = records.shape[0] // stride
    for _cid, at in places:
        for start in (at, at + 3):
            word = np.ndarray((n,), dtype="<u8", buffer=records, offset=start, strides=(stride,))
            if not np.all(word == word[0]):
                return False
    return True


__all__ = ["Row", "first_row", "row_layout", "rows_hold", "walked"]
