"""``ambdaq identify``: system identification from recordings (modal parameters from impact tests)."""

from __future__ import annotations

import json

import click
import numpy as np

from ..analysis.modal import free_decays, stable_modes, strikes
from ..daq import load
from ..errors import BadInputError

HAMMER = "/amb/hammer"
GAP = "/amb/gap"


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
    rec = load(file, topics=[HAMMER, GAP])  # one line and exit 2 if a topic is missing
    gap, hammer = rec[GAP], rec[HAMMER]
    rate = rec[GAP].nominal_rate
    force = np.interp(gap.log_time, hammer.log_time, hammer["hammer"]) if len(hammer) != len(gap) else hammer["hammer"]
    hits = strikes(force, rate)
    if not hits:
        raise BadInputError(f"{file}: no hammer strike found on {HAMMER}")
    names = list(gap.fields)
    for axis in axes:
        if axis not in names:
            raise BadInputError(f"--axis {axis!r}: the gap sensors are {', '.join(names)}")
    if not axes:  # the axes whose response to the first strike is at least a tenth of the largest
        a, _ = hits[0]
        swing = {n: np.ptp(gap[n][a: a + int(0.02 * rate)]) for n in names}
        axes = tuple(n for n in names if swing[n] >= 0.1 * max(swing.values()))
    decays = free_decays(np.column_stack([gap[n] for n in axes]), force, rate, window_s=window_s, skip_s=skip_s)
    if not decays:
        raise BadInputError(f"{file}: no strike has {window_s:g} s of free decay after it")
    found, order = stable_modes(decays, rate)
    if not found:
        raise BadInputError(f"{file}: no damped mode confirmed on {', '.join(axes)} (ERA orders 2-12 disagree)")
    result = {"file": str(file), "axes": list(axes), "strikes": len(decays), "order": order,
              "modes": [{"freq_hz": round(m.freq_hz, 4), "zeta": round(m.zeta, 5),
                         "amplitude": float(f"{m.amplitude:.4g}")} for m in found]}
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    unit = gap.units.get(axes[0], "")
    click.echo(f"{file}: {len(decays)} strikes, response {', '.join(axes)}, ERA order {order}")
    for k, m in enumerate(found):
        mark = "  (dominant)" if k == 0 else ""
        click.echo(f"  {m.freq_hz:9.3f} Hz  zeta {m.zeta:6.4f}  amplitude {m.amplitude:.3g} {unit}{mark}")
