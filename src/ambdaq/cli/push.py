"""``ambdaq push`` and ``ambdaq controller status``: verified coefficient downloads."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click

from ..workflows.push import describe_difference, plan_controller_push, plan_push, plan_rollback, push, resolve_key
from ..workflows.push import rollback as roll_back
from ..documents.coefficients import Coefficients
from ..drivers.coefbank import BankImage
from ..drivers.registry import open_controller
from ..workflows.controller_params import values_text
from ..drivers.rigfile import load_rig
from ..errors import BadInputError, DeviceError
from .options import a2l_option, plot_option


def _target(device: str | None, rig: str | None, given: dict | None) -> tuple[str, str | None, dict]:
    """The device URL, the rig file's unlock key for it and its description (an XCP controller's
    A2L, from the rig file or ``--a2l``): ``--device`` is a URL or, with ``--rig``, a device name
    in the rig file."""
    given = given or {}
    if rig is None:
        if device is None:
            raise BadInputError("name the controller: --device URL (or --rig FILE with its unlock_key)")
        return device, None, given
    entries = load_rig(rig).devices
    chosen = [e for e in entries if device in (e.name, e.url)] if device else [e for e in entries if e.unlock_key]
    if len(chosen) != 1:
        raise BadInputError(f"{rig}: {'no' if not chosen else 'more than one'} device "
                            f"{'named ' + repr(device) if device else 'with an unlock_key'}; pass --device NAME")
    return chosen[0].url, chosen[0].unlock_key, {**chosen[0].description, **given}


def _controller_design(file: str):
    """The controller design in ``file`` (``controller design`` wrote it), or None for any other file."""
    from ..documents.sealed import read_json
    from ..workflows.controller_design import FORMAT, load_design

    try:  # a regular file of bounded size only (a FIFO or a device is never read)
        head = read_json(Path(file), "coefficient file")
    except BadInputError:
        return None  # Coefficients.load says what is wrong with it
    if not (isinstance(head, dict) and head.get("format") == FORMAT):
        return None
    design = load_design(file)
    if not design.meets_target:
        raise BadInputError(f"{file}: the design did not meet its target (controller design said why): not pushed")
    return design


@click.command("push")
@click.argument("file", type=click.Path(dir_okay=False), required=False)
@click.option("--device", metavar="URL", help="The controller: serial:PORT or can://IF/CH?node=N (or a name in --rig).")
@click.option("--rig", type=click.Path(dir_okay=False), help="Rig file: the controller's URL and unlock_key.")
@click.option("--key", help="Unlock key (else $AMBDAQ_UNLOCK_KEY, else the rig file's unlock_key).")
@a2l_option
@click.option("--dry-run", is_flag=True, help="Validate and print the difference from the active bank; write nothing.")
@click.option("--rollback", is_flag=True,
              help="Put back the bank the last push from this machine to --device replaced (no FILE).")
@click.option("--yes", is_flag=True, help="Do not ask before committing.")
def push_command(file, device, rig, key, description, dry_run, rollback, yes):
    """Download coefficient FILE into the controller: validate, write the inactive bank, check the
    device's CRC-32, commit at a control-period boundary, log. FILE may be a controller design
    (controller design): its PID and sections replace the controller's, the feedforward the active
    bank runs is kept. With --rollback, put back what the
    last push replaced, the same way (and --rollback again undoes that).

    \b
    Examples:
      ambdaq push coef.json --device serial:///dev/pts/5 --dry-run
      ambdaq push coef.json --device serial:///dev/pts/5 --yes
      ambdaq push --rollback --device serial:///dev/pts/5 --yes
      ambdaq push coef.json --device "can://socketcan/can0?node=0x50" --key "$KEY" --yes
      ambdaq push coef.json --device xcp+tcp://127.0.0.1:5555 --a2l spindle.a2l --yes
    """
    if bool(file) == rollback:
        raise BadInputError("push takes a coefficient FILE, or --rollback without one")
    url, rig_key, description = _target(device, rig, description)
    # a broken file fails before any device is opened: a controller design, or coefficients
    design = None if rollback else _controller_design(file)
    coef = None if rollback or design is not None else Coefficients.load(file)
    unlock_key = None if dry_run else resolve_key(key, rig_key)
    port = open_controller(url, description)
    try:
        plan = (plan_rollback(port, url) if rollback else plan_controller_push(port, file, design) if design is not None
                else plan_push(port, file, coef))
        status = plan.status
        if dry_run or not yes:
            new = BankImage.decode(plan.image) if rollback else plan.image
            old = BankImage.decode(port.read_bank("active", status["active_length"]))
            what = (f"the bank before {plan.last.get('file')} ({plan.last.get('host_time')}, CRC-32 "
                    f"{plan.last['replaced_crc32']})") if rollback else Path(file).name
            click.echo(f"{url}: active bank {status['active_bank']} (CRC-32 {status['active_crc32']}, "
                       f"{status['active_mode']}) -> {what}")
            for line in describe_difference(old, new, list(status["axes"])):
                click.echo(f"  {line}")
            if dry_run:
                click.echo("dry run: nothing written")
                return
            try:
                answer = click.confirm("commit these coefficients?")
            except click.Abort:
                if sys.stdin.isatty():
                    raise  # the user stopped it at the prompt
                raise BadInputError("push asks before it commits and its input ended without an answer (no "
                                    "terminal): pass --yes, or --dry-run to see the difference") from None
            if not answer:
                click.echo("push cancelled, nothing written")
                return
        result = (roll_back(port, plan, unlock_key, target=url) if rollback
                  else push(port, plan, unlock_key, target=url))
    finally:
        port.close()
    if rollback:
        click.echo(f"{url}: rolled back to bank {result.bank} (CRC-32 {result.crc32}, device-verified, what it ran "
                   f"before {plan.last.get('file')}), running from sample {result.effective_sample}; logged to {result.log}")
    elif result.already_active:
        click.echo(f"{url}: bank {result.bank} already holds {file} (CRC-32 {result.crc32}): nothing to do")
    else:
        click.echo(f"{url}: committed {file} to bank {result.bank} (CRC-32 {result.crc32}, device-verified), "
                   f"running from sample {result.effective_sample}; logged to {result.log}")


@click.group("controller")
def controller_group() -> None:
    """The AMB controller: what it runs."""


@controller_group.command("status")
@click.option("--device", metavar="URL", required=True, help="The controller: serial:PORT or can://IF/CH?node=N.")
@a2l_option
@click.option("--json", "as_json", is_flag=True, help="Print the status as JSON.")
def status_command(device, description, as_json):
    """Active coefficient bank, its CRC-32 and source file hash, and the controller's push log."""
    port = open_controller(device, description)
    try:
        st = port.bank_status()
    finally:
        port.close()
    if as_json:
        click.echo(json.dumps(st, indent=2))
        return
    fir = f"  FIR {st['active_fir_taps']} taps" if st.get("active_fir_taps") else ""
    click.echo(f"active bank   {st['active_bank']}  mode {st['active_mode']}{fir}  CRC-32 {st['active_crc32']}  "
               f"({st['active_length']} bytes)")
    click.echo(f"source sha256 {st['active_source_sha256'] or '-'}")
    click.echo(f"inactive bank CRC-32 {st['inactive_crc32']} ({st['inactive_length']} bytes); "
               f"{'locked' if st['locked'] else 'unlocked'}")
    click.echo(f"push log ({len(st['log'])} entries):")
    for e in st["log"]:
        click.echo(f"  {e.get('host_time', '?')}  bank {e['bank']}  crc {e['crc32']}  {e.get('file', '?')} "
                   f"sha256 {e.get('file_sha256', '')[:12]}  from sample {e['effective_sample']}  "
                   f"by {e.get('host', '?')} -> {e.get('target', '?')}")


@controller_group.command("design")
@click.argument("model_file", type=click.Path(dir_okay=False))
@click.option("--machine", default="flexible", show_default=True,
              help="The rotor model the design is checked on over speed (machines/).")
@click.option("--stiffness", type=float, help="Bearing stiffness, N/m; default the machine's PID's.")
@click.option("--damping", type=float, help="Bearing damping, N s/m; default the machine's PID's.")
@click.option("--max-rpm", type=float, help="Top of the speed grid, rpm; default the machine's maximum speed.")
@click.option("--draws", type=click.IntRange(min=1, max=10_000), default=200, show_default=True,
              help="Plants drawn within the identified uncertainty, each closed with the design.")
@click.option("--zone", "target_zone", type=click.Choice(["A", "B", "C"]), default="A", show_default=True,
              help="The ISO 14839-3 zone every axis must reach at every speed.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True,
              help="Controller design file (sealed JSON: the PID and sections per axis, and the prediction).")
@click.option("--overwrite", is_flag=True)
@plot_option("Predicted peak |Gs| over speed per axis, the design's and the stock controller's (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print the design and its prediction as JSON.")
def design_command(model_file, machine, stiffness, damping, max_rpm, draws, target_zone, output, overwrite, plot_path,
                   as_json):
    """PID gains for a stated bearing stiffness and damping, and the sections (notch, low-pass,
    lead, lag) placed on MODEL_FILE's bending modes (plant fit, at standstill), chosen to lower the
    worst ISO 14839-3 peak |Gs| over speed; predicted per axis on a 1 % speed grid of the machine's
    rotor model, and on plants drawn within the identified uncertainty (docs/tuning.md). Exit 1
    (the file written, for inspection) where the design is not stable on the whole grid or on
    every drawn plant, or an axis is beyond the target zone at some speed.

    \b
    Example:
      ambdaq controller design model.json --machine flexible -o controller.json
    """
    from ..errors import AmbdaqError
    from ..workflows.controller_design import design, source_of
    from ..workflows.plant_fit import load_model

    out = Path(output)
    if out.exists() and not overwrite:
        raise BadInputError(f"{out} exists: choose another -o or pass --overwrite")
    result = design(load_model(model_file), machine, stiffness=stiffness, damping=damping, max_rpm=max_rpm,
                    draws=draws, target_zone=target_zone)
    result.source = {**source_of(model_file), **result.source}
    result.save(out, overwrite=overwrite)
    if plot_path:
        from ..figures import save
        from ..figures.controller import draw_design
        from ..workflows.controller_design import AXES

        save(draw_design(result.speeds_rpm, result.peak_db, result.stock_peak_db, list(AXES),
                         {name: [s.label for s in c] for name, c in result.chains.items()}), plot_path)
    summary = result.as_dict()
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        for name, labels in summary["sections"].items():
            click.echo(f"{name:6s} {'; '.join(labels) or 'no sections'}")
        click.echo("axis      peak |Gs|  at        speed      zone  identified at standstill  stock")
        for row in summary["axes"]:
            stock = (f"{row['stock_peak_db']:.1f} dB" if row["stock_peak_db"] is not None
                     else f"unstable from {row['stock_unstable_from_rpm']:.0f} rpm")
            click.echo(f"{row['axis']:9s} {row['peak_db'] if row['peak_db'] is not None else '-':>6} dB  "
                       f"{row['at_hz'] or 0:7.1f} Hz  {row['at_rpm']:7.0f} rpm  {row['zone'] or '-':4s}  "
                       f"{row['identified_standstill_db']} dB{'':15s}{stock}")
        rb, pt = summary["robustness"], summary["perturbed"]
        click.echo(f"{rb['stable']} of {rb['draws']} plants drawn within the identified uncertainty stable; their "
                   f"worst peak median {rb['worst_peak_db_median']} dB, 95th percentile {rb['worst_peak_db_95']} dB")
        click.echo(f"{pt['stable']} of {pt['plants']} plants perturbed by +-10 % frequency, +-20 % damping, +-5 % gain "
                   f"stable; their worst peak median {pt['worst_peak_db_median']} dB, 95th percentile "
                   f"{pt['worst_peak_db_95']} dB")
    click.echo(f"-> {out}" + (f", {plot_path}" if plot_path else ""), err=True)
    if not result.robust:
        where = ("unstable on the machine's model at some speed" if not result.stable else
                 f"unstable with {result.draws - result.stable_draws} of {result.draws} plants drawn within the "
                 "identified uncertainty" if result.stable_draws < result.draws else
                 f"unstable with {result.perturbed - result.stable_perturbed} of {result.perturbed} perturbed plants")
        raise AmbdaqError(f"the design is {where}: do not push it; measure the plant finer (docs/tuning.md)")
    if not result.meets_target:
        raise AmbdaqError(f"the design reaches zone {result.zone}, not {target_zone}, at some axis and speed: change "
                          "--stiffness or --damping, or measure the plant finer (docs/tuning.md)")


@controller_group.command("ff")
@click.argument("action", type=click.Choice(["off", "hold", "on"]))
@click.option("--device", metavar="URL", required=True, help="The controller: serial:PORT, sim://spindle, xcp+...")
@a2l_option
def ff_command(action, device, description):
    """Switch the runout feedforward: off, hold (the present weights, not adapting), or on (the
    mode its active bank runs: table or LMS, from the weights it holds now). The bank is not
    touched: push --rollback undoes a push. Read back after the write, and logged: controller
    param --undo puts the mode back.

    \b
    Example:
      ambdaq controller ff off --device serial:///dev/pts/5
      ambdaq controller ff on --device serial:///dev/pts/5
    """
    from ..drivers.coefbank import MODES
    from ..workflows import controller_params

    names = {v: k for k, v in MODES.items()}
    port = open_controller(device, description)
    try:
        status = port.bank_status()
        want = {"off": "off", "hold": "table", "on": status["active_mode"]}[action]
        change = controller_params.write_param(port, device, "ff.mode", [float(MODES[want])])
        before, now = (names.get(int(v[0]), "?") for v in (change.old, change.new))
    finally:
        port.close()
    if now != want:
        raise DeviceError(f"{device}: ff.mode reads back {now} after writing {want}")
    click.echo(f"{device}: feedforward {before} -> {now}" + (f" (the active bank's mode, CRC-32 {status['active_crc32']})"
                                                           if action == "on" else ""))


@controller_group.command("param")
@click.option("--device", metavar="URL", required=True, help="The controller: serial:PORT, sim://spindle ...")
@click.argument("name", required=False)
@click.argument("values", nargs=-1, type=float)
@a2l_option
@click.option("--page", type=click.IntRange(0, 255), metavar="N",
              help="The calibration page to read or write (XCP: its page number, e.g. 0 working, 1 reference); "
                   "the page presented before is restored.")
@click.option("--yes", is_flag=True, help="Write without asking (changing a gain on a levitated rotor changes the loop).")
@click.option("--undo", is_flag=True,
              help="Write back what the last change ambdaq made to this controller replaced (refused if it was "
                   "changed since).")
def param_command(device, name, values, description, page, yes, undo):
    """Read a controller parameter, or write VALUES to it (e.g. pid.d, speed.rpm; docs/protocol.md);
    without NAME, list the parameters.  Every write is read back and logged with what it replaced,
    and --undo puts the last one back.

    \b
    Example:
      ambdaq controller param --device serial:///dev/pts/5 pid.d
      ambdaq controller param --device serial:///dev/pts/5 pid.d 0.001 0.001 0.002 0.002 0.002 --yes
      ambdaq controller param --device serial:///dev/pts/5 --undo --yes
      ambdaq controller param --device xcp+udp://127.0.0.1:5555 --a2l hello.a2l --page 1 params.flow_rate
    """
    from contextlib import nullcontext

    from ..drivers.interfaces import CalibrationPages, Controller
    from ..drivers.registry import open_parameters
    from ..workflows import controller_params

    if any(not math.isfinite(v) for v in values):
        raise BadInputError(f"{name}: values must be finite numbers")
    if undo and (name is not None or page is not None):
        raise BadInputError("--undo takes no NAME, VALUES or --page: it undoes the last change, where it was made")
    dev = open_parameters(device, description)
    try:
        if not isinstance(dev, Controller):
            raise BadInputError(f"{device}: not a controller with parameters")
        if undo:
            found = controller_params.last_change(device)
            last = found[1]
            if not yes and not click.confirm(f"{last['name']}: {values_text(last['new'])} -> {values_text(last['old'])} "
                                             f"on {device} (undo the change of {last['host_time']})?"):
                raise click.Abort()
            change = controller_params.undo(dev, device, found, page_of=getattr(dev, "on_page", None))
            click.echo(f"{change.name} = {values_text(change.new)} (was {values_text(change.old)}: the change of "
                       f"{last['host_time']} undone)")
            return
        if name is None:
            for known in dev.parameter_names():
                click.echo(known)
            return
        if page is not None and not isinstance(dev, CalibrationPages):
            raise BadInputError(f"{device}: --page is for controllers with calibration pages (XCP)")
        with dev.on_page(page) if page is not None else nullcontext():
            if values:
                old = dev.read_param(name)
                if not yes and not click.confirm(f"{name}: {values_text(old)} -> {values_text(values)} on {device}?"):
                    raise click.Abort()
                change = controller_params.write_param(dev, device, name, list(values), page, old=old)
                click.echo(f"{name} = {values_text(change.new)}" + ("" if page is None else f" (page {page})")
                           + f" (was {values_text(change.old)}; logged, --undo puts it back)")
            else:
                click.echo(f"{name} = {values_text(dev.read_param(name))}" + ("" if page is None else f" (page {page})"))
            for axis, points in dev.read_axes(name).items():  # a CURVE or MAP that stores its own axis points
                click.echo(f"{name}.{axis} = {values_text(points)}")
    finally:
        dev.close()


@controller_group.command("copy-page")
@click.option("--device", metavar="URL", required=True, help="The controller (XCP: xcp+udp://HOST:PORT ...).")
@click.argument("parameter")
@a2l_option
@click.option("--from", "source", type=click.IntRange(0, 255), required=True, metavar="N", help="The page copied.")
@click.option("--to", "target", type=click.IntRange(0, 255), required=True, metavar="N", help="The page written.")
@click.option("--yes", is_flag=True, help="Copy without asking (every parameter of the segment changes at once).")
def copy_page_command(device, parameter, description, source, target, yes):
    """Copy the calibration segment that holds PARAMETER from one page to another (COPY_CAL_PAGE):
    e.g. the reference page over the working page, back to the values the controller was built with.

    \b
    Example:
      ambdaq controller copy-page --device xcp+udp://127.0.0.1:5555 --a2l hello.a2l params.flow_rate --from 1 --to 0
    """
    from ..drivers.interfaces import CalibrationPages
    from ..drivers.registry import open_parameters

    dev = open_parameters(device, description)
    try:
        if not isinstance(dev, CalibrationPages):
            raise BadInputError(f"{device}: copy-page is for controllers with calibration pages (XCP)")
        if not yes and not click.confirm(f"copy page {source} over page {target} of {parameter}'s segment on {device}?"):
            raise click.Abort()
        dev.copy_page(parameter, source, target)
        click.echo(f"page {source} copied to page {target}; {parameter} = {values_text(dev.read_param(parameter))}")
    finally:
        dev.close()
