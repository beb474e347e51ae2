"""``ambdaq apht``: amplitude and phase of the synchronous vectors against time at one speed."""

from __future__ import annotations

import json
from pathlib import Path

import click

from .options import POSITIVE, max_lost_option, plot_option


def _orders(value: str) -> list[int]:
    from ..errors import BadInputError

    try:
        out = [int(v) for v in value.split(",")]
    except ValueError:
        out = []
    if not out or any(not 1 <= k <= 20 for k in out):
        raise BadInputError(f"--orders {value!r}: expected orders 1..20, comma-separated (e.g. 1,2)")
    return out


@click.command("apht")
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--coefficients", type=click.Path(dir_okay=False),
              help="Runout coefficient file (runout identify): the sensor runout is taken out of the gap first.")
@click.option("--orders", default="1", show_default=True, help="Orders to track, comma-separated.")
@click.option("--window", "window_s", type=POSITIVE, default=0.5, show_default=True, metavar="SECONDS",
              help="Length of each window.")
@plot_option("Amplitude and phase against time per axis, the feedforward's beside (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the vectors per window as JSON.")
@max_lost_option
def command(recording, coefficients, orders, window_s, plot_path, as_json, max_lost):
    """APHT: amplitude and phase of 1X (and NX) against time at one speed, per radial axis, with
    the command error's and the feedforward output's where recorded (an LMS converging, a
    thermal bow growing).

    \b
    Example:
      ambdaq apht steady.mcap --coefficients coef.json --orders 1,2 --plot apht.png
    """
    from ..daq.recording import open_recording
    from ..workflows.apht import apht
    from ..workflows.runout import RUNOUT_REMOVED

    res = apht(open_recording(recording), orders=_orders(orders), window_s=window_s,
               coefficients=Path(coefficients) if coefficients else None, max_lost=max_lost)
    if coefficients:
        click.echo(f"ambdaq: note: {RUNOUT_REMOVED}", err=True)
    if as_json:
        click.echo(json.dumps(res.as_dict(recording, RUNOUT_REMOVED if coefficients else None), indent=2))
    else:
        click.echo(f"APHT at {res.rpm:,.0f} rpm, {len(res.time_s)} windows of {window_s:g} s; compensation: "
                   f"{res.compensation}")
        rows = {k: res.first_last(k) for k in res.orders}
        for j in range(len(res.axes)):
            for k in res.orders:
                row = rows[k][j]
                g0, g1 = row["gap_first"], row["gap_last"]
                line = (f"{row['axis']:<9} {k}X gap {g0['amplitude']:8.3f} um {g0['phase_deg']:6.1f}° -> "
                        f"{g1['amplitude']:8.3f} um {g1['phase_deg']:6.1f}°")
                if "error_first" in row:
                    line += f"; error {row['error_first']['amplitude']:.3f} -> {row['error_last']['amplitude']:.3f} um"
                click.echo(line)
    if plot_path:
        from ..figures import save
        from ..figures.apht import draw_apht

        save(draw_apht(res), plot_path)
        click.echo(f"-> {plot_path}", err=True)


