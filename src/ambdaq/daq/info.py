"""What a recording holds: topics, rates, duration, drops and metadata (``ambdaq info``)."""

from __future__ import annotations

from pathlib import Path

from ..mcap.mcapfile import McapFile
from ..mcap.reader import ambdaq_channels
from .recording import statistics_entry


def describe(path: str | Path) -> dict:
    """Summary of a finished MCAP file as a JSON-ready dict.

    Parameters
    ----------
    path : str or Path
        The recording.
    """
    f = McapFile(path)
    s = f.summary
    st = f.statistics
    meta = f.metadata()
    per_topic = {t: statistics_entry(f.path, t, v) for t, v in meta.get("ambdaq.statistics", {}).items()}
    start, end = f.span_ns
    duration = (end - start) * 1e-9
    ours = ambdaq_channels(f)
    topics = []
    for cid, ch in sorted(s.channels.items()):
        count = st.channel_message_counts.get(cid, 0) if st else 0
        schema = s.schemas.get(ch.schema_id)
        ts = per_topic.get(ch.topic, {})
        topics.append(
            {
                "topic": ch.topic,
                "schema": schema.name if schema else "",
                "messages": count,
                # a topic's rate over its own span (devices start and stop apart); else the file's
                "rate_hz": ts.get("rate_hz", round((count - 1) / duration, 3) if duration > 0 and count > 1 else 0.0),
                **{k: ts.get(k) for k in ("drops", "duplicates", "wraps", "restarts")},
                "device": ts.get("device", (ch.metadata or {}).get("device", "")),
                "fields": list(ours[ch.topic][1].fields) if ch.topic in ours else [],
            }
        )
    return {
        "path": str(f.path),
        "size_bytes": f.path.stat().st_size,
        "start_ns": start,
        "end_ns": end,
        "duration_s": round(duration, 6),
        "messages": st.message_count if st else 0,
        "chunks": st.chunk_count if st else 0,
        "compression": sorted({ci.compression or "none" for ci in f.chunks if not f.is_loose(ci)}),
        "indexed": bool(s.chunk_indexes) or not f.chunks,
        "summary": f.has_summary,
        "unchunked_messages": f.unchunked,
        "data_crc": bool(f.data_crc),
        "topics": topics,
        "metadata": {k: v for k, v in meta.items() if k != "ambdaq.statistics"},
        "attachments": [a.name for a in s.attachment_indexes],
    }


def format_text(d: dict) -> str:
    """``describe``'s dict as the human-readable text ``ambdaq info`` prints."""
    lines = [
        f"file:        {d['path']} ({d['size_bytes'] / 1e6:.1f} MB)",
        f"duration:    {d['duration_s']:.3f} s (first to last message)",
        f"messages:    {d['messages']} in {d['chunks']} chunks ({', '.join(d['compression']) or 'none'}"
        f"{'' if d['indexed'] else '; no indexes: Foxglove reads it whole'}"
        f"{'' if d['summary'] else '; no summary: read by walking its records'}"
        f"{'; some outside chunks' if d['unchunked_messages'] else ''})",
        "checked:     " + ("data section CRC-32" if d["data_crc"] else "no data section CRC: its metadata is unprotected"),
        "",
        f"{'topic':<18} {'messages':>10} {'rate Hz':>10} {'drops':>7} {'dups':>5} {'wraps':>5} {'restarts':>8}  fields",
    ]
    for t in d["topics"]:
        n = {k: "-" if t.get(k) is None else str(t[k]) for k in ("drops", "duplicates", "wraps", "restarts")}
        if not t["messages"]:  # a message or page that never came: no drop counts it, so say it
            lines.append(f"{t['topic']:<18} {'never received':>21}  {'':>7} {'':>5} {'':>5} {'':>8}  {', '.join(t['fields'])}")
            continue
        lines.append(f"{t['topic']:<18} {t['messages']:>10} {t['rate_hz']:>10.1f} {n['drops']:>7} {n['duplicates']:>5} "
                     f"{n['wraps']:>5} {n['restarts']:>8}  {', '.join(t['fields'])}")
    for name, meta in d["metadata"].items():
        lines.append("")
        lines.append(f"[{name}]")
        lines += [f"  {k} = {v}" for k, v in meta.items()]
    if d["attachments"]:
        lines.append("")
        lines.append("attachments: " + ", ".join(d["attachments"]))
    return "\n".join(lines)
