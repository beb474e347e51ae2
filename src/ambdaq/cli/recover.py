"""``ambdaq recover``: rebuild a finished file from a crashed or damaged recording."""

from __future__ import annotations

import json

import click

from ..acquisition.recover import recover


@click.command("recover")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="The rebuilt file.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("--index/--no-index", default=True, show_default=True,
              help="Write the message and chunk indexes (as record does); a file recorded with --no-index "
                   "gets them here to be opened in Foxglove at any length.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable report.")
def command(file, output, overwrite, index, as_json):
    """Recover every intact chunk of FILE, wherever the damage, into a finished OUTPUT (indexed
    unless --no-index); say per topic the samples and seconds kept and lost (docs/data-format.md,
    "Recovery")."""
    report = recover(file, output, overwrite=overwrite, index=index)
    if as_json:
        click.echo(json.dumps(report.as_dict(), indent=2))
    else:
        click.echo(
            f"recovered {report.messages} messages in {report.chunks_kept} chunks -> {output}; "
            f"lost {report.chunks_dropped} damaged chunks, {report.bytes_dropped} bytes unread"
            + (f", {report.orphan_messages} messages of unknown channels" if report.orphan_messages else ""),
            err=True,
        )
        for topic, t in report.topics.items():
            if "samples" not in t:  # another writer's topic: the messages kept
                click.echo(f"  {topic:<28} kept {t['messages']:>10,} messages (losses not numbered)", err=True)
                continue
            kept = "?" if t["seconds_kept"] is None else f"{t['seconds_kept']:.3f} s"
            lost = "?" if t["seconds_lost"] is None else f"{t['seconds_lost']:.3f} s"
            click.echo(f"  {topic:<28} kept {t['samples']:>10,} samples ({kept}), lost {t['samples_lost']:>8,} ({lost})",
                       err=True)
