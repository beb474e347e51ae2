"""A machine that is not the spindle's names: a controller that calls its bearings drive end and
non-drive end and its axial axis thrust (``de_x, de_y, nde_x, nde_y, thrust``); a foreign
controller that knows nothing of the machine, whose every signal is one topic of its own names,
mapped to roles by the rig file's ``[machine]`` table; a machine of one radial bearing. The host
side takes its bearings, axes and signals from the recording (ambdaq.machines.machine), so runout
identification, ISO 14839-2 grading, run-up order tracking, plot, the live status and the fleet
scan give on each the numbers they give on the spindle's equivalent axes (the same physics,
recorded under other names)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ambdaq.daq import open_recording
from ambdaq.acquisition.recorder import Recorder, RecordOptions, machine_from_sources
from ambdaq.drivers.interfaces import PassThrough
from ambdaq.drivers.signals import SampleBlock, SignalGroup
from ambdaq.machines.spindle import SPINDLE
from ambdaq.sim.source import SimSource
from ambdaq.speed import SpeedProfile

NAMES = {"front_x": "de_x", "front_y": "de_y", "rear_x": "nde_x", "rear_y": "nde_y", "axial": "thrust"}
BEARINGS = {"front": "de", "rear": "nde"}
# the foreign controller's own names: every signal on one topic (as an XCP controller's event is)
LOOP = "/ctl/loop"
FOREIGN = {"/amb/gap": "probe_", "/amb/current": "coil_", "/amb/error": "err_"}
ROTOR = {"angle": "kp_angle", "speed": "kp_speed"}


class Blower(PassThrough):
    """The simulated spindle as a controller that names its axes otherwise: every topic's fields
    renamed, the samples untouched."""

    def __init__(self, inner: SimSource) -> None:
        super().__init__(inner)
        self.name = "blower"

    def signal_groups(self):
        return [SignalGroup(g.topic, g.type_name, tuple(NAMES.get(f, f) for f in g.fields), g.units)
                for g in self.inner.signal_groups()]

    def identity(self):
        return {**self.inner.identity(), "model": "blower (the simulated spindle, renamed)"}



class Foreign(PassThrough):
    """The simulated spindle as a controller that knows nothing of the machine: the gap, currents,
    command error and key-phasor in one topic under its own names (``probe_1`` ...), no calibration."""

    def __init__(self, inner: SimSource) -> None:
        super().__init__(inner)
        self.groups = {g.topic: g for g in inner.signal_groups()}
        fields, units = [], []
        for topic, prefix in FOREIGN.items():
            g = self.groups[topic]
            fields += [f"{prefix}{i + 1}" for i in range(len(g.fields))]
            units += list(g.units)
        self.group = SignalGroup(LOOP, "Loop", (*fields, *ROTOR.values()), (*units, "rad", "rad/s"))

    def signal_groups(self):
        return [self.group]

    def identity(self):
        return {"kind": "controller", "model": "a foreign controller (the simulated spindle)"}

    def device_calibration(self):
        return {}

    def read(self):
        b = self.inner.read()
        if b is None:
            return None
        rotor = b.values["/amb/rotor"][:, [self.groups["/amb/rotor"].fields.index(f) for f in ROTOR]]
        values = np.column_stack([b.values[t] for t in FOREIGN] + [rotor])
        return SampleBlock(b.device_time_ns, b.seq, {LOOP: values}, b.host_time_ns, b.received_ns, b.status)


def foreign_machine() -> dict:
    """What the foreign controller's rig file says in its [machine] table: which of its fields is
    which role's axis, the bearings' clearance and the rigid rotor's constants."""
    table = {role: {NAMES[a]: f"{LOOP}.{prefix}{i + 1}" for i, a in enumerate(NAMES)}
             for role, prefix in (("gap", "probe_"), ("current", "coil_"), ("error", "err_"))}
    table["rotor"] = {k: f"{LOOP}.{v}" for k, v in ROTOR.items()}
    rotor = SPINDLE.rotor
    table["rigid_rotor"] = {"mass_kg": rotor.mass, "jt_kgm2": rotor.jt, "jp_kgm2": rotor.jp, "a_m": rotor.a,
                            "b_m": rotor.b, "kx_n_per_m": list(rotor.kx), "ki_n_per_a": list(rotor.ki)}
    table["min_clearance_m"] = SPINDLE.min_clearance
    return table


class OneBearing(PassThrough):
    """The simulated spindle recorded at its front bearing and its axial axis only."""

    KEPT = ("front_x", "front_y", "axial")

    def signal_groups(self):
        return [SignalGroup(g.topic, g.type_name, self.KEPT, tuple(g.units[g.fields.index(f)] for f in self.KEPT))
                if g.topic in ("/amb/gap", "/amb/current", "/amb/error") else g for g in self.inner.signal_groups()]

    def read(self):
        b = self.inner.read()
        if b is None:
            return None
        groups = {g.topic: g for g in self.inner.signal_groups()}
        values = {t: v[:, [groups[t].fields.index(f) for f in self.KEPT]] if t in ("/amb/gap", "/amb/current", "/amb/error")
                  else v for t, v in b.values.items()}
        return SampleBlock(b.device_time_ns, b.seq, values, b.host_time_ns, b.received_ns, b.status)


MACHINES = {"spindle": (lambda s: s, None), "blower": (Blower, None), "foreign": (Foreign, foreign_machine()),
            "one": (OneBearing, None)}


pytestmark = pytest.mark.xdist_group("any-machine")  # one worker builds the module's files; the other runs other tests


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """Recordings of the same physics on each machine: a steady run, a slow roll, a run-up."""
    d = tmp_path_factory.mktemp("blower")
    out = {}
    for name, speed, seconds in (("steady", SpeedProfile(30000, 30000), 1.0), ("slow", SpeedProfile(800, 800), 2.0),
                                 ("runup", SpeedProfile(0, 30000, 3.0), 3.0)):
        for machine, (wrap, table) in MACHINES.items():
            path = d / f"{machine}_{name}.mcap"
            Recorder([wrap(SimSource("spindle", seed=5, speed=speed))], path, RecordOptions(duration_s=seconds, fsync=False),
                     machine_table=table).run()
            out[machine, name] = path
    return out


RENAMED = ("blower", "foreign")  # the spindle's axes under NAMES: named by the device, or by the rig file


def test_runout_identify_gives_the_same_runout_under_other_names(pairs, run_cli, tmp_path):
    coef = {}
    for machine in ("spindle", *RENAMED):
        r = run_cli("runout", "identify", pairs[machine, "slow"], pairs[machine, "steady"], "-o", tmp_path / f"{machine}.json")
        assert r.exit_code == 0, r.output
        coef[machine] = json.loads((tmp_path / f"{machine}.json").read_text())
    for machine in RENAMED:
        assert coef[machine]["target"]["axes"] == list(NAMES.values())
        for axis, other in NAMES.items():  # the same fit of the same samples: equal to the last bit
            assert coef[machine]["runout"]["weights"][other] == coef["spindle"]["runout"]["weights"][axis]


def test_iso_vibration_and_runup_grade_and_track_the_bearings_by_their_own_names(pairs, run_cli):
    iso = {m: json.loads(run_cli("iso", "vibration", pairs[m, "runup"], "--cmin", "150", "--json").stdout)
           for m in ("spindle", *RENAMED)}
    runup = {m: json.loads(run_cli("runup", pairs[m, "runup"], "--json").stdout) for m in ("spindle", *RENAMED)}
    for machine in RENAMED:
        assert [b["bearing"] for b in iso[machine]["bands"]] == [BEARINGS[b["bearing"]] for b in iso["spindle"]["bands"]]
        for s, b in zip(iso["spindle"]["bands"], iso[machine]["bands"]):
            assert {k: v for k, v in b.items() if k != "bearing"} == {k: v for k, v in s.items() if k != "bearing"}
        assert list(runup[machine]["axes"]) == ["de_x", "de_y", "nde_x", "nde_y"]
        for axis, other in NAMES.items():
            if axis != "axial":
                assert runup[machine]["axes"][other] == runup["spindle"]["axes"][axis]
        assert list(runup[machine]["peaks_1x"]) == ["de_x", "de_y", "nde_x", "nde_y"]
        assert list(runup[machine]["peaks_1x"].values()) == list(runup["spindle"]["peaks_1x"].values())
    # the foreign controller's clearance came from the rig file's [machine]: the same grading without --cmin
    graded = json.loads(run_cli("iso", "vibration", pairs["foreign", "runup"], "--json").stdout)
    assert graded["cmin_um"] == 150.0 and graded["bands"] == iso["foreign"]["bands"]


def test_plot_and_live_status_find_the_blowers_bearings(pairs, run_cli, tmp_path):
    from ambdaq.figures import pyplot
    from ambdaq.live.view import LiveView
    from ambdaq.figures.signal import draw_signal
    from ambdaq.daq import load

    for machine in RENAMED:
        r = run_cli("plot", pairs[machine, "steady"], "--field", "nde_y", "-o", tmp_path / "p.png")
        assert r.exit_code == 0, r.output
        rec = load(pairs[machine, "steady"])
        fig = draw_signal(rec, "/amb/gap", "nde_y", 150e-6)  # the gap, wherever the machine records it
        try:
            orbit = fig.axes[2]
            # the bearing's x across and y up, though its y was the field asked for
            assert (orbit.get_xlabel(), orbit.get_ylabel()) == ("nde_x [µm]", "nde_y [µm]")
        finally:
            pyplot().close(fig)
    # the live status: its bearings and their 1X from blocks of each machine's device
    status = {}
    for machine, (wrap, table) in MACHINES.items():
        device = wrap(SimSource("spindle", seed=5, speed=SpeedProfile(30000, 30000)))
        groups = {device.name: {g.topic: list(g.fields) for g in device.signal_groups()}}
        view = LiveView({device.name: device.sample_rate}, groups, machine_from_sources([device], table))
        device.start(5000)
        while (block := device.read()) is not None:
            view.received(device.name, block)
        device.close()
        status[machine] = view.bearings()
    for machine in RENAMED:
        assert [b.bearing for b in status[machine]] == ["de", "nde"]
        for s, b in zip(status["spindle"], status[machine]):
            assert b.one_x == s.one_x and b.dc_um == s.dc_um
    (front,) = status["one"]
    assert front.bearing == "front" and front.one_x == status["spindle"][0].one_x


def test_the_machine_is_in_the_recording(pairs):
    """What the host side reads: the description the recorder wrote (ambdaq.machine), its roles
    where the devices record them, the rig file's constants beside the device's."""
    foreign = open_recording(pairs["foreign", "steady"])
    m = foreign.machine
    assert m.axes == tuple(NAMES.values()) and [b.name for b in m.bearings] == ["de", "nde"] and m.axial == ("thrust",)
    assert m.role("gap").topic == LOOP and m.role("gap").fields["nde_x"] == "probe_3"
    assert m.cmin_m == SPINDLE.min_clearance and m.rotor == SPINDLE.rotor
    spindle = open_recording(pairs["spindle", "steady"])
    assert "ambdaq.machine" in spindle.metadata and spindle.machine.rotor == SPINDLE.rotor
    np.testing.assert_array_equal(foreign.role("gap")["de_x"], spindle["/amb/gap"]["front_x"])


def test_a_machine_of_one_radial_bearing(pairs, run_cli, tmp_path):
    """One radial bearing and a thrust axis: graded and tracked at that bearing with the spindle's
    front numbers; the rigid-rotor runout separation, which needs two bearings, says so in one line."""
    iso = {m: json.loads(run_cli("iso", "vibration", pairs[m, "runup"], "--cmin", "150", "--json").stdout)
           for m in ("spindle", "one")}
    assert {b["bearing"] for b in iso["one"]["bands"]} == {"front"}
    assert iso["one"]["bands"] == [b for b in iso["spindle"]["bands"] if b["bearing"] == "front"]
    runup = json.loads(run_cli("runup", pairs["one", "runup"], "--json").stdout)
    assert list(runup["axes"]) == ["front_x", "front_y"]
    r = run_cli("runout", "identify", pairs["one", "slow"], "-o", tmp_path / "one.json")
    assert r.exit_code == 2 and "two radial bearings and one axial axis" in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_fleet_scan_holds_each_machines_own_axes(pairs, tmp_path):
    """One dataset of four machines: each row holds its own axes and bearings, with the numbers of
    the spindle's equivalent ones (the fleet's library call, on an in-process Dask cluster)."""
    from distributed import Client

    from ambdaq.workflows.fleet import read, scan

    paths = [pairs[m, "steady"] for m in MACHINES]
    # threads in this process, on TCP bound to loopback (the in-process default, inproc://, opens its
    # HTTP servers on every interface), the scheduler's HTTP server on a free port (it opens one
    # even without a dashboard; 8787 may be another test's)
    with Client(processes=False, n_workers=1, threads_per_worker=1, protocol="tcp://", host="127.0.0.1",
                dashboard_address="127.0.0.1:0", worker_dashboard_address=None) as client:
        report = scan(paths, tmp_path / "fleet.parquet", client)
    assert len(report.scanned) == 4 and not report.errors
    rows = {r["path"].rsplit("/", 1)[-1].split("_")[0]: r for r in read(tmp_path / "fleet.parquet").to_dict("records")}
    spindle = rows["spindle"]
    for machine in RENAMED:
        for axis, other in NAMES.items():
            for figure in ("onex_{}_um", "onex_{}_deg", "runout_{}_1x_um", "runout_{}_2x_deg"):
                assert rows[machine][figure.format(other)] == spindle[figure.format(axis)], (machine, figure)
        for bearing, other in BEARINGS.items():
            assert rows[machine][f"vibration_{other}_um"] == spindle[f"vibration_{bearing}_um"]
            assert rows[machine][f"zone_{other}"] == spindle[f"zone_{bearing}"]
    one = rows["one"]
    assert one["vibration_front_um"] == spindle["vibration_front_um"] and np.isnan(one["vibration_rear_um"])
    assert "two radial bearings" in one["note"]  # its runout: why not


@pytest.mark.realtime  # the rig is served in real time
def test_a_rig_files_machine_table_goes_into_the_recording(run_cli, tmp_path):
    """``record --rig``: the rig file's [machine] table is checked against what the devices record
    before anything is recorded (a field no device records is one line, exit 2) and written into
    the recording over what the controller declares."""
    rig = tmp_path / "rig.toml"
    base = '[[device]]\nname = "ctl"\nurl = "sim://spindle?rpm=3000"\n[machine]\nid = "blower-7"\n'
    rig.write_text(base + 'min_clearance_m = 120e-6\ngap.de_x = "/amb/gap.no_such_axis"\n')
    r = run_cli("record", "--rig", rig, "--duration", "0.2", "-o", tmp_path / "bad.mcap")
    assert r.exit_code == 2 and "/amb/gap has no field 'no_such_axis'" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and not (tmp_path / "bad.mcap").exists()
    rig.write_text(base + 'min_clearance_m = 120e-6\n')
    r = run_cli("record", "--rig", rig, "--duration", "0.2", "-o", tmp_path / "ok.mcap")
    assert r.exit_code == 0, r.output
    rec = open_recording(tmp_path / "ok.mcap")
    assert rec.machine.id == rec.machine_id == "blower-7" and rec.machine.cmin_m == 120e-6  # the rig file's
    assert rec.machine.rotor == SPINDLE.rotor  # the controller's own
