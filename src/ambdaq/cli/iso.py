"""``ambdaq iso``: the ISO 14839 evaluations a machine is accepted against (docs/iso.md)."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..analysis.iso14839 import STABILITY_LIMITS, VIBRATION_LIMITS, ZoneLimits, db
from ..errors import BadInputError
from .options import POSITIVE, RangeArg, a2l_option, excited_run_options, excited_runs, max_lost_option, plot_option


class LimitsArg(click.ParamType):
    """``AB,BC,CD``: three increasing zone boundaries, each a number (a gain, a fraction of Cmin) or,
    for a gain, in dB (``9.5dB``)."""

    name = "AB,BC,CD"

    def convert(self, value, param, ctx):
        if isinstance(value, ZoneLimits):
            return value
        try:
            parts = [p.strip().lower() for p in str(value).split(",")]
            if len(parts) != 3:
                raise ValueError("three boundaries")
            gains = [10 ** (float(p[:-2]) / 20) if p.endswith("db") else float(p) for p in parts]
            return ZoneLimits(*gains)
        except (ValueError, OverflowError) as err:
            self.fail(f"{value!r}: expected three increasing boundaries A/B,B/C,C/D, e.g. 3,4,5 or 9.5dB,12dB,14dB "
                      f"({err})", param, ctx)


@click.group("iso")
def command() -> None:
    """ISO 14839 evaluations: stability margin (part 3), vibration zones (part 2)."""


@command.command("stability")
@click.argument("recordings", nargs=-1, type=click.Path(dir_okay=False))
@click.option("--device", metavar="URL", help="Measure on this controller (sim://spindle, serial://..., xcp+...).")
@a2l_option
@click.option("--rpm", "speeds", type=click.FloatRange(min=0, max=200_000), multiple=True, metavar="RPM",
              help="A speed to measure at (repeatable; 0: standstill); set through the controller's speed parameter.")
@excited_run_options
@click.option("--band", type=RangeArg("LO:HI", "Hz", "10:2000"), help="Band searched for the peak, Hz; default: every measured frequency.")
@click.option("--limits", type=LimitsArg(), default=",".join(f"{v:g}" for v in STABILITY_LIMITS.as_list()), show_default=True,
              help="Peak |Gs| at the zone boundaries A/B, B/C, C/D (gains, or e.g. 9.5dB,12dB,14dB).")
@click.option("--min-coherence", type=click.FloatRange(0.0, 1.0), default=0.9, show_default=True,
              help="Least coherence at the peak for a grade.")
@click.option("--input", "input_axis", metavar="AXIS",
              help="The excited axis of RECORDINGS that do not say it (another tool's); ambdaq's own say it.")
@click.option("--compare", "design_file", type=click.Path(dir_okay=False),
              help="A controller design (controller design): each graded peak beside its prediction; exit 1 where "
                   "one is more than 0.5 dB from it.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Results file (JSON).")
@click.option("--overwrite", is_flag=True)
@plot_option("Sensitivity functions with the zone limits (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the results (without curves) as JSON.")
@click.option("-q", "--quiet", is_flag=True, help="No progress lines.")
@max_lost_option
def stability(recordings, device, description, speeds, axes, amplitude, duration, settle, runs_dir, resolution, band, limits,
              min_coherence, input_axis, design_file, output, overwrite, plot_path, as_json, quiet, max_lost):
    """ISO 14839-3: peak of the sensitivity function per axis and speed, and its zone.

    Measures with --device (white noise at the sensor summing point, one axis at a time, at each
    --rpm), or grades RECORDINGS made with the test signal on (frf measure). A grade is given only
    where the coherence supports it; otherwise the axis is "not measured", with the reason.

    \b
    Example:
      ambdaq iso stability --device serial:///dev/pts/5 --rpm 0 --rpm 20000 -o stability.json
      ambdaq iso stability gs_*.mcap -o stability.json --limits 9.5dB,12dB,14dB
    """
    from ..workflows import iso_stability as iso
    from ..workflows.controller_design import COMPARE_TOLERANCE_DB, compare, load_design

    if input_axis and device:
        raise BadInputError("--input names the excited axis of recordings; with --device the runs say it (--axes)")
    design = load_design(design_file) if design_file else None  # a broken file fails before the measurement
    out = Path(output)
    paths = excited_runs("iso stability", recordings, device, description, list(speeds) or None, axes, amplitude,
                         duration, settle, runs_dir, out, overwrite, quiet)
    from ..daq.recording import open_recording

    runs = iso.evaluate([open_recording(p) for p in paths], resolution_hz=resolution, band_hz=band, limits=limits,
                        min_coherence=min_coherence, input_axis=input_axis, max_lost=max_lost)
    iso.check_speeds(runs, list(speeds) or None)
    iso.save(out, runs, limits=limits, min_coherence=min_coherence, resolution_hz=resolution, overwrite=overwrite)
    if plot_path:
        from ..figures import save
        from ..figures.iso import draw_stability

        save(draw_stability([{"speed_rpm": r.speed_rpm, "axis": r.axis, "freq_hz": r.freq_hz, "gs": r.gs,
                           "coherence": r.coherence, "peak_db": r.grade.peak_db, "zone": r.grade.zone} for r in runs],
                             limits), plot_path)
    compared = (None if design is None else
                compare(design, [(r.axis, r.speed_rpm, r.grade.peak_db, r.grade.zone) for r in runs]))
    if as_json:
        click.echo(json.dumps({"standard": "ISO 14839-3", "limits_peak_gs": limits.as_list(),
                               "runs": [r.as_dict(curves=False) for r in runs]}
                              | ({"compared": {"design": Path(design_file).name, "tolerance_db": COMPARE_TOLERANCE_DB,
                                               "rows": compared}} if design is not None else {}), indent=2))
    else:
        click.echo(stability_table(runs, limits))
        if compared is not None:
            click.echo(f"against {Path(design_file).name}'s prediction (within {COMPARE_TOLERANCE_DB:g} dB):")
            for c in compared:
                click.echo(f"{round(c['speed_rpm']):>10,}  {c['axis']:<9} measured {c['measured_db']:6.2f} dB  predicted "
                           f"{c['predicted_db']:6.2f} dB  {c['difference_db']:+.2f} dB  {'ok' if c['within'] else 'NOT AS PREDICTED'}")
    click.echo(f"-> {out}" + (f", {plot_path}" if plot_path else ""), err=True)
    ungraded = [r for r in runs if r.grade.zone is None]
    if ungraded:  # the results are kept, but an acceptance run with an ungraded axis has not passed
        first = ungraded[0]
        raise BadInputError(f"{len(ungraded)} of {len(runs)} runs not graded; {first.axis} at {round(first.speed_rpm):,} rpm: "
                            f"{first.grade.reason}")
    off = [c for c in compared or [] if not c["within"]]
    if off:
        from ..errors import AmbdaqError

        raise AmbdaqError(f"{len(off)} of {len(compared)} peaks are not as {Path(design_file).name} predicted: "
                          f"{off[0]['axis']} at {round(off[0]['speed_rpm']):,} rpm measured {off[0]['measured_db']:.2f} dB, "
                          f"predicted {off[0]['predicted_db']:.2f} dB")


def stability_table(runs, limits: ZoneLimits) -> str:
    """The results as a table for the terminal."""
    bounds = "  ".join(f"{z} < {v:.2f} ({db(v):.1f} dB)" for z, v in zip("ABC", limits.as_list()))
    lines = [f"ISO 14839-3 peak sensitivity |Gs| (zones: {bounds} <= D)",
             f"{'speed rpm':>10}  {'axis':<9} {'peak |Gs|':>9} {'dB':>6} {'at Hz':>7} {'coherence':>9}  zone"]
    for r in runs:
        g = r.grade
        if np.isnan(g.peak):
            lines.append(f"{round(r.speed_rpm):>10,}  {r.axis:<9} not measured: {g.reason}")
            continue
        zone = g.zone if g.zone else f"not measured: {g.reason}"
        lines.append(f"{round(r.speed_rpm):>10,}  {r.axis:<9} {g.peak:>9.3f} {g.peak_db:>6.2f} {g.peak_hz:>7g} "
                     f"{g.coherence_at_peak:>9.3f}  {zone}")
    return "\n".join(lines)


@command.command("vibration")
@click.argument("recordings", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cmin", type=POSITIVE, metavar="UM",
              help="Minimum clearance (the touchdown bearings' radial clearance), um; default: what the recording's "
                   "controller reports.")
@click.option("--coefficients", type=click.Path(dir_okay=False),
              help="Runout coefficient file (runout identify): the sensors' runout is taken out first.")
@click.option("--band-rpm", type=POSITIVE, default=1000.0, show_default=True, help="Width of the speed bands, rpm.")
@click.option("--limits", type=LimitsArg(), default=",".join(f"{v:g}" for v in VIBRATION_LIMITS.as_list()),
              show_default=True, help="Displacement per Cmin at the zone boundaries A/B, B/C, C/D.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Results file (JSON).")
@click.option("--overwrite", is_flag=True)
@plot_option("Orbit maxima per speed band against the zone limits (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON.")
@max_lost_option
def vibration(recordings, cmin, coefficients, band_rpm, limits, output, overwrite, plot_path, as_json, max_lost):
    """ISO 14839-2: the rotor's vibration at each radial bearing against Cmin, per speed band.

    Graded: per 0.1 s window, the orbit's largest excursion from its mean centre; each band takes
    its worst window (docs/iso.md). RECORDINGS: a run-up, a coast-down or steady runs.

    \b
    Example:
      ambdaq iso vibration runup.mcap --coefficients runout.json
      ambdaq iso vibration run_*.mcap --cmin 150 --band-rpm 5000 --json
    """
    from ..daq.recording import open_recording
    from ..documents.sealed import write_sealed
    from ..workflows import iso_vibration as iso

    grades, info = iso.evaluate([open_recording(p) for p in recordings], cmin_m=None if cmin is None else cmin * 1e-6,
                                band_rpm=band_rpm, coefficients=Path(coefficients) if coefficients else None,
                                limits=limits, max_lost=max_lost)
    for note in info["notes"] + ([info["runout_removed"]["means"]] if info["runout_removed"] else []):
        click.echo(f"ambdaq: note: {note}", err=True)
    doc = {**info, "bands": [g.as_dict() for g in grades]}
    if output:
        write_sealed(output, {"format": "ambdaq-iso-vibration", "version": 1, **doc}, overwrite=overwrite)
    if as_json:
        click.echo(json.dumps(doc, indent=2))
    else:
        bounds = "  ".join(f"{z} < {v:g} Cmin ({v * info['cmin_um']:.0f} um)" for z, v in zip("ABC", limits.as_list()))
        taken = "runout taken out" if info["runout_removed"] else "runout not taken out (no --coefficients)"
        click.echo(f"ISO 14839-2 vibration, Cmin {info['cmin_um']:g} um ({info['cmin_from']}), {taken}\n"
                   f"zones: {bounds} <= D\n"
                   f"{'bearing':<8} {'band rpm':>17} {'windows':>7} {'max um':>8} {'/Cmin':>6}  zone  {'at rpm':>8}")
        for g in grades:
            click.echo(f"{g.bearing:<8} {g.rpm_from:>8,.0f}-{g.rpm_to:<8,.0f} {g.windows:>7} {g.max_um:>8.2f} "
                       f"{g.ratio:>6.3f}  {g.zone:<4}  {g.at_rpm:>8,.0f}")
        worst = max(grades, key=lambda g: g.ratio)
        click.echo(f"worst: {worst.bearing} {worst.max_um:.2f} um = {worst.ratio:.3f} Cmin at {worst.at_rpm:,.0f} rpm, "
                   f"zone {worst.zone}")
    if plot_path:
        from ..figures import save
        from ..figures.iso import draw_vibration

        save(draw_vibration(doc["bands"], limits, info["cmin_um"]), plot_path)
    if output or plot_path:
        click.echo(f"-> {', '.join(p for p in (output, plot_path) if p)}", err=True)
