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

import numpy as np

from ..coefbank import BankImage, crc32
from ..rig.base_motion import MAX_FIR_TAPS
from ..rig.spindle import N_HARMONICS, PHASE_BIN_HZ, PHASE_BINS
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


def _runs_fir(rig) -> bool:
    """A controller whose feedforward is the base-motion FIR (seed 002), not the runout table."""
    return hasattr(rig, "set_feedforward_fir")


def _axes(rig) -> list[str]:
    return list(next(g.fields for g in rig.signal_groups() if g.topic == "/amb/gap"))


def layout(rig) -> dict:
    """What the controller's banks hold: axes, runout harmonics, and the FIR's shape if any."""
    out = {"axes": _axes(rig), "harmonics": 0 if _runs_fir(rig) else N_HARMONICS}
    if _runs_fir(rig):
        out["fir"] = {"planes": ["vertical", "horizontal"], "outputs": 2, "inputs": 2, "max_taps": MAX_FIR_TAPS,
                      "sample_rate_hz": rig.params.sample_rate}
    return out


def _layout_problem(rig, image: BankImage) -> str:
    """Why ``image`` does not fit this controller, or ''."""
    lay = layout(rig)
    problem = image.problem(len(lay["axes"]), lay["harmonics"])
    if problem:
        return problem
    fir = lay.get("fir")
    if image.fir_taps is None:
        return ""
    if fir is None:
        return "this controller runs no FIR feedforward"
    shape = (len(fir["planes"]), fir["outputs"], fir["inputs"])
    if image.fir_taps.shape[:3] != shape or image.fir_taps.shape[3] > fir["max_taps"]:
        return f"the FIR is {image.fir_taps.shape}; this controller runs {shape} x at most {fir['max_taps']} taps"
    if image.fir_rate_hz != fir["sample_rate_hz"]:
        return f"the FIR runs at {image.fir_rate_hz:g} Hz, this controller at {fir['sample_rate_hz']:g} Hz"
    return ""


def _present_image(rig) -> BankImage:
    """What the rig runs at start-up, as a bank image (bank 0)."""
    if _runs_fir(rig):
        taps = rig.feedforward_fir
        return BankImage(np.zeros((len(_axes(rig)), 0, 2)), "off", [], "", None, PHASE_BIN_HZ,
                         taps if np.any(taps) else None, rig.params.sample_rate)
    sched = rig.mu_schedule
    rows = ([(float(k), *r) for k, rs in sched.items() for r in rs] if isinstance(sched, dict)
            else [(0.0, *r) for r in sched])
    phase = rig.lms_phase
    return BankImage(rig.feedforward_weights, rig.feedforward_mode, rows, "",
                     phase if np.any(phase) else None, PHASE_BIN_HZ)


def _phase_for_rig(image: BankImage) -> np.ndarray | None:
    """The image's phase table resampled onto the controller's own 10 Hz bins (nearest)."""
    if image.phase_rad is None:
        return None
    f = np.arange(PHASE_BINS) * PHASE_BIN_HZ
    idx = np.minimum(np.round(f / image.phase_bin_hz).astype(int), image.phase_rad.shape[1] - 1)
    return image.phase_rad[:, idx]


def apply_image(rig, image: BankImage) -> None:
    """Make ``rig`` run ``image``: schedule and phase first, then weights and mode (one boundary);
    a base-motion controller loads the FIR (none: no feedforward)."""
    if _runs_fir(rig):
        rig.set_feedforward_fir(image.fir_taps)
        return
    rig.set_mu_schedule(image.per_harmonic_schedule())
    rig.set_lms_phase(_phase_for_rig(image))
    rig.set_feedforward(image.mode, image.weights)


class CoefficientBanks:
    """Two coefficient banks of a controller running ``server``'s rig.

    Parameters
    ----------
    server : RigServer
        The running rig; a commit switches it at a control-period boundary.
    key : str
        The unlock key writes need.
    clock : callable
        The controller's clock (ns), for the push log.
    """

    def __init__(self, server: RigServer, key: str = DEFAULT_UNLOCK_KEY, clock=time.time_ns) -> None:
        self.server = server
        self.key = key
        self.clock = clock
        self.banks = [_present_image(server.rig).encode(), b""]
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
            problem = _layout_problem(self.server.rig, image)
            if problem:
                raise BankRefused("bad_value", problem)
            try:
                step = self.server.at_boundary(lambda rig: apply_image(rig, image), timeout=BOUNDARY_WAIT_S)
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
                **layout(self.server.rig),
                "active_fir_taps": 0 if fir is None else int(fir.shape[3]),
                "log": list(self.log),
            }

