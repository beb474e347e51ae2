"""``ambdaq record``: record devices (or a rig file) into MCAP."""

from __future__ import annotations

import json
import os
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import click

from ..acquisition.recorder import Progress, Recorder, RecordOptions, print_progress
from ..acquisition.snapshot import SnapshotOptions
from ..drivers.registry import Opened, open_url
from ..drivers.rigfile import RigFile, load_rig
from ..errors import BadInputError
from .options import (DURATION, POSITIVE, Output, a2l_option, measure_option, output_options, report_options, snapshot_options,
                      speed_option)


def run_recording(sources, out: Output, *, duration, quiet, as_json, rig: RigFile | None = None,
                  reconnect: bool = False, live: "LiveOptions | None" = None,
                  snapshot: SnapshotOptions | None = None, records: dict[str, dict[str, str]] | None = None) -> None:
    """Run the recorder over opened ``sources`` and report on the terminal (shared by record and sim);
    with ``live``, serve the topics to Foxglove while recording; with ``snapshot``, write a file
    around each trigger instead of one recording; ``rig``: the rig file they came from (attached,
    its [machine] described); ``records``: more metadata records for every file (what the
    workflow did to the machine: :class:`~ambdaq.acquisition.recorder.RecordOptions`)."""
    options = RecordOptions(duration_s=duration, split_size=out.split_size, split_duration_s=out.split_duration_s,
                            compression=out.compression, reconnect=reconnect, fsync=out.fsync, snapshot=snapshot,
                            index=out.index, records=records or {})
    recorder = Recorder(sources, out.path, options, command=" ".join(sys.argv), rig_file=rig.path if rig else None,
                        overwrite=out.overwrite, machine_table=rig.machine if rig else None)
    tty = sys.stderr.isatty()
    if snapshot is not None and not quiet:
        manual = "SIGUSR1" + (" or Enter" if sys.stdin.isatty() else "")
        click.echo(f"ambdaq: snapshot: the last {snapshot.pre_s:g} s in memory (at most "
                   f"{recorder.snapshot_bound / 1e6:.1f} MB"
                   + (f", and {recorder.drop_bound / 1e6:.1f} MB for a rotor drop's record" if recorder.drop_bound else "")
                   + f"), {snapshot.post_s:g} s after each trigger: "
                   f"{', '.join(t.text for t in snapshot.triggers)}; {manual} fires one (pid {os.getpid()})", err=True)
    if snapshot is not None and sys.stdin.isatty():
        threading.Thread(target=_enter_fires, args=(recorder,), name="enter-trigger", daemon=True).start()

    def snapped(path: Path, firing) -> None:
        if not quiet:
            click.echo(f"ambdaq: {firing.cause}: {firing.detail} -> {path}", err=True)

    def progress(p: Progress) -> None:
        if p.elapsed_s >= 1.0:  # only for anything longer than a second
            print_progress(p)

    def stopping(files: list[Path]) -> str:  # said at once, so a user who pressed Ctrl-C knows it was heard
        return f"ambdaq: stopping, finishing {', '.join(str(f) for f in files)} ..."

    server = start_live(sources, recorder.machine, live) if live is not None else None
    try:
        result = _run(recorder, sources, tty and not quiet, None if quiet else progress, stopping,
                      [server] if server is not None else [], snapped)
    finally:
        if server is not None:
            server.close()
    for name, clock in result.clocks.items():  # said even with -q: the file's times carry it
        if "suspect" in clock:
            click.echo(f"ambdaq: warning: {name}: {clock['suspect']}; its samples were timed by the offset alone "
                       "while it lasted, as the file's clock metadata says", err=True)
    if as_json:
        click.echo(json.dumps(result.as_dict(), indent=2))
    elif not quiet and snapshot is not None:
        how = " (stopped)" if result.stopped_by_user else ""
        click.echo(f"watched {result.duration_s:.3f} s{how}: {result.counts_line()}; "
                   f"{len(result.files)} snapshot{'' if len(result.files) == 1 else 's'}, memory peak {result.snapshot['memory_peak_bytes'] / 1e6:.1f} MB"
                   + "".join(f"\n  {f} ({f.stat().st_size / 1e6:.1f} MB)" for f in result.files), err=True)
    elif not quiet:
        size = sum(f.stat().st_size for f in result.files) / 1e6
        how = " (stopped)" if result.stopped_by_user else ""
        click.echo(
            f"recorded {result.duration_s:.3f} s{how}: {result.counts_line()} "
            f"-> {', '.join(str(f) for f in result.files)} ({size:.1f} MB)",
            err=True,
        )


@dataclass(frozen=True)
class LiveOptions:
    """``--live``: where the Foxglove WebSocket server listens and the display rate, Hz."""

    port: int
    host: str = "127.0.0.1"
    display_hz: float = 100.0


def start_live(sources, machine, live: LiveOptions):
    """The Foxglove live server for ``sources``; one line if the extra is missing or the port is taken."""
    try:
        import foxglove  # noqa: F401 (the live extra)
    except ImportError:
        raise BadInputError("--live needs foxglove-sdk, the live extra: pip install 'ambdaq[live]'") from None
    from ..live.foxglove import FoxgloveLive

    if live.host not in ("127.0.0.1", "localhost", "::1"):
        click.echo(f"ambdaq: warning: the live view is served on {live.host}: anyone who reaches it sees the "
                   "machine's signals", err=True)
    try:
        server = FoxgloveLive(sources, machine, live.host, live.port, live.display_hz,
                              warn=lambda text: click.echo(f"ambdaq: live: {text}", err=True))
    except RuntimeError as err:  # foxglove-sdk reports a bind failure so
        raise BadInputError(f"--live {live.port}: cannot serve on {live.host}:{live.port} ({err})") from None
    click.echo(f"ambdaq: live view on ws://{live.host}:{server.port} (Foxglove: open a WebSocket connection)", err=True)
    return server


def _enter_fires(recorder) -> None:
    """Enter on the terminal fires the manual trigger (a snapshot recording's key press)."""
    for _ in sys.stdin:
        recorder.trigger("Enter")


def _run(recorder, sources, status: bool, progress, stopping, sinks: list, snapped):
    """Run ``recorder`` with the live terminal status when ``status`` (stderr is a terminal), else
    with ``progress`` lines; ``sinks`` see every block as it is received; ``snapped`` hears of
    every snapshot file opened; ``stopping`` gives the line said when the user stops it (above the
    live status on a terminal: written to stderr under it, the status's next redraw erased it)."""
    if not status:
        return recorder.run(on_progress=progress, progress_interval_s=5.0,
                            on_stopping=lambda files: click.echo(stopping(files), err=True), sinks=sinks,
                            on_snapshot=snapped)
    from rich.console import Console
    from rich.live import Live

    from ..live.view import LiveView
    from .live import status_table

    groups = {s.name: {g.topic: list(g.fields) for g in s.signal_groups()} for s in sources}
    view = LiveView({s.name: s.sample_rate for s in sources}, groups, recorder.machine)
    shown: list[Progress] = []

    def redraw(p: Progress) -> None:
        live.update(status_table(p, shown[-1] if shown else None, view.bearings()))
        shown[:] = [p]

    with Live(console=Console(stderr=True), refresh_per_second=2) as live:
        return recorder.run(on_progress=redraw, progress_interval_s=0.5, sinks=[view, *sinks], on_snapshot=snapped,
                            on_stopping=lambda files: live.console.print(stopping(files), markup=False,
                                                                         highlight=False, soft_wrap=True))


def _named_apart(opened: Opened, url: str, **options) -> Opened:
    """``url`` opened under the name its device gives itself (a controller's kind, a DBC's or EDS's
    file, ``rig``), or, where a device opened before has that name, the name with ``-2``, ``-3``
    ... (the summary and the file then say which is which, not ``dev0``/``dev1``)."""
    taken = {s.name for s in opened.sources}
    first = open_url(url, **options)
    if not taken & {s.name for s in first.sources}:
        return first
    base = first.sources[0].name.split(".")[0]  # a DBC device's sources are NAME.MESSAGE
    first.close()
    k = 2
    while any(n == f"{base}-{k}" or n.startswith((f"{base}-{k}-", f"{base}-{k}.")) for n in taken):
        k += 1
    return open_url(url, name=f"{base}-{k}", **options)


@click.command("record")
@click.option("--device", "devices", multiple=True, metavar="URL", envvar="AMBDAQ_DEVICE",
              help="Device URL, e.g. sim://spindle?seed=3 (repeatable).")
@click.option("--rig", "rig_path", type=click.Path(dir_okay=False), help="Rig file (TOML) listing devices.")
@click.option("--duration", type=DURATION, metavar="SECONDS",
              help="Recording length; default: until Ctrl-C.")
@speed_option
@click.option("--truth", is_flag=True, help="Also record /truth/... topics (simulated rigs).")
@click.option("--reconnect", is_flag=True,
              help="Reopen a device that is lost and go on recording; the gap is marked in the file.")
@a2l_option
@measure_option
@click.option("--live", "live_port", type=click.IntRange(0, 65535), is_flag=False, flag_value=8765, metavar="[PORT]",
              help="Serve the topics to Foxglove over its WebSocket protocol while recording (default port 8765; "
                   "0: any free one); the file keeps every sample (docs/live.md).")
@click.option("--live-host", default="127.0.0.1", show_default=True,
              help="Address the live view listens on; anything but loopback is warned about.")
@click.option("--live-rate", type=POSITIVE, default=100.0, show_default=True, metavar="HZ",
              help="Samples per second and topic sent to the live view.")
@snapshot_options
@output_options
@report_options
def command(devices, rig_path, duration, speed, truth, reconnect, description, measure, live_port, live_host, live_rate,
            snapshot, out, quiet, as_json):
    """Record devices in real time into an MCAP file.

    \b
    Examples:
      ambdaq record --device sim://spindle --duration 10 --rpm 30000 -o run.mcap
      ambdaq record --rig lab.toml --split-duration 60 -o long.mcap
      ambdaq record --device xcp+tcp://127.0.0.1:5555 --a2l spindle.a2l --duration 10 -o run.mcap
      ambdaq record --device xcp+udp://127.0.0.1:5555 --a2l ecu.a2l --measure 'Motor*' --duration 10 -o ecu.mcap
      ambdaq record --device sim://spindle --snapshot 30s --trigger fault --trigger 'excursion>0.5' -o event.mcap
    """
    if not devices and not rig_path:
        raise BadInputError("nothing to record: give --device URL or --rig FILE")
    rig = load_rig(rig_path) if rig_path else None
    if measure:
        description = {**(description or {}), "measurements": list(measure)}
    with Opened() as opened:  # however the recording ends, every device and simulated rig is closed
        for url in devices:
            opened.add(_named_apart(opened, url, speed=speed, truth=truth or None, description=description))
        for d in rig.devices if rig is not None else ():
            opened.add(open_url(d.url, name=d.name, speed=speed or d.rpm, truth=truth or None,
                                calibration=d.calibration, description=d.description))
        run_recording(opened.sources, out, duration=duration, quiet=quiet, as_json=as_json, rig=rig,
                      reconnect=reconnect,
                      live=None if live_port is None else LiveOptions(live_port, live_host, live_rate),
                      snapshot=snapshot)
