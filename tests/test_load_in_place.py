"""A device's chunks hold its rows alone, so ``load`` hands out its fields as views of the inflated
records; files of ambdaq 0.1, whose chunks interleave devices, are read as before; and memory a
caller still holds is never handed out again."""

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile
from ambdaq.acquisition.writer import RecordingWriter
from ambdaq.drivers.signals import SampleBlock, SignalGroup

OLD = Path(__file__).parent / "data" / "ambdaq_0_1_two_devices.mcap"
T0 = 1_700_000_000_000_000_000
BLOCKS, PER_BLOCK = 10, 100


def two_devices(path: Path, chunk_size: int = 64 << 10, blocks: int = BLOCKS) -> None:
    """What tests/data/ambdaq_0_1_two_devices.mcap holds (written by ambdaq 0.1's writer, commit
    ee0928e, with this code), written by today's writer: two devices at 10 kHz, their blocks of
    100 instants alternating, one with a 64-bit integer field."""
    w = RecordingWriter(path, fsync=False, chunk_size=chunk_size)
    w.add_device("amp", [SignalGroup("/amp/current", "CoilCurrent", ("x", "y"), ("A", "A"))], {"url": "sim://amp"}, {})
    w.add_device("ctl", [SignalGroup("/ctl/gap", "Gap", ("front_x", "front_y", "rear_x"), ("m", "m", "m")),
                         SignalGroup("/ctl/count", "Counter", ("n",), ("",), ("int64",))], {"url": "sim://ctl"}, {})
    for b in range(blocks):
        k = np.arange(b * PER_BLOCK, (b + 1) * PER_BLOCK)
        host = T0 + k * 100_000
        w.write("amp", SampleBlock(k * 100_000, k.astype(np.uint32),
                                   {"/amp/current": np.stack([np.sin(k / 7.0), np.cos(k / 7.0)], 1)}, host))
        w.write("ctl", SampleBlock(k * 100_000 + 7, k.astype(np.uint32),
                                   {"/ctl/gap": np.stack([k * 1e-6, -k * 1e-6, np.full(k.shape, 2.5e-4)], 1),
                                    "/ctl/count": np.array([(int(i) * 3_000_000_007,) for i in k], dtype=[("n", "<i8")])},
                                   host + 50_000))
    w.close()


def assert_the_values_written(rec) -> None:
    """Every value equal to what was written, bit for bit (no arithmetic between)."""
    k = np.arange(BLOCKS * PER_BLOCK)
    amp, gap, count = rec["/amp/current"], rec["/ctl/gap"], rec["/ctl/count"]
    np.testing.assert_array_equal(amp["x"], np.sin(k / 7.0))
    np.testing.assert_array_equal(amp["y"], np.cos(k / 7.0))
    np.testing.assert_array_equal(amp.log_time, T0 + k * 100_000)
    np.testing.assert_array_equal(amp.device_time, k * 100_000)
    np.testing.assert_array_equal(gap["front_y"], -k * 1e-6)
    np.testing.assert_array_equal(gap["rear_x"], 2.5e-4)
    np.testing.assert_array_equal(gap.log_time, T0 + k * 100_000 + 50_000)
    np.testing.assert_array_equal(gap.device_time, k * 100_000 + 7)
    np.testing.assert_array_equal(gap.seq, k)
    assert count["n"].dtype == np.int64  # past 2**53: exact only as an integer
    np.testing.assert_array_equal(count["n"], k * 3_000_000_007)


def test_a_device_s_chunks_hold_its_rows_alone_and_its_fields_are_views_of_them(tmp_path):
    path = tmp_path / "two.mcap"
    two_devices(path)
    f = McapFile(path)
    device = {cid: ch.metadata["device"] for cid, ch in f.summary.channels.items()}
    chunks = f.summary.chunk_indexes
    assert len(chunks) >= 4  # each device's records span chunks, so the stride runs from one to the next
    for ci in chunks:
        assert len({device[cid] for cid in ci.message_index_offsets}) == 1
    rec = load(path)
    assert_the_values_written(rec)
    gap, count = rec["/ctl/gap"], rec["/ctl/count"]
    row = gap.fields["front_x"].strides[0]
    # one instant: both topics' records, each a 31-byte record header, the 4-byte CDR header,
    # device time, seq and status (20 bytes), and its values
    assert row == 2 * (31 + 20) + 3 * 8 + 8
    assert np.may_share_memory(gap["front_x"], count["n"])  # one buffer, no copy
    # the official reader and ROS 2 decoder read the same values from the same file
    with open(path, "rb") as fh:
        decoded = [(c.topic, m.log_time, d) for _s, c, m, d in
                   make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(log_time_order=True)]
    theirs = [d.rear_x for topic, _t, d in decoded if topic == "/ctl/gap"]
    np.testing.assert_array_equal(theirs, gap["rear_x"])
    np.testing.assert_array_equal([d.n for topic, _t, d in decoded if topic == "/ctl/count"], count["n"])


def test_a_file_of_ambdaq_0_1_whose_chunks_interleave_devices_reads_as_before():
    f = McapFile(OLD)
    device = {cid: ch.metadata["device"] for cid, ch in f.summary.channels.items()}
    assert any(len({device[cid] for cid in ci.message_index_offsets}) == 2 for ci in f.summary.chunk_indexes)
    rec = load(OLD)
    assert_the_values_written(rec)
    assert not np.may_share_memory(rec["/ctl/gap"]["front_x"], rec["/ctl/count"]["n"])  # copied out


def test_a_time_window_reads_in_place_too(tmp_path):
    path = tmp_path / "two.mcap"
    two_devices(path)
    gap = load(path, start=0.025, end=0.0749)["/ctl/gap"]  # s after the first message, at T0
    k = (gap.log_time - T0 - 50_000) // 100_000
    np.testing.assert_array_equal(k, np.arange(250, 749))
    np.testing.assert_array_equal(gap["front_x"], k * 1e-6)


def test_memory_a_caller_holds_is_never_handed_out_again(tmp_path):
    """``load`` uses the memory of recordings no longer referred to again (ambdaq.mcap.memory):
    a second load of a 4.0 MB file takes a small part of that from the allocator; arrays still
    held, even one field alone or a view of it, keep theirs through loads of equal size."""
    import tracemalloc

    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    two_devices(a, chunk_size=1 << 20, blocks=200)
    two_devices(b, chunk_size=512 << 10, blocks=200)
    records = sum(ci.uncompressed_size for ci in McapFile(b).summary.chunk_indexes)
    assert records == 200 * PER_BLOCK * (2 * (31 + 20) + 3 * 8 + 8 + (31 + 20) + 2 * 8)
    held = load(a)["/ctl/gap"]["front_x"][::2]  # the rest of the recording is let go
    kept = held.copy()
    load(b)
    tracemalloc.start()
    again = load(b)["/amp/current"]["x"]
    fresh = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert fresh < records / 4  # numpy reports its allocations to tracemalloc; the rest is Python's
    for _ in range(3):
        load(a), load(b)
    np.testing.assert_array_equal(held, kept)
    np.testing.assert_array_equal(again, np.sin(np.arange(200 * PER_BLOCK) / 7.0))
    assert not np.shares_memory(held, again)


def _held_forms(rec) -> dict:
    """One recording's arrays kept every way a user keeps them, and a copy of what each held."""
    import threading

    import pyarrow as pa

    gap, rotor = rec["/amb/gap"], rec["/amb/rotor"]
    x = gap["front_x"]
    forms = {
        "field": gap["front_y"],
        "slice": gap["rear_x"][5:-5:3],
        "asarray": np.asarray(gap["rear_y"]),
        "view as bytes": gap["front_x"].view(np.uint64)[::2],
        "memoryview": memoryview(rotor["speed"]),
        "frombuffer": np.frombuffer(memoryview(np.ascontiguousarray(x[:10])), dtype=np.float64),
        "pandas": gap.to_pandas(),
        "pandas column": gap.to_pandas()["front_x"],
        "pyarrow array": pa.array(rotor["angle"]),
        "pyarrow table": pa.table({"x": gap["front_x"], "t": gap.log_time}),
        "log times": gap.log_time,
        "topic": rec["/amb/current"],
        "dict": {"x": rec["/amb/current"]["front_x"][100:]},
    }
    forms["closure"] = (lambda a: (lambda: a))(rec["/amb/error"]["front_x"])
    box: dict = {}
    ready, done = threading.Event(), threading.Event()

    def hold() -> None:  # a thread that holds an array in a local while the main thread loads
        local = rec["/amb/error"]["rear_y"]
        box["copy"] = local.copy()
        ready.set()
        done.wait()
        box["after"] = local.copy()

    thread = threading.Thread(target=hold)
    thread.start()
    ready.wait()
    forms["thread"] = (thread, done, box)
    return forms


def _snapshot(forms: dict) -> dict:
    import pyarrow as pa

    out = {}
    for name, v in forms.items():
        if name == "thread":
            continue
        if isinstance(v, dict):
            v = v["x"]
        elif callable(v):
            v = v()
        elif isinstance(v, memoryview):
            v = np.asarray(v)
        elif isinstance(v, pa.Table):
            v = np.stack([c.to_numpy() for c in v.columns]).astype(np.float64)
        elif isinstance(v, pa.Array):
            v = v.to_numpy(zero_copy_only=False)
        elif hasattr(v, "fields") and hasattr(v, "topic"):  # a TopicData: every field
            v = np.stack(list(v.fields.values()))
        elif hasattr(v, "to_numpy"):
            v = v.to_numpy()
        out[name] = np.array(v, copy=True)
    return out


def test_arrays_a_user_holds_never_change_whatever_is_loaded_after(tmp_path, run_cli):
    """The memory ``load`` uses again is only memory no array refers to: a user's arrays of one
    load, held as fields, slices, views, ``np.asarray``, memoryviews, pandas frames and columns,
    pyarrow arrays and buffers, in a dict, a closure or another thread's locals, hold the same
    values through loads of other recordings of the same size (whose blocks would fit) and of
    the same file again."""
    files = []
    for seed in (1, 2, 3):
        f = tmp_path / f"s{seed}.mcap"
        assert run_cli("sim", "generate", "--duration", "0.6", "--seed", seed, "-q", "-o", f).exit_code == 0
        files.append(f)
    rec = load(files[0])
    forms = _held_forms(rec)
    before = _snapshot(forms)
    del rec
    for _round in range(3):
        for f in files:  # the same file again, and others after it (their values last in any reused block)
            other = load(f)
            for t in other:  # touch every topic, as a user would
                for name in other[t]:
                    assert other[t][name].shape[0] > 0
            del other
    thread, done, box = forms["thread"]
    done.set()
    thread.join()
    after = _snapshot(forms)
    for name, values in before.items():
        np.testing.assert_array_equal(after[name], values, err_msg=name)
    np.testing.assert_array_equal(box["after"], box["copy"], err_msg="thread")


def test_the_memory_kept_between_loads_is_bounded_and_can_be_given_back(tmp_path, run_cli, monkeypatch):
    """At most KEEP bytes are kept for the next load (a larger block is never kept: its memory goes
    when its arrays do), and ``release_memory`` gives back what no array refers to."""
    import gc
    import tracemalloc

    from ambdaq.daq import release_memory
    from ambdaq.mcap import memory

    f = tmp_path / "s.mcap"
    assert run_cli("sim", "generate", "--duration", "0.6", "-q", "-o", f).exit_code == 0
    gc.collect()  # what earlier tests of this process let go
    release_memory()
    tracemalloc.start()
    rec = load(f)
    loaded = tracemalloc.get_traced_memory()[0]
    del rec
    kept = tracemalloc.get_traced_memory()[0]
    assert memory.kept() > 0 and kept > loaded / 2  # kept for the next load
    assert release_memory() > 0 and memory.kept() == 0
    assert tracemalloc.get_traced_memory()[0] < loaded / 10  # given back
    monkeypatch.setattr(memory, "KEEP", 1 << 20)  # below this recording's columns
    rec = load(f)
    del rec
    assert memory.kept() <= 1 << 20 and tracemalloc.get_traced_memory()[0] < loaded / 10
    tracemalloc.stop()
