"""Bytes of an MCAP file changed the way tests need them, read off the file's own structure
(the footer, Data End) with no ambdaq code."""

from __future__ import annotations

import struct

FOOTER = 1 + 8 + 8 + 8 + 4  # opcode, length, summary start, summary offset start, summary CRC
MAGIC = 8


def data_end(data: bytes | bytearray) -> int:
    """Where the Data End record starts: just before the summary (both ambdaq's writer and the
    official one put it there)."""
    summary_start = struct.unpack_from("<Q", data, len(data) - MAGIC - FOOTER + 9)[0]
    at = summary_start - 13
    assert data[at] == 0x0F, "no Data End before the summary"
    return at


def without_data_crc(data: bytes | bytearray) -> bytearray:
    """``data`` with its data section CRC set to 0, as writers that compute none leave it (the
    official Python writer by default, ambdaq before 0.3): its metadata and chunks are then
    protected only by what each record carries."""
    out = bytearray(data)
    struct.pack_into("<I", out, data_end(out) + 9, 0)
    return out
