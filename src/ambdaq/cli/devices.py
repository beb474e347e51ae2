"""``ambdaq devices``: CAN interfaces/channels, serial ports and, where asked, XCP slaves."""

from __future__ import annotations

import json

import click

from ..drivers.discovery import NOT_SEARCHED, ask_slcan, can_channels, serial_ports, slcan_adapters
from ..errors import BadInputError


@click.command("devices")
@click.option("--ask-slcan", "ask", metavar="PORT", multiple=True,
              help="Ask the serial port PORT whether an SLCAN adapter is there (its version and serial number); "
                   "repeatable. Ports are never written to unless named here.")
@click.option("--ask-xcp", "ask_xcp", metavar="URL", multiple=True,
              help="Ask whether an XCP slave answers at URL (xcp+tcp://HOST:PORT, xcp+udp://HOST:PORT, "
                   "xcp+sxi:PORT or xcp+can://...): its A2L project, resources, every DAQ event with its cycle or "
                   "'sporadic'; repeatable.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def command(ask, ask_xcp, as_json):
    """List CAN channels (python-can's detection), SLCAN adapters (by their USB ids), serial
    ports (pyserial's list_ports) and the XCP slaves asked for."""
    from ..drivers.registry import backend, plugin_schemes

    found = {"can": can_channels(), "slcan": slcan_adapters() + [ask_slcan(port) for port in ask],
             "serial": serial_ports(), "xcp": [_ask_xcp(url) for url in ask_xcp],
             "plugins": {s: backend(s).discover() for s in plugin_schemes()}}
    if as_json:
        click.echo(json.dumps(found, indent=2))
        return
    click.echo("CAN (python-can):" if found["can"] else "CAN (python-can): none detected")
    for c in found["can"]:
        click.echo(f"  {c['interface']:<12} {c['channel']:<16} {c['url']}")
    click.echo("SLCAN adapters:" if found["slcan"] else "SLCAN adapters: none recognised (--ask-slcan PORT asks one)")
    for a in found["slcan"]:
        what = a.get("adapter") or f"hardware {a['hardware_version']}, software {a['software_version']}, serial {a['serial']}"
        click.echo(f"  {a['port']:<20} {what:<30} {a['url']}")
    click.echo("serial (pyserial):" if found["serial"] else "serial (pyserial): none")
    for p in found["serial"]:
        click.echo(f"  {p['port']:<20} {p['description']:<30} {p['url']}")
    for x in found["xcp"]:
        click.echo(f"XCP slave {x['url']}: {x['asap2_name']}, resources {x['resources']} (locked: "
                   f"{x['protected'] or 'none'}), MAX_CTO {x['max_cto']}, MAX_DTO {x['max_dto']}")
        for key in sorted((k for k in x if k.startswith("event_")), key=lambda k: int(k[6:])):
            click.echo(f"  event {key[6:]}: {x[key]}")
    for scheme, devices in found["plugins"].items():  # back-ends of installed packages, by their discover()
        click.echo(f"{scheme}:// (plug-in):" if devices else f"{scheme}:// (plug-in): none found")
        for d in devices:
            click.echo("  " + "  ".join(f"{v}" for k, v in d.items() if k != "url") + f"  {d['url']}")
    click.echo("not searched: " + "; ".join(f"{k} ({why})" for k, why in NOT_SEARCHED.items()))
    click.echo("simulated rigs: sim://spindle (in process); ambdaq sim serve (on a pseudo-terminal)")


def _ask_xcp(text: str) -> dict[str, str]:
    from ..drivers.registry import backend, parse_device_url

    url = parse_device_url(text)
    if not url.scheme.startswith("xcp+"):
        raise BadInputError(f"--ask-xcp {text!r}: expected xcp+tcp://HOST:PORT, xcp+udp://HOST:PORT or xcp+sxi:PORT")
    return backend(url.scheme).ask(url)
