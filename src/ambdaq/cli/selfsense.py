"""``ambdaq selfsense``: Jeon et al.'s flux-linkage angle estimator run offline over recordings."""

from __future__ import annotations

import json

import click

from ..daq.recording import open_recording
from ..workflows.selfsense import CONVERGED_DEG, analyse
from .options import plot_option

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
        from ..figures import save
        from ..figures.selfsense import draw_selfsense

        save(draw_selfsense(results), plot_path)
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


