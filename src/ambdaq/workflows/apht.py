"""APHT: amplitude and phase of the synchronous vectors against time at one speed (Bently Nevada's
APHT plot), per radial axis, the sensor runout taken out; with the controller's feedforward output
beside it where the recording holds it (``/amb/ff``: what an LMS feedforward adds, whose 1X grows as
its weights converge). A thermal bow shows as a 1X that turns and grows over minutes; an LMS as a
command error whose 1X falls while the feedforward's rises.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..analysis.runout import harmonic_fit
from ..documents.coefficients import Coefficients
from ..daq.quality import MAX_LOST, require_complete
from ..daq.recording import Recording
from ..errors import BadInputError
from ..units import RAD_S_TO_RPM
from .runout import runout_at

WINDOW_S = 0.5  # 250 revolutions at 30,000 rpm, 7 at 800 rpm: the vector of each half second
STEADY = 0.02  # a recording whose speed moves more than 2 % is a run-up: `runup` tracks that


@dataclass(frozen=True)
class Apht:
    """Synchronous vectors per window of one steady recording.

    Attributes
    ----------
    time_s : ndarray, shape (windows,)
        Start of each window, s from the recording's first message.
    rpm : float
        The recording's median speed, rpm.
    axes : list of str
        The radial axes.
    orders : list of int
        The orders tracked (1 = 1X).
    gap : ndarray of complex, shape (windows, order, axis)
        The gap's vectors, m (``a + j b`` for ``a sin + b cos`` of the key-phasor angle), runout
        taken out where a coefficient file was given.
    error : ndarray of complex or None
        The command error's (role ``error``), m, where recorded.
    feedforward : ndarray of complex or None
        The feedforward output's (role ``ff``), in its unit, where recorded.
    ff_unit : str
        Its unit.
    compensation : str
        What was taken out of the gap.
    window_s : float
        The windows' length, s.
    """

    time_s: np.ndarray
    rpm: float
    axes: list[str]
    orders: list[int]
    gap: np.ndarray
    error: np.ndarray | None
    feedforward: np.ndarray | None
    ff_unit: str
    compensation: str
    window_s: float
    current: np.ndarray | None = None  # the coil currents' vectors (A), where asked (currents=True)
    current_names: tuple[str, ...] = ()  # their channels (/amb/current's fields: per axis or per coil)

    def as_dict(self, recording: str, runout_removed: str | None) -> dict:
        """What ``apht --json`` prints: every window's vectors, per order and axis (µm and degrees;
        the feedforward's in its own unit), with what was taken out of the gap."""
        ff_scale = 1e6 if self.ff_unit == "m" else 1.0
        return {"recording": recording, "rpm": round(self.rpm, 1), "window_s": self.window_s, "axes": self.axes,
                "orders": self.orders, "compensation": self.compensation, "runout_removed": runout_removed,
                "time_s": np.round(self.time_s, 4).tolist(), "gap_um": _vectors(self.gap, 1e6),
                "error_um": None if self.error is None else _vectors(self.error, 1e6),
                "feedforward": None if self.feedforward is None else {
                    **_vectors(self.feedforward, ff_scale), "unit": "um" if self.ff_unit == "m" else self.ff_unit}}

    def first_last(self, order: int = 1) -> list[dict]:
        """Per axis, the gap's vector of ``order`` in the first and the last window, and the command
        error's where recorded: the rows of ``apht``'s table and the commissioning report's, the
        numbers of :meth:`as_dict` (µm, degrees)."""
        i = self.orders.index(order)
        rows = []
        for j, axis in enumerate(self.axes):
            row = {"axis": axis, "order": order, "gap_first": _vector(self.gap[0, i, j], 1e6),
                   "gap_last": _vector(self.gap[-1, i, j], 1e6)}
            if self.error is not None:
                row |= {"error_first": _vector(self.error[0, i, j], 1e6),
                        "error_last": _vector(self.error[-1, i, j], 1e6)}
            rows.append(row)
        return rows


def _vectors(v: np.ndarray, scale: float) -> dict:
    """Amplitude (times ``scale``) and phase (degrees, of ``a sin + b cos`` as ``a + j b``) of
    (window, order, axis) vectors: 5 and 2 decimals, as every APHT number is given."""
    return {"amplitude": np.round(np.abs(v) * scale, 5).tolist(), "phase_deg": np.round(np.degrees(np.angle(v)), 2).tolist()}


def _vector(v: complex, scale: float) -> dict:
    """One vector as :func:`_vectors` gives it."""
    return {"amplitude": round(float(abs(v)) * scale, 5), "phase_deg": round(float(np.degrees(np.angle(v))), 2)}


def apht(rec: Recording, *, orders=(1,), window_s: float = WINDOW_S, coefficients: Path | None = None,
         max_lost: float = MAX_LOST, currents: bool = False) -> Apht:
    """The APHT of a steady recording (see the module docstring).

    Parameters
    ----------
    rec : Recording
        With the gap and the rotor angle (roles ``gap``, ``rotor``; ``error`` and ``ff`` used where
        present).
    orders : sequence of int
        Orders tracked.
    window_s : float
        Length of each window, s.
    coefficients : Path, optional
        A runout coefficient file: its runout is taken out of the gap first.
    max_lost : float
        The share of samples (0..1) the recording may have lost (:mod:`ambdaq.daq.quality`).
    currents : bool
        Also the coil currents' vectors per window (A; the role ``current`` must be there), every
        channel it records.
    """
    if not rec.has_role("rotor"):
        raise BadInputError(f"{rec.path}: no rotor angle (/amb/rotor): APHT needs the key-phasor")
    if currents and not rec.has_role("current"):
        raise BadInputError(f"{rec.path}: no coil currents (/amb/current): the bearings' forces need them")
    roles = [r for r in ("gap", "rotor", "error", "ff", *(("current",) if currents else ())) if rec.has_role(r)]
    rec.load_roles(roles)
    require_complete(rec, [rec.role(r).topic for r in roles], "APHT", max_lost)
    signals = dict(zip(roles, rec.together(*roles)))  # gap first: the others at its instants
    gap, rot = signals["gap"], signals["rotor"]
    n = len(gap)
    speed = rot["speed"][:n] * RAD_S_TO_RPM
    rpm = float(np.median(speed))
    if rpm <= 0 or np.max(np.abs(speed - rpm)) > STEADY * rpm:
        raise BadInputError(f"{rec.path}: APHT is of one speed; this recording runs from {speed.min():,.0f} to "
                            f"{speed.max():,.0f} rpm (ambdaq runup tracks a run-up)")
    axes = list(rec.machine.radial)
    theta = rot["angle"][:n]
    x = np.column_stack([gap[a][:n] for a in axes])
    compensation = "none (the sensor signal as recorded)"
    if coefficients is not None:
        x = x - runout_at(Coefficients.load(coefficients), axes, theta, coefficients)
        compensation = f"runout coefficients {coefficients}"
    size = int(round(window_s * gap.nominal_rate))
    if size < 2 or n < size:
        raise BadInputError(f"{rec.path}: {n} samples, fewer than one {window_s:g} s window")
    starts = range(0, n - size + 1, size)
    orders = list(orders)

    def vectors(signal: np.ndarray) -> np.ndarray:
        return np.array([harmonic_fit(signal[s:s + size], theta[s:s + size], orders) for s in starts])

    def of(role: str) -> np.ndarray | None:
        if role not in signals or not all(a in signals[role].fields for a in axes):
            return None
        return vectors(np.column_stack([signals[role][a][:n] for a in axes]))

    ff_unit = signals["ff"].units.get(axes[0], "") if "ff" in signals else ""
    return Apht(gap.time[list(starts)], rpm, axes, orders, vectors(x), of("error"), of("ff"), ff_unit, compensation,
                window_s, *(_channels(signals["current"], n, vectors) if currents else (None, ())))


def _channels(signal, n: int, vectors) -> tuple[np.ndarray, tuple[str, ...]]:
    """Every field of ``signal`` (its first ``n`` samples) through ``vectors``, and their names: the
    coil currents by the names the machine gives them (per bearing axis on the spindle, per coil on
    the cone rig)."""
    names = tuple(signal.fields)
    return vectors(np.column_stack([signal[c][:n] for c in names])), names


__all__ = ["Apht", "WINDOW_S", "apht"]
