"""``ambdaq runup``: run-up and coast-down diagnostics (order tracking, Bode, polar, waterfall, Campbell)."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import click
import numpy as np

from ..analysis.orders import CRITICAL_AMPLIFICATION
from ..errors import BadInputError
from .figures import plot_option, pyplot
from .options import max_lost_option


def _orders(value: str) -> tuple[int, ...]:
    try:
        out = tuple(sorted({int(v) for v in value.split(",")}))
    except ValueError:
        raise BadInputError(f"--orders {value!r}: expected comma-separated orders, e.g. 1,2") from None
    if not out or out[0] < 1 or out[-1] > 20:
        raise BadInputError(f"--orders {value!r}: orders are 1 .. 20")
    return out


def _speeds(value: str | None) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value.split(":"))
        if not 0 <= lo < hi < 1e6:
            raise ValueError
    except ValueError:
        raise BadInputError(f"--speeds {value!r}: expected FROM:TO in rpm, e.g. 0:50000") from None
    return lo, hi


@click.command("runup")
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--coefficients", type=click.Path(dir_okay=False),
              help="Runout coefficient file (runout identify): the sensor runout is taken out (the rotor's motion is left).")
@click.option("--slow-roll", type=click.Path(dir_okay=False),
              help="Slow-roll recording: its vector per order is taken out of every window's (Bently style).")
@click.option("--orders", default="1,2", show_default=True, help="Orders to track.")
@click.option("--revolutions", type=click.IntRange(1, 1000), default=8, show_default=True,
              help="Revolutions per tracking window.")
@click.option("--speeds", metavar="FROM:TO", help="Speed range the run must cover, rpm.")
@click.option("--model", type=click.Choice(["spindle", "cone"]),
              help="Overlay the modes this model's loop predicts (Campbell): the spindle's or the cone rotor's.")
@click.option("--waterfall-axis", help="Gap axis of the waterfall; default: the first radial one.")
@plot_option("Bode, polar, waterfall with order lines (and Campbell with --model) (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the tracked vectors and peaks as JSON.")
@max_lost_option
def command(recording, coefficients, slow_roll, orders, revolutions, speeds, model, waterfall_axis, plot_path, as_json,
            max_lost):
    """Order tracking of a run-up or coast-down on the key-phasor: 1X (and NX) amplitude and phase
    against speed, 1X peaks with their amplification factor (critical speeds, API 684), a waterfall.

    \b
    Example:
      ambdaq runup runup.mcap --coefficients coef.json --model spindle --plot runup.png
      ambdaq runup coastdown.mcap --slow-roll slow.mcap --orders 1,2,3 --json
    """
    from ..daq.recording import open_recording
    from ..workflows.runup_diagnostics import analyse

    res = analyse(open_recording(recording), coefficients=Path(coefficients) if coefficients else None,
                  slow_roll=open_recording(slow_roll) if slow_roll else None, orders=_orders(orders), revolutions=revolutions,
                  speeds=_speeds(speeds), waterfall_axis=waterfall_axis, model=model, max_lost=max_lost)
    for note in res.notes:
        click.echo(f"ambdaq: warning: {note}", err=True)
    t = res.track
    if as_json:
        click.echo(json.dumps({
            "recording": recording, "compensation": res.compensation, "notes": res.notes, "revolutions": revolutions,
            "rpm": np.round(t.rpm, 1).tolist(),
            "axes": {a: {f"{k}X": {"amplitude_um": np.round(np.abs(t.order(k)[:, i]) * 1e6, 4).tolist(),
                                   "phase_deg": np.round(np.degrees(np.angle(t.order(k)[:, i])), 2).tolist()}
                         for k in t.orders} for i, a in enumerate(res.axes)},
            "peaks_1x": {a: [{"rpm": round(p.rpm, 1), "amplitude_um": round(p.amplitude * 1e6, 3),
                              "band_rpm": [round(v, 1) for v in p.band_rpm], "phase_change_deg": round(p.phase_change_deg, 1),
                              "amplification": round(p.amplification, 2), "critical": p.is_critical()} for p in peaks]
                         for a, peaks in res.peaks.items()},
            "centreline": {"rpm": np.round(res.centreline.rpm, 1).tolist(),
                           "time_s": np.round(res.centreline.time_s, 4).tolist(),
                           "cmin_um": None if res.centreline.cmin_m is None else round(res.centreline.cmin_m * 1e6, 3),
                           "bearings": {b: {"x_um": np.round(x * 1e6, 4).tolist(), "y_um": np.round(y * 1e6, 4).tolist()}
                                        for b, (x, y) in res.centreline.bearings.items()}},
            "model_modes": None if res.modes is None else {
                "rpm": res.modes.rpm.round(1).tolist(),
                "freq_hz": [[None if np.isnan(f) else round(float(f), 2) for f in row] for row in res.modes.freq_hz],
                "damping": [[None if np.isnan(z) else round(float(z), 4) for z in row] for row in res.modes.damping],
                "whirl": [[None if np.isnan(f) or not w else ("forward" if w > 0 else "backward")
                           for f, w in zip(row, ws)] for row, ws in zip(res.modes.freq_hz, res.modes.whirl)]},
            "critical_speeds": [c.as_dict() for c in res.criticals],
        }, indent=2))
    else:
        _print_table(res)
    if plot_path:
        runup_figure(res, plot_path, Path(recording).name)
        click.echo(f"-> {plot_path}", err=True)


def _print_table(res) -> None:
    t = res.track
    lo, hi = float(t.rpm.min()), float(t.rpm.max())
    at = np.linspace(lo, hi, 5)
    idx = [int(np.argmin(np.abs(t.rpm - r))) for r in at]
    click.echo(f"run {lo:,.0f}-{hi:,.0f} rpm, {t.rpm.shape[0]} windows; compensation: {res.compensation}")
    click.echo(f"{'axis':<9} order " + "".join(f"{t.rpm[i]:>17,.0f} rpm" for i in idx))
    for j, a in enumerate(res.axes):
        for k in t.orders:
            v = t.order(k)[:, j]
            cells = "".join(f"{abs(v[i]) * 1e6:>11.2f} um {np.degrees(np.angle(v[i])):>5.0f}°" for i in idx)
            click.echo(f"{a:<9} {k:>4}X {cells}")
    for a, peaks in res.peaks.items():
        if not peaks:
            click.echo(f"{a}: no 1X peak that stands out of the scatter with its half-power band inside the run: "
                       "no critical speed")
        for p in peaks:
            verdict = ("a critical speed" if p.is_critical() else
                       f"critically damped (amplification < {CRITICAL_AMPLIFICATION:g}, API 684)")
            click.echo(f"{a}: 1X peak {p.amplitude * 1e6:.2f} um at {p.rpm:,.0f} rpm, half-power band "
                       f"{p.band_rpm[0]:,.0f}-{p.band_rpm[1]:,.0f} rpm, phase turns {p.phase_change_deg:.0f}°, "
                       f"amplification {p.amplification:.1f}: {verdict}")
    for c in res.criticals:  # the model's critical speeds against the run (API 684)
        row = c.as_dict()
        said = (f"predicted {row['predicted_rpm']:,.0f} rpm (amplification {row['predicted_amplification']:.2f})"
                if c.predicted else "not predicted")
        seen = (f"measured {row['measured_rpm']:,.0f} rpm on {c.axis} (amplification {row['measured_amplification']:.2f})"
                if c.measured else "no peak measured")
        click.echo(f"critical speed: {said}; {seen}: {'pass' if c.passed else 'FAIL'} ({c.rule})")


def phase_lag_deg(vector: np.ndarray) -> np.ndarray:
    """A vector's phase as engineers read it against speed: the lag behind the key-phasor, in
    degrees, unwrapped along the run (it grows through each critical speed instead of jumping at
    +-180), starting within 0..360."""
    lag = -np.degrees(np.unwrap(np.angle(vector)))
    return lag - 360.0 * np.floor(lag[0] / 360.0) if lag.size else lag


def runup_figure(res, out, name: str) -> None:
    """:func:`draw_runup`'s figure written to ``out`` (a path or a binary file, PNG)."""
    plt = pyplot()
    fig = draw_runup(res, name)
    fig.savefig(out, dpi=100, format="png" if not isinstance(out, str) else None)
    plt.close(fig)


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
        dashed = a.endswith("_y")
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
        # down; in the full spectrum each on its own side (a mode whose whirl the model does not give:
        # on both, hollow)
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
