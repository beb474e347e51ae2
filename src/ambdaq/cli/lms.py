"""``ambdaq lms``: Ro et al.'s LMS feedforward inside the loop: convergence map, sign flips, schedules."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..workflows.lms_design import convergence_map, schedule
from .options import POSITIVE, plot_option

plant_option = click.option("--plant", default="bearings", show_default=True, metavar="PLANT",
                            help="Loop to design on: the spindle's front, rear, bearings, rig; tf:NUM/DEN; ss:FILE (docs/lms.md).")


@click.group("lms")
def command() -> None:
    """LMS runout feedforward design (Ro et al.): convergence map, sign flips, step-size schedules."""


@command.command("map")
@plant_option
@click.option("--harmonic", type=click.IntRange(1, 8), default=1, show_default=True)
@click.option("--rpm-max", type=click.FloatRange(min=1000), default=60000.0, show_default=True)
@click.option("--mu-max", type=POSITIVE, default=0.01, show_default=True,
              help="The map spans -MU_MAX .. +MU_MAX.")
@click.option("--compensated", is_flag=True, help="Map the phase-compensated update instead of Ro et al.'s.")
@plot_option("Write the map as an image (Fig. 5).")
@click.option("--json", "as_json", is_flag=True)
def map_command(plant, harmonic, rpm_max, mu_max, compensated, plot_path, as_json):
    """Where the LMS converges over speed and step size, and where the sign of mu must flip.

    \b
    Examples:
      ambdaq lms map --plant front --plot fig5.png
      ambdaq lms map --plant rig --harmonic 2 --json
    """
    found = convergence_map(plant, harmonic=harmonic, rpm_max=rpm_max, mu_max=mu_max, compensated=compensated,
                            radius=bool(plot_path))
    report, rpm = found.report, found.rpm
    if as_json:
        click.echo(json.dumps(report, indent=2))
    else:
        for name, rep in report["loops"].items():
            flips = ", ".join(f"{f:,.0f}" for f in rep["sign_flips_rpm"])
            where = f"flips at {flips} rpm" if flips else f"never flips ({rpm[0]:,.0f}-{rpm[-1]:,.0f} rpm)"
            click.echo(f"{name}: {harmonic}X, {'phase-compensated' if compensated else 'Ro et al. update'}: "
                       f"sign of mu {where}")
            if rep["no_sign_converges_rpm"]:
                lo, hi = rep["no_sign_converges_rpm"]
                click.echo(f"  no sign of |mu| = {mu_max / 10:g} converges between {lo:,.0f} and {hi:,.0f} rpm")
    if plot_path:
        from ..figures import save
        from ..figures.lms import draw_map

        save(draw_map(found.radius, rpm, found.mu, harmonic, plant, compensated), plot_path, dpi=110)
        click.echo(f"-> {plot_path}", err=True)


@command.command("schedule")
@plant_option
@click.option("--mu", type=POSITIVE, default=0.001, show_default=True,
              help="Step size magnitude.")
@click.option("--dead-band", type=click.FloatRange(min=0), default=500.0, show_default=True,
              help="Hold the weights this many rpm either side of a sign flip (Ro et al. update).")
@click.option("--harmonics", type=click.IntRange(1, 8), default=6, show_default=True, help="Schedule 1X .. NX.")
@click.option("--compensated", is_flag=True,
              help="Phase-compensated update: one positive mu at every speed, with the loop's inverse phase.")
@click.option("--frf", "frf_file", type=click.Path(dir_okay=False),
              help="Take the loop's phase from this measured frequency response (ambdaq frf estimate; "
                   "every axis excited) instead of the plant model; implies --compensated.")
@click.option("--weights", "weights_file", type=click.Path(dir_okay=False),
              help="Start the LMS from this coefficient file's weights (e.g. from runout identify).")
@click.option("--rpm-max", type=click.FloatRange(min=1000), default=60000.0, show_default=True)
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Coefficient file to write.")
@click.option("--overwrite", is_flag=True)
def schedule_command(plant, mu, dead_band, harmonics, compensated, frf_file, weights_file, rpm_max, output,
                     overwrite):
    """Write a coefficient file whose LMS step-size schedule converges on the plant's map.

    \b
    Examples:
      ambdaq lms schedule --plant rig --weights coef.json -o coef_lms.json
      ambdaq lms schedule --plant rig --compensated --mu 0.002 -o coef_lms.json
      ambdaq lms schedule --plant rig --frf loop.frf.json --mu 0.002 -o coef_lms.json   # measured phase
    """
    coef = schedule(plant, mu=mu, dead_band=dead_band, harmonics=harmonics, compensated=compensated,
                    frf_file=frf_file, weights_file=weights_file, rpm_max=rpm_max)
    rows, compensated = coef.lms_schedule, coef.source["lms_design"]["compensated"]
    coef.save(output, overwrite=overwrite)
    click.echo(f"{len(rows)} schedule rows for 1X..{harmonics}X on plant {plant}"
               f"{' (phase-compensated)' if compensated else ''} -> {Path(output)}")
    for k in range(1, min(harmonics, 2) + 1):
        for r in rows:
            if r[0] == k:
                click.echo(f"  {k}X {r[1]:>7,.0f} .. {r[2]:>7,.0f} rpm  mu {r[3]:+g}")


@command.command("runup")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--seconds", type=click.FloatRange(min=1), default=10.0, show_default=True, help="Ramp 0 -> 50,000 rpm.")
@click.option("--speeds", default="3000,10000,12000,20000,30000,50000", show_default=True,
              help="Constant speeds (rpm) for the time to converge.")
@click.option("--json", "as_json", is_flag=True)
def runup_command(files, seconds, speeds, as_json):
    """Compare coefficient files (e.g. a sign-switched and a phase-compensated schedule) on the
    simulated spindle: command error over a 0 -> 50,000 rpm run-up, and time to converge.

    \b
    Example:
      ambdaq lms schedule --plant rig -o sign.json
      ambdaq lms schedule --plant rig --compensated -o comp.json
      ambdaq lms runup sign.json comp.json
    """
    from ..studies.lms_runup import compare

    report, runs, conv = compare(list(files), seconds=seconds, speeds=[float(s) for s in speeds.split(",")])
    rpms, bands = [float(s) for s in speeds.split(",")], report["bands_rpm"]
    if as_json:  # never converging is null
        report["time_to_converge_s"] = {n: {r: (None if np.isinf(t) else t) for r, t in c.items()}
                                        for n, c in conv.items()}
        click.echo(json.dumps(report, indent=2))
        return
    click.echo(f"run-up 0 -> 50,000 rpm in {seconds:g} s: worst radial |1X| / |2X| / RMS of the command error, um")
    click.echo(f"{'band (rpm)':<16}" + "".join(f"{r.name[:24]:>26}" for r in runs))
    for i, (lo, hi) in enumerate(bands):
        cells = "".join(f"{'%.2f / %.2f / %.2f' % tuple(report['runs'][r.name][i]):>26}" for r in runs)
        click.echo(f"{f'{lo}-{min(hi, 50000)}':<16}{cells}")
    click.echo("time from zero weights until 1X stays 20 dB below feedforward off, s (inf: never)")
    click.echo(f"{'rpm':<16}" + "".join(f"{n[:24]:>26}" for n in conv))
    for r in rpms:
        click.echo(f"{r:<16,.0f}" + "".join(f"{conv[n][str(int(r))]:>26.1f}" for n in conv))
