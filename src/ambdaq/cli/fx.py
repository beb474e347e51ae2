"""``ambdaq fx``: base-motion compensators (Kang & Jung): stepped-sine campaign, MFXLMS, FIR fit."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..documents.compensator_points import PAIRS
from ..errors import BadInputError
from ..machines.base_motion import PLANES
from ..workflows import fx
from .options import POSITIVE, max_lost_option, plot_option


def _freqs(spec: str) -> list[float]:
    """``5:100:5`` (from:to:step) or ``5,10,40``, in Hz."""
    try:
        if ":" in spec:
            lo, hi, step = (float(v) for v in spec.split(":"))
            return [float(f) for f in np.arange(lo, hi + step / 2, step)]
        return [float(v) for v in spec.split(",")]
    except ValueError:
        raise BadInputError(f"--freqs {spec!r}: expected FROM:TO:STEP or F1,F2,... in Hz") from None


def _alpha(text: str) -> complex:
    try:
        return complex(text.replace(" ", ""))
    except ValueError:
        raise BadInputError(f"--alphas: {text!r} is not a number (e.g. 1, -1, 0.5+0.5j)") from None


def _simulated_exact(f_hz):
    """The simulated base-motion rig's exact compensator W* = -B^-1 C at ``f_hz`` (Hz), V per m/s^2
    (Kang & Jung eq. 17): what ``fx fit --exact`` compares with."""
    from ..sim.rigs.base_motion import BaseMotionRig

    return BaseMotionRig().responses(f_hz)[2]


@click.group("fx")
def command() -> None:
    """Base-motion feedforward (Kang & Jung): campaign, MFXLMS estimate, FIR fit."""


@command.command("campaign")
@click.option("--device", default="sim://base-motion", show_default=True, metavar="URL",
              help="The AMB controller (streams /amb/gap and /base/accel): serial://PORT, or sim://base-motion "
                   "served in this process with its simulated shaker generator.")
@click.option("--shaker", metavar="URL",
              help="The two-channel SCPI generator driving the base shakers (scpi:///dev/ttyUSB1, "
                   "scpi:socket://HOST:5025); default for sim://base-motion: its simulated one.")
@click.option("--shaker-gain", type=POSITIVE,
              help="Base acceleration per generator volt, m/s^2/V (required on hardware; a simulated rig reports "
                   "its shakers').")
@click.option("--freqs", default="5:100:5", show_default=True, help="FROM:TO:STEP or F1,F2,... Hz.")
@click.option("--amplitude", type=POSITIVE, default=1.0, show_default=True,
              help="Peak base acceleration d2, m/s^2.")
@click.option("--alphas", default="1,-1+0.5j", show_default=True,
              help="Two disturbance ratios d1/d2 (Kang & Jung eq. A-10); each frequency is run with both.")
@click.option("--seconds", type=click.FloatRange(min=0.5), default=3.0, show_default=True, help="Recorded per step.")
@click.option("--settle", type=click.FloatRange(min=0), default=0.5, show_default=True,
              help="Wait after moving the shaker before recording each step, s.")
@click.option("-o", "--output", type=click.Path(file_okay=False), required=True, help="Campaign folder.")
@max_lost_option
def campaign(device, shaker, shaker_gain, freqs, amplitude, alphas, seconds, settle, output, max_lost):
    """Stepped sine over the base: the shakers are set through their generator, then every
    (frequency, alpha) step is recorded from the controller to its own MCAP file, listed in
    campaign.json.  The same commands run on hardware and on the simulator.

    \b
    Examples:
      ambdaq fx campaign --freqs 5:100:5 -o campaign/
      ambdaq fx campaign --device serial:///dev/ttyUSB0 --shaker scpi:socket://10.0.0.7:5025 \\
          --shaker-gain 4.2 --freqs 5:100:5 -o campaign/
    """
    out = fx.campaign(device, shaker, shaker_gain, _freqs(freqs), amplitude, [_alpha(a) for a in alphas.split(",")],
                      seconds, settle, Path(output),
                      on_step=lambda f, a, path: click.echo(f"{f:>7g} Hz  alpha {a:g}  -> {path}", err=True),
                      max_lost=max_lost)
    click.echo("shakers stopped, the base at rest", err=True)
    click.echo(f"{len(json.loads(out.read_text())['steps'])} steps -> {out}")


@command.command("estimate")
@click.argument("folder", type=click.Path(file_okay=False, exists=True))
@click.option("--path", "path_file", type=click.Path(dir_okay=False), required=True,
              help="Secondary path: frequency-response file from /amb/ff to /amb/gap (ambdaq frf estimate).")
@click.option("--mu", type=click.FloatRange(min=0, min_open=True, max=0.5), default=0.01, show_default=True,
              help="Normalised step on gap 1's error (eta, on gap 2's, is the same).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Compensator points (JSON).")
@click.option("--overwrite", is_flag=True)
@max_lost_option
def estimate(folder, path_file, mu, output, overwrite, max_lost):
    """MFXLMS per frequency and plane over a campaign; two alphas per frequency give W11, W21,
    W12, W22 (Kang & Jung eq. A-4 to A-17).

    \b
    Example:
      ambdaq fx estimate campaign/ --path secondary.frf.json -o points.json
    """
    def say(f: float, residual: list[float]) -> None:
        click.echo(f"{f:>7g} Hz  " + "  ".join(f"{PLANES[p]}: residual {20 * np.log10(residual[p]):6.1f} dB"
                                              for p in range(2)), err=True)

    out, n = fx.estimate(Path(folder), path_file, mu, output, overwrite=overwrite, on_frequency=say, max_lost=max_lost)
    click.echo(f"{n} frequencies x 2 planes -> {out}")


@command.command("fit")
@click.argument("points", type=click.Path(dir_okay=False))
@click.option("--max-order", type=click.IntRange(0, 63), default=24, show_default=True)
@click.option("--order", type=click.IntRange(0, 63), help="Use this order instead of the knee.")
@click.option("--exact", is_flag=True, help="Also report the error against the simulated rig's exact W* = -B^-1 C.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Coefficient file with the FIR.")
@click.option("--overwrite", is_flag=True)
@plot_option("Bode plot: points and fits.")
@click.option("--json", "as_json", is_flag=True)
@click.option("--max-fit-error", type=POSITIVE, default=fx.MAX_FIT_ERROR_PCT, show_default=True, metavar="PCT",
              help="Refuse a fit that misses a point by more than this, % (a bad campaign step).")
def fit(points, max_order, order, exact, output, overwrite, plot_path, as_json, max_fit_error):
    """Weighted least-squares FIR fit of each compensator W_jm (Kang & Jung eq. 19); the order at the
    knee of cost against order unless --order; a FIR is stable by construction.

    \b
    Example:
      ambdaq fx fit points.json -o fir.json --plot fir.png --exact
    """
    result = fx.fit(points, max_order, order, exact=_simulated_exact if exact else None,
                    max_fit_error_pct=max_fit_error)
    result.coefficients.save(output, overwrite=overwrite)
    report, freqs, costs, chosen = result.report, result.freqs, result.costs, result.report["order"]
    orders = np.arange(0, max_order + 1)
    if plot_path:
        from ..figures import save
        from ..figures.fx import draw_compensators

        save(draw_compensators(freqs, result.points, result.sample_rate, result.taps), plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    click.echo("fit error per FIR order: RMS relative error over the points of both planes, % (eq. 19's J)")
    click.echo(f"{'order':>5}" + "".join(f"{f'W{j + 1}{m + 1}':>11}" for j, m in PAIRS))
    for i, o in enumerate(orders):
        mark = "  <- knee" if o == chosen else ""
        click.echo(f"{o:>5}" + "".join(f"{100 * np.sqrt(costs[j, m, i] / (2 * len(freqs))):>11.3f}"
                                        for j, m in PAIRS) + mark)
    click.echo(f"FIR order {chosen} ({chosen + 1} taps) -> {output}")
    click.echo(f"{'Hz':>7}{'fit err %':>11}" + (f"{'vs W* %':>10}{'points vs W* %':>16}" if exact else ""))
    for i, f in enumerate(freqs):
        row = f"{f:>7g}{report['fit_error_pct'][i]:>11.3f}"
        if exact:
            row += f"{report['error_vs_exact_pct'][i]:>10.3f}{report['points_vs_exact_pct'][i]:>16.3f}"
        click.echo(row)


