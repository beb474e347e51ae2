"""``ambdaq fleet``: every recording of every machine as one Parquet dataset, scanned on Dask, and the
trends over it (docs/fleet.md)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import click

from ..errors import BadInputError, DeviceError
from .options import POSITIVE, plot_option


def _client(scheduler: str | None, workers: int):
    """A Dask client: the scheduler named (or in DASK_SCHEDULER_ADDRESS), else a LocalCluster of
    ``workers`` processes on this machine."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise BadInputError("fleet needs dask.distributed, the fleet extra: pip install 'ambdaq[fleet]'") from None
    address = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS")
    if address:
        try:
            return Client(address, timeout="10s")
        except (OSError, TimeoutError) as err:
            raise DeviceError(f"--scheduler {address}: cannot reach the Dask scheduler ({err})") from None
    # on loopback only; the scheduler opens an HTTP server even without a dashboard, on a free port
    # here (on 8787, a second scan beside the first was told "Port 8787 is already in use")
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                           host="127.0.0.1")
    return Client(cluster)


@click.group("fleet")
def command() -> None:
    """Fleet analysis: scan every recording into one table, and trend it per machine."""


@command.command("scan")
@click.argument("inputs", nargs=-1, required=True, metavar="FOLDER_OR_GLOB...")
@click.option("-o", "--output", "dataset", type=click.Path(file_okay=False), required=True,
              help="The Parquet dataset (a folder, partitioned by machine), created or added to.")
@click.option("--scheduler", metavar="tcp://HOST:8786",
              help="A Dask scheduler to run on (default: $DASK_SCHEDULER_ADDRESS, else a local cluster).")
@click.option("--workers", type=click.IntRange(1, 256), default=os.cpu_count() or 1, show_default="the CPUs",
              help="Worker processes of the local cluster.")
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary.")
@click.option("--json", "as_json", is_flag=True, help="Print what was scanned as JSON.")
def scan_command(inputs, dataset, scheduler, workers, quiet, as_json):
    """One row per recording (or split part): machine, time, speed, drops, runout and 1X per axis and
    harmonic, the ISO 14839-2 zone; files already scanned and unchanged are skipped. Balancing
    records (balance ... --record) found there give the recordings they grade their ISO 21940-11
    balance grade.

    \b
    Examples:
      ambdaq fleet scan recordings/ -o fleet.parquet
      ambdaq fleet scan 'plant/**/*.mcap' -o fleet.parquet --scheduler tcp://10.0.0.5:8786
    """
    from ..workflows.fleet import add_balancing, balancing_records, check_layout, recordings, scan

    paths = recordings(inputs)
    records = balancing_records(inputs)
    check_layout(Path(dataset))  # a dataset this version cannot add to is refused before a cluster starts
    client = _client(scheduler, workers)
    try:
        progress = None
        if not quiet and not as_json:
            from rich.progress import Progress

            bar = Progress(transient=False)
            task = bar.add_task("scanning", total=None)
            bar.start()

            def progress(row, done, total):
                bar.update(task, completed=done, total=total)
        try:
            report = scan(paths, Path(dataset), client, on_row=progress)
        finally:
            if progress is not None:
                bar.stop()
    finally:
        client.close()
    record_errors = add_balancing(Path(dataset), records)
    if as_json:
        click.echo(json.dumps({"scanned": len(report.scanned), "unchanged": report.unchanged,
                               "balancing_records": len(records) - len(record_errors),
                               "balancing_errors": [{"path": p, "error": e} for p, e in record_errors],
                               "writing": report.writing, "errors": [{"path": p, "error": e} for p, e in report.errors],
                               "interrupted": report.interrupted, "seconds": round(report.seconds, 3),
                               "warm_s": round(report.warm_s, 3),
                               "bytes_read": report.bytes_read}, indent=2))
    elif not quiet:
        click.echo(f"{len(report.scanned)} scanned ({report.bytes_read / 1e6:.1f} MB in {report.seconds:.1f} s), "
                   f"{report.unchanged} unchanged, {len(report.writing)} being written -> {dataset}", err=True)
        for p in report.writing:
            click.echo(f"  skipped, no footer yet (being written?): {p}", err=True)
        for p, e in report.errors:
            click.echo(f"  error: {p}: {e}", err=True)
        if records:
            click.echo(f"{len(records) - len(record_errors)} balancing records", err=True)
        for p, e in record_errors:
            click.echo(f"  balancing record left out: {p}: {e}", err=True)
    if report.interrupted:
        raise DeviceError(f"interrupted: {len(report.scanned)} rows written to {dataset}; run the same scan "
                          "again to go on")


FIGURES = ("onex", "runout", "vibration")


@command.command("trend")
@click.argument("dataset", type=click.Path(exists=True, file_okay=False))
@click.option("--machine", help="The machine whose trend is plotted (default: every machine's summary).")
@click.option("--threshold", type=POSITIVE, default=5.0, show_default=True, metavar="UM",
              help="List machines whose 1X, runout or orbit moved more than this from their first recording.")
@click.option("--touchdown-limit", type=click.IntRange(min=1), default=10, show_default=True, metavar="DROPS",
              help="Rotor drops on record after which a machine's touchdown bearings are to be inspected (take the "
                   "bearing maker's rating).")
@click.option("--touchdown-energy", type=POSITIVE, metavar="J",
              help="... or after drops bringing this much impact energy in all.")
@plot_option("Trend plot of one --machine: 1X per axis, runout per harmonic, orbit against the zones (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the rows and the movements as JSON.")
def trend_command(dataset, machine, threshold, touchdown_limit, touchdown_energy, plot_path, as_json):
    """Trends over a fleet dataset, and the machines whose figures moved.

    \b
    Examples:
      ambdaq fleet trend fleet.parquet
      ambdaq fleet trend fleet.parquet --machine AMB-07 --plot amb07.png
    """
    import numpy as np

    from ..workflows.fleet import HARMONICS, axes_of, bearings_of, moved, read, touchdowns
    from ..workflows.runout import UNBALANCE_NEGLIGIBLE_RPM

    df = read(Path(dataset), machine)
    drops = touchdowns(df, count_limit=touchdown_limit, energy_limit_j=touchdown_energy)
    axes = axes_of(df)
    figures = ([f"onex_{a}_um" for a in axes] + [f"runout_{a}_{k}x_um" for a in axes for k in HARMONICS]
               + [f"vibration_{b}_um" for b in bearings_of(df)])
    movements = moved(df, figures, threshold)
    at_speed = int(((df["rpm_min"] > UNBALANCE_NEGLIGIBLE_RPM) & df["error"].isna()).sum())
    notes = [f"the 1X runout of {at_speed} recording{'s' if at_speed != 1 else ''} at speed (above "
             f"{UNBALANCE_NEGLIGIBLE_RPM:,.0f} rpm) holds the rotor's unbalance response there (one speed cannot tell "
             "them apart): its trend is runout and unbalance together; slow rolls trend the runout alone"] if at_speed else []
    if plot_path:
        if machine is None:
            raise BadInputError("--plot draws one machine's trend: give --machine")
        from ..figures import save
        from ..figures.fleet import draw_trend

        save(draw_trend(df, machine), plot_path)
    if as_json:
        cols = ["path", "machine", "start", "duration_s", "rpm_min", "rpm_max", "drops", "zone", "error", "note",
                "coefficients_sha256", "balance_grade_mm_s", "balance_grade", "latest_balance_grade_mm_s",
                "latest_balance_grade", *figures]
        rows = json.loads(df[cols].to_json(orient="records", date_format="iso"))
        click.echo(json.dumps({"rows": rows, "moved": [
            {"machine": m.machine, "figure": m.figure, "first_um": round(m.first, 3), "last_um": round(m.last, 3),
             "first": m.first_start, "last": m.last_start} for m in movements],
            "touchdowns": [{"machine": t.machine, "drops": t.count,
                            "energy_j": None if np.isnan(t.energy_j) else t.energy_j, "worst_ratio_cmin": t.worst_ratio,
                            "last": t.last, "inspect": t.inspect} for t in drops], "notes": notes}, indent=2))
        return
    for note in notes:
        click.echo(f"ambdaq: note: {note}", err=True)
    good = df[df["error"].isna()]
    # "lost": the samples the recordings lost (the dataset's drops column), not the rotor drops below
    click.echo(f"{'machine':10s} {'recordings':>10s} {'from':>17s} {'to':>17s} {'lost':>6s} {'zone now':>8s} "
               f"{'largest 1X now':>22s} {'balance grade':>20s} {'errors':>6s}")
    for m, rows in df.groupby("machine"):
        ok = good[good["machine"] == m].sort_values("start")
        last = ok.iloc[-1] if len(ok) else None
        one_x = {a: last[f"onex_{a}_um"] for a in axes if last is not None and np.isfinite(last[f"onex_{a}_um"])}
        biggest = f"{max(one_x.values()):.2f} um {max(one_x, key=one_x.get)}" if one_x else "-"
        graded = rows.dropna(subset=["balance_grade_mm_s"])  # the latest a record states, with its class
        grade = (f"{graded.iloc[-1]['balance_grade_mm_s']:.3g} mm/s {graded.iloc[-1]['balance_grade']}"
                 if len(graded) else "-")
        click.echo(f"{m:10s} {len(rows):10d} {str(ok['start'].min())[:16]:>17s} {str(ok['start'].max())[:16]:>17s} "
                   f"{int(rows['drops'].sum()):6d} {str(last['zone'] if last is not None else '-'):>8s} "
                   f"{biggest:>22s} {grade:>20s} {int(rows['error'].notna().sum()):6d}")
    if movements:
        click.echo(f"moved more than {threshold:g} um since the first recording:")
        for mv in movements:
            click.echo(f"  {mv.machine:10s} {mv.figure:22s} {mv.first:8.2f} -> {mv.last:8.2f} um "
                       f"({mv.change:+.2f}; {mv.first_start[:10]} -> {mv.last_start[:10]})")
    else:
        click.echo(f"no machine moved more than {threshold:g} um since its first recording")
    if drops:
        click.echo(f"rotor drops on record (ISO 14839-5; inspect at {touchdown_limit} drops"
                   + (f" or {touchdown_energy:g} J" if touchdown_energy else "") + "):")
        for t in drops:
            energy = "-" if np.isnan(t.energy_j) else f"{t.energy_j:.3g} J"
            click.echo(f"  {t.machine:10s} {t.count:4d} drops, {energy:>10s} in all, worst {t.worst_ratio:.2f} Cmin, "
                       f"last {t.last[:19]}" + ("  -> inspect the touchdown bearings" if t.inspect else ""))
