"""XCP: the simulated controller's slave proven against an independent master (pyxcp, no ambdaq
code on the master side) and its A2L file read by an independent parser (pya2ldb); then
ambdaq's XCP device, recording and pushing through it."""

from __future__ import annotations

import json
import logging
import struct
import subprocess
import sys
from collections import deque

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile
from ambdaq.drivers.coefbank import BankImage, crc32
from ambdaq.drivers.registry import open_controller
from ambdaq.errors import DeviceError
from ambdaq.sim.serve import serve
from ambdaq.speed import SpeedProfile

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

pyxcp = pytest.importorskip("pyxcp")  # the xcp extra, in the test extras
RADIAL = ("front_x", "front_y", "rear_x", "rear_y")


class Served:
    """The spindle served in this process with its XCP slave; every rig block kept by seq."""

    def __init__(self) -> None:
        self.rig = serve("spindle", speed=SpeedProfile(30000, 30000), can=None, xcp="tcp:0")
        self.slave = self.rig.devices["xcp"]
        self.url = self.rig.urls["xcp"]
        self.port = int(self.url.rsplit(":", 1)[1])
        self.blocks: deque = deque(maxlen=2000)  # 20 s
        self.rig.server.subscribe(self.blocks.append)

    def truth(self, topic: str, field: str, seq: np.ndarray) -> np.ndarray:
        """The rig's value of ``topic``/``field`` at each sample ``seq``."""
        col = [g.fields for g in self.rig.server.rig.signal_groups() if g.topic == topic][0].index(field)
        by_seq = {int(s): v for b in list(self.blocks) for s, v in zip(b.seq, b.values[topic][:, col])}
        return np.array([by_seq[int(s)] for s in seq])


@pytest.fixture(scope="module")
def served():
    s = Served()
    yield s
    s.rig.stop()


@pytest.fixture(scope="module")
def a2l(tmp_path_factory):
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    path = tmp_path_factory.mktemp("a2l") / "spindle.a2l"
    assert CliRunner().invoke(cli, ["sim", "a2l", "-o", str(path)]).exit_code == 0
    return path


def application(port: int):
    """pyxcp's configuration, made first: its DAQ classes would otherwise parse pytest's argv."""
    from pyxcp.config import create_application_from_config, set_application

    app = create_application_from_config({"Transport": {"Eth": {"host": "127.0.0.1", "port": port,
                                                                "protocol": "TCP"}}}, log_level=logging.ERROR)
    app.transport.layer = "ETH"
    set_application(app)  # pyxcp's DAQ classes take their settings from the global one
    return app


def master(port: int, policy=None, app=None):
    from pyxcp.master import Master

    return Master("eth", config=app or application(port), policy=policy)


def described(a2l):
    """The A2L's measurements as pya2ldb reads them: name -> (address, data type, unit)."""
    from pya2l import import_a2l, model

    session = import_a2l(str(a2l), in_memory=True, loglevel="ERROR", progress_bar=False)
    return {m.name: (m.ecu_address.address, m.datatype, m.phys_unit.unit) for m in session.query(model.Measurement)}


def test_pyxcp_reads_the_a2l_measurements_from_the_slave(served, a2l):
    found = described(a2l)
    assert len(found) == len(served.slave.memory.measurements) == 29  # the counter and 28 rig fields
    from pyxcp.master.errorhandler import SystemExit as XcpError

    with master(served.port) as x:
        connected = x.connect()
        assert connected.maxCto == 255 and connected.commModeBasic.byteOrder == "INTEL"
        assert connected.resource.calpag and connected.resource.daq
        assert x.identifier(1) == "AMBDAQ_SPINDLE"  # the A2L's PROJECT name
        values = {}
        for name, (address, datatype, unit) in found.items():
            if name == "control_period":
                assert datatype == "ULONG"
                continue
            assert datatype == "FLOAT32_IEEE" and unit  # every measurement in SI, its unit stated
            values[name] = struct.unpack("<f", x.shortUpload(4, address))[0]
        # the rig's state, read through the A2L's addresses: 30,000 rpm (float32), gaps of tens of um
        assert found["amb.rotor.speed"][2] == "rad/s" and found["amb.gap.front_x"][2] == "m"
        assert values["amb.rotor.speed"] == pytest.approx(30000 * 2 * np.pi / 60, abs=1e-3)
        assert all(abs(values[f"amb.gap.{a}"]) < 1e-4 for a in RADIAL)
        assert -1e-6 <= values["amb.rotor.angle"] < 2 * np.pi + 1e-6  # wrapped to a turn, to float32 rounding
        # calibration is locked until seed & key; a command this slave lacks is ERR_CMD_UNKNOWN
        assert x.getStatus().resourceProtectionStatus.calpag
        with pytest.raises(XcpError, match="ERR_CMD_UNKNOWN"):
            x.programStart()
        x.disconnect()


def test_pyxcp_daq_list_samples_every_control_period(served, a2l):
    """A DAQ list set up by pyxcp's own DaqProcessor on event 0 delivers every control period,
    timestamped on the controller's clock, with the rig's values."""
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy

    names = ["control_period", "amb.gap.front_x", "amb.gap.rear_y", "amb.current.front_x", "amb.rotor.angle"]
    found = described(a2l)
    app = application(served.port)
    rows = []

    class Keep(DaqOnlinePolicy):
        def initialize(self):
            pass

        def finalize(self):
            pass

        def on_daq_list(self, _daq, _ts0, ts1, payload):
            rows.append((ts1, payload))

    policy = Keep([DaqList(name="amb", event_num=0, stim=False, enable_timestamps=True, priority=0, prescaler=1,
                           measurements=[(n, found[n][0], 0, "U32" if n == "control_period" else "F32")
                                         for n in names])])
    with master(served.port, policy, app) as x:
        x.connect()
        x.getCommModeInfo()
        policy.setup()
        policy.start()
        import time

        time.sleep(1.0)
        policy.stop()
        x.disconnect()
    seq = np.array([p[0] for _t, p in rows], dtype=np.int64)
    assert len(seq) > 9000 and np.all(np.diff(seq) == 1)  # every period of the second, none twice
    # 1 us ticks of a clock 50 ppm fast: 100.005 us per period, so steps of 100 or 101 us
    steps = np.diff([t for t, _p in rows]) / 1000
    assert set(np.unique(steps)) <= {100.0, 101.0} and abs(steps.mean() - 100.005) < 0.01
    for k, name in enumerate(names[1:], start=1):
        topic, field = "/" + "/".join(name.split(".")[:2]), name.split(".")[2]
        # float32 is the slave's type: the cast is the one rounding, so the values are equal exactly
        got = np.array([p[k] for _t, p in rows])
        np.testing.assert_array_equal(got, served.truth(topic, field, seq).astype(np.float32), err_msg=name)


def test_record_over_xcp_holds_what_the_controller_sent(served, a2l, tmp_path, run_cli):
    url = served.url
    out = tmp_path / "xcp.mcap"
    r = run_cli("record", "--device", url, "--a2l", a2l, "--duration", "1.5", "--json", "-o", out)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["samples"] == 15000 and summary["drops"] == 0 and summary["duplicates"] == 0
    rec = load(out)
    assert set(rec) == {"/amb/gap", "/amb/current", "/amb/error", "/amb/ff", "/amb/accel", "/amb/rotor"}
    gap = rec["/amb/gap"]
    assert gap.units["front_x"] == "m" and rec["/amb/rotor"].units["speed"] == "rad/s"
    for topic, field in (("/amb/gap", "front_x"), ("/amb/current", "rear_y"), ("/amb/rotor", "angle")):
        got = rec[topic]
        np.testing.assert_array_equal(got[field], served.truth(topic, field, got.seq).astype(np.float32))
    # the official reader and ROS 2 decoder read the same SI values
    with open(out, "rb") as fh:
        decoded = [m for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(topics=["/amb/gap"])]
    assert len(decoded) == len(gap)
    np.testing.assert_array_equal([m.front_x for m in decoded[:500]], gap["front_x"][:500])
    info = run_cli("info", out).output
    assert "xcp controller" in info and "AMBDAQ_SPINDLE" in info
    # the calibration read at open: the constants and the parameters as they were (the gains)
    calibration = McapFile(out).metadata()["ambdaq.calibration.controller"]
    rig = served.rig.server.rig
    assert float(calibration["rotor.mass_kg"]) == float(rig.calibration()["rotor.mass_kg"])
    assert [float(v) for v in calibration["pid.d"].split(",")] == list(rig.pid_gains[2])  # FLOAT64: exact


def test_pyxcp_calibrates_the_controllers_parameters_by_the_a2l(served, a2l):
    """pyxcp's own Master, by the A2L's CHARACTERISTICs: the parameters read as the rig runs them;
    after seed & key a DOWNLOAD changes them, never by half a value; one the controller refuses
    (an amplitude above its test signal's maximum) is ERR_OUT_OF_RANGE and changes nothing."""
    from pya2l import import_a2l, model
    from pyxcp.master.errorhandler import SystemExit as XcpError
    from pyxcp.master.errorhandler import set_suppress_xcp_error_log

    from ambdaq.drivers.xcp.keys import sim_key

    session = import_a2l(str(a2l), in_memory=True, loglevel="ERROR", progress_bar=False)
    found = {c.name: (c.address, c.number.number if c.number else 1, c.lowerLimit, c.upperLimit)
             for c in session.query(model.Characteristic) if not c.read_only and c.deposit == "RL_FLOAT64"}
    assert list(found) == ["pid.p", "pid.i", "pid.d", "ff.mode", "speed.rpm", "exc.signal"]  # ff.mode: controller ff
    assert found["pid.d"][1:] == (5, 1e-6, 1.0) and found["exc.signal"][1] == 3
    rig = served.rig.server.rig
    address, before = found["pid.p"][0], rig.pid_gains[0].copy()
    new = before * 1.02
    raw = struct.pack("<5d", *new)
    set_suppress_xcp_error_log(True)  # the refusal below is expected: no frame dump of pyxcp's
    try:
        with master(served.port) as x:
            x.connect()
            x.setMta(address)
            assert struct.unpack("<5d", x.fetch(40)) == tuple(before)
            assert x.getStatus().resourceProtectionStatus.calpag  # locked until seed & key
            seed = bytes(x.getSeed(0, 0x01).seed)
            key = sim_key(0x01, seed, "ambdaq-sim")
            x.unlock(len(key), key)
            try:
                x.setMta(address)
                x.download(raw[:12])  # the first value and half of the second: nothing taken
                np.testing.assert_array_equal(rig.pid_gains[0], before)
                x.download(raw[12:16])  # the second whole (the MTA moved on): both taken
                np.testing.assert_array_equal(rig.pid_gains[0], [*new[:2], *before[2:]])
                x.download(raw[16:])
                np.testing.assert_array_equal(rig.pid_gains[0], new)
                x.setMta(found["exc.signal"][0])
                with pytest.raises(XcpError, match="ERR_OUT_OF_RANGE"):
                    x.download(struct.pack("<3d", 0, 1e-3, 0))  # 1 mm RMS: the maximum is 20 um
                assert rig.excitation is None
            finally:
                x.setMta(address)
                x.download(struct.pack("<5d", *before))
            np.testing.assert_array_equal(rig.pid_gains[0], before)
            x.disconnect()
    finally:
        set_suppress_xcp_error_log(False)


def test_a_test_signal_the_a2l_describes_badly_is_one_line_exit_2(served, a2l, tmp_path, run_cli):
    bad = tmp_path / "bad.a2l"
    text = a2l.read_text()
    assert "role=test-signal axes=" in text
    bad.write_text(text.replace("role=test-signal axes=", "role=test-signal axis="))
    r = run_cli("controller", "param", "--device", f"{served.url}?a2l={bad}", "pid.d")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert f"A2L file {bad}: exc.signal: a test-signal parameter needs 3 values and axes=" in r.output


def test_push_over_xcp_refusals_leave_the_active_page(served, a2l):
    url = f"{served.url}?a2l={a2l}"
    with open_controller(url) as port:
        status = port.bank_status()
        before = port.read_bank("active", status["active_length"])
        assert crc32(before) == int(status["active_crc32"], 16)  # BUILD_CHECKSUM agrees with the host
        with pytest.raises(DeviceError, match="unlock refused: wrong key"):
            port.unlock("not-the-key")
    with open_controller(url) as port:  # a wrong key ends the session (ASAM XCP Part 2): a new one
        image = BankImage(np.full((5, status["harmonics"], 2), 1e-6)).encode()
        port.unlock("ambdaq-sim")
        port.write_bank(image)
        held = port.bank_status()
        assert held["inactive_crc32"] == f"{crc32(image):08x}" and held["inactive_length"] == len(image)
        with pytest.raises(DeviceError, match="refused the page switch: crc"):
            port.commit_bank(crc32(image) ^ 1, {"file": "wrong-crc"})
        after = port.bank_status()
        assert after["active_bank"] == status["active_bank"] and port.read_bank("active", len(before)) == before


@pytest.mark.parametrize("case", ["garbled", "missing", "key"])
def test_bad_a2l_or_url_is_one_line_exit_2(a2l, tmp_path, run_cli, case):
    bad = tmp_path / "bad.a2l"
    bad.write_text(a2l.read_text().replace("ECU_ADDRESS 0x00010008", "ECU_ADDRESS zz"))
    url, want = {"garbled": (f"xcp+tcp://127.0.0.1:9?a2l={bad}", f"A2L file {bad}: line "),
                 "missing": ("xcp+tcp://127.0.0.1:9", "needs its A2L file"),
                 "key": (f"xcp+tcp://127.0.0.1:9?a2l={a2l}&key=acme", "unknown XCP key algorithm 'acme'")}[case]
    r = run_cli("record", "--device", url, "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and want in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.long  # recording over XCP from another process runs by default (test_xcp_on_can_across_processes_through_slcan)
def test_runout_workflow_over_xcp_against_sim_serve_in_another_process(a2l, tmp_path, run_cli, monkeypatch):
    """Record, identify, push, record and `runout check` over XCP, the slave served by `ambdaq sim
    serve --xcp` in its own process (the commands in this one, through the command line's door):
    the same 20 dB / 5 um as over serial; then the push undone."""
    monkeypatch.setenv("AMBDAQ_UNLOCK_KEY", "ambdaq-sim")
    monkeypatch.setenv("AMBDAQ_STATE_DIR", str(tmp_path / "state"))
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--rpm", "30000", "--xcp", "tcp:0",
                             "--duration", "120"], stdout=subprocess.PIPE, text=True)
    try:
        line = ""
        while not line.startswith("xcp "):
            line = proc.stdout.readline()
            assert line, "sim serve printed no xcp URL"
        url = line.split()[1]  # the A2L by option, as the user types it

        def run(*args):
            r = run_cli(*args)
            assert r.exit_code == 0, r.output
            return r.stdout

        before, after, coef = tmp_path / "before.mcap", tmp_path / "after.mcap", tmp_path / "coef.json"
        run("record", "--device", url, "--a2l", a2l, "--duration", 2.5, "-q", "-o", before)  # 1,250 turns
        run("runout", "identify", before, "-o", coef)
        assert "device-verified" in run("push", coef, "--device", url, "--a2l", a2l, "--yes")
        run("record", "--device", url, "--a2l", a2l, "--duration", 2.5, "-q", "-o", after)
        check = json.loads(run("runout", "check", before, after, "--min-db", 20, "--max-rms", 5, "--json"))
        # and undone over XCP: the feedforward off and on (ff.mode, read back), then the push rolled
        # back, the controller's bank the stock one again, and the runout back in the command error
        stock = json.loads(run("controller", "status", "--device", url, "--a2l", a2l, "--json"))["log"]
        assert "table -> off" in run("controller", "ff", "off", "--device", url, "--a2l", a2l)
        assert "off -> table (the active bank's mode" in run("controller", "ff", "on", "--device", url, "--a2l", a2l)
        assert "rolled back to bank 0" in run("push", "--rollback", "--device", url, "--a2l", a2l, "--yes")
        status = json.loads(run("controller", "status", "--device", url, "--a2l", a2l, "--json"))
        pushed = json.loads((tmp_path / "state" / "push.log").read_text().splitlines()[0])
        assert status["active_crc32"] == pushed["replaced_crc32"] and status["active_mode"] == "off", (status, stock)
        undone = tmp_path / "undone.mcap"
        run("record", "--device", url, "--a2l", a2l, "--duration", 1, "-q", "-o", undone)
        back = json.loads(run("runout", "check", before, undone, "--json"))
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    for a in RADIAL:
        axis = check["axes"][a]
        assert axis["harmonics"][0]["change_db"] <= -20 and axis["harmonics"][1]["change_db"] <= -20, check
        assert axis["rms_after_um"] < 5.0, check  # (and `runout check` exited 0 on the same limits)
        # the runout is back: the 1X of the command error as before the push, within 1 dB
        assert abs(back["axes"][a]["harmonics"][0]["change_db"]) < 1.0, back


def test_xcp_on_sxi_over_a_serial_line(a2l, tmp_path, run_cli, monkeypatch):
    """The same slave on a serial line (a pseudo-terminal; SxI framed with LEN and CTR words):
    pyxcp's SxI transport reads a measurement, ambdaq records every period, pushes and has the
    page stored (STORE_CAL_REQ)."""
    rig = serve("spindle", speed=SpeedProfile(30000, 30000), can=None, xcp="sxi")
    try:
        url = rig.urls["xcp"]
        assert url.startswith("xcp+sxi:///dev/pts/")
        from pyxcp.master import Master

        from pyxcp.config import create_application_from_config

        app = create_application_from_config({"Transport": {"SxI": {
            "port": url[len("xcp+sxi://"):], "bitrate": 3_000_000, "header_format": "HEADER_LEN_CTR_WORD",
            "tail_format": "NO_CHECKSUM"}}}, log_level=logging.ERROR)
        app.transport.layer = "SXI"
        with Master("sxi", config=app) as x:
            x.connect()
            address = described(a2l)["amb.rotor.speed"][0]
            assert struct.unpack("<f", x.shortUpload(4, address))[0] == pytest.approx(30000 * np.pi / 30, abs=1e-3)
            x.disconnect()
        out = tmp_path / "sxi.mcap"
        r = run_cli("record", "--device", url, "--a2l", a2l, "--duration", "1", "--json", "-o", out)
        assert r.exit_code == 0, r.output
        assert json.loads(r.stdout)["samples"] == 10000 and json.loads(r.stdout)["drops"] == 0
        coef = tmp_path / "coef.json"
        assert run_cli("runout", "identify", out, "-o", coef).exit_code == 0
        monkeypatch.setenv("AMBDAQ_STATE_DIR", str(tmp_path / "state"))
        r = run_cli("push", coef, "--device", f"{url}?a2l={a2l}&store=1", "--key", "ambdaq-sim", "--yes")
        assert r.exit_code == 0 and "device-verified" in r.output, r.output
        with open_controller(f"{url}?a2l={a2l}") as port:  # store=1: STORE_CAL_REQ kept the new page
            status = port.bank_status()
            assert status["stored_crc32"] == status["active_crc32"] and status["log"][-1]["file"] == "coef.json"
    finally:
        rig.stop()


def test_devices_asks_an_address_for_an_xcp_slave(served, a2l, tmp_path, run_cli):
    r = run_cli("devices", "--ask-xcp", served.url, "--json")
    assert r.exit_code == 0, r.output
    (slave,) = json.loads(r.stdout)["xcp"]
    assert slave == {"url": served.url, "asap2_name": "AMBDAQ_SPINDLE", "max_cto": "255", "max_dto": "1024",
                     "byte_order": "INTEL", "resources": "calpag,daq", "protected": "calpag",
                     "event_0": "control (every 100 us)", "lacks": "none of the optional commands asked"}
    # nothing listening there: one line, exit 1, for asking and for recording alike
    for args in (("devices", "--ask-xcp", "xcp+tcp://127.0.0.1:9"),
                 ("record", "--device", "xcp+tcp://127.0.0.1:9", "--a2l", a2l, "--duration", "1", "-o", tmp_path / "x.mcap")):
        r = run_cli(*args)
        assert r.exit_code == 1 and "127.0.0.1:9" in r.output and "Connection refused" in r.output, r.output
        assert len(r.output.strip().splitlines()) == 1


def test_xcp_on_can_with_a_prescaler_the_bus_can_carry(a2l, tmp_path, run_cli):
    """The same slave on the rig's CAN bus (python-can's virtual interface, in this process):
    pyxcp's CAN transport reads a measurement; a DAQ list the bus cannot carry is refused with the
    prescaler that fits; two measurements every 10th period are recorded with none lost."""
    rig = serve("spindle", speed=SpeedProfile(30000, 30000), can="virtual", xcp="can")
    blocks: deque = deque(maxlen=500)
    rig.server.subscribe(blocks.append)
    try:
        url = rig.urls["xcp"]
        assert url.startswith("xcp+can://virtual/") and "id_master=0x7F1&id_slave=0x7F2" in url
        from pyxcp.config import create_application_from_config
        from pyxcp.master import Master

        interface, channel = url[len("xcp+can://"):].split("?")[0].split("/", 1)
        app = create_application_from_config({"Transport": {"CAN": {
            "interface": interface, "channel": channel, "can_id_master": 0x7F1, "can_id_slave": 0x7F2}}},
            log_level=logging.ERROR)
        app.transport.layer = "CAN"
        with Master("can", config=app) as x:
            connected = x.connect()
            assert connected.maxCto == 8 and connected.maxDto == 8  # one CAN frame per packet
            address = described(a2l)["amb.rotor.speed"][0]
            assert struct.unpack("<f", x.shortUpload(4, address))[0] == pytest.approx(30000 * np.pi / 30, abs=1e-3)
            x.disconnect()
        # every measurement every period: 18 frames per sample, far beyond 1 Mbit/s
        r = run_cli("record", "--device", url, "--a2l", a2l, "--duration", "1", "-o", tmp_path / "all.mcap")
        assert r.exit_code == 2 and "give prescaler=" in r.output and len(r.output.strip().splitlines()) == 1, r.output
        rigfile = tmp_path / "rig.toml"
        rigfile.write_text(f'''[[device]]
name = "controller"
url = "{url}&prescaler=10"
a2l = "{a2l}"
measurements = ["amb.gap.front_x", "amb.rotor.angle"]
''')
        out = tmp_path / "can.mcap"
        r = run_cli("record", "--rig", rigfile, "--duration", "1", "--json", "-o", out)
        assert r.exit_code == 0, r.output
        summary = json.loads(r.stdout)
        assert summary["samples"] == 1000 and summary["drops"] == 0  # 10 kHz / 10 for 1 s
        gap = load(out)["/amb/gap"]
        assert list(gap.fields) == ["front_x"] and gap.nominal_rate == 1000.0
        assert np.all(np.diff(gap.seq.astype(np.int64)) == 1)
        col = [g.fields for g in rig.server.rig.signal_groups() if g.topic == "/amb/gap"][0].index("front_x")
        by_seq = {int(s): v for b in list(blocks) for s, v in zip(b.seq, b.values["/amb/gap"][:, col])}
        # seq counts samples: the controller's period is seq x 10 (float32 on the wire, exactly)
        np.testing.assert_array_equal(gap["front_x"], np.float32([by_seq[int(s) * 10] for s in gap.seq]))
    finally:
        rig.stop()


def test_xcp_on_can_across_processes_through_slcan(a2l, tmp_path, run_cli):
    """`sim serve --can slcan --xcp can` in its own process: the slave on the rig's CAN bus,
    reached through the simulated SLCAN adapter with python-can's slcan interface."""
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--rpm", "30000", "--can", "slcan",
                             "--xcp", "can", "--duration", "60"], stdout=subprocess.PIPE, text=True)
    try:
        line = ""
        while not line.startswith("xcp "):
            line = proc.stdout.readline()
            assert line, "sim serve printed no xcp URL"
        url = line.split()[1]
        assert url.startswith("xcp+can://slcan/dev/pts/")
        rigfile = tmp_path / "rig.toml"
        rigfile.write_text(f'[[device]]\nname = "controller"\nurl = "{url}&prescaler=20"\na2l = "{a2l}"\n'
                           'measurements = ["amb.gap.front_x", "amb.rotor.angle"]\n')
        r = run_cli("record", "--rig", rigfile, "--duration", "1", "--json", "-o", tmp_path / "can.mcap")
        assert r.exit_code == 0, r.output
        summary = json.loads(r.stdout)
        assert summary["samples"] == 500 and summary["drops"] == 0  # 10 kHz / 20 for 1 s
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_a_slave_that_never_answers_is_one_line_exit_1(a2l, tmp_path, run_cli):
    """A TCP port that accepts and then says nothing (a hung controller): a timeout, one line."""
    import socket
    import threading

    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    held = []
    threading.Thread(target=lambda: held.append(listener.accept()), daemon=True).start()
    try:
        r = run_cli("record", "--device", f"xcp+tcp://127.0.0.1:{port}", "--a2l", a2l, "--duration", "1",
                    "-o", tmp_path / "x.mcap")
        assert r.exit_code == 1 and "connect" in r.output and len(r.output.strip().splitlines()) == 1, r.output
        assert not (tmp_path / "x.mcap").exists()
    finally:
        listener.close()


def test_an_xcp_error_response_is_named_with_its_meaning(served):
    """A command out of sequence (WRITE_DAQ before SET_DAQ_PTR): the slave answers ERR_SEQUENCE,
    which ambdaq reports as one line with its meaning."""
    from ambdaq.drivers.xcp.device import xcp_errors
    from ambdaq.drivers.xcp.master import XcpMaster
    from ambdaq.drivers.xcp.transport import TcpLink

    x = XcpMaster(TcpLink(served.url, "127.0.0.1", served.port, 2.0), served.url)
    try:
        x.connect()
        x.free_daq()
        with pytest.raises(DeviceError) as err:
            with xcp_errors(served.url, "write a DAQ entry"):
                x.write_daq(4, 0, 0x0001_0000)
        x.disconnect()
    finally:
        x.close()
    assert str(err.value) == f"{served.url}: write a DAQ entry: the controller answered ERR_SEQUENCE (commands out of sequence)"


def test_static_daq_lists_hold_what_the_controller_sent(a2l, tmp_path, run_cli):
    """A slave whose DAQ lists are static (3 lists of 16 ODTs of 7 entries, as many ECUs have: no
    FREE_DAQ or ALLOC): every measurement of the A2L goes into the room GET_DAQ_LIST_INFO gives,
    after CLEAR_DAQ_LIST (the slave refuses an eighth entry in an ODT), and each recorded value is
    the rig's at that sample."""
    rig = serve("spindle", speed=SpeedProfile(30000, 30000), can=None, xcp="tcp:0", static_daq=True)
    blocks: deque = deque(maxlen=2000)
    rig.server.subscribe(blocks.append)
    try:
        out = tmp_path / "static.mcap"
        r = run_cli("record", "--device", rig.urls["xcp"], "--a2l", a2l, "--duration", "1", "--json", "-o", out)
        assert r.exit_code == 0, r.output
        summary = json.loads(r.stdout)
        assert summary["samples"] == 10000 and summary["drops"] == 0
        rec = load(out)
        for topic, field in (("/amb/gap", "front_x"), ("/amb/current", "rear_y"), ("/amb/rotor", "angle")):
            got = rec[topic]
            col = [g.fields for g in rig.server.rig.signal_groups() if g.topic == topic][0].index(field)
            by_seq = {int(s): v for b in list(blocks) for s, v in zip(b.seq, b.values[topic][:, col])}
            np.testing.assert_array_equal(got[field], np.array([by_seq[int(s)] for s in got.seq], dtype=np.float32))
    finally:
        rig.stop()
