"""Snapshot recording (issue 16, item 2): ``--snapshot SECONDS --trigger ...`` keeps the last seconds in
memory and writes a file around each trigger.

Each trigger is checked on the simulator against ground truth: ``sim generate`` is deterministic per
seed, so the same run recorded whole says at which sample a condition first holds and what every
sample in a snapshot's window must be.  The fault and the manual trigger (SIGUSR1) are checked on a
real-time recording of the served spindle, whose controller reports an injected fault.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time
from datetime import datetime, timezone

import numpy as np
import pytest
from click.testing import CliRunner

from ambdaq.cli.main import cli
from ambdaq.daq import load
from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.acquisition.snapshot import SnapshotOptions
from ambdaq.acquisition.triggers import parse_trigger
from ambdaq.drivers.interfaces import Source
from ambdaq.drivers.signals import SampleBlock, SignalGroup

RATE = 10_000.0  # the simulated rigs' sample rate, Hz
SAMPLE_NS = 100_000


def generate(tmp_path, name, *args):
    res = CliRunner().invoke(cli, ["sim", "generate", *args, "-o", str(tmp_path / name), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def snapshots(tmp_path, stem):
    return sorted(tmp_path.glob(f"{stem}_*.mcap"))


def snap_meta(rec):
    return rec.metadata["ambdaq.snapshot"]


def test_touchdown_fires_on_the_cone_rigs_touchdown_start(tmp_path):
    """The cone rig starting on its touchdown bearings with its amplifiers just enabled: a gap at the
    clearance and a coil voltage at the 25 V supply in the first sample, so one snapshot from there."""
    out = generate(tmp_path, "td.mcap", "--profile", "cone", "--start", "touchdown", "--duration", "1",
                   "--snapshot", "0.2s", "--post", "0.3s", "--trigger", "touchdown")
    (f,) = snapshots(tmp_path, "td")
    assert f.name.endswith("_touchdown.mcap") and out["snapshot"]["files"] == 1
    rec = load(f)
    gap, volt = rec["/amb/gap"], rec["/amb/voltage"]
    # the calibration's clearance (250 um) and supply (25 V) are what the trigger used
    cal = rec.metadata["ambdaq.calibration.rig"]
    cmin, supply = float(cal["machine.min_clearance_m"]), float(cal["machine.voltage_limit_v"])
    first_gap = max(abs(gap[a][0]) for a in ("x", "y1", "y2", "z1", "z2"))
    assert first_gap >= 0.9 * cmin  # on the touchdown bearing
    assert max(abs(volt[m][0]) for m in volt.fields) >= 0.98 * supply  # an amplifier at its limit
    # nothing before the start: the file is the first 0.3 s, every sample, and its metadata says it
    # holds nothing before the trigger where 0.2 s were asked for
    assert len(gap) == round(0.3 * RATE) and gap.seq[0] == 0 and np.all(np.diff(gap.seq.astype(np.int64)) == 1)
    assert snap_meta(rec)["pre_s"] == "0.2" and snap_meta(rec)["pre_held_s"] == "0"


def test_speed_band_entered_on_a_ramp_writes_the_window_around_it(tmp_path):
    """A run-up 0 -> 30,000 rpm in 3 s enters 10,000..12,000 rpm at 1.0 s: one snapshot, whose trigger
    is the first sample at or above 10,000 rpm and whose samples are [T - 0.2 s, T + 0.1 s) of the
    whole run, sample for sample."""
    generate(tmp_path, "whole.mcap", "--rpm", "0:30000", "--duration", "3")
    out = generate(tmp_path, "sp.mcap", "--rpm", "0:30000", "--duration", "3", "--snapshot", "0.2s", "--post", "0.1s",
                   "--trigger", "speed:10000..12000")
    whole = load(tmp_path / "whole.mcap")["/amb/rotor"]
    rpm = whole["speed"] * 60 / (2 * np.pi)
    k = int(np.argmax(rpm >= 10_000))
    assert abs(k - 1.0 * RATE) <= 1  # the ramp's own figure, within one sample
    (f,) = snapshots(tmp_path, "sp")
    assert "_speed-10000-12000" in f.name and out["snapshot"]["files"] == 1
    rec = load(f)
    meta = snap_meta(rec)
    # the trigger is sample k; unpaced, a sample's host time is the start plus its device time
    t0 = int(rec.metadata["ambdaq.snapshot"]["trigger_ns"]) - k * SAMPLE_NS
    snap = rec["/amb/rotor"]
    assert snap.seq[0] == k - round(0.2 * RATE) and snap.seq[-1] == k + round(0.1 * RATE) - 1
    assert np.array_equal(snap["speed"], whole["speed"][snap.seq])
    assert np.array_equal(rec["/amb/gap"]["front_x"], load(tmp_path / "whole.mcap")["/amb/gap"]["front_x"][snap.seq])
    assert snap.log_time[0] == t0 + (k - 2000) * SAMPLE_NS and meta["pre_s"] == "0.2" and meta["post_s"] == "0.1"
    assert meta["pre_held_s"] == "0.2"  # the whole window before the trigger is in the file
    # named by the trigger's UTC time, to the millisecond
    stamp = datetime.fromtimestamp(int(meta["trigger_ns"]) / 1e9, timezone.utc).strftime("%Y%m%dT%H%M%S.%f")[:-3]
    assert f.name == f"sp_{stamp}Z_speed-10000-12000.mcap"


def test_threshold_and_excursion_fire_at_each_hammer_strike(tmp_path):
    """The cone rig struck by the hammer every 0.5 s from 0.2 s (peaks of 18 um against 0.5 um of
    noise): a threshold on the force and an excursion beyond 0.04 Cmin (10 um) each fire at the first
    sample where the whole run shows the condition, once per strike; the excursion, inside the
    force's open snapshot, extends that file to its own post time instead of opening a second."""
    args = ["--profile", "cone", "--duration", "1.5", "--impact", "x:50"]
    generate(tmp_path, "whole.mcap", *args)
    out = generate(tmp_path, "hit.mcap", *args, "--snapshot", "0.05s", "--post", "0.1s",
                   "--trigger", "/amb/hammer.hammer>25", "--trigger", "excursion>0.04")
    whole = load(tmp_path / "whole.mcap")
    gap = whole["/amb/gap"]
    # the cone's axes (x, y1, y2, z1, z2) have no NAME_x/NAME_y pairs: each |gap| alone
    excursion = np.max(np.abs(np.column_stack([gap[a] for a in gap.fields])), axis=1) > 0.04 * 250e-6

    def rising(cond):
        return np.flatnonzero(cond & ~np.concatenate(([False], cond[:-1])))

    force_at, gap_at = rising(whole["/amb/hammer"]["hammer"] > 25), rising(excursion)
    assert np.allclose(force_at / RATE, [0.2, 0.7, 1.2], atol=0.01) and len(gap_at) == 3
    files = snapshots(tmp_path, "hit")
    assert len(files) == 3 == out["snapshot"]["files"]
    for f, k, g in zip(files, force_at, gap_at):
        assert k < g < k + 1000  # the rotor moves after the hammer, inside the snapshot
        rec = load(f)
        seq = rec["/amb/gap"].seq
        fired = snap_meta(rec)["triggers"].split("; ")
        assert [x.split(" ")[0] for x in fired] == ["amb-hammer-hammer", "excursion"]
        assert int(fired[1].split(" ")[2].rstrip(":")) - int(fired[0].split(" ")[2].rstrip(":")) == (g - k) * SAMPLE_NS
        assert seq[0] == k - 500 and seq[-1] == g + 1000 - 1  # 0.05 s before the strike, 0.1 s after the excursion
        assert np.array_equal(rec["/amb/gap"]["x"], gap["x"][seq])


def test_an_orbit_at_the_limit_every_revolution_is_one_firing(tmp_path):
    """At 30,000 rpm the front orbit (runout and unbalance, about 38 um) crosses 0.25 Cmin (37.5 um) on
    hundreds of revolutions a second; the trigger fires once, at the first crossing of the whole run,
    and not again while the crossings come closer together than the 0.25 s re-arm time."""
    args = ["--rpm", "30000", "--duration", "2"]
    generate(tmp_path, "whole.mcap", *args)
    out = generate(tmp_path, "orb.mcap", *args, "--snapshot", "0.1s", "--post", "0.1s", "--trigger", "excursion>0.25")
    gap = load(tmp_path / "whole.mcap")["/amb/gap"]
    radius = np.maximum(np.hypot(gap["front_x"], gap["front_y"]), np.hypot(gap["rear_x"], gap["rear_y"]))
    radius = np.maximum(radius, np.abs(gap["axial"]))
    over = radius > 0.25 * 150e-6
    crossings = np.flatnonzero(over & ~np.concatenate(([False], over[:-1])))
    assert len(crossings) > 50 and np.max(np.diff(crossings)) < 0.25 * RATE  # never quiet for 0.25 s
    (f,) = snapshots(tmp_path, "orb")
    meta = snap_meta(load(f))
    assert out["snapshot"]["files"] == 1 and len(meta["triggers"].split("; ")) == 1
    snap = load(f)["/amb/gap"]
    assert snap.seq[0] == max(0, crossings[0] - 1000)
    assert int(meta["trigger_ns"]) == snap.log_time[np.flatnonzero(snap.seq == crossings[0])[0]]


class Scripted(Source):
    """A 1 kHz device whose ``seq`` loses and repeats samples where the script says, unpaced."""

    sample_rate = 1000.0

    def __init__(self, seq):
        self.name, self._seq, self._pos = "scripted", np.asarray(seq, dtype=np.uint32), 0

    def signal_groups(self):
        return [SignalGroup("/amb/gap", "Gap", ("axial",), ("m",))]

    def identity(self):
        return {"url": "scripted://", "kind": "test device"}

    def device_calibration(self):
        return {}

    def start(self, n_samples):
        pass

    def read(self):
        if self._pos >= len(self._seq):
            return None
        s = self._seq[self._pos:self._pos + 37]
        self._pos += 37
        t = s.astype(np.int64) * 1_000_000
        return SampleBlock(t, s, {"/amb/gap": np.where(s % 1000 == 500, 1.0, 0.0)[:, None] * 1e-4})

    def _close(self):
        self._pos = len(self._seq)


def test_a_snapshots_losses_are_counted_within_its_span(tmp_path):
    """A device that loses 7 samples inside a snapshot's window, 3 just before it and repeats 2 in it:
    the file counts the 7 and the 2, not the 3 (they are before its first sample), and holds every
    other sample of the window exactly once.  Fires at seq 500, 1500, 2500 (|gap| > 50 um)."""
    seq = list(range(0, 3000))
    seq = [s for s in seq if not 1395 <= s < 1398 and not 1520 <= s < 1527]  # 3 before, 7 inside
    i = seq.index(1600)
    seq[i:i] = [1599, 1599]  # two duplicates inside
    opts = SnapshotOptions(0.1, 0.2, 10**8, [parse_trigger("|/amb/gap.axial|>5e-5")])
    result = Recorder([Scripted(seq)], tmp_path / "s.mcap", RecordOptions(snapshot=opts)).run()
    assert result.drops == 10 and result.duplicates == 2 and len(result.files) == 3
    rec = load(result.files[1])
    stats = json.loads(rec.metadata["ambdaq.statistics"]["/amb/gap"])
    assert stats["drops"] == 7 and stats["duplicates"] == 2
    want = [s for s in range(1400, 1700) if not 1520 <= s < 1527]  # [T - 0.1 s, T + 0.2 s) with T at 1500
    assert rec["/amb/gap"].seq.tolist() == want
    assert result.snapshot["memory_peak_bytes"] <= result.snapshot["memory_bound_bytes"]


def test_memory_is_bounded_and_stated(tmp_path):
    """10 s of the spindle through a 1 s snapshot: the rings never held more than the bound printed
    before recording, and that bound is about 1 s of samples (not 10)."""
    out = generate(tmp_path, "m.mcap", "--duration", "10", "--snapshot", "1s", "--trigger", "manual")
    snap = out["snapshot"]
    per_second = RATE * (8 * (5 * 4 + 3) + 50)  # /amb/gap, current, error, ff (5 fields), rotor (3); times, counts
    # the bound: 1 s, 0.5 s for late triggers, two 0.2 s segments, and their objects' overhead
    assert snap["memory_peak_bytes"] <= snap["memory_bound_bytes"] < 2.5 * per_second
    assert snap["memory_peak_bytes"] > 0.9 * per_second  # it did hold the second it promised
    assert snap["files"] == 0 and out["samples"] == 100_000
    assert "at most" in CliRunner().invoke(cli, ["sim", "generate", "--duration", "0.1", "--snapshot", "1s",
                                                 "-o", str(tmp_path / "n.mcap")]).stderr


@pytest.mark.parametrize("args, message", [
    (["--trigger", "gap>3"], r"--trigger 'gap>3' does not parse: give one of fault, manual"),
    (["--trigger", "/amb/gap.nope>1"], r"no device records /amb/gap.nope \(recorded: "),
    (["--trigger", "|/amb/gap.axial>1"], r"a magnitude is written \|TOPIC.FIELD\|>V"),
    (["--trigger", "speed:5000..100"], r"the band must be LO..HI rpm"),
    (["--trigger", "touchdown:8W"], r"touchdown:8A or touchdown:25V"),
    (["--snapshot-memory", "1M"], r"--snapshot 30s of these devices needs up to \d+ MB, more than --snapshot-memory 1 MB"),
])
def test_a_bad_trigger_is_one_line_and_exit_2_before_recording(tmp_path, args, message):
    res = CliRunner().invoke(cli, ["sim", "generate", "--duration", "1", "--snapshot", "30s", *args,
                                   "-o", str(tmp_path / "b.mcap")])
    assert res.exit_code == 2 and re.search(message, res.stderr), res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not list(tmp_path.iterdir())


def test_triggers_need_a_snapshot_and_a_clearance(tmp_path):
    res = CliRunner().invoke(cli, ["sim", "generate", "--duration", "1", "--trigger", "fault", "-o", str(tmp_path / "a.mcap")])
    assert res.exit_code == 2 and "--trigger and --post need --snapshot SECONDS" in res.stderr
    res = CliRunner().invoke(cli, ["sim", "generate", "--profile", "base-motion", "--duration", "1", "--snapshot", "1s",
                                   "--trigger", "excursion>0.5", "-o", str(tmp_path / "a.mcap")])
    assert res.exit_code == 2 and "no minimum clearance" in res.stderr and "pass --cmin UM" in res.stderr


@pytest.mark.realtime
def test_fault_and_sigusr1_on_the_served_spindle(tmp_path):
    """``ambdaq record`` of the spindle served in this process, its controller reporting an injected
    fault 3.5 s after it starts (its CAN devices may take 2.5 s to start on a loaded host); SIGUSR1
    0.5 s after ambdaq says the fault's snapshot is open (after the fault's 0.3 s, so the manual
    trigger opens a file of its own instead of joining the fault's: with a fixed delay from the
    armed line, a host slow to start the rig once put both in one file).  Two files, each with every
    device's samples over [T - 0.5 s, T + 0.3 s) and the fault event in the fault's."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ambdaq", "record", "--device", "sim://spindle?fault=3.5", "--rpm", "12000",
         "--duration", "5.5", "--snapshot", "0.5s", "--post", "0.3s", "--trigger", "fault", "--json",
         "-o", str(tmp_path / "rt.mcap")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    assert "snapshot: the last 0.5 s in memory (at most" in line and "SIGUSR1 fires one" in line, line
    seen = [line]
    while "ambdaq: fault:" not in seen[-1] and seen[-1]:
        seen.append(proc.stderr.readline())
    time.sleep(0.5)
    os.kill(proc.pid, signal.SIGUSR1)
    stdout, stderr = proc.communicate(timeout=60)
    stderr = "".join(seen) + stderr
    assert proc.returncode == 0, stderr
    result = json.loads(stdout)
    files = {re.sub(r"rt_\d{8}T[\d.]+Z_", "", f.name): f for f in snapshots(tmp_path, "rt")}
    assert sorted(files) == ["fault.mcap", "manual.mcap"] and result["snapshot"]["files"] == 2, (stderr, files)
    pre, post = 500_000_000, 300_000_000  # ns
    for name, f in files.items():
        rec = load(f)
        meta = snap_meta(rec)
        t = int(meta["trigger_ns"])
        assert meta["cause"] == name.removesuffix(".mcap") and int(meta["end_ns"]) == t + post
        # each device's samples reach the window's edges within twice its largest spacing in the
        # file (the spacing across an edge is not in it: a gap sensor's last sample once came 23 ms
        # before the end, its largest spacing inside 18 ms): 0.1 ms for the controller (stamped by
        # its clock); for the CAN gap sensor, stamped by the host when its SYNC goes out, up to tens
        # of ms on a loaded host (the SYNC thread waits for the CPU); plus 2 ms for the clock map
        for topic in ("/amb/gap", "/can/amb/gap"):
            d = rec[topic]
            slack = 2 * np.diff(d.log_time).max() + 2e6
            assert t - pre <= d.log_time[0] <= t - pre + slack, (name, topic, d.log_time[0] - t)
            assert t + post - slack <= d.log_time[-1] < t + post, (name, topic, d.log_time[-1] - t)
            # every sample of the span once, or counted lost in the file (the CAN devices in this
            # process may lose a few beside another test's load; the serial line loses none)
            drops = json.loads(rec.metadata["ambdaq.statistics"][topic])["drops"]
            # every sample between the first and the last is there or counted lost (a host starved of
            # CPU loses some, counted: 1,300 of the gap's once on a slow CI host; losing none beside
            # one busy process is test_record_stress.py's subject)
            assert len(d) + drops == int(d.seq[-1]) - int(d.seq[0]) + 1, topic
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(files["fault.mcap"], "rb") as fh:
        events = [d for _s, _c, _m, d in make_reader(fh, decoder_factories=[DecoderFactory()])
                  .iter_decoded_messages(topics=["/amb/events"])]
    assert [(e.kind, e.code) for e in events] == [("fault", 0x2310)] and "injected fault" in events[0].text
    assert "manual: manual trigger (SIGUSR1) ->" in stderr and "fault: rig: severity 2: injected fault" in stderr


def test_enter_on_the_terminal_fires_a_snapshot(tmp_path):
    """``ambdaq record`` with a terminal (a pseudo-terminal) as its stdin: the armed line offers
    Enter, and a key press writes one file around its moment, its cause "manual (Enter)"."""
    import pty

    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "ambdaq", "record", "--device", "sim://spindle", "--rpm", "12000", "--duration", "3",
         "--snapshot", "0.5s", "--post", "0.3s", "--trigger", "manual", "--json", "-o", str(tmp_path / "key.mcap")],
        stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    os.close(slave)
    try:
        line = proc.stderr.readline()
        assert "SIGUSR1 or Enter fires one" in line, line
        time.sleep(1.0)
        os.write(master, b"\n")
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        os.close(master)
    assert proc.returncode == 0, stderr
    files = snapshots(tmp_path, "key")
    assert len(files) == 1 and files[0].name.endswith("_manual.mcap") and json.loads(stdout)["snapshot"]["files"] == 1
    meta = snap_meta(load(files[0]))
    assert meta["cause"] == "manual" and "manual trigger (Enter)" in stderr
    assert int(meta["end_ns"]) - int(meta["trigger_ns"]) == 300_000_000
