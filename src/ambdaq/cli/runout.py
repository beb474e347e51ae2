"""``ambdaq runout``: identify sensor runout from recordings and write a coefficient file."""

from __future__ import annotations

import json
import sys

import click
import numpy as np

from ..daq.recording import open_recording
from ..errors import AmbdaqError
from ..workflows.runout import METHODS, check_recordings, identify_recordings, runout_table
from .options import POSITIVE, max_lost_option, plot_option

@click.group("runout")
def command() -> None:
    """Sensor runout: identify it from recordings."""


@command.command("identify")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Coefficient file (JSON).")
@click.option("--harmonics", type=click.IntRange(1, 8), default=6, show_default=True, help="Identify 1X .. NX.")
@click.option("--method", type=click.Choice(sorted(METHODS)), default="fit", show_default=True,
              help="fit: batch least squares; average: angle-domain synchronous averaging (slow roll); "
                   "lms: Ro et al.'s LMS run offline.")
@click.option("--overwrite", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the identified runout as JSON.")
@plot_option("Report image (.png, .pdf, .svg): spectrum, polar plot per harmonic, orbits before and after.")
@max_lost_option
def identify(files, output, harmonics, method, overwrite, as_json, plot_path, max_lost):
    """Identify runout per axis and harmonic from FILES (each at one constant speed).

    \b
    Examples:
      ambdaq runout identify slowroll.mcap -o coef.json
      ambdaq runout identify run_12k.mcap run_24k.mcap run_36k.mcap -o coef.json --plot report.png
    """
    ident = identify_recordings([open_recording(f) for f in files], list(range(1, harmonics + 1)), method,
                                max_lost=max_lost)
    coef = ident.coef
    coef.save(output, overwrite=overwrite)
    if plot_path:
        from ..figures import save  # matplotlib and scipy.signal: only for a figure
        from ..figures.runout import draw_identification

        save(draw_identification(ident), plot_path)
        click.echo(f"-> {plot_path}", err=True)
    for w in ident.warnings:
        click.echo(f"ambdaq: warning: {w}", err=True)
    # u_um: each part's standard uncertainty from the recordings' noise (the Cramer-Rao bound);
    # bound_um: a bound on the error the noise does not cover (MODEL_BOUND); null where not
    # propagated (1X separated from the unbalance over several speeds)
    table = runout_table(coef)
    if as_json:
        click.echo(json.dumps(table, indent=2))
    else:
        click.echo(f"{'axis':<9}" + "".join(f"{f'{k}X um (+-u) / deg':>26}" for k in coef.harmonics))
        for axis, rows in table.items():
            click.echo(f"{axis:<9}" + "".join(
                f"{r['amplitude_um']:>9.3f} ({'-' if r['u_um'] is None else format(r['u_um'], '.3f'):>5}) "
                f"{r['phase_deg']:>7.1f} " for r in rows))
        worst = np.nanmax(ident.model_bound) if np.isfinite(ident.model_bound).any() else float("nan")
        click.echo("u: each part's standard uncertainty from the noise at that harmonic (Cramer-Rao bound); "
                   f"-: not propagated; the model's error beyond it is at most {worst * 1e9:.1f} nm (--json: bound_um)",
                   err=True)
        click.echo(f"-> {output}", err=True)
    sys.stdout.flush()


class CheckFailed(AmbdaqError):
    """``runout check``: the after-recording did not meet the asked reduction (exit 1)."""


@command.command("check")
@click.argument("before", type=click.Path(dir_okay=False))
@click.argument("after", type=click.Path(dir_okay=False))
@click.option("--harmonics", type=click.IntRange(1, 8), default=2, show_default=True, help="Compare 1X .. NX.")
@click.option("--min-db", type=click.FloatRange(min=0), help="Fail (exit 1) unless every harmonic falls this much.")
@click.option("--max-rms", type=POSITIVE,
              help="Fail (exit 1) unless the command error's RMS after is below this, in um.")
@plot_option("Image (.png, .pdf, .svg): command-error orbits and spectra before and after.")
@click.option("--json", "as_json", is_flag=True)
@max_lost_option
def check(before, after, harmonics, min_db, max_rms, plot_path, as_json, max_lost):
    """Prove on a new recording that the command error went down: 1X .. NX and RMS, per axis.

    The command error is what the controller acts on (gap minus feedforward); the gap sensor
    still carries the runout, and its 1X after is shown beside it.

    \b
    Examples:
      ambdaq runout check run.mcap after.mcap
      ambdaq runout check run.mcap after.mcap --min-db 20 --max-rms 5 --plot check.png
    """
    orders = list(range(1, harmonics + 1))
    recs = [open_recording(f) for f in (before, after)]
    result = check_recordings(*recs, orders, min_db=min_db, max_rms_um=max_rms, max_lost=max_lost)
    b, a, rows, failures = result.before, result.after, result.axes, result.failures
    if plot_path:
        from ..figures import save  # matplotlib and scipy.signal: only for a figure
        from ..figures.runout import draw_check

        save(draw_check(*recs, orders), plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps({"before": b, "after": a, "axes": rows, "failures": failures}, indent=2))
    else:
        click.echo(f"command error, before {before} at {b['rpm']:,.0f} rpm, after {after} at {a['rpm']:,.0f} rpm")
        click.echo(f"{'axis':<9}" + "".join(f"{f'{k}X um (dB)':>26}" for k in orders)
                   + f"{'RMS um':>18}{'sensor 1X after':>17}")
        for axis, r in rows.items():
            cells = "".join(f"{h['before_um']:>9.3f} ->{h['after_um']:>7.3f} ({h['change_db']:+6.1f})"
                            for h in r["harmonics"])
            click.echo(f"{axis:<9}{cells}{r['rms_before_um']:>8.2f} ->{r['rms_after_um']:>6.2f}"
                       f"{r['sensor_1x_after_um']:>14.2f} um")
    for note in result.notes:
        click.echo(f"ambdaq: note: {note}", err=True)
    if failures:
        raise CheckFailed("check failed: " + "; ".join(failures))
