"""A machine that is not the spindle's names: a controller that calls its bearings drive end and
non-drive end and its axial axis thrust (``de_x, de_y, nde_x, nde_y, thrust``). The host side takes
its bearings and axes from the recording (ambdaq.machines.machine), so runout identification,
ISO 14839-2 grading, run-up order tracking, plot and the live status give on it the numbers they
give on the spindle's equivalent axes (the same physics, recorded under other names)."""

from __future__ import annotations

import json

import pytest

from ambdaq.daq.recorder import Recorder, RecordOptions, machine_of
from ambdaq.drivers.interfaces import PassThrough
from ambdaq.drivers.signals import SignalGroup
from ambdaq.sim.source import SimSource
from ambdaq.speed import SpeedProfile

NAMES = {"front_x": "de_x", "front_y": "de_y", "rear_x": "nde_x", "rear_y": "nde_y", "axial": "thrust"}
BEARINGS = {"front": "de", "rear": "nde"}


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



@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """(spindle, blower) recordings of the same physics: a steady run, a slow roll, a run-up."""
    d = tmp_path_factory.mktemp("blower")
    out = {}
    for name, speed, seconds in (("steady", SpeedProfile(30000, 30000), 1.0), ("slow", SpeedProfile(800, 800), 2.0),
                                 ("runup", SpeedProfile(0, 30000, 3.0), 3.0)):
        for machine in ("spindle", "blower"):
            source = SimSource("spindle", seed=5, speed=speed)
            path = d / f"{machine}_{name}.mcap"
            Recorder([source if machine == "spindle" else Blower(source)], path,
                     RecordOptions(duration_s=seconds, fsync=False)).run()
            out[machine, name] = path
    return out


def test_runout_identify_gives_the_same_runout_under_other_names(pairs, run_cli, tmp_path):
    coef = {}
    for machine in ("spindle", "blower"):
        r = run_cli("runout", "identify", pairs[machine, "slow"], pairs[machine, "steady"], "-o", tmp_path / f"{machine}.json")
        assert r.exit_code == 0, r.output
        coef[machine] = json.loads((tmp_path / f"{machine}.json").read_text())
    assert coef["blower"]["target"]["axes"] == list(NAMES.values())
    for axis, other in NAMES.items():  # the same fit of the same samples: equal to the last bit
        assert coef["blower"]["runout"]["weights"][other] == coef["spindle"]["runout"]["weights"][axis]


def test_iso_vibration_and_runup_grade_and_track_the_bearings_by_their_own_names(pairs, run_cli):
    iso = {m: json.loads(run_cli("iso", "vibration", pairs[m, "runup"], "--cmin", "150", "--json").stdout)
           for m in ("spindle", "blower")}
    assert [b["bearing"] for b in iso["blower"]["bands"]] == [BEARINGS[b["bearing"]] for b in iso["spindle"]["bands"]]
    for s, b in zip(iso["spindle"]["bands"], iso["blower"]["bands"]):
        assert {k: v for k, v in b.items() if k != "bearing"} == {k: v for k, v in s.items() if k != "bearing"}
    runup = {m: json.loads(run_cli("runup", pairs[m, "runup"], "--json").stdout) for m in ("spindle", "blower")}
    assert list(runup["blower"]["axes"]) == ["de_x", "de_y", "nde_x", "nde_y"]
    for axis, other in NAMES.items():
        if axis != "axial":
            assert runup["blower"]["axes"][other] == runup["spindle"]["axes"][axis]
    assert list(runup["blower"]["peaks_1x"]) == ["de_x", "de_y", "nde_x", "nde_y"]
    assert list(runup["blower"]["peaks_1x"].values()) == list(runup["spindle"]["peaks_1x"].values())


def test_plot_and_live_status_find_the_blowers_bearings(pairs, run_cli, tmp_path):
    from ambdaq.cli.figures import pyplot
    from ambdaq.live.view import LiveView
    from ambdaq.cli.plot import draw_signal
    from ambdaq.daq import load

    r = run_cli("plot", pairs["blower", "steady"], "--field", "nde_y", "-o", tmp_path / "p.png")
    assert r.exit_code == 0, r.output
    rec = load(pairs["blower", "steady"], topics=["/amb/gap", "/amb/rotor"])
    fig = draw_signal(rec, "/amb/gap", "nde_y", 150e-6)
    try:
        orbit = fig.axes[2]
        assert (orbit.get_xlabel(), orbit.get_ylabel()) == ("nde_y [µm]", "nde_x [µm]")
    finally:
        pyplot().close(fig)
    # the live status: its bearings and their 1X from blocks of each machine's device
    status = {}
    for machine in ("spindle", "blower"):
        source = SimSource("spindle", seed=5, speed=SpeedProfile(30000, 30000))
        device = source if machine == "spindle" else Blower(source)
        groups = {device.name: {g.topic: list(g.fields) for g in device.signal_groups()}}
        view = LiveView({device.name: device.sample_rate}, groups, machine_of([device]))
        device.start(5000)
        while (block := device.read()) is not None:
            view.received(device.name, block)
        device.close()
        status[machine] = view.bearings()
    assert [b.bearing for b in status["blower"]] == ["de", "nde"]
    for s, b in zip(status["spindle"], status["blower"]):
        assert b.one_x == s.one_x and b.dc_um == s.dc_um
