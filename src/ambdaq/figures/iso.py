"""ISO 14839 figures: the sensitivity function against the zone limits (part 3, ``ambdaq iso
stability --plot``) and the orbit per speed band against Cmin (part 2, ``ambdaq iso vibration --plot``)."""

from __future__ import annotations

import numpy as np

from ..analysis.iso14839 import ZoneLimits, db
from . import pyplot


def draw_stability(curves: list[dict], limits: ZoneLimits):
    """|Gs| against frequency per axis, one panel per speed, with the zone limits.

    Parameters
    ----------
    curves : list of dict
        Each with ``speed_rpm``, ``axis``, ``freq_hz`` (Hz), ``gs`` (complex), ``coherence``,
        ``peak_db`` (or None) and ``zone`` (or None).
    limits : ZoneLimits
        Peak |Gs| at the zone boundaries.
    """
    plt = pyplot()
    speeds = sorted({c["speed_rpm"] for c in curves})
    fig, axes = plt.subplots(len(speeds), 1, figsize=(9, 3.2 * len(speeds) + 0.6), squeeze=False, sharex=True,
                             constrained_layout=True)
    for ax, rpm in zip(axes[:, 0], speeds):
        for c in (c for c in curves if c["speed_rpm"] == rpm):
            trusted = np.asarray(c["coherence"]) >= 0.9
            mag = db(np.abs(c["gs"]))
            peak = "not graded" if c["zone"] is None else f"{c['peak_db']:.1f} dB, zone {c['zone']}"
            line = ax.semilogx(c["freq_hz"], np.where(trusted, mag, np.nan), lw=0.9, label=f"{c['axis']}: {peak}")[0]
            ax.semilogx(c["freq_hz"], np.where(trusted, np.nan, mag), lw=0.5, alpha=0.3, color=line.get_color())
        for z, v in zip(("A/B", "B/C", "C/D"), limits.as_list()):
            ax.axhline(db(v), color="grey", lw=0.7, ls="--")
            ax.annotate(z, (1.0, db(v)), xycoords=("axes fraction", "data"), ha="right", va="bottom", fontsize=7)
        ax.set(ylabel="|Gs| [dB]", title=f"sensitivity function at {rpm:,.0f} rpm (faint: coherence < 0.9)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, loc="lower right")
    axes[-1, 0].set(xlabel="frequency [Hz]")
    return fig


def draw_vibration(bands: list[dict], limits: ZoneLimits, cmin_um: float):
    """Each bearing's graded orbit per speed band against the zone limits (as fractions of Cmin).

    Parameters
    ----------
    bands : list of dict
        ``iso vibration``'s bands (``bearing``, ``rpm_from``, ``rpm_to``, ``max_um``).
    limits : ZoneLimits
        Displacement per Cmin at the zone boundaries.
    cmin_um : float
        Minimum clearance, in um.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    for bearing in sorted({b["bearing"] for b in bands}):
        rows = [b for b in bands if b["bearing"] == bearing]
        ax.step([r["rpm_from"] for r in rows] + [rows[-1]["rpm_to"]], [r["max_um"] for r in rows] + [rows[-1]["max_um"]],
                where="post", label=f"{bearing} bearing")
    for z, v in zip(("A/B", "B/C", "C/D"), limits.as_list()):
        ax.axhline(v * cmin_um, color="grey", lw=0.7, ls="--")
        ax.annotate(f"{z} {v:g} Cmin", (1.0, v * cmin_um), xycoords=("axes fraction", "data"), ha="right", va="bottom",
                    fontsize=7)
    ax.set(xlabel="speed [rpm]", ylabel="orbit maximum from its centre [µm]",
           title=f"ISO 14839-2 vibration per speed band, Cmin {cmin_um:g} µm")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    return fig
