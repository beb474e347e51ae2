"""``ambdaq plot``: time series, spectrum and X-Y orbit of a recorded signal."""

from __future__ import annotations

import click
import numpy as np

from ..analysis.spectrum import amplitude_spectrum
from ..daq.reader import load
from ..errors import BadInputError
from .options import window_options
from .figures import ImagePath, pyplot

UNIT_SCALE = {"m": (1e6, "µm"), "m/s^2": (1.0, "m/s²"), "A": (1.0, "A"), "rad": (1.0, "rad"), "rad/s": (1.0, "rad/s")}


def orbit_partner(field: str, fields) -> str | None:
    """The other radial axis of the same bearing: ``front_x`` <-> ``front_y``."""
    for a, b in (("_x", "_y"), ("_y", "_x")):
        if field.endswith(a) and field[: -len(a)] + b in fields:
            return field[: -len(a)] + b
    return None


@click.command("plot")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--topic", default="/amb/gap", show_default=True)
@click.option("--field", "field_name", required=True, help="Field, e.g. front_x.")
@window_options
@click.option("-o", "--output", type=ImagePath(), required=True, help="Image file (.png, .pdf, .svg ...).")
def command(file, topic, field_name, start, end, output):
    """Plot FIELD of TOPIC: time series, amplitude spectrum, and the bearing's X-Y orbit."""
    plt = pyplot()

    data = load(file, topics=[topic], start=start, end=end)[topic]
    y = data[field_name]
    if len(data) < 2:
        raise BadInputError(f"{file}: {topic} has {len(data)} samples in the window; nothing to plot")
    scale, unit = UNIT_SCALE.get(data.units[field_name], (1.0, data.units[field_name]))
    partner = orbit_partner(field_name, data.fields)
    ncols = 3 if partner else 2
    fig, axes = plt.subplots(1, ncols, figsize=(5 * ncols, 4.2), constrained_layout=True)
    ax = axes[0]
    ax.plot(data.time, y * scale, lw=0.6)
    ax.set(xlabel="time [s]", ylabel=f"{field_name} [{unit}]", title=f"{topic} {field_name}")
    ax.grid(alpha=0.3)
    f, a = amplitude_spectrum(y, fs=data.sample_rate)
    ax = axes[1]
    ax.semilogy(f, np.maximum(a * scale, 1e-12), lw=0.6)
    ax.set(xlabel="frequency [Hz]", ylabel=f"amplitude [{unit}]", title="spectrum (Hann)")
    ax.grid(alpha=0.3, which="both")
    if partner:
        ax = axes[2]
        ax.plot(y * scale, data[partner] * scale, lw=0.4)
        ax.set(xlabel=f"{field_name} [{unit}]", ylabel=f"{partner} [{unit}]", title="orbit")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    fig.savefig(output, dpi=110)
    plt.close(fig)
    click.echo(output)
