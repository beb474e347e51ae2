"""What this host can talk to: CAN interfaces and channels, serial ports, SLCAN adapters."""

from __future__ import annotations

import logging

import can
from serial.tools import list_ports

from ..errors import DeviceError


NOT_SEARCHED = {
    "socketcand": "its servers announce themselves by a UDP beacon every 3 s on the LAN, too slow to wait for",
    "udp_multicast": "it talks over an IP network (its URLs are refused: can/backend.py NETWORK_INTERFACES)",
    "virtual": "in-process only, what sim:// runs on; detection would invent a channel name",
}
"""python-can interfaces ``ambdaq devices`` does not ask, and why."""


def _local_interfaces() -> list[str]:
    """The python-can interfaces to ask: every one but :data:`NOT_SEARCHED`."""
    return sorted(i for i in can.interfaces.VALID_INTERFACES if i not in NOT_SEARCHED)


def can_channels() -> list[dict[str, str]]:
    """CAN configurations python-can detects (interface, channel), as device URL stems.

    Backends that are not installed say so on import through python-can's loggers; their
    chatter is silenced here, an interface that is missing is simply not listed.
    """
    found = []
    quiet = [logging.getLogger(n) for n in ("can", "can.interfaces") + tuple(logging.root.manager.loggerDict)
             if n.startswith("can")]
    levels = [lg.level for lg in quiet]
    for lg in quiet:
        lg.setLevel(logging.CRITICAL)
    try:
        configs = can.detect_available_configs(interfaces=_local_interfaces())
    finally:
        for lg, lvl in zip(quiet, levels):
            lg.setLevel(lvl)
    for cfg in configs:
        iface, channel = str(cfg.get("interface", "")), str(cfg.get("channel", ""))
        path = channel if channel.startswith("/") else f"/{channel}"  # a device path keeps its one slash
        found.append({"interface": iface, "channel": channel, "url": f"can://{iface}{path}?node=N"})
    return found


def serial_ports() -> list[dict[str, str]]:
    """Serial ports pyserial lists, with what the system knows of them."""
    return [
        {"port": p.device, "description": p.description or "", "hwid": p.hwid or "", "url": f"serial://{p.device}"}
        for p in list_ports.comports()
    ]


SLCAN_USB_IDS = {
    (0x16D0, 0x117E): "CANable (slcan firmware)",
    (0x04D8, 0x000A): "USBtin",
    (0x0403, 0xFFA8): "Lawicel CANUSB",
}
"""USB vendor and product ids of SLCAN adapters, recognised without opening their port."""


def slcan_adapters() -> list[dict[str, str]]:
    """Serial ports whose USB ids are a known SLCAN adapter's, as ``can://slcan/...`` URL stems."""
    found = []
    for p in list_ports.comports():
        name = SLCAN_USB_IDS.get((p.vid, p.pid)) if p.vid is not None else None
        if name is not None:
            found.append({"port": p.device, "adapter": name, "url": f"can://slcan{p.device}?node=N"})
    return found


def ask_slcan(port: str, timeout_s: float = 0.5) -> dict[str, str]:
    """The version and serial number of the SLCAN adapter on ``port``, asked through python-can's
    ``slcan`` interface (``V`` and ``N``); DeviceError if nothing answers as an SLCAN adapter."""
    try:
        bus = can.Bus(interface="slcan", channel=port, sleep_after_open=0)
    except (can.CanError, OSError, ValueError) as err:
        raise DeviceError(f"{port}: cannot open it as an SLCAN adapter: {err}") from None
    try:
        hw, sw = bus.get_version(timeout_s)
        serial = bus.get_serial_number(timeout_s)
    finally:
        bus.shutdown()
    if hw is None:
        raise DeviceError(f"{port}: no SLCAN adapter answered the version request (V) within {timeout_s:g} s")
    return {"port": port, "hardware_version": str(hw), "software_version": str(sw), "serial": serial or "",
            "url": f"can://slcan{port}?node=N"}
