"""Options shared by several commands, defined once."""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import click

from ..errors import BadInputError

SIZE_UNITS = {"": 1, "k": 10**3, "m": 10**6, "g": 10**9, "ki": 2**10, "mi": 2**20, "gi": 2**30}


class FinitePositive(click.FloatRange):
    """A finite number above 0 (click's FloatRange lets ``nan`` and ``inf`` through)."""

    def __init__(self) -> None:
        super().__init__(min=0, min_open=True)

    def convert(self, value, param, ctx):
        out = super().convert(value, param, ctx)
        if not math.isfinite(out):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return out


POSITIVE = FinitePositive()
"""The type of every option that takes a duration, an amplitude or a limit above 0."""


class RangeArg(click.ParamType):
    """A range ``LO:HI`` of finite numbers, 0 <= LO < HI, in ``unit``."""

    def __init__(self, name: str, unit: str, example: str) -> None:
        self.name, self.unit, self.example = name, unit, example

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        try:
            lo, hi = (float(v) for v in str(value).split(":"))
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
                raise ValueError
        except ValueError:
            self.fail(f"{value!r}: expected {self.name} in {self.unit}, {self.name.split(':')[0]} below "
                      f"{self.name.split(':')[1]}, e.g. {self.example}", param, ctx)
        return lo, hi


SPEED_RANGE = RangeArg("FROM:TO", "rpm", "0:50000")


class ByteSize(click.ParamType):
    """A size in bytes: ``500000``, ``100M``, ``1G``, ``64MiB``."""

    name = "SIZE"

    def convert(self, value, param, ctx):
        if isinstance(value, int):
            return value
        m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmg]i?)?b?\s*", str(value).lower())
        if not m:
            self.fail(f"{value!r} is not a size: expected e.g. 500000, 100M, 1G, 64MiB", param, ctx)
        size = int(float(m.group(1)) * SIZE_UNITS[m.group(2) or ""])
        if size <= 0:
            self.fail("size must be > 0", param, ctx)
        return size


@dataclass(frozen=True)
class Output:
    """Where and how a recording command writes: -o, splitting, compression, overwrite, fsync, indexes."""

    path: Path
    split_size: int | None = None
    split_duration_s: float | None = None
    compression: str = "zstd"
    overwrite: bool = False
    fsync: bool = True
    index: bool = True


def output_options(command):
    """-o, splitting, compression, overwrite, fsync, indexes: handed to the command as one ``out: Output``."""

    @functools.wraps(command)
    def bundled(*args, output, split_size, split_duration, compression, overwrite, fsync, index, **kwargs):
        return command(*args, out=Output(Path(output), split_size, split_duration, compression, overwrite, fsync,
                                         index), **kwargs)

    f = click.option("--index/--no-index", default=True, show_default=True,
                     help="Write the message and chunk indexes: Foxglove then seeks in the file and opens any "
                          "length. --no-index: files 0.63x the size (smaller than zstd Parquet of the same "
                          "values) that ambdaq reads as fast, the official reader streams, and Foxglove reads "
                          "whole before it shows them (up to 1 GB: split longer recordings). "
                          "See docs/data-format.md.")(bundled)

    f = click.option("--fsync/--no-fsync", default=True, show_default=True,
                     help="Force every flushed chunk (twice a second) to the disk; --no-fsync leaves it to the OS "
                          "(a power cut may then lose what the OS still held).")(f)
    f = click.option("--overwrite", is_flag=True, help="Replace existing output files.")(f)
    f = click.option("--compression", type=click.Choice(["zstd", "lz4", "none"]), default="zstd", show_default=True,
                     help="Chunk compression.")(f)
    f = click.option("--split-duration", type=DURATION, metavar="SECONDS",
                     help="Start a new file every SECONDS on the host clock from the start (NAME_000.mcap, "
                          "NAME_001.mcap ...); each sample goes to the part its time falls in.")(f)
    f = click.option("--split-size", type=ByteSize(), help="Start a new file when one reaches SIZE (e.g. 100M).")(f)
    f = click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Output MCAP file.")(f)
    return f


def report_options(f):
    """-q and --json."""
    f = click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary on stdout.")(f)
    f = click.option("-q", "--quiet", is_flag=True, help="No progress or summary on the terminal.")(f)
    return f


def max_lost_option(f):
    """--max-lost SHARE: the data-quality gate's limit on samples lost per input (:mod:`ambdaq.daq.quality`)."""
    from ..daq.quality import MAX_LOST

    return click.option(
        "--max-lost", type=click.FloatRange(0.0, 1.0), default=MAX_LOST, show_default=True, metavar="SHARE",
        help="Refuse an input that lost more than this share of its samples (0.001 = 0.1 %).",
    )(f)


def speed_option(f):
    return click.option(
        "--rpm", "speed", metavar="SPEED",
        help="Rotor speed: RPM, FROM:TO (ramp over the run), FROM:TO:SECONDS, or slowroll (800 rpm).",
    )(f)


def speed_restored_note(quiet: bool):
    """What a measurement that took ``--rpm`` says when it has set the controller's speed back
    (:func:`ambdaq.workflows.speed_restore.speed_restored`): the speed, or why it could not."""
    def say(rpm_or_error) -> None:
        if isinstance(rpm_or_error, Exception):
            click.echo(f"ambdaq: warning: could not set the speed back: {rpm_or_error}", err=True)
        elif not quiet:
            click.echo(f"speed set back to {rpm_or_error:,.0f} rpm, as before the measurement", err=True)

    return say


def excited_run_options(f):
    """The options of a closed-loop measurement's runs (``iso stability``, ``plant identify``), the
    ones :func:`excited_runs` takes: --axes, --amplitude, --duration, --settle, --runs, and the
    --resolution their responses are estimated at."""
    for option in reversed([
        click.option("--axes", help="Comma-separated axes to excite (every axis of a coupled set); default: every "
                                    "axis of the test-signal input."),
        click.option("--amplitude", type=POSITIVE, default=2.0, show_default=True,
                     help="RMS of the white-noise test signal: um for a displacement input, else the input's unit."),
        click.option("--duration", type=DURATION, default=10.0, show_default=True, metavar="SECONDS",
                     help="Per axis and speed."),
        click.option("--settle", type=DURATION, default=60.0, show_default=True, metavar="SECONDS",
                     help="Longest wait for the rotor to reach each speed (--rpm)."),
        click.option("--runs", "runs_dir", type=click.Path(file_okay=False),
                     help="Where the measured recordings go; default: beside -o, in NAME_runs/."),
        click.option("--resolution", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
                     help="Frequency step, Hz."),
    ]):
        f = option(f)
    return f


def excited_runs(command: str, recordings, device: str | None, description: dict | None, speeds: list[float] | None,
                 axes: str | None, amplitude: float, duration: float, settle: float, runs_dir: str | None, out: Path,
                 overwrite: bool, quiet: bool) -> list[Path]:
    """The runs a closed-loop measurement works on (``iso stability``, ``plant identify``): recorded
    on ``device``, one white-noise run per axis and speed into ``runs_dir`` (default beside ``out``
    in NAME_runs/), each announced, the test signal switched off after each and the speed set back;
    or ``recordings`` as given.  Either one, never both; ``out`` must be new unless ``overwrite``."""
    from ..workflows.iso_stability import measure

    if bool(recordings) == bool(device):
        raise BadInputError(f"{command} takes either --device URL (measure) or recordings, not both or neither")
    if description and not device:
        raise BadInputError("--a2l names the A2L of the controller measured with --device; recordings need none")
    if out.exists() and not overwrite:
        raise BadInputError(f"{out} exists: choose another -o or pass --overwrite")
    if not device:
        return [Path(p) for p in recordings]
    where = Path(runs_dir) if runs_dir else out.with_name(out.stem + "_runs")

    def announce(axis, rpm, path):
        if not quiet:
            at = "at the present speed" if rpm is None else f"at {rpm:,.0f} rpm"
            click.echo(f"exciting {axis} {at} for {duration:g} s -> {path}", err=True)

    paths = measure(device, speeds, [a.strip() for a in axes.split(",")] if axes else None, amplitude, duration, where,
                    settle_s=settle, overwrite=overwrite, on_run=announce, description=description,
                    on_restore=speed_restored_note(quiet))
    if not quiet:
        click.echo("test signal switched off after each run", err=True)
    return paths


def a2l_option(f):
    """--a2l FILE, given to the command as the device description ``{"a2l": absolute path}``
    (None without it), as a rig file's ``a2l`` is."""
    return click.option(
        "--a2l", "description", type=click.Path(dir_okay=False), metavar="FILE",
        callback=lambda _ctx, _param, value: {"a2l": str(Path(value).resolve())} if value else None,
        help="The A2L file of an XCP controller (xcp+tcp://...); else a2l=FILE in its URL or the rig file.",
    )(f)


def measure_option(f):
    """--measure NAME_OR_GLOB (repeatable): what to record of an XCP controller's A2L, given to
    the command as ``measure`` (a list, empty without it)."""
    return click.option(
        "--measure", "measure", multiple=True, metavar="NAME_OR_GLOB",
        help="An A2L measurement (or a glob of them) to record from an XCP device (repeatable); default: the ones "
             "an ambdaq annotation places. ambdaq xcp list FILE lists them.",
    )(f)


def window_options(f):
    f = click.option("--end", type=float, metavar="SECONDS", help="End of the time window (s from the start).")(f)
    f = click.option("--start", type=float, metavar="SECONDS", help="Start of the time window (s from the start).")(f)
    return f


class ExcitationArg(click.ParamType):
    """``AXIS:AMPLITUDE[:FREQ_HZ]``: white noise of that RMS, or a sine of that peak and frequency.
    The amplitude is in the unit of the rig's feedforward: um (spindle), V (base-motion)."""

    name = "AXIS:AMP[:HZ]"

    def convert(self, value, param, ctx):
        from ..drivers.excitation import ExcitationRequest

        if isinstance(value, ExcitationRequest):
            return value
        parts = str(value).split(":")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            return ExcitationRequest(parts[0], float(parts[1]), float(parts[2]) if len(parts) == 3 else 0.0)
        except ValueError:
            self.fail(f"{value!r}: expected AXIS:AMPLITUDE[:FREQ_HZ], e.g. front_x:2 (2 um RMS white noise), "
                      "front_x:5:120 (5 um sine at 120 Hz), amb1_y:0.05 (base-motion: 0.05 V RMS)", param, ctx)


def excitation_option(f):
    return click.option(
        "--excite", "excitation", type=ExcitationArg(),
        help="Test signal added to one axis's feedforward (frequency-response measurement): AXIS:AMP for "
             "white noise of that RMS, AXIS:AMP:HZ for a sine of that peak; AMP in um where the controller's input "
             "is a displacement (spindle), else in its unit (V: base-motion).",
    )(f)


class Seconds(click.ParamType):
    """A time: ``30``, ``30s``, ``500ms``, ``2min``, in s (finite, above 0)."""

    name = "SECONDS"
    UNITS = {"": 1.0, "s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
    LONGEST = 1e7  # 116 days: a longer time is a typing error, not a recording

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)):
            seconds = float(value)
        else:
            m = re.fullmatch(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*(s|ms|min|h)?\s*", str(value))
            if not m:
                self.fail(f"{value!r} is not a time: expected e.g. 10, 10s, 500ms, 2min, 1h", param, ctx)
            seconds = float(m.group(1)) * self.UNITS[m.group(2) or ""]
        if not 0 < seconds <= self.LONGEST:
            self.fail(f"{value!r} is not a time above 0 and up to {self.LONGEST:,.0f} s", param, ctx)
        return seconds


DURATION = Seconds()
"""The type of every option that takes a duration: ``10``, ``10s``, ``500ms``, ``2min``, ``1h``."""


def snapshot_options(command):
    """--snapshot, --post, --trigger, --cmin, --snapshot-memory: handed to the command as one
    ``snapshot: SnapshotOptions | None`` (triggers parsed here, so a bad one is exit 2 before anything opens)."""
    from ..acquisition.snapshot import SnapshotOptions
    from ..acquisition.triggers import ManualTrigger, parse_trigger

    @functools.wraps(command)
    def bundled(*args, snapshot_s, post_s, triggers, cmin_um, snapshot_memory, **kwargs):
        if snapshot_s is None:
            if triggers or post_s is not None:
                raise BadInputError("--trigger and --post need --snapshot SECONDS (the time kept before a trigger)")
            return command(*args, snapshot=None, **kwargs)
        parsed = [parse_trigger(t) for t in triggers] or [ManualTrigger()]
        return command(*args, snapshot=SnapshotOptions(snapshot_s, 5.0 if post_s is None else post_s,
                                                       snapshot_memory, parsed,
                                                       None if cmin_um is None else cmin_um * 1e-6), **kwargs)

    f = click.option("--snapshot-memory", type=ByteSize(), default="1G", show_default=True,
                     help="Most memory the snapshot may hold (all devices); a --snapshot that needs more is refused.")(
        bundled)
    f = click.option("--cmin", "cmin_um", type=POSITIVE, metavar="UM",
                     help="Minimum clearance (the touchdown bearings'), um, for the excursion and touchdown triggers; "
                          "default: the devices' calibration (machine.min_clearance_m).")(f)
    f = click.option("--trigger", "triggers", multiple=True, metavar="EXPR",
                     help="What writes a snapshot (repeatable): fault, manual, excursion>F (F of Cmin), "
                          "touchdown[:8A|:25V], speed:LO..HI (rpm), TOPIC.FIELD>V, TOPIC.FIELD<V, |TOPIC.FIELD|>V. "
                          "SIGUSR1 and Enter always fire (docs/live.md).")(f)
    f = click.option("--post", "post_s", type=DURATION, metavar="SECONDS",
                     help="Time written after a trigger (default 5s).")(f)
    f = click.option("--snapshot", "snapshot_s", type=DURATION, metavar="SECONDS",
                     help="Keep the last SECONDS in memory and write NAME_<time>_<cause>.mcap around each trigger "
                          "instead of one recording.")(f)
    return f


class ImagePath(click.ParamType):
    """An image file to write: its suffix must be one matplotlib writes (png, pdf, svg ...),
    checked before any work is done."""

    name = "IMAGE"

    def convert(self, value, param, ctx):
        from ..figures import image_formats

        path = Path(value)
        if path.is_dir():
            self.fail(f"{value!r} is a directory", param, ctx)
        formats = image_formats()
        if path.suffix.lstrip(".").lower() not in formats:
            self.fail(f"{value!r}: an image needs one of the suffixes {', '.join('.' + k for k in sorted(formats))}",
                      param, ctx)
        return str(path)


def plot_option(help_text: str):
    """``--plot IMAGE``: where a command draws its figure."""
    return click.option("--plot", "plot_path", type=ImagePath(), help=help_text)


def critical_limits_options(command):
    """--critical-tolerance, --af-tolerance, --critically-damped: how a run-up's critical speeds are
    verified against a --model, handed to the command as one ``limits: CriticalLimits`` (the
    defaults API 684's, docs/iso.md)."""
    from ..analysis.orders import AMPLIFICATION_TOLERANCE, CRITICAL_AMPLIFICATION, SPEED_TOLERANCE, CriticalLimits

    @functools.wraps(command)
    def bundled(*args, critical_tolerance, af_tolerance, critically_damped, **kwargs):
        return command(*args, limits=CriticalLimits(critical_tolerance / 100, af_tolerance / 100, critically_damped),
                       **kwargs)

    f = click.option("--critically-damped", type=click.FloatRange(1.0, 100.0), default=CRITICAL_AMPLIFICATION,
                     show_default=True, metavar="AF",
                     help="Amplification factor below which a mode is critically damped and a 1X peak no critical "
                          "speed (API 684).")(bundled)
    f = click.option("--af-tolerance", type=click.FloatRange(0.0, 100.0), default=AMPLIFICATION_TOLERANCE * 100,
                     show_default=True, metavar="PCT",
                     help="How much more amplified than the model predicts a measured critical speed may be, %.")(f)
    return click.option("--critical-tolerance", type=click.FloatRange(0.0, 50.0, min_open=True),
                        default=SPEED_TOLERANCE * 100, show_default=True, metavar="PCT",
                        help="A measured critical speed is the predicted one within this much of its speed, % "
                             "(API 684's run-up against the model).")(f)
