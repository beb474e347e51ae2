"""The simulated rig profiles: name -> the module that defines it (loaded when asked for).

Each profile is one module in :mod:`ambdaq.sim.rigs` with a rig class (physics, a
:class:`~ambdaq.sim.rigs.base.Rig`) and a ``PROFILE`` listing the kinds of device it serves on
transports (:mod:`ambdaq.sim.device_kinds`: its controller, which runs the profile's
:class:`~ambdaq.sim.devices.firmware.Firmware`, on a serial line; its CANopen devices on a CAN bus;
a shaker generator on a serial line).  A new profile is one module and one line here.  The models of
the machine a rig simulates (its loop, its LMS design loops) are the machine's, in
:mod:`ambdaq.machines.models`: the host side reads them there, without the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..loading import load_object
from ..errors import BadInputError

PROFILES = {
    "spindle": "ambdaq.sim.rigs.spindle",
    "base-motion": "ambdaq.sim.rigs.base_motion",
    "cone": "ambdaq.sim.rigs.cone",
    "lorentz": "ambdaq.sim.rigs.lorentz",
    "flexible": "ambdaq.sim.rigs.flexible",
    "flexible-long": "ambdaq.sim.rigs.flexible_long",
}


@dataclass(frozen=True)
class Profile:
    """One simulated rig and the devices it serves.

    Parameters
    ----------
    name : str
        The profile's name (``sim://NAME``, ``--profile NAME``).
    rig : type
        Its rig class.
    firmware : Firmware or None
        What its AMB controller runs.
    devices : tuple of str
        The kinds of device it serves on transports, in order (:data:`ambdaq.sim.device_kinds.KINDS`:
        ``controller``, ``can``, ``shaker``); empty: it serves none (``ambdaq sim generate`` only).
    """

    name: str
    rig: type
    firmware: Any = None
    devices: tuple = ()

    @property
    def served(self) -> bool:
        return bool(self.devices)

    def build(self, **options: Any):
        """The rig, with keyword ``options`` (seed, speed, truth, ff_mode, noise). ``ff_mode`` other
        than ``off`` goes only to a rig with Ro et al.'s runout feedforward (``"feedforward"`` in
        its ``inputs``); another's is one line, and a rig without it never sees the option."""
        ff_mode = options.pop("ff_mode", "off")
        if ff_mode != "off":
            if "feedforward" not in self.rig.inputs:
                raise BadInputError(f"the {self.name} rig has no runout feedforward to run in mode {ff_mode!r}: "
                                    "leave ff off")
            options["ff_mode"] = ff_mode
        return self.rig(**options)


def profile(name: str) -> Profile:
    """The profile called ``name``; BadInputError listing them if there is none."""
    module = PROFILES.get(name)
    if module is None:
        raise BadInputError(f"unknown simulated rig {name!r}: profiles are {', '.join(sorted(PROFILES))}")
    return load_object(f"{module}:PROFILE")


def require_served(name: str) -> Profile:
    """The profile, if it serves devices on transports; BadInputError saying what it can do instead."""
    p = profile(name)
    if not p.served:
        raise BadInputError(f"the {name} rig serves no devices on a transport: use `ambdaq sim generate --profile {name}`")
    return p
