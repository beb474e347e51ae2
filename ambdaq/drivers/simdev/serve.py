"""Serve a simulated rig's devices on real transports (``ambdaq sim serve``)."""

from __future__ import annotations

import os
import tty
from dataclasses import dataclass, field

from .. import framing
from ..rig.profiles import build_rig, require_served
from ..rig.speed import SpeedProfile
from .banks import DEFAULT_UNLOCK_KEY
from .controller import FdPort, SimController
from .rig_server import DeviceClock, RigServer
from .shaker import SimShaker


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
    """A running simulated rig and the transports its devices sit behind."""

    server: RigServer
    devices: dict[str, SimController | SimShaker]  # by name, as in ``ptys``
    ptys: dict[str, Pty] = field(default_factory=dict)

    def stop(self) -> None:
        for device in self.devices.values():
            device.stop()
        self.server.stop()
        for p in self.ptys.values():
            p.close()


def serve_serial(profile: str = "spindle", *, seed: int = 0, speed: str = "0", truth: bool = False,
                 unlock_key: str = DEFAULT_UNLOCK_KEY, clock: DeviceClock = DeviceClock(offset_ns=5_000_000_000, drift_ppm=50.0),
                 base_motion=None) -> ServedRig:
    """Start the rig and its AMB controller on a new pseudo-terminal (and for the base-motion rig
    its shaker generator on another); returns what is running.

    Parameters
    ----------
    profile : str
        Rig profile.
    seed : int
        Noise seed.
    speed : str
        Speed spec (rpm).
    truth : bool
        Stream the ground truth topics too.
    unlock_key : str
        The key the controller's coefficient banks want (``ambdaq push``).
    clock : DeviceClock
        The controller's clock (default: 5 s ahead of the host, running 50 ppm fast).
    base_motion : BaseExcitation, optional
        The simulated shaker's motion from the start (base-motion rig).
    """
    require_served(profile, "serial")
    framing.warm_up()  # before the rig's clock starts: compiling must not make it late
    rig = build_rig(profile, seed=seed, speed=SpeedProfile.parse(speed), truth=truth)
    if base_motion is not None:
        rig.set_base_motion(base_motion)
    server = RigServer(rig)
    ptys = {"controller": Pty.open()}
    devices = {"controller": SimController(FdPort(ptys["controller"].master), server, clock=clock, truth=truth,
                                           unlock_key=unlock_key)}
    if profile == "base-motion":  # the shakers' generator, for fx campaign
        ptys["shaker"] = Pty.open()
        devices["shaker"] = SimShaker(FdPort(ptys["shaker"].master), server)
    server.start()
    for device in devices.values():
        device.start()
    return ServedRig(server, devices, ptys)
