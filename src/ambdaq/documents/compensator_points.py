"""The compensator points file: what ``ambdaq fx estimate`` writes and ``fx fit`` reads.

A JSON document (docs/base-motion.md), versioned and checksummed like the coefficient file: per
campaign frequency and plane, the four base-motion compensators W_jm (actuator j, accelerometer
m) that MFXLMS found, in V per m/s^2::

    {"format": "ambdaq-fx-points", "version": 1, "unit": "V/(m/s^2)", "freq_hz": [...],
     "planes": {"vertical": {"W11": {"re": [...], "im": [...]}, ...}, "horizontal": {...}},
     "residual": [[...], ...], "source": {...}, "checksum": "crc32:xxxxxxxx"}
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import BadInputError
from ..machines.base_motion import PLANES
from .sealed import read_sealed, write_sealed

FORMAT, VERSION = "ambdaq-fx-points", 1
PAIRS = [(j, m) for j in range(2) for m in range(2)]  # (actuator, accelerometer)


def save_points(path: str | Path, freqs: list[float], W: np.ndarray, residual: list[list[float]], source: dict, *,
                overwrite: bool = False) -> Path:
    """Write the points: ``W`` (freq, plane, j, m) complex, V per m/s^2; ``residual`` per frequency and
    plane (RMS error after MFXLMS over before, 1)."""
    doc = {"format": FORMAT, "version": VERSION, "unit": "V/(m/s^2)", "freq_hz": list(freqs),
           "planes": {PLANES[p]: {f"W{j + 1}{m + 1}": {"re": W[:, p, j, m].real.tolist(), "im": W[:, p, j, m].imag.tolist()}
                                  for j, m in PAIRS} for p in range(2)},
           "residual": [[float(r) for r in row] for row in residual], "source": source}
    return write_sealed(path, doc, overwrite=overwrite, indent=1)


def load_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A points file -> (freq_hz (n,), W (n, plane, j, m) complex); checked like every ambdaq file."""
    from .sealed_schemas import PointsDocument, check_document

    doc = read_sealed(path, FORMAT, VERSION, "compensator points file")
    check_document(PointsDocument, doc, path)  # types, ranges, lengths: one line naming the key
    try:
        f = np.array(doc["freq_hz"], dtype=float)
        if f.ndim != 1:
            raise ValueError("freq_hz is not a list of frequencies")
        W = np.empty((f.shape[0], 2, 2, 2), dtype=complex)
        for p, plane in enumerate(PLANES):
            for j, m in PAIRS:
                v = doc["planes"][plane][f"W{j + 1}{m + 1}"]
                W[:, p, j, m] = np.array(v["re"], dtype=float) + 1j * np.array(v["im"], dtype=float)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as err:
        raise BadInputError(f"{path}: malformed points file ({err})") from None
    if not np.all(np.isfinite(W)):
        raise BadInputError(f"{path}: a compensator point is not a finite number")
    return f, W
