"""A simulated third-party CANopen amplifier described only by its vendor's EDS
(``ambdaq/sim/vendor/md402_amb.eds``): the MD-402, a CiA 402 drive used as a four-phase AMB
current amplifier, with vendor objects and a default PDO mapping unlike ambdaq's own devices.

A canopen ``LocalNode`` answers SDO from the EDS.  Like a real device it checks a PDO mapping
written to it (CiA 301 abort codes: 0x06020000 no such object, 0x06040041 not mappable,
0x06040042 longer than the PDO) and, when OPERATIONAL, sends each valid TPDO whose transmission
type is synchronous (1..240: every n-th SYNC) with the mapped objects' values, sampled from the
rig when the SYNC arrives, unless its synchronous window (0x1007, set by the host) has closed by
then.  It does not echo the SYNC counter: the host matches its replies to their SYNC by time.  It raises EMCY 0x2310 when a phase current exceeds OVERCURRENT_A.  Its EDS
lists 0x6077 (torque actual value) as mappable, but this firmware refuses to map it (0x06040041):
vendors' EDS files and firmware do disagree, and the host must show the device's own answer.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path

import canopen
import numpy as np

from ...machines.spindle import AXES
from .rig_server import RigServer

EDS_PATH = Path(__file__).parent.parent / "vendor" / "md402_amb.eds"
DEFAULT_NODE = 5
PHASES = ("front_x", "front_y", "rear_x", "rear_y")  # 0x2210 sub 1..4: the rig's radial coil currents
OVERCURRENT_A = 6.0
STATUS_OPERATION_ENABLED, STATUS_FAULT = 0x0627, 0x0008
UNSUPPORTED = (0x6077,)  # in the EDS as mappable; not in this firmware
ABORT_NO_OBJECT, ABORT_NOT_MAPPABLE, ABORT_PDO_TOO_LONG = 0x06020000, 0x06040041, 0x06040042


class SimVendorDrive:
    """The MD-402 at ``node_id`` on ``network``, fed by ``server``'s rig."""

    def __init__(self, network: canopen.Network, server: RigServer, node_id: int = DEFAULT_NODE) -> None:
        self.node = canopen.LocalNode(node_id, str(EDS_PATH))
        network.add_node(self.node)
        self.network, self.server = network, server
        self.node.set_data(0x1018, 4, struct.pack("<I", 40_201), check_writable=False)
        self.node.add_write_callback(self._check_mapping)
        self.node.nmt.state = "PRE-OPERATIONAL"
        self._columns = [AXES.index(a) for a in PHASES]
        self._syncs = 0
        self._fault = False
        network.subscribe(0x80, self._on_sync)

    def _object(self, index: int, subindex: int):
        od = self.node.object_dictionary
        if index not in od:
            return None
        obj = od[index]
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            return obj if subindex == 0 else None
        return obj[subindex] if subindex in obj else None

    def _entry_bits(self, value: int) -> int:
        """Bits of mapping entry ``value`` (index << 16 | subindex << 8 | bits); aborts if the
        object is not there or not mappable."""
        if value == 0:
            return 0
        var = self._object(value >> 16, (value >> 8) & 0xFF)
        if var is None:
            raise canopen.SdoAbortedError(ABORT_NO_OBJECT)
        if (not var.pdo_mappable or var.index in UNSUPPORTED
                or (value & 0xFF) != 8 * len(var.encode_raw(var.default or 0))):
            raise canopen.SdoAbortedError(ABORT_NOT_MAPPABLE)
        return value & 0xFF

    def _check_mapping(self, index: int, subindex: int, od, data: bytes) -> None:
        if not 0x1A00 <= index <= 0x1A03:
            return
        if subindex:
            self._entry_bits(struct.unpack("<I", bytes(data))[0])
            return
        count = bytes(data)[0]
        bits = sum(self._entry_bits(struct.unpack("<I", self.node.get_data(index, i))[0]) for i in range(1, count + 1))
        if count > 8 or bits > 64:
            raise canopen.SdoAbortedError(ABORT_PDO_TOO_LONG)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        self._syncs += 1
        try:
            _step, rows = self.server.sample_at(int(round(timestamp * 1e9)))
        except LookupError:
            return
        amps = rows["/amb/current"][self._columns]
        self._update(amps)
        window_us = struct.unpack("<I", self.node.get_data(0x1007, 0))[0]
        for n in range(4):
            if window_us and (time.time() - timestamp) * 1e6 > window_us:
                return  # CiA 301: no synchronous PDO after the synchronous window has closed
            cob_id = struct.unpack("<I", self.node.get_data(0x1800 + n, 1))[0]
            ttype = self.node.get_data(0x1800 + n, 2)[0]
            if cob_id & 0x80000000 or not 1 <= ttype <= 240 or self._syncs % ttype:
                continue
            count = self.node.get_data(0x1A00 + n, 0)[0]
            payload = b""
            for i in range(1, count + 1):
                value = struct.unpack("<I", self.node.get_data(0x1A00 + n, i))[0]
                payload += self.node.get_data(value >> 16, (value >> 8) & 0xFF)[: (value & 0xFF) // 8]
            self.network.send_message(cob_id & 0x7FF, payload)

    def _update(self, amps: np.ndarray) -> None:
        """The mapped objects' values at this SYNC (raw units as the EDS says)."""
        milli = np.clip(np.round(amps * 1000.0), -32768, 32767).astype(int)
        for sub, value in enumerate(milli.tolist(), start=1):
            self.node.set_data(0x2210, sub, struct.pack("<h", value), check_writable=False)
        rated_ma = struct.unpack("<I", self.node.get_data(0x6075, 0))[0]
        per_mille = int(np.clip(round(float(amps[0]) * 1e6 / rated_ma), -32768, 32767))
        self.node.set_data(0x6078, 0, struct.pack("<h", per_mille), check_writable=False)
        self.node.set_data(0x2200, 0, struct.pack("<H", 3200), check_writable=False)  # 320.0 V
        self.node.set_data(0x2201, 0, struct.pack("<h", 412), check_writable=False)  # 41.2 degC
        fault = bool(np.any(np.abs(amps) > OVERCURRENT_A))
        if fault and not self._fault:
            self.node.emcy.send(0x2310, 0x03, b"")
        self._fault = fault
        status = STATUS_OPERATION_ENABLED | (STATUS_FAULT if fault else 0)
        self.node.set_data(0x6041, 0, struct.pack("<H", status), check_writable=False)
