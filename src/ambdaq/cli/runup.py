"""``ambdaq runup``: run-up and coast-down diagnostics (order tracking, Bode, polar, waterfall, Campbell)."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..errors import BadInputError
from .options import SPEED_RANGE, critical_limits_options, max_lost_option, plot_option


def _orders(value: str) -> tuple[int, ...]:
    try:
        out = tuple(sorted({int(v) for v in value.split(",")}))
    except ValueError:
        raise BadInputError(f"--orders {value!r}: expected comma-separated orders, e.g. 1,2") from None
    if not out or out[0] < 1 or out[-1] > 20:
        raise BadInputError(f"--orders {value!r}: orders are 1 .. 20")
    return out


@click.command("runup")
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--coefficients", type=click.Path(dir_okay=False),
              help="Runout coefficient file (runout identify): the sensor runout is taken out (the rotor's motion is left).")
@click.option("--slow-roll", type=click.Path(dir_okay=False),
              help="Slow-roll recording: its vector per order is taken out of every window's (Bently style).")
@click.option("--orders", default="1,2", show_default=True, help="Orders to track.")
@click.option("--revolutions", type=click.IntRange(1, 1000), default=8, show_default=True,
              help="Revolutions per tracking window.")
@click.option("--speeds", type=SPEED_RANGE, help="Speed range the run must cover, rpm.")
@click.option("--operating", type=SPEED_RANGE,
              help="The operating range, minimum operating to maximum continuous speed, rpm: with --model, each critical "
                   "speed must also keep API 617's separation margin from it.")
@click.option("--model", type=click.Choice(["spindle", "cone"]),
              help="Overlay the modes this model's loop predicts (Campbell): the spindle's or the cone rotor's.")
@critical_limits_options
@click.option("--waterfall-axis", help="Gap axis of the waterfall; default: the first radial one.")
@plot_option("Bode, polar, waterfall with order lines (and Campbell with --model) (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the tracked vectors and peaks as JSON.")
@max_lost_option
def command(recording, coefficients, slow_roll, orders, revolutions, speeds, operating, model, limits, waterfall_axis,
            plot_path, as_json, max_lost):
    """Order tracking of a run-up or coast-down on the key-phasor: 1X (and NX) amplitude and phase
    against speed, 1X peaks with their amplification factor (critical speeds, API 684), a waterfall.

    \b
    Example:
      ambdaq runup runup.mcap --coefficients coef.json --model spindle --plot runup.png
      ambdaq runup coastdown.mcap --slow-roll slow.mcap --orders 1,2,3 --json
    """
    from ..daq.recording import open_recording
    from ..workflows.runout import RUNOUT_REMOVED
    from ..workflows.runup_diagnostics import analyse

    if operating is not None and model is None:
        raise BadInputError("--operating checks the critical speeds of a --model: give one (spindle or cone)")
    res = analyse(open_recording(recording), coefficients=Path(coefficients) if coefficients else None,
                  slow_roll=open_recording(slow_roll) if slow_roll else None, orders=_orders(orders), revolutions=revolutions,
                  speeds=speeds, waterfall_axis=waterfall_axis, model=model, operating_rpm=operating, limits=limits,
                  max_lost=max_lost)
    for note in res.notes:
        click.echo(f"ambdaq: warning: {note}", err=True)
    if coefficients:
        click.echo(f"ambdaq: note: {RUNOUT_REMOVED}", err=True)
    if as_json:
        click.echo(json.dumps({**res.as_dict(recording, revolutions),
                               "runout_removed": RUNOUT_REMOVED if coefficients else None}, indent=2))
    else:
        _print_table(res)
    if plot_path:
        from ..figures import save
        from ..figures.runup import draw_runup

        save(draw_runup(res, Path(recording).name), plot_path)
        click.echo(f"-> {plot_path}", err=True)


def _print_table(res) -> None:
    from ..analysis.orders import phase_lag_deg

    t = res.track
    lo, hi = float(t.rpm.min()), float(t.rpm.max())
    at = np.linspace(lo, hi, 5)
    idx = [int(np.argmin(np.abs(t.rpm - r))) for r in at]
    click.echo(f"run {lo:,.0f}-{hi:,.0f} rpm, {t.rpm.shape[0]} windows; compensation: {res.compensation}")
    click.echo("amplitude and phase lag behind the key-phasor (unwrapped along the run, as the Bode plot draws it)")
    click.echo(f"{'axis':<9} order " + "".join(f"{t.rpm[i]:>17,.0f} rpm" for i in idx))
    for j, a in enumerate(res.axes):
        for k in t.orders:
            v, lag = t.order(k)[:, j], phase_lag_deg(t.order(k)[:, j])
            cells = "".join(f"{abs(v[i]) * 1e6:>11.2f} um {lag[i]:>5.0f}°" for i in idx)
            click.echo(f"{a:<9} {k:>4}X {cells}")
    for a, peaks in res.peaks.items():
        if not peaks:
            click.echo(f"{a}: no 1X peak that stands out of the scatter with its half-power band inside the run: "
                       "no critical speed")
        for p in peaks:
            verdict = ("a critical speed" if p.is_critical(res.limits.critically_damped) else
                       f"critically damped (amplification < {res.limits.critically_damped:g}, API 684)")
            click.echo(f"{a}: 1X peak {p.amplitude * 1e6:.2f} um at {p.rpm:,.0f} rpm, half-power band "
                       f"{p.band_rpm[0]:,.0f}-{p.band_rpm[1]:,.0f} rpm, phase turns {p.phase_change_deg:.0f}°, "
                       f"amplification {p.amplification:.1f}: {verdict}")
    if res.modes is not None:
        click.echo(f"model: its loop at {res.modes.basis}")
    for c in res.criticals:  # the model's critical speeds against the run (API 684)
        row = c.as_dict()
        said = (f"predicted {row['predicted_rpm']:,.0f} rpm (amplification {row['predicted_amplification']:.2f})"
                if c.predicted else "not predicted")
        seen = (f"measured {row['measured_rpm']:,.0f} rpm on {c.axis} (amplification {row['measured_amplification']:.2f})"
                if c.measured else "no peak measured")
        margin = ("" if c.margin is None else
                  f"; {c.margin.actual:.1%} from the operating range, {c.margin.required:.1%} required")
        click.echo(f"critical speed: {said}; {seen}{margin}: {'pass' if c.passed else 'FAIL'} ({c.rule})")


