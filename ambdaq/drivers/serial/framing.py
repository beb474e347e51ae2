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

import numpy as np
from numba import njit

DELIMITER = b"\x00"
MAX_FRAME = 65536  # longest decoded frame we accept, in bytes


@njit(cache=True, nogil=True)
def _cobs_encode(src: np.ndarray, dst: np.ndarray) -> int:
    n = src.shape[0]
    code_pos, code, j = 0, 1, 1
    for idx in range(n):
        b = src[idx]
        if b == 0:
            dst[code_pos] = code
            code_pos, code, j = j, 1, j + 1
        else:
            dst[j] = b
            j += 1
            code += 1
            if code == 255:
                dst[code_pos] = code
                if idx == n - 1:  # canonical: no empty block after a full one at the end
                    return j
                code_pos, code, j = j, 1, j + 1
    dst[code_pos] = code
    return j


@njit(cache=True, nogil=True)
def _cobs_decode(src: np.ndarray, dst: np.ndarray) -> int:
    """Decoded length, or -1 if ``src`` is not a valid COBS encoding."""
    i, j, n = 0, 0, src.shape[0]
    while i < n:
        code = src[i]
        if code == 0 or i + code > n:
            return -1
        for k in range(i + 1, i + code):
            if src[k] == 0:
                return -1
            dst[j] = src[k]
            j += 1
        i += code
        if code < 255 and i < n:
            dst[j] = 0
            j += 1
    return j


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: ``data`` without any zero byte (overhead <= 1/254)."""
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.shape[0] + src.shape[0] // 254 + 2, dtype=np.uint8)
    return dst[: _cobs_encode(src, dst)].tobytes()


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises ``ValueError`` on a malformed encoding."""
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.shape[0], dtype=np.uint8)
    n = _cobs_decode(src, dst)
    if n < 0:
        raise ValueError("malformed COBS frame")
    return dst[:n].tobytes()


def warm_up() -> None:
    """Compile the COBS kernels now (first use compiles them, holding the GIL for a moment):
    a simulated rig calls this before its clock starts, so compiling never makes it late."""
    cobs_decode(cobs_encode(b"\x00warm\x00"))


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
