"""A simulated rig's devices on real transports: each kind of device its profile lists
(``Profile.devices``, :mod:`.served`: its AMB controller and a base-motion rig's shaker generator
on pseudo-terminals, its CANopen devices on a python-can ``virtual`` bus, reached in this process
directly or from any process through a simulated SLCAN adapter), started one after another.

The one way a simulated rig is served: ``ambdaq sim serve`` (another process: pseudo-terminals,
CAN through the SLCAN adapter) and ``sim://`` (this process, :mod:`.backend`).  Each served
device is named by a device URL that the real drivers open.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from ..speed import SpeedProfile
from .devices.banks import DEFAULT_UNLOCK_KEY
from .devices.rig_server import DeviceClock, RigServer
from .profiles import require_served
from .device_kinds import KINDS, Pty, ServeOptions

CONTROLLER_CLOCK = DeviceClock(offset_ns=5_000_000_000, drift_ppm=50.0)
"""The simulated controller's own clock: 5 s ahead of the host's, running 50 ppm fast."""


@dataclass
class ServedRig:
    """A running simulated rig and its devices on transports.

    Attributes
    ----------
    server : RigServer
        The rig in real time.
    profile : Profile
        Its profile (the controller's firmware, the kinds of device it serves).
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
    finishing : list of callable
        What a kind of device does once every kind is served (an XCP slave on the rig's CAN bus).
    can_channel, can_bus : str
        The rig's CAN channel and how a URL names its bus, once its CANopen devices are served.
    """

    server: RigServer
    profile: Any = None
    devices: dict = field(default_factory=dict)
    can_devices: list = field(default_factory=list)
    urls: dict[str, str] = field(default_factory=dict)
    ptys: dict[str, Pty] = field(default_factory=dict)
    network: object = None
    started: list = field(default_factory=list)
    finishing: list[Callable[[], None]] = field(default_factory=list)
    can_channel: str = ""
    can_bus: str = ""

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
    options = ServeOptions(seed, truth, unlock_key, clock, can, third_party, xcp, static_daq, fault_after_s,
                           line_errors)
    served = ServedRig(RigServer(rig), profile)
    try:
        for kind in profile.devices:
            KINDS[kind].serve(served, options)
        for finish in served.finishing:
            finish()
        served.server.start()
        for device in served.devices.values():
            device.start()
            served.started.append(device)
    except BaseException:
        served.stop()
        raise
    return served
