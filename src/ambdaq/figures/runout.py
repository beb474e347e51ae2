"""Figures of ``ambdaq runout``: the identification report and the before/after check."""

from __future__ import annotations


import numpy as np

from ..units import RAD_S_TO_RPM
from ..analysis.runout import synthesise
from ..analysis.spectrum import amplitude_spectrum
from ..daq.recording import Recording
from . import pyplot

ORBIT_REVS = 20  # revolutions drawn in an orbit: enough to show its spread, few enough to see its shape


def _last_revolutions(theta: np.ndarray, revs: int) -> slice:
    """The samples of the last ``revs`` revolutions; ``theta`` in rad, wrapped or not."""
    turns = np.unwrap(theta) / (2 * np.pi)
    return slice(int(np.searchsorted(turns, turns[-1] - revs)), len(theta))


def _order_spectrum(ax, signals: dict[str, tuple[np.ndarray, float]], fs: float, *, max_order: float,
                    styles: dict[str, dict]) -> None:
    """Amplitude spectra (um) against order; ``signals`` maps a label to (signal in m, speed in rad/s)."""
    for label, (x, spin) in signals.items():
        f, a = amplitude_spectrum(x, fs=fs)
        order = f * 2 * np.pi / spin
        keep = order <= max_order
        ax.semilogy(order[keep], np.maximum(a[keep] * 1e6, 1e-4), lw=0.7, label=label, **styles.get(label, {}))
    ax.set(xlabel="order (multiples of running speed)", ylabel="amplitude [µm]", xlim=(0, max_order))
    ax.grid(alpha=0.3, which="both")


def draw_identification(ident):
    """The identification report: spectrum, a polar plot per harmonic, orbits with and without the
    identified runout.

    Parameters
    ----------
    ident : Identification
        What ``identify_recordings`` returned.

    Notes
    -----
    The spectrum and the orbits are of the first recording's gap sensors, for each bearing of the
    coefficient file (its NAME_x / NAME_y axes). The second orbit is the sensor signal less the
    identified runout (``synthesise`` at the recorded rotor angle): what the controller would see
    of the rotor with the coefficients pushed; nothing has been pushed yet. A bearing's x axis is
    drawn solid with filled markers, its y axis dashed with open ones on top, so equal values
    (an isotropic bearing) show both.
    """
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    coef = ident.coef
    harmonics = coef.harmonics
    axes = list(coef.weights)
    runout = np.array([[complex(*coef.weights[a][i]) for a in axes] for i in range(len(harmonics))])
    gap, rot = ident.first.together("gap", "rotor")
    n = len(gap)
    theta, spin = rot["angle"][:n], float(ident.spins[0])
    rpm = spin * RAD_S_TO_RPM
    bearings = [(b.name, b.x, b.y) for b in ident.first.machine.bearings if b.x in axes and b.y in axes]
    style = {}
    for b, (_name, x, y) in enumerate(bearings):
        style[x] = {"color": f"C{2 * b}", "ls": "-", "marker": "o", "mfc": f"C{2 * b}", "zorder": 2, "lw": 1.4}
        style[y] = {"color": f"C{2 * b + 1}", "ls": "--", "marker": "s", "mfc": "none", "zorder": 3, "lw": 1.0}

    fig = plt.figure(figsize=(max(12.0, 2.6 * len(harmonics)), 12.5), constrained_layout=True)
    top, middle, bottom = fig.subfigures(3, 1, height_ratios=[1.0, 0.9, 1.2])
    for ax, (bearing, x, y) in zip(np.atleast_1d(top.subplots(1, len(bearings))), bearings):
        _order_spectrum(ax, {a: (gap[a][:n], spin) for a in (x, y)}, gap.sample_rate, max_order=max(harmonics) + 2.5,
                        styles={a: {"color": style[a]["color"], "ls": style[a]["ls"], "zorder": style[a]["zorder"]}
                                for a in (x, y)})
        for a in (x, y):
            amp = np.abs(runout[:, axes.index(a)]) * 1e6
            st = style[a]
            ax.plot(harmonics, amp, st["marker"], mfc=st["mfc"], color=st["color"], ms=7 if a == x else 5,
                    zorder=st["zorder"] + 2, label=f"{a} identified runout")
        ax.set_title(f"{bearing}: gap sensor spectrum at {rpm:,.0f} rpm")
        ax.legend(fontsize=7)
    top.suptitle(f"runout identification ({coef.source.get('method', '')}) from "
                 f"{', '.join(p.name for p in ident.paths)}")

    polar = middle.subplots(1, len(harmonics), subplot_kw={"projection": "polar"}, squeeze=False)[0]
    several = len(ident.paths) > 1
    radial = [a for _b, x, y in bearings for a in (x, y)]
    for i, (ax, k) in enumerate(zip(polar, harmonics)):
        for a in radial:
            j = axes.index(a)
            p = runout[i, j] * 1e6
            st = style[a]
            ax.plot([0, np.angle(p)], [0, abs(p)], color=st["color"], ls=st["ls"], lw=st["lw"], zorder=st["zorder"])
            ax.plot(np.angle(p), abs(p), st["marker"], mfc=st["mfc"], color=st["color"], ms=7 if st["ls"] == "-" else 5,
                    zorder=st["zorder"] + 2, label=a)
            if several:  # each recording's own estimate: at 1X these differ by the unbalance response
                q = ident.per_file[:, i, j] * 1e6
                ax.plot(np.angle(q), np.abs(q), "x", color=st["color"], ms=5)
        ax.set_title(f"{k}X [µm, deg]", fontsize=9)
        ax.yaxis.set_major_locator(MaxNLocator(3))
        ax.tick_params(labelsize=7)
    # the legend beside the polar plots, never on their angle labels
    handles, labels = polar[0].get_legend_handles_labels()
    middle.legend(handles, labels, fontsize=7, loc="outside right center")
    middle.suptitle("runout phasor per harmonic (angle from the key-phasor)"
                    + ("; x: each recording alone" if several else ""))

    window = _last_revolutions(theta, ORBIT_REVS)
    removed = synthesise(runout, harmonics, theta[window])
    for ax, (bearing, x, y) in zip(np.atleast_1d(bottom.subplots(1, len(bearings))), bearings):
        gx, gy = gap[x][:n][window], gap[y][:n][window]
        ax.plot(gx * 1e6, gy * 1e6, lw=0.5, color="0.55", label="sensor, as recorded")
        ax.plot((gx - removed[:, axes.index(x)]) * 1e6, (gy - removed[:, axes.index(y)]) * 1e6, lw=0.8,
                color="C3", label="sensor less the identified runout (the rotor, as the controller would see it)")
        ax.set(xlabel=f"{x} [µm]", ylabel=f"{y} [µm]", title=f"{bearing} orbit, last {ORBIT_REVS} revolutions")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    return fig


def draw_check(before: Recording, after: Recording, harmonics: list[int]):
    """The before/after figure: command-error orbit and spectrum per bearing, both recordings.

    Parameters
    ----------
    before, after : Recording
        With the command error and the rotor angle, before and after the push.
    harmonics : list of int
        Orders marked on the spectra.
    """
    plt = pyplot()
    runs = {}
    for label, rec in (("before", before), ("after", after)):
        err, rot = rec.together("error", "rotor")
        n = len(err)
        runs[label] = (rec.path, err, n, rot["angle"][:n], float(np.median(rot["speed"][:n])))
    styles = {"before": {"color": "0.55"}, "after": {"color": "C3"}}
    fields = before.role("error").fields
    bearings = [(b.name, b.x, b.y) for b in before.machine.bearings if b.x in fields and b.y in fields]
    fig, axes = plt.subplots(2, len(bearings), figsize=(6 * len(bearings), 10), constrained_layout=True, squeeze=False)
    for col, (bearing, x, y) in enumerate(bearings):
        ax = axes[0, col]
        for label, (file, err, n, theta, _) in runs.items():
            w = _last_revolutions(theta, ORBIT_REVS)
            ax.plot(err[x][:n][w] * 1e6, err[y][:n][w] * 1e6, lw=0.6, label=f"{label}: {file.name}", **styles[label])
        ax.set(xlabel=f"{x} [µm]", ylabel=f"{y} [µm]",
               title=f"{bearing}: command error orbit, last {ORBIT_REVS} revolutions")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        ax = axes[1, col]
        _order_spectrum(ax, {label: (err[x][:n], spin) for label, (_, err, n, _, spin) in runs.items()},
                        runs["before"][1].sample_rate, max_order=max(harmonics) + 4.5, styles=styles)
        for k in harmonics:
            ax.axvline(k, color="k", lw=0.4, ls=":")
        ax.set_title(f"{x}: command error spectrum")
        ax.legend(fontsize=7)
    fig.suptitle(f"command error before ({before.path.name}) and after ({after.path.name})")
    return fig
