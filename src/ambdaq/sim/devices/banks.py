"""The simulated controller's coefficient banks: two images, an unlock key and a push log.

The same store answers the serial protocol (``SimController``) and SDO (``SimCanController``),
as one controller reached over two ports would.  Writes go to the inactive bank only; the device
computes the CRC-32 of what it holds; a commit names the CRC the host expects and is refused
unless the inactive bank matches it and decodes to a valid image; the switch happens between two
control periods (:meth:`RigServer.at_boundary`).  Nothing the host does before a successful
commit changes what the controller runs.
"""

from __future__ import annotations

import threading
import time


from ...drivers.coefbank import BankImage, crc32
from .firmware import Feedforward
from .rig_server import RigServer

DEFAULT_UNLOCK_KEY = "ambdaq-sim"  # documented in docs/push.md; `ambdaq sim serve --unlock-key` sets another
UNLOCK_S = 30.0  # an unlock lasts this long after the last bank operation
LOG_KEEP = 32
BOUNDARY_WAIT_S = 0.5  # a commit that finds no control-period boundary this soon is refused as busy


class BankRefused(Exception):
    """A bank operation the controller refuses; ``reason`` is one of ``locked``, ``bad_value``,
    ``crc``, ``busy``."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class CoefficientBanks:
    """Two coefficient banks of a controller running ``server``'s rig.

    Parameters
    ----------
    server : RigServer
        The running rig; a commit switches it at a control-period boundary.
    feedforward : Feedforward
        How a bank image loads into the rig (the controller's firmware).
    key : str
        The unlock key writes need.
    clock : callable
        The controller's clock (ns), for the push log.
    """

    def __init__(self, server: RigServer, feedforward: Feedforward, key: str = DEFAULT_UNLOCK_KEY,
                 clock=time.time_ns) -> None:
        self.server = server
        self.feedforward = feedforward
        self.key = key
        self.clock = clock
        self.banks = [feedforward.present(server.rig).encode(), b""]
        self.active = 0
        self.log: list[dict] = []
        self._expected_len = 0
        self._unlocked_until = 0.0
        self._lock = threading.Lock()

    # --- access -------------------------------------------------------------------------------

    def unlock(self, key: str) -> None:
        with self._lock:
            if key != self.key:
                self._unlocked_until = 0.0
                raise BankRefused("locked", "wrong unlock key")
            self._unlocked_until = time.monotonic() + UNLOCK_S

    def _check_unlocked(self) -> None:
        if time.monotonic() > self._unlocked_until:
            raise BankRefused("locked", "coefficient banks are locked: unlock first")
        self._unlocked_until = time.monotonic() + UNLOCK_S

    # --- the inactive bank ------------------------------------------------------------------------

    def write(self, offset: int, total: int, data: bytes) -> None:
        """Write ``data`` at ``offset`` of the inactive bank, which is ``total`` bytes long; a write
        at offset 0 starts a new image."""
        with self._lock:
            self._check_unlocked()
            if not 0 < total <= 65536 or offset + len(data) > total:
                raise BankRefused("bad_value", f"write of {len(data)} bytes at {offset} outside a {total}-byte image")
            inactive = 1 - self.active
            if offset == 0:
                self.banks[inactive] = bytearray(total)
                self._expected_len = total
            elif total != self._expected_len or not self.banks[inactive]:
                raise BankRefused("bad_value", "write continues no image: start at offset 0")
            self.banks[inactive][offset : offset + len(data)] = data

    def inactive_crc(self) -> int:
        with self._lock:
            return crc32(bytes(self.banks[1 - self.active]))

    def read(self, which: str, offset: int, length: int) -> bytes:
        """Bytes of the ``active`` or ``inactive`` bank."""
        with self._lock:
            bank = self.banks[self.active if which == "active" else 1 - self.active]
            return bytes(bank[offset : offset + length])

    def commit(self, expected_crc: int, record: dict) -> int:
        """Switch to the inactive bank if it holds ``expected_crc`` and a valid image; returns the
        first sample index run with it.  ``record`` (host time, file hash, target) goes to the log."""
        with self._lock:
            self._check_unlocked()
            data = bytes(self.banks[1 - self.active])
            got = crc32(data)
            if got != expected_crc:
                raise BankRefused("crc", f"inactive bank CRC-32 is {got:08x}, not {expected_crc:08x}")
            try:
                image = BankImage.decode(data)
            except ValueError as err:
                raise BankRefused("bad_value", f"inactive bank: {err}") from None
            problem = self.feedforward.problem(self.server.rig, image)
            if problem:
                raise BankRefused("bad_value", problem)
            try:
                step = self.server.at_boundary(lambda rig: self.feedforward.apply(rig, image), timeout=BOUNDARY_WAIT_S)
            except TimeoutError as err:
                raise BankRefused("busy", str(err)) from None
            self.active = 1 - self.active
            self._unlocked_until = 0.0  # every push unlocks anew
            entry = {"device_time_ns": int(self.clock()), "bank": self.active, "crc32": f"{got:08x}",
                     "effective_sample": int(step), "source_sha256": image.source_sha256, "mode": image.mode,
                     "phase_compensated": image.phase_rad is not None}
            entry.update({k: str(v) for k, v in record.items() if k in ("host_time", "file", "file_sha256",
                                                                          "target", "host")})
            self.log.append(entry)
            del self.log[:-LOG_KEEP]
            return int(step)

    def status(self) -> dict:
        """Active bank, the CRC-32 of both banks (device-computed), the active image's source, the log."""
        with self._lock:
            active = bytes(self.banks[self.active])
            try:
                image = BankImage.decode(active)
                mode, sha, fir = image.mode, image.source_sha256, image.fir_taps
            except ValueError:
                mode, sha, fir = "?", "", None
            return {
                "active_bank": self.active,
                "active_crc32": f"{crc32(active):08x}",
                "active_length": len(active),
                "active_mode": mode,
                "active_source_sha256": sha,
                "inactive_crc32": f"{crc32(bytes(self.banks[1 - self.active])):08x}",
                "inactive_length": len(self.banks[1 - self.active]),
                "locked": time.monotonic() > self._unlocked_until,
                **self.feedforward.layout(self.server.rig),
                "active_fir_taps": 0 if fir is None else int(fir.shape[3]),
                "log": list(self.log),
            }

