"""CANopen drivers against simulated devices and against canopen's own LocalNode, on the virtual bus."""

import itertools
import struct
import threading
import time

import can
import canopen
import numpy as np
import pytest

from ambdaq.daq import load
from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.drivers.can.bus import bus_load, frame_bits
from ambdaq.drivers.can.device_profiles import ALL_DEVICE_PROFILES, DEVICE_PROFILES, build_od
from ambdaq.drivers.registry import open_device
from ambdaq.speed import SpeedProfile
from ambdaq.sim.rigs.spindle import SpindleRig
from ambdaq.sim.devices.canopen import open_network, serve_can
from ambdaq.sim.devices.rig_server import RigServer
from ambdaq.errors import BadInputError, DeviceError

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

_channels = itertools.count()


@pytest.fixture
def can_rig():
    """A rig at 30,000 rpm with one simulated device of each type on a fresh virtual channel."""
    channel = f"test{next(_channels)}"
    rig = SpindleRig(speed=SpeedProfile(30000, 30000), truth=True)
    server = RigServer(rig)
    net = open_network(channel)
    sims = serve_can(net, server)
    server.start()
    yield channel, server, sims, net
    server.stop()
    net.disconnect()


def test_shipped_eds_files_match_the_profiles():
    for p in ALL_DEVICE_PROFILES.values():
        shipped = canopen.import_od(str(p.eds_path))
        built = build_od(p)
        assert sorted(shipped.indices) == sorted(built.indices)
        for idx in built.indices:
            b, s = built[idx], shipped[idx]
            members = [b] if isinstance(b, canopen.objectdictionary.ODVariable) else list(b.values())
            for m in members:
                sm = s if isinstance(s, canopen.objectdictionary.ODVariable) else s[m.subindex]
                assert (sm.name, sm.data_type, sm.access_type, sm.default) == (m.name, m.data_type, m.access_type, m.default)


def test_frame_bits_and_bus_load():
    assert frame_bits(8) == 135 and frame_bits(0) == 55  # worst-case stuffing, 11-bit id
    assert 1_000_000 // frame_bits(8) == 7407  # "roughly 7,000-8,000 frames/s" at 1 Mbit/s
    assert bus_load([0, 8, 8], 1000, 1_000_000) == pytest.approx((55 + 270) / 1000)


def test_a_stalled_rig_thread_loses_no_sync_cycle(can_rig):
    """The rig's own thread stops for 120 ms, longer than it computes ahead (50 ms): the device
    waits for its sample instead of leaving those SYNCs unanswered, and every cycle keeps its time."""
    channel, server, _sims, _net = can_rig
    p = DEVICE_PROFILES["gap_sensor"]
    listener = can.Bus(interface="virtual", channel=channel)  # sees every SYNC with its bus time
    dev = open_device(f"can://virtual/{channel}?node={p.default_node}&sync=500")
    try:
        dev.start(250)
        stall = threading.Timer(0.1, lambda: server.at_boundary(lambda rig: time.sleep(0.12)))
        stall.start()
        blocks = []
        while (b := dev.read()) is not None:
            blocks.append(b)
        stall.join()
        t = np.concatenate([b.device_time_ns for b in blocks])
        seq = np.concatenate([b.seq for b in blocks]).astype(np.int64)
        assert len(t) == 250 and np.all(np.diff(seq) == 1)  # every SYNC answered, in order
        # each cycle keeps the time of the SYNC it answers (the host's own scheduling jitter moves
        # when SYNCs go out, not which time a cycle gets): the bus's time of it, from its echo
        # (a quarter of the 2 ms period is allowed, for an interface that times it as it is sent)
        syncs = [m.timestamp for m in iter(lambda: listener.recv(0), None) if m.arbitration_id == 0x80]
        lag = np.round(np.array(syncs)[seq] * 1e9).astype(np.int64) - t
        assert lag.min() >= 0 and lag.max() < 500_000
    finally:
        dev.close()
        listener.shutdown()


@pytest.mark.parametrize("kind", sorted(DEVICE_PROFILES))
def test_each_driver_streams_its_simulated_device(can_rig, kind):
    channel, server, _sims, _net = can_rig
    p = DEVICE_PROFILES[kind]
    dev = open_device(f"can://virtual/{channel}?node={p.default_node}&sync=500")
    try:
        assert dev.profile.kind == kind and dev.name == kind
        assert dev.identity()["serial"] == str(1000 + p.default_node)
        dev.start(250)
        blocks = []
        while (b := dev.read()) is not None:
            blocks.append(b)
        t = np.concatenate([b.device_time_ns for b in blocks])
        vals = np.concatenate([b.values[dev.group.topic] for b in blocks])
        seq = np.concatenate([b.seq for b in blocks]).astype(np.int64)
        assert len(t) == 250 and np.all(np.diff(seq) == 1)
        # 500 Hz SYNC: over the whole stream (a SYNC the producer sent late is followed by one
        # sent early to catch up, so single intervals, and under load their median, say less)
        assert (t[-1] - t[0]) / (len(t) - 1) == pytest.approx(2e6, rel=0.02)
        # every value is the rig's value at the SYNC instant, to the resolution of the wire format.
        # The host stamps its SYNC as it hands it to the bus and the device samples when it gets
        # it, microseconds later (under 0.5 ms: test_a_stalled_rig_thread...), which may be the
        # next 100 us rig step: the row must be the rig's sample of one of the steps in between.
        def mismatch(ti: int, row: np.ndarray) -> float:
            _step, rows = server.sample_at(ti)
            expect = rows[p.rig_topic][[c.rig_column for c in p.channels]]
            if kind == "keyphasor":
                expect[0] %= 2 * np.pi
            tol = np.array([c.scale for c in p.channels]) * 0.51 + np.abs(expect) * 1e-6
            diff = row - expect
            if kind == "keyphasor":
                diff[0] = (diff[0] + np.pi) % (2 * np.pi) - np.pi  # an angle is circular
            return float(np.max(np.abs(diff) / tol))

        for ti, row in zip(t[::25], vals[::25]):
            assert min(mismatch(int(ti) + lag, row) for lag in range(0, 500_001, 100_000)) < 1.0
    finally:
        dev.close()


def test_sdo_parameters_and_refusals(can_rig):
    channel, *_ = can_rig
    amp = open_device(f"can://virtual/{channel}?kind=amplifier")
    try:
        assert amp.read_param("bias_current") == pytest.approx(2.1)
        amp.write_param("current_limit", 4.5)
        assert amp.read_param("current_limit") == pytest.approx(4.5)
        with pytest.raises(DeviceError, match="writing temperature failed"):
            amp.write_param("temperature", 20.0)  # read-only: the SDO server aborts
        with pytest.raises(BadInputError, match="no parameter 'gain'"):
            amp.read_param("gain")
    finally:
        amp.close()


@pytest.mark.parametrize("kind", sorted(DEVICE_PROFILES))
def test_driver_against_canopens_own_local_node(kind):
    """An independent peer: canopen's LocalNode with its own PDO encoding, no ambdaq device code."""
    channel = f"peer{next(_channels)}"
    net = open_network(channel)
    p = DEVICE_PROFILES[kind]
    node_id = p.default_node + 1
    node = canopen.LocalNode(node_id, str(p.eds_path))
    net.add_node(node)
    node.set_data(0x1018, 4, struct.pack("<I", 4242), check_writable=False)
    raw = {c.index: 10 * (k + 1) + 7 for k, c in enumerate(p.channels)}  # distinct raw counts, fit a u8

    def on_sync(can_id, data, timestamp):  # canopen's own TPDO machinery
        if node.nmt.state != "OPERATIONAL":
            return
        node.tpdo.read(from_od=False)
        for i, pdo in enumerate(node.tpdo.values()):
            if not pdo.enabled:
                continue
            pdo.cob_id = 0x180 + 0x100 * i + node_id
            for var in pdo:
                var.raw = data[0] if var.index == 0x5000 else raw.get(var.index, 0)
            pdo.transmit()

    net.subscribe(0x80, on_sync)
    dev = open_device(f"can://virtual/{channel}?node={node_id}&sync=200")
    try:
        assert dev.profile.kind == kind and dev.serial == 4242
        dev.start(40)
        rows = np.concatenate([b.values[p.topic] for b in iter(dev.read, None)])
        assert rows.shape == (40, len(p.channels))
        expect = np.array([raw[c.index] * c.scale for c in p.channels])
        np.testing.assert_allclose(rows, np.tile(expect, (40, 1)), rtol=1e-6)
    finally:
        dev.close()
        net.disconnect()


def test_a_reply_ahead_of_its_sync_is_that_syncs_not_one_240_cycles_older():
    """python-can's virtual bus hands a SYNC to each listener in turn, so a device's node can
    answer before the host's own copy of the SYNC reaches it.  A peer bus replays exactly that
    order for one cycle after the counter has wrapped (241 SYNCs): the reply must land on its own
    SYNC, not on the one 240 cycles older with the same counter (a duplicate with an old time)."""
    channel = f"early{next(_channels)}"
    net = open_network(channel)
    p = DEVICE_PROFILES["gap_sensor"]
    node = canopen.LocalNode(p.default_node, str(p.eds_path))  # answers the driver's SDO
    net.add_node(node)
    node.set_data(0x1018, 4, struct.pack("<I", 7), check_writable=False)
    fmt = {canopen.objectdictionary.INTEGER16: "h", canopen.objectdictionary.UNSIGNED16: "H",
           canopen.objectdictionary.UNSIGNED8: "B", canopen.objectdictionary.REAL32: "f",
           canopen.objectdictionary.INTEGER32: "i"}
    packers = [struct.Struct("<" + "".join(fmt[t] for _i, t in p.tpdo_layout(i))) for i in range(len(p.tpdos))]

    def reply(counter: int) -> None:
        for i, packer in enumerate(packers):
            values = [0] * (len(packer.format) - 2) + ([counter] if i == len(packers) - 1 else [0])
            net.bus.send(can.Message(arbitration_id=0x180 + 0x100 * i + p.default_node, is_extended_id=False,
                                     data=packer.pack(*values)))

    def sync(counter: int) -> None:
        net.bus.send(can.Message(arbitration_id=0x80, is_extended_id=False, data=bytes([counter])))

    dev = open_device(f"can://virtual/{channel}?node={p.default_node}&sync=800")
    try:
        dev.configure()  # SDO and the driver's callbacks; the SYNCs come from the peer
        for k in range(242):
            counter = k % 240 + 1
            if k == 241:  # the reply overtakes its SYNC
                reply(counter)
                sync(counter)
            else:
                sync(counter)
                reply(counter)
        net.bus.send(can.Message(arbitration_id=0x700 + p.default_node, is_extended_id=False, data=b"\x05"))
        blocks = []
        while sum(len(b) for b in blocks) < 242:
            blocks.append(dev.read())
        seq = np.concatenate([b.seq for b in blocks]).astype(np.int64)
        t = np.concatenate([b.device_time_ns for b in blocks])
        np.testing.assert_array_equal(seq, np.arange(242))  # cycle 241 once, in its place
        assert np.all(np.diff(t) > 0)  # with its own SYNC's time
    finally:
        dev.close()
        net.disconnect()


def test_bus_load_above_80_percent_is_refused_with_what_fits(can_rig):
    channel, *_ = can_rig
    # per SYNC: the SYNC (1 byte) and 6 TPDOs, 785 bits worst case: 79% at 1 kHz, 86% at 1.1 kHz
    devs = [open_device(f"can://virtual/{channel}?kind={k}&sync=1100") for k in sorted(DEVICE_PROFILES)]
    try:
        devs[0].start(10)
        with pytest.raises(BadInputError, match=r"CAN stream needs 86% of 1,000,000 bit/s \(7 frames per SYNC at 1100 Hz, 7,700 frames/s\); the limit is 80%: use sync=1019 or lower"):
            for d in devs[1:]:
                d.start(10)
    finally:
        for d in devs:
            d.close()


def test_emcy_error_frames_and_heartbeat_loss(can_rig, tmp_path):
    channel, _server, sims, net = can_rig
    amp = open_device(f"can://virtual/{channel}?kind=amplifier&sync=500", name="amp")
    amp.write_param("current_limit", 0.05)  # far below the running currents: over-current EMCY

    def trouble():
        time.sleep(1.0)
        net.bus.send(can.Message(is_error_frame=True, arbitration_id=0x20000004, data=b"\x00\x08\x00\x00\x00\x00\x00\x00"))
        time.sleep(0.8)
        sims[0].node.nmt.stop_heartbeat()  # the amplifier goes silent

    import threading

    threading.Thread(target=trouble, daemon=True).start()
    with pytest.raises(DeviceError, match=r"amp \(can://virtual/.*\) lost at .*no heartbeat from node 16"):
        Recorder([amp], tmp_path / "can.mcap", RecordOptions(duration_s=10)).run()
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(tmp_path / "can.mcap", "rb") as fh:
        msgs = [(c.topic, d) for _s, c, _m, d in make_reader(fh, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=["/amb/events", "/can/bus"])]
    assert any(t == "/amb/events" and d.code == 0x2310 and "Current" in d.text for t, d in msgs), [(t, d.kind, d.code, d.text) for t, d in msgs]
    assert any(t == "/can/bus" and d.kind == "error-frame" for t, d in msgs)
    cur = load(tmp_path / "can.mcap")["/amb/current"]
    assert len(cur) > 500 and np.all(cur.status & 0x1)  # over-current bit in every status word


def test_an_emcy_fires_a_snapshot_fault_trigger(can_rig, tmp_path):
    """A snapshot recording of the amplifier over CAN whose current limit is lowered 1 s in: its
    over-current EMCY is a ``fault`` trigger, and the one file written holds the EMCY event and the
    current samples of [T - 0.4 s, T + 0.3 s), every one of them or counted lost."""
    import json

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from ambdaq.acquisition.snapshot import SnapshotOptions
    from ambdaq.acquisition.triggers import parse_trigger

    channel, *_ = can_rig
    amp = open_device(f"can://virtual/{channel}?kind=amplifier&sync=500", name="amp")
    streaming = threading.Event()

    def limit_once_streaming(progress):
        # 1 s after the first samples arrive, not after the call: a loaded host once took 0.99 s to
        # open the device, and the 0.4 s before the fault had not been recorded yet
        if progress.samples and not streaming.is_set():
            streaming.set()
            threading.Timer(1.0, amp.write_param, ("current_limit", 0.05)).start()  # far below the running currents

    snap = SnapshotOptions(pre_s=0.4, post_s=0.3, max_bytes=64 << 20, triggers=[parse_trigger("fault")])
    Recorder([amp], tmp_path / "emcy.mcap", RecordOptions(duration_s=2.5, snapshot=snap)).run(
        on_progress=limit_once_streaming, progress_interval_s=0.05)
    (f,) = sorted(tmp_path.glob("emcy_*.mcap"))
    assert f.name.endswith("_fault.mcap")
    rec = load(f)
    meta = rec.metadata["ambdaq.snapshot"]
    t, pre, post = int(meta["trigger_ns"]), 400_000_000, 300_000_000
    assert meta["cause"] == "fault" and int(meta["end_ns"]) == t + post
    with open(f, "rb") as fh:
        events = [d for _s, _c, _m, d in make_reader(fh, decoder_factories=[DecoderFactory()])
                  .iter_decoded_messages(topics=["/amb/events"])]
    assert [(e.kind, e.code) for e in events] == [("fault", 0x2310)], [(e.kind, e.code, e.text) for e in events]
    cur = rec["/amb/current"]
    # the samples reach the window's edges within their own largest spacing (SYNC stamps on the host
    # clock: a loaded host delays some) plus 2 ms for the clock map
    slack = np.diff(cur.log_time).max() + 2e6
    assert t - pre <= cur.log_time[0] <= t - pre + slack and t + post - slack <= cur.log_time[-1] < t + post
    drops = json.loads(rec.metadata["ambdaq.statistics"]["/amb/current"])["drops"]
    assert len(cur) + drops == int(cur.seq[-1]) - int(cur.seq[0]) + 1
    assert np.all(cur.status[cur.log_time >= t + 20_000_000] & 0x1)  # over-current bit once it is raised


def test_bus_off_is_reported(can_rig, tmp_path):
    channel, *_ = can_rig
    dev = open_device(f"can://virtual/{channel}?kind=accelerometer&sync=200")

    class BusOff(type(dev.hub.network.bus)):
        state = property(lambda self: can.BusState.ERROR)

    def go_bus_off_once_samples_arrived(p):
        # by what was received, not by a wall time: a loaded host may take most of a second to start
        if p.samples >= 100:
            dev.hub.network.bus.__class__ = BusOff

    with pytest.raises(DeviceError, match="went bus-off"):
        Recorder([dev], tmp_path / "off.mcap", RecordOptions(duration_s=10)).run(
            on_progress=go_bus_off_once_samples_arrived, progress_interval_s=0.05)
    assert len(load(tmp_path / "off.mcap")["/amb/accel"]) >= 100  # what came before is kept


def test_serial_controller_and_can_device_align_within_a_sample(tmp_path):
    """The controller (own clock, +50 ppm, mapped online) against the gap sensor (SYNC stamps on the
    host clock) on one rig: for every instant the CAN device sampled, the controller's log_time of
    that rig step is near the step's true time (bounds and their reasons below)."""
    from ambdaq.sim.devices.controller import FdPort, SimController
    from ambdaq.sim.devices.rig_server import DeviceClock
    from ambdaq.sim.device_kinds import Pty

    channel = f"align{next(_channels)}"
    rig = SpindleRig(speed=SpeedProfile(30000, 30000))
    server = RigServer(rig)
    net = open_network(channel)
    serve_can(net, server, {"gap_sensor": 0x20})
    pty = Pty.open()
    server.start()
    ctl_sim = SimController(FdPort(pty.master), server, clock=DeviceClock(7_000_000_000, 50.0))
    ctl_sim.start()
    try:
        ctl = open_device(f"serial://{pty.path}")
        gap = open_device(f"can://virtual/{channel}?kind=gap_sensor&sync=500&namespace=can")
        res = Recorder([ctl, gap], tmp_path / "mixed.mcap", RecordOptions(duration_s=8)).run()
    finally:
        ctl_sim.stop()
        server.stop()
        net.disconnect()
        pty.close()
    rec = load(tmp_path / "mixed.mcap")
    c, g = rec["/amb/gap"], rec["/can/amb/gap"]
    steps = (g.log_time - server.start_wall_ns) // rig.period_ns  # the rig step each SYNC sampled
    idx = np.searchsorted(c.seq.astype(np.int64), steps)
    ok = (idx < len(c)) & (c.seq[np.minimum(idx, len(c) - 1)].astype(np.int64) == steps)
    assert ok.sum() > 3000
    err = (c.log_time[idx[ok]] - (server.start_wall_ns + steps[ok] * rig.period_ns)) * 1e-3
    # Unmapped, the controller's times would be 7 s off, and its drift alone 400 us off by the end.
    # Mapped, the error is the latency of the fastest clock pairs plus what the map could not know:
    # an idle host keeps within one sample period, but a loaded one lifts every pair for a while
    # (182 us beside the other test worker; 1.4 ms on a CI host held off the CPU).  The recorder
    # states that part: each map's uncertainty includes its revision, how far later fits moved the
    # times already written.  So the bound is 2.5 sample periods plus the recorder's own statement
    # (honest on any host), and the drift must be learned within 20 ppm of the true 50 ppm (15 ppm
    # is the worst CI has shown in the two-controller test of test_serial_controller.py) or, on a
    # host loaded enough to lift the pairs for seconds, within what the recorder states: a drift
    # error carries the times apart by itself times the recording's 8 s, and the stated alignment
    # must hold that (three test workers on two cores: 20.6 ppm, 165 us, beside a stated 556 us).
    settled = g.log_time[ok] > g.log_time[0] + 1_000_000_000
    claim = res.alignment_us
    assert claim == pytest.approx(res.clocks["controller"]["uncertainty_us"])  # the CAN side is exact
    assert np.percentile(np.abs(err[settled]), 99.9) < 250.0 + claim, (claim, np.percentile(err, [1, 50, 99]))
    assert np.abs(err).max() < 350.0 + claim, (claim, np.abs(err).max())
    assert abs(res.clocks["controller"]["drift_ppm"] + 50.0) * 8.0 < max(20.0 * 8.0, claim), res.clocks
    assert res.clocks["gap_sensor"] == {"host_clock": True, "uncertainty_us": 0.0}


def test_amplifier_enable_and_gap_sensor_calibration_by_sdo(can_rig):
    channel, server, *_ = can_rig
    amp = open_device(f"can://virtual/{channel}?kind=amplifier&sync=200")
    gap = open_device(f"can://virtual/{channel}?kind=gap_sensor&sync=200")
    try:
        amp.write_param("enabled", 0)
        gap.write_param("offset", 50e-6)  # 50 um zero shift
        amp.start(60)
        gap.start(60)
        a = [b for b in iter(amp.read, None)]
        g = [b for b in iter(gap.read, None)]
        cur = np.concatenate([b.values["/amb/current"] for b in a])
        status = np.concatenate([b.status for b in a])
        assert np.all(cur == 0.0) and np.all(status & 0x8000 == 0)  # output stage off
        t = np.concatenate([b.device_time_ns for b in g])
        vals = np.concatenate([b.values["/amb/gap"] for b in g])
        _step, rows = server.sample_at(int(t[-1]))
        np.testing.assert_allclose(vals[-1], rows["/amb/gap"] + 50e-6, atol=1.1e-8)
    finally:
        amp.close()
        gap.close()
