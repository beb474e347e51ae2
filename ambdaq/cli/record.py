"""``ambdaq record``: record devices (or a rig file) into MCAP."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from ..daq.recorder import Progress, Recorder, RecordOptions, print_progress
from ..drivers.registry import Opened, open_url
from ..drivers.rigfile import load_rig
from ..errors import BadInputError
from .options import POSITIVE, Output, output_options, report_options, speed_option


def run_recording(sources, out: Output, *, duration, quiet, as_json, rig_file: Path | None = None,
                  reconnect: bool = False) -> None:
    """Run the recorder over opened ``sources`` and report on the terminal (shared by record and sim)."""
    options = RecordOptions(duration_s=duration, split_size=out.split_size, split_duration_s=out.split_duration_s,
                            compression=out.compression, reconnect=reconnect, fsync=out.fsync)
    recorder = Recorder(sources, out.path, options, command=" ".join(sys.argv), rig_file=rig_file,
                        overwrite=out.overwrite)
    tty = sys.stderr.isatty()

    def progress(p: Progress) -> None:
        if p.elapsed_s >= 1.0:  # only for anything longer than a second
            print_progress(p)

    def stopping(files: list[Path]) -> None:  # at once, so a user who pressed Ctrl-C knows it was heard
        click.echo(f"ambdaq: stopping, finishing {', '.join(str(f) for f in files)} ...", err=True)

    if tty and not quiet:  # a terminal: the live status (docs/cli.md), redrawn twice a second
        from rich.console import Console
        from rich.live import Live

        from .live import LiveView, status_table

        view = LiveView({s.name: s.sample_rate for s in sources})
        groups = {s.name: {g.topic: list(g.fields) for g in s.signal_groups()} for s in sources}
        shown: list[Progress] = []

        def redraw(p: Progress) -> None:
            live.update(status_table(p, shown[-1] if shown else None, view.bearings(groups)))
            shown[:] = [p]

        with Live(console=Console(stderr=True), refresh_per_second=2) as live:
            result = recorder.run(on_progress=redraw, progress_interval_s=0.5, on_stopping=stopping,
                                  on_block=view.observe)
    else:
        result = recorder.run(on_progress=None if quiet else progress, progress_interval_s=5.0, on_stopping=stopping)
    if as_json:
        click.echo(json.dumps(result.as_dict(), indent=2))
    elif not quiet:
        size = sum(f.stat().st_size for f in result.files) / 1e6
        how = " (stopped)" if result.stopped_by_user else ""
        dups = f", {result.duplicates} duplicates dropped" if result.duplicates else ""
        click.echo(
            f"recorded {result.duration_s:.3f} s{how}: {result.samples} samples, {result.drops} drops{dups} "
            f"-> {', '.join(str(f) for f in result.files)} ({size:.1f} MB)",
            err=True,
        )


@click.command("record")
@click.option("--device", "devices", multiple=True, metavar="URL", envvar="AMBDAQ_DEVICE",
              help="Device URL, e.g. sim://spindle?seed=3 (repeatable).")
@click.option("--rig", "rig_path", type=click.Path(dir_okay=False), help="Rig file (TOML) listing devices.")
@click.option("--duration", type=POSITIVE, metavar="SECONDS",
              help="Recording length; default: until Ctrl-C.")
@speed_option
@click.option("--truth", is_flag=True, help="Also record /truth/... topics (simulated rigs).")
@click.option("--reconnect", is_flag=True,
              help="Reopen a device that is lost and go on recording; the gap is marked in the file.")
@click.option("--a2l", "a2l", type=click.Path(dir_okay=False), metavar="FILE",
              help="A2L file of the --device XCP controllers (xcp+tcp://...).")
@output_options
@report_options
def command(devices, rig_path, duration, speed, truth, reconnect, a2l, out, quiet, as_json):
    """Record devices in real time into an MCAP file.

    \b
    Examples:
      ambdaq record --device sim://spindle --duration 10 --rpm 30000 -o run.mcap
      ambdaq record --rig lab.toml --split-duration 60 -o long.mcap
      ambdaq record --device xcp+tcp://127.0.0.1:5555 --a2l spindle.a2l --duration 10 -o run.mcap
    """
    if not devices and not rig_path:
        raise BadInputError("nothing to record: give --device URL or --rig FILE")
    rig = load_rig(rig_path) if rig_path else None
    with Opened() as opened:  # however the recording ends, every device and simulated rig is closed
        for i, url in enumerate(devices):
            opened.add(open_url(url, name=None if len(devices) == 1 else f"dev{i}", speed=speed, truth=truth or None,
                                description={"a2l": str(Path(a2l).resolve())} if a2l else None))
        for d in rig.devices if rig is not None else ():
            opened.add(open_url(d.url, name=d.name, speed=speed or d.rpm, truth=truth or None,
                                calibration=d.calibration, description=d.description))
        run_recording(opened.sources, out, duration=duration, quiet=quiet, as_json=as_json,
                      rig_file=rig.path if rig else None, reconnect=reconnect)
