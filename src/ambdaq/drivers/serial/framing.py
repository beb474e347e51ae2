"""Serial framing: COBS-encoded frames with a CRC-32, delimited by 0x00 (see docs/protocol.md).

On the wire a frame is ``COBS(body + crc32_le(body)) + b"\\x00"``.  COBS removes every zero
byte from the frame, so 0x00 only ever marks a frame's end: after noise, a lost byte or garbage,
the decoder resynchronises at the next delimiter.  A frame whose COBS structure or CRC is wrong is
counted and dropped, never delivered.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

from cobs import cobs

DELIMITER = b"\x00"
MAX_FRAME = 65536  # longest decoded frame we accept, in bytes


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing (Cheshire and Baker, 1999): ``data`` without any zero
    byte (overhead <= 1/254); the ``cobs`` package's C encoder, canonical (no empty block after a
    full one at the end)."""
    return cobs.encode(data)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises ``ValueError`` on a malformed encoding (a zero byte,
    a block running past the end)."""
    try:
        return cobs.decode(data)
    except cobs.DecodeError as err:
        raise ValueError(f"malformed COBS frame: {err}") from None


def encode_frame(body: bytes) -> bytes:
    """A complete wire frame for ``body``."""
    return cobs_encode(body + struct.pack("<I", zlib.crc32(body))) + DELIMITER


@dataclass
class FrameStats:
    """What the decoder has seen: good frames, CRC and COBS rejections, bytes skipped."""

    frames: int = 0
    crc_errors: int = 0
    cobs_errors: int = 0
    oversize: int = 0

    @property
    def rejected(self) -> int:
        return self.crc_errors + self.cobs_errors + self.oversize


@dataclass
class FrameDecoder:
    """Incremental decoder: feed bytes as they arrive, get back the good frame bodies."""

    stats: FrameStats = field(default_factory=FrameStats)
    _pending: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[bytes]:
        """Frame bodies (CRC stripped) completed by ``data``; bad frames are counted and dropped."""
        self._pending += data
        if DELIMITER not in data:
            if len(self._pending) > 2 * MAX_FRAME:  # a stream with no delimiter at all: garbage
                self._pending.clear()
                self.stats.oversize += 1
            return []
        *frames, rest = bytes(self._pending).split(DELIMITER)
        self._pending = bytearray(rest)
        out = []
        for raw in frames:
            if not raw:
                continue  # back-to-back delimiters: idle line
            if len(raw) > MAX_FRAME:
                self.stats.oversize += 1
                continue
            try:
                decoded = cobs_decode(raw)
            except ValueError:
                self.stats.cobs_errors += 1
                continue
            if len(decoded) < 5:
                self.stats.cobs_errors += 1
                continue
            body, crc = decoded[:-4], struct.unpack("<I", decoded[-4:])[0]
            if zlib.crc32(body) != crc:
                self.stats.crc_errors += 1
                continue
            self.stats.frames += 1
            out.append(body)
        return out
