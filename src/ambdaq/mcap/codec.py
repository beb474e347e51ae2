"""Chunk compression: one contract for every codec an MCAP chunk may use (zstd, lz4, none).

**Inflating fills what it is given, or raises.**  :func:`inflate_into` writes every one of the
``size`` bytes of its destination, or raises :class:`CorruptChunk`; :func:`inflate` returns new
memory of exactly ``size`` bytes, filled.  No codec hands back memory of its own for the caller to
find: a codec that cannot inflate in place (lz4) or has nothing to inflate (none) copies into the
destination, so a reader that hands out views of its destination never hands out bytes no codec
wrote (a reader that did lost lz4 and uncompressed files to another file's samples, issue 37).

**Sizes before memory.**  The size a chunk declares (its ``uncompressed_size``) is checked against
what its compressed data can hold before anything is sized from it (:func:`size_problem`): exactly
the stored size for "none", the size a zstd or lz4 frame header declares where it declares one, and
otherwise at most :data:`MAX_RATIO` times the compressed size (the most either format can expand:
a zstd block of 128 KiB from a 4-byte RLE block, lz4's 255-fold run lengths), and never more than
:data:`MAX_CHUNK`.

**The bytes are checked** by the codec's own checksum where the frame carries one (zstd's and
lz4's content checksum: ambdaq's writer always sets it), else by the chunk's CRC-32 where its
writer stored one (MCAP's ``uncompressed_crc``: the official writer does, for every codec); a
chunk with neither is read unchecked (:func:`checked_by`).  CRC-32 is computed by ISA-L
(:func:`crc32`: 9 GB/s here, zlib's 3 GB/s), the same polynomial as zlib's.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import lz4.frame
import numpy as np
import zstandard
from isal.isal_zlib import crc32, crc32_combine

COMPRESSIONS = ("zstd", "lz4", "none")
"""What ``--compression`` takes; a chunk record names "none" as the empty string."""
MAX_RATIO = {"zstd": 32768, "lz4": 256, "": 1}
"""The most a codec can expand its compressed bytes by where its frame does not state the size."""
MAX_CHUNK = 1 << 31
"""Bytes: a chunk declaring more is refused (chunks are MiBs; 2 GiB also bounds ``recover``)."""
ZSTD_LEVEL = -1
"""zstd's fastest level that still compresses our records as well as level 1 (ratio 0.305 against
0.309 on the spindle): the negative levels store literals without Huffman coding, which buys
nothing on sensor noise and costs 30% of the decompression time (benchmarks/bench_read.py)."""
# with a frame checksum: corruption is caught on decompression at xxhash speed
_ZSTD_C = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_checksum=True)


PIECE = 4 << 20
"""Bytes: :func:`crc32_parallel` splits what holds two or more (below, one thread does it all)."""


def crc32_parallel(data: memoryview, threads: int = max(2, os.cpu_count() or 2)) -> int:
    """CRC-32 of ``data`` (as zlib's), in pieces on ``threads`` threads combined with
    ``crc32_combine``: the data section of a 100 MB file in 6 ms on two cores here."""
    n = len(data)
    if n < 2 * PIECE or threads < 2:
        return crc32(data)
    bounds = [n * k // threads for k in range(threads + 1)]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        parts = list(pool.map(lambda k: crc32(data[bounds[k] : bounds[k + 1]]), range(threads)))
    crc = parts[0]
    for k in range(1, threads):
        crc = crc32_combine(crc, parts[k], bounds[k + 1] - bounds[k])
    return crc


class CorruptChunk(ValueError):
    """A chunk's compressed data does not inflate to what the chunk says it holds."""


def compress(data: bytes | memoryview, method: str) -> bytes:
    """Compress chunk records with ``method`` ("zstd", "lz4" or "none"), the codec's content
    checksum on (zstd, lz4)."""
    if method == "zstd":
        return _ZSTD_C.compress(data)
    if method == "lz4":
        return lz4.frame.compress(data, compression_level=0, content_checksum=True)
    return bytes(data)


def _frame(packed, method: str) -> tuple[int | None, bool]:
    """The size a zstd or lz4 frame declares (None where it does not) and whether it carries a
    content checksum; CorruptChunk if it is not such a frame."""
    try:
        if method == "zstd":
            p = zstandard.get_frame_parameters(packed)
            return (None if p.content_size == zstandard.CONTENTSIZE_UNKNOWN else p.content_size), p.has_checksum
        info = lz4.frame.get_frame_info(packed)
        return (info["content_size"] or None), bool(info["content_checksum"])
    except Exception as err:  # whatever the codec says of a header that is not its frame's
        raise CorruptChunk(f"not a {method} frame ({err})") from None


def declared_size(packed, method: str) -> int | None:
    """The uncompressed size compressed data ``packed`` states of itself: its length for "none", its
    zstd or lz4 frame's content size where the frame states one; None otherwise (or not a frame)."""
    if method == "":
        return len(packed)
    try:
        return _frame(packed, method)[0]
    except CorruptChunk:
        return None


def size_problem(packed, method: str, size: int) -> str | None:
    """Why compressed data ``packed`` cannot hold ``size`` bytes of records, or None.

    Parameters
    ----------
    packed : bytes-like
        The chunk's compressed data.
    method : {"zstd", "lz4", ""}
        Its compression, as the chunk record names it ("" for none).
    size : int
        The uncompressed size the chunk declares, bytes.
    """
    if size > MAX_CHUNK:
        return f"it declares {size} bytes, more than the {MAX_CHUNK >> 30} GiB ambdaq reads in one chunk"
    if method == "":
        return None if size == len(packed) else f"it declares {size} bytes but stores {len(packed)} uncompressed"
    try:
        declared, _checksum = _frame(packed, method)
    except CorruptChunk as err:
        return str(err)
    if declared is not None and declared != size:
        return f"it declares {size} bytes, its {method} frame {declared}"
    if size > MAX_RATIO[method] * len(packed) + (1 << 17):
        return f"it declares {size} bytes, more than {len(packed)} bytes of {method} can hold"
    return None


def checked_by(packed, method: str, crc: int) -> str:
    """What checks a chunk's bytes as it is inflated: "zstd" or "lz4" (the frame's content
    checksum), "crc" (the chunk's CRC-32), or "" (nothing)."""
    if method in ("zstd", "lz4") and _frame(packed, method)[1]:
        return method
    return "crc" if crc else ""


def inflate_into(packed, method: str, size: int, dest: np.ndarray, crc: int = 0) -> None:
    """Inflate a chunk's records into ``dest``, every byte of it, or raise.

    Parameters
    ----------
    packed : bytes-like
        The chunk's compressed data.
    method : {"zstd", "lz4", ""}
        Its compression ("" for none).
    size : int
        The uncompressed size it declares, bytes (checked by :func:`size_problem` first).
    dest : ndarray of uint8, shape (size,)
        Where the records go.
    crc : int
        The chunk's CRC-32 of its records (0: none stored); checked where the codec's own
        checksum does not cover them.

    Raises
    ------
    CorruptChunk
        The data is damaged: it does not inflate, inflates to another size, or fails a checksum.
    """
    if dest.shape != (size,):
        raise ValueError(f"destination of {dest.shape} bytes for a chunk of {size}")
    problem = size_problem(packed, method, size)
    if problem is not None:
        raise CorruptChunk(problem)
    try:
        if method == "zstd":
            reader, view, got = zstandard.ZstdDecompressor().stream_reader(packed, read_across_frames=True), memoryview(dest), 0
            while got < size:
                n = reader.readinto(view[got:])
                if n == 0:
                    raise CorruptChunk(f"its zstd data holds {got} bytes, the chunk says {size}")
                got += n
            if reader.read(1):  # the frame must end here; its checksum is checked on the way
                raise CorruptChunk(f"its zstd data holds more than the chunk's {size} bytes")
        elif method == "lz4":
            d = lz4.frame.LZ4FrameDecompressor()
            out = d.decompress(packed, max_length=size + 1)
            if len(out) != size or not d.eof or d.unused_data:
                raise CorruptChunk(f"its lz4 data holds {'more than ' if len(out) > size else ''}"
                                   f"{min(len(out), size)} bytes, the chunk says {size}")
            dest[:] = np.frombuffer(out, dtype=np.uint8)
        elif method == "":
            dest[:] = np.frombuffer(packed, dtype=np.uint8)
        else:
            raise CorruptChunk(f"unsupported compression {method!r}")
    except CorruptChunk:
        raise
    except Exception as err:  # zstd and lz4 say damaged data, or a checksum, in their own words
        raise CorruptChunk(f"its {method} data is damaged ({err})") from None
    if checked_by(packed, method, crc) == "crc" and crc32(dest) != crc:
        raise CorruptChunk("its records fail the chunk's CRC-32")


def inflate(packed, method: str, size: int, crc: int = 0) -> np.ndarray:
    """A chunk's records in new memory (uint8, ``size`` bytes), checked as :func:`inflate_into`."""
    problem = size_problem(packed, method, size)
    if problem is not None:
        raise CorruptChunk(problem)
    dest = np.empty(size, dtype=np.uint8)
    inflate_into(packed, method, size, dest, crc)
    return dest


def first_frame(packed, method: str) -> bytes | None:
    """What the first zstd or lz4 frame of ``packed`` inflates to, whatever follows it (None where
    it does not inflate, or for "none"): for ``recover``, where a chunk's stated compressed size
    may be the damaged field and its frame whole.  Unchecked beyond the frame's own checksum: the
    caller checks the chunk's CRC."""
    try:
        if method == "zstd":
            return zstandard.ZstdDecompressor().decompressobj().decompress(bytes(packed))
        if method == "lz4":
            d = lz4.frame.LZ4FrameDecompressor()
            out = d.decompress(bytes(packed))
            return out if d.eof else None
    except Exception:  # whatever the codec says of damaged data
        return None
    return None


def inflate_head(packed, method: str, size: int, nbytes: int) -> bytes:
    """The first ``nbytes`` (at most ``size``) of a chunk's records, without inflating all of a
    zstd chunk: what its first records are.  Unchecked (a checksum needs the whole), so a caller
    only learns a layout from it and checks it against the whole chunk when it reads it."""
    problem = size_problem(packed, method, size)
    if problem is not None:
        raise CorruptChunk(problem)
    want = min(nbytes, size)
    try:
        if method == "zstd":
            reader, parts, got = zstandard.ZstdDecompressor().stream_reader(packed, read_across_frames=True), [], 0
            while got < want:
                part = reader.read(want - got)
                if not part:
                    break
                parts.append(part)
                got += len(part)
            return b"".join(parts)
        if method == "lz4":
            return lz4.frame.LZ4FrameDecompressor().decompress(packed, max_length=want)
        return bytes(packed[:want])
    except Exception as err:
        raise CorruptChunk(f"its {method} data is damaged ({err})") from None


__all__ = ["COMPRESSIONS", "CorruptChunk", "MAX_CHUNK", "checked_by", "compress", "crc32", "crc32_parallel", "declared_size", "first_frame", "inflate", "inflate_head",
           "inflate_into", "size_problem"]
