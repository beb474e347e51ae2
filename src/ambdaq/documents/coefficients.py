"""The coefficient file: what identification produces and ``ambdaq push`` downloads.

A JSON document (docs/coefficients.md), versioned and checksummed::

    {"format": "ambdaq-coefficients", "version": 1,
     "target": {"rig": ..., "device": ..., "serial": ..., "axes": [...]},
     "source": {"recordings": [{"path", "sha256", "speed_rpm"}], "method": ..., "created": ...},
     "runout": {"units": "m", "harmonics": [1, 2, ...],
                "weights": {"front_x": [[w_k0, w_k1], ...], ...}},
     "lms_schedule": [[rpm_from, rpm_to, mu], ...],
     "lms_phase": {"bin_hz": 10.0, "phase_rad": {"front_x": [...], ...}},
     "lms_plant": "rig",
     "fir": {},
     "checksum": "crc32:xxxxxxxx"}

The weights are the feedforward r_c = sum w_k0 sin k theta + w_k1 cos k theta of Ro et al. eq. 10;
to cancel the runout they equal its phasors.  The checksum is the CRC-32 of the canonical JSON
(sorted keys, no spaces) of everything but the checksum.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..errors import BadInputError
from .sealed import read_sealed, seal, write_sealed

RECENT_NS = 1_000_000_000  # a file modified this recently is hashed anew, never taken from memory
FORMAT = "ambdaq-coefficients"
VERSION = 1


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, hex.  Remembered per path, size and modification time (ns), so the
    steps of one job that each name their sources (a fleet row: runout, vibration, its own index)
    read a file once; a file that changes gets a new time, and is read again.  A file changed in the
    last second is always read (a file system's clock may step only every few ms, so two writes in
    a row can share a time)."""
    st = os.stat(path)
    if time.time_ns() - st.st_mtime_ns < RECENT_NS:
        return _sha256.__wrapped__(path, st.st_size, st.st_mtime_ns)
    return _sha256(str(Path(path).resolve()), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass
class Coefficients:
    """A coefficient document (see the module docstring)."""

    target: dict
    source: dict
    harmonics: list[int]
    weights: dict[str, list[list[float]]]
    lms_schedule: list[list[float]] = field(default_factory=list)
    lms_phase: dict = field(default_factory=dict)
    fir: dict = field(default_factory=dict)
    lms_plant: str = ""

    def to_dict(self) -> dict:
        doc = {
            "format": FORMAT,
            "version": VERSION,
            "target": self.target,
            "source": self.source,
            "runout": {"units": "m", "harmonics": self.harmonics, "weights": self.weights},
            "lms_schedule": self.lms_schedule,
            "fir": self.fir,
        }
        if self.lms_phase:
            doc["lms_phase"] = self.lms_phase
        if self.lms_plant:
            doc["lms_plant"] = self.lms_plant
        return seal(doc)

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        return write_sealed(path, self.to_dict(), overwrite=overwrite, indent=2)

    @classmethod
    def load(cls, path: str | Path) -> "Coefficients":
        """Read and check a coefficient file: format, version, checksum, then every value's type
        and range (:mod:`.sealed_schemas`)."""
        from .sealed_schemas import CoefficientDocument, check_document

        path = Path(path)
        doc = check_document(CoefficientDocument, read_sealed(path, FORMAT, VERSION, "coefficient file"), path)
        return cls(doc.target, doc.source, list(doc.runout.harmonics),
                   {axis: [list(pair) for pair in rows] for axis, rows in doc.runout.weights.items()},
                   [list(row) for row in doc.lms_schedule],
                   doc.lms_phase.model_dump() if doc.lms_phase else {},
                   doc.fir.model_dump() if doc.fir else {}, doc.lms_plant)


def fir_array(coef: Coefficients, planes: list[str], where: str) -> tuple[np.ndarray, float]:
    """The coefficient file's base-motion FIR as taps (planes, outputs, inputs, taps) in the order of
    ``planes``, and its sample rate (Hz); BadInputError (one line) if missing or malformed."""
    fir = coef.fir or {}
    try:
        rate = float(fir["sample_rate_hz"])
        taps = np.array([fir["planes"][p] for p in planes], dtype=float)
    except KeyError as err:
        raise BadInputError(f"{where}: no base-motion FIR for plane {err} (ambdaq fx fit writes one)") from None
    except (TypeError, ValueError) as err:
        raise BadInputError(f"{where}: malformed FIR ({err})") from None
    if taps.ndim != 4 or taps.shape[3] < 1:
        raise BadInputError(f"{where}: the FIR must be planes x outputs x inputs x taps, not {taps.shape}")
    if not (np.all(np.isfinite(taps)) and math.isfinite(rate) and rate > 0):
        raise BadInputError(f"{where}: a FIR tap or its sample rate is not a finite number")
    return taps, rate


def now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")
