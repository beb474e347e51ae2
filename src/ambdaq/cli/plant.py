"""``ambdaq plant``: the plant of a levitated machine, measured in closed loop (docs/tuning.md)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..errors import BadInputError
from .options import a2l_option, excited_run_options, excited_runs, max_lost_option, plot_option


@click.group("plant")
def command() -> None:
    """The machine's plant, from the controller's output to the gap: measured in closed loop."""


@command.command("identify")
@click.argument("recordings", nargs=-1, type=click.Path(dir_okay=False))
@click.option("--device", metavar="URL", help="Measure on this controller (serial://..., xcp+..., sim://flexible).")
@a2l_option
@click.option("--rpm", type=click.FloatRange(min=0, max=200_000), metavar="RPM",
              help="The speed to measure at, set through the controller's speed parameter; default: the present one.")
@excited_run_options
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Plant file (sealed JSON).")
@click.option("--overwrite", is_flag=True)
@plot_option("Measured plant per axis with its 95 % band, sensitivity and coherence (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option("-q", "--quiet", is_flag=True, help="No progress lines.")
@max_lost_option
def identify(recordings, device, description, rpm, axes, amplitude, duration, settle, runs_dir, resolution, output,
             overwrite, plot_path, as_json, quiet, max_lost):
    """The plant P (controller output, V, to gap, m) per axis and across axes, with its random error,
    and the sensitivity S and complementary sensitivity T per axis, measured in closed loop.

    The test signal is white noise at the sensor summing point (ISO 14839-3), one axis at a time;
    the plant is the joint input-output estimate P = H_RY H_RU^-1, both responses referred to the
    test signal, which the feedback and the sensor noise are not correlated with (the direct
    estimate from the controller's output is biased towards the inverse of the controller).
    Measures with --device, or takes RECORDINGS made so (iso stability --runs DIR keeps them).

    \b
    Example:
      ambdaq plant identify --device serial:///dev/pts/5 --duration 10 -o plant.json --plot plant.png
      ambdaq plant identify runs/gs_*.mcap -o plant.json --json
    """
    from ..workflows.plant_identification import identify as identify_plant

    out = Path(output)
    paths = excited_runs("plant identify", recordings, device, description, None if rpm is None else [rpm], axes,
                         amplitude, duration, settle, runs_dir, out, overwrite, quiet)
    from ..daq.recording import open_recording

    measured = identify_plant([open_recording(p) for p in paths], resolution_hz=resolution, max_lost=max_lost)
    measured.save(out, overwrite=overwrite)
    if plot_path:
        from ..figures import save
        from ..figures.plant import draw_plant

        save(draw_plant(measured), plot_path)
    if as_json:
        click.echo(json.dumps(measured.as_dict(), indent=2))
    else:
        click.echo(f"plant at {measured.speed_rpm:,.0f} rpm over {', '.join(measured.axes)} "
                   f"({len(measured.freq_hz)} points of {measured.freq_hz[1] - measured.freq_hz[0]:g} Hz)")
        for row in measured.rows():
            band = row["plant_coherent_band_hz"]
            click.echo(f"  {row['axis']:<8} S peak {row['sensitivity_peak_db']:5.1f} dB at {row['sensitivity_peak_hz']:6.0f} Hz"
                       f"  plant coherent {'-' if band is None else f'{band[0]:g}-{band[1]:g} Hz'}"
                       f"  resonances {', '.join(f'{f:g}' for f in row['plant_resonances_hz']) or '-'} Hz")
    click.echo(f"-> {out}" + (f", {plot_path}" if plot_path else ""), err=True)


@command.command("fit")
@click.argument("plant_file", type=click.Path(dir_okay=False))
@click.option("--axes", help="Comma-separated axes to fit; default: every axis of the plant file.")
@click.option("--sample-rate", type=click.FloatRange(min=1.0), default=10_000.0, show_default=True,
              help="The controller's rate the plant was measured at, Hz (the model is held over its period).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Model file (sealed JSON).")
@click.option("--overwrite", is_flag=True)
@plot_option("Measured and fitted plant side by side, per axis (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the parameters with their standard deviations as JSON.")
def fit(plant_file, axes, sample_rate, output, overwrite, plot_path, as_json):
    """A parametric model of each axis's plant, with the covariance of its parameters: rigid-body
    modes (their unstable poles), bending modes (frequency, damping, residue), the amplifier's
    bandwidth and damping, the delay; fitted to the trusted points of PLANT_FILE (plant identify),
    weighted by their random error.

    \b
    Example:
      ambdaq plant fit plant.json -o model.json --plot fit.png
    """
    import numpy as np

    from ..workflows.plant_fit import STD_HOLDS, fit_file

    out = Path(output)
    if out.exists() and not overwrite:
        raise BadInputError(f"{out} exists: choose another -o or pass --overwrite")
    measured, fitted = fit_file(plant_file, 1.0 / sample_rate, [a.strip() for a in axes.split(",")] if axes else None)
    fitted.save(out, overwrite=overwrite)
    if plot_path:
        from ..figures import save
        from ..figures.plant import draw_plant

        shown = [a for a in measured.axes if a in fitted.responses]
        model = np.stack([fitted.response(a, measured.freq_hz) for a in shown], axis=1)
        save(draw_plant(measured.subset(shown), model), plot_path)
    if as_json:
        click.echo(json.dumps(fitted.as_dict(), indent=2))
    else:
        f = fitted.fit
        click.echo(f"{', '.join(f.axes)}: {f.points} points, reduced chi-square {f.chi2_reduced:.2f}")
        for row in fitted.rows():
            click.echo(f"  {row['parameter']:<26} {row['value']:12.5g} +- {row['std']:.3g}")
        click.echo(f"warning: the deviations (+-) hold {STD_HOLDS}", err=True)
    shapes = fitted.mode_shapes
    if shapes.get("unsettled"):
        click.echo(f"warning: the {shapes['constraints']} mode-shape constraints did not settle in 20 steps: each "
                   "element's residues are stated on their own, with their wider deviations", err=True)
    elif shapes and not shapes["imposed"]:
        click.echo(f"warning: the modes' residues are not one shape per mode over each plane's bearings (Wald "
                   f"chi-square {shapes['wald_chi2']:g} over {shapes['constraints']} constraints, beyond "
                   f"{shapes['limit']:g}): each element's residues are stated on their own, with their wider "
                   "deviations", err=True)
    elif shapes and not as_json:
        click.echo(f"mode shapes: {shapes['constraints']} constraints imposed (Wald chi-square "
                   f"{shapes['wald_chi2']:g}, at most {shapes['limit']:g})")
    click.echo(f"-> {out}" + (f", {plot_path}" if plot_path else ""), err=True)


@command.command("gains")
@click.argument("plant_file", type=click.Path(dir_okay=False))
@click.option("--machine", default="flexible", show_default=True,
              help="The rotor model the bearings' gains are fitted with (machines/).")
@click.option("--json", "as_json", is_flag=True, help="Print the gains with their standard deviations as JSON.")
def gains(plant_file, machine, as_json):
    """Each magnetic bearing's actuator gain ki*ka (force per controller volt, N/V) and negative
    stiffness kx (N/m), fitted to the standstill plant of PLANT_FILE (plant identify) with the
    machine's rotor model, with their standard deviations and the machine's own values beside.

    \b
    Example:
      ambdaq plant gains plant.json --machine flexible
    """
    from ..machines.flexible_spindle import flexible_machine
    from ..workflows.bearing_gains import fit_bearing_gains
    from ..workflows.plant_identification import load_measurement

    params, _top = flexible_machine(machine)
    result = fit_bearing_gains(load_measurement(plant_file), params, machine)
    if as_json:
        click.echo(json.dumps(result.as_dict(), indent=2))
        return
    click.echo(f"{machine}: {result.points} points below {result.band_hz:.0f} Hz, reduced chi-square "
               f"{result.chi2_reduced:.2f}")
    for row in result.rows():
        click.echo(f"  {row['parameter']:<12} {row['value']:12.5g} +- {row['std']:<9.3g} {row['unit']:<4} "
                   f"(machine data {row['machine']:.5g}: x{row['ratio']:.4f})")
