"""The run-up figure (``ambdaq runup --plot``, the commissioning report): Bode, polar, shaft
centreline and the full-spectrum waterfall with the model's Campbell lines."""

from __future__ import annotations

import textwrap

import numpy as np

from ..analysis.orders import phase_lag_deg
from . import pyplot


def _draw_centreline(ax, line) -> None:
    """Each bearing's mean position over the run, coloured by speed, inside its clearance circle:
    the origin is the levitation set-point (the sensors' zero)."""
    from matplotlib.colors import Normalize

    norm = Normalize(vmin=float(line.rpm.min()) if line.rpm.size else 0.0,
                     vmax=float(line.rpm.max()) if line.rpm.size else 1.0)
    points = None
    for b, (name, (x, y)) in enumerate(line.bearings.items()):
        ax.plot(x * 1e6, y * 1e6, lw=0.6, color=f"C{b}", label=f"{name} bearing")
        points = ax.scatter(x * 1e6, y * 1e6, c=line.rpm, s=6, cmap="viridis", norm=norm, zorder=3)
    if line.cmin_m is not None:
        circle = np.linspace(0, 2 * np.pi, 361)
        r = line.cmin_m * 1e6
        ax.plot(r * np.cos(circle), r * np.sin(circle), color="k", lw=0.8, label=f"clearance Cmin {r:g} µm")
    ax.plot(0, 0, "k+", ms=10, label="levitation set-point")
    ax.set(xlabel="x [µm]", ylabel="y [µm]", title="shaft centreline (mean position per 0.1 s)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    if points is not None:
        ax.figure.colorbar(points, ax=ax, label="speed [rpm]")


def draw_runup(res, name: str):
    """Bode (1X and NX amplitude, 1X phase lag unwrapped), the 1X polar plot, and the waterfall with
    the order lines and the model's modes, of :func:`~ambdaq.workflows.runup_diagnostics.analyse`'s
    result. An axis keeps one colour; x axes are drawn solid and y axes dashed on top, so a pair of
    equal curves (an isotropic bearing) shows both."""
    plt = pyplot()
    from matplotlib.colors import LogNorm

    t = res.track
    fig = plt.figure(figsize=(18, 10), constrained_layout=True)
    grid = fig.add_gridspec(2, 3)
    amp_ax, ph_ax = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0])
    polar = fig.add_subplot(grid[0, 1], projection="polar")
    centre = fig.add_subplot(grid[0, 2])
    fall = fig.add_subplot(grid[1, 1:])
    _draw_centreline(centre, res.centreline)
    for j, a in enumerate(res.axes):
        color = f"C{j}"
        dashed = a in {b.y for b in res.bearings}
        for k in t.orders:
            v = t.order(k)[:, j] * 1e6
            style = dict(color=color, ls="--" if dashed else "-", lw=(1.0 if dashed else 1.6) / k, zorder=3 if dashed else 2)
            amp_ax.plot(t.rpm, np.abs(v), alpha=1.0 if k == 1 else 0.6, label=f"{a} {k}X", **style)
            if k == 1:
                ph_ax.plot(t.rpm, phase_lag_deg(v), label=f"{a} 1X", **style)
                polar.plot(np.angle(v), np.abs(v), label=a, **style)
                for p in res.peaks.get(a, []):
                    amp_ax.annotate(f"{p.rpm:,.0f} rpm, AF {p.amplification:.1f}", (p.rpm, p.amplitude * 1e6),
                                    fontsize=7, xytext=(5, 5), textcoords="offset points")
    # a compensation names a file: wrapped, so a long path stays inside the panel
    amp_ax.set(ylabel="amplitude [µm, 0-peak]", title="\n".join(textwrap.wrap(f"order tracking, {res.compensation}", 60)))
    amp_ax.title.set_fontsize(9)
    ph_ax.set(xlabel="speed [rpm]", ylabel="1X phase lag [deg] from the key-phasor, unwrapped")
    for ax in (amp_ax, ph_ax):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    polar.set_title("1X vector over the run [µm, deg]", fontsize=10)
    polar.legend(fontsize=7, loc="lower left", bbox_to_anchor=(-0.15, -0.12))
    rpm, f, a = res.waterfall
    full = f[0] < 0  # a bearing's full spectrum: backward whirl left of zero
    limit = min(f[-1], 1.2 * max(t.orders + (4,)) * rpm.max() / 60.0)
    keep = (np.abs(f) if full else f) <= limit
    order = np.argsort(rpm)
    mesh = fall.pcolormesh(f[keep], rpm[order], np.maximum(a[order][:, keep] * 1e6, 1e-3), shading="nearest",
                           norm=LogNorm(vmin=1e-2, vmax=max(1e-1, float(a.max() * 1e6))), cmap="viridis")
    fig.colorbar(mesh, ax=fall, label="amplitude [µm]")
    for k in (1, 2, 3, 4, *((-1, -2) if full else ())):
        fall.plot(k * rpm[order] / 60.0, rpm[order], color="w", lw=0.6, ls=":")
        fall.annotate(f"{k:+d}X" if full else f"{k}X", (k * rpm.max() / 60.0, rpm.max()), color="w", fontsize=7,
                      ha="center", va="bottom")
    if res.modes is not None:
        speeds, table, whirl = res.modes.rpm, res.modes.freq_hz, res.modes.whirl
        # points: a mode may enter or leave the damping limit over the run. Forward whirl up, backward
        # down; in the full spectrum each on its own side (a mode that whirls neither way, axial or
        # planar, or whose whirl the model does not give: on both, hollow)
        for direction, marker, label in ((1, "^", "model modes, forward"), (-1, "v", "model modes, backward"),
                                         (0, "o", "model modes")):
            f = np.where(whirl == direction, table, np.nan)
            if not np.isfinite(f).any():
                continue
            rows = np.repeat(speeds[:, None], f.shape[1], axis=1)
            if full and direction == 0:
                fall.plot(np.concatenate([f.ravel(), -f.ravel()]), np.concatenate([rows.ravel()] * 2), marker,
                          color="r", mfc="none", ms=2.5, ls="none", label=label)
            else:
                fall.plot((-f if full and direction < 0 else f).ravel(), rows.ravel(), marker, color="r", ms=3,
                          ls="none", label=label)
        fall.legend(fontsize=7, loc="lower right")
    fall.set(xlabel="frequency [Hz]" + (": backward < 0 < forward" if full else ""), ylabel="speed [rpm]",
             xlim=(-limit if full else 0, limit),
             title=(f"full-spectrum waterfall of the {res.waterfall_axis} bearing" if full
                    else f"waterfall of {res.waterfall_axis}") + (" with the model's modes (Campbell)" if res.modes else ""))
    fig.suptitle(f"run-up diagnostics: {name}")
    return fig
