"""Rebuild an indexed MCAP file from an unfinished or damaged one (``ambdaq recover``).

Every complete chunk is kept, wherever the damage is (docs/data-format.md, "Recovery"):

- **Chunks are found by what they are, not by where the record before them says.**  The file is
  scanned for the Chunk opcode; a candidate is a chunk when its header holds together (a known
  compression, its compressed data inside the file) and its records decompress to the CRC-32
  its header states.  Its end is taken from its own compressed size, so a damaged record
  length (its own or a neighbour's) costs nothing, and one bad byte costs at most the chunk it
  is in.
- **Schemas, channels, metadata and attachments** are read record by record in the stretches
  between chunks, each stretch until its first record that does not parse, and schemas and
  channels also inside the kept chunks (rosbag2's writer puts them there); the summary (after
  Data End) is read for the schema and channel records it repeats, so a damaged data-section
  channel record is still known.  A kept chunk's messages on a channel known from neither are
  dropped and counted (``orphan_messages``): without its channel record a message cannot be
  read.
- **Messages outside chunks** (a writer that does not chunk) are kept up to the first damage of
  their stretch and written as one chunk.
- **Statistics** (samples, drops per topic) are recomputed from the recovered sequence numbers;
  per topic the report says the seconds kept (samples) and lost (gaps in ``seq``), at the rate
  its device declared.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, ChunkIndex, Metadata, Schema

from ..errors import BadInputError
from ..mcap.codec import CorruptChunk, crc32, declared_size, first_frame, inflate
from ..mcap.mcapfile import FOOTER_SIZE, MAGIC, BlockWriter, _read, chunk_header, iter_records, message_indexes_of, rows_index
from ..output import check_output
from ..mcap.schema import MESSAGE_HEADER_SIZE, MESSAGE_OPCODE, TopicLayout, parse_schema
from .sequence import SampleCounts, SequenceTracker
from .writer import PROFILE

KNOWN_OPCODES = {int(op) for op in Opcode}


@dataclass
class RecoveryReport:
    """What recovery kept and dropped."""

    chunks_kept: int
    chunks_dropped: int
    messages: int
    bytes_dropped: int
    topics: dict[str, dict]
    orphan_messages: int = 0

    def as_dict(self) -> dict:
        return {"chunks_kept": self.chunks_kept, "chunks_dropped": self.chunks_dropped, "messages": self.messages,
                "orphan_messages": self.orphan_messages, "bytes_dropped": self.bytes_dropped, "topics": self.topics}


def chunk_at(data: bytes, pos: int) -> tuple[bytes, int] | None:
    """The records of the chunk whose record starts at ``pos`` and the offset just past its data,
    or None unless a whole, intact chunk is there (see the module docstring)."""
    h = chunk_header(data, pos)
    if h is None:
        return None
    packed = data[h.data_start : h.data_end]
    # the header's size is a hint where the frame states its own: the CRC says whether the data is whole
    size = declared_size(packed, h.compression) or h.uncompressed_size
    try:
        records = inflate(packed, h.compression, size, h.crc).tobytes()
    except CorruptChunk:  # damaged data, or a damaged compressed size around a whole frame
        records = first_frame(packed, h.compression)
        if records is None or not h.crc:  # the CRC alone can then say the records are whole
            return None
    if (crc32(records) != h.crc) if h.crc else size != h.uncompressed_size:
        return None
    return records, h.data_end


def find_chunks(data: bytes, start: int) -> tuple[list[tuple[int, int, bytes]], int]:
    """Every intact chunk from ``start`` on: (record offset, end offset, records), in file order;
    and how many candidates had a chunk's header but not its data (damaged chunks)."""
    found, damaged, pos = [], 0, start
    while True:
        q = data.find(bytes([Opcode.CHUNK]), pos)
        if q < 0 or q + 9 > len(data):
            return found, damaged
        got = chunk_at(data, q)
        if got is None:
            damaged += _looks_like_a_chunk(data, q)
            pos = q + 1
            continue
        records, end = got
        found.append((q, end, records))
        pos = end


def _looks_like_a_chunk(data: bytes, pos: int) -> int:
    """1 when a chunk's header is at ``pos`` (its record length agreeing with where its data ends)
    but its data did not check: a damaged chunk; else 0."""
    h = chunk_header(data, pos)
    return int(h is not None and pos + 9 + h.record_length == h.data_end)


def recover(src: str | Path, dst: str | Path, *, overwrite: bool = False, index: bool = True) -> RecoveryReport:
    """Recover the readable part of ``src`` into a new, finished file ``dst``.

    Parameters
    ----------
    src : str or Path
        The damaged or unfinished MCAP file (never modified).
    dst : str or Path
        The file to write; must not exist unless ``overwrite``.
    overwrite : bool
        Replace an existing ``dst``.
    index : bool
        Write message and chunk indexes (:class:`~.mcapfile.BlockWriter`): also what indexes a
        file recorded with ``--no-index``.
    """
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise BadInputError(f"{src}: no such file")
    if dst.exists() and dst.resolve() == src.resolve():
        raise BadInputError(f"{dst} exists: it is the file recovered; choose another -o")
    check_output(dst, overwrite)
    data = src.read_bytes()
    if not data.startswith(MAGIC):
        raise BadInputError(f"{src}: not an MCAP file (bad magic bytes)")
    chunks, damaged = find_chunks(data, len(MAGIC))
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: list[Metadata] = []
    attachments: list[Attachment] = []
    covered = len(MAGIC) + sum(end - pos for pos, end, _r in chunks)
    bounds = [len(MAGIC), *[x for pos, end, _r in chunks for x in (pos, end)], len(data)]
    loose: list[bytes] = []
    for a, b in zip(bounds[0::2], bounds[1::2]):
        covered += _read_stretch(data, a, b, schemas, channels, metadata, attachments, loose)
    if loose:  # a writer that does not chunk: its messages become one chunk of the recovered file
        chunks = [*chunks, (len(data), len(data), b"".join(loose))]
    for _pos, _end, records in chunks:  # writers such as rosbag2's put them inside the chunks
        _chunk_definitions(records, schemas, channels)
    layouts, stats, trackers = {}, {}, {}
    tmp = dst.with_name(dst.name + ".part")
    messages = orphans = 0
    per_channel: dict[int, int] = {}
    with open(tmp, "wb") as out:
        w = BlockWriter(out, profile=PROFILE, index=index)
        for s in schemas.values():
            w.add_schema(s.name, s.encoding, s.data, schema_id=s.id)
        for c in channels.values():
            if c.schema_id not in schemas and c.schema_id != 0:
                continue
            w.add_channel(c.topic, c.schema_id, c.message_encoding, c.metadata, channel_id=c.id)
            s = schemas.get(c.schema_id)
            group = parse_schema(s.name, s.data.decode(errors="replace")) if s is not None else None
            if group is not None:
                layouts[c.id] = TopicLayout(group)
                stats[c.id] = SampleCounts((c.metadata or {}).get("device", ""))
                trackers[c.id] = SequenceTracker()
        known = {c.id for c in channels.values() if c.schema_id in schemas or c.schema_id == 0}
        for m in metadata:
            if m.name not in ("ambdaq.statistics", "ambdaq.recovery"):  # recomputed below
                w.add_metadata(m.name, m.metadata)
        for a in attachments:
            w.add_attachment(a.name, a.media_type, a.data, a.log_time)
        for _pos, _end, records in chunks:
            records, lost = _known_only(records, known)
            orphans += lost
            found = message_indexes_of(records)[0]  # once per chunk: counted here, indexed by the writer
            messages += _count(records, found, layouts, stats, trackers, per_channel)
            w.add_chunk_records(records, found)
        rates = _declared_rates(metadata)
        written = _written_samples(metadata)
        topics = {}
        for cid, st in stats.items():
            topic = w.channel_topic(cid)
            d = {k: v for k, v in st.as_dict().items() if k in ("samples", "drops", "duplicates", "wraps", "restarts")}
            # lost: what the finished file said it held less what is kept; of an unfinished one,
            # the gaps in seq (a lost first or last chunk leaves none)
            lost = written[topic] - st.samples if topic in written else st.drops
            rate = rates.get(st.device)
            d["samples_lost"] = lost
            d["seconds_kept"] = round(st.samples / rate, 6) if rate else None
            d["seconds_lost"] = round(lost / rate, 6) if rate else None
            topics[topic] = d
        for cid in known - set(stats):  # another writer's topics: what was kept (its losses are not numbered)
            topics[w.channel_topic(cid)] = {"messages": per_channel.get(cid, 0)}
        indexed = _indexed_chunks(data)
        if indexed is not None:
            damaged = len(indexed - {pos for pos, _end, _r in chunks})
        dropped_bytes = len(data) - covered
        w.add_metadata("ambdaq.statistics", {w.channel_topic(cid): st.as_json() for cid, st in stats.items()})
        w.add_metadata("ambdaq.recovery", {"source": str(src), "chunks_kept": str(len(chunks)),
                                           "chunks_dropped": str(damaged), "orphan_messages": str(orphans),
                                           "bytes_dropped": str(dropped_bytes)})
        w.finish()
    tmp.replace(dst)
    return RecoveryReport(len(chunks), damaged, messages, dropped_bytes, topics, orphans)


def _read_stretch(data: bytes, start: int, end: int, schemas: dict, channels: dict, metadata: list,
                  attachments: list, loose: list) -> int:
    """Read the non-chunk records from ``start`` to ``end``; the bytes read.  After a record that
    does not parse, go on at the next offset where a record parses and the one after it starts
    (or the stretch ends) there: a damaged record costs itself and no more.  Messages outside
    chunks (a writer that does not chunk) go to ``loose`` as their record bytes, up to the first
    damage only: a message has no CRC, and one found after a resynchronisation could be any bytes."""
    pos, read, clean = start, 0, True
    while pos + 9 <= end:
        got = _record_at(data, pos, end)
        if got is None:
            pos = _next_record(data, pos + 1, end)
            clean = False
            continue
        op, record, rec_end = got
        if op == MESSAGE_OPCODE and clean:
            loose.append(bytes(data[pos:rec_end]))
        if op == Opcode.SCHEMA:
            schemas.setdefault(record.id, record)
        elif op == Opcode.CHANNEL:
            channels.setdefault(record.id, record)
        elif op == Opcode.METADATA:
            metadata.append(record)
        elif op == Opcode.ATTACHMENT:
            attachments.append(record)
        read += rec_end - pos
        if op == Opcode.FOOTER and data[rec_end:end] == MAGIC:
            read += len(MAGIC)
            break
        pos = rec_end
    return read


RECORD_CLASSES = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.METADATA: Metadata,
                  Opcode.ATTACHMENT: Attachment}


def _record_at(data: bytes, pos: int, end: int):
    """(opcode, parsed record or None, end offset) of a record at ``pos`` that lies within ``end``,
    is of a known kind and, if ambdaq keeps it, parses; else None."""
    op, length = struct.unpack_from("<BQ", data, pos)
    rec_end = pos + 9 + length
    if op not in KNOWN_OPCODES or rec_end > end:
        return None
    cls = RECORD_CLASSES.get(op)
    if cls is None:
        return op, None, rec_end
    try:
        return op, _read(cls, memoryview(data)[pos + 9 : rec_end]), rec_end
    except Exception:  # whatever the record classes say of damaged bytes
        return None


def _next_record(data: bytes, pos: int, end: int) -> int:
    """The first offset from ``pos`` where a record is (:func:`_record_at`) and the next one starts
    or the stretch ends; ``end`` if none."""
    for q in range(pos, end - 8):
        if data[q] not in KNOWN_OPCODES:
            continue
        got = _record_at(data, q, end)
        if got is not None and (got[2] == end or (got[2] + 9 <= end and _record_at(data, got[2], end) is not None)):
            return q
    return end



def _chunk_definitions(records: bytes, schemas: dict, channels: dict) -> None:
    """The Schema and Channel records a chunk holds (MCAP allows them there), for the messages
    after them (none in a chunk of rows of messages)."""
    if rows_index(records) is not None:
        return
    for op, pos, body in iter_records(records, 0):
        if op in (Opcode.SCHEMA, Opcode.CHANNEL):
            got = _record_at(records, pos, pos + 9 + len(body))
            if got is not None and got[1] is not None:
                target = schemas if op == Opcode.SCHEMA else channels
                target.setdefault(got[1].id, got[1])


def _known_only(records: bytes, known: set[int]) -> tuple[bytes, int]:
    """``records`` without the messages on channels not in ``known``, and how many those were."""
    rows = rows_index(records)
    if rows is not None and rows.keys() <= known:
        return records, 0
    keep, lost, clean = [], 0, True
    for op, pos, body in iter_records(records, 0):
        if op == MESSAGE_OPCODE and struct.unpack_from("<H", body, 0)[0] not in known:
            lost += 1
            clean = False
            continue
        keep.append(bytes(records[pos : pos + 9 + len(body)]))
    return (records if clean else b"".join(keep)), lost


def _written_samples(metadata: list[Metadata]) -> dict[str, int]:
    """Samples per topic that a finished file's ``ambdaq.statistics`` says it held."""
    out = {}
    for m in metadata:
        if m.name == "ambdaq.statistics":
            for topic, text in m.metadata.items():
                try:
                    out[topic] = int(json.loads(text)["samples"])
                except (ValueError, KeyError, TypeError):
                    pass
    return out


def _indexed_chunks(data: bytes) -> set[int] | None:
    """The chunk offsets the summary's Chunk Index records give, if the footer and summary hold."""
    fpos = len(data) - len(MAGIC) - FOOTER_SIZE
    if fpos < len(MAGIC) or data[-len(MAGIC):] != MAGIC:
        return None
    op, length, summary_start = struct.unpack_from("<BQQ", data, fpos)
    if op != Opcode.FOOTER or length != FOOTER_SIZE - 9 or not len(MAGIC) <= summary_start < fpos:
        return None
    out = set()
    for op, _pos, body in iter_records(data, summary_start, fpos):
        if op == Opcode.CHUNK_INDEX:
            try:
                out.add(_read(ChunkIndex, body).chunk_start_offset)
            except Exception:  # a damaged index: no count from it
                return None
    return out


def _declared_rates(metadata: list[Metadata]) -> dict[str, float]:
    """Each device's declared sample rate (Hz), from its ``ambdaq.device.<name>`` metadata."""
    out = {}
    for m in metadata:
        if m.name.startswith("ambdaq.device."):
            try:
                out[m.name[len("ambdaq.device."):]] = float(m.metadata["sample_rate_hz"])
            except (KeyError, ValueError):
                pass
    return out


def _count(records: bytes, found: dict[int, np.ndarray], layouts: dict[int, TopicLayout],
           stats: dict[int, SampleCounts], trackers: dict[int, SequenceTracker], per_channel: dict[int, int]) -> int:
    """Count the messages of one chunk (``found``: its message index entries), per channel too,
    and update each ambdaq topic's counts from the CDR seq (a recording never holds a duplicate:
    the recorder dropped them, so here they only count)."""
    buf = np.frombuffer(records, dtype=np.uint8)
    for cid, idx in found.items():
        per_channel[cid] = per_channel.get(cid, 0) + idx.shape[0]
        if cid in layouts:  # payload: cdr header u32, device_time i64, seq u32
            at = idx["offset"].astype(np.int64) + MESSAGE_HEADER_SIZE + 12
            seq = buf[at[:, None] + np.arange(4)].copy().view("<u4").ravel()
            t = idx["log_time"].astype(np.int64)
            stats[cid].add(trackers[cid].admit(seq, t).counts(stats[cid].device, slice(0, seq.shape[0]), seq, t))
    return sum(idx.shape[0] for idx in found.values())
