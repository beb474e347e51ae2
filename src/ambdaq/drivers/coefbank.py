"""The coefficient bank image: what ``ambdaq push`` downloads into a controller's inactive bank.

Host and device share this layout (docs/protocol.md, "Coefficient banks"); the controller keeps
two banks, runs from the active one, and switches only after the host has read back the CRC-32
the device computed over the inactive one.  All numbers little-endian::

    magic "AMBC" | version u16 | axes u8 | harmonics u8 | mode u8 | sections u8 | rows u16
    | sha256 of the coefficient file (32 bytes)
    | weights: axes x harmonics x [sin, cos] f64, m   (axis order of the controller, 1X first)
    | LMS schedule: rows x [harmonic, rpm_from, rpm_to, mu] f64  (harmonic 0: every harmonic)
    | if sections bit 0: bins u16 | bin width f64 (Hz) | axes x bins f32: the LMS phase
      compensation per axis at 0, bin, 2 bin ... Hz of loop frequency (rad)
    | if sections bit 1: planes u8 | outputs u8 | inputs u8 | taps u16 | sample rate f64 (Hz)
      | planes x outputs x inputs x taps f64: the base-motion feedforward u = W d (Kang & Jung eq. 15),
      tap t on d(k - t), V per m/s^2
    | if sections bit 2: axes u8 | biquads u8 | axes x [P V/V, I 1/s, D s] f64
      | axes x biquads x [b0, b1, b2, a1, a2] f64: the feedback controller, a PID and a chain of
      second-order sections per axis (transposed direct form II, a0 = 1; issue 42)

``mode`` is the feedforward the bank runs: 0 off, 1 fixed table (r_c of Ro et al. eq. 10 with
these weights), 2 LMS (eq. 9) starting from these weights with the schedule's step sizes.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

MAGIC = b"AMBC"
VERSION = 1
HEAD = struct.Struct("<4sHBBBBH32s")
PHASE_HEAD = struct.Struct("<Hd")
FIR_HEAD = struct.Struct("<BBBHd")
CONTROLLER_HEAD = struct.Struct("<BB")
SECTION_PHASE, SECTION_FIR, SECTION_CONTROLLER = 1, 2, 4
FIR_TAP_LIMIT = 100.0  # V per m/s^2: the compensators are ~0.1; far larger is a units mistake
MODES = {"off": 0, "table": 1, "lms": 2}
WEIGHT_LIMIT_M = 1e-3  # no runout term above 1 mm: larger is a units mistake
MU_LIMIT = 1.0  # |mu| above this diverges at any speed
PID_LIMITS = (100.0, 1e4, 1.0)  # P V/V, I 1/s, D s: larger is a units mistake (the spindle's are 1.6, 1, 0.0015)


def crc32(data: bytes) -> int:
    """CRC-32 (IEEE 802.3, as ``zlib.crc32``) the controller computes over a bank."""
    return zlib.crc32(data) & 0xFFFFFFFF


@dataclass
class BankImage:
    """The contents of one coefficient bank.

    Parameters
    ----------
    weights : ndarray, shape (axes, harmonics, 2)
        Feedforward weights [sin, cos] per axis and harmonic (1X first), in m.
    mode : {"off", "table", "lms"}
        Feedforward mode the bank runs.
    schedule : list of (harmonic, rpm_from, rpm_to, mu)
        LMS step sizes over speed (rpm); harmonic 0 applies to every harmonic.
    source_sha256 : str
        Hex SHA-256 of the coefficient file the bank came from ("" for none).
    phase_rad : ndarray, shape (axes, bins), optional
        LMS phase compensation per axis over loop frequency, in rad (None: Ro et al.'s update).
    phase_bin_hz : float
        Frequency step of ``phase_rad``, in Hz.
    fir_taps : ndarray, shape (planes, outputs, inputs, taps), optional
        Base-motion feedforward taps, in V per m/s^2 (None: none).
    fir_rate_hz : float
        Sample rate the taps run at, in Hz.
    pid : ndarray, shape (axes, 3), optional
        The feedback controller's [P (V/V), I (1/s), D (s)] per axis (None: the bank leaves the
        controller as it is).
    biquads : ndarray, shape (axes, sections, 5), optional
        Its second-order sections per axis after the PID, (b0, b1, b2, a1, a2) each; with ``pid``.
    """

    weights: np.ndarray
    mode: str = "table"
    schedule: list[tuple[float, float, float, float]] = field(default_factory=list)
    source_sha256: str = ""
    phase_rad: np.ndarray | None = None
    phase_bin_hz: float = 10.0
    fir_taps: np.ndarray | None = None
    fir_rate_hz: float = 0.0
    pid: np.ndarray | None = None
    biquads: np.ndarray | None = None

    def encode(self) -> bytes:
        w = np.asarray(self.weights, dtype="<f8")
        sha = bytes.fromhex(self.source_sha256) if self.source_sha256 else bytes(32)
        rows = np.asarray(self.schedule, dtype="<f8").reshape(-1, 4)
        sections = ((SECTION_PHASE if self.phase_rad is not None else 0) | (SECTION_FIR if self.fir_taps is not None else 0)
                    | (SECTION_CONTROLLER if self.pid is not None else 0))
        head = HEAD.pack(MAGIC, VERSION, w.shape[0], w.shape[1], MODES[self.mode], sections, rows.shape[0], sha)
        out = head + w.tobytes() + rows.tobytes()
        if self.phase_rad is not None:
            ph = np.asarray(self.phase_rad, dtype="<f4")
            out += PHASE_HEAD.pack(ph.shape[1], self.phase_bin_hz) + ph.tobytes()
        if self.fir_taps is not None:
            t = np.asarray(self.fir_taps, dtype="<f8")
            out += FIR_HEAD.pack(*t.shape, self.fir_rate_hz) + t.tobytes()
        if self.pid is not None:
            pid = np.asarray(self.pid, dtype="<f8")
            bq = np.asarray(self.biquads if self.biquads is not None else np.zeros((pid.shape[0], 0, 5)), dtype="<f8")
            out += CONTROLLER_HEAD.pack(pid.shape[0], bq.shape[1]) + pid.tobytes() + bq.tobytes()
        return out

    @classmethod
    def decode(cls, data: bytes) -> "BankImage":
        """Parse and check an image; ``ValueError`` says what is wrong."""
        if len(data) < HEAD.size:
            raise ValueError(f"image of {len(data)} bytes is shorter than its header")
        magic, version, axes, harmonics, mode, sections, n_rows, sha = HEAD.unpack_from(data)
        if magic != MAGIC or version != VERSION:
            raise ValueError("not a version-1 coefficient image")
        want = HEAD.size + 8 * (axes * harmonics * 2 + 4 * n_rows)
        phase, bin_hz, fir, fir_rate = None, 10.0, None, 0.0
        if sections & SECTION_PHASE:
            if len(data) < want + PHASE_HEAD.size:
                raise ValueError(f"image of {len(data)} bytes ends in its phase table's header")
            bins, bin_hz = PHASE_HEAD.unpack_from(data, want)
            start = want + PHASE_HEAD.size
            want = start + 4 * axes * bins
            if len(data) >= want:
                phase = np.frombuffer(data, "<f4", axes * bins, start).reshape(axes, bins).astype(float)
        if sections & SECTION_FIR:
            if len(data) < want + FIR_HEAD.size:
                raise ValueError(f"image of {len(data)} bytes ends in its FIR's header")
            *shape, fir_rate = FIR_HEAD.unpack_from(data, want)
            start = want + FIR_HEAD.size
            want = start + 8 * int(np.prod(shape))
            if len(data) >= want:
                fir = np.frombuffer(data, "<f8", int(np.prod(shape)), start).reshape(shape).copy()
        pid = biquads = None
        if sections & SECTION_CONTROLLER:
            if len(data) < want + CONTROLLER_HEAD.size:
                raise ValueError(f"image of {len(data)} bytes ends in its controller's header")
            n_axes, n_bq = CONTROLLER_HEAD.unpack_from(data, want)
            start = want + CONTROLLER_HEAD.size
            want = start + 8 * (n_axes * 3 + n_axes * n_bq * 5)
            if len(data) >= want:
                pid = np.frombuffer(data, "<f8", n_axes * 3, start).reshape(n_axes, 3).copy()
                biquads = np.frombuffer(data, "<f8", n_axes * n_bq * 5, start + 24 * n_axes).reshape(n_axes, n_bq, 5).copy()
        if sections & ~(SECTION_PHASE | SECTION_FIR | SECTION_CONTROLLER):
            raise ValueError(f"unknown image sections 0x{sections:02x}")
        if len(data) != want:
            raise ValueError(f"image is {len(data)} bytes, its header says {want}")
        modes = {v: k for k, v in MODES.items()}
        if mode not in modes:
            raise ValueError(f"unknown feedforward mode {mode}")
        w = np.frombuffer(data, "<f8", axes * harmonics * 2, HEAD.size).reshape(axes, harmonics, 2).copy()
        rows = np.frombuffer(data, "<f8", 4 * n_rows, HEAD.size + w.nbytes).reshape(n_rows, 4)
        image = cls(w, modes[mode], [tuple(float(x) for x in r) for r in rows], "" if not any(sha) else sha.hex(),
                    phase, bin_hz, fir, fir_rate, pid, biquads)
        problem = image.problem()
        if problem:
            raise ValueError(problem)
        return image

    def problem(self, axes: int | None = None, harmonics: int | None = None) -> str:
        """Why this image cannot run on a controller with ``axes`` axes and ``harmonics`` harmonics
        ("" if it can): finite values, weights within 1 mm, step sizes within +-1, sane rows."""
        w = np.asarray(self.weights)
        if axes is not None and w.shape[0] != axes:
            return f"image has {w.shape[0]} axes, the controller {axes}"
        if harmonics is not None and w.shape[1] > harmonics:
            return f"image has {w.shape[1]} harmonics, the controller runs at most {harmonics}"
        if not np.all(np.isfinite(w)):
            return "a weight is not a finite number"
        if np.any(np.abs(w) > WEIGHT_LIMIT_M):
            return f"a weight exceeds {WEIGHT_LIMIT_M * 1e3:g} mm"
        for k, lo, hi, mu in self.schedule:
            if not all(np.isfinite((k, lo, hi, mu))):
                return "a schedule row is not finite"
            if k != int(k) or not 0 <= k <= w.shape[1]:
                return f"schedule row names harmonic {k:g}; the image has 1..{w.shape[1]}"
            if not 0 <= lo < hi:
                return f"schedule row {lo:g}..{hi:g} rpm is not an increasing speed range"
            if abs(mu) > MU_LIMIT:
                return f"step size {mu:g} exceeds +-{MU_LIMIT:g}"
        if self.phase_rad is not None:
            ph = np.asarray(self.phase_rad)
            if ph.shape[0] != w.shape[0] or not np.all(np.isfinite(ph)) or not self.phase_bin_hz > 0:
                return "the LMS phase table must be finite, one row per axis, with a positive bin width"
        if self.fir_taps is not None:
            t = np.asarray(self.fir_taps)
            if t.ndim != 4 or t.shape[3] < 1 or not self.fir_rate_hz > 0:
                return "the FIR must be planes x outputs x inputs x taps with a positive sample rate"
            if not np.all(np.isfinite(t)):
                return "a FIR tap is not a finite number"
            if np.any(np.abs(t) > FIR_TAP_LIMIT):
                return f"a FIR tap exceeds {FIR_TAP_LIMIT:g} V per m/s^2"
        if self.pid is not None:
            return controller_problem(np.asarray(self.pid), self.biquads)
        return ""

    def per_harmonic_schedule(self) -> dict[int, tuple[tuple[float, float, float], ...]]:
        """The schedule as harmonic (1-based) -> rows (rpm_from, rpm_to, mu)."""
        out: dict[int, list] = {}
        for k, lo, hi, mu in self.schedule:
            for kk in range(1, self.weights.shape[1] + 1) if k == 0 else (int(k),):
                out.setdefault(kk, []).append((lo, hi, mu))
        return {k: tuple(v) for k, v in out.items()}


def controller_problem(pid: np.ndarray, biquads: np.ndarray | None) -> str:
    """Why a feedback controller (PID per axis, shape (axes, 3), and second-order sections, shape
    (axes, sections, 5)) cannot run, or '': gains finite, non-negative and within
    :data:`PID_LIMITS`; sections finite with their poles inside the unit circle (the triangle
    |a2| < 1, |a1| < 1 + a2 of 1 + a1 z^-1 + a2 z^-2: else the filter itself diverges)."""
    if pid.ndim != 2 or pid.shape[1] != 3:
        return "the PID must be one row of [P, I, D] per axis"
    if not np.all(np.isfinite(pid)) or np.any(pid < 0):
        return "a PID gain is not a finite, non-negative number"
    for k, (name, limit) in enumerate(zip("PID", PID_LIMITS)):
        if np.any(pid[:, k] > limit):
            return f"a PID {name} gain exceeds {limit:g}"
    if biquads is None:
        return ""
    bq = np.asarray(biquads)
    if bq.ndim != 3 or bq.shape[0] != pid.shape[0] or bq.shape[2] != 5:
        return "the sections must be axes x sections x (b0, b1, b2, a1, a2), one chain per PID row"
    if not np.all(np.isfinite(bq)):
        return "a section coefficient is not a finite number"
    a1, a2 = bq[..., 3], bq[..., 4]
    bad = ~((np.abs(a2) < 1.0) & (np.abs(a1) < 1.0 + a2))
    if np.any(bad):
        axis, section = (int(v) for v in np.argwhere(bad)[0])
        return (f"section {section + 1} of axis {axis + 1} has poles outside the unit circle "
                f"(a1 {a1[axis, section]:g}, a2 {a2[axis, section]:g}): the filter itself would diverge")
    return ""
