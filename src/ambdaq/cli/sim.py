"""``ambdaq sim``: the simulated rigs outside real time."""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from ..documents.coefficients import Coefficients, fir_array
from ..drivers.excitation import TEST_SIGNAL_RECORD
from ..machines.base_motion import PLANES
from ..errors import BadInputError
from ..sim.profiles import PROFILES, profile as rig_profile
from ..sim.source import SimSource
from ..speed import SpeedProfile
from ..sim.devices.banks import DEFAULT_UNLOCK_KEY
from .options import DURATION, POSITIVE, excitation_option, output_options, report_options, snapshot_options, speed_option
from .record import run_recording

if TYPE_CHECKING:
    from ..sim.rigs.base_motion import BaseExcitation


@click.group("sim")
def command() -> None:
    """Simulated rigs: generate data unpaced."""


@command.command("generate")
@click.option("--profile", type=click.Choice(sorted(PROFILES)), default="spindle", show_default=True)
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed; the run is deterministic per seed.")
@speed_option
@click.option("--duration", type=DURATION, required=True, metavar="SECONDS")
@click.option("--truth", is_flag=True, help="Also write /truth/runout and /truth/position.")
@click.option("--ff", type=click.Choice(["off", "lms"]), default="off", show_default=True,
              help="Feedforward of the simulated controller (lms: Ro et al.'s adaptive runout cancellation).")
@click.option("--noise/--no-noise", default=True, show_default=True, help="Sensor noise and A/D, D/A quantisation.")
@excitation_option
@click.option("--base", metavar="SPEC", help="Base motion (base-motion rig): sine:HZ:AMP[:ALPHA_MAG[:ALPHA_DEG]] "
              "or noise:LO-HI:RMS, in m/s^2; ALPHA = d1/d2, the ratio of the two bearings' base accelerations.")
@click.option("--fir", "fir_file", type=click.Path(dir_okay=False),
              help="Base-motion rig: run its feedforward u = W d with the FIR of this coefficient file (ambdaq fx fit).")
@click.option("--impact", metavar="AXIS:PEAK_N[:EVERY_S]",
              help="Cone rig: instrumented-hammer strikes on a bearing coordinate (x, y1, y2, z1, z2), a 0.5 ms "
                   "half-sine of PEAK_N newtons from 0.2 s, every EVERY_S s (default 0.5).")
@click.option("--start", type=click.Choice(["levitated", "touchdown"]), default="levitated", show_default=True,
              help="Cone rig: start levitated, or at rest on the touchdown bearings with the amplifiers just enabled.")
@click.option("--drop", metavar="AT_S:DURATION_S",
              help="Cone and spindle rigs: the amplifiers off at AT_S for DURATION_S (a power loss): the rotor drops "
                   "onto its touchdown bearings, then levitates again.")
@click.option("--trial", "trials", metavar="PLANE:GRAMS@DEG[:RADIUS_MM]", multiple=True,
              help="Spindle and cone rigs: a trial mass on a balancing plane (the spindle's front, rear; the cone's upper, "
                   "lower), its angle from the key-phasor's mark in the direction of rotation; the radius the "
                   "machine's balancing holes' by default (spindle 30 mm, cone 25 mm).")
@click.option("--correction", "corrections", metavar="PLANE:GRAMS@DEG[:RADIUS_MM]", multiple=True,
              help="Spindle and cone rigs: a correction mass, as --trial (recorded as the rig's masses either way).")
@click.option("--unbalance", metavar="UPPER_KGM:LOWER_KGM[:DEG]",
              help="Cone rig: a mass unbalance at its two bearing planes, kg m, the lower one DEG ahead (Jeong et al. "
                   "give none, so the rig has none unless asked); --trial and --correction masses add to it.")
@click.option("--param", "params", metavar="NAME=VALUES", multiple=True,
              help="Write a parameter of the rig's controller before the run, as `ambdaq controller param NAME VALUES` "
                   "does on the served one: VALUES comma-separated (e.g. pid.d=0.00075,0.00075,0.001,0.001,0.002). "
                   "Repeat for more.")
@snapshot_options
@output_options
@report_options
def generate(profile, seed, speed, duration, truth, ff, noise, excitation, base, fir_file, impact, start, drop,
             trials, corrections, unbalance, params, snapshot, out, quiet, as_json):
    """Run a simulated rig as fast as it goes and write the same MCAP a recording would.

    \b
    Example:
      ambdaq sim generate --duration 60 --rpm 0:50000 --truth -o runup.mcap
      ambdaq sim generate --duration 20 --excite front_x:2 -o frf_front_x.mcap
      ambdaq sim generate --profile base-motion --duration 10 --base noise:5-100:1 -o base.mcap
      ambdaq sim generate --profile cone --duration 3 --impact x:50 -o impact.mcap
      ambdaq sim generate --profile cone --start touchdown --duration 2 --snapshot 0.5s --trigger touchdown -o td.mcap
      ambdaq sim generate --profile cone --rpm 600 --drop 0.5:0.2 --duration 2 --snapshot 0.3s --post 0.7s \
          --trigger touchdown -o drop.mcap
      ambdaq sim generate --rpm 3000:15000:6 --duration 6 --param pid.d=0.00075,0.00075,0.001,0.001,0.002 -o detuned.mcap
    """
    source = SimSource(profile, seed=seed, speed=SpeedProfile.parse(speed or "0"), truth=truth, ff_mode=ff, noise=noise)
    records = {}  # the test signal, said in the file as frf measure says it
    try:
        if excitation is not None:
            if "excitation" not in source.rig.inputs:
                raise BadInputError(f"--excite: the {profile} rig has no test-signal input")
            spec = source.rig.excitation_spec()
            resolved = excitation.resolve(spec)
            source.rig.set_excitation(resolved)
            records[TEST_SIGNAL_RECORD] = resolved.record(source.name, spec)
        if base is not None:
            motion = _base_motion(profile, base)  # refused before the rig is asked
            source.rig.set_base_motion(motion)
        if fir_file is not None:
            if "fir" not in source.rig.inputs:
                raise BadInputError(f"--fir: the {profile} rig has no FIR feedforward (use --profile base-motion)")
            taps, rate = fir_array(Coefficients.load(fir_file), list(PLANES), fir_file)
            if rate != source.rig.params.sample_rate:
                raise BadInputError(f"{fir_file}: its FIR runs at {rate:g} Hz, the rig at {source.rig.params.sample_rate:g} Hz")
            source.rig.set_feedforward_fir(taps)
        if impact is not None or start != "levitated":
            if "impact" not in source.rig.inputs:
                raise BadInputError(f"--impact/--start: the {profile} rig has no hammer or touchdown bearings (use --profile cone)")
            from ..sim.rigs.cone import Impact

            source.rig.set_impact(None if impact is None else Impact.parse(impact))
            source.rig.restart(start)
        if drop is not None:
            if "drop" not in source.rig.inputs:
                raise BadInputError(f"--drop: the {profile} rig has no touchdown bearings to drop onto "
                                    "(the cone and spindle rigs have)")
            from ..sim.rigs.drop import Drop

            source.rig.set_drop(Drop.parse(drop))
        if unbalance is not None:
            if "unbalance" not in source.rig.inputs:
                raise BadInputError(f"--unbalance: the {profile} rig's unbalance is its own (use --profile cone)")
            from ..sim.rigs.cone import Unbalance

            source.rig.set_unbalance(Unbalance.parse(unbalance))
        if trials or corrections:
            if "balancing" not in source.rig.inputs:
                raise BadInputError(f"--trial/--correction: the {profile} rig has no balancing planes (the spindle "
                                    "and cone rigs have)")
            from ..machines.balance_masses import BalanceMass

            rig = source.rig
            source.rig.add_masses([BalanceMass.parse(spec, rig.balance_planes, rig.params.balance_radius)
                                   for spec in (*trials, *corrections)])
        for spec in params:
            _write_param(source.rig, profile, spec)
    except ValueError as err:
        raise BadInputError(str(err)) from None
    run_recording([source], out, duration=duration, quiet=quiet, as_json=as_json, snapshot=snapshot, records=records)


@command.command("fleet")
@click.option("-o", "--output", "folder", type=click.Path(file_okay=False), required=True,
              help="Folder for the recordings: FOLDER/<machine>/<machine>_<date>.mcap.")
@click.option("--machines", type=click.IntRange(1, 1000), default=10, show_default=True)
@click.option("--days", type=click.IntRange(1, 3650), default=4, show_default=True, help="One recording a day each.")
@click.option("--duration", type=DURATION, default=1.0, show_default=True, metavar="SECONDS", help="Each recording's.")
@click.option("--rpm", type=POSITIVE, default=30000.0, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True, help="Everything follows from it.")
@click.option("--drop-chance", type=click.FloatRange(0, 1), default=0.15, show_default=True,
              help="Chance that a recording lost a run of samples.")
def fleet(folder, machines, days, duration, rpm, seed, drop_chance):
    """Record a fleet of simulated spindles once a day: each its own runout, an unbalance that grows,
    occasional drops (what `ambdaq fleet scan` is tested on).

    \b
    Example:
      ambdaq sim fleet --machines 10 --days 4 -o fleet/ && ambdaq fleet scan fleet/ -o fleet.parquet
    """
    from ..studies.simulated_fleet import generate_fleet

    paths = generate_fleet(Path(folder), n_machines=machines, days=days, duration_s=duration, rpm=rpm, seed=seed,
                           drop_chance=drop_chance)
    size = sum(p.stat().st_size for p in paths) / 1e6
    click.echo(f"{len(paths)} recordings of {machines} machines over {days} days ({size:.1f} MB) -> {folder}", err=True)


@command.command("serve")
@click.option("--profile", type=click.Choice(sorted(PROFILES)), default="spindle", show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@speed_option
@click.option("--truth", is_flag=True, help="The controller also streams /truth/runout and /truth/position.")
@click.option("--drift-ppm", type=float, default=50.0, show_default=True, help="Controller clock rate error.")
@click.option("--unlock-key", default=DEFAULT_UNLOCK_KEY, show_default=True,
              help="The key the controller wants before its coefficient banks can be written (ambdaq push).")
@click.option("--base", metavar="SPEC", help="Base motion of the base-motion rig's simulated shaker (as for generate).")
@click.option("--can", "can", type=click.Choice(["none", "slcan"]), default="none", show_default=True,
              help="Serve the rig's CANopen devices through a simulated SLCAN USB-CAN adapter on a pseudo-terminal.")
@click.option("--third-party", is_flag=True,
              help="With --can: also serve devices described by vendor files, not by ambdaq (a probe conditioner "
                   "sending the raw frames of its DBC, a CiA 402 drive known by its EDS; docs/hardware.md).")
@click.option("--xcp", "xcp", metavar="tcp:PORT|sxi|can",
              help="Also serve the controller's XCP slave: XCP on TCP on 127.0.0.1:PORT (tcp:0: a free port), "
                   "XCP on SxI on a pseudo-terminal, or XCP on CAN on the rig's bus (with --can slcan); it prints "
                   "its xcp+... URL; its A2L: ambdaq sim a2l.")
@click.option("--xcp-daq", type=click.Choice(["dynamic", "static"]), default="dynamic", show_default=True,
              help="With --xcp: DAQ lists the master allocates (dynamic), or a fixed set it fills (static, as many "
                   "ECUs have).")
@click.option("--duration", type=DURATION, metavar="SECONDS",
              help="Stop after this long; default: until Ctrl-C.")
def serve(profile, seed, speed, truth, drift_ppm, unlock_key, base, can, third_party, xcp, xcp_daq, duration):
    """Run a simulated rig in this process with its devices on real transports.

    Prints one line per pseudo-terminal, NAME PATH, and with --can one per CANopen device,
    KIND URL; then serves until Ctrl-C:

    \b
      ambdaq sim serve --rpm 30000 &
      ambdaq record --device serial:///dev/pts/N --duration 10 -o run.mcap
      ambdaq sim serve --rpm 30000 --can slcan &
      ambdaq record --device 'can://slcan/dev/pts/M?node=16&open_delay=0' --duration 10 -o can.mcap
      ambdaq sim serve --rpm 30000 --xcp tcp:5555 &
      ambdaq record --device xcp+tcp://127.0.0.1:5555 --a2l spindle.a2l --duration 10 -o xcp.mcap
    """
    from ..sim.devices.rig_server import DeviceClock
    from ..sim.serve import CONTROLLER_CLOCK, serve

    if xcp is not None and xcp not in ("sxi", "can"):
        kind, _, port = xcp.partition(":")
        if kind != "tcp" or not port.isdigit() or int(port) > 65535:
            raise BadInputError(f"--xcp {xcp!r}: expected tcp:PORT, sxi or can")
    if xcp == "can" and can != "slcan":
        raise BadInputError("--xcp can serves XCP on the rig's CAN bus: give --can slcan as well (another "
                            "process reaches the bus through the simulated SLCAN adapter)")
    if third_party and can == "none":
        raise BadInputError("--third-party serves CAN devices: give --can slcan as well")
    motion = None if base is None else _base_motion(profile, base)
    served = serve(profile, seed=seed, speed=SpeedProfile.parse(speed or "0"), truth=truth, unlock_key=unlock_key,
                   clock=DeviceClock(CONTROLLER_CLOCK.offset_ns, drift_ppm), base_motion=motion,
                   can=None if can == "none" else can, third_party=third_party, xcp=xcp,
                   static_daq=xcp_daq == "static")
    for name, pty in served.ptys.items():
        if name != "xcp":
            click.echo(f"{name} {pty.path}")
    for name, url in served.urls.items():
        if url.startswith(("can://", "xcp+")):
            click.echo(f"{name} {url}")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda s, f: stop.set())
    try:
        stop.wait(duration)
    finally:
        adapter = served.devices.get("can")
        served.stop()
        if adapter is not None:
            click.echo(f"can: {adapter.frames_from_host} frames from the host, {adapter.frames_to_host} to it, "
                       f"{adapter.lost} lost (the terminal's backlog was full)", err=True)


@command.command("a2l")
@click.option("--profile", type=click.Choice(sorted(PROFILES)), default="spindle", show_default=True)
@click.option("--truth", is_flag=True, help="The slave of `sim serve --truth`, with the /truth/... measurements.")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Write it here instead of stdout.")
def a2l(profile, truth, out):
    """The A2L (ASAM MCD-2 MC) file of the simulated controller's XCP slave: its measurements,
    their addresses, types and units.

    \b
      ambdaq sim a2l -o spindle.a2l
    """
    from ..sim.devices.xcp_memory import a2l_text

    text = a2l_text(rig_profile(profile).build(truth=truth))
    if out is None:
        click.echo(text, nl=False)
    else:
        with open(out, "w") as fh:
            fh.write(text)


def _write_param(rig, profile: str, spec: str) -> None:
    """``--param NAME=VALUES``: write the controller parameter NAME of the rig's firmware, checked as
    the served controller checks a PARAM_WRITE (docs/protocol.md)."""
    name, sep, text = spec.partition("=")
    firmware = rig_profile(profile).firmware
    param = None if firmware is None else firmware.parameters.get(name)
    if not sep or param is None:
        known = "none" if firmware is None else ", ".join(n for n, p in sorted(firmware.parameters.items()) if p.write)
        raise BadInputError(f"--param {spec!r}: NAME=VALUES with a writable parameter of the {profile} rig's "
                            f"controller ({known})")
    if param.write is None:
        raise BadInputError(f"--param {name}: read-only")
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise BadInputError(f"--param {name}: {text!r} is not comma-separated numbers") from None
    problem = param.check(rig, values)
    if problem:
        raise BadInputError(f"--param {name}: {problem}")
    param.write(rig, values)


def _base_motion(profile: str, spec: str) -> BaseExcitation:
    """``--base SPEC`` for the ``profile`` rig; one line (BadInputError) if it has no moving base or
    the spec is wrong."""
    if "base" not in rig_profile(profile).rig.inputs:
        raise BadInputError(f"--base: the {profile} rig has no moving base (use --profile base-motion)")
    try:
        from ..sim.rigs.base_motion import BaseExcitation  # a rig module: loaded for the rig that needs it

        return BaseExcitation.parse(spec)
    except ValueError as err:
        raise BadInputError(str(err)) from None
