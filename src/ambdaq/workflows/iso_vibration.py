"""ISO 14839-2 vibration zones over recordings: the rotor's displacement at each radial bearing
against the minimum clearance Cmin, per speed band.

What is graded: per window of ``WINDOW_S`` seconds, the orbit's largest radial excursion from its
mean centre, ``max sqrt((x - mean x)^2 + (y - mean y)^2)`` over the window (0-peak in the radial
plane).  The standard grades the rotor's vibration displacement at the bearings against Cmin;
the orbit's maximum is what comes closest to the touchdown bearing in any direction, where a
peak-to-peak per axis can miss an elliptical orbit's tilt.  The static position (the levitation
set-point) is the controller's choice, not vibration: it is reported beside it
(``max_from_centre_um``), not graded.  Each speed band takes its worst window.

The gap sensors see the rotor plus their runout (the sensor is not the rotor): given a
coefficient file from ``ambdaq runout identify``, the runout is synthesised at the recorded rotor
angle and taken out first.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..analysis.iso14839 import VIBRATION_LIMITS, ZoneLimits
from ..documents.coefficients import Coefficients, file_sha256
from ..daq.quality import MAX_LOST, require_complete
from ..daq.recording import Recording
from ..errors import BadInputError
from ..units import RAD_S_TO_RPM
from .runout import RUNOUT_REMOVED, runout_at, with_rotor

WINDOW_S = 0.1  # 1,000 samples at 10 kHz: 5 revolutions at 3,000 rpm, 83 at 50,000


def recorded_cmin(rec: Recording) -> float | None:
    """Cmin (m) the recording's machine description gives (its controller's calibration, or the rig
    file's [machine]), if any."""
    return rec.machine.cmin_m


@dataclass(frozen=True)
class BandGrade:
    """One bearing in one speed band.

    Attributes
    ----------
    bearing : str
        The bearing's name (its gap axes NAME_x, NAME_y: ``front``, ``de`` ...).
    rpm_from, rpm_to : float
        The band, in rpm.
    windows : int
        Windows of ``WINDOW_S`` seconds in it.
    max_um : float
        Largest orbit excursion from its mean centre, in um (graded).
    max_from_centre_um : float
        Largest distance from the sensors' zero (the bearing centre), in um (reported).
    ratio : float
        ``max_um`` per Cmin.
    zone : str
        ``A`` .. ``D``.
    at_rpm : float
        Speed of the worst window, in rpm.
    """

    bearing: str
    rpm_from: float
    rpm_to: float
    windows: int
    max_um: float
    max_from_centre_um: float
    ratio: float
    zone: str
    at_rpm: float

    def as_dict(self) -> dict:
        return {"bearing": self.bearing, "rpm_from": self.rpm_from, "rpm_to": self.rpm_to, "windows": self.windows,
                "max_um": round(self.max_um, 3), "max_from_centre_um": round(self.max_from_centre_um, 3),
                "ratio_cmin": round(self.ratio, 4), "zone": self.zone, "at_rpm": round(self.at_rpm, 1)}


def orbit_windows(x: np.ndarray, y: np.ndarray, speed_rpm: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per window of ``n`` samples: mean speed (rpm), largest excursion from the window's mean
    centre and from the origin (both in the unit of ``x`` and ``y``)."""
    w = x.shape[0] // n
    xs, ys = x[: w * n].reshape(w, n), y[: w * n].reshape(w, n)
    dx, dy = xs - xs.mean(axis=1, keepdims=True), ys - ys.mean(axis=1, keepdims=True)
    return (speed_rpm[: w * n].reshape(w, n).mean(axis=1), np.sqrt(dx * dx + dy * dy).max(axis=1),
            np.sqrt(xs * xs + ys * ys).max(axis=1))


def evaluate(recs: list[Recording], *, cmin_m: float | None, band_rpm: float = 1000.0,
             coefficients: Path | None = None, limits: ZoneLimits = VIBRATION_LIMITS,
             max_lost: float = MAX_LOST) -> tuple[list[BandGrade], dict]:
    """ISO 14839-2 zones per bearing and speed band over ``paths``.

    Parameters
    ----------
    recs : list of Recording
        Recordings with the gap sensors and the rotor angle and speed (roles ``gap``, ``rotor``).
    cmin_m : float or None
        Minimum clearance, in m; None: the one the recordings' controller reports.
    band_rpm : float
        Width of the speed bands, in rpm (bands start at 0).
    coefficients : Path, optional
        A runout coefficient file: its runout is taken out of the gap signals first.
    limits : ZoneLimits
        Displacement per Cmin at the zone boundaries.
    max_lost : float
        The share of samples (0..1) a recording may have lost (:mod:`ambdaq.daq.quality`).

    Returns
    -------
    grades : list of BandGrade
    info : dict
        Cmin used and where it came from, the sources, whether runout was removed.
    """
    if cmin_m is None:
        found = {recorded_cmin(r) for r in recs}
        if None in found or len(found) != 1:
            raise BadInputError("no minimum clearance: pass --cmin UM (the touchdown bearings' radial clearance) "
                                "or record with a controller that reports machine.min_clearance_m")
        cmin_m, cmin_from = found.pop(), "recording"
    else:
        cmin_from = "option"
    if not (np.isfinite(cmin_m) and cmin_m > 0):
        raise BadInputError(f"minimum clearance must be a finite length above 0, not {cmin_m!r} m")
    coef = Coefficients.load(coefficients) if coefficients is not None else None
    rows: dict[str, list[np.ndarray]] = {}
    bearings = None
    sources, notes = [], []
    for rec in recs:
        path = rec.path
        with_rotor(rec, "grading vibration per speed")
        gap, rot = rec.together("gap", "rotor")
        notes += require_complete(rec, [gap.topic, rot.topic], "ISO 14839-2 grading", max_lost)
        m = len(gap)
        n = int(round(WINDOW_S * gap.nominal_rate))
        if m < n:
            raise BadInputError(f"{path}: {m} samples, fewer than one {WINDOW_S:g} s window")
        speed = rot["speed"][:m] * RAD_S_TO_RPM
        removed = None if coef is None else runout_at(coef, list(gap.fields), rot["angle"][:m], coefficients)
        fields = list(gap.fields)
        here = rec.machine.bearings  # the recording's own radial bearings, any names
        if not here:
            raise BadInputError(f"{path}: its gap has no radial bearing (axes NAME_x and NAME_y, or a rig file's "
                                f"[machine] bearings): {', '.join(fields)}")
        if bearings is not None and here != bearings:
            raise BadInputError(f"{path}: its bearings ({', '.join(b.name for b in here)}) are not the first "
                                f"recording's ({', '.join(b.name for b in bearings)})")
        bearings = here
        for b in bearings:
            x, y = gap[b.x][:m], gap[b.y][:m]
            if removed is not None:
                x, y = x - removed[:, fields.index(b.x)], y - removed[:, fields.index(b.y)]
            rows.setdefault(b.name, []).append(np.column_stack(orbit_windows(x, y, speed, n)))
        sources.append({"path": str(path), "sha256": file_sha256(path), "seconds": round(m / gap.nominal_rate, 3)})
    grades = []
    for bearing, parts in rows.items():
        win = np.concatenate(parts)
        band = np.floor(win[:, 0] / band_rpm).astype(np.int64)
        for b in np.unique(band):
            sel = win[band == b]
            worst = int(np.argmax(sel[:, 1]))
            ratio = float(sel[worst, 1] / cmin_m)
            grades.append(BandGrade(bearing, float(b * band_rpm), float((b + 1) * band_rpm), int(sel.shape[0]),
                                    float(sel[worst, 1] * 1e6), float(sel[:, 2].max() * 1e6), ratio,
                                    limits.zone(ratio), float(sel[worst, 0])))
    info = {"standard": "ISO 14839-2", "cmin_um": round(cmin_m * 1e6, 3), "cmin_from": cmin_from,
            "limits_ratio_cmin": limits.as_list(), "window_s": WINDOW_S, "band_rpm": band_rpm,
            "runout_removed": None if coefficients is None else {"path": str(coefficients),
                                                                 "sha256": file_sha256(coefficients),
                                                                 "means": RUNOUT_REMOVED},
            "sources": sources, "notes": notes}
    return grades, info


__all__ = ["BandGrade", "WINDOW_S", "evaluate", "orbit_windows", "recorded_cmin"]
