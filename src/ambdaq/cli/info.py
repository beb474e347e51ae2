"""``ambdaq info``: what a recording holds."""

from __future__ import annotations

import json

import click

from ..daq.info import describe, format_text


@click.command("info")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def command(file, as_json):
    """Topics, rates, duration, drops and metadata of FILE."""
    d = describe(file)
    click.echo(json.dumps(d, indent=2) if as_json else format_text(d))
