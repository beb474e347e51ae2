"""A CANopen device known only by its vendor's EDS: the simulated MD-402 drive (a CiA 402 drive
used as a four-phase current amplifier, canopen LocalNode), mapped by the rig file or recorded as
it is mapped, with SYNC from ambdaq or from another master."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import can
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.sim.devices.vendor_drive import EDS_PATH, PHASES

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

RATE = 200  # Hz: the drive's synchronous window is then 2.5 ms


@pytest.fixture
def drive(third_party_rig):
    return third_party_rig, third_party_rig.urls["drive"].split("?")[0], third_party_rig.can_devices[-1]


def rig_file(tmp_path, channel_url, signals: str, *, sync=RATE) -> str:
    (tmp_path / "md402.eds").write_bytes(EDS_PATH.read_bytes())
    path = tmp_path / "rig.toml"
    path.write_text(f'''name = "vendor-amp"
[[device]]
name = "amp"
url = "{channel_url}?node=5&sync={sync}"
eds = "md402.eds"
mapping = "configure"
{signals}''')
    return str(path)


PHASE_SIGNALS = "".join(f'''[[device.signal]]
object = "0x2210.{i + 1}"
topic = "/amp/current"
field = "{axis}"
factor = 0.001
unit = "A"
''' for i, axis in enumerate(PHASES)) + '''[[device.signal]]
object = "DC link voltage"
topic = "/amp/supply"
field = "dc_link"
[[device.signal]]
object = "0x2201"
topic = "/amp/supply"
field = "heatsink"
'''


def test_configured_mapping_records_si_values_of_the_rig(drive, tmp_path, run_cli):
    served, channel_url, sim = drive
    out = tmp_path / "amp.mcap"
    r = run_cli("record", "--rig", rig_file(tmp_path, channel_url, PHASE_SIGNALS), "--duration", "1", "--json",
                "-o", out)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    # every cycle is either recorded or counted lost.  The drive answers from the same interpreter
    # as the recorder, so how many replies miss their synchronous window depends on the machine;
    # what must hold is the count, and that every kept value is its own SYNC's
    assert summary["samples"] + summary["drops"] == RATE and summary["samples"] >= RATE // 4
    rec = load(out)
    cur, supply = rec["/amp/current"], rec["/amp/supply"]
    assert cur.units["front_x"] == "A" and supply.units == {"dc_link": "V", "heatsink": "degC"}  # the EDS's own
    np.testing.assert_allclose(supply["dc_link"], 320.0)  # 3200 counts of 0.1 V
    np.testing.assert_allclose(supply["heatsink"], 41.2)
    # the drive sends the rig's coil currents in mA at the SYNC instant: within one count, at the
    # SYNC's time or up to 0.5 ms later (when the drive got it, see test_canopen_devices)
    for t, row in zip(cur.log_time[::20], np.column_stack([cur[a] for a in PHASES])[::20]):
        best = min(np.max(np.abs(row - served.server.sample_at(int(t) + lag)[1]["/amb/current"][[0, 1, 2, 3]]))
                   for lag in range(0, 500_001, 100_000))
        assert best <= 0.0005 + 1e-9
    # the mapping it asked for is the one the device holds, and the official decoder reads it
    info = run_cli("info", out).output
    assert "tpdos = 0x185: 0x2210.1, 0x2210.2, 0x2210.3, 0x2210.4; 0x285: 0x2200.0, 0x2201.0" in info
    assert "synchronous_window_us = 2500\n" in info  # set on the device (its EDS has 0x1007)
    assert struct.unpack("<I", sim.node.get_data(0x1007, 0))[0] == 2500
    assert struct.unpack("<I", sim.node.get_data(0x1A00, 1))[0] == 0x22100110
    with open(out, "rb") as fh:
        decoded = [m.rear_y for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(topics=["/amp/current"])]
    np.testing.assert_array_equal(decoded, cur["rear_y"])


def test_existing_mapping_with_sync_from_another_master(drive, tmp_path, run_cli):
    _served, channel_url, sim = drive
    for n, (cob, entries) in enumerate([(0x185, [0x60410010, 0x60780010]),  # the drive as shipped
                                        (0x285, [0x22100110, 0x22100210, 0x22100310, 0x22100410])]):
        sim.node.set_data(0x1800 + n, 1, struct.pack("<I", cob), check_writable=False)
        sim.node.set_data(0x1A00 + n, 0, bytes([len(entries)]), check_writable=False)
        for i, e in enumerate(entries, start=1):
            sim.node.set_data(0x1A00 + n, i, struct.pack("<I", e), check_writable=False)
    master = can.Bus(interface="virtual", channel=channel_url.split("/")[-1])
    task = master.send_periodic(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False), 1 / RATE)
    try:
        out = tmp_path / "as-is.mcap"
        r = run_cli("record", "--device", f"{channel_url}?node=5&sync=external&eds={EDS_PATH}", "--duration", "1",
                    "--json", "-o", out)
        assert r.exit_code == 0, r.output
    finally:
        task.stop()
        master.shutdown()
    rec = load(out)
    data = rec["/md402_amb"]
    assert list(data.fields) == ["statusword", "current_actual_value", "phase_a_current", "phase_b_current",
                                 "phase_c_current", "phase_d_current"]
    assert set(data["statusword"]) <= {0x0627, 0x0627 | 0x0008}  # operation enabled (fault bit on over-current)
    info = run_cli("info", out).output
    assert "sync = external" in info
    rate = float(info.split("sample_rate_hz = ")[1].split()[0])
    assert rate == pytest.approx(RATE, rel=0.05)  # measured from the other master's SYNC
    with open(out, "rb") as fh:
        texts = [m.text for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                 .iter_decoded_messages(topics=["/amb/events"])]
    assert "node 5 OPERATIONAL" in texts  # the NMT state, from its heartbeat


@pytest.mark.parametrize("signal, says", [
    ('object = "0x2300"', "0x2300.0 (Firmware build) is not PDO-mappable"),
    ('object = "0x6079"', "no object 0x6079 in the EDS"),
    ("".join(f'object = "0x2210.{i}"\ntpdo = 1\n[[device.signal]]\n' for i in (1, 2, 3, 4)) + 'object = "0x2201"\ntpdo = 1',
     "does not fit TPDO1: it would carry 80 bits; a CAN frame holds 64"),
])
def test_a_mapping_the_eds_forbids_is_refused_before_the_device_is_touched(drive, tmp_path, run_cli, signal, says):
    _served, channel_url, sim = drive
    before = [sim.node.get_data(0x1A00 + n, i) for n in range(4) for i in range(9)]
    r = run_cli("record", "--rig", rig_file(tmp_path, channel_url, f"[[device.signal]]\n{signal}\n"),
                "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1 and says in r.output, r.output
    assert [sim.node.get_data(0x1A00 + n, i) for n in range(4) for i in range(9)] == before


def test_the_devices_own_sdo_abort_is_shown_with_its_meaning(drive, tmp_path, run_cli):
    _served, channel_url, _sim = drive
    r = run_cli("record", "--rig", rig_file(tmp_path, channel_url, '[[device.signal]]\nobject = "0x6077"\n'),
                "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 1 and "Code 0x06040041" in r.output and "cannot be mapped" in r.output.lower(), r.output
    assert "(on download of 0x1A00.1, " in r.output  # the object the abort was about, named


def test_an_eds_device_behind_slcan_is_refused(tmp_path, run_cli):
    r = run_cli("record", "--device", f"can://slcan/dev/null?node=5&eds={EDS_PATH}", "--duration", "1",
                "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1 and "bus time stamps" in r.output


def test_a_broken_eds_is_one_line_exit_2(tmp_path, run_cli):
    bad = tmp_path / "bad.eds"
    bad.write_text(EDS_PATH.read_text().replace("[1018sub2]", "[1018sub2\n"))
    r = run_cli("record", "--device", f"can://virtual/nobus?node=5&eds={bad}", "--duration", "1",
                "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1 and "bad.eds" in r.output, r.output


CORPUS_EDS = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "eds" / "e35.eds"


@pytest.mark.parametrize("obj, says", [
    ("Node ID", "2 objects of the EDS are named 'Node ID' (0x2000.1, 0x2001.1): give the index"),
    ("Uart configuration.BaudRate", "0x2000.2 (BaudRate) is not PDO-mappable"),  # found by record and sub name
    ("0x2000.9", "object 0x2000 (Uart configuration) has no sub-index 9 (it has 0, 1, 2, 3, 4, 5, 6, 7, 8)"),
    ("0x6041.1", "object 0x6041 (Statusword) has no sub-indices: give 0x6041"),
    ("Uart configuration", "is object 0x2000, which has sub-objects: name one"),
    ("Motor speed", "no object named 'Motor speed' in the EDS"),
])
def test_names_in_a_vendors_eds_resolve_or_say_why_not(obj, says, tmp_path, run_cli):
    """A CiA 402 drive's EDS as its vendor tooling writes it (canopen's e35.eds): objects by index,
    by a sub-object's name, ambiguous names refused with the candidates, all before any bus opens."""
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[[device]]\nname = "drive"\nurl = "can://virtual/nobus?node=5&sync=100"\neds = "{CORPUS_EDS}"\n'
                   f'mapping = "configure"\n[[device.signal]]\nobject = "{obj}"\n')
    r = run_cli("record", "--rig", rig, "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and says in r.output and len(r.output.strip().splitlines()) == 1, r.output


@pytest.mark.parametrize("damage, obj, says", [
    (lambda t: "", "Statusword", "no objects (is it an EDS file?)"),
    (lambda t: t.replace("[6041]\n", "[6041]\nFactor=nan\n", 1), "Statusword", "(Statusword) has the factor nan"),
    (lambda t: t.replace("SubNumber=0x9", "SubNumber=99999999", 1), "Statusword", ""),  # canopen counts the subs
])
def test_a_hostile_eds_is_one_line_before_the_bus_opens(damage, obj, says, tmp_path, run_cli):
    """An empty EDS, a NaN factor: one line, exit 2, no canopen log line beside it; a SubNumber of
    99999999 costs nothing (canopen reads the sub-objects there are)."""
    bad = tmp_path / "bad.eds"
    bad.write_text(damage(CORPUS_EDS.read_text(encoding="latin-1")), encoding="latin-1")
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[[device]]\nname = "drive"\nurl = "can://virtual/nobus-{len(says)}?node=5&sync=100"\n'
                   f'eds = "{bad}"\nmapping = "configure"\n[[device.signal]]\nobject = "{obj}"\n')
    r = run_cli("record", "--rig", rig, "--duration", "1", "-o", tmp_path / "x.mcap")
    if says:
        assert r.exit_code == 2 and says in r.output and len(r.output.strip().splitlines()) == 1, r.output
    else:  # the file is fine for Statusword: the recording goes as far as the bus, where no device answers
        assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
