"""``ambdaq frf``: measure the loop's frequency response with the controller's excitation input."""

from __future__ import annotations

import json

import click

from ..errors import BadInputError
from ..workflows.frf import COHERENT, estimate_responses, excited_device, summarize
from .options import (a2l_option, excitation_option, max_lost_option, output_options, plot_option, report_options,
                      speed_option,
                      speed_restored_note)
from .record import run_recording
from ..roles import ERROR, FF


@click.group("frf")
def command() -> None:
    """Frequency responses: excite the loop, record, estimate H1 with coherence."""


@command.command("measure")
@click.option("--device", required=True, metavar="URL", help="The AMB controller (or sim://spindle).")
@excitation_option
@click.option("--duration", type=click.FloatRange(min=1), default=20.0, show_default=True, metavar="SECONDS")
@speed_option
@a2l_option
@output_options
@report_options
def measure(device, excitation, duration, speed, description, out, quiet, as_json):
    """Record with the controller's test signal on (one axis), then switch it off.

    \b
    Example:
      ambdaq frf measure --device serial:///dev/pts/5 --excite front_x:2 --duration 20 -o frf_fx.mcap
      ambdaq frf estimate frf_fx.mcap -o loop.frf.json
    """
    if excitation is None:
        raise BadInputError("frf measure needs --excite AXIS:AMPLITUDE[:HZ] (e.g. front_x:2 for 2 um RMS white noise)")
    # --rpm: the speed the controller had is set again, however the run ends
    with excited_device(device, excitation, speed=speed, description=description,
                        on_restore=speed_restored_note(quiet)) as (sources, excited):
        run_recording(sources, out, duration=duration, quiet=quiet, as_json=as_json, records=excited.records())
    if excited.switch_off_problem:
        click.echo(f"ambdaq: warning: could not switch the excitation off: {excited.switch_off_problem}", err=True)
    elif not quiet:
        click.echo("test signal switched off", err=True)


@command.command("estimate")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Frequency-response file (JSON).")
@click.option("--resolution", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Frequency step, Hz (10 matches the LMS phase table).")
@click.option("--input", "input_axis", help="The excited axis; default: the one axis whose input is not zero.")
@click.option("--input-topic", default=FF, show_default=True, help="Where the test signal is recorded.")
@click.option("--output-topic", default=ERROR, show_default=True,
              help="The response: /amb/error (the LMS loop), /amb/gap (base-motion secondary path).")
@click.option("--overwrite", is_flag=True)
@plot_option("Bode plot and coherence (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print a summary as JSON.")
@max_lost_option
def estimate(files, output, resolution, input_axis, input_topic, output_topic, overwrite, plot_path, as_json, max_lost):
    """H1 frequency response with coherence, from each recording's excited axis to every axis.

    The input is the feedforward input /amb/ff (where the controller adds its test signal), the
    output the command error /amb/error: T_aa on the diagonal is what the phase-compensated LMS
    needs (ambdaq lms schedule --frf).

    \b
    Example:
      ambdaq frf estimate frf_fx.mcap frf_fy.mcap frf_rx.mcap frf_ry.mcap frf_ax.mcap -o loop.frf.json
    """
    from ..daq.recording import open_recording

    frf = estimate_responses([open_recording(f) for f in files], resolution, input_axis, input_topic, output_topic,
                             max_lost=max_lost)
    frf.save(output, overwrite=overwrite)
    summary = summarize(frf)
    if plot_path:
        from ..figures import save
        from ..figures.frf import draw_bode

        save(draw_bode(frf), plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        span = f"{frf.freq_hz[0]:g}-{frf.freq_hz[-1]:,.0f} Hz"
        for axis, s in summary.items():
            if s["coherent_band_hz"] is None:
                click.echo(f"{axis}: {s['points']} points, coherence never reaches {COHERENT:g} (median "
                           f"{s['median_coherence']:.3f} over {span}): the input explains too little of the output "
                           f"({s['source']})")
                continue
            lo, hi = s["coherent_band_hz"]
            click.echo(f"{axis}: {s['points']} points, coherence >= {COHERENT:g} from {lo:g} to {hi:,.0f} Hz (median "
                       f"{s['median_coherence_in_band']:.3f} there, {s['median_coherence']:.3f} over {span}); peak |H| "
                       f"there {s['peak_gain']:.3g} {frf.unit} at {s['peak_hz']:g} Hz  ({s['source']})")
        click.echo(f"-> {output}", err=True)


