"""``ambdaq recover``: rebuild an indexed file from a crashed or damaged recording."""

from __future__ import annotations

import json

import click

from ..daq.recover import recover


@click.command("recover")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="The rebuilt file.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable report.")
def command(file, output, overwrite, as_json):
    """Recover every complete chunk of FILE into a finished, indexed OUTPUT."""
    report = recover(file, output, overwrite=overwrite)
    if as_json:
        click.echo(json.dumps(report.as_dict(), indent=2))
    else:
        click.echo(
            f"recovered {report.messages} messages in {report.chunks_kept} chunks -> {output}; "
            f"dropped {report.chunks_dropped} damaged chunks and {report.bytes_dropped} trailing bytes",
            err=True,
        )
