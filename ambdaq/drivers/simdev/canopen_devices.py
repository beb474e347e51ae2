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

import canopen
import numpy as np
from canopen import objectdictionary as od

from .. import canopen_profiles as cp
from ..canopen_profiles import PROFILES, DeviceProfile
from .banks import BankRefused, CoefficientBanks
from .rig_server import RigServer

_FMT = {od.INTEGER16: "h", od.UNSIGNED16: "H", od.UNSIGNED8: "B", od.REAL32: "f", od.INTEGER32: "i"}
_LIMITS = {od.INTEGER16: (-32768, 32767), od.UNSIGNED16: (0, 65535), od.UNSIGNED8: (0, 255)}
THERMAL_TAU_S = 5.0  # amplifier heat-sink time constant
THERMAL_K = 8.0  # degC per A^2 (rms, per axis) at steady state
STATUS_OVERCURRENT, STATUS_OVERTEMP, STATUS_ENABLED = 0x1, 0x2, 0x8000
NOMINAL_SENSITIVITY = 1.0e4  # V/m: the rig's sensor gain; the conditioner's 0x2100 scales against it


class SimCanDevice:
    """One simulated device of type ``kind`` at ``node_id`` on ``network``, fed by ``server``."""

    def __init__(self, network: canopen.Network, kind: str, node_id: int, server: RigServer, *,
                 serial: int = 1) -> None:
        self.profile: DeviceProfile = PROFILES[kind]
        self.server = server
        self.node = canopen.LocalNode(node_id, str(self.profile.eds_path))
        network.add_node(self.node)
        self.network = network
        self.node.set_data(0x1018, 4, struct.pack("<I", serial), check_writable=False)
        self._pack = [struct.Struct("<" + "".join(_FMT[t] for _i, t in self.profile.tpdo_layout(i)))
                      for i in range(len(self.profile.tpdos))]
        self._cols = np.array([c.rig_column for c in self.profile.channels])
        self._scale = np.array([c.scale for c in self.profile.channels])
        self._kinds = [c.data_type for c in self.profile.channels]
        self._fault = 0
        self._temperature = 35.0
        self._last_t: int | None = None
        self.node.nmt.state = "PRE-OPERATIONAL"
        network.subscribe(0x80, self._on_sync)

    def _tpdo(self, i: int) -> tuple[int, int]:
        cob = struct.unpack("<I", self.node.get_data(0x1800 + i, 1))[0]
        ttype = self.node.get_data(0x1800 + i, 2)[0]
        return cob, ttype

    def _raw(self, row: np.ndarray) -> list:
        """Raw counts: integers saturate at their type's limits, except an angle, which wraps."""
        out = []
        for i, (v, dt) in enumerate(zip(row / self._scale, self._kinds)):
            if self.profile.channels[i].unit == "rad" and dt == od.UNSIGNED16:
                out.append(int(round(float(v))) % 65536)
            elif dt in _LIMITS:
                lo, hi = _LIMITS[dt]
                out.append(int(min(max(round(float(v)), lo), hi)))
            else:
                out.append(float(v))
        return out

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        t_ns = int(round(timestamp * 1e9))
        try:
            _step, rows = self.server.sample_at(t_ns)
        except LookupError:
            return
        row = rows[self.profile.rig_topic][self._cols].copy()
        if self.profile.kind == "keyphasor":
            row[0] = row[0] % (2 * np.pi)
        elif self.profile.kind == "gap_sensor":  # the conditioner's calibration applies to what it sends
            sens = struct.unpack("<f", self.node.get_data(0x2100, 0))[0]
            offset = struct.unpack("<f", self.node.get_data(0x2101, 0))[0]
            row = row * (sens / NOMINAL_SENSITIVITY) + offset
        tail = [self._amplifier_status(row, t_ns)] if self.profile.status_index is not None else []
        tail.append(data[0] if data else 0)  # echo the SYNC counter
        values = self._raw(row)
        pos = 0
        last = len(self._pack) - 1
        for i, packer in enumerate(self._pack):
            n = len(self.profile.tpdos[i])
            args = values[pos : pos + n] + (tail if i == last else [])
            pos += n
            cob, ttype = self._tpdo(i)
            if cob & 0x80000000 or ttype != 1:
                continue
            self.network.send_message(cob & 0x7FF, packer.pack(*args))

    def _amplifier_status(self, currents: np.ndarray, t_ns: int) -> int:
        limit = struct.unpack("<f", self.node.get_data(0x2002, 0))[0]
        temp_limit = struct.unpack("<f", self.node.get_data(0x2004, 0))[0]
        dt = 0.0 if self._last_t is None else (t_ns - self._last_t) * 1e-9
        self._last_t = t_ns
        target = 35.0 + THERMAL_K * float(np.mean(currents**2))
        self._temperature += (target - self._temperature) * min(1.0, dt / THERMAL_TAU_S)
        self.node.set_data(0x2003, 0, struct.pack("<f", self._temperature), check_writable=False)
        enabled = self.node.get_data(0x2001, 0)[0] != 0
        if not enabled:  # output stage off: no coil current (the rig's physics is not coupled back)
            currents[:] = 0.0
        fault = 0
        if np.any(np.abs(currents) > limit):
            fault |= STATUS_OVERCURRENT
        if self._temperature > temp_limit:
            fault |= STATUS_OVERTEMP
        new = fault & ~self._fault
        if new & STATUS_OVERCURRENT:
            self.node.emcy.send(0x2310, 0x03, b"")
        if new & STATUS_OVERTEMP:
            self.node.emcy.send(0x4210, 0x09, b"")
        self._fault = fault
        return (STATUS_ENABLED if enabled else 0) | fault


def serve_can(network: canopen.Network, server: RigServer, nodes: dict[str, int] | None = None) -> list[SimCanDevice]:
    """Put one simulated device of each type on ``network``; ``nodes`` maps kind -> node id."""
    nodes = nodes or {k: p.default_node for k, p in PROFILES.items()}
    return [SimCanDevice(network, kind, node, server, serial=1000 + node) for kind, node in nodes.items()]


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
