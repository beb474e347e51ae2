"""MCAP at block speed: a chunk writer that encodes whole blocks with numpy (a chunk per device),
and a memory-mapped reader of chunks, message indexes and the summary.

The file is standard MCAP (https://mcap.dev/spec): magic, header, schemas and channels, chunks
each followed by their message indexes (unless written without indexes), metadata and
attachments, data end, summary (schemas, channels, statistics, chunk/attachment/metadata
indexes, summary offsets), footer, magic.  The non-hot records are serialised by the official
``mcap`` package's record classes; only Message records, Chunks and Message Indexes are built
here, from numpy arrays.

Crash safety: every chunk is written and flushed to the OS as soon as it closes, and the
recorder closes them at least twice a second, so a killed writer leaves a file whose complete
chunks ``ambdaq recover`` (:mod:`.recover`) keeps.
"""

from __future__ import annotations

import io
import mmap
import os
import struct
from collections import defaultdict
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from .. import __version__
from ..errors import BadInputError
from .codec import (COMPRESSIONS, CorruptChunk, compress, crc32, crc32_parallel, inflate, inflate_head, inflate_into,
                    size_problem)
from .schema import MESSAGE_OPCODE

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = f"ambdaq/{__version__}"
FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_INDEX_DTYPE = np.dtype([("log_time", "<u8"), ("offset", "<u8")])  # a Message Index entry
_MESSAGE_HEAD = struct.Struct("<BQHIQ")  # opcode, length, channel id, sequence, log time


CHUNK_HEAD = struct.Struct("<QQQII")  # message start, end, uncompressed size, CRC-32, compression name length
CHUNK_COMPRESSIONS = {b"": "", b"zstd": "zstd", b"lz4": "lz4"}


@dataclass(frozen=True)
class ChunkHeader:
    """What a Chunk record's header says: its record length, uncompressed size, CRC-32 (0: none),
    compression, and where its compressed data lies (``data_start`` .. ``data_end``)."""

    record_length: int
    uncompressed_size: int
    crc: int
    compression: str
    data_start: int
    data_end: int


def chunk_header(data, pos: int) -> ChunkHeader | None:
    """The header of the Chunk record at ``pos``, or None unless one is there: the Chunk opcode, a
    known compression and compressed data that ends inside ``data``.  The record length is
    reported, not relied on (recovery finds chunks whose length field is damaged)."""
    n = len(data)
    head = pos + 9
    if pos + 1 > n or data[pos] != Opcode.CHUNK or head + CHUNK_HEAD.size > n:
        return None
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    _start, _end, usize, crc, nlen = CHUNK_HEAD.unpack_from(data, head)
    p = head + CHUNK_HEAD.size
    if nlen > 4 or p + nlen + 8 > n:
        return None
    method = CHUNK_COMPRESSIONS.get(bytes(data[p : p + nlen]))
    if method is None:
        return None
    (clen,) = struct.unpack_from("<Q", data, p + nlen)
    start = p + nlen + 8
    if start + clen > n:
        return None
    return ChunkHeader(length, usize, crc, method, start, start + clen)


CHUNK_SIZE = 4 << 20
"""Uncompressed chunk size limit, bytes (a block larger than a chunk's room is split at a sample
instant).  ``load`` pays a fixed cost per chunk and topic, so smaller chunks read slower (1 MiB:
1.01x, 2 MiB: 0.79x, 4 MiB: 0.55x Parquet's time; 8 MiB 0.56x), while the file size does not
change (bench_read.py, 2026-11-27).  A damaged chunk
costs 0.6 s of the spindle with ground truth.  A paced recording closes its chunks at the flush
interval anyway (0.5 s of the spindle: 2.7 MB, with ground truth 3.6 MB)."""
@dataclass
class _OpenChunk:
    """Messages of the chunk being built: record bytes and per-channel index pieces."""

    parts: list[bytes] = field(default_factory=list)
    size: int = 0
    start: int = 2**64 - 1
    end: int = 0
    index: dict[int, list[np.ndarray]] = field(default_factory=lambda: defaultdict(list))


class BlockWriter:
    """Writes an MCAP file block by block.

    Parameters
    ----------
    stream : binary file object
        Where to write; must support ``tell``.
    compression : {"zstd", "lz4", "none"}
        Chunk compression.
    chunk_size : int
        Close a chunk when its uncompressed records reach this many bytes.
    profile : str
        MCAP profile string of the header.
    index : bool
        Write each chunk's Message Indexes and the summary's Chunk Indexes (the MCAP
        specification makes both optional).  Without them a file is 0.63x the size
        (docs/performance.md): readers find the chunks by walking the file (:attr:`McapFile.chunks`)
        and Foxglove reads it whole before it shows it, as it does any file without chunk indexes.
    """

    def __init__(
        self, stream: BinaryIO, *, compression: str = "zstd", chunk_size: int = CHUNK_SIZE, profile: str = "",
        index: bool = True,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise BadInputError(f"compression must be one of {', '.join(COMPRESSIONS)}, not {compression!r}")
        self._out = stream
        self._compression = compression
        self._chunk_size = chunk_size
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._index = index
        self._chunk_indexes: list[ChunkIndex] = []  # every chunk's, written to the summary only with index
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = defaultdict(int)
        self._start = 2**64 - 1
        self._end = 0
        self._chunks: dict[tuple[int, ...], _OpenChunk] = {}  # open chunks, one per row of channels
        self._finished = False
        self._data_crc: int | None = 0  # CRC-32 of the data section so far; None once Data End is written
        self._emit(MAGIC)
        self._write_record(Header(profile=profile, library=LIBRARY))

    # --- records outside chunks ---------------------------------------------------------------

    def _emit(self, data: bytes | memoryview) -> None:
        """Write ``data``; before Data End, also into the data section's CRC-32 (MCAP's
        ``data_section_crc``: every byte from the magic up to the Data End record)."""
        if self._data_crc is not None:
            self._data_crc = crc32(data, self._data_crc)
        self._out.write(data)

    def _write_record(self, record) -> int:
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        offset = self._out.tell()
        self._emit(data)
        return offset

    def add_schema(self, name: str, encoding: str, data: bytes, schema_id: int | None = None) -> int:
        """Register a schema (id: the next free one, or ``schema_id``); returns its id."""
        sid = schema_id if schema_id is not None else len(self._schemas) + 1
        self._schemas[sid] = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._write_record(self._schemas[sid])
        return sid

    def add_channel(
        self, topic: str, schema_id: int, message_encoding: str, metadata: dict[str, str], channel_id: int | None = None
    ) -> int:
        """Register a channel (id: the next free one, or ``channel_id``); returns its id."""
        cid = channel_id if channel_id is not None else len(self._channels) + 1
        self._channels[cid] = Channel(
            id=cid, topic=topic, message_encoding=message_encoding, schema_id=schema_id, metadata=metadata
        )
        self._write_record(self._channels[cid])
        return cid

    def channel_topic(self, channel_id: int) -> str:
        return self._channels[channel_id].topic

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a metadata record (name -> string map)."""
        rec = Metadata(name=name, metadata=dict(data))
        offset = self._write_record(rec)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=self._out.tell() - offset, name=name))

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time: int) -> None:
        """Write an attachment (e.g. the rig file); ``log_time`` in ns."""
        rec = Attachment(log_time=log_time, create_time=log_time, name=name, media_type=media_type, data=data)
        offset = self._out.tell()
        self._write_record(rec)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=self._out.tell() - offset,
                log_time=log_time,
                create_time=log_time,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )

    # --- messages ------------------------------------------------------------------------------

    def add_messages(self, records: np.ndarray, layout: list[tuple[int, int, int]], log_time: np.ndarray) -> None:
        """Append a block of Message records, interleaved by sample instant.

        Rows of one layout go into a chunk of their own (a device's chunks hold its rows and
        nothing else), so that a reader sees one constant stride through all of a device's chunks
        and can hand out its fields as views of the inflated records (docs/data-format.md).

        Parameters
        ----------
        records : ndarray of uint8, shape (n, row_size)
            Row i holds, back to back, the complete Message records of every channel for
            sample instant i.
        layout : list of (channel_id, offset, size)
            Where each channel's record sits in a row, in bytes.
        log_time : ndarray of uint64, shape (n,)
            Log time of each row, in ns (non-decreasing).
        """
        n, row = records.shape
        key = tuple(cid for cid, _offset, _size in layout)
        chunk = self._chunks.setdefault(key, _OpenChunk())
        # a block larger than a chunk's room is split at an instant: chunks stay near chunk_size
        while n > 0 and chunk.size + n * row > self._chunk_size:
            take = max(1, -(-(self._chunk_size - chunk.size) // row))
            self._add_rows(key, records[:take], layout, log_time[:take])
            records, log_time, n = records[take:], log_time[take:], n - take
            chunk = self._chunks.setdefault(key, _OpenChunk())
        if n:
            self._add_rows(key, records, layout, log_time)

    def _add_rows(self, key: tuple[int, ...], records: np.ndarray, layout: list[tuple[int, int, int]],
                  log_time: np.ndarray) -> None:
        """Append rows to the open chunk of their layout; close it once it reaches chunk_size."""
        n, row = records.shape
        chunk = self._chunks[key]
        if self._index:  # each channel's entries computed: its record sits at one offset in every row
            rows = chunk.size + np.arange(n, dtype=np.uint64) * np.uint64(row)
            for cid, offset, _size in layout:
                idx = np.empty(n, dtype=_INDEX_DTYPE)
                idx["log_time"] = log_time
                idx["offset"] = rows + np.uint64(offset)
                chunk.index[cid].append(idx)
        for cid, _offset, _size in layout:
            self._counts[cid] += n
        chunk.parts.append(records.tobytes())
        chunk.size += n * row
        chunk.start = min(chunk.start, int(log_time[0]))
        chunk.end = max(chunk.end, int(log_time[-1]))
        if chunk.size >= self._chunk_size:
            self._close(key)

    def add_message(self, channel_id: int, sequence: int, log_time: int, payload: bytes) -> None:
        """Append one Message record (the path for rare messages such as events)."""
        record = struct.pack("<BQHIQQ", MESSAGE_OPCODE, 22 + len(payload), channel_id, sequence & 0xFFFFFFFF,
                             log_time, log_time) + payload
        row = np.frombuffer(record, dtype=np.uint8).reshape(1, -1)
        self.add_messages(row, [(channel_id, 0, len(record))], np.array([log_time], dtype=np.uint64))

    def close_chunks(self) -> None:
        """Compress and write every open chunk and its message indexes, earliest first, then flush
        to the OS (with no open chunk, what is written so far: the header and the records before
        any message)."""
        for key in sorted(self._chunks, key=lambda k: self._chunks[k].start):
            self._close(key)
        self._out.flush()

    def _close(self, key: tuple[int, ...]) -> None:
        chunk = self._chunks.pop(key)
        self._write_chunk(b"".join(chunk.parts), chunk.start, chunk.end,
                          {cid: np.concatenate(p) for cid, p in chunk.index.items()})

    def _write_chunk(self, data: bytes, start: int, end: int, index: dict[int, np.ndarray]) -> None:
        method = self._compression
        packed = compress(data, method)
        name = b"" if method == "none" else method.encode()
        offset = self._out.tell()
        header = struct.pack(
            "<BQQQQI", Opcode.CHUNK, 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(packed), start, end, len(data), crc32(data)
        ) + struct.pack("<I", len(name)) + name + struct.pack("<Q", len(packed))
        self._emit(header)
        self._emit(packed)
        chunk_length = self._out.tell() - offset
        index_start = self._out.tell()
        index_offsets = {}
        for cid, idx in index.items() if self._index else ():
            index_offsets[cid] = self._out.tell()
            body = idx.tobytes()
            self._emit(struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + len(body), cid, len(body)))
            self._emit(body)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=offset,
                chunk_length=chunk_length,
                message_index_offsets=index_offsets,
                message_index_length=self._out.tell() - index_start,
                compression=name.decode(),
                compressed_size=len(packed),
                uncompressed_size=len(data),
            )
        )
        self._start = min(self._start, start)
        self._end = max(self._end, end)
        self._out.flush()

    def add_chunk_records(self, data: bytes, arrays: dict[int, np.ndarray] | None = None) -> None:
        """Write already-built chunk records (Message records only), indexed by ``arrays`` (each
        channel's message index entries) or by a scan (:func:`message_indexes_of`).

        Used by recovery to re-emit the messages of chunks from a damaged file.
        """
        if arrays is None:
            arrays, _end = message_indexes_of(data)
        if not arrays:
            return
        for cid, idx in arrays.items():
            self._counts[cid] += idx.shape[0]
        start = min(int(a["log_time"].min()) for a in arrays.values())
        end = max(int(a["log_time"].max()) for a in arrays.values())
        self._write_chunk(data, start, end, arrays)

    # --- finish --------------------------------------------------------------------------------

    def finish(self) -> None:
        """Close the open chunk, write data end, the summary and the footer."""
        if self._finished:
            return
        self._finished = True
        self.close_chunks()
        crc, self._data_crc = self._data_crc, None
        self._write_record(DataEnd(data_section_crc=crc))
        summary_start = self._out.tell()
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: int, records) -> None:
            start = builder.count
            for r in records:
                r.write(builder)
            if builder.count > start:
                offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                             group_length=builder.count - start))

        stats = Statistics(
            message_count=sum(self._counts.values()),
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=len(self._attachment_indexes),
            metadata_count=len(self._metadata_indexes),
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._start if self._counts else 0,
            message_end_time=self._end,
            channel_message_counts=dict(self._counts),
        )
        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes if self._index else ())
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for o in offsets:
            o.write(builder)
        summary = builder.end()
        crc = crc32(summary)
        crc = crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self._out.write(summary)
        self._write_record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc))
        self._out.write(MAGIC)
        self._out.flush()


# --- reading -------------------------------------------------------------------------------------


def iter_records(data, pos: int, end: int | None = None) -> Iterator[tuple[int, int, memoryview]]:
    """Walk MCAP records in ``data`` from ``pos`` to ``end``: yields (opcode, offset, body).

    Stops silently at the first record that runs past the end (a truncated tail).
    """
    view = memoryview(data)
    end = len(view) if end is None else end
    while pos + 9 <= end:
        op, length = struct.unpack_from("<BQ", view, pos)
        if pos + 9 + length > end:
            return
        yield op, pos, view[pos + 9 : pos + 9 + length]
        pos += 9 + length


def rows_index(data) -> dict[int, np.ndarray] | None:
    """:func:`message_indexes_of` in one numpy pass where the chunk's records are rows (every
    chunk ambdaq writes: the same channels' Message records in the same order and of the same
    lengths, one row per sample instant), each row's opcode, length and channel checked against the
    first's; None where they are not."""
    buf = np.frombuffer(data, dtype=np.uint8)
    places, at, seen = [], 0, set()
    while at + 25 <= buf.shape[0]:  # the first row: records up to the first channel seen again
        op, length, cid = struct.unpack_from("<BQH", buf, at)
        if op != MESSAGE_OPCODE or length < 22 or cid in seen:
            break
        seen.add(cid)
        places.append((cid, at))
        at += 9 + length
    stride = at
    if not places or buf.shape[0] % stride:
        return None
    n = buf.shape[0] // stride
    for _cid, at in places:
        for start in (at, at + 3):  # opcode, length and channel: two overlapping 8-byte words
            word = np.ndarray((n,), dtype="<u8", buffer=buf, offset=start, strides=(stride,))
            if not np.all(word == word[0]):
                return None
    out = {}
    for cid, at in places:
        idx = np.empty(n, dtype=_INDEX_DTYPE)
        idx["log_time"] = np.ndarray((n,), dtype="<u8", buffer=buf, offset=at + 15, strides=(stride,))
        idx["offset"] = at + stride * np.arange(n, dtype=np.uint64)
        out[cid] = idx
    return out


def message_indexes_of(data) -> tuple[dict[int, np.ndarray], int]:
    """What the Message Indexes of the chunk records ``data`` would say: each channel's (log time,
    offset) entries (16 bytes), and the offset where the records stopped (``len(data)`` unless a
    record runs past the end: :func:`iter_records`).  Rows of records are indexed in one numpy
    pass (:func:`rows_index`); any other chunk is walked record by record."""
    rows = rows_index(data)
    if rows is not None:
        return rows, len(data)
    found: dict[int, list[tuple[int, int]]] = defaultdict(list)
    end = 0
    for op, pos, body in iter_records(data, 0):
        if op == MESSAGE_OPCODE and len(body) >= 22:
            cid, _seq, log_time = struct.unpack_from("<HIQ", body, 0)
            found[cid].append((log_time, pos))
        end = pos + 9 + len(body)
    return {cid: np.array(rows, dtype=np.uint64).view(_INDEX_DTYPE).ravel() for cid, rows in found.items()}, end


def _read(cls, body: memoryview):
    return cls.read(ReadDataStream(io.BytesIO(body)))


@dataclass
class Summary:
    """What the summary section of a finished file says."""

    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    statistics: Statistics | None
    chunk_indexes: list[ChunkIndex]
    attachment_indexes: list[AttachmentIndex]
    metadata_indexes: list[MetadataIndex]


@dataclass
class _Walk:
    """What a walk of the data section found (:meth:`McapFile._walk`)."""

    chunks: list[ChunkIndex] = field(default_factory=list)
    data_end: int | None = None  # where the Data End record starts (None: the file has none)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[MetadataIndex] = field(default_factory=list)
    attachments: list[AttachmentIndex] = field(default_factory=list)


class McapFile:
    """A finished MCAP file opened for fast reading (memory-mapped).

    Any valid MCAP file opens: with a summary and its indexes (ambdaq's files, rosbag2's), without
    chunk or message indexes (``--no-index``), without a summary at all, with its messages outside
    chunks; a file without a summary, or without chunk indexes, is walked record by record as the
    official stream reader does (:meth:`_walk`), and its messages outside chunks are read as if
    each run of them were an uncompressed chunk.

    What is checked on opening (docs/data-format.md, "What is checked"): the footer, the summary's
    CRC-32 and the data section's (every byte from the magic to Data End: schemas, channels,
    chunks, indexes, metadata, attachments) where the writer stored them, and every chunk's header
    against its index before any memory is sized from it (:meth:`chunks`).

    Raises :class:`~ambdaq.errors.BadInputError` for anything that is not a complete, intact MCAP
    file, naming ``ambdaq recover`` when the file looks like an unfinished or damaged recording.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            with open(self.path, "rb") as fh:
                size = os.fstat(fh.fileno()).st_size
                if size == 0:
                    raise BadInputError(f"{self.path}: empty file, not an MCAP file")
                self._data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except FileNotFoundError:
            raise BadInputError(f"{self.path}: no such file") from None
        except IsADirectoryError:
            raise BadInputError(f"{self.path}: is a directory, not an MCAP file") from None
        except PermissionError:
            raise BadInputError(f"{self.path}: permission denied") from None
        data = self._data
        if data[: len(MAGIC)] != MAGIC:
            raise BadInputError(f"{self.path}: not an MCAP file (bad magic bytes)")
        if len(data) < len(MAGIC) * 2 + 9 + FOOTER_SIZE or data[-len(MAGIC) :] != MAGIC:
            raise BadInputError(
                f"{self.path}: MCAP file is truncated or unfinished (no footer); "
                f"rebuild it with: ambdaq recover {self.path} -o FIXED.mcap"
            )
        fpos = len(data) - len(MAGIC) - FOOTER_SIZE
        op, length, summary_start, summary_offset_start, crc = struct.unpack_from("<BQQQI", data, fpos)
        if op != Opcode.FOOTER or length != 20 or summary_start > fpos or 0 < summary_start < len(MAGIC):
            raise BadInputError(f"{self.path}: the footer is damaged; try: ambdaq recover {self.path} -o FIXED.mcap")
        self._loose: dict[int, ChunkHeader] = {}  # runs of messages outside chunks, read as chunks
        self._walked: _Walk | None = None
        self.data_crc = 0  # until the data section's CRC is checked below, no chunk relies on it
        if summary_start == 0:  # no summary (the specification allows it): everything from a walk
            self._summary_start = fpos
            walk = self._walk()
            self._definitions_in_chunks(walk)
            self.summary = Summary(walk.schemas, walk.channels, None, [], walk.attachments, walk.metadata)
            data_end = walk.data_end
        else:
            if crc != 0 and crc32(data[summary_start : fpos + 1 + 8 + 16]) != crc:
                raise BadInputError(f"{self.path}: MCAP summary is corrupted (CRC mismatch); try: ambdaq recover")
            self.summary = self._read_summary(summary_start, fpos)
            self._summary_start = summary_start
            if self._definitions_missing():  # the summary need not repeat them (the specification)
                walk = self._walk()
                if self._definitions_missing():
                    self._definitions_in_chunks(walk)
                for cid, ch in walk.channels.items():
                    self.summary.channels.setdefault(cid, ch)
                for sid, sc in walk.schemas.items():
                    self.summary.schemas.setdefault(sid, sc)
            data_end = summary_start - 13  # where ambdaq's and the official writer put Data End
            if not (data_end >= len(MAGIC) and data[data_end] == Opcode.DATA_END
                    and struct.unpack_from("<Q", data, data_end + 1)[0] == 4):
                data_end = self._walk().data_end
        crc = struct.unpack_from("<I", data, data_end + 9)[0] if data_end is not None else 0
        if crc and crc32_parallel(memoryview(data)[:data_end]) != crc:
            raise BadInputError(f"{self.path}: the data section fails its CRC-32: a byte of it (metadata, a chunk, "
                                "an index) is not what was written; try: ambdaq recover")
        self.data_crc = crc
        """The data section's CRC-32 as written and checked on opening (0: the writer stored none)."""

    def _definitions_missing(self) -> bool:
        """Whether a channel that messages are counted or indexed on, or a schema a channel names,
        is missing from the summary (or, with chunks and no count, there is no channel at all)."""
        s = self.summary
        used = set(s.statistics.channel_message_counts) if s.statistics is not None else set()
        for ci in s.chunk_indexes:
            used.update(ci.message_index_offsets)
        if used - s.channels.keys() or any(c.schema_id and c.schema_id not in s.schemas for c in s.channels.values()):
            return True
        return bool(s.chunk_indexes) and not s.channels

    def _read_summary(self, start: int, end: int) -> Summary:
        s = Summary({}, {}, None, [], [], [])
        try:
            for op, _pos, body in iter_records(self._data, start, end):
                if op == Opcode.SCHEMA:
                    r = _read(Schema, body)
                    s.schemas[r.id] = r
                elif op == Opcode.CHANNEL:
                    r = _read(Channel, body)
                    s.channels[r.id] = r
                elif op == Opcode.STATISTICS:
                    s.statistics = _read(Statistics, body)
                elif op == Opcode.CHUNK_INDEX:
                    s.chunk_indexes.append(_read(ChunkIndex, body))
                elif op == Opcode.ATTACHMENT_INDEX:
                    s.attachment_indexes.append(_read(AttachmentIndex, body))
                elif op == Opcode.METADATA_INDEX:
                    s.metadata_indexes.append(_read(MetadataIndex, body))
        except Exception as err:  # any parse failure of the summary is a corrupted file
            raise BadInputError(f"{self.path}: MCAP summary is corrupted ({err}); try: ambdaq recover") from None
        return s

    def _walk(self) -> _Walk:
        """The data section walked record by record, as the official stream reader reads a file:
        its chunks (each with the Message Indexes that follow it), runs of messages outside chunks
        (each read as an uncompressed chunk of their records), schemas and channels (also those a
        writer such as rosbag2's put inside chunks), metadata and attachments, and where Data End
        is.  Walked once, when first needed.  A record that runs past the data section is a damaged
        file (BadInputError naming ``ambdaq recover``), never a file that silently ends there."""
        if self._walked is not None:
            return self._walked
        data, end, pos, w = self._data, self._summary_start, len(MAGIC), _Walk()
        run: list[int] = []  # the run of loose messages being collected: first offset, log times
        times: list[int] = []

        def close_run(at: int) -> None:
            if run:
                start = run[0]
                self._loose[start] = ChunkHeader(at - start, at - start, 0, "", start, at)
                w.chunks.append(ChunkIndex(
                    message_start_time=min(times), message_end_time=max(times), chunk_start_offset=start,
                    chunk_length=at - start, message_index_offsets={}, message_index_length=0, compression="",
                    compressed_size=at - start, uncompressed_size=at - start))
                run.clear()
                times.clear()

        try:
            while pos + 9 <= end:
                op, length = struct.unpack_from("<BQ", data, pos)
                if pos + 9 + length > end:
                    break
                body = memoryview(data)[pos + 9 : pos + 9 + length]
                if op != MESSAGE_OPCODE:
                    close_run(pos)
                if op == Opcode.DATA_END:
                    w.data_end = pos
                    break
                if op == Opcode.CHUNK:
                    h = chunk_header(data, pos)
                    if h is None or h.data_end > pos + 9 + length:
                        break
                    start_time, end_time = struct.unpack_from("<QQ", data, pos + 9)
                    w.chunks.append(ChunkIndex(
                        message_start_time=start_time, message_end_time=end_time, chunk_start_offset=pos,
                        chunk_length=9 + length, message_index_offsets={}, message_index_length=0,
                        compression=h.compression,
                        compressed_size=h.data_end - h.data_start, uncompressed_size=h.uncompressed_size))
                elif op == Opcode.MESSAGE_INDEX and w.chunks and w.chunks[-1].chunk_start_offset not in self._loose:
                    last = w.chunks[-1]
                    if last.chunk_start_offset + last.chunk_length + last.message_index_length == pos:
                        last.message_index_offsets[struct.unpack_from("<H", body, 0)[0]] = pos
                        last.message_index_length += 9 + length
                elif op == MESSAGE_OPCODE and length >= 22:
                    if not run:
                        run.append(pos)
                    times.append(struct.unpack_from("<Q", body, 6)[0])
                elif op == Opcode.SCHEMA:
                    r = _read(Schema, body)
                    w.schemas[r.id] = r
                elif op == Opcode.CHANNEL:
                    r = _read(Channel, body)
                    w.channels[r.id] = r
                elif op == Opcode.METADATA:
                    w.metadata.append(MetadataIndex(offset=pos, length=9 + length, name=_read(Metadata, body).name))
                elif op == Opcode.ATTACHMENT:
                    a = _read(Attachment, body)
                    w.attachments.append(AttachmentIndex(
                        offset=pos, length=9 + length, log_time=a.log_time, create_time=a.create_time,
                        data_size=len(a.data), name=a.name, media_type=a.media_type))
                pos += 9 + length
        except Exception as err:  # a record the record classes cannot parse
            raise BadInputError(f"{self.path}: the record at byte {pos} is damaged ({err}); "
                                "try: ambdaq recover") from None
        close_run(pos)
        if not (pos == end or w.data_end is not None):
            raise BadInputError(f"{self.path}: the record at byte {pos} is damaged (it runs past the data section); "
                                "try: ambdaq recover")
        self._walked = w
        return w

    def _definitions_in_chunks(self, w: _Walk) -> None:
        """Schemas and channels that a writer such as rosbag2's put inside chunks, where no summary
        repeats them (every chunk inflated once)."""
        for ci in w.chunks:
            if ci.chunk_start_offset in self._loose:
                continue
            try:
                for op, _pos, body in iter_records(self.chunk_records(ci), 0):
                    if op == Opcode.SCHEMA:
                        r = _read(Schema, body)
                        w.schemas.setdefault(r.id, r)
                    elif op == Opcode.CHANNEL:
                        r = _read(Channel, body)
                        w.channels.setdefault(r.id, r)
            except BadInputError:
                raise
            except Exception as err:
                raise self.damaged_chunk(ci, f"a schema or channel record in it does not parse ({err})") from None

    @cached_property
    def chunks(self) -> list[ChunkIndex]:
        """Every chunk of the file, as its Chunk Index describes it: the summary's, or where the
        summary lists none (a file written without indexes, ``--no-index``, a file without a
        summary, another writer's unchunked messages) what a walk of the data section finds
        (:meth:`_walk`).  Each is checked against its own header before anything is sized from it."""
        found = self.summary.chunk_indexes or self._walk().chunks
        for ci in found:
            self._chunk_data(ci)
        return found

    @cached_property
    def statistics(self) -> Statistics | None:
        """The file's Statistics record, or where it has none, the same counted from its messages
        (every chunk inflated once); None for a file without messages or channels."""
        if self.summary.statistics is not None:
            return self.summary.statistics
        counts: dict[int, int] = defaultdict(int)
        start, end = 2**64 - 1, 0
        for ci in self.chunks:
            found, _stop = message_indexes_of(self.chunk_records(ci))
            for cid, idx in found.items():
                counts[cid] += idx.shape[0]
                start, end = min(start, int(idx["log_time"].min())), max(end, int(idx["log_time"].max()))
        s = self.summary
        return Statistics(message_count=sum(counts.values()), schema_count=len(s.schemas),
                          channel_count=len(s.channels), attachment_count=len(s.attachment_indexes),
                          metadata_count=len(s.metadata_indexes), chunk_count=len(self.chunks) - len(self._loose),
                          message_start_time=start if counts else 0, message_end_time=end,
                          channel_message_counts=dict(counts))

    @property
    def span_ns(self) -> tuple[int, int]:
        """The log times of its first message and its last, any topic, in ns ((0, 0) without messages):
        the span every duration ambdaq states of a file is (``info``, the record summary, a
        :class:`~ambdaq.daq.recording.Recording`)."""
        st = self.statistics
        return (st.message_start_time, st.message_end_time) if st is not None and st.message_count else (0, 0)

    @property
    def unchunked(self) -> bool:
        """Whether messages lie outside chunks (read as uncompressed chunks of their records)."""
        return bool(self.chunks) and bool(self._loose)

    def is_loose(self, ci: ChunkIndex) -> bool:
        """Whether ``ci`` is a run of messages outside chunks rather than a chunk record."""
        return ci.chunk_start_offset in self._loose

    @property
    def has_summary(self) -> bool:
        """Whether the file has a summary section (else it was walked, :meth:`_walk`)."""
        return self._summary_start != len(self._data) - len(MAGIC) - FOOTER_SIZE

    def metadata(self) -> dict[str, dict[str, str]]:
        """All metadata records, name -> map."""
        out = {}
        for idx in self.summary.metadata_indexes:
            out[idx.name] = self._indexed(Metadata, idx.offset, idx.name).metadata
        return out

    def _indexed(self, cls, offset: int, name: str):
        """The record of class ``cls`` an index puts at ``offset``; a damaged one is a BadInputError."""
        try:
            op, length = struct.unpack_from("<BQ", self._data, offset)
            if offset + 9 + length > len(self._data):
                raise ValueError("it runs past the end of the file")
            return _read(cls, memoryview(self._data)[offset + 9 : offset + 9 + length])
        except Exception as err:  # whatever the record classes say of damaged bytes
            raise BadInputError(f"{self.path}: the {cls.__name__.lower()} record {name!r} is damaged ({err}); "
                                "try: ambdaq recover") from None

    def attachments(self) -> dict[str, bytes]:
        """All attachments, name -> bytes."""
        out = {}
        for idx in self.summary.attachment_indexes:
            out[idx.name] = self._indexed(Attachment, idx.offset, idx.name).data
        return out

    def _chunk_data(self, ci: ChunkIndex) -> tuple[ChunkHeader, memoryview]:
        """The header of the chunk ``ci`` names and its compressed data, as the index describes them
        (:meth:`_check_chunk`); BadInputError otherwise."""
        h = self._loose.get(ci.chunk_start_offset) or chunk_header(self._data, ci.chunk_start_offset)
        problem = "not a chunk" if h is None else _disagreement(ci, h)
        if problem is None:
            packed = memoryview(self._data)[h.data_start : h.data_end]
            problem = size_problem(packed, h.compression, h.uncompressed_size)
        if problem is not None:
            raise self.damaged_chunk(ci, problem)
        return h, packed

    def damaged_chunk(self, ci: ChunkIndex, problem: str) -> BadInputError:
        """The one line that refuses the chunk ``ci``: the file, the chunk, what is wrong."""
        return BadInputError(f"{self.path}: the chunk at byte {ci.chunk_start_offset} is damaged: {problem}; "
                             "try: ambdaq recover")

    def _crc(self, h: ChunkHeader) -> int:
        """The CRC-32 a chunk's records are still to be checked against: none where the data
        section's CRC, checked on opening, already covered its bytes as stored (an uncompressed
        chunk's are its records; a compressed one's inflate to one result only)."""
        return 0 if self.data_crc else h.crc

    def chunk_records(self, ci: ChunkIndex) -> np.ndarray:
        """The records of one chunk, inflated into new memory and checked (:func:`.codec.inflate`)."""
        h, packed = self._chunk_data(ci)
        try:
            return inflate(packed, h.compression, h.uncompressed_size, self._crc(h))
        except CorruptChunk as err:
            raise self.damaged_chunk(ci, str(err)) from None

    def inflate_into(self, ci: ChunkIndex, dest: np.ndarray) -> None:
        """Inflate one chunk's records into ``dest`` (uint8, exactly its uncompressed size), every
        byte, checked (:func:`.codec.inflate_into`); BadInputError naming the chunk otherwise."""
        h, packed = self._chunk_data(ci)
        try:
            inflate_into(packed, h.compression, h.uncompressed_size, dest, self._crc(h))
        except CorruptChunk as err:
            raise self.damaged_chunk(ci, str(err)) from None

    def chunk_head(self, ci: ChunkIndex, nbytes: int) -> bytes:
        """The first ``nbytes`` (at most) of one chunk's records, unchecked: what its first records
        are, without inflating all of it (:func:`.codec.inflate_head`)."""
        h, packed = self._chunk_data(ci)
        try:
            return inflate_head(packed, h.compression, h.uncompressed_size, nbytes)
        except CorruptChunk as err:
            raise self.damaged_chunk(ci, str(err)) from None

    def message_index(self, ci: ChunkIndex, channel_id: int) -> np.ndarray:
        """(log_time, offset) of a channel's messages in one chunk, from its Message Index; the
        record must lie within the chunk's message indexes and hold whole entries."""
        pos = ci.message_index_offsets[channel_id]
        first = ci.chunk_start_offset + ci.chunk_length
        if not first <= pos <= first + ci.message_index_length - 15 or pos + 15 > self._summary_start:
            raise BadInputError(f"{self.path}: the message index at byte {pos} lies outside its chunk's indexes; "
                                "try: ambdaq recover")
        op, length, cid, nbytes = struct.unpack_from("<BQHI", self._data, pos)
        if (op != Opcode.MESSAGE_INDEX or cid != channel_id or length != 6 + nbytes or nbytes % 16
                or pos + 15 + nbytes > first + ci.message_index_length):
            raise BadInputError(f"{self.path}: the message index at byte {pos} is damaged; try: ambdaq recover")
        return np.frombuffer(self._data, dtype=_INDEX_DTYPE, count=nbytes // 16, offset=pos + 15)


def _disagreement(ci: ChunkIndex, h: ChunkHeader) -> str | None:
    """How a chunk's own header disagrees with its Chunk Index (None where it does not): the
    summary is CRC-checked, the header is not, so a size it states is taken only where both agree."""
    if h.compression != ci.compression:
        return f"its header says compression {h.compression or 'none'!r}, its index {ci.compression or 'none'!r}"
    if h.uncompressed_size != ci.uncompressed_size:
        return f"its header says {h.uncompressed_size} bytes of records, its index {ci.uncompressed_size}"
    if h.data_end - h.data_start != ci.compressed_size:
        return f"its header says {h.data_end - h.data_start} compressed bytes, its index {ci.compressed_size}"
    if h.data_end > ci.chunk_start_offset + ci.chunk_length:
        return "its data runs past the record its index describes"
    return None


def message_view(records: bytes | memoryview | np.ndarray, index: np.ndarray, message_dtype: np.dtype,
                 channel_id: int) -> np.ndarray:
    """The Message records of channel ``channel_id`` that the Message Index entries ``index``
    (:meth:`McapFile.message_index`: log time and offset) point at in ``records``, header and
    payload, as a structured array of ``message_dtype`` (:meth:`TopicLayout.message_dtype`).

    Where the records sit at a constant stride (every file ambdaq writes: one row of records per
    sample instant) this is a strided view into ``records``, no copy: a caller copying each field
    out touches every byte once.  Otherwise each record is gathered by index (one copy).

    A Message Index has no checksum, so its entries are checked against the records (opcode,
    length, channel, log time): at a constant stride the first and last record (a damaged offset
    breaks the stride, and the records are covered by the chunk's checksum: a caller takes the
    log times from the records), otherwise every record.  BadInputError if one is not the
    message its entry names.
    """
    offsets = index["offset"]
    n = offsets.shape[0]
    size = message_dtype.itemsize
    if n == 0:
        return np.empty(0, dtype=message_dtype)
    buf = np.frombuffer(records, dtype=np.uint8)
    first = int(offsets[0])
    stride = int(offsets[1]) - first if n > 1 else size
    # the constant-stride case is checked with one pass over the offsets (a decreasing pair wraps
    # in uint64 and fails the comparison); its ends bound every record in between
    # a record's length field counts what follows it: the record less its opcode and length
    expected = (MESSAGE_OPCODE, size - 9, channel_id)
    if (stride >= size and first + (n - 1) * stride + size <= buf.shape[0]
            and (n == 1 or np.all(np.diff(offsets) == stride))):
        for i in (0, n - 1):  # two records: struct, not numpy, for the fixed cost per chunk and topic
            opcode, length, channel, _sequence, log_time = _MESSAGE_HEAD.unpack_from(buf, first + i * stride)
            if (opcode, length, channel) != expected or log_time != index["log_time"][i]:
                raise BadInputError(f"message index does not point at channel {channel_id}'s messages")
        return np.ndarray(shape=(n,), dtype=message_dtype, buffer=buf, offset=first, strides=(stride,))
    if int(offsets.max()) + size > buf.shape[0]:
        raise BadInputError("message index points past the end of its chunk")
    rows = buf[offsets.astype(np.int64)[:, None] + np.arange(size)]
    view = np.ascontiguousarray(rows).view(message_dtype).ravel()
    if not (np.all(view["opcode"] == expected[0]) and np.all(view["length"] == expected[1])
            and np.all(view["channel"] == channel_id) and np.array_equal(view["log_time"], index["log_time"])):
        raise BadInputError(f"message index does not point at channel {channel_id}'s messages")
    return view
