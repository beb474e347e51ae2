"""``ambdaq plot``: time series, spectrum and X-Y orbit of a recorded signal."""

from __future__ import annotations


import click

from ..daq.recording import open_recording
from ..errors import BadInputError
from .options import POSITIVE, ImagePath, window_options
from ..roles import GAP


@click.command("plot")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--topic", default=GAP, show_default=True,
              help="A topic, or a role's (/amb/gap: the machine's gap, wherever recorded).")
@click.option("--field", "field_name", required=True, help="Field, e.g. front_x.")
@window_options
@click.option("--cmin", type=POSITIVE, metavar="UM",
              help="Minimum clearance for the orbit's clearance circle, um; default: what the recording reports.")
@click.option("-o", "--output", type=ImagePath(), required=True, help="Image file (.png, .pdf, .svg ...).")
def command(file, topic, field_name, start, end, cmin, output):
    """Plot FIELD of TOPIC: time series, amplitude spectrum (with the speed and its orders where the
    rotor angle was recorded), and the bearing's X-Y orbit (with the clearance circle where Cmin is
    known)."""
    from ..figures import save
    from ..figures.signal import draw_signal

    rec = open_recording(file, start=start, end=end)
    data = rec.signals(topic)
    if len(data) < 2:
        raise BadInputError(f"{file}: {topic} has {len(data)} samples in the window; nothing to plot")
    clearance = cmin * 1e-6 if cmin is not None else rec.machine.cmin_m
    save(draw_signal(rec, topic, field_name, clearance), output, dpi=110)
    click.echo(output)


