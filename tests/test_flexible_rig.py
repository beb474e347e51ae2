"""The flexible rotor's simulated rig (issue 42, item 1): its kernel is the linear loop of
machines/flexible_spindle.py to rounding, its firmware's PID and sections are parameters over the
serial protocol and XCP (the A2L's characteristics, read by pya2ldb and written by pyxcp), and a
controller in a coefficient bank is CRC-checked and switched as a coefficient file is."""

from dataclasses import replace

import numpy as np
import pytest

from ambdaq.analysis.sections import lead_lag, notch
from ambdaq.drivers.coefbank import BankImage, controller_problem
from ambdaq.drivers.excitation import Excitation
from ambdaq.machines.flexible_spindle import AXES, FLEXIBLE, FlexibleLoop
from ambdaq.sim.rigs.flexible import IDENTITY_SECTION, MAX_SECTIONS, FlexibleRig, chain
from ambdaq.speed import SpeedProfile

FS = FLEXIBLE.sample_rate


def linear_response(loop: FlexibleLoop, rpm: float, rc: np.ndarray) -> np.ndarray:
    """The loop's command error e = C x - r_c for the test signal ``rc`` (n, axes), from rest."""
    M, B, C = loop.matrices(rpm)
    x = np.zeros(M.shape[0])
    out = np.empty_like(rc)
    for k in range(rc.shape[0]):
        out[k] = C @ x - rc[k]
        x = M @ x + B @ rc[k]
    return out


@pytest.mark.parametrize("rpm", [0.0, 20_000.0])
def test_the_kernel_is_the_linear_loop_with_sections_on_one_axis(rpm):
    """White noise of 1 um at front_y's summing point, a notch and a lead on front_y only, no
    sensor noise and no unbalance: the rig's command error on every axis is the linear loop's
    within 1e-9 of front_y's RMS (both step the same matrices; what is left is rounding over 2,000
    steps of a 60-state loop; at standstill the x axes see nothing, at speed the gyroscopic
    coupling moves them)."""
    params = replace(FLEXIBLE, unbalance=())
    rig = FlexibleRig(params, noise=False, speed=SpeedProfile(rpm, rpm))
    front_y = [notch(1505.0, 4.0, FS), lead_lag(300.0, 900.0, FS)]
    rig.set_sections(chain([[], front_y, [], []]))
    rig.set_excitation(Excitation(1, 1e-6, 0.0))
    block = rig.run(2000)
    rc = block.values["/amb/ff"]
    assert np.count_nonzero(rc[:, 1]) == 2000 and not np.any(rc[:, [0, 2, 3]])
    loop = FlexibleLoop(params, sections=[[], front_y, [], []])
    want = linear_response(loop, rpm, rc)
    got = block.values["/amb/error"]
    scale = np.sqrt(np.mean(want[:, 1] ** 2))
    assert np.max(np.abs(got - want)) < 1e-9 * scale
    assert (np.abs(want[:, 0]).max() > 1e-3 * scale) == (rpm > 0)
    # and the rig's own loop() is that loop: its present gains and sections
    M1, _, _ = rig.loop().matrices(rpm)
    M2, _, _ = loop.matrices(rpm)
    assert M1.shape == M2.shape and np.allclose(M1, M2, rtol=0, atol=1e-12)


def test_the_stock_controller_trips_at_speed_and_a_bank_holds_the_controller():
    """At 36,000 rpm the stock PID's loop is unstable (tests/test_flexible_spindle.py; its least
    damped pole grows at 1.9 1/s, so sensor noise and unbalance take seconds to reach the clearance):
    the rotor grows until a sensor reads more than the clearance and the protection trips; the rig
    says when, and the rotor stays where it tripped."""
    rig = FlexibleRig(speed=SpeedProfile(36_000.0, 36_000.0), seed=3)
    gaps = np.concatenate([rig.run(10_000).values["/amb/gap"] for _ in range(8)])
    assert rig.tripped_at is not None and 1.0 < rig.tripped_at < 8.0, rig.tripped_at
    trip = int(round(rig.tripped_at * FS))
    assert np.abs(gaps[trip]).max() > FLEXIBLE.clearance >= np.abs(gaps[:trip]).max()
    assert np.ptp(gaps[trip + 1 :] - gaps[trip + 1], axis=0).max() < 10 * FLEXIBLE.gap_noise
    # what a bank holds: the PID and the sections, through bytes and back
    image = BankImage(np.zeros((4, 0, 2)), "off", pid=np.column_stack(rig.pid_gains),
                      biquads=chain([[notch(1505.0, 4.0, FS)]] * 4))
    back = BankImage.decode(image.encode())
    assert np.array_equal(back.pid, image.pid) and np.array_equal(back.biquads, image.biquads)
    assert back.biquads.shape == (4, MAX_SECTIONS, 5) and tuple(back.biquads[0, 1]) == IDENTITY_SECTION


@pytest.mark.parametrize("biquads, says", [
    (np.array([[[1, 0, 0, -2.1, 1.2]]] * 4, float), "poles outside the unit circle"),
    (np.array([[[1, 0, 0, np.nan, 0]]] * 4, float), "not a finite number"),
])
def test_a_section_that_would_diverge_is_refused(biquads, says):
    pid = np.tile([1.4, 2.0, 0.0012], (4, 1))
    assert says in controller_problem(pid, biquads)
    with pytest.raises(ValueError, match=says.split()[0]):
        BankImage.decode(BankImage(np.zeros((4, 0, 2)), "off", pid=pid, biquads=biquads).encode())
    assert controller_problem(pid * [1, 1, 1e4], None) == "a PID D gain exceeds 1"
    assert len(AXES) == 4


@pytest.mark.realtime  # the served rig runs against the wall clock
def test_sections_are_characteristics_pyxcp_writes_and_the_serial_line_reads_back(tmp_path):
    """The flexible rig served in this process, its controller on a pseudo-terminal and its XCP
    slave on TCP.  pya2ldb finds the PID and the sections in the A2L ``ambdaq sim a2l --profile
    flexible`` writes (VAL_BLK of 4 and 80 FLOAT64); pyxcp, after seed & key, DOWNLOADs a notch
    into front_x's first section by that address, and the serial driver reads the same
    coefficients back (FLOAT64 both ways: exact); a section with a pole outside the unit circle is
    ERR_OUT_OF_RANGE and changes nothing.  A bank image holding a PID and sections is written,
    committed only on its CRC-32, and run from the next control period."""
    import struct

    from click.testing import CliRunner
    from pya2l import import_a2l, model
    from pyxcp.master.errorhandler import SystemExit as XcpError
    from pyxcp.master.errorhandler import set_suppress_xcp_error_log

    from ambdaq.cli.main import cli
    from ambdaq.drivers.registry import open_controller, open_device
    from ambdaq.drivers.xcp.keys import sim_key
    from ambdaq.drivers.coefbank import crc32
    from ambdaq.errors import DeviceError
    from ambdaq.sim.serve import serve
    from test_xcp import master

    a2l = tmp_path / "flexible.a2l"
    assert CliRunner().invoke(cli, ["sim", "a2l", "--profile", "flexible", "-o", str(a2l)]).exit_code == 0
    session = import_a2l(str(a2l), in_memory=True, loglevel="ERROR", progress_bar=False)
    found = {c.name: (c.address, c.number.number if c.number else 1)
             for c in session.query(model.Characteristic) if not c.read_only and c.deposit == "RL_FLOAT64"}
    assert found == {**{k: (found[k][0], 4) for k in ("pid.p", "pid.i", "pid.d")},
                     "filter.sections": (found["filter.sections"][0], 4 * MAX_SECTIONS * 5),
                     "speed.rpm": (found["speed.rpm"][0], 1), "exc.signal": (found["exc.signal"][0], 3)}
    # the A2L and the slave name the rig they are (they said "spindle" for every profile)
    assert session.query(model.Project).one().name == "AMBDAQ_FLEXIBLE"
    served = serve("flexible", can=None, xcp="tcp:0")
    try:
        rig = served.server.rig
        port = int(served.urls["xcp"].rsplit(":", 1)[1])
        stock = rig.sections
        wanted = stock.copy()
        wanted[0, 0] = notch(1505.0, 4.0, FS)
        address = found["filter.sections"][0]
        set_suppress_xcp_error_log(True)
        try:
            with master(port) as x:
                x.connect()
                assert x.identifier(1) == "AMBDAQ_FLEXIBLE"
                seed = bytes(x.getSeed(0, 0x01).seed)
                key = sim_key(0x01, seed, "ambdaq-sim")
                x.unlock(len(key), key)
                x.setMta(address)
                x.download(struct.pack("<5d", *wanted[0, 0]))
                x.setMta(address + 8 * MAX_SECTIONS * 5)  # front_y's first section
                with pytest.raises(XcpError, match="ERR_OUT_OF_RANGE"):
                    x.download(struct.pack("<5d", 1.0, 0.0, 0.0, -2.5, 1.5))
                x.disconnect()
        finally:
            set_suppress_xcp_error_log(False)
        controller = open_device(served.urls["controller"])
        try:
            assert np.array_equal(controller.read_param("filter.sections").reshape(wanted.shape), wanted)
            assert "filter.sections" in controller.parameter_names()
        finally:
            controller.close()
        assert np.array_equal(rig.sections, wanted)

        # the whole controller through the banks: written, refused on a wrong CRC, committed on the right one
        pid = np.column_stack(rig.pid_gains) * [1.1, 1.0, 0.9]
        design = chain([[notch(1505.0, 4.0, FS), lead_lag(300.0, 900.0, FS)]] * 4)
        image = BankImage(np.zeros((4, 0, 2)), "off", pid=pid, biquads=design).encode()
        with open_controller(served.urls["controller"]) as bank:
            before = bank.bank_status()
            bank.unlock("ambdaq-sim")
            bank.write_bank(image)
            with pytest.raises(DeviceError, match="inactive bank CRC-32 is"):
                bank.commit_bank(crc32(image) ^ 1, {"file": "wrong-crc"})
            assert np.array_equal(rig.sections, wanted)
            bank.commit_bank(crc32(image), {"file": "design.json"})
            assert np.array_equal(rig.sections, design) and np.allclose(np.column_stack(rig.pid_gains), pid)
            assert bank.bank_status()["active_crc32"] == f"{crc32(image):08x}" != before["active_crc32"]
    finally:
        served.stop()
