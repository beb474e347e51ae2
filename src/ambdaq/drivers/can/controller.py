"""Driver for the AMB controller's CANopen configuration port: the coefficient banks over SDO.

The same operations as the serial controller's bank messages (docs/protocol.md), on objects
0x2F00.. of ``eds/controller.eds``: the image goes down in one segmented SDO download, the
device's CRC-32 comes back by upload, the commit is a write of the expected CRC.  A refused
operation is an SDO abort, turned into one DeviceError line.
"""

from __future__ import annotations

import json
import struct

import canopen

from ...errors import DeviceError, DeviceTimeout
from ..interfaces import BankPort
from . import device_profiles as cp
from .bus import CanHub

COMMIT_TIMEOUT_S = 2.0  # the controller switches within a control period or answers busy within 0.5 s
ABORT_MEANING = {
    0x08000022: "locked (unlock with the controller's key first)",
    0x08000020: "the inactive bank does not hold the expected CRC-32",
    0x08000021: "the controller is busy",
    0x06090030: "a value is out of range",
}


class CanopenController(BankPort):
    """The controller at ``node_id`` on ``hub``'s bus, for ``ambdaq push`` and ``controller status``.

    Parameters
    ----------
    hub : CanHub
        The bus.
    node_id : int
        CANopen node id of the controller's configuration port.
    url : str
        The device URL, for messages.
    """

    def __init__(self, hub: CanHub, node_id: int, *, url: str = "") -> None:
        self.hub = hub
        self.node_id = node_id
        self.url = url or f"can://{hub.interface}/{hub.channel}?node={node_id}"
        self.node = canopen.RemoteNode(node_id, str(cp.CONTROLLER.eds_path))
        hub.network.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = 1.0
        self._closed = False
        try:
            code = struct.unpack("<I", self._upload(0x1018, 2, "read its identity"))[0]
            if code != cp.CONTROLLER.product_code:
                raise DeviceError(f"CANopen node {node_id}: product code 0x{code:04x} is not an AMB controller")
            self.serial = struct.unpack("<I", self._upload(0x1018, 4, "read its serial number"))[0]
        except DeviceError:
            hub.network.nodes.pop(node_id, None)  # the caller releases the hub
            raise

    def _fail(self, what: str, err: Exception) -> DeviceError:
        if isinstance(err, canopen.SdoAbortedError):
            why = ABORT_MEANING.get(err.code, str(err))
            return DeviceError(f"{self.url}: controller refused to {what}: {why}")
        return DeviceTimeout(f"{self.url}: no answer to {what}: {err}")

    def _upload(self, index: int, sub: int, what: str) -> bytes:
        try:
            return self.node.sdo.upload(index, sub)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise self._fail(what, err) from None

    def _download(self, index: int, data: bytes, what: str) -> None:
        try:
            self.node.sdo.download(index, 0, data)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise self._fail(what, err) from None

    def unlock(self, key: str) -> None:
        """Unlock the coefficient banks with the controller's key."""
        self._download(cp.BANK_UNLOCK, key.encode(), "unlock")

    def write_bank(self, image: bytes) -> None:
        """Write ``image`` into the inactive bank (segmented SDO download)."""
        self._download(cp.BANK_IMAGE, image, "write the inactive bank")

    def bank_status(self) -> dict:
        """Active bank, device-computed CRC-32s, the push log."""
        return json.loads(self._upload(cp.BANK_STATUS, 0, "report its bank status").decode())

    def commit_bank(self, crc: int, record: dict) -> int:
        """Switch to the inactive bank if the device finds ``crc`` in it; returns the first sample
        index run with it."""
        self._download(cp.BANK_RECORD, json.dumps(record, separators=(",", ":")).encode(), "take the push record")
        sdo = self.node.sdo
        saved = sdo.RESPONSE_TIMEOUT, sdo.MAX_RETRIES
        # sent once (a commit is not idempotent: the caller checks the status when no answer comes),
        # waiting longer than the controller takes to switch or to answer busy
        sdo.RESPONSE_TIMEOUT, sdo.MAX_RETRIES = COMMIT_TIMEOUT_S, 0
        try:
            self._download(cp.BANK_COMMIT, struct.pack("<I", crc), "commit")
        finally:
            sdo.RESPONSE_TIMEOUT, sdo.MAX_RETRIES = saved
        return struct.unpack("<I", self._upload(cp.BANK_EFFECTIVE, 0, "report the commit"))[0]

    def read_bank(self, which: str, length: int) -> bytes:
        """The ``active`` or ``inactive`` bank (``length`` bytes)."""
        index = cp.BANK_ACTIVE if which == "active" else cp.BANK_IMAGE
        return self._upload(index, 0, f"read the {which} bank")[:length]

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.hub.network.nodes.pop(self.node_id, None)
        self.hub.release()
