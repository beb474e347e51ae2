"""Simulated CANopen devices: canopen ``LocalNode``s fed by the rig, sampling on SYNC.

Each device answers SDO from its EDS object dictionary, produces its heartbeat when 0x1017 is
set, goes OPERATIONAL on the NMT start command, and on every SYNC samples the rig at the SYNC's
bus timestamp and sends its TPDOs (transmission type 1; a COB-ID with bit 31 set disables one),
the last one ending with the SYNC's counter.
The amplifier raises EMCY 0x2310 (over-current) when a coil current exceeds its limit and
0x4210 (over-temperature) from a first-order thermal model of I^2 heating; 0x2001 = 0 switches
its output stage off (zero current, status bit 15 clear; the rig's physics is not coupled back).
The gap conditioner applies its calibration (0x2100 sensitivity against 10,000 V/m, 0x2101
offset) to what it sends.
The controller's configuration port (:class:`SimCanController`) answers SDO for the coefficient
banks it shares with the controller's serial port.
"""

from __future__ import annotations

import json
import struct
import time

import can
import canopen
import numpy as np
from canopen import objectdictionary as od

from ...drivers.can import device_profiles as cp
from ...drivers.can.device_profiles import DEVICE_PROFILES, DeviceProfile
from .banks import BankRefused, CoefficientBanks
from .rig_server import RigServer

_FMT = {od.INTEGER16: "h", od.UNSIGNED16: "H", od.UNSIGNED8: "B", od.REAL32: "f", od.INTEGER32: "i"}
_LIMITS = {od.INTEGER16: (-32768, 32767), od.UNSIGNED16: (0, 65535), od.UNSIGNED8: (0, 255)}
THERMAL_TAU_S = 5.0  # amplifier heat-sink time constant
THERMAL_K = 8.0  # degC per A^2 (rms, per axis) at steady state
STATUS_OVERCURRENT, STATUS_OVERTEMP, STATUS_ENABLED = 0x1, 0x2, 0x8000
NOMINAL_SENSITIVITY = 1.0e4  # V/m: the rig's sensor gain; the conditioner's 0x2100 scales against it
TEMPERATURE_INDEX = 0x2003  # the amplifier's heat-sink temperature, which it writes itself


STALE_CYCLES = 200
"""A SYNC more than this many SYNC periods old when the simulation gets to it is not answered: the
host matches a reply to its SYNC by the counter, which tells apart 240 SYNCs.  A real device
answers within microseconds; only a simulator starved of CPU gets this far behind (250 ms at
800 Hz), and then the cycle is lost, as the host counts it, never attributed to the wrong SYNC."""


NOTIFIER_CYCLE_S = 0.05  # canopen's default, 1 s, is how long closing a network waits


def open_network(channel: str) -> canopen.Network:
    """A connected canopen network on python-can's ``virtual`` ``channel``, for simulated devices
    (and tests' peers): its receive thread wakes every 50 ms, so it closes at once."""
    network = canopen.Network(can.Bus(interface="virtual", channel=channel))
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
    return network.connect()


class SimCanDevice:
    """One simulated device of type ``kind`` at ``node_id`` on ``network``; answers the SYNCs that
    :func:`serve_can` hands it with the rig's sample."""

    def __init__(self, network: canopen.Network, kind: str, node_id: int, *, serial: int = 1) -> None:
        self.profile: DeviceProfile = DEVICE_PROFILES[kind]
        self.node = canopen.LocalNode(node_id, str(self.profile.eds_path))
        network.add_node(self.node)
        self.network = network
        self.node.set_data(0x1018, 4, struct.pack("<I", serial), check_writable=False)
        self._pack = [struct.Struct("<" + "".join(_FMT[t] for _i, t in self.profile.tpdo_layout(i)))
                      for i in range(len(self.profile.tpdos))]
        self._sizes = [len(t) for t in self.profile.tpdos]
        self._cols = np.array([c.rig_column for c in self.profile.channels])
        self._scale = np.array([c.scale for c in self.profile.channels])
        self._kinds = [(c.unit == "rad" and c.data_type == od.UNSIGNED16, _LIMITS.get(c.data_type))
                       for c in self.profile.channels]
        self._fault = 0
        self._temperature = 35.0
        self._last_t: int | None = None
        self._settings: dict | None = None  # read from the object dictionary after each SDO write
        self.node.add_write_callback(self._on_write)
        self.node.nmt.state = "PRE-OPERATIONAL"

    def _on_write(self, index: int, **_written) -> None:
        if index != TEMPERATURE_INDEX:  # not its own reading: a setting changed
            self._settings = None  # stored after the callbacks: read again at the next SYNC

    def _f32(self, index: int) -> float:
        return struct.unpack("<f", self.node.get_data(index, 0))[0]

    def settings(self) -> dict:
        """TPDO COB-IDs and transmission types, calibration and limits, as the SDO client left them."""
        if self._settings is None:
            n = len(self.profile.tpdos)
            tpdos = [(struct.unpack("<I", self.node.get_data(0x1800 + i, 1))[0], self.node.get_data(0x1800 + i, 2)[0])
                     for i in range(n)]
            out: dict = {"tpdos": tpdos}
            if self.profile.kind == "gap_sensor":
                out["gain"], out["offset"] = self._f32(0x2100) / NOMINAL_SENSITIVITY, self._f32(0x2101)
            if self.profile.status_index is not None:
                out["limit"], out["temp_limit"] = self._f32(0x2002), self._f32(0x2004)
                out["enabled"] = self.node.get_data(0x2001, 0)[0] != 0
            self._settings = out
        return self._settings

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL"

    def _raw(self, row: np.ndarray) -> list:
        """Raw counts: integers saturate at their type's limits, except an angle, which wraps."""
        out = []
        for v, (wraps, limits) in zip((row / self._scale).tolist(), self._kinds):
            if wraps:
                out.append(int(round(v)) % 65536)
            elif limits is not None:
                out.append(int(min(max(round(v), limits[0]), limits[1])))
            else:
                out.append(v)
        return out

    def respond(self, counter: int, rows: dict[str, np.ndarray], t_ns: int) -> None:
        """Send this device's TPDOs for the SYNC with ``counter`` whose instant is ``t_ns``, from the
        rig's sample ``rows`` (one row per signal group)."""
        cfg = self.settings()
        row = rows[self.profile.rig_topic][self._cols]
        if self.profile.kind == "keyphasor":
            row[0] = row[0] % (2 * np.pi)
        elif self.profile.kind == "gap_sensor":  # the conditioner's calibration applies to what it sends
            row = row * cfg["gain"] + cfg["offset"]
        tail = [self._amplifier_status(row, t_ns, cfg)] if self.profile.status_index is not None else []
        tail.append(counter)  # echo the SYNC counter
        values = self._raw(row)
        pos = 0
        last = len(self._pack) - 1
        for i, packer in enumerate(self._pack):
            args = values[pos : pos + self._sizes[i]] + (tail if i == last else [])
            pos += self._sizes[i]
            cob, ttype = cfg["tpdos"][i]
            if cob & 0x80000000 or ttype != 1:
                continue
            self.network.send_message(cob & 0x7FF, packer.pack(*args))

    def _amplifier_status(self, currents: np.ndarray, t_ns: int, cfg: dict) -> int:
        dt = 0.0 if self._last_t is None else (t_ns - self._last_t) * 1e-9
        self._last_t = t_ns
        target = 35.0 + THERMAL_K * float(np.mean(currents**2))
        self._temperature += (target - self._temperature) * min(1.0, dt / THERMAL_TAU_S)
        self.node.set_data(TEMPERATURE_INDEX, 0, struct.pack("<f", self._temperature), check_writable=False)
        if not cfg["enabled"]:  # output stage off: no coil current (the rig's physics is not coupled back)
            currents[:] = 0.0
        fault = 0
        if np.any(np.abs(currents) > cfg["limit"]):
            fault |= STATUS_OVERCURRENT
        if self._temperature > cfg["temp_limit"]:
            fault |= STATUS_OVERTEMP
        new = fault & ~self._fault
        if new & STATUS_OVERCURRENT:
            self.node.emcy.send(0x2310, 0x03, b"")
        if new & STATUS_OVERTEMP:
            self.node.emcy.send(0x4210, 0x09, b"")
        self._fault = fault
        return (STATUS_ENABLED if cfg["enabled"] else 0) | fault


def serve_can(network: canopen.Network, server: RigServer, nodes: dict[str, int] | None = None) -> list[SimCanDevice]:
    """Put one simulated device of each type on ``network``, fed by ``server``'s rig; ``nodes`` maps
    kind -> node id.  On every SYNC the rig is sampled once, at the SYNC's bus time, and each
    OPERATIONAL device answers with its TPDOs."""
    nodes = nodes or {k: p.default_node for k, p in DEVICE_PROFILES.items()}
    devices = [SimCanDevice(network, kind, node, serial=1000 + node) for kind, node in nodes.items()]

    period = [0.0, 0.0]  # the last SYNC's time and the SYNC period (s), learnt from the bus

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        last, period[0] = period[0], timestamp
        if last and 0 < timestamp - last < 1.0:
            period[1] = timestamp - last if not period[1] else 0.9 * period[1] + 0.1 * (timestamp - last)
        live = [d for d in devices if d.operational]
        if not live or (period[1] and time.time() - timestamp > STALE_CYCLES * period[1]):
            return
        t_ns = int(round(timestamp * 1e9))
        try:
            _step, rows = server.sample_at(t_ns)
        except LookupError:
            return
        counter = data[0] if data else 0
        for d in live:
            d.respond(counter, rows, t_ns)

    network.subscribe(0x80, on_sync)
    return devices


ABORT = {"locked": 0x08000022, "crc": 0x08000020, "busy": 0x08000021, "bad_value": 0x06090030}
"""SDO abort codes for refused bank operations (CiA 301: device state, cannot store, local
control, value range)."""


class SimCanController:
    """The controller's CANopen configuration port at ``node_id``: SDO objects 0x2F00.. over
    ``banks`` (docs/protocol.md).  A failed check aborts the SDO transfer and writes nothing."""

    def __init__(self, network: canopen.Network, banks: CoefficientBanks, node_id: int = cp.CONTROLLER.default_node,
                 *, serial: int = 1) -> None:
        self.banks = banks
        self.node = canopen.LocalNode(node_id, str(cp.CONTROLLER.eds_path))
        network.add_node(self.node)
        self.node.set_data(0x1018, 4, struct.pack("<I", serial), check_writable=False)
        self.node.nmt.state = "PRE-OPERATIONAL"
        self._record: dict = {}
        self._effective = 0
        self.node.add_read_callback(self._read)
        self.node.add_write_callback(self._write)

    def _read(self, index: int, subindex: int, od):
        if index == cp.BANK_CRC:
            return self.banks.inactive_crc()
        if index == cp.BANK_STATUS:
            return json.dumps(self.banks.status(), separators=(",", ":")).encode()
        if index in (cp.BANK_IMAGE, cp.BANK_ACTIVE):
            which = "active" if index == cp.BANK_ACTIVE else "inactive"
            return self.banks.read(which, 0, 1 << 16)
        if index == cp.BANK_EFFECTIVE:
            return self._effective
        return None

    def _write(self, index: int, subindex: int, od, data: bytes) -> None:
        try:
            if index == cp.BANK_UNLOCK:
                self.banks.unlock(bytes(data).decode(errors="replace"))
            elif index == cp.BANK_IMAGE:
                self.banks.write(0, len(data), bytes(data))
            elif index == cp.BANK_RECORD:
                self._record = json.loads(bytes(data).decode() or "{}")
            elif index == cp.BANK_COMMIT:
                self._effective = self.banks.commit(struct.unpack("<I", data)[0], self._record)
                self._record = {}
        except BankRefused as err:
            raise canopen.SdoAbortedError(ABORT[err.reason]) from None
        except (ValueError, UnicodeDecodeError):
            raise canopen.SdoAbortedError(ABORT["bad_value"]) from None
