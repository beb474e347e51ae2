"""Rebuild an indexed MCAP file from an unfinished or damaged one (``ambdaq recover``).

The data section is walked record by record.  Schemas, channels, metadata and attachments are
kept; every chunk whose records decompress and match their CRC is re-emitted with fresh message
indexes; a chunk that is cut off or corrupt is counted and dropped, as is a truncated tail.
Statistics (samples, drops per topic) are recomputed from the recovered sequence numbers.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Metadata, Schema

from ..errors import BadInputError
from .mcapfile import MAGIC, BlockWriter, _read, decompress, iter_records
from .schema import MESSAGE_HEADER_SIZE, MESSAGE_OPCODE, TopicLayout, parse_schema
from .sequence import SampleCounts, SequenceTracker
from .writer import PROFILE


@dataclass
class RecoveryReport:
    """What recovery kept and dropped."""

    chunks_kept: int
    chunks_dropped: int
    messages: int
    bytes_dropped: int
    topics: dict[str, dict]

    def as_dict(self) -> dict:
        return {"chunks_kept": self.chunks_kept, "chunks_dropped": self.chunks_dropped, "messages": self.messages,
                "bytes_dropped": self.bytes_dropped, "topics": self.topics}


def _chunk_records(body: memoryview) -> bytes:
    """Decompress a chunk body and check its CRC; raises ValueError when damaged."""
    _start, _end, usize, crc, nlen = struct.unpack_from("<QQQII", body, 0)
    p = 8 + 8 + 8 + 4 + 4
    method = bytes(body[p : p + nlen]).decode()
    p += nlen
    (clen,) = struct.unpack_from("<Q", body, p)
    p += 8
    if p + clen > len(body):
        raise ValueError("chunk data runs past its record")
    data = decompress(bytes(body[p : p + clen]), method, usize)
    if len(data) != usize or (crc and zlib.crc32(data) != crc):
        raise ValueError("chunk CRC mismatch")
    return data


def recover(src: str | Path, dst: str | Path, *, overwrite: bool = False) -> RecoveryReport:
    """Recover the readable part of ``src`` into a new, finished, indexed file ``dst``.

    Parameters
    ----------
    src : str or Path
        The damaged or unfinished MCAP file (never modified).
    dst : str or Path
        The file to write; must not exist unless ``overwrite``.
    overwrite : bool
        Replace an existing ``dst``.
    """
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise BadInputError(f"{src}: no such file")
    if dst.exists() and (not overwrite or dst.resolve() == src.resolve()):
        raise BadInputError(f"{dst} exists: choose another -o" + ("" if dst.resolve() == src.resolve() else " or pass --overwrite"))
    data = src.read_bytes()
    if not data.startswith(MAGIC):
        raise BadInputError(f"{src}: not an MCAP file (bad magic bytes)")
    schemas: dict[int, Schema] = {}
    layouts: dict[int, TopicLayout] = {}
    stats: dict[int, SampleCounts] = {}
    trackers: dict[int, SequenceTracker] = {}
    kept = dropped = messages = 0
    consumed = len(MAGIC)
    tmp = dst.with_name(dst.name + ".part")
    with open(tmp, "wb") as out:
        w = BlockWriter(out, profile=PROFILE)
        for op, pos, body in iter_records(data, len(MAGIC)):
            consumed = pos + 9 + len(body)
            if op == Opcode.DATA_END or op == Opcode.FOOTER:
                break
            try:
                if op == Opcode.SCHEMA:
                    s = _read(Schema, body)
                    schemas[s.id] = s
                    w.add_schema(s.name, s.encoding, s.data, schema_id=s.id)
                elif op == Opcode.CHANNEL:
                    c = _read(Channel, body)
                    w.add_channel(c.topic, c.schema_id, c.message_encoding, c.metadata, channel_id=c.id)
                    s = schemas.get(c.schema_id)
                    group = parse_schema(s.name, s.data.decode(errors="replace")) if s is not None else None
                    if group is not None:
                        layouts[c.id] = TopicLayout(group)
                        stats[c.id] = SampleCounts((c.metadata or {}).get("device", ""))
                        trackers[c.id] = SequenceTracker()
                elif op == Opcode.METADATA:
                    m = _read(Metadata, body)
                    if m.name != "ambdaq.statistics":  # recomputed below
                        w.add_metadata(m.name, m.metadata)
                elif op == Opcode.ATTACHMENT:
                    a = _read(Attachment, body)
                    w.add_attachment(a.name, a.media_type, a.data, a.log_time)
                elif op == Opcode.CHUNK:
                    records = _chunk_records(body)
                    messages += _count(records, layouts, stats, trackers)
                    w.add_chunk_records(records)
                    kept += 1
            except Exception:
                if op == Opcode.CHUNK:
                    dropped += 1
                continue
        w.add_metadata("ambdaq.statistics", {w.channel_topic(cid): st.as_json() for cid, st in stats.items()})
        w.add_metadata("ambdaq.recovery", {"source": str(src), "chunks_kept": str(kept), "chunks_dropped": str(dropped),
                                           "bytes_dropped": str(len(data) - consumed)})
        w.finish()
    tmp.replace(dst)
    return RecoveryReport(kept, dropped, messages, len(data) - consumed,
                          {w.channel_topic(cid): {k: v for k, v in st.as_dict().items()
                                                  if k in ("samples", "drops", "duplicates", "wraps", "restarts")}
                           for cid, st in stats.items()})


def _count(records: bytes, layouts: dict[int, TopicLayout], stats: dict[int, SampleCounts],
           trackers: dict[int, SequenceTracker]) -> int:
    """Count messages of one chunk and update each topic's counts from the CDR seq (a recording
    never holds a duplicate: the recorder dropped them, so here they only count)."""
    n = 0
    seqs: dict[int, list[int]] = {}
    times: dict[int, list[int]] = {}
    for op, pos, body in iter_records(records, 0):
        if op != MESSAGE_OPCODE:
            continue
        n += 1
        cid, _s, log_time = struct.unpack_from("<HIQ", body, 0)
        if cid in layouts:
            # payload: cdr header u32, device_time i64, seq u32
            (seq,) = struct.unpack_from("<I", body, MESSAGE_HEADER_SIZE - 9 + 12)
            seqs.setdefault(cid, []).append(seq)
            times.setdefault(cid, []).append(log_time)
    for cid, sq in seqs.items():
        seq, t = np.array(sq, dtype=np.uint32), np.array(times[cid], dtype=np.int64)
        stats[cid].add(trackers[cid].admit(seq, t).counts(stats[cid].device, slice(0, seq.shape[0]), seq, t))
    return n
