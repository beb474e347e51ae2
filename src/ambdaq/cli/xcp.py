"""``ambdaq xcp list``: what an A2L file offers (measurements, parameters, events), from the file
or uploaded from the slave."""

from __future__ import annotations

import fnmatch
import json
import tempfile
from pathlib import Path

import click

from ..errors import BadInputError


@click.group("xcp")
def command():
    """XCP controllers' A2L files: list what they offer."""


@command.command("list")
@click.argument("a2l", required=False, type=click.Path(dir_okay=False))
@click.option("--device", metavar="URL", help="Upload the A2L from this XCP slave (GET_ID) instead of a file.")
@click.option("--match", "pattern", metavar="GLOB", default="*", show_default=True, help="Only names matching it.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def list_command(a2l, device, pattern, as_json):
    """List an A2L's measurements (type, unit, address, conversion, events), parameters and events.

    \b
    Examples:
      ambdaq xcp list hello_xcp.a2l
      ambdaq xcp list --device xcp+udp://127.0.0.1:5555 --match 'temp*'
    """
    from ..drivers.registry import backend, parse_device_url
    from ..drivers.xcp.a2l import catalogue, read_a2l

    if bool(a2l) == bool(device):
        raise BadInputError("give an A2L FILE or --device URL (to upload it from the slave), one of them")
    if device:
        url = parse_device_url(device)
        if not url.scheme.startswith("xcp+"):
            raise BadInputError(f"--device {device!r}: expected an xcp+tcp://, xcp+udp://, xcp+sxi: or xcp+can:// URL")
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "uploaded.a2l"
            path.write_bytes(backend(url.scheme).upload_a2l(url))
            found = catalogue(read_a2l(path))
        found["file"] = f"{device} (GET_ID)"
    else:
        found = catalogue(read_a2l(a2l))
    for key in ("measurements", "parameters"):
        found[key] = [x for x in found[key] if fnmatch.fnmatchcase(x["name"], pattern)]
    if as_json:
        click.echo(json.dumps(found, indent=2))
        return
    unread = sum(1 for p in found["parameters"] if p["problem"])
    click.echo(f"{found['file']}: project {found['project']}, {len(found['measurements'])} measurements, "
               f"{len(found['parameters'])} parameters" + (f" ({unread} not read: see below)" if unread else ""))
    click.echo("events:" if found["events"] else "events: none declared in the A2L (ambdaq devices --ask-xcp URL asks the slave)")
    for e in found["events"]:
        click.echo(f"  {e['number']:>4}  {e['name']:<24} {'every %g us' % (e['cycle_ns'] / 1e3) if e['cycle_ns'] else 'sporadic'}")
    click.echo("measurements:")
    for m in found["measurements"]:
        shape = f"[{m['count']}]" if m["count"] > 1 else ""
        events = ",".join(map(str, m["events"])) or "-"
        note = f"  ({m['problem']})" if m["problem"] else ""
        click.echo(f"  {m['name']:<32} {m['type'] + shape:<16} {m['unit'] or '-':<8} {m['address']:<14} "
                   f"{m['conversion']:<18} event {events}{note}")
    click.echo("parameters:")
    for p in found["parameters"]:
        if p["problem"]:
            click.echo(f"  {p['name']:<32} {p['type']:<16} {p['problem']}")
            continue
        shape = f"[{p['count']}]" if p["count"] > 1 else ""
        click.echo(f"  {p['name']:<32} {p['type'] + shape:<16} {p['unit'] or '-':<8} {p['address']:<14} "
                   f"{p['limits'][0]:g} .. {p['limits'][1]:g}{'' if p['writable'] else '  read-only'}")
