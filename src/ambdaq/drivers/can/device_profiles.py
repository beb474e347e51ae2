"""CANopen (CiA 301) device types: object dictionaries, process data and parameters.

Each device type is described once here; its EDS file in ``ambdaq/drivers/can/eds/`` is generated
from the description (``python -m ambdaq.drivers.can.device_profiles``) and shipped.  At run time
the simulated devices and the drivers both load the shipped EDS.

Common objects: 0x1000 device type, 0x1001 error register, 0x1005 SYNC COB-ID, 0x1014 EMCY
COB-ID, 0x1017 producer heartbeat time, 0x1018 identity, 0x1019 synchronous counter overflow
(240: SYNC carries a counter 1..240), 0x1800.. TPDO communication, 0x1A00.. TPDO mapping.
Process values sit in 0x6000.. (transmitted on every SYNC), parameters in 0x2000.. (SDO).  The
last TPDO ends with 0x5000, the counter of the SYNC it answers, so the host attributes every
sample to its SYNC even when a reply is late.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen import objectdictionary as od
from ...roles import ACCEL, CURRENT, GAP, ROTOR

EDS_DIR = Path(__file__).parent / "eds"
SYNC_COUNTER_MAX = 240  # 0x1019
SYNC_ECHO_INDEX = 0x5000
VENDOR_ID = 0x00A3BD00  # ambdaq (unregistered, for the simulated devices)


@dataclass(frozen=True)
class Channel:
    """One process value: a field of the device's topic, carried in a TPDO.

    Parameters
    ----------
    field : str
        Field name in the topic (rig axis, ``angle`` ...).
    index : int
        Object index (0x6000..); subindex 0.
    data_type : int
        CANopen data type (``od.INTEGER16``, ``od.REAL32`` ...).
    scale : float
        SI value of one raw unit (e.g. 1e-8 m per count).
    unit : str
        SI unit of the field.
    rig_column : int
        Column of the rig's signal group that feeds it in simulation.
    """

    field: str
    index: int
    data_type: int
    scale: float
    unit: str
    rig_column: int


@dataclass(frozen=True)
class Parameter:
    """A configuration object reached by SDO (index, subindex 0)."""

    name: str
    index: int
    data_type: int
    default: float
    access: str = "rw"
    unit: str = ""


@dataclass(frozen=True)
class DeviceProfile:
    """A CANopen device type.

    Parameters
    ----------
    kind : str
        ``amplifier``, ``gap_sensor``, ``accelerometer``, ``keyphasor``.
    product : str
        Product name in the EDS.
    product_code : int
        0x1018 sub 2.
    device_type : int
        0x1000 value.
    default_node : int
        Node id used when the URL gives none.
    topic, type_name : str
        Recorded topic and message type.
    tpdos : tuple of tuple of Channel
        Channels mapped into TPDO1, TPDO2 ...
    status_index : int or None
        Object with the device's status word (mapped last in the last TPDO), if any.
    parameters : tuple of Parameter
        SDO parameters.
    rig_topic : str
        Rig signal group feeding the simulated device.
    """

    kind: str
    product: str
    product_code: int
    device_type: int
    default_node: int
    topic: str
    type_name: str
    tpdos: tuple[tuple[Channel, ...], ...]
    status_index: int | None
    parameters: tuple[Parameter, ...]
    rig_topic: str

    @property
    def channels(self) -> tuple[Channel, ...]:
        return tuple(c for t in self.tpdos for c in t)

    @property
    def eds_path(self) -> Path:
        return EDS_DIR / f"{self.kind}.eds"

    def tpdo_layout(self, i: int) -> list[tuple[int, int]]:
        """(object index, data type) mapped into TPDO ``i`` (0-based), in order."""
        out = [(c.index, c.data_type) for c in self.tpdos[i]]
        if i == len(self.tpdos) - 1:
            if self.status_index is not None:
                out.append((self.status_index, od.UNSIGNED16))
            out.append((SYNC_ECHO_INDEX, od.UNSIGNED8))
        return out

    def tpdo_bytes(self) -> list[int]:
        """Data length of each TPDO, in bytes."""
        sizes = [sum(_SIZE[t] for _i, t in self.tpdo_layout(i)) for i in range(len(self.tpdos))]
        assert max(sizes, default=0) <= 8, f"{self.kind}: a TPDO carries at most 8 bytes"
        return sizes


_SIZE = {od.INTEGER16: 2, od.UNSIGNED16: 2, od.UNSIGNED8: 1, od.REAL32: 4, od.INTEGER32: 4}
RADIAL = ("front_x", "front_y", "rear_x", "rear_y")

DEVICE_PROFILES: dict[str, DeviceProfile] = {
    p.kind: p
    for p in (
        DeviceProfile(
            "amplifier", "ambdaq AMB power amplifier (5 axes, 8 A)", 0x0101, 0x00000191, 0x10,
            CURRENT, "Current",
            (tuple(Channel(a, 0x6000 + i, od.INTEGER16, 1e-3, "A", i) for i, a in enumerate(RADIAL)),
             (Channel("axial", 0x6004, od.INTEGER16, 1e-3, "A", 4),)),
            0x6010,
            (Parameter("bias_current", 0x2000, od.REAL32, 2.1, "rw", "A"),
             Parameter("enabled", 0x2001, od.UNSIGNED8, 1),
             Parameter("current_limit", 0x2002, od.REAL32, 5.9, "rw", "A"),
             Parameter("temperature", 0x2003, od.REAL32, 35.0, "ro", "degC"),
             Parameter("temperature_limit", 0x2004, od.REAL32, 85.0, "rw", "degC")),
            CURRENT,
        ),
        DeviceProfile(
            "gap_sensor", "ambdaq eddy-current gap sensor conditioner (5 axes)", 0x0102, 0x00000194, 0x20,
            GAP, "Gap",
            (tuple(Channel(a, 0x6000 + i, od.INTEGER16, 1e-8, "m", i) for i, a in enumerate(RADIAL)),
             (Channel("axial", 0x6004, od.INTEGER16, 1e-8, "m", 4),)),
            None,
            (Parameter("sensitivity", 0x2100, od.REAL32, 1.0e4, "rw", "V/m"),
             Parameter("offset", 0x2101, od.REAL32, 0.0, "rw", "m")),
            GAP,
        ),
        DeviceProfile(
            "accelerometer", "ambdaq housing accelerometer module (3 axes)", 0x0103, 0x00000195, 0x30,
            ACCEL, "Accel",
            ((Channel("front_x", 0x6000, od.INTEGER16, 1e-2, "m/s^2", 0),
              Channel("front_y", 0x6001, od.INTEGER16, 1e-2, "m/s^2", 1),
              Channel("axial", 0x6002, od.INTEGER16, 1e-2, "m/s^2", 4)),),
            None,
            (Parameter("range", 0x2200, od.REAL32, 300.0, "rw", "m/s^2"),),
            ACCEL,
        ),
        DeviceProfile(
            "keyphasor", "ambdaq key-phasor / tachometer", 0x0104, 0x00000196, 0x40,
            ROTOR, "Rotor",
            ((Channel("angle", 0x6000, od.UNSIGNED16, 2 * 3.141592653589793 / 65536, "rad", 0),
              Channel("speed", 0x6001, od.REAL32, 1.0, "rad/s", 1),
              Channel("keyphasor", 0x6002, od.UNSIGNED8, 1.0, "1", 2)),),
            None,
            (Parameter("pulses_per_rev", 0x2300, od.UNSIGNED8, 1),
             Parameter("angle_offset", 0x2301, od.REAL32, 0.0, "rw", "rad")),
            ROTOR,
        ),
    )
}


# The AMB controller's configuration port on CAN: no process data (that streams on its serial
# line), only SDO objects for the coefficient banks (docs/protocol.md, "Coefficient banks").
BANK_UNLOCK, BANK_IMAGE, BANK_CRC, BANK_COMMIT, BANK_RECORD, BANK_STATUS, BANK_ACTIVE, BANK_EFFECTIVE = range(0x2F00, 0x2F08)
CONTROLLER = DeviceProfile(
    "controller", "ambdaq AMB controller (configuration port)", 0x0105, 0x00000000, 0x50, "", "", (), None,
    (Parameter("unlock key", BANK_UNLOCK, od.VISIBLE_STRING, None, "wo"),
     Parameter("inactive bank image", BANK_IMAGE, od.DOMAIN, None, "rw"),
     Parameter("inactive bank CRC-32", BANK_CRC, od.UNSIGNED32, 0, "ro"),
     Parameter("commit with CRC-32", BANK_COMMIT, od.UNSIGNED32, 0, "wo"),
     Parameter("push record", BANK_RECORD, od.VISIBLE_STRING, None, "wo"),
     Parameter("bank status", BANK_STATUS, od.DOMAIN, None, "ro"),
     Parameter("active bank image", BANK_ACTIVE, od.DOMAIN, None, "ro"),
     Parameter("first sample of the last commit", BANK_EFFECTIVE, od.UNSIGNED32, 0, "ro")),
    "",
)
ALL_DEVICE_PROFILES = {**DEVICE_PROFILES, CONTROLLER.kind: CONTROLLER}
"""Every CANopen device type with a shipped EDS: the streaming devices and the controller port."""


def _var(name: str, index: int, sub: int, dtype: int, default, access: str = "rw", pdo: bool = False):
    v = od.ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    v.pdo_mappable = pdo
    return v


def _record(name: str, index: int, members) -> od.ODRecord:
    r = od.ODRecord(name, index)
    for sub, (n, dtype, default, access) in enumerate(members):
        r.add_member(_var(n, index, sub, dtype, default, access))
    return r


def build_od(p: DeviceProfile) -> od.ObjectDictionary:
    """The object dictionary of device type ``p`` (node id applied at run time as $NODEID)."""
    d = od.ObjectDictionary()
    d.device_information.product_name = p.product
    d.device_information.vendor_name = "ambdaq"
    d.device_information.vendor_number = VENDOR_ID
    d.device_information.product_number = p.product_code
    d.device_information.nr_of_TXPDO = len(p.tpdos)
    d.device_information.nr_of_RXPDO = 0
    for rate in (10, 20, 50, 125, 250, 500, 800, 1000):
        d.device_information.allowed_baudrates.add(rate * 1000)
    d.add_object(_var("Device type", 0x1000, 0, od.UNSIGNED32, p.device_type, "ro"))
    d.add_object(_var("Error register", 0x1001, 0, od.UNSIGNED8, 0, "ro"))
    d.add_object(_var("COB-ID SYNC", 0x1005, 0, od.UNSIGNED32, 0x80))
    d.add_object(_var("COB-ID EMCY", 0x1014, 0, od.UNSIGNED32, 0x80))
    d.add_object(_var("Producer heartbeat time", 0x1017, 0, od.UNSIGNED16, 0))
    d.add_object(_var("Synchronous counter overflow value", 0x1019, 0, od.UNSIGNED8, SYNC_COUNTER_MAX))
    d.add_object(_record("Identity object", 0x1018, [
        ("Number of entries", od.UNSIGNED8, 4, "ro"), ("Vendor-ID", od.UNSIGNED32, VENDOR_ID, "ro"),
        ("Product code", od.UNSIGNED32, p.product_code, "ro"), ("Revision number", od.UNSIGNED32, 0x00010000, "ro"),
        ("Serial number", od.UNSIGNED32, 0, "ro")]))
    p.tpdo_bytes()  # checks the 8-byte limit
    channels = {c.index: c for c in p.channels}
    for i, chans in enumerate(p.tpdos):
        d.add_object(_record(f"TPDO{i + 1} communication parameter", 0x1800 + i, [
            ("Highest sub-index supported", od.UNSIGNED8, 5, "ro"),
            ("COB-ID used by TPDO", od.UNSIGNED32, 0x180 + 0x100 * i, "rw"),
            ("Transmission type", od.UNSIGNED8, 1, "rw"),
            ("Inhibit time", od.UNSIGNED16, 0, "rw"),
            ("Reserved", od.UNSIGNED8, 0, "rw"),
            ("Event timer", od.UNSIGNED16, 0, "rw")]))
        mapped = [(idx, _SIZE[t] * 8) for idx, t in p.tpdo_layout(i)]
        members = [("Number of mapped objects", od.UNSIGNED8, len(mapped), "rw")]
        members += [(f"Mapped object {k + 1}", od.UNSIGNED32, (idx << 16) | bits, "rw")
                    for k, (idx, bits) in enumerate(mapped)]
        d.add_object(_record(f"TPDO{i + 1} mapping parameter", 0x1A00 + i, members))
        for c in chans:
            d.add_object(_var(c.field, c.index, 0, c.data_type, 0, "ro", pdo=True))
    if p.status_index is not None:
        d.add_object(_var("status", p.status_index, 0, od.UNSIGNED16, 0, "ro", pdo=True))
    if p.tpdos:
        d.add_object(_var("sync counter", SYNC_ECHO_INDEX, 0, od.UNSIGNED8, 0, "ro", pdo=True))
    for prm in p.parameters:
        d.add_object(_var(prm.name, prm.index, 0, prm.data_type, prm.default, prm.access))
    assert set(channels) <= set(d.indices)
    return d


def write_eds() -> list[Path]:
    """Regenerate every shipped EDS file from :data:`DEVICE_PROFILES`."""
    EDS_DIR.mkdir(exist_ok=True)
    out = []
    for p in ALL_DEVICE_PROFILES.values():
        canopen.export_od(build_od(p), str(p.eds_path), "eds")
        out.append(p.eds_path)
    return out


if __name__ == "__main__":
    for path in write_eds():
        print(path, file=sys.stdout)
