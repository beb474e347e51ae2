"""A recorded signal (``ambdaq plot``): time series, spectrum, the bearing's orbit and full spectrum."""

from __future__ import annotations

import textwrap

import numpy as np

from ..analysis.spectrum import amplitude_spectrum, full_spectrum
from ..daq.recording import Recording
from ..machines.machine import Bearing, orbit_partner, radial_bearings
from ..units import RAD_S_TO_RPM
from . import pyplot

UNIT_SCALE = {"m": (1e6, "µm"), "m/s^2": (1.0, "m/s²"), "A": (1.0, "A"), "rad": (1.0, "rad"),
              "rad/s": (RAD_S_TO_RPM, "rpm")}  # a speed in rpm, as an AMB engineer reads it
ENVELOPE_BINS = 800  # a long window's time panel: min and max per bin (about a screen pixel each)
RAW_POINTS = 4000  # up to this many samples the waveform itself is drawn


def _wrapped(text: str, width: int = 48) -> str:
    return "\n".join(textwrap.wrap(text, width))


def _full_spectrum_panel(ax, data, bearing: Bearing, scale: float, unit: str, steady_rpm: float | None) -> None:
    """The bearing's full spectrum (x + j y, x turning towards y): forward whirl at positive
    frequencies, backward at negative ones; with a steady speed, the +-1X and +-2X marks."""
    from matplotlib.ticker import MaxNLocator

    f, a = full_spectrum(data[bearing.x], data[bearing.y], fs=data.sample_rate)
    span = min(f[-1], 10.5 * steady_rpm / 60.0) if steady_rpm else f[-1]
    keep = np.abs(f) <= span
    ax.semilogy(f[keep], np.maximum(a[keep] * scale, 1e-12), lw=0.6)
    if steady_rpm:
        for k in (1, 2, -1, -2):
            ax.axvline(k * steady_rpm / 60.0, color="C3", lw=0.6, ls=":", alpha=0.8)
            ax.annotate(f"{'+' if k > 0 else '-'}{abs(k)}X", (k * steady_rpm / 60.0, 0.98),
                        xycoords=("data", "axes fraction"), color="C3", fontsize=7, ha="left", va="top")
    ax.set(xlabel="frequency [Hz]: backward < 0 < forward", ylabel=f"whirl radius [{unit}]",
           title=_wrapped(f"full spectrum of {bearing.name}: forward and backward whirl"))
    ax.xaxis.set_major_locator(MaxNLocator(6))
    ax.grid(alpha=0.3, which="both")


def _bearings(rec: Recording, fields: list[str]) -> list[Bearing]:
    """The radial bearings among ``fields``: the machine's where the topic carries its axes (gap,
    current, error), else the NAME_x/NAME_y pairs of the topic's own fields."""
    machine = [b for b in rec.machine.bearings if b.x in fields and b.y in fields]
    return machine or radial_bearings(fields)


def draw_signal(rec: Recording, topic: str, field_name: str, clearance_m: float | None):
    """The figure of ``plot``: the time series (the waveform up to RAW_POINTS samples, beyond that
    its min-max envelope per bin, so ten seconds at 10 kHz read as amplitude over time and not as a
    solid band), the amplitude spectrum with the speed's orders when it was steady, and the
    bearing's orbit with the clearance circle (``clearance_m``, m, if known).

    Parameters
    ----------
    rec : Recording
        With ``topic`` (and the rotor angle for the order marks).
    topic, field_name : str
        The signal: a role, its topic (``/amb/gap``: the machine's gap wherever recorded) or any
        topic, and a field of it.
    clearance_m : float or None
        Minimum clearance, m.
    """
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    data = rec.signals(topic)
    y = data[field_name]
    scale, unit = UNIT_SCALE.get(data.units[field_name], (1.0, data.units[field_name]))
    bearings = _bearings(rec, list(data.fields))
    partner = orbit_partner(field_name, bearings)
    bearing = next((b for b in bearings if field_name in (b.x, b.y)), None)
    ncols = 4 if partner else 2
    fig, axes = plt.subplots(1, ncols, figsize=(5 * ncols, 4.2), constrained_layout=True)
    ax = axes[0]
    t = data.time
    t0 = float(t[0])
    span = float(t[-1] - t0)
    # short windows in ms from their first sample, long ones in s: tick labels stay short
    tscale, tunit = (1e3, "ms") if span < 1.0 else (1.0, "s")
    rel = (t - t0) * tscale
    if len(y) <= RAW_POINTS:
        ax.plot(rel, y * scale, lw=0.7)
        shown = "waveform"
    else:
        edges = np.linspace(0, len(y), ENVELOPE_BINS + 1).astype(int)
        lo = np.minimum.reduceat(y, edges[:-1]) * scale
        hi = np.maximum.reduceat(y, edges[:-1]) * scale
        mid = rel[(edges[:-1] + edges[1:]) // 2]
        ax.fill_between(mid, lo, hi, color="C0", alpha=0.35, lw=0, label="min-max per bin")
        ax.plot(mid, np.add.reduceat(y, edges[:-1]) / np.diff(edges) * scale, color="C0", lw=0.8, label="mean per bin")
        ax.legend(fontsize=7, loc="upper right")
        shown = f"envelope of {len(y):,} samples in {ENVELOPE_BINS} bins"
    ax.set(xlabel=f"time [{tunit}] from {t0:.4g} s", ylabel=f"{field_name} [{unit}]",
           title=_wrapped(f"{topic} {field_name}: {shown}"))
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.grid(alpha=0.3)
    f, a = amplitude_spectrum(y, fs=data.sample_rate)
    ax = axes[1]
    ax.semilogy(f, np.maximum(a * scale, 1e-12), lw=0.6)
    title = "spectrum (Hann)"
    steady_rpm = None
    rotor = rec.role("rotor") if rec.has_role("rotor") else None
    if rotor is not None and rotor.topic != data.topic and len(rotor):
        rpm = rotor["speed"] * RAD_S_TO_RPM
        lo_rpm, hi_rpm, mean = float(rpm.min()), float(rpm.max()), float(rpm.mean())
        if hi_rpm - lo_rpm <= 0.02 * max(mean, 1.0) and mean / 60.0 > 2 * (f[1] - f[0]):  # steady: mark the orders
            steady_rpm = mean
            title = f"spectrum (Hann) at {mean:,.0f} rpm"
            for k in range(1, 7):
                if k * mean / 60.0 < f[-1]:
                    ax.axvline(k * mean / 60.0, color="C3", lw=0.6, ls=":", alpha=0.8)
                    ax.annotate(f"{k}X", (k * mean / 60.0, 0.98), xycoords=("data", "axes fraction"), color="C3",
                                fontsize=7, ha="left", va="top")
        else:
            title = f"spectrum (Hann), {lo_rpm:,.0f}-{hi_rpm:,.0f} rpm (no order marks: the speed changed)"
    ax.set(xlabel="frequency [Hz]", ylabel=f"amplitude [{unit}]", title=_wrapped(title))
    ax.xaxis.set_major_locator(MaxNLocator(6))
    ax.grid(alpha=0.3, which="both")
    if partner:
        ax = axes[2]
        # the bearing's x across and its y up, whichever of them was asked: the orbit as the rotor
        # whirls (x against y turns counter-clockwise for a forward whirl), never mirrored
        ox, oy = (bearing.x, bearing.y) if bearing is not None else (field_name, partner)
        ax.plot(data[ox] * scale, data[oy] * scale, lw=0.4)
        ax.set(xlabel=f"{ox} [{unit}]", ylabel=f"{oy} [{unit}]", title=f"orbit: {ox} across, {oy} up")
        if clearance_m is not None and data.units[field_name] == "m":
            circle = np.linspace(0, 2 * np.pi, 361)
            ax.plot(clearance_m * scale * np.cos(circle), clearance_m * scale * np.sin(circle), color="k", lw=0.8,
                    label=f"Cmin {clearance_m * 1e6:g} µm")
            ax.legend(fontsize=7, loc="upper right")
            ax.set_title("orbit and the touchdown clearance")
        ax.set_aspect("equal", adjustable="datalim")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(MaxNLocator(5))
        ax.grid(alpha=0.3)
        _full_spectrum_panel(axes[3], data, bearing, scale, unit, steady_rpm)
    for ax in axes:
        ax.title.set_fontsize(10)
    return fig
