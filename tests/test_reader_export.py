"""The fast reader's options and the exports, against the data they came from."""

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile
from ambdaq.errors import BadInputError

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def test_load_selected_topics_and_time_window(spindle_file):
    rec = load(spindle_file, topics=["/amb/gap"], start=0.5, end=1.0)
    assert list(rec.topics) == ["/amb/gap"]
    t = rec["/amb/gap"].time
    assert t[0] == pytest.approx(0.5) and t[-1] == pytest.approx(1.0)
    full = load(spindle_file, topics=["/amb/gap"])["/amb/gap"]
    np.testing.assert_array_equal(rec["/amb/gap"]["rear_x"], full["rear_x"][5000:10001])


def test_unknown_topic_and_field_are_clear_errors(spindle_file):
    with pytest.raises(BadInputError, match="no ambdaq topic /amb/nope; topics: /amb/accel"):
        load(spindle_file, topics=["/amb/nope"])
    with pytest.raises(BadInputError, match="has no field 'middle_x'"):
        load(spindle_file, topics=["/amb/gap"])["/amb/gap"]["middle_x"]


def test_export_csv_npz_parquet_round_trip(spindle_file, tmp_path, run_cli):
    full = load(spindle_file, topics=["/amb/gap", "/amb/rotor"], end=0.1)
    r = run_cli("export", spindle_file, "--format", "csv", "--topic", "/amb/gap", "--topic", "/amb/rotor",
                "--end", "0.1", "-o", tmp_path / "csv")
    assert r.exit_code == 0, r.output
    data = pd.read_csv(tmp_path / "csv" / "amb_gap.csv")  # each column's unit in its header
    np.testing.assert_array_equal(data["front_x [m]"], full["/amb/gap"]["front_x"])
    # integer columns stay exact: ns stamps do not fit a float64 mantissa
    lines = (tmp_path / "csv" / "amb_rotor.csv").read_text().splitlines()
    assert lines[0] == "time [s],log_time_ns [ns],device_time_ns [ns],seq,angle [rad],speed [rad/s],keyphasor [1]"  # 1: dimensionless
    assert int(lines[2].split(",")[1]) == int(full["/amb/rotor"].log_time[1])

    r = run_cli("export", spindle_file, "--format", "npz", "--end", "0.1", "-o", tmp_path / "all.npz")
    assert r.exit_code == 0, r.output
    z = np.load(tmp_path / "all.npz")
    np.testing.assert_array_equal(z["/amb/gap/rear_y"], full["/amb/gap"]["rear_y"])
    np.testing.assert_array_equal(z["/amb/gap/log_time_ns"], full["/amb/gap"].log_time)

    r = run_cli("export", spindle_file, "--format", "parquet", "--topic", "/amb/gap", "--end", "0.1",
                "-o", tmp_path / "gap.parquet")
    assert r.exit_code == 0, r.output
    table = pq.read_table(tmp_path / "gap.parquet")
    np.testing.assert_array_equal(table.column("axial").to_numpy(), full["/amb/gap"]["axial"])
    # exporting again does not overwrite without --overwrite
    r = run_cli("export", spindle_file, "--format", "parquet", "--topic", "/amb/gap", "-o", tmp_path / "gap.parquet")
    assert r.exit_code == 2 and "exists" in r.output


def test_a_recording_is_a_read_only_mapping_with_short_reprs(spindle_file):
    """Issue 12, item 9: in a notebook a Recording lists its topics, reads like a mapping and
    shows a line, not every array."""
    rec = load(spindle_file)
    assert list(rec) == list(rec.topics) and len(rec) == 8 and "/amb/gap" in rec
    assert dict(rec.items())["/amb/gap"] is rec["/amb/gap"]
    text = repr(rec)
    assert "\n" not in text and len(text) < 600 and "spindle.mcap: 8 topics, 2.000 s" in text, text
    gap = rec["/amb/gap"]
    assert repr(gap) == ("<TopicData /amb/gap: 20000 samples, 2.000 s at 10000 Hz; front_x [m], front_y [m], "
                         "rear_x [m], rear_y [m], axial [m]>")
    assert gap.nominal_rate == 10000.0  # the rate the device declares, a value
    with pytest.raises(TypeError):
        rec["/amb/new"] = gap  # read-only


def test_to_pandas_has_the_time_as_index_and_the_units(spindle_file):
    gap = load(spindle_file, topics=["/amb/gap"])["/amb/gap"]
    df = gap.to_pandas()
    assert df.index.name == "time" and list(df.columns) == list(gap.fields)
    np.testing.assert_array_equal(df.index.to_numpy(), gap.time)
    np.testing.assert_array_equal(df["rear_y"].to_numpy(), gap["rear_y"])
    assert df.attrs["units"]["front_x"] == "m" and df.attrs["time_unit"] == "s" and df.attrs["topic"] == "/amb/gap"


def test_slices_by_time_an_index_pandas_resamples_and_one_frame_of_several_topics(spindle_file):
    """``between`` (s, as ``time``), ``to_pandas(index="timedelta")`` that ``resample`` takes, the
    UTC ``datetime`` index, and ``Recording.to_pandas`` of the gap and the accelerometer (another
    device, 800 Hz) on the gap's samples: each row the latest acceleration at or before it."""

    rec = load(spindle_file)
    gap = rec["/amb/gap"]
    part = gap.between(0.5, 0.6)
    inside = (gap.time >= 0.5 - 1e-12) & (gap.time < 0.6)
    assert len(part) == int(inside.sum()) > 0 and np.shares_memory(part["front_x"], gap["front_x"])
    np.testing.assert_array_equal(part["front_x"], gap["front_x"][inside])
    assert part.time[0] >= 0.5 and part.time[-1] < 0.6 and len(gap.between(5.0, 6.0)) == 0
    df = gap.to_pandas(index="timedelta")
    assert isinstance(df.index, pd.TimedeltaIndex)
    ms = df.resample("1ms").mean()  # 10 samples a millisecond at 10 kHz
    np.testing.assert_allclose(ms["front_x"].iloc[1], gap["front_x"][(gap.time >= 0.001) & (gap.time < 0.002)].mean())
    when = gap.to_pandas(index="datetime").index
    assert str(when.tz) == "UTC" and when[0].value == gap.log_time[0]
    both = rec.to_pandas(["/amb/gap", "/amb/accel"])
    accel = rec["/amb/accel"]
    assert len(both) == len(gap) and "/amb/accel.front_x" in both and both.attrs["units"]["/amb/accel.front_x"] == "m/s^2"
    at = np.searchsorted(accel.log_time, gap.log_time, side="right") - 1
    ok = (at >= 0) & (gap.log_time - accel.log_time[np.maximum(at, 0)] <= 1.5e9 / accel.nominal_rate)
    np.testing.assert_array_equal(both["/amb/accel.front_x"].to_numpy()[ok], accel["front_x"][at[ok]])
    assert both["/amb/accel.front_x"].isna().to_numpy()[~ok].all()
    with pytest.raises(BadInputError, match="is not a role"):
        rec.together("gap", "/amb/accel")


def _write_gap(path, order, official_chunk_size=None):
    """A /amb/gap file holding instants ``order`` (0..199, 100 us apart): written by the official
    writer (chunks cut where it likes), or by ours in blocks of 25 instants, one chunk each."""
    from ambdaq.mcap.schema import MESSAGE_HEADER_SIZE, TopicLayout
    from ambdaq.acquisition.writer import RecordingWriter
    from ambdaq.drivers.signals import SampleBlock, SignalGroup

    group = SignalGroup("/amb/gap", "Gap", ("front_x", "front_y"), ("m", "m"))
    log_time, values = (1_000_000_000 + order * 100_000).astype(np.int64), np.stack([order * 1e-6, -order * 1e-6], 1)
    if official_chunk_size:
        from mcap.writer import CompressionType, Writer

        layout = TopicLayout(group)
        with open(path, "wb") as fh:
            w = Writer(fh, chunk_size=official_chunk_size, compression=CompressionType.ZSTD)
            w.start()
            cid = w.register_channel("/amb/gap", "cdr", w.register_schema(layout.schema_name, "ros2msg",
                                                                          layout.schema_text.encode()))
            for i, t, v in zip(order, log_time, values):
                message = np.zeros(1, dtype=layout.message_dtype)  # the official writer adds the record header
                message["cdr_header"], message["device_time"], message["seq"], message["values"] = 0x100, i * 100_000, i, v
                w.add_message(cid, log_time=int(t), data=message.tobytes()[MESSAGE_HEADER_SIZE:], publish_time=0)
            w.finish()
        return
    w = RecordingWriter(path, chunk_size=25 * (31 + 36), fsync=False)
    w.add_device("rig", [group], {}, {})
    for a in range(0, len(order), 25):
        b = slice(a, a + 25)
        w.write("rig", SampleBlock(order[b] * 100_000, order[b].astype(np.uint32), {"/amb/gap": values[b]}, log_time[b]))
    w.close()


@pytest.mark.parametrize("order, official", [
    (np.arange(199, -1, -1), True),  # the official writer: one chunk, backwards
    (np.r_[np.arange(0, 200, 2), np.arange(1, 200, 2)], False),  # chunks in order inside, overlapping in time
])
def test_messages_written_out_of_time_order_are_loaded_in_time_order(tmp_path, order, official):
    """Messages out of log-time order within a chunk (a file in ambdaq's layout from another
    tool), or from one chunk to the next: every column comes back sorted by log time, each
    sample's fields still with its own seq."""
    path = tmp_path / "shuffled.mcap"
    _write_gap(path, order, 1 << 20 if official else None)
    assert len(McapFile(path).summary.chunk_indexes) == (1 if official else 8)
    gap = load(path)["/amb/gap"]
    np.testing.assert_array_equal(gap.log_time, 1e9 + np.arange(200) * 100_000)
    np.testing.assert_array_equal(gap.seq, np.arange(200))
    np.testing.assert_array_equal(gap.device_time, np.arange(200) * 100_000)
    np.testing.assert_array_equal(gap["front_x"], np.arange(200) * 1e-6)
    np.testing.assert_array_equal(gap["front_y"], -np.arange(200) * 1e-6)
    np.testing.assert_allclose(gap.time, np.arange(200) * 1e-4, atol=1e-12)


def test_a_workflow_takes_a_recording_already_loaded(spindle_file):
    """What the fleet does: open once, hand the recording to several workflows, each topic decoded
    once. A recording shown with fewer topics than the workflow needs is one clear error."""
    from ambdaq.daq import open_recording
    from ambdaq.workflows.runout import identify_recordings

    rec = load(spindle_file, topics=["/amb/gap", "/amb/rotor"])
    with pytest.raises(BadInputError, match="no current signals"):
        identify_recordings([rec], [1, 2], "fit")
    opened = open_recording(spindle_file)
    by_open = identify_recordings([opened], [1, 2], "fit")
    gap = opened["/amb/gap"]
    assert identify_recordings([opened], [1, 2], "fit").coef.weights == by_open.coef.weights
    assert opened["/amb/gap"] is gap  # decoded once, kept
    by_rec = identify_recordings([load(spindle_file, topics=["/amb/gap", "/amb/current", "/amb/rotor"])], [1, 2], "fit")
    assert by_rec.coef.weights == by_open.coef.weights and by_rec.paths == by_open.paths


def test_export_mf4_reads_back_with_asammdf(spindle_file, tmp_path, run_cli):
    """MDF 4 for the XCP world, as CANape, INCA and asammdf show it: every topic a channel group
    named after it, whose source is the device that recorded it; every channel's name unique in
    the file (``amb.gap.front_x`` beside ``amb.current.front_x``), so that ``get(name)`` finds each
    and ``to_dataframe()`` has no ``_0``/``_1`` suffixes; units and values what the recording holds,
    its metadata attached; read back by asammdf (its own reader)."""
    import json

    asammdf = pytest.importorskip("asammdf")
    full = load(spindle_file, end=0.2)
    r = run_cli("export", spindle_file, "--format", "mf4", "--end", "0.2", "-o", tmp_path / "run.mf4")
    assert r.exit_code == 0, r.output
    with asammdf.MDF(tmp_path / "run.mf4") as mdf:
        groups = {g.channel_group.acq_name: g for g in mdf.groups}
        assert set(groups) == set(full)
        names = [ch.name for g in mdf.groups for ch in g.channels]
        masters = [n for n in names if n == "time"]  # each group's time channel
        assert len(set(names) - {"time"}) == len(names) - len(masters)  # every other name once
        for topic, data in full.items():
            assert groups[topic].channel_group.acq_source.name == "rig"  # sim://spindle: one device, "rig"
            prefix = topic.strip("/").replace("/", ".")
            for field in data.fields:
                sig = mdf.get(f"{prefix}.{field}")  # by name alone: no "Multiple occurrences"
                np.testing.assert_array_equal(sig.samples, data[field])
                assert sig.unit == data.units[field] and sig.comment == f"{topic} {field}"
                # time: s since the recording's first message, to the ns the file keeps
                np.testing.assert_allclose(sig.timestamps, data.time, atol=1e-9)
            np.testing.assert_array_equal(mdf.get(f"{prefix}.seq").samples, data.seq)
        frame = mdf.to_dataframe(time_from_zero=False)
        assert not [c for c in frame.columns if c[-2:] in ("_0", "_1")] and "amb.gap.front_x" in frame.columns
        (attachment, _name, _md5), = [mdf.extract_attachment(i) for i in range(len(mdf.attachments))]
        assert json.loads(attachment)["ambdaq.session"]["ambdaq_version"]
