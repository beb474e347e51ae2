"""Fleet analysis on Dask (issue 17): ``ambdaq sim fleet`` records 40 simulated spindles' days,
``ambdaq fleet scan`` turns them into a Parquet dataset on a LocalCluster of 2 worker processes (reached
by address, as a plant's cluster is), and
every row equals what the single-file commands say of its file (``runout identify``, ``iso vibration``,
``info``).  Damaged files are rows with their error; a file still being written is skipped; a second
scan is incremental; Ctrl-C leaves a dataset that the next scan completes."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ambdaq.cli.main import cli
from ambdaq.workflows.fleet import read

# one worker builds the fleet once and runs these in order (the last two rewrite a recording)
pytestmark = pytest.mark.xdist_group("fleet")

AXES = ("front_x", "front_y", "rear_x", "rear_y", "axial")


def run(*args):
    res = CliRunner().invoke(cli, list(args))
    assert res.exit_code == 0, res.output
    return res


def ambdaq(*args, **kw):
    return subprocess.run([sys.executable, "-m", "ambdaq", *args], capture_output=True, text=True, timeout=300, **kw)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """40 recordings (10 machines, 4 days, 0.3 s at 30,000 rpm: 150 revolutions, 3 of iso vibration's
    windows), plus a truncated file, a file that is not MCAP, and one being written (no footer,
    modified just now)."""
    root = tmp_path_factory.mktemp("fleet")
    run("sim", "fleet", "--machines", "10", "--days", "4", "--duration", "0.3", "-o", str(root / "plant"))
    good = sorted((root / "plant").rglob("*.mcap"))
    assert len(good) == 40
    bad = root / "plant" / "damaged"
    bad.mkdir()
    data = good[0].read_bytes()
    (bad / "truncated.mcap").write_bytes(data[: len(data) // 2])
    os.utime(bad / "truncated.mcap", (time.time() - 3600, time.time() - 3600))  # an hour old: a crash, not a writer
    (bad / "garbage.mcap").write_bytes(b"not an mcap file at all" * 100)
    os.utime(bad / "garbage.mcap", (time.time() - 3600, time.time() - 3600))
    (bad / "writing.mcap").write_bytes(data[: len(data) // 3])  # fresh: its recorder is still at it
    return root, good


@pytest.fixture(scope="module")
def scheduler():
    """The cluster every scan reaches by address (``--scheduler``, and DASK_SCHEDULER_ADDRESS), as a
    plant's would be: a LocalCluster of 2 worker processes on 127.0.0.1, started once."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        yield cluster.scheduler_address


@pytest.fixture(scope="module")
def scanned(fleet, scheduler):
    root, good = fleet
    ds = root / "fleet.parquet"
    res = ambdaq("fleet", "scan", str(root / "plant"), "-o", str(ds), "--scheduler", scheduler, "--json")
    assert res.returncode == 0, res.stderr
    return ds, json.loads(res.stdout)


def test_scan_on_two_workers_matches_the_single_file_commands(fleet, scanned, tmp_path):
    import pandas as pd

    root, good = fleet
    ds, report = scanned
    assert report["scanned"] == 42 and report["unchanged"] == 0  # 40 recordings and the two damaged files
    assert report["writing"] == [str((root / "plant" / "damaged" / "writing.mcap").resolve())]
    assert len(pd.read_parquet(ds)) == 42  # pandas reads the dataset directly, the machine from the partition
    df = read(ds)  # each machine's axes and bearings as columns
    assert len(df) == 42 and df["path"].is_unique
    rows = {r["path"]: r for r in df.to_dict("records")}
    lossy = []
    for path in good:
        row = rows[str(path.resolve())]
        assert pd.isna(row["error"]) and str(row["machine"]) == path.parent.name
        # info FILE --json: the drops
        info = json.loads(run("info", "--json", str(path)).stdout)
        gap = next(t for t in info["topics"] if t["topic"] == "/amb/gap")
        assert (row["drops"], row["samples"]) == (gap["drops"], gap["messages"])
        assert abs(row["rpm_min"] - 30000) < 1 and abs(row["rpm_max"] - 30000) < 1
        coef = tmp_path / f"{path.stem}.json"
        if gap["drops"] > 0.001 * (gap["drops"] + gap["messages"]):
            # lost more than the data-quality gate takes: the commands refuse, the row says why
            for args in (("runout", "identify", str(path), "-o", str(coef)), ("iso", "vibration", str(path))):
                res = CliRunner().invoke(cli, list(args))
                assert res.exit_code == 2 and "would compute over the holes" in res.output, res.output
            assert pd.isna(row["runout_front_x_1x_um"]) and pd.isna(row["vibration_front_um"])
            assert "runout identification would compute over the holes" in row["note"]
            lossy.append(path)
            continue
        # runout identify FILE: the coefficient file's weights, per axis and harmonic (the same
        # function on the same bits: equal to the last digit, 1e-9 um only for the um conversion)
        run("runout", "identify", str(path), "-o", str(coef), "--harmonics", "4", "--overwrite")
        weights = json.loads(coef.read_text())["runout"]["weights"]
        for axis in AXES:
            for k, (a, b) in enumerate(weights[axis], 1):
                assert row[f"runout_{axis}_{k}x_um"] == pytest.approx(abs(complex(a, b)) * 1e6, abs=1e-9)
        # iso vibration FILE --json: its worst band per bearing and zone (printed to 0.001 um)
        iso = json.loads(run("iso", "vibration", str(path), "--json").stdout)
        for bearing in ("front", "rear"):
            worst = max((b for b in iso["bands"] if b["bearing"] == bearing), key=lambda b: b["ratio_cmin"])
            assert row[f"vibration_{bearing}_um"] == pytest.approx(worst["max_um"], abs=5e-4)
            assert row[f"zone_{bearing}"] == worst["zone"]
        assert row["cmin_um"] == iso["cmin_um"] == 150.0
    assert df["drops"].gt(0).sum() >= 1 and lossy  # the generator's occasional losses are there
    assert len(lossy) < len(good) // 2  # and most recordings are graded
    # one machine in four runs a pushed coefficient file, named in its recordings' identity
    assert set(df.loc[df["coefficients_sha256"].notna(), "machine"].astype(str)) == {"AMB-04", "AMB-08"}


def test_damaged_files_are_rows_with_their_error(fleet, scanned):
    import pandas as pd

    root, _ = fleet
    ds, report = scanned
    errors = {os.path.basename(e["path"]): e["error"] for e in report["errors"]}
    assert set(errors) == {"truncated.mcap", "garbage.mcap"}
    assert "not an MCAP file" in errors["garbage.mcap"]
    df = pd.read_parquet(ds)
    bad = df[df["error"].notna()]
    assert sorted(os.path.basename(p) for p in bad["path"]) == ["garbage.mcap", "truncated.mcap"]
    assert set(bad["machine"].astype(str)) == {"unknown"}


def test_the_commands_own_cluster_and_duckdb_agree_with_the_scan(fleet, scanned, tmp_path):
    """Without a scheduler `fleet scan` starts its own LocalCluster (``--workers``, what a user
    without a cluster runs): one machine's four rows equal the cluster scan's, column for column.
    DuckDB, a reader that shares no code with pyarrow, reads the whole dataset with its machine
    partitions: per machine the same recordings, samples and drops as pandas."""
    import duckdb
    import pandas as pd

    root, _ = fleet
    ds, _ = scanned
    own = tmp_path / "own.parquet"
    env = {k: v for k, v in os.environ.items() if k != "DASK_SCHEDULER_ADDRESS"}
    res = ambdaq("fleet", "scan", str(root / "plant" / "AMB-05"), "-o", str(own), "--workers", "1", "--json", env=env)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["scanned"] == 4
    mine = read(own).set_index("path").sort_index()
    theirs = read(ds).set_index("path").loc[mine.index]
    assert list(mine.columns) == list(theirs.columns)
    for column in mine.columns:  # the same function on the same bytes: equal, not close
        assert mine[column].astype(object).equals(theirs[column].astype(object)), column
    query = (f"SELECT machine, count(*) AS n, sum(samples) AS samples, sum(drops) AS drops "
             f"FROM read_parquet('{ds}/*/*.parquet', hive_partitioning = true) GROUP BY machine ORDER BY machine")
    got = duckdb.sql(query).df().set_index("machine")
    want = pd.read_parquet(ds).groupby("machine", observed=True).agg(
        n=("path", "size"), samples=("samples", "sum"), drops=("drops", "sum"))
    assert len(got) == 11  # 10 machines and "unknown", the damaged files'
    for machine, row in want.iterrows():
        assert tuple(got.loc[str(machine)]) == (row["n"], row["samples"], row["drops"]), machine


def test_dask_reads_the_dataset_and_a_second_scan_is_incremental(fleet, scanned, scheduler, tmp_path):
    import dask.dataframe as dd

    root, good = fleet
    ds, _ = scanned
    assert len(dd.read_parquet(ds).compute()) == 42
    # unchanged files are skipped by size and time; a touched one (same bytes, new time) keeps its row
    # by its hash; a rewritten one (another day's bytes) is scanned again
    os.utime(good[1], (time.time() - 7200, time.time() - 7200))
    good[2].write_bytes(good[3].read_bytes())
    res = ambdaq("fleet", "scan", str(root / "plant"), "-o", str(ds), "--json",
                 env={**os.environ, "DASK_SCHEDULER_ADDRESS": scheduler})  # Dask's own convention
    again = json.loads(res.stdout)
    assert (again["scanned"], again["unchanged"], len(again["writing"])) == (1, 41, 1)
    import pandas as pd

    df = pd.read_parquet(ds)
    assert len(df) == 42 and df["path"].is_unique
    row = df[df["path"] == str(good[2].resolve())].iloc[0]
    assert row["sha256"] == df[df["path"] == str(good[3].resolve())].iloc[0]["sha256"]
    assert row["mtime_ns"] == good[2].stat().st_mtime_ns
    assert df[df["path"] == str(good[1].resolve())].iloc[0]["mtime_ns"] == good[1].stat().st_mtime_ns


def test_trend_lists_the_machines_that_moved_and_plots_one(scanned, tmp_path):
    ds, _ = scanned
    out = json.loads(run("fleet", "trend", str(ds), "--threshold", "3", "--json").stdout)
    assert len(out["rows"]) == 42
    moved = {m["machine"] for m in out["moved"]}
    assert moved and all(abs(m["last_um"] - m["first_um"]) > 3 for m in out["moved"])
    text = run("fleet", "trend", str(ds), "--threshold", "3").stdout
    assert "moved more than 3 um" in text and all(m in text for m in moved)
    # the samples each machine's recordings lost, headed "lost" (not "drops": those are rotor drops)
    assert text.splitlines()[0].split()[4] == "lost"
    lost = read(ds).groupby("machine")["drops"].sum()
    for machine, count in lost.items():
        (line,) = [x for x in text.splitlines() if x.startswith(f"{machine} ")]
        assert int(line[58:64]) == count, line  # the columns' widths: 10, 10, 17, 17, then 6
    run("fleet", "trend", str(ds), "--machine", "AMB-01", "--plot", str(tmp_path / "amb01.png"))
    assert (tmp_path / "amb01.png").stat().st_size > 10_000
    # what the figure shows: dates with their year, no tick label on another, legends off the panels
    from ambdaq.figures import pyplot
    from ambdaq.figures.fleet import draw_trend
    from test_figures import overlapping_tick_labels, titles_inside

    fig = draw_trend(read(ds, "AMB-01"), "AMB-01")
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        dates = [t.get_text() for t in fig.axes[2].get_xticklabels() if t.get_text()]
        assert dates and all(d.startswith("2026-01-") for d in dates), dates
        for ax in fig.axes:
            assert overlapping_tick_labels(ax) == []
            legend, panel = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
            assert legend.x0 >= panel.x1, ax.get_ylabel()  # beside the panel, on no data
        assert titles_inside(fig) == []
    finally:
        pyplot().close(fig)
    res = CliRunner().invoke(cli, ["fleet", "trend", str(ds), "--machine", "AMB-99"])
    assert res.exit_code == 2 and "no machine 'AMB-99' (machines: AMB-01" in res.stderr


def test_ctrl_c_leaves_a_dataset_the_next_scan_completes(fleet, scheduler, tmp_path):
    """Over three machines' 12 recordings on the cluster: SIGINT once the first row is written."""
    root, good = fleet
    ds = tmp_path / "interrupted.parquet"
    plant = [str(root / "plant" / f"AMB-0{m}") for m in (1, 2, 3)]
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "fleet", "scan", *plant, "-o", str(ds),
                             "--scheduler", scheduler, "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list(ds.glob("machine=*/*.parquet")) and time.monotonic() < deadline:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    written = list(ds.glob("machine=*/*.parquet"))
    if proc.returncode == 0:  # the scan finished before the signal came: nothing to resume
        pytest.skip("the scan ended before Ctrl-C")
    assert proc.returncode == 1 and "interrupted:" in err and "run the same scan again to go on" in err, err
    assert 1 <= len(written) < 12 and not list(ds.rglob("*.tmp"))
    import pandas as pd

    assert len(pd.read_parquet(ds)) == len(written)  # every row written is whole
    res = json.loads(ambdaq("fleet", "scan", *plant, "-o", str(ds), "--scheduler", scheduler, "--json").stdout)
    assert res["scanned"] == 12 - len(written) and res["unchanged"] == len(written)
    df = pd.read_parquet(ds)
    assert len(df) == 12 and df["path"].is_unique


def test_every_rotor_drop_on_record_and_when_to_inspect(scheduler, build_once, tmp_path):
    """ISO 14839-5: the drops the simulated rigs' snapshots caught (tests/test_touchdown.py checks
    each against the rig's truth) are collected per machine; trend counts them, sums their impact
    energy, and says when the touchdown bearings are due."""
    from ambdaq.daq.recording import open_recording
    from ambdaq.acquisition.touchdowns import recorded_drop
    from test_touchdown import DROPS, drop_files

    drops = build_once("rotor-drops", drop_files)
    ds = tmp_path / "drops.parquet"
    res = ambdaq("fleet", "scan", str(drops), "-o", str(ds), "--scheduler", scheduler, "--json")
    assert res.returncode == 0, res.stderr
    files = sorted(drops.rglob("*.mcap"))
    assert json.loads(res.stdout)["scanned"] == len(files) == len(DROPS) + 1  # and one without a drop
    held = [d.touchdown for f in files if (d := recorded_drop(open_recording(f).metadata)) is not None]
    n = len(held)
    assert n == len(DROPS)
    out = json.loads(run("fleet", "trend", str(ds), "--touchdown-limit", str(n), "--json").stdout)
    (summary,) = out["touchdowns"]  # one machine: the rigs name none, so both are this host's
    assert summary["drops"] == n and summary["inspect"]
    # the energy of the drops whose impact was recorded (one began before its snapshot: none known)
    known = [t.energy_j for t in held if t.energy_j is not None]
    assert len(known) == n - 1 and summary["energy_j"] == pytest.approx(sum(known), rel=1e-12)
    assert summary["worst_ratio_cmin"] == pytest.approx(max(t.peak_ratio for t in held), rel=1e-12)
    text = run("fleet", "trend", str(ds), "--touchdown-limit", str(n)).stdout
    assert f"{n} drops" in text and "inspect the touchdown bearings" in text
    assert "inspect the touchdown bearings" not in run("fleet", "trend", str(ds), "--touchdown-limit", str(n + 1)).stdout
    by_energy = run("fleet", "trend", str(ds), "--touchdown-energy", f"{sum(known) * 0.99:.6g}").stdout
    assert "inspect the touchdown bearings" in by_energy


def test_a_dataset_written_with_another_row_layout_is_refused(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    old = tmp_path / "old.parquet" / "machine=AMB-01"
    old.mkdir(parents=True)
    pq.write_table(pa.table({"path": ["/plant/a.mcap"], "size": [1], "onex_front_x_um": [2.0]}), old / "a.parquet")
    (tmp_path / "a.mcap").write_bytes(b"")
    for args in (("fleet", "trend", str(tmp_path / "old.parquet")),
                 ("fleet", "scan", str(tmp_path / "a.mcap"), "-o", str(tmp_path / "old.parquet"))):
        res = CliRunner().invoke(cli, list(args))
        assert res.exit_code == 2 and "laid out as another ambdaq version wrote them" in res.output, res.output


def test_a_balancing_record_grades_its_recording_and_the_machines_rows_after_it(fleet, scheduler, tmp_path):
    """Issue 43, item 4: a balancing record (``balance forces --record``) beside one machine's
    recordings; ``fleet scan`` keeps its ISO 21940-11 grade, and the rows carry it: the recording it
    assessed its own grade, every row of that machine from then on the latest grade (none before).
    A record whose seal is broken is left out with a line; other JSON files are passed over."""
    import shutil

    _root, good = fleet
    days = sorted(p for p in good if p.parent.name == "AMB-03")
    plant = tmp_path / "plant"
    plant.mkdir()
    copies = [Path(shutil.copy(p, plant / p.name)) for p in days]
    coef = plant / "coef.json"  # a runout file: JSON, and no balancing record
    run("runout", "identify", str(copies[0]), "-o", str(coef))
    graded = json.loads(run("balance", "forces", str(copies[1]), "--coefficients", str(coef), "--max-rpm", "60000",
                            "--json", "--record", str(plant / "job.json")).stdout)
    broken = plant / "broken.json"
    broken.write_text((plant / "job.json").read_text().replace('"max_rpm": 60000', '"max_rpm": 6000'))
    ds = tmp_path / "fleet.parquet"
    report = json.loads(run("fleet", "scan", str(plant), "-o", str(ds), "--scheduler", scheduler, "--json").stdout)
    assert report["balancing_records"] == 1 and [e["path"] for e in report["balancing_errors"]] == [str(broken)]
    df = read(ds).set_index("path")
    rows = [df.loc[str(p.resolve())] for p in copies]
    assert rows[1]["balance_grade_mm_s"] == graded["grade_mm_s"] and rows[1]["balance_grade"] == graded["grade"]
    assert rows[1]["balance_grade_std_mm_s"] == graded["grade_std_mm_s"]
    assert rows[1]["balance_record"] == str((plant / "job.json").resolve())
    assert np.isnan(rows[0]["latest_balance_grade_mm_s"]) and rows[0]["latest_balance_grade"] is None
    for row in rows[1:]:
        assert (row["latest_balance_grade_mm_s"], row["latest_balance_grade"]) == (graded["grade_mm_s"], graded["grade"])
    for row in rows[2:]:
        assert np.isnan(row["balance_grade_mm_s"])  # graded by no record of its own
    text = run("fleet", "trend", str(ds)).stdout
    (line,) = [x for x in text.splitlines() if x.startswith("AMB-03 ")]
    assert f"{graded['grade_mm_s']:.3g} mm/s {graded['grade']}" in line, line
