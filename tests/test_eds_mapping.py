"""CANopen mapping as the device allows (CiA 301): a TPDO carries no more objects than its mapping
record (0x1A00 + n) holds, whatever fits its 64 bits.

The EDS files here are written as vendors write them, with mapping records of 0 to 8 entries;
the device behind them is a canopen LocalNode built from the file as written, on a bus reached
through a socketcand gateway in another process (``tests/eds_gateway.py``, no ambdaq code in the
device).  A mapping that fits is spread over the TPDOs with room and recorded, every value the
device's own; one that does not is refused in one line naming the object and the TPDO, before
anything is written to the device (it had ended in ``KeyError: 'Subindex 0x05 was not found'``
after the device was half configured).  A DCF that maps one object in two TPDOs is recorded
under names that say which PDO (it had ended in ``fields repeat``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ambdaq.daq import load

sys.path.insert(0, str(Path(__file__).parent))
from eds_gateway import value_of  # noqa: E402

pytestmark = pytest.mark.realtime

NODE, RATE = 9, 100


def _var(index: str, name: str, data_type: int, access: str, default: str, pdo: int, **more) -> str:
    extra = "".join(f"{k}={v}\n" for k, v in more.items())
    return (f"[{index}]\nParameterName={name}\nObjectType=0x7\nDataType=0x{data_type:04X}\nAccessType={access}\n"
            f"DefaultValue={default}\nPDOMapping={pdo}\n{extra}\n")


def eds_text(capacity: int, *, double: bool = False) -> str:
    """An EDS of a small I/O module: eight UNSIGNED16 inputs at 0x2000 (PDO-mappable), four TPDOs
    whose mapping records hold ``capacity`` entries each; with ``double``, a DCF whose TPDO1 and
    TPDO2 both map input 1 (ParameterValue beside DefaultValue, COB-IDs as $NODEID expressions)."""
    optional = [f"0x{0x1800 + n:04X}" for n in range(4)] + [f"0x{0x1A00 + n:04X}" for n in range(4)] + ["0x1017"]
    out = ["[FileInfo]\nFileName=io.eds\nFileVersion=1\nFileRevision=1\nEDSVersion=4.0\nDescription=8 inputs\n\n",
           "[DeviceInfo]\nVendorName=Test\nProductName=IO8\nBaudRate_1000=1\nSimpleBootUpSlave=1\n"
           "NrOfRXPDO=0\nNrOfTXPDO=4\nGranularity=8\n\n",
           "[MandatoryObjects]\nSupportedObjects=3\n1=0x1000\n2=0x1001\n3=0x1018\n\n",
           _var("1000", "Device type", 0x7, "ro", "0x00000191", 0),
           _var("1001", "Error register", 0x5, "ro", "0", 0),
           "[1018]\nParameterName=Identity object\nObjectType=0x9\nSubNumber=5\n\n",
           _var("1018sub0", "Number of entries", 0x5, "ro", "4", 0),
           _var("1018sub1", "Vendor-ID", 0x7, "ro", "0x000000AB", 0),
           _var("1018sub2", "Product code", 0x7, "ro", "0x00000008", 0),
           _var("1018sub3", "Revision number", 0x7, "ro", "0x00010000", 0),
           _var("1018sub4", "Serial number", 0x7, "ro", "0x00001234", 0),
           "[OptionalObjects]\nSupportedObjects=9\n" + "".join(f"{i + 1}={o}\n" for i, o in enumerate(optional)) + "\n",
           _var("1017", "Producer heartbeat time", 0x6, "rw", "0", 0)]
    for n in range(4):
        comm, mapping = f"{0x1800 + n:04X}", f"{0x1A00 + n:04X}"
        mapped = ["0x20000110"] if double and n < 2 else []
        cob = f"$NODEID+0x{0x180 + 0x100 * n:X}"
        out += [f"[{comm}]\nParameterName=TPDO{n + 1} communication parameter\nObjectType=0x9\nSubNumber=3\n\n",
                _var(f"{comm}sub0", "Highest sub-index supported", 0x5, "ro", "2", 0),
                _var(f"{comm}sub1", "COB-ID used by TPDO", 0x7, "rw", cob, 0,
                     **({"ParameterValue": cob} if double else {})),
                _var(f"{comm}sub2", "Transmission type", 0x5, "rw", "1", 0),
                f"[{mapping}]\nParameterName=TPDO{n + 1} mapping parameter\nObjectType=0x9\nSubNumber={capacity + 1}\n\n",
                _var(f"{mapping}sub0", "Number of mapped objects", 0x5, "rw", str(len(mapped)), 0, LowLimit=0,
                     HighLimit=capacity, **({"ParameterValue": str(len(mapped))} if double else {}))]
        for k in range(1, capacity + 1):
            value = mapped[k - 1] if k <= len(mapped) else "0x00000000"
            out.append(_var(f"{mapping}sub{k}", f"Mapped object {k}", 0x7, "rw", value, 0,
                            **({"ParameterValue": value} if double else {})))
    out += ["[ManufacturerObjects]\nSupportedObjects=1\n1=0x2000\n\n",
            "[2000]\nParameterName=Inputs\nObjectType=0x8\nSubNumber=9\n\n",
            _var("2000sub0", "Number of inputs", 0x5, "ro", "8", 0)]
    out += [_var(f"2000sub{k}", f"Input {k}", 0x6, "ro", "0", 1) for k in range(1, 9)]
    return "".join(out)


def _rig(tmp_path: Path, eds: Path, port: int, inputs: int, mapping: str = "configure") -> Path:
    signals = "".join(f'[[device.signal]]\nobject = "0x2000.{k}"\ntopic = "/io/in"\nfield = "in{k}"\n'
                      for k in range(1, inputs + 1)) if mapping == "configure" else ""
    rig = tmp_path / "rig.toml"
    rig.write_text(f'name = "io"\n[[device]]\nname = "io"\n'
                   f'url = "can://socketcand/can0?host=127.0.0.1&port={port}&node={NODE}&sync=external"\n'
                   f'eds = "{eds}"\nmapping = "{mapping}"\n{signals}')
    return rig


@pytest.mark.parametrize("capacity", [0, 1, pytest.param(2, marks=pytest.mark.long), 8])  # 2: between 1 and 8
def test_eight_inputs_are_spread_over_the_tpdos_that_have_room_or_refused(capacity, tmp_path, run_cli):
    """Eight 16-bit inputs: 64 bits would take two TPDOs, but a mapping record of ``capacity``
    entries takes no more than that: four TPDOs of 0 or 1 cannot carry them, of 2 they can (every
    TPDO full), of 8 they fit in two (by bits: each TPDO's 64 bits full).  A refusal names the object and the room, before the
    gateway is even reached (none runs here for it)."""
    eds = tmp_path / "io.eds"
    eds.write_text(eds_text(capacity))
    if 4 * min(capacity, 4) < 8:
        rig = _rig(tmp_path, eds, 9, 8)  # nothing listens on port 9: the check comes first
        r = run_cli("record", "--rig", rig, "--duration", "1", "-o", tmp_path / "x.mcap")
        assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
        assert "0x2000." in r.output and "does not fit" in r.output, r.output
        assert "TPDO1 " + str(capacity) in r.output or capacity == 0, r.output
        return
    proc = subprocess.Popen([sys.executable, str(Path(__file__).parent / "eds_gateway.py"), str(eds), str(NODE),
                             str(RATE), "0"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        port = int(proc.stdout.readline())
        out = tmp_path / "io.mcap"
        r = run_cli("record", "--rig", _rig(tmp_path, eds, port, 8), "--duration", "1.5", "-q", "-o", out)
    finally:
        proc.stdin.close()
        proc.wait(timeout=10)
    assert r.exit_code == 0, r.output
    got = load(out)["/io/in"]
    assert len(got) > 20
    counters = [c for c in range(1, 241)]
    first = {value_of(c, 0x2000, 1, 0x6): c for c in counters}
    which = np.array([first[v] for v in got["in1"].astype(int).tolist()])
    for k in range(2, 9):  # every input holds its own value of the same SYNC as input 1
        np.testing.assert_array_equal(got[f"in{k}"], [value_of(int(c), 0x2000, k, 0x6) for c in which], err_msg=str(k))


def test_an_object_mapped_in_two_tpdos_is_recorded_under_names_that_say_which(tmp_path, run_cli):
    """A DCF whose TPDO1 and TPDO2 both map input 1 (ParameterValue over DefaultValue, $NODEID
    COB-IDs), recorded as the device is mapped: input 1 from TPDO1 and again from TPDO2, each
    under its own name, both the device's value."""
    eds = tmp_path / "io.dcf"
    eds.write_text(eds_text(4, double=True))
    proc = subprocess.Popen([sys.executable, str(Path(__file__).parent / "eds_gateway.py"), str(eds), str(NODE),
                             str(RATE), "0"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        port = int(proc.stdout.readline())
        out = tmp_path / "io.mcap"
        r = run_cli("record", "--rig", _rig(tmp_path, eds, port, 0, mapping="existing"), "--duration", "1.5", "-q",
                    "-o", out)
    finally:
        proc.stdin.close()
        proc.wait(timeout=10)
    assert r.exit_code == 0, r.output
    got = load(out)["/io"]
    assert list(got.fields) == ["input_1", "input_1_tpdo2"]
    np.testing.assert_array_equal(got["input_1"], got["input_1_tpdo2"])
    assert len(got) > 20
