"""``ambdaq identify``: system identification from recordings (modal parameters from impact tests)."""

from __future__ import annotations

import json

import click

from ..daq.recording import open_recording
from ..workflows.modal import identify_modal


@click.group("identify")
def command() -> None:
    """Identify system parameters from recordings."""


@command.command("modal")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--axis", "axes", multiple=True,
              help="Gap-sensor axis analysed; repeat for several (default: every axis that moves with the strike).")
@click.option("--window", "window_s", type=click.FloatRange(min=0.005), default=0.05, show_default=True,
              metavar="SECONDS", help="Free decay analysed after each strike.")
@click.option("--skip", "skip_s", type=click.FloatRange(min=0.0), default=0.002, show_default=True,
              metavar="SECONDS", help="Time left out after each strike ends (the fast poles).")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def modal(file, axes, window_s, skip_s, as_json):
    """Natural frequency and damping ratio from hammer strikes (an impact test).

    FILE holds an instrumented hammer's force (/amb/hammer) and the gap sensors (/amb/gap), e.g.
    from `ambdaq sim generate --profile cone --impact x:50`.  Each strike's free decay goes into
    the eigensystem realisation algorithm; the model order is the lowest the next order confirms.

    \b
    Example:
      ambdaq sim generate --profile cone --duration 3 --impact x:50 -o impact.mcap
      ambdaq identify modal impact.mcap --axis x
    """
    res = identify_modal(open_recording(file), tuple(axes), window_s=window_s, skip_s=skip_s)
    result = {"file": str(file), "axes": res.axes, "strikes": res.strikes, "order": res.order,
              "modes": [{"freq_hz": round(m.freq_hz, 4), "zeta": round(m.zeta, 5),
                         "amplitude": float(f"{m.amplitude:.4g}")} for m in res.modes]}
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    click.echo(f"{file}: {res.strikes} strikes, response {', '.join(res.axes)}, ERA order {res.order}")
    for k, m in enumerate(res.modes):
        mark = "  (dominant)" if k == 0 else ""
        click.echo(f"  {m.freq_hz:9.3f} Hz  zeta {m.zeta:6.4f}  amplitude {m.amplitude:.3g} {res.unit}{mark}")
