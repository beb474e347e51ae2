"""Every rotor drop on record (issue 30, item 5; ISO 14839-5): a simulated rig's amplifiers are
switched off for a known time at a known speed (the cone rig, and the spindle with its touchdown
bearings), the rotor drops onto its touchdown bearings, a ``--snapshot --trigger touchdown`` catches
it, and the snapshot's ``ambdaq.touchdown`` record is checked against the rig's true rotor position
(``/truth/position``), then shown by the report and collected by the fleet (test_fleet.py)."""

import json
from pathlib import Path

import numpy as np
import pytest

from ambdaq.analysis.orders import WHIRL_RATIO
from ambdaq.analysis.touchdown import AT_CLEARANCE, IMPACT_WINDOW_S
from ambdaq.daq.recording import load, open_recording
from ambdaq.acquisition.touchdowns import recorded_drop
from report_page import Tables

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

RATE_HZ = 10_000.0  # both rigs' sample rate
DROPS = {  # name: (rig, rpm, amplifiers off at s, for s, snapshot's pre-trigger time s)
    "short": ("cone", 600, 0.5, 0.1, 0.4),
    "long": ("cone", 1200, 0.5, 0.3, 0.5),
    "late": ("cone", 600, 0.5, 0.2, 0.1),  # the trigger (re-levitation at 0.7 s) keeps 0.1 s: the rotor is down already
    "spindle": ("spindle", 20000, 0.5, 0.2, 0.3),  # its trigger fires as it falls
}


def drop_files(d):
    """One snapshot file per drop of DROPS in ``d/NAME/``, and a levitated recording ``d/calm.mcap``."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    def run(*args):
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output

    for name, (rig, rpm, at, lasting, pre) in DROPS.items():
        (d / name).mkdir()
        run("sim", "generate", "--profile", rig, "--rpm", rpm, "--drop", f"{at}:{lasting}", "--truth",
            "--duration", at + lasting + 0.6, "--snapshot", f"{pre}s", "--post", "0.5s", "--trigger", "touchdown",
            "-q", "-o", d / name / "drop.mcap")
    run("sim", "generate", "--profile", "cone", "--duration", "0.3", "-q", "-o", d / "calm.mcap")


@pytest.fixture(scope="module")
def drops(build_once):
    d = build_once("rotor-drops", drop_files)
    return {name: next((d / name).glob("drop_*_touchdown.mcap")) for name in DROPS} | {"calm": d / "calm.mcap"}


def truth_of(path):
    """What really happened in a drop file: the true radius at each bearing, then the true |gap| of
    each other axis (the axial), over Cmin; the times (s from the file's first sample), the rig's own
    clock (s since the run began), the machine, the true positions, and the most the gap sensors'
    runout moves a place, over Cmin (the spindle's: 0 on the cone)."""
    rec = open_recording(path)
    m = rec.machine
    cmin = m.cmin_m
    topics = load(path, ["/truth/position", *(["/truth/runout"] if "/truth/runout" in rec else [])])
    data = topics["/truth/position"]
    pos = {a: np.asarray(data[a]) for a in data.fields}
    radii = np.column_stack([np.hypot(pos[b.x], pos[b.y]) for b in m.bearings]
                            + [np.abs(pos[a]) for a in m.axes if a not in m.bearing_axes]) / cmin
    runout = 0.0
    if "/truth/runout" in topics:
        r = topics["/truth/runout"]
        runout = max(float(np.max(np.hypot(r[b.x], r[b.y]))) for b in m.bearings) / cmin
    return radii, np.asarray(data.time), np.asarray(data.device_time) * 1e-9, m, pos, runout


@pytest.mark.parametrize("name", ["short", "long", "spindle"])
def test_a_drop_is_characterised_as_the_rotor_really_fell(drops, name):
    _, rpm, at, lasting, _ = DROPS[name]
    rec = open_recording(drops[name])
    drop = recorded_drop(rec.metadata)
    assert drop is not None and drop.device == "rig"
    t = drop.touchdown
    radii, time_s, rig_s, machine, pos, runout = truth_of(drops[name])
    worst = radii.max(axis=1)
    on = np.flatnonzero(worst >= AT_CLEARANCE)
    first, last = on[0], on[on < on[0] + int(lasting * RATE_HZ) + 1000].max()
    # the first contact where the true rotor reached 0.9 Cmin. The gap sensors see it with their
    # noise (about 1 um against a rotor falling 5 um a sample: 2 samples) and, on the spindle, their
    # runout: the rotor falls through the runout's reach in runout / impact speed
    k = int(round(IMPACT_WINDOW_S * RATE_HZ))
    true_speed = (worst[first] - worst[first - k]) * machine.cmin_m / (k / RATE_HZ)
    slack = 2.5 / RATE_HZ + runout * machine.cmin_m / true_speed
    assert abs(t.contact_s - time_s[first]) <= slack
    assert at < rig_s[first] < at + 0.05  # after the amplifiers went off: the current decays, the rotor falls
    assert abs(t.on_bearing_s - (time_s[last] - time_s[first])) <= 2 * slack
    # on the bearing about as long as the amplifiers were off (less the fall, plus the lift)
    assert t.on_bearing_s == pytest.approx(lasting, rel=0.15)
    assert t.relevitated and not t.began_before
    assert t.speed_rpm == pytest.approx(rpm, abs=0.5)
    # the peak: the true one, give or take the sensor noise (0.02 Cmin) and the runout
    assert t.peak_ratio == pytest.approx(worst[first:last + 1].max(), abs=0.02 + runout)
    if runout == 0.0:  # where it was: a runout can make another place look the furthest
        names = [b.name for b in machine.bearings] + [a for a in machine.axes if a not in machine.bearing_axes]
        assert t.peak_at == names[int(np.argmax(radii[first:last + 1].max(axis=0)))]
    # the whirl at the radial bearing that went furthest: the true orbit's full spectrum says the same
    # (where the truth is clearly one way: the runout's own 1X whirls forward)
    b = machine.bearings[int(np.argmax(radii[first:last + 1, :len(machine.bearings)].max(axis=0)))]
    z = pos[b.x][first:last + 1] + 1j * pos[b.y][first:last + 1]
    spectrum = np.fft.fft((z - z.mean()) * np.hanning(z.shape[0]))
    freq = np.fft.fftfreq(z.shape[0], 1 / RATE_HZ)
    fwd, bwd = np.sum(np.abs(spectrum[freq > 0]) ** 2), np.sum(np.abs(spectrum[freq < 0]) ** 2)
    if runout == 0.0 or max(fwd / bwd, bwd / fwd) > 2 * WHIRL_RATIO:
        assert t.whirl == ("forward" if fwd > WHIRL_RATIO * bwd else "backward" if bwd > WHIRL_RATIO * fwd else "mixed")
    # the impact: the true excursion's speed over the 2 ms before the first contact, within 10 %
    # and, on the spindle, what its gap sensors' runout adds to the speed they see (its whirl at
    # 20,000 rpm moves the sensed radius at up to 2 pi f r: as fast as the fall itself)
    spin_hz = rpm / 60.0
    assert abs(t.impact_speed_m_s - true_speed) <= 0.10 * true_speed + 2 * np.pi * spin_hz * runout * machine.cmin_m
    assert t.energy_j == pytest.approx(0.5 * machine.rotor_mass_kg * t.impact_speed_m_s**2, rel=1e-12)
    # the amplifiers come back on against a rotor on its bearing: the output near its limit
    assert t.amplifier_at_limit > 0.5


def test_a_drop_that_began_before_the_snapshot_says_its_time_is_a_lower_bound(drops):
    t = recorded_drop(open_recording(drops["late"]).metadata).touchdown
    radii, time_s, rig_s, _, _, _ = truth_of(drops["late"])
    assert radii.max(axis=1)[0] >= AT_CLEARANCE  # the truth: down at the file's first sample
    assert t.began_before and t.contact_s == 0.0
    assert t.impact_speed_m_s is None and t.energy_j is None  # the impact was not recorded: not guessed
    assert t.on_bearing_s < DROPS["late"][3]


def test_a_recording_without_a_drop_holds_no_touchdown_record(drops):
    assert recorded_drop(open_recording(drops["calm"]).metadata) is None


def test_the_report_lists_each_drop_with_the_numbers_of_json(drops, run_cli, chromium, tmp_path):
    import subprocess

    from ambdaq.report.pdf import HEADLESS

    page = tmp_path / "drops.html"
    files = [drops[n] for n in ("short", "long", "late", "calm")]
    r = run_cli("report", *[a for f in files for a in ("--drops", f)], "-o", page, "--json")
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    dom = subprocess.run([chromium, *HEADLESS, f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0
    tables = Tables()
    tables.feed(dom.stdout)
    rows = tables.tables["touchdowns"]
    assert [row[0] for row in rows] == [f.name for f in files]
    for cells, entry in zip(rows, data["touchdowns"]):
        t = entry["drop"]
        if t is None:
            assert cells[1] == "no drop in it"
            continue
        assert cells[2:8] == [f"{t['speed_rpm']:,.0f}", ("≥ " if t["began_before"] else "") + f"{t['on_bearing_s']:.3f}",
                              "yes" if t["relevitated"] else "no", f"{t['peak_ratio']:.3f}", t["peak_at"], t["whirl"]]
        assert cells[10] == ("–" if t["energy_j"] is None else f"{t['energy_j']:.3g}")
    line = next(v for v in data["verdict"]["lines"] if v["standard"] == "ISO 14839-5")
    assert line["result"].startswith("3 drops in 4 snapshot files")
    late = [i for i in data["verdict"]["open_items"] if drops["late"].name in i and "lower bound" in i]
    assert len(late) == 1
    # the forms docs/iso.md shows: --drops A B ..., and a quoted glob; each file once, in order
    r = run_cli("report", "--drops", *files, "-o", tmp_path / "list.html", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["touchdowns"] == data["touchdowns"], r.output
    folder = files[0].parent
    r = run_cli("report", "--drops", str(folder / "*.mcap"), "--drops", files[0], "-o", tmp_path / "glob.html", "--json")
    assert r.exit_code == 0, r.output
    assert [Path(e["file"]).name for e in json.loads(r.stdout)["touchdowns"]] == sorted(p.name for p in folder.glob("*.mcap"))
    r = run_cli("report", "stray.mcap", "-o", tmp_path / "x.html")
    assert r.exit_code == 2 and "snapshot files follow --drops" in r.output


def test_a_drops_record_is_kept_within_the_memory_stated_before_recording(run_cli, tmp_path):
    """What a file keeps for its drop (only the gap device's columns the record needs, from just
    before the first contact) is bounded before recording, printed, and never exceeded."""
    r = run_cli("sim", "generate", "--profile", "cone", "--rpm", "1000", "--drop", "0.5:0.2", "--duration", "1.6",
                "--snapshot", "0.4s", "--post", "0.5s", "--trigger", "touchdown", "-o", tmp_path / "d.mcap", "--json")
    assert r.exit_code == 0, r.output
    snap = json.loads(r.stdout)["snapshot"]
    assert 0 < snap["drop_memory_peak_bytes"] <= snap["drop_memory_bound_bytes"]
    assert f"and {snap['drop_memory_bound_bytes'] / 1e6:.1f} MB for a rotor drop's record" in r.stderr
