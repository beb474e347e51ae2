"""``ambdaq report``: one self-contained HTML commissioning report for a machine (docs/iso.md),
gathered by :func:`~ambdaq.workflows.commissioning.gather` and rendered by :mod:`ambdaq.report`."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..errors import BadInputError
from ..machines.models import MODELS
from ..report.page import render
from ..report.pdf import browser, print_pdf
from .options import POSITIVE, SPEED_RANGE, critical_limits_options


def _drop_files(given: tuple[str, ...], more: tuple[str, ...]) -> list[str]:
    """The drop snapshots: ``--drops`` values and the files after them, a glob expanded where no
    file has its name; each named once, in the order given."""
    import glob

    if more and not given:
        raise BadInputError(f"unexpected argument {more[0]!r}: snapshot files follow --drops")
    out: list[str] = []
    for name in (*given, *more):
        found = [name] if Path(name).exists() or not glob.has_magic(name) else sorted(glob.glob(name))
        if not found:
            raise BadInputError(f"--drops {name}: no file matches")
        out += [f for f in found if f not in out]
    return out


@click.command("report")
@click.option("--stability", type=click.Path(dir_okay=False), help="ISO 14839-3 results (iso stability -o).")
@click.option("--runup", type=click.Path(dir_okay=False), help="A run-up or coast-down recording.")
@click.option("--coefficients", type=click.Path(dir_okay=False), help="The runout coefficient file that was pushed.")
@click.option("--before", type=click.Path(dir_okay=False), help="A recording before the push (one speed).")
@click.option("--after", type=click.Path(dir_okay=False), help="A recording after the push, at the same speed.")
@click.option("--push-log", type=click.Path(dir_okay=False), help="Push log (JSON lines); default: this machine's.")
@click.option("--cmin", type=POSITIVE, metavar="UM", help="Minimum clearance, um; default: what the run-up reports.")
@click.option("--model", type=click.Choice(sorted(MODELS)),
              help="Verify the run-up's critical speeds against this rotordynamic model's (API 684).")
@click.option("--operating", type=SPEED_RANGE,
              help="The operating range, minimum operating to maximum continuous speed, rpm: with --model, each critical "
                   "speed must keep API 617's separation margin from it.")
@critical_limits_options
@click.option("--drops", multiple=True, type=click.Path(dir_okay=False),
              help="Snapshot files a touchdown trigger caught (record --snapshot): --drops A B ..., a quoted glob "
                   "('drop_*.mcap'), or --drops repeated.")
@click.argument("more_drops", nargs=-1, type=click.Path(dir_okay=False), metavar="[DROPS]...")
@click.option("--design", type=click.Path(dir_okay=False),
              help="The controller design that was pushed (controller design): its prediction beside --stability.")
@click.option("--balancing", type=click.Path(dir_okay=False),
              help="A balancing record (balance ... --record): the unbalance, the correction masses, the grade.")
@click.option("--title", default="AMB commissioning report", show_default=True)
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="The report (.html).")
@click.option("--pdf", type=click.Path(dir_okay=False), help="Also print it to this PDF (headless Chromium).")
@click.option("--overwrite", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the numbers of the report's tables as JSON.")
def command(stability, runup, coefficients, before, after, push_log, cmin, model, operating, limits, drops, more_drops,
            design, balancing, title, output, pdf, overwrite, as_json):
    """One self-contained HTML commissioning report from a session's files: the machine, the ISO
    14839-3 table and plots, the ISO 14839-2 zones through the run-up, the runout before and after the
    push with the push log and the APHT of the run after it, the run-up's order tracking, the rotor drops
    the snapshots caught (ISO 14839-5).

    \b
    Example:
      ambdaq report --stability stability.json --runup runup.mcap --coefficients coef.json \\
                    --before before.mcap --after after.mcap -o report.html --pdf report.pdf
    """
    from ..daq.recording import open_recording
    from ..workflows.commissioning import SessionFiles, gather

    if operating is not None and model is None:
        raise BadInputError("--operating checks the critical speeds of a --model: give one (spindle or cone)")
    drops = _drop_files(drops, more_drops)
    out = Path(output)
    for target in (out, Path(pdf) if pdf else None):
        if target is not None and target.exists() and not overwrite:
            raise BadInputError(f"{target} exists: choose another name or pass --overwrite")
    if pdf:
        browser()  # before the work: a missing browser is one line now, not after a minute of figures
    as_path = (lambda v: Path(v) if v else None)
    opened = (lambda v: open_recording(v) if v else None)
    found = gather(SessionFiles(as_path(stability), opened(runup), as_path(coefficients), opened(before),
                                opened(after), as_path(push_log), None if cmin is None else cmin * 1e-6, model,
                                [open_recording(p) for p in drops], operating, limits, as_path(design),
                                as_path(balancing)))
    out.write_text(render(found, title))
    if pdf:
        print_pdf(out, Path(pdf))
    if as_json:
        click.echo(json.dumps(found.data, indent=2))
    click.echo(f"-> {out}" + (f", {pdf}" if pdf else ""), err=True)
