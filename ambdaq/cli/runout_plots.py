"""Figures for ``ambdaq runout``: the identification report and the before/after check."""

from __future__ import annotations


import numpy as np

from ..machines.spindle import AXES
from ..units import RAD_S_TO_RPM
from ..analysis.runout import synthesise
from ..analysis.spectrum import amplitude_spectrum
from ..daq.reader import Recording
from .figures import pyplot

BEARINGS = ("front", "rear")
ORBIT_REVS = 20  # revolutions drawn in an orbit: enough to show its spread, few enough to see its shape
COLOURS = {"front_x": "C0", "front_y": "C1", "rear_x": "C2", "rear_y": "C3"}


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


def identify_report(ident, path: str) -> None:
    """Write the identification report: spectrum, a polar plot per harmonic, orbits before and after.

    Parameters
    ----------
    ident : Identification
        What ``identify_recordings`` returned.
    path : str
        Image file (.png, .pdf, .svg).

    Notes
    -----
    The spectrum and the orbits are of the first recording's gap sensors.  The orbit "after" is
    the sensor signal with the identified runout (``synthesise`` at the recorded rotor angle)
    taken away: what the controller would see of the rotor with the coefficients pushed.
    """
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    coef = ident.coef
    harmonics = coef.harmonics
    runout = np.array([[complex(*coef.weights[a][i]) for a in AXES] for i in range(len(harmonics))])
    gap, rot = ident.first["/amb/gap"], ident.first["/amb/rotor"]
    n = min(len(gap), len(rot))
    theta, spin = rot["angle"][:n], float(ident.spins[0])
    rpm = spin * RAD_S_TO_RPM
    radial = [a for a in AXES if a in COLOURS]

    fig = plt.figure(figsize=(max(12.0, 2.6 * len(harmonics)), 12.5), constrained_layout=True)
    top, middle, bottom = fig.subfigures(3, 1, height_ratios=[1.0, 0.9, 1.2])
    for ax, bearing in zip(top.subplots(1, 2), BEARINGS):
        axes = [a for a in radial if a.startswith(bearing)]
        _order_spectrum(ax, {a: (gap[a][:n], spin) for a in axes}, gap.sample_rate, max_order=max(harmonics) + 2.5,
                        styles={a: {"color": COLOURS[a]} for a in axes})
        for a in axes:
            amp = np.abs(runout[:, AXES.index(a)]) * 1e6
            ax.plot(harmonics, amp, "o", mfc="none", color=COLOURS[a], label=f"{a} identified runout")
        ax.set_title(f"{bearing}: gap sensor spectrum at {rpm:,.0f} rpm")
        ax.legend(fontsize=7)
    top.suptitle(f"runout identification ({coef.source.get('method', '')}) from "
                 f"{', '.join(p.name for p in ident.paths)}")

    polar = middle.subplots(1, len(harmonics), subplot_kw={"projection": "polar"}, squeeze=False)[0]
    several = len(ident.paths) > 1
    for i, (ax, k) in enumerate(zip(polar, harmonics)):
        for a in radial:
            j = AXES.index(a)
            p = runout[i, j] * 1e6
            ax.plot([0, np.angle(p)], [0, abs(p)], color=COLOURS[a], lw=1.5)
            ax.plot(np.angle(p), abs(p), "o", color=COLOURS[a], label=a)
            if several:  # each recording's own estimate: at 1X these differ by the unbalance response
                q = ident.per_file[:, i, j] * 1e6
                ax.plot(np.angle(q), np.abs(q), "x", color=COLOURS[a], ms=5)
        ax.set_title(f"{k}X [µm, deg]", fontsize=9)
        ax.yaxis.set_major_locator(MaxNLocator(3))
        ax.tick_params(labelsize=7)
    polar[0].legend(fontsize=7, loc="lower left", bbox_to_anchor=(-0.35, -0.25))
    middle.suptitle("runout phasor per harmonic (angle from the key-phasor)"
                    + ("; x: each recording alone" if several else ""))

    window = _last_revolutions(theta, ORBIT_REVS)
    removed = synthesise(runout, harmonics, theta[window])
    for ax, bearing in zip(bottom.subplots(1, 2), BEARINGS):
        x, y = f"{bearing}_x", f"{bearing}_y"
        gx, gy = gap[x][:n][window], gap[y][:n][window]
        ax.plot(gx * 1e6, gy * 1e6, lw=0.5, color="0.55", label="sensor (before)")
        ax.plot((gx - removed[:, AXES.index(x)]) * 1e6, (gy - removed[:, AXES.index(y)]) * 1e6, lw=0.8,
                color="C3", label="identified runout removed (after)")
        ax.set(xlabel=f"{x} [µm]", ylabel=f"{y} [µm]", title=f"{bearing} orbit, last {ORBIT_REVS} revolutions")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def check_report(before: Recording, after: Recording, harmonics: list[int], path: str) -> None:
    """Write the before/after figure: command-error orbit and spectrum per bearing, both recordings.

    Parameters
    ----------
    before, after : Recording
        Loaded with ``/amb/error`` and ``/amb/rotor``, before and after the push.
    harmonics : list of int
        Orders marked on the spectra.
    path : str
        Image file (.png, .pdf, .svg).
    """
    plt = pyplot()
    runs = {}
    for label, rec in (("before", before), ("after", after)):
        err, rot = rec["/amb/error"], rec["/amb/rotor"]
        n = min(len(err), len(rot))
        runs[label] = (rec.path, err, n, rot["angle"][:n], float(np.median(rot["speed"][:n])))
    styles = {"before": {"color": "0.55"}, "after": {"color": "C3"}}
    fig, axes = plt.subplots(2, 2, figsize=(12, 10), constrained_layout=True)
    for col, bearing in enumerate(BEARINGS):
        x, y = f"{bearing}_x", f"{bearing}_y"
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
    fig.savefig(path, dpi=100)
    plt.close(fig)
