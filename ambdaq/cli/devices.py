"""``ambdaq devices``: CAN interfaces/channels and serial ports on this host."""

from __future__ import annotations

import json

import click

from ..drivers.discovery import NOT_SEARCHED, ask_slcan, can_channels, serial_ports, slcan_adapters


@click.command("devices")
@click.option("--ask-slcan", "ask", metavar="PORT", multiple=True,
              help="Ask the serial port PORT whether an SLCAN adapter is there (its version and serial number); "
                   "repeatable. Ports are never written to unless named here.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def command(ask, as_json):
    """List CAN channels (python-can's detection), SLCAN adapters (by their USB ids) and serial
    ports (pyserial's list_ports)."""
    found = {"can": can_channels(), "slcan": slcan_adapters() + [ask_slcan(port) for port in ask],
             "serial": serial_ports()}
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
    click.echo("not searched: " + "; ".join(f"{k} ({why})" for k, why in NOT_SEARCHED.items()))
    click.echo("simulated rigs: sim://spindle (in process); ambdaq sim serve (on a pseudo-terminal)")
