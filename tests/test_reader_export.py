"""The fast reader's options and the exports, against the data they came from."""

import numpy as np
import pyarrow.parquet as pq
import pytest

from ambdaq.daq import load
from ambdaq.errors import BadInputError


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
    data = np.genfromtxt(tmp_path / "csv" / "amb_gap.csv", delimiter=",", names=True)
    np.testing.assert_allclose(data["front_x"], full["/amb/gap"]["front_x"], rtol=1e-8)
    # integer columns stay exact: ns stamps do not fit a float64 mantissa
    lines = (tmp_path / "csv" / "amb_rotor.csv").read_text().splitlines()
    assert lines[0] == "time,log_time_ns,device_time_ns,seq,angle,speed,keyphasor"
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
