"""The kinds of device a simulated rig serves on real transports, each put on its transport by
itself: a rig profile lists those it has (``Profile.devices``) and :func:`~.serve.serve` starts
them one after another.

==============  ================================================================================
kind            on its transport
==============  ================================================================================
``controller``  the AMB controller (its profile's ``Firmware``) on a pseudo-terminal, with its XCP
                slave where asked (TCP, SxI or CAN) and an injected fault
``can``         the CANopen amplifier, gap sensor, accelerometer and key-phasor on a python-can
                ``virtual`` bus or behind a simulated SLCAN adapter; with ``third_party`` the DBC
                probe conditioner and the EDS drive beside them
``shaker``      the base shakers' SCPI generator on a pseudo-terminal
==============  ================================================================================

A new kind is one class here with a ``name`` and ``serve(served, options)``, and one entry of
:data:`KINDS`; a profile that has it lists its name.
"""

from __future__ import annotations

import itertools
import os
import tty
from dataclasses import dataclass

from ..drivers.can.device_profiles import DEVICE_PROFILES
from .devices.canopen import open_network, serve_can
from .devices.controller import FdPort, SimController
from .devices.faults import FaultyPort, ScheduledFault
from .devices.probes import DBC_PATH as PROBES_DBC, SimProbeConditioner
from .devices.rig_server import DeviceClock
from .devices.shaker import SimShaker
from .devices.slcan import SimSlcanAdapter
from .devices.vendor_drive import DEFAULT_NODE as VENDOR_DRIVE_NODE, EDS_PATH as VENDOR_DRIVE_EDS, SimVendorDrive
from .devices.xcp import XcpSlave

CAN_SYNC_HZ = 800.0  # 7 frames per SYNC: 63% of 1 Mbit/s
SLCAN_SYNC_HZ = 400.0
"""Through the SLCAN adapter: python-can 4.6's slcan reader takes a byte per system call, about
4,000 frames/s here at a full core (docs/performance.md); 400 Hz is 2,400 frames/s with all
four devices."""
THIRD_PARTY_SYNC_HZ = 400.0  # with the drive's TPDOs, 800 Hz is 81 % (refused); 400 Hz with the probes too: ~55 %
CAN_NAMESPACED = ("gap_sensor", "amplifier", "keyphasor")  # their topics are the controller's too: /can/amb/...
_channels = itertools.count()


@dataclass
class Pty:
    """A pseudo-terminal pair: the device holds the master, drivers open ``path``."""

    master: int
    slave: int
    path: str

    @classmethod
    def open(cls) -> "Pty":
        master, slave = os.openpty()
        tty.setraw(slave)  # bytes pass unchanged: no echo, no line discipline
        return cls(master, slave, os.ttyname(slave))

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


@dataclass(frozen=True)
class ServeOptions:
    """How the devices are served (:func:`~.serve.serve`'s options)."""

    seed: int
    truth: bool
    unlock_key: str
    clock: DeviceClock
    can: str | None
    third_party: bool
    xcp: str | None
    static_daq: bool
    fault_after_s: float | None
    line_errors: float


class Controller:
    """The AMB controller on a pseudo-terminal (``urls["controller"]``); once every other device is
    served (XCP on CAN needs the rig's bus), its XCP slave where asked (``urls["xcp"]``) and its
    injected fault."""

    name = "controller"

    def serve(self, served, options: ServeOptions) -> None:
        pty = served.ptys["controller"] = Pty.open()
        port = FaultyPort(pty.master, flip=options.line_errors, seed=options.seed) if options.line_errors \
            else FdPort(pty.master)
        controller = served.devices["controller"] = SimController(
            port, served.server, served.profile.firmware, clock=options.clock, truth=options.truth,
            unlock_key=options.unlock_key)
        served.urls["controller"] = f"serial://{pty.path}"
        served.finishing.append(lambda: self._extras(served, controller, options))

    @staticmethod
    def _extras(served, controller: SimController, options: ServeOptions) -> None:
        if options.xcp is not None:
            slave = served.devices["xcp"] = XcpSlave(served.server, controller.banks, options.clock,
                                                     static_daq=options.static_daq)
            if options.xcp == "sxi":
                served.ptys["xcp"] = Pty.open()
                slave.serve_pty(served.ptys["xcp"])
            elif options.xcp == "can":
                if served.network is None:
                    raise ValueError("XCP on CAN needs the rig's CAN bus (can='virtual' or 'slcan')")
                slave.serve_can(served.can_channel, served.can_bus)
            else:
                slave.serve_tcp(int(options.xcp.partition(":")[2]))
            served.urls["xcp"] = slave.url
        if options.fault_after_s is not None:
            served.devices["fault"] = ScheduledFault(controller, options.fault_after_s)


class CanopenDevices:
    """The CANopen devices on a python-can ``virtual`` bus (``can="virtual"``) or behind a simulated
    SLCAN adapter on a pseudo-terminal (``can="slcan"``, any process); not served with ``can=None``.
    With ``third_party`` the devices described by vendor files beside them (docs/hardware.md)."""

    name = "can"

    def serve(self, served, options: ServeOptions) -> None:
        if options.can is None:
            return
        channel = served.can_channel = f"ambdaq-sim-{next(_channels)}"
        served.network = open_network(channel)
        served.can_devices = serve_can(served.network, served.server)
        bus, sync = f"virtual/{channel}?", CAN_SYNC_HZ
        if options.can == "slcan":
            served.ptys["can"] = Pty.open()
            served.devices["can"] = SimSlcanAdapter(served.ptys["can"].master, channel)
            bus, sync = f"slcan{served.ptys['can'].path}?open_delay=0&", SLCAN_SYNC_HZ
        served.can_bus = bus
        if options.third_party:
            sync = min(sync, THIRD_PARTY_SYNC_HZ)
        for dev in served.can_devices:
            kind = dev.profile.kind
            namespace = "&namespace=can" if kind in CAN_NAMESPACED else ""
            served.urls[kind] = f"can://{bus}node={DEVICE_PROFILES[kind].default_node}&sync={sync:g}{namespace}"
        if options.third_party:
            served.devices["probes"] = SimProbeConditioner(channel, served.server)
            served.urls["probes"] = f"can://{bus}dbc={PROBES_DBC}"
            # a new list: serve_can's SYNC handler keeps its own (ambdaq's device types only)
            served.can_devices = [*served.can_devices, SimVendorDrive(served.network, served.server)]
            if options.can == "virtual":  # its replies are matched by bus time, which python-can's slcan lacks
                served.urls["drive"] = f"can://{bus}node={VENDOR_DRIVE_NODE}&sync={sync:g}&eds={VENDOR_DRIVE_EDS}"


class Shaker:
    """The base shakers' two-channel SCPI generator on a pseudo-terminal (``urls["shaker"]``)."""

    name = "shaker"

    def serve(self, served, options: ServeOptions) -> None:
        served.ptys["shaker"] = Pty.open()
        served.devices["shaker"] = SimShaker(FdPort(served.ptys["shaker"].master), served.server)
        served.urls["shaker"] = f"scpi://{served.ptys['shaker'].path}"


KINDS = {kind.name: kind for kind in (Controller(), CanopenDevices(), Shaker())}
"""Each kind of device by the name a profile lists it under (``Profile.devices``)."""

__all__ = ["KINDS", "Pty", "ServeOptions"]
