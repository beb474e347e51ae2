"""``ambdaq apht``: amplitude and phase of the synchronous vectors against time at one speed."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..units import phasor_um_deg
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


def _vectors(v: np.ndarray, scale: float) -> dict:
    """Amplitude and phase of (window, order, axis) vectors, per order."""
    return {"amplitude": np.round(np.abs(v) * scale, 5).tolist(),
            "phase_deg": np.round(np.degrees(np.angle(v)), 2).tolist()}


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
        out = {"recording": recording, "rpm": round(res.rpm, 1), "window_s": window_s, "axes": res.axes,
               "orders": res.orders, "compensation": res.compensation,
               "runout_removed": RUNOUT_REMOVED if coefficients else None, "time_s": np.round(res.time_s, 4).tolist(),
               "gap_um": _vectors(res.gap, 1e6),
               "error_um": None if res.error is None else _vectors(res.error, 1e6),
               "feedforward": None if res.feedforward is None else {
                   **_vectors(res.feedforward, 1e6 if res.ff_unit == "m" else 1.0),
                   "unit": "um" if res.ff_unit == "m" else res.ff_unit}}
        click.echo(json.dumps(out, indent=2))
    else:
        click.echo(f"APHT at {res.rpm:,.0f} rpm, {len(res.time_s)} windows of {window_s:g} s; compensation: "
                   f"{res.compensation}")
        for j, a in enumerate(res.axes):
            for i, k in enumerate(res.orders):
                (um0, deg0), (um1, deg1) = phasor_um_deg(res.gap[0, i, j]), phasor_um_deg(res.gap[-1, i, j])
                line = f"{a:<9} {k}X gap {um0:8.3f} um {deg0:6.1f}° -> {um1:8.3f} um {deg1:6.1f}°"
                if res.error is not None:
                    line += f"; error {abs(res.error[0, i, j]) * 1e6:.3f} -> {abs(res.error[-1, i, j]) * 1e6:.3f} um"
                click.echo(line)
    if plot_path:
        from ..figures import save
        from ..figures.apht import draw_apht

        save(draw_apht(res), plot_path)
        click.echo(f"-> {plot_path}", err=True)


