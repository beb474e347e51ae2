"""A simulated rig's devices on real transports: its AMB controller (and a base-motion rig's
shaker generator) on pseudo-terminals, its CANopen devices on a python-can ``virtual`` bus,
reached in this process directly or from any process through a simulated SLCAN adapter.

The one way a simulated rig is served: ``ambdaq sim serve`` (another process: pseudo-terminals,
CAN through the SLCAN adapter) and ``sim://`` (this process, :mod:`.backend`).  Each served
device is named by a device URL that the real drivers open.
"""

from __future__ import annotations

import itertools
import os
import tty
from dataclasses import dataclass, field

from ..drivers.can.profiles import PROFILES as CAN_PROFILES
from ..speed import SpeedProfile
from .devices.banks import DEFAULT_UNLOCK_KEY
from .devices.canopen import open_network, serve_can
from .devices.controller import FdPort, SimController
from .devices.faults import FaultyPort, ScheduledFault
from .devices.rig_server import DeviceClock, RigServer
from .devices.shaker import SimShaker
from .devices.probes import DBC_PATH as PROBES_DBC, SimProbeConditioner
from .devices.slcan import SimSlcanAdapter
from .devices.xcp import XcpSlave
from .devices.vendor_drive import DEFAULT_NODE as VENDOR_DRIVE_NODE, EDS_PATH as VENDOR_DRIVE_EDS, SimVendorDrive
from .profiles import require_served

CONTROLLER_CLOCK = DeviceClock(offset_ns=5_000_000_000, drift_ppm=50.0)
"""The simulated controller's own clock: 5 s ahead of the host's, running 50 ppm fast."""
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


@dataclass
class ServedRig:
    """A running simulated rig and its devices on transports.

    Attributes
    ----------
    server : RigServer
        The rig in real time.
    devices : dict
        The simulated devices on pseudo-terminals by name (``controller``, ``shaker``, ``can``
        the SLCAN adapter): each runs its own threads, started and stopped here.
    can_devices : list of SimCanDevice
        The CANopen devices; they answer on the network's thread and go with it.
    urls : dict of str to str
        The device URL of each, as a driver opens it.
    ptys : dict of str to Pty
        The pseudo-terminals, by device name.
    started : list
        The devices started, in order: what :meth:`stop` stops.
    """

    server: RigServer
    devices: dict = field(default_factory=dict)
    can_devices: list = field(default_factory=list)
    urls: dict[str, str] = field(default_factory=dict)
    ptys: dict[str, Pty] = field(default_factory=dict)
    network: object = None
    started: list = field(default_factory=list)

    def stop(self) -> None:
        """Stop every device that was started and the rig; safe to call twice (and after a failed
        start, when some devices never ran)."""
        for device in self.started:
            device.stop()
        self.started.clear()
        self.devices.clear()
        self.can_devices.clear()
        self.server.stop()
        if self.network is not None:
            self.network.disconnect()
            self.network = None
        for p in self.ptys.values():
            p.close()
        self.ptys.clear()


def serve(name: str, *, seed: int = 0, speed: SpeedProfile = SpeedProfile(0.0, 0.0), truth: bool = False,
          ff_mode: str = "off", noise: bool = True, unlock_key: str = DEFAULT_UNLOCK_KEY,
          clock: DeviceClock = CONTROLLER_CLOCK, base_motion=None, can: str | None = "virtual",
          third_party: bool = False, xcp: str | None = None, fault_after_s: float | None = None,
          line_errors: float = 0.0, static_daq: bool = False) -> ServedRig:
    """Start rig profile ``name`` in real time with its devices on transports.

    Parameters
    ----------
    name : str
        Rig profile; it must serve devices (its ``PROFILE.firmware``).
    seed, speed, truth, ff_mode, noise
        The rig's options (:class:`~ambdaq.sim.source.SimSource` has them too).
    unlock_key : str
        The key the controller's coefficient banks want (``ambdaq push``).
    clock : DeviceClock
        The controller's own clock.
    base_motion : BaseExcitation, optional
        The base's motion from the start (a rig with a moving base).
    can : {"virtual", "slcan", None}
        Where the CANopen devices are reached: python-can's ``virtual`` bus (this process only),
        a simulated SLCAN adapter on a pseudo-terminal (any process), or not at all.
    third_party : bool
        Also serve, on the same CAN bus, the devices described by vendor files rather than by
        ambdaq (docs/hardware.md): a probe conditioner sending raw frames of its DBC.
    xcp : {"tcp:PORT", "sxi", "can"}, optional
        Also serve the controller's XCP slave: on TCP on 127.0.0.1:PORT (0: a free port), on SxI
        on a pseudo-terminal, or on CAN on the rig's bus; ``urls["xcp"]`` says where.
    static_daq : bool
        The XCP slave has static DAQ lists, not dynamic ones.
    fault_after_s : float, optional
        The controller reports an injected fault (:data:`~ambdaq.sim.devices.faults.INJECTED_FAULT`)
        this many seconds after the rig starts, in s.
    line_errors : float
        Share of the frames the controller sends that its serial line damages (a bit flipped: the
        host's CRC rejects the frame), 0..1: a bad cable, to rehearse what lost samples do.
    """
    profile = require_served(name)
    rig = profile.build(seed=seed, speed=speed, truth=truth, ff_mode=ff_mode, noise=noise)
    if base_motion is not None:
        rig.set_base_motion(base_motion)
    served = ServedRig(RigServer(rig))
    try:
        served.ptys["controller"] = Pty.open()
        master = served.ptys["controller"].master
        port = FaultyPort(master, flip=line_errors, seed=seed) if line_errors else FdPort(master)
        served.devices["controller"] = SimController(port, served.server, profile.firmware, clock=clock, truth=truth,
                                                     unlock_key=unlock_key)
        served.urls["controller"] = f"serial://{served.ptys['controller'].path}"
        if profile.can and can is not None:
            channel = f"ambdaq-sim-{next(_channels)}"
            served.network = open_network(channel)
            served.can_devices = serve_can(served.network, served.server)
            bus, sync = f"virtual/{channel}?", CAN_SYNC_HZ
            if can == "slcan":
                served.ptys["can"] = Pty.open()
                served.devices["can"] = SimSlcanAdapter(served.ptys["can"].master, channel)
                bus, sync = f"slcan{served.ptys['can'].path}?open_delay=0&", SLCAN_SYNC_HZ
            if third_party:
                sync = min(sync, THIRD_PARTY_SYNC_HZ)
            for dev in served.can_devices:
                kind = dev.profile.kind
                namespace = "&namespace=can" if kind in CAN_NAMESPACED else ""
                served.urls[kind] = (f"can://{bus}node={CAN_PROFILES[kind].default_node}"
                                     f"&sync={sync:g}{namespace}")
            if third_party:
                served.devices["probes"] = SimProbeConditioner(channel, served.server)
                served.urls["probes"] = f"can://{bus}dbc={PROBES_DBC}"
                # a new list: serve_can's SYNC handler keeps its own (ambdaq's device types only)
                served.can_devices = [*served.can_devices, SimVendorDrive(served.network, served.server)]
                if can == "virtual":  # its replies are matched by bus time, which python-can's slcan lacks
                    served.urls["drive"] = f"can://{bus}node={VENDOR_DRIVE_NODE}&sync={sync:g}&eds={VENDOR_DRIVE_EDS}"
        if xcp is not None:
            slave = served.devices["xcp"] = XcpSlave(served.server, served.devices["controller"].banks, clock,
                                                     static_daq=static_daq)
            if xcp == "sxi":
                served.ptys["xcp"] = Pty.open()
                slave.serve_pty(served.ptys["xcp"])
            elif xcp == "can":
                if served.network is None:
                    raise ValueError("XCP on CAN needs the rig's CAN bus (can='virtual' or 'slcan')")
                slave.serve_can(channel, bus)
            else:
                slave.serve_tcp(int(xcp.partition(":")[2]))
            served.urls["xcp"] = slave.url
        if profile.shaker:
            served.ptys["shaker"] = Pty.open()
            served.devices["shaker"] = SimShaker(FdPort(served.ptys["shaker"].master), served.server)
            served.urls["shaker"] = f"serial://{served.ptys['shaker'].path}"
        if fault_after_s is not None:
            served.devices["fault"] = ScheduledFault(served.devices["controller"], fault_after_s)
        served.server.start()
        for device in served.devices.values():
            device.start()
            served.started.append(device)
    except BaseException:
        served.stop()
        raise
    return served
