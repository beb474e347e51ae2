"""``ambdaq selfsense``: Jeon et al.'s flux-linkage angle estimator run offline over recordings."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..daq.recording import open_recording
from ..workflows.selfsense import CONVERGED_DEG, analyse
from .figures import plot_option, pyplot

@click.command("selfsense")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--initial-error", "initial_error_deg", type=float, default=8.0, show_default=True, metavar="DEG",
              help="The estimator starts this far from the encoder's angle (mechanical degrees).")
@click.option("--settle", "settle_s", type=click.FloatRange(min=0), default=1.0, show_default=True, metavar="SECONDS",
              help="Steady-state statistics start after this, and after the error has stayed below 1 deg if it does.")
@click.option("--resistance", type=float, metavar="OHM", help="Coil resistance the estimator assumes (default: calibration).")
@click.option("--inductance", type=float, metavar="H", help="Coil inductance the estimator assumes (default: calibration).")
@click.option("--emf-constant", type=float, metavar="V_S", help="k_e B sin(2 pi/5) (default: calibration).")
@click.option("--sweep", is_flag=True, help="Also run from initial errors -85..145 deg and compare with the Lyapunov bound (eq. 18).")
@plot_option("Figure like Jeon et al. Fig. 5-7.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def command(files, initial_error_deg, settle_s, resistance, inductance, emf_constant, sweep, plot_path, as_json):
    """Rotor angle from the coil voltages (Jeon et al.'s flux-linkage estimator, its equations 10-13)
    over recordings, against the encoder.

    Each FILE holds six coil voltages (/coil/voltage), currents (/coil/current) and an encoder
    (/motor/encoder), e.g. from `ambdaq sim generate --profile lorentz`.  Reports when the error
    stays below 1 deg, and its steady-state mean, mean absolute value and spread.  With several
    files at different speeds the figure shows the error's mean and spread against speed (Fig. 7).

    \b
    Example:
      ambdaq sim generate --profile lorentz --rpm 0:100:2 --duration 6 -o start.mcap
      ambdaq selfsense start.mcap --sweep --plot start.png
    """
    overrides = {"resistance": resistance, "inductance": inductance, "emf_constant": emf_constant}
    results = [analyse(open_recording(f), initial_error_deg, settle_s, overrides, sweep) for f in files]
    if plot_path:
        _plot(results, plot_path)
    for r in results:
        r.pop("_series")
    if as_json:
        click.echo(json.dumps(results if len(results) > 1 else results[0], indent=2))
        return
    for r in results:
        if r["converged_s"] is None:
            conv = f"the error is still {CONVERGED_DEG:g} deg or more at the end of the recording"
        else:
            conv = f"the error stays below {CONVERGED_DEG:g} deg after {r['converged_s']:.3f} s"
        click.echo(f"{r['file']}: {r['speed_rpm']['start']:g} -> {r['speed_rpm']['end']:g} rpm, "
                   f"from {r['initial_error_deg']:g} deg {conv}")
        if "steady" in r:
            s = r["steady"]
            click.echo(f"  steady from {s['from_s']:g} s at {s['speed_rpm']:g} rpm: mean {s['mean_deg']:+.3f} deg, "
                       f"mean |error| {s['mean_abs_deg']:.3f} deg, std {s['std_deg']:.3f} deg, max {s['max_abs_deg']:.3f} deg")
        if "sweep" in r:
            sw = r["sweep"]
            conv = [e for e, c in zip(sw["initial_deg"], sw["converges"]) if c]
            click.echo(f"  sweep: converges from {min(conv):g} to {max(conv):g} deg (steps of 5); Lyapunov bound (eq. 18) "
                       f"({sw['lyapunov_deg'][0]:g}, {sw['lyapunov_deg'][1]:g}) deg up to {sw['lyapunov_max_rpm']:,} rpm: "
                       + ("agrees" if sw["agrees"] else "DISAGREES"))


def _plot(results: list[dict], path: str) -> None:
    plt = pyplot()
    fig = draw_selfsense(results)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def draw_selfsense(results: list[dict]):
    """Jeon et al. Fig. 5-7 from :func:`_analyse`'s results: (a) the encoder's and the estimate's
    angle (of the first file: with several, their sawtooths would lie on each other), (b) the
    angle error of every file, with several files the steady error against speed (Fig. 7), and
    with ``--sweep`` the convergence region: the final error against the initial one, beside the
    Lyapunov bound (eq. 18)."""
    plt = pyplot()
    several = len(results) > 1
    sweeps = [r for r in results if "sweep" in r]
    rows = 2 + several + bool(sweeps)
    fig, axes = plt.subplots(rows, 1, figsize=(9, 3.1 * rows), constrained_layout=True)
    first = results[0]
    t, true, est, _err, _ = first["_series"]
    axes[0].plot(t, np.rad2deg(true) % 360, lw=0.8, label="encoder")
    axes[0].plot(t, np.rad2deg(est) % 360, lw=0.8, ls="--", label="estimate")
    axes[0].set_ylabel("angle (deg)")
    axes[0].set_title("(a) measured and estimated rotor angle (Fig. 5a, 6a)"
                      + (f", {Path(first['file']).name}" if several else ""))
    axes[0].legend(fontsize=7, loc="upper right")
    for r in results:
        t, _true, _est, err, _ = r["_series"]
        axes[1].plot(t, err, lw=0.6, label=Path(r["file"]).name)
    axes[1].set_ylabel("error (deg)")
    axes[1].set_xlabel("time (s)")
    axes[1].axhline(CONVERGED_DEG, color="k", lw=0.5, ls=":")
    axes[1].axhline(-CONVERGED_DEG, color="k", lw=0.5, ls=":")
    axes[1].set_title("(b) angle error (Fig. 5b, 6b)")
    if several:
        axes[1].legend(fontsize=7, loc="upper right")
        steady = sorted((r["steady"]["speed_rpm"], r["steady"]["mean_deg"], r["steady"]["std_deg"])
                        for r in results if "steady" in r)
        ax = axes[2]
        if steady:
            sp, mean, std = map(np.array, zip(*steady))
            ax.plot(sp, mean, "o-", label="mean")
            ax.plot(sp, std, "s-", label="standard deviation")
            ax.legend(fontsize=7)
        ax.set(xlabel="speed (rpm)", ylabel="error (deg)", title="(c) steady-state angle error against speed (Fig. 7)")
    if sweeps:
        ax = axes[-1]
        sw = sweeps[0]["sweep"]
        lo, hi = sw["lyapunov_deg"]
        ax.axvspan(lo, hi, color="C2", alpha=0.15, label=f"Lyapunov bound (eq. 18): {lo:g} to {hi:g} deg")
        initial, final = np.array(sw["initial_deg"]), np.array(sw["final_deg"])
        ok = np.array(sw["converges"])
        ax.plot(initial[ok], final[ok], "o", color="C2", ms=4, label="converged (final |error| < 1 deg)")
        ax.plot(initial[~ok], final[~ok], "x", color="C3", ms=5, label="did not converge")
        ax.set(xlabel="initial error (deg)", ylabel="final error (deg)",
               title=f"({'d' if several else 'c'}) convergence region, {Path(sweeps[0]['file']).name}")
        ax.legend(fontsize=7, loc="best")
    for ax in axes:
        ax.grid(True, lw=0.3)
    return fig
