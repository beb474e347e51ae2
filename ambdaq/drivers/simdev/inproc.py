"""A whole simulated rig behind real transports in this process: what ``sim://PROFILE`` opens.

The rig runs in real time (:class:`RigServer`); its AMB controller sits on a pseudo-terminal and
is reached by the serial driver, its CANopen devices sit on a private python-can ``virtual``
channel and are reached by the CANopen driver.  The drivers cannot tell these devices from
hardware; closing the last driver stops the simulation.

Topics: the controller streams ``/amb/gap``, ``/amb/current``, ``/amb/error``, ``/amb/ff``,
``/amb/rotor`` at 10 kHz (and ``/truth/...`` when asked); the accelerometer module gives
``/amb/accel``; the gap sensor, amplifier and key-phasor, whose topics the controller already
has, record under the ``can`` namespace (``/can/amb/gap`` ...) at the SYNC rate.
"""

from __future__ import annotations

import itertools
import threading

from .. import framing
from ..canopen_profiles import PROFILES
from ..controller import ControllerDriver
from ..devices import open_can_device
from ..rig.profiles import build_rig, require_served
from ..rig.speed import SpeedProfile
from ..serial_link import SerialLink
from .canopen_devices import open_network, serve_can
from .controller import FdPort, SimController
from .rig_server import DeviceClock, RigServer
from .serve import Pty

CAN_SYNC_HZ = 800.0  # 7 frames per SYNC: 63% of 1 Mbit/s
CLOCK = DeviceClock(offset_ns=5_000_000_000, drift_ppm=50.0)  # the controller's own clock
NAMESPACED = ("gap_sensor", "amplifier", "keyphasor")
_channels = itertools.count()


class SimulatedRig:
    """The running simulation behind a ``sim://`` URL; stops when its last driver closes."""

    def __init__(self, profile: str, *, seed: int, speed: SpeedProfile, truth: bool, ff_mode: str, noise: bool) -> None:
        framing.warm_up()  # before the rig's clock starts: compiling must not make it late
        self.rig = build_rig(profile, seed=seed, speed=speed, truth=truth, ff_mode=ff_mode, noise=noise)
        self.server = RigServer(self.rig)
        self.pty = Pty.open()
        self.controller = SimController(FdPort(self.pty.master), self.server, clock=CLOCK, truth=truth)
        self.channel = f"ambdaq-sim-{next(_channels)}"
        self.network = open_network(self.channel)
        self.can_devices = serve_can(self.network, self.server)
        self._open = 0
        self._lock = threading.Lock()
        self.server.start()
        self.controller.start()

    def attach(self, driver) -> None:
        """Make closing ``driver`` count towards stopping the simulation."""
        close = driver.close

        def close_and_release() -> None:
            close()
            self._release()

        driver.close = close_and_release
        with self._lock:
            self._open += 1

    def _release(self) -> None:
        with self._lock:
            self._open -= 1
            if self._open:
                return
        self.controller.stop()
        self.server.stop()
        self.network.disconnect()
        self.pty.close()


def open_simulated_rig(profile: str, *, name: str, seed: int, speed: SpeedProfile, truth: bool, ff_mode: str,
                       noise: bool, calibration: dict[str, str] | None = None) -> list:
    """Start the simulated rig and open the real drivers on it; returns them as recorder sources."""
    require_served(profile, "can")
    sim = SimulatedRig(profile, seed=seed, speed=speed, truth=truth, ff_mode=ff_mode, noise=noise)
    drivers = []
    try:
        ctl = ControllerDriver(SerialLink(sim.pty.path), name=name, url=f"sim://{profile} (controller on {sim.pty.path})")
        ctl.extra_calibration = dict(calibration or {})
        sim.attach(ctl)
        drivers.append(ctl)
        for kind, p in PROFILES.items():
            url = f"can://virtual/{sim.channel}?node={p.default_node}&sync={CAN_SYNC_HZ:g}"
            dev = open_can_device(url, name=f"{name}-{kind}", namespace="can" if kind in NAMESPACED else "", kind=kind)
            sim.attach(dev)
            drivers.append(dev)
    except BaseException:
        for d in drivers:
            d.close()
        if not drivers:
            sim._open = 1
            sim._release()
        raise
    return drivers
