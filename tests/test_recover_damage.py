"""``ambdaq recover`` against damage anywhere in a file (issue 18 item 1): the recovered file holds
every chunk that an independent reading (the official mcap package's Chunk parser, with its CRC
check) proves intact, and no other."""

from __future__ import annotations

import io
import json
from collections import Counter

import pytest
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.sim.source import SimSource
from ambdaq.speed import SpeedProfile

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

RATE = 10_000.0


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """0.3 s of the spindle in 16 KiB chunks (about 30 of them), and its layout as the official
    reader sees it."""
    path = tmp_path_factory.mktemp("damage") / "run.mcap"
    Recorder([SimSource("spindle", seed=3, speed=SpeedProfile(30000, 30000), block_s=0.01)], path,
             RecordOptions(duration_s=0.3, chunk_size=16 * 1024, fsync=False)).run()
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    return path, path.read_bytes(), summary


def intact_counts(damaged: bytes, summary) -> tuple[Counter, int]:
    """Messages per topic in the chunks the official parser reads whole from ``damaged`` (at the
    offsets the undamaged file's index gives), and how many chunks those are."""
    topics = {cid: ch.topic for cid, ch in summary.channels.items()}
    counts, chunks = Counter(), 0
    for ci in summary.chunk_indexes:
        pos = ci.chunk_start_offset
        if damaged[pos] != Opcode.CHUNK:
            continue
        try:
            chunk = Chunk.read(ReadDataStream(io.BytesIO(damaged[pos + 9 : pos + ci.chunk_length])))
            records = breakup_chunk(chunk, validate_crc=True)
        except Exception:  # whatever the official parser says about damaged data
            continue
        chunks += 1
        counts.update(topics[r.channel_id] for r in records if isinstance(r, Message))
    return counts, chunks


def damage_offsets(data: bytes, summary) -> dict[str, int]:
    """Where to flip a byte: every field of a chunk record's header, its data, its message index,
    the records before the first chunk, the metadata, data end, summary and footer."""
    cis = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    out = {"header record": 8, "schema region": 40, "channel region": cis[0].chunk_start_offset - 30}
    for name, ci in (("first", cis[0]), ("middle", cis[len(cis) // 2]), ("last", cis[-1])):
        p = ci.chunk_start_offset
        fields = {"opcode": 0, "length low byte": 1, "length high byte": 8, "start time": 9, "end time": 17,
                  "uncompressed size": 25, "crc": 33, "name length": 37, "name": 41, "compressed size": 45,
                  "first data byte": 53, "middle of the data": ci.chunk_length // 2, "last data byte": ci.chunk_length - 1}
        out.update({f"{name} chunk {k}": p + v for k, v in fields.items()})
        index = min(ci.message_index_offsets.values())
        out[f"{name} chunk message index opcode"] = index
        out[f"{name} chunk message index length"] = index + 1
    summary_start = int.from_bytes(data[-8 - 20 : -8 - 12], "little")  # the footer's summary_start
    data_end = data.rfind(bytes([Opcode.DATA_END]), 0, summary_start)
    out.update({"data end": data_end, "summary start": summary_start, "summary middle": (summary_start + len(data)) // 2,
                "footer": len(data) - 8 - 20, "last magic byte": len(data) - 1})
    return out


@pytest.mark.parametrize("edge_chunks", [False, pytest.param(True, marks=pytest.mark.long)],
                         ids=["middle chunk and the rest of the file", "first and last chunks"])
def test_recover_keeps_exactly_the_intact_chunks_wherever_the_damage(recording, tmp_path, run_cli, edge_chunks):
    """Each field of the middle chunk, and every record outside the chunks; ``-m long`` the same
    fields of the first and the last chunk."""
    path, data, summary = recording
    offsets = damage_offsets(data, summary)
    assert len(summary.chunk_indexes) >= 10 and len(offsets) >= 45
    for where, offset in offsets.items():
        if where.startswith(("first chunk", "last chunk")) != edge_chunks:
            continue
        damaged = bytearray(data)
        damaged[offset] ^= 0xFF
        bad, fixed = tmp_path / "bad.mcap", tmp_path / "fixed.mcap"
        bad.write_bytes(damaged)
        r = run_cli("recover", bad, "-o", fixed, "--overwrite", "--json")
        assert r.exit_code == 0, (where, r.output)
        report = json.loads(r.stdout)
        want, chunks = intact_counts(bytes(damaged), summary)
        with open(fixed, "rb") as fh:  # the official reader indexes what recover wrote
            got = make_reader(fh).get_summary()
        got_counts = {got.channels[cid].topic: n for cid, n in got.statistics.channel_message_counts.items() if n}
        assert got_counts == dict(want), where
        assert report["chunks_kept"] == chunks, where
        for topic, n in want.items():  # seconds kept: every recovered sample, at the declared 10 kHz
            assert report["topics"][topic]["samples"] == n
            assert report["topics"][topic]["seconds_kept"] == pytest.approx(n / RATE, abs=1e-9), where
        # what is lost is said: the chunks, and per topic the samples and seconds
        assert report["chunks_dropped"] == len(summary.chunk_indexes) - chunks, where
        for cid, n in summary.statistics.channel_message_counts.items():
            topic = summary.channels[cid].topic
            if topic in report["topics"]:
                kept = report["topics"][topic]
                assert kept["samples_lost"] == n - want[topic], where
                assert kept["seconds_lost"] == pytest.approx((n - want[topic]) / RATE, abs=1e-9), where


def test_a_flipped_record_length_mid_file_costs_nothing(recording, tmp_path, run_cli):
    """The case first reported: one record-length field flipped mid-file left recover with no
    messages; every chunk is intact, so every message comes back."""
    path, data, summary = recording
    ci = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)[len(summary.chunk_indexes) // 2]
    damaged = bytearray(data)
    damaged[ci.chunk_start_offset + 4] ^= 0x40  # the chunk record's length, far past the end of the file
    (tmp_path / "bad.mcap").write_bytes(damaged)
    r = run_cli("recover", tmp_path / "bad.mcap", "-o", tmp_path / "fixed.mcap", "--json")
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert report["chunks_kept"] == len(summary.chunk_indexes) and report["chunks_dropped"] == 0
    assert report["messages"] == sum(summary.statistics.channel_message_counts.values())


def test_without_an_index_a_damaged_chunk_is_still_counted(recording, tmp_path, run_cli):
    """An unfinished file (no summary) with one chunk's data damaged: the chunk is found by its
    header and counted lost, the others kept."""
    path, data, summary = recording
    cis = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    damaged = bytearray(data[: cis[-1].chunk_start_offset])  # cut before the last chunk: no summary
    middle = cis[len(cis) // 2]
    damaged[middle.chunk_start_offset + middle.chunk_length // 2] ^= 0xFF
    (tmp_path / "bad.mcap").write_bytes(damaged)
    r = run_cli("recover", tmp_path / "bad.mcap", "-o", tmp_path / "fixed.mcap", "--json")
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert report["chunks_dropped"] == 1 and report["chunks_kept"] == len(cis) - 2
