"""The simulated controller's XCP slave, proven against an independent master (pyxcp, no ambdaq
code on the master side), and its A2L file, read by an independent parser (pya2ldb)."""

from __future__ import annotations

import logging
import struct

import numpy as np
import pytest

from ambdaq.sim.serve import serve
from ambdaq.speed import SpeedProfile

pytestmark = pytest.mark.realtime  # devices run in real time: one at a time (conftest.py)

pyxcp = pytest.importorskip("pyxcp")  # the xcp extra, in the test extras


@pytest.fixture(scope="module")
def slave():
    served = serve("spindle", speed=SpeedProfile(30000, 30000), can=None, xcp_port=0)
    yield served.devices["xcp"]
    served.stop()


def master(port: int):
    from pyxcp.config import create_application_from_config
    from pyxcp.master import Master

    app = create_application_from_config({"Transport": {"Eth": {"host": "127.0.0.1", "port": port,
                                                                "protocol": "TCP"}}}, log_level=logging.ERROR)
    app.transport.layer = "ETH"
    return Master("eth", config=app)


def test_pyxcp_reads_the_a2l_measurements_from_the_slave(slave, tmp_path, run_cli):
    a2l = tmp_path / "spindle.a2l"
    assert run_cli("sim", "a2l", "-o", a2l).exit_code == 0
    from pya2l import import_a2l, model

    session = import_a2l(str(a2l), in_memory=True, loglevel="ERROR", progress_bar=False)
    described = {m.name: (m.ecu_address.address, m.datatype, m.phys_unit.unit) for m in session.query(model.Measurement)}
    assert len(described) == len(slave.memory.measurements) == 28
    with master(slave.port) as x:
        connected = x.connect()
        assert connected.maxCto == 255 and connected.commModeBasic.byteOrder == "INTEL"
        assert x.identifier(1) == "AMBDAQ_SPINDLE"  # the A2L's PROJECT name
        values = {}
        for name, (address, datatype, unit) in described.items():
            assert datatype == "FLOAT32_IEEE" and unit  # every measurement in SI, its unit stated
            values[name] = struct.unpack("<f", x.shortUpload(4, address))[0]
        # the rig's state, read through the A2L's addresses: 30,000 rpm (float32), gaps of tens of um
        assert described["amb_rotor_speed"][2] == "rad/s" and described["amb_gap_front_x"][2] == "m"
        assert values["amb_rotor_speed"] == pytest.approx(30000 * 2 * np.pi / 60, abs=1e-3)
        assert all(abs(values[f"amb_gap_{a}"]) < 1e-4 for a in ("front_x", "front_y", "rear_x", "rear_y"))
        assert -1e-6 <= values["amb_rotor_angle"] < 2 * np.pi + 1e-6  # wrapped to a turn, to float32 rounding
        # a command this slave lacks (no DAQ yet) is answered ERR_CMD_UNKNOWN, as the standard asks
        from pyxcp.master.errorhandler import SystemExit as XcpError

        with pytest.raises(XcpError, match="ERR_CMD_UNKNOWN"):
            x.getDaqProcessorInfo()
        x.disconnect()
