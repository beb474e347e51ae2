"""The worked example of docs/architecture.md, "Adding a device type": a Modbus-TCP probe
conditioner whose registers a register-map file describes, as another package ships it
(tests/plugins/modbus_gap.py: one back-end module, one entry point, its rig-file key, its
discovery), recorded from a Modbus server no one here wrote (pymodbus) and mapped to the gap role
by the rig file's [machine] table."""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ambdaq.daq import open_recording

pytestmark = pytest.mark.realtime  # a device read against the wall clock
PLUGINS = Path(__file__).parent / "plugins"
MAP = """
[[register]]
address = 0
type = "uint16"
topic = "/probes/status"
field = "frames"

[[register]]
address = 1
type = "int16"
topic = "/probes/gap"
field = "de_x"
scale = 1e-8
unit = "m"

[[register]]
address = 2
type = "uint32"
topic = "/probes/gap"
field = "de_y"
scale = 1e-10
unit = "m"

[[register]]
address = 4
type = "float32"
topic = "/probes/gap"
field = "thrust"
scale = 1e-6
unit = "m"
"""


@pytest.fixture(scope="module")
def server():
    """pymodbus's server on a free loopback port, in its own process."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    proc = subprocess.Popen([sys.executable, str(PLUGINS / "modbus_server.py"), str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            break
        except OSError:
            assert proc.poll() is None and time.monotonic() < deadline, "the Modbus server did not start"
            time.sleep(0.1)
    yield port
    proc.terminate()
    proc.wait(timeout=10)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The plug-in as an installed distribution leaves it: its module and a dist-info whose
    entry_points.txt names the back-end."""
    site = tmp_path_factory.mktemp("site")
    info = site / "modbus_gap-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: modbus-gap\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[ambdaq.backends]\nmodbus+tcp = modbus_gap:ModbusBackend\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(PLUGINS), os.environ.get("PYTHONPATH", "")])}


def ambdaq(env, *args):
    return subprocess.run([sys.executable, "-m", "ambdaq", *map(str, args)], env=env, capture_output=True, text=True,
                          timeout=120)


def test_a_modbus_conditioner_from_its_register_map_is_recorded_and_is_the_machines_gap(server, installed, tmp_path):
    (tmp_path / "probes.toml").write_text(MAP)
    rig = tmp_path / "blower.toml"
    rig.write_text(f'[[device]]\nname = "probes"\nurl = "modbus+tcp://127.0.0.1:{server}?rate=200"\n'
                   'register_map = "probes.toml"\n'
                   '[machine]\nid = "blower-7"\naxial = ["thrust"]\nmin_clearance_m = 150e-6\n'
                   'gap.de_x = "/probes/gap.de_x"\ngap.de_y = "/probes/gap.de_y"\ngap.thrust = "/probes/gap.thrust"\n')
    out = tmp_path / "probes.mcap"
    run = ambdaq(installed, "record", "--rig", rig, "--duration", "0.5", "--json", "-o", out)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    rec = open_recording(out)
    gap, status = rec["/probes/gap"], rec["/probes/status"]
    n = len(gap)
    assert n == summary["devices"]["probes"]["samples"] and summary["samples"] + summary["drops"] == 100  # 0.5 s at 200 Hz
    # what the server holds, decoded by the map: exactly (scaling in float64 of the same raw values)
    assert np.all(gap["de_x"] == -1234 * 1e-8) and np.all(gap["de_y"] == 100_000 * 1e-10)
    assert np.all(gap["thrust"] == 1.5 * 1e-6)
    # the server counts every read: one read per sample recorded, none lost between them
    frames = status["frames"]
    assert np.all(np.diff(frames) == 1)
    # lost periods: before the first sample (a first poll late by more than a period under load
    # skips it: seq 0 lost on a fresh clone beside two busy workers), between samples, after the last
    seq = gap.seq.astype(np.int64)
    assert summary["drops"] == 100 - n == int(seq[0]) + int(np.sum(np.diff(seq) - 1)) + 99 - int(seq[-1])
    # the rig file made it the machine's gap: its bearing, its thrust axis and its clearance
    m = rec.machine
    assert m.id == "blower-7" and [b.name for b in m.bearings] == ["de"] and m.axial == ("thrust",)
    assert m.cmin_m == 150e-6 and rec.role("gap").topic == "/probes/gap"
    plot = ambdaq(installed, "plot", out, "--field", "de_x", "-o", tmp_path / "de.png")
    assert plot.returncode == 0 and (tmp_path / "de.png").stat().st_size > 10_000, plot.stderr


def test_discovery_and_an_unreachable_server(server, installed, tmp_path):
    env = {**installed, "AMBDAQ_MODBUS_HOSTS": f"127.0.0.1:{server},127.0.0.1:1"}
    found = json.loads(ambdaq(env, "devices", "--json").stdout)["plugins"]["modbus+tcp"]
    assert found == [{"url": f"modbus+tcp://127.0.0.1:{server}", "description": "a Modbus TCP server that answers"}]
    (tmp_path / "probes.toml").write_text(MAP)
    rig = tmp_path / "gone.toml"
    rig.write_text('[[device]]\nurl = "modbus+tcp://127.0.0.1:1"\nregister_map = "probes.toml"\n')
    run = ambdaq(installed, "record", "--rig", rig, "--duration", "0.2", "-o", tmp_path / "x.mcap")
    assert run.returncode == 1 and "cannot connect" in run.stderr and len(run.stderr.strip().splitlines()) == 1
