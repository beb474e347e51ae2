"""``ambdaq push`` and ``ambdaq controller status`` against the simulated controller, over its
serial line (a PTY) and its CANopen configuration port (python-can ``virtual``), through the CLI.

Every failure test reads the controller back afterwards and shows the active coefficients did
not change."""

import hashlib
import itertools
import json
import threading
import time

import numpy as np
import pytest
from click.testing import CliRunner

from ambdaq.cli.main import cli
from ambdaq.documents.coefficients import Coefficients
from ambdaq.drivers.serial.controller import ControllerDriver
from ambdaq.speed import SpeedProfile
from ambdaq.sim.rigs.spindle import N_HARMONICS, SpindleRig
from ambdaq.drivers.serial.link import SerialLink
from ambdaq.sim.devices.banks import DEFAULT_UNLOCK_KEY
from ambdaq.sim.devices.canopen import SimCanController, open_network
from ambdaq.sim.devices.controller import SimController
from ambdaq.sim.devices.faults import FaultyPort
from ambdaq.sim.devices.rig_server import RigServer
from ambdaq.sim.device_kinds import Pty

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

AXES = ["front_x", "front_y", "rear_x", "rear_y", "axial"]
_channels = itertools.count()


class Controller:
    """One simulated controller at 30,000 rpm with two ports sharing its banks: a serial line
    (which can be stalled) and a CANopen configuration port."""

    def __init__(self):
        self.rig = SpindleRig(speed=SpeedProfile(30000, 30000))
        self.server = RigServer(self.rig)
        self.pty = Pty.open()
        self.port = FaultyPort(self.pty.master)
        self.sim = SimController(self.port, self.server)
        self.channel = f"push-test-{next(_channels)}"
        self.network = open_network(self.channel)
        self.can_port = SimCanController(self.network, self.sim.banks)
        self.server.start()
        self.sim.start()
        self.serial_url = f"serial://{self.pty.path}"
        self.can_url = f"can://virtual/{self.channel}?node=0x50"

    def close(self):
        self.sim.stop()
        self.server.stop()
        self.network.disconnect()
        self.pty.close()

    def active(self):
        """What the controller runs: (mode, weights, active bank CRC), read over the serial line."""
        drv = ControllerDriver(SerialLink(self.pty.path))
        try:
            mode = int(drv.read_param("ff.mode")[0])
            table = drv.read_param("ff.table").reshape(5, N_HARMONICS, 2)
            return mode, table, drv.bank_status()["active_crc32"]
        finally:
            drv.close()


@pytest.fixture
def ctl(tmp_path, monkeypatch):
    monkeypatch.setenv("AMBDAQ_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.delenv("AMBDAQ_UNLOCK_KEY", raising=False)
    c = Controller()
    yield c
    c.close()


def runout_file(path, rig, *, scale=1.0, schedule=(), axes=AXES, harmonics=range(1, 7)):
    """A coefficient file with the rig's true runout as the feedforward weights."""
    s, c = rig.params.runout_sin_cos()
    weights = {a: [[scale * s[i, k - 1], scale * c[i, k - 1]] for k in harmonics] for i, a in enumerate(axes)}
    Coefficients({"rig": "spindle", "axes": list(axes)}, {"method": "test"}, list(harmonics), weights,
                 [list(r) for r in schedule]).save(path, overwrite=True)
    return path


def run(*args, env=None):
    return CliRunner().invoke(cli, [str(a) for a in args], env=env)


def expected_table(rig, scale=1.0):
    s, c = rig.params.runout_sin_cos()
    t = np.zeros((5, N_HARMONICS, 2))
    t[:, :6, 0], t[:, :6, 1] = scale * s[:, :6], scale * c[:, :6]
    return t


@pytest.mark.parametrize("port", ["serial", "can"])
def test_push_commits_verified_and_logs_on_both_sides(ctl, tmp_path, port):
    url = ctl.serial_url if port == "serial" else ctl.can_url
    coef = runout_file(tmp_path / "coef.json", ctl.rig)
    before = ctl.active()
    assert before[0] == 0  # feedforward off
    r = run("push", coef, "--device", url, "--key", DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 0, r.output
    assert "device-verified" in r.output
    mode, table, crc = ctl.active()
    assert mode == 1 and crc != before[2]
    np.testing.assert_allclose(table, expected_table(ctl.rig), atol=1e-15)
    # the controller's log and ours name the file's hash and the target
    st = json.loads(run("controller", "status", "--device", url, "--json").output)
    assert st["active_crc32"] == crc and st["active_bank"] == 1 and st["locked"]
    sha = hashlib.sha256(coef.read_bytes()).hexdigest()
    assert st["active_source_sha256"] == sha
    (entry,) = st["log"]
    assert entry["file_sha256"] == sha and entry["target"] == url and entry["crc32"] == crc
    local = [json.loads(line) for line in (tmp_path / "state" / "push.log").read_text().splitlines()]
    assert local[-1]["outcome"] == "committed" and local[-1]["file_sha256"] == sha
    text = run("controller", "status", "--device", url).output
    assert f"CRC-32 {crc}" in text and "coef.json" in text
    # the same file again: nothing to write
    r = run("push", coef, "--device", url, "--key", DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 0 and "already holds" in r.output


def test_declining_the_confirmation_writes_nothing(ctl, tmp_path):
    """Without --yes the difference is shown and a "no" ends the push: said in words, exit 0,
    neither bank touched."""
    before, inactive = ctl.active(), ctl.sim.banks.status()["inactive_crc32"]
    r = CliRunner().invoke(cli, ["push", str(runout_file(tmp_path / "c.json", ctl.rig)), "--device", ctl.serial_url,
                                 "--key", DEFAULT_UNLOCK_KEY], input="n\n")
    assert r.exit_code == 0 and r.output.strip().endswith("push cancelled, nothing written"), r.output
    assert "Aborted" not in r.output
    assert ctl.active()[2] == before[2] and ctl.sim.banks.status()["inactive_crc32"] == inactive


@pytest.mark.parametrize("port", ["serial", "can"])
def test_wrong_key_is_refused_and_nothing_is_written(ctl, tmp_path, port):
    url = ctl.serial_url if port == "serial" else ctl.can_url
    before = ctl.active()
    inactive_before = ctl.sim.banks.status()["inactive_crc32"]
    r = run("push", runout_file(tmp_path / "c.json", ctl.rig), "--device", url, "--key", "guess", "--yes")
    assert r.exit_code == 1
    assert r.output.count("\n") == 1 and ("wrong unlock key" in r.output or "locked" in r.output)
    after = ctl.active()
    assert after[0] == before[0] and after[2] == before[2]
    np.testing.assert_array_equal(after[1], before[1])
    assert ctl.sim.banks.status()["inactive_crc32"] == inactive_before  # not even the inactive bank
    assert ctl.sim.banks.status()["log"] == []


def test_key_comes_from_environment_or_rig_file(ctl, tmp_path):
    coef = runout_file(tmp_path / "c.json", ctl.rig)
    r = run("push", coef, "--device", ctl.serial_url, "--yes")
    assert r.exit_code == 2 and "no unlock key" in r.output
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[[device]]\nname = "ctl"\nurl = "{ctl.serial_url}"\nunlock_key = "{DEFAULT_UNLOCK_KEY}"\n')
    assert run("push", coef, "--rig", rig, "--device", "ctl", "--yes").exit_code == 0
    coef2 = runout_file(tmp_path / "c2.json", ctl.rig, scale=0.5)
    r = run("push", coef2, "--device", ctl.serial_url, "--yes", env={"AMBDAQ_UNLOCK_KEY": DEFAULT_UNLOCK_KEY})
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(ctl.active()[1], expected_table(ctl.rig, 0.5), atol=1e-15)


@pytest.mark.parametrize("port", ["serial", "can"])
def test_crc_mismatch_on_readback_is_not_committed(ctl, tmp_path, monkeypatch, port):
    """The device's memory corrupts one byte of the image: the CRC it computes disagrees with the
    host's, so the host never commits."""
    url = ctl.serial_url if port == "serial" else ctl.can_url
    banks = ctl.sim.banks
    write = banks.write

    def corrupting(offset, total, data):
        data = bytearray(data)
        if offset <= 100 < offset + len(data):
            data[100 - offset] ^= 0x10
        write(offset, total, bytes(data))

    monkeypatch.setattr(banks, "write", corrupting)
    before = ctl.active()
    r = run("push", runout_file(tmp_path / "c.json", ctl.rig), "--device", url, "--key", DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 1 and "read-back CRC-32" in r.output and "not committed" in r.output
    after = ctl.active()
    assert after[0] == before[0] and after[2] == before[2]
    np.testing.assert_array_equal(after[1], before[1])
    assert "failed" in (tmp_path / "state" / "push.log").read_text()


def test_commit_with_a_wrong_crc_is_refused_by_the_device(ctl, tmp_path):
    """Even a host that skipped the read-back cannot switch to a bank that does not hold the CRC
    it names: the device refuses (NAK 7) and keeps the active bank."""
    drv = ControllerDriver(SerialLink(ctl.pty.path))
    try:
        before = drv.bank_status()
        drv.unlock(DEFAULT_UNLOCK_KEY)
        drv.write_bank(b"AMBC" + bytes(60))
        with pytest.raises(Exception, match="CRC-32"):
            drv.commit_bank(0x12345678, {})
        drv.unlock(DEFAULT_UNLOCK_KEY)
        with pytest.raises(Exception, match="image|header"):  # the right CRC of a malformed image
            drv.commit_bank(int(drv.bank_status()["inactive_crc32"], 16), {})
        assert drv.bank_status()["active_crc32"] == before["active_crc32"]
    finally:
        drv.close()


def test_link_lost_mid_transfer_leaves_the_active_bank(ctl, tmp_path):
    """The serial line goes dead after the second bank write: the push fails (exit 1, one line)
    and, once the line is back, the controller still runs what it ran before."""
    before = ctl.active()
    port = ctl.port
    writes = {"n": 0}
    banks = ctl.sim.banks
    bank_write = banks.write

    def count_then_die(offset, total, data):
        writes["n"] += 1
        bank_write(offset, total, data)
        if writes["n"] == 2:
            port.stalled.set()  # nothing leaves the device from now on: the host times out

    banks.write = count_then_die
    r = run("push", runout_file(tmp_path / "c.json", ctl.rig), "--device", ctl.serial_url, "--key",
            DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 1 and r.output.count("\n") == 1, r.output
    port.stalled.clear()
    after = ctl.active()
    assert after[0] == before[0] and after[2] == before[2]
    np.testing.assert_array_equal(after[1], before[1])


def test_rig_not_running_makes_the_device_refuse_the_commit(ctl, tmp_path):
    """A controller that cannot reach a control-period boundary (its loop stopped) answers BUSY
    and keeps the active bank."""
    before = ctl.active()
    ctl.server.stop()
    r = run("push", runout_file(tmp_path / "c.json", ctl.rig), "--device", ctl.can_url, "--key",
            DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 1 and "busy" in r.output
    assert ctl.sim.banks.status()["active_crc32"] == before[2]
    # the refused switch was withdrawn: the loop's next boundary (run here by hand) applies nothing
    ctl.server._apply_boundary()
    after = ctl.active()
    assert after[0] == before[0] and after[2] == before[2]
    np.testing.assert_array_equal(after[1], before[1])


def test_validation_refuses_before_anything_is_written(ctl, tmp_path):
    rig = ctl.rig
    cases = {
        "axis 'spare' does not exist": runout_file(tmp_path / "a.json", rig, axes=AXES[:4] + ["spare"]),
        "exceeds 1 mm": runout_file(tmp_path / "big.json", rig, scale=1e3),
        "LMS schedule is not stable": runout_file(tmp_path / "s.json", rig, schedule=[(0, 60000, 0.001)]),
        # the work a file can ask for is bounded: 200 such rows, for the controller's 8 harmonics
        # on both bearings every 100 rpm, are 1,920,000 points of the map
        "1,920,000 points of the convergence map": runout_file(tmp_path / "g.json", rig, schedule=[(0, 60000, 0.001)] * 200),
    }
    doc = json.loads((tmp_path / "a.json").read_text())  # a file whose harmonics the controller lacks
    doc["runout"]["harmonics"] = [1, 2, 3, 4, 5, 9]
    doc.pop("checksum")
    Coefficients(doc["target"], doc["source"], doc["runout"]["harmonics"],
                 {a: doc["runout"]["weights"]["front_x"] for a in AXES}).save(tmp_path / "h.json")
    cases["harmonic 9X is not run"] = tmp_path / "h.json"
    nan = json.loads((tmp_path / "big.json").read_text())
    nan["runout"]["weights"]["front_x"][0][0] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps(nan))
    before = ctl.sim.banks.status()
    for why, path in cases.items():
        r = run("push", path, "--device", ctl.serial_url, "--key", DEFAULT_UNLOCK_KEY, "--yes")
        assert r.exit_code == 2 and why in r.output and r.output.count("\n") == 1, (why, r.output)
    r = run("push", tmp_path / "nan.json", "--device", ctl.serial_url, "--key", DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 2 and ("checksum" in r.output or "finite" in r.output)
    after = ctl.sim.banks.status()
    assert after["inactive_crc32"] == before["inactive_crc32"] and after["active_crc32"] == before["active_crc32"]
    # a schedule stable on the map passes: -mu below the flip, held around it, +mu above, 1X only
    ok = runout_file(tmp_path / "ok.json", rig, schedule=[(1, 200, 12500, -0.001), (1, 17000, 60000, 0.001)])
    assert run("push", ok, "--device", ctl.serial_url, "--key", DEFAULT_UNLOCK_KEY, "--yes").exit_code == 0


def test_dry_run_prints_the_difference_and_writes_nothing(ctl, tmp_path):
    before = ctl.sim.banks.status()
    r = run("push", runout_file(tmp_path / "c.json", ctl.rig), "--device", ctl.serial_url, "--dry-run")
    assert r.exit_code == 0, r.output
    assert "mode: off -> table" in r.output and "front_x  1X:" in r.output and "dry run: nothing written" in r.output
    assert ctl.sim.banks.status() == before


def test_the_switch_happens_at_a_control_period_boundary(ctl, tmp_path):
    """Push over CAN while the serial line streams: every sample before the reported first sample
    ran the old bank (no feedforward), every sample from it on runs the new table exactly."""
    drv = ControllerDriver(SerialLink(ctl.pty.path))
    blocks, stop = [], threading.Event()

    def stream():
        drv.start(None)
        while not stop.is_set():
            blocks.append(drv.read())

    t = threading.Thread(target=stream, daemon=True)
    t.start()
    try:
        threading.Event().wait(0.3)
        r = run("push", runout_file(tmp_path / "c.json", ctl.rig), "--device", ctl.can_url, "--key",
                DEFAULT_UNLOCK_KEY, "--yes")
        assert r.exit_code == 0, r.output
        first = ctl.sim.banks.status()["log"][-1]["effective_sample"]
        threading.Event().wait(0.3)
    finally:
        stop.set()
        t.join(2)
        drv.close()
    seq = np.concatenate([b.seq for b in blocks]).astype(np.int64)
    ff = np.concatenate([b.values["/amb/ff"] for b in blocks])
    theta = np.concatenate([b.values["/amb/rotor"][:, 0] for b in blocks])
    assert seq[0] < first < seq[-1]
    old, new = seq < first, seq >= first
    assert np.all(ff[old] == 0.0)
    s, c = ctl.rig.params.runout_sin_cos()
    k = np.arange(1, 7)
    want = (np.sin(np.outer(theta[new], k)) @ s[:, :6].T + np.cos(np.outer(theta[new], k)) @ c[:, :6].T)
    np.testing.assert_allclose(ff[new], want, atol=2e-9)  # float32 on the wire


def test_a_base_motion_fir_is_refused_by_a_controller_that_runs_none(ctl, tmp_path):
    taps = np.full((2, 2, 2, 3), 0.01)
    fir = {"sample_rate_hz": 10000.0, "unit": "V/(m/s^2)", "planes": {"vertical": taps[0].tolist(),
                                                                     "horizontal": taps[1].tolist()}}
    path = tmp_path / "fir.json"
    Coefficients({"rig": "base-motion"}, {"method": "test"}, [], {}, fir=fir).save(path)
    before = ctl.active()
    r = run("push", path, "--device", ctl.serial_url, "--key", DEFAULT_UNLOCK_KEY, "--yes")
    assert r.exit_code == 2 and "this controller runs no FIR feedforward" in r.output
    assert ctl.active()[2] == before[2]


@pytest.mark.parametrize("port", ["serial", pytest.param("can", marks=pytest.mark.long)])  # a push over CAN: above
def test_rollback_puts_back_what_the_push_replaced_bit_for_bit(ctl, tmp_path, port):
    """Two pushes, then --rollback twice: each puts back the bank the push before it replaced, read
    back from the controller byte for byte (its CRC-32 and the bank's bytes); a third rollback
    undoes the second; a rollback when the controller runs what no push of ours wrote is refused
    with nothing written."""
    url = ctl.serial_url if port == "serial" else ctl.can_url
    first = runout_file(tmp_path / "first.json", ctl.rig)
    second = runout_file(tmp_path / "second.json", ctl.rig, scale=0.5)
    def bank() -> tuple[str, bytes]:  # what the controller runs, read over its serial line
        drv = ControllerDriver(SerialLink(ctl.pty.path))
        try:
            st = drv.bank_status()
            return st["active_crc32"], drv.read_bank("active", st["active_length"])
        finally:
            drv.close()

    stock = bank()
    key = ("--key", DEFAULT_UNLOCK_KEY)
    r = run("push", "--rollback", "--device", url, *key, "--yes")
    assert r.exit_code == 2 and "nothing to roll back" in r.output, r.output
    assert run("push", first, "--device", url, *key, "--yes").exit_code == 0
    pushed_first = bank()
    assert run("push", second, "--device", url, *key, "--yes").exit_code == 0
    r = run("push", "--rollback", "--device", url, *key, "--dry-run")
    assert r.exit_code == 0 and "the bank before second.json" in r.output and "dry run" in r.output, r.output
    r = run("push", "--rollback", "--device", url, *key, "--yes")
    assert r.exit_code == 0 and "rolled back" in r.output and "device-verified" in r.output, r.output
    assert bank() == pushed_first
    mode, table, _ = ctl.active()
    assert mode == 1 and np.allclose(table, expected_table(ctl.rig), atol=1e-15)  # first.json's, not half of it
    r = run("push", "--rollback", "--device", url, *key, "--yes")  # the rollback itself is undone
    assert r.exit_code == 0 and bank()[0] != pushed_first[0]
    np.testing.assert_allclose(ctl.active()[1], expected_table(ctl.rig, 0.5), atol=1e-15)
    assert run("push", "--rollback", "--device", url, *key, "--yes").exit_code == 0
    assert bank() == pushed_first
    # each push's entry names what it replaced, kept byte for byte
    log = [json.loads(line) for line in (tmp_path / "state" / "push.log").read_text().splitlines()]
    assert log[0]["replaced_crc32"] == stock[0]
    assert (tmp_path / "state" / "banks" / f"{stock[0]}.bin").read_bytes() == stock[1]
    # another host changed the bank since: refused, nothing written
    other = runout_file(tmp_path / "other.json", ctl.rig, scale=0.25)
    monkey_state = tmp_path / "elsewhere"
    r = run("push", other, "--device", url, *key, "--yes", env={"AMBDAQ_STATE_DIR": str(monkey_state)})
    assert r.exit_code == 0, r.output
    before = ctl.active()[2]
    r = run("push", "--rollback", "--device", url, *key, "--yes")
    assert r.exit_code == 2 and "something else changed it since; nothing written" in r.output, r.output
    assert ctl.active()[2] == before


def test_the_feedforward_switches_off_holds_and_comes_back_without_the_bank(ctl, tmp_path):
    """``controller ff off`` stops the pushed LMS, ``on`` resumes it from the weights it held (the
    bank untouched: its CRC-32 the same throughout), ``hold`` runs those weights as a fixed table;
    each read back from ff.mode."""
    coef = runout_file(tmp_path / "lms.json", ctl.rig, scale=0.5, schedule=[(1, 200, 12500, -0.001), (1, 17000, 60000, 0.001)])
    url = ctl.serial_url
    assert run("push", coef, "--device", url, "--key", DEFAULT_UNLOCK_KEY, "--yes").exit_code == 0
    mode, _, crc = ctl.active()
    assert mode == 2
    r = run("controller", "ff", "off", "--device", url)
    assert r.exit_code == 0 and "feedforward lms -> off" in r.output, r.output
    assert ctl.active()[0] == 0 and ctl.active()[2] == crc
    frozen = ctl.active()[1]
    time.sleep(0.2)
    np.testing.assert_array_equal(ctl.active()[1], frozen)  # off: nothing adapts
    r = run("controller", "ff", "on", "--device", url)
    assert r.exit_code == 0 and "feedforward off -> lms (the active bank's mode" in r.output, r.output
    r = run("controller", "ff", "hold", "--device", url)
    assert r.exit_code == 0 and "-> table" in r.output
    held = ctl.active()[1]
    time.sleep(0.2)
    np.testing.assert_array_equal(ctl.active()[1], held)  # hold: the weights as they were
    assert ctl.active()[2] == crc
