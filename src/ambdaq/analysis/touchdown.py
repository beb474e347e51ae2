"""A rotor drop characterised from the gap around it (ISO 14839-5's touchdown-bearing condition
monitoring: each landing's speed, duration, excursion, whirl and violence is what wears the
touchdown bearings, so every one is kept on record).

The rotor is *on its touchdown bearing* while any radial bearing's orbit radius sqrt(x^2 + y^2),
or any axial gap |z|, is at least ``AT_CLEARANCE`` of the minimum clearance Cmin; it is
*levitated again* once every one has stayed within ``LEVITATED`` of Cmin for ``SETTLE_S``.
What is measured, per drop:

* the speed at the first contact (the key-phasor's), rpm;
* the time on the bearing: first contact to the last, where it levitated again (else to the end
  of what was recorded, and ``relevitated`` is false: it came to rest or the record ended);
  where the record begins with the rotor already on its bearing (``began_before``) the first
  contact was not recorded: the time on the bearing is then a lower bound, and the impact is
  not known;
* the peak excursion over Cmin and where (a bearing's radius, or an axial gap);
* the whirl while in contact, at the radial bearing that went furthest: the energy of its full spectrum (x + j y)
  at positive frequencies against negative ones, forward or backward where one outweighs the other
  by ``WHIRL_RATIO`` (as a model's modes are marked, :mod:`.orders`); backward whirl on a
  touchdown bearing is the violent kind (it can drive the rotor round the bearing's inner race);
* the amplifier at its limit: the largest |output| over its limit (current or voltage);
* the impact speed: the gap's speed towards the bearing over the ``IMPACT_WINDOW_S`` before the
  first contact, m/s, and where the rotor's mass is known the kinetic energy it brings, J.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from .orders import WHIRL_RATIO
from .spectrum import full_spectrum

AT_CLEARANCE = 0.9  # an excursion this close to Cmin is on the touchdown bearing (the touchdown trigger's)
LEVITATED = 0.5  # within this share of Cmin the rotor is levitated again ...
SETTLE_S = 0.05  # ... once it stays there this long
IMPACT_WINDOW_S = 0.002  # the gap's speed just before the first contact is taken over this window


@dataclass(frozen=True)
class Touchdown:
    """One drop (see the module docstring).  The contact's time in s in the time base it was given,
    lengths as ratios of Cmin, speeds in rpm and m/s, energy in J."""

    contact_s: float
    speed_rpm: float | None
    on_bearing_s: float
    relevitated: bool
    began_before: bool
    peak_ratio: float
    peak_at: str
    whirl: str
    amplifier_at_limit: float | None
    impact_speed_m_s: float | None
    energy_j: float | None

    def record(self) -> dict[str, str]:
        """As metadata (strings, SI: docs/live.md): "" where not known."""
        def text(v) -> str:
            if v is None:
                return ""
            if isinstance(v, bool):
                return "true" if v else "false"
            return repr(v) if isinstance(v, float) else str(v)

        return {k: text(v) for k, v in asdict(self).items()}

    @classmethod
    def from_record(cls, record: dict[str, str]) -> "Touchdown":
        def number(key: str) -> float | None:
            return float(record[key]) if record.get(key, "") != "" else None

        return cls(number("contact_s"), number("speed_rpm"), number("on_bearing_s"), record["relevitated"] == "true",
                   record["began_before"] == "true",
                   number("peak_ratio"), record["peak_at"], record["whirl"], number("amplifier_at_limit"),
                   number("impact_speed_m_s"), number("energy_j"))


def excursions(gap: np.ndarray, pairs, single) -> np.ndarray:
    """Per sample and place, each radial bearing's orbit radius (columns ``pairs``) then each other
    axis's |gap| (columns ``single``), in the unit of ``gap``: shape (n, places)."""
    return np.column_stack([np.hypot(gap[:, i], gap[:, j]) for i, j in pairs] + [np.abs(gap[:, i]) for i in single])


def characterise(time_s: np.ndarray, gap: np.ndarray, cmin_m: float, *, pairs: Sequence[tuple[int, int]],
                 single: Sequence[int], names: Sequence[str], speed_rad_s: np.ndarray | None = None,
                 amplifier: np.ndarray | None = None, limit: float | None = None,
                 mass_kg: float | None = None) -> Touchdown | None:
    """The first drop in a record, or None if the rotor never reached its touchdown bearing.

    Parameters
    ----------
    time_s : ndarray, shape (n,)
        Sample times, s (the contact's time is given in their base: from a file's first sample).
    gap : ndarray, shape (n, axes)
        The gap at the sensors, m.
    cmin_m : float
        Minimum clearance, m.
    pairs : sequence of (int, int)
        The columns of each radial bearing's x and y.
    single : sequence of int
        The columns of the other (axial) axes.
    names : sequence of str
        The name of each place: the bearings, then the axial axes.
    speed_rad_s : ndarray, shape (n,), optional
        Rotor speed at the same instants, rad/s.
    amplifier : ndarray, shape (n, outputs), optional
        The amplifiers' outputs (currents, A, or voltages, V).
    limit : float, optional
        Their limit, in the same unit.
    mass_kg : float, optional
        The rotor's mass, kg (the impact's energy).
    """
    n = gap.shape[0]
    if n < 2:
        return None
    dt = float(np.median(np.diff(time_s)))
    r = excursions(gap, pairs, single)
    ratio = r / cmin_m
    worst = ratio.max(axis=1)
    on = worst >= AT_CLEARANCE
    if not on.any():
        return None
    first = int(np.argmax(on))
    settle = max(1, int(round(SETTLE_S / dt)))
    down = worst >= LEVITATED
    contacts = np.flatnonzero(on)
    # levitated again: the first SETTLE_S after the first contact with every place within LEVITATED
    calm = np.convolve(~down, np.ones(settle, dtype=int), mode="valid") >= settle  # calm[i]: [i, i + settle) calm
    again = np.flatnonzero(calm)
    again = again[again > first]
    relevitated = bool(again.size)
    last = int(contacts[contacts < again[0]].max()) if relevitated else int(contacts.max())
    span = slice(first, last + 1)
    peak_sample = first + int(np.argmax(worst[span]))
    place = int(np.argmax(ratio[peak_sample]))
    whirl = "none"
    if pairs and last > first + 4:
        i, j = pairs[int(np.argmax(ratio[span, :len(pairs)].max(axis=0)))]
        freq, amplitude = full_spectrum(gap[span, i], gap[span, j], fs=1.0 / dt)
        forward, backward = float(np.sum(amplitude[freq > 0] ** 2)), float(np.sum(amplitude[freq < 0] ** 2))
        whirl = "forward" if forward > WHIRL_RATIO * backward else "backward" if backward > WHIRL_RATIO * forward \
            else "mixed"
    began_before = first == 0
    impact = None
    if not began_before:
        k = max(1, int(round(IMPACT_WINDOW_S / dt)))
        before = r[max(0, first - k) : first + 1].max(axis=1)
        impact = max(0.0, float((before[-1] - before[0]) / (dt * (before.shape[0] - 1))))
    at_limit = None
    if amplifier is not None and limit:
        at_limit = float(np.max(np.abs(amplifier[span])) / limit)
    return Touchdown(
        contact_s=float(time_s[first]),
        speed_rpm=None if speed_rad_s is None else float(speed_rad_s[first] * 60.0 / (2 * np.pi)),
        on_bearing_s=float(time_s[last] - time_s[first]),
        relevitated=relevitated,
        began_before=began_before,
        peak_ratio=float(ratio[peak_sample, place]),
        peak_at=names[place],
        whirl=whirl,
        amplifier_at_limit=at_limit,
        impact_speed_m_s=impact,
        energy_j=None if mass_kg is None or impact is None else 0.5 * mass_kg * impact**2,
    )


__all__ = ["AT_CLEARANCE", "LEVITATED", "SETTLE_S", "Touchdown", "characterise", "excursions"]
