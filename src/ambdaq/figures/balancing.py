"""The balancing figure (``ambdaq balance influence --plot``, ``balance correct --plot``): polar
plots in the rotor's frame, angles from the key-phasor's mark in the direction of rotation, as a
balancing instrument shows them (ISO 21940-13's vector diagrams)."""

from __future__ import annotations

import numpy as np

from . import pyplot


def _arrow(ax, v: complex, **style) -> None:
    """A phasor from the origin: a line and a marker at its head."""
    ax.plot([0.0, np.angle(v)], [0.0, abs(v)], lw=style.pop("lw", 1.4), color=style["color"], ls=style.pop("ls", "-"))
    ax.plot(np.angle(v), abs(v), style.pop("marker", "o"), **style)


def draw_balancing(result):
    """One polar plot per balancing plane with its influence coefficient at every radial axis
    (um per g mm; N per g mm for the bearings' forces), one with the run's 1X per axis (runout
    out) beside the residual the correction predicts (um; N), and one with the correction masses
    per plane (g) and the unbalance they cancel.

    Parameters
    ----------
    result : ambdaq.workflows.balancing.Balancing
        Influence coefficients (m or N per kg m), the run's 1X (m or N), the correction (kg m) and
        its masses.
    """
    from ..workflows.balancing import SIGNALS

    plt = pyplot()
    unit, scale = SIGNALS[result.signal]
    unit = "µm" if unit == "um" else unit
    from matplotlib.ticker import MaxNLocator

    n = len(result.planes) + 2
    # the legends below the panels grow with the rows (axes, or axes at each speed): the figure with them
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.4 + 0.2 * len(result.axes)), subplot_kw={"projection": "polar"},
                             constrained_layout=True)
    colors = {a: c for a, c in zip(result.axes, plt.rcParams["axes.prop_cycle"].by_key()["color"])}
    for k, (ax, plane) in enumerate(zip(axes, result.planes)):
        for i, a in enumerate(result.axes):
            _arrow(ax, result.influence[i, k] * scale * 1e-6, color=colors[a], label=a, ms=6)  # per g mm
        ax.set_title(f"influence of {plane} [{unit} per g mm]", fontsize=9, pad=14)
    ax = axes[len(result.planes)]
    for i, a in enumerate(result.axes):
        _arrow(ax, result.reference[i] * scale, color=colors[a], label=f"{a} run", ms=6)
        _arrow(ax, result.residual[i] * scale, color=colors[a], ls=":", lw=1.0, marker="x", ms=6,
               label=f"{a} predicted after")
    what = "1X force" if result.signal == "forces" else "1X"
    ax.set_title(f"{what}, runout out [{unit}]" if result.runout_removed else f"{what}, no runout taken out [{unit}]",
                 fontsize=9, pad=14)
    ax = axes[-1]
    for m in result.masses():
        _arrow(ax, m.grams * np.exp(1j * np.radians(m.deg)), color=f"C{3 + result.planes.index(m.plane)}",
               marker="s", ms=7, label=f"{m.plane}: {m.grams:.3g} g at {m.deg:.0f}°")
    for k, (p, u) in enumerate(zip(result.planes, result.correction)):  # the unbalance now, opposite its correction
        g = abs(u) / result.radius_m[p] * 1e3
        _arrow(ax, -g * np.exp(1j * np.angle(u)), color=f"C{3 + k}", ls="--", lw=1.0, marker="^", ms=6,
               mfc="none", label=f"{p}: the unbalance now")
    radii = sorted({f"{r * 1e3:g}" for r in result.radius_m.values()})
    ax.set_title(f"correction [g at {', '.join(radii)} mm]", fontsize=9, pad=14)
    for ax in axes:
        ax.yaxis.set_major_locator(MaxNLocator(3))
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(-0.1, -0.08), ncol=2, frameon=False)
    speeds = " and ".join(f"{r:,.0f}" for r in (result.speeds_rpm or [result.rpm]))
    fig.suptitle(f"balancing at {speeds} rpm (angles from the key-phasor's mark, in the direction of rotation)",
                 fontsize=10)
    return fig
