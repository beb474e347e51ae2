"""``ambdaq export``: recordings to CSV, NPZ or Parquet."""

from __future__ import annotations

from pathlib import Path

import click

from ..daq.export import FORMATS, export, value_tables
from ..daq.recording import load
from .options import window_options


@click.command("export")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(FORMATS), required=True)
@click.option("--topic", "topics", multiple=True, help="Topic to export (repeatable); default all.")
@window_options
@click.option("-o", "--output", type=click.Path(), required=True,
              help="Output: a .npz file; for csv/parquet a file (one topic) or a directory.")
@click.option("--overwrite", is_flag=True, help="Replace existing files.")
@click.option("--labels", is_flag=True,
              help="Beside each field with a value table (a DBC's choices, an A2L's TAB_VERB), its text as FIELD_label.")
@click.option("--device-names", is_flag=True,
              help="csv/parquet/npz: name each field's column as its device does where that differs (a DBC signal's "
                   "own name, HU_date_year for hu_date_year).")
@click.option("--push-log", type=click.Path(dir_okay=False),
              help="mf4: the push log whose entries of the running coefficient files are attached (default: this machine's).")
def command(file, fmt, topics, start, end, output, overwrite, labels, device_names, push_log):
    """Export topics of FILE with time, device time, seq and every field in SI units."""
    rec = load(file, topics=list(topics) or None, start=start, end=end)
    tables = value_tables(rec) if labels else None
    history = None
    if fmt == "mf4":  # the calibration history of what the recording's controllers ran
        from ..workflows.push import push_log_entries

        running = {d.identity["active_coefficients_sha256"] for d in rec.devices.values()
                   if d.identity.get("active_coefficients_sha256")}
        history = push_log_entries(Path(push_log) if push_log else None, running) if running else []
    for path in export(rec, fmt, Path(output), overwrite=overwrite, labels=tables, push_log=history,
                       device_names=device_names):
        click.echo(str(path))
    for topic in rec.values():
        if topic.skipped:  # a topic of another writer: what is not a number is not exported
            click.echo(f"{topic.topic}: not exported (not numbers): {', '.join(topic.skipped)}", err=True)
