"""The simulated rig profiles: name -> the module that defines it (loaded when asked for).

Each profile is one module in :mod:`ambdaq.sim.rigs` with a rig class (physics, a
:class:`~ambdaq.sim.rigs.base.Rig`) and a ``PROFILE`` listing the kinds of device it serves on
transports (:mod:`ambdaq.sim.served`: its controller, which runs the profile's
:class:`~ambdaq.sim.devices.firmware.Firmware`, on a serial line; its CANopen devices on a CAN bus;
a shaker generator on a serial line).  A new profile is one module and one line here; a profile
with a rotordynamic model (``modes``) is a ``runup --model``, one with LMS design models (``lms``)
a ``lms --plant``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..loading import load_object
from ..errors import BadInputError

PROFILES = {
    "spindle": "ambdaq.sim.rigs.spindle",
    "base-motion": "ambdaq.sim.rigs.base_motion",
    "cone": "ambdaq.sim.rigs.cone",
    "lorentz": "ambdaq.sim.rigs.lorentz",
}


@dataclass(frozen=True)
class LoopModel:
    """A rotordynamic model's closed loop, with the controller gains it was built at.

    Attributes
    ----------
    at : callable
        ``at(rpm)`` (rpm): the loop's lightly damped modes there, as frequencies (Hz), damping
        ratios and whirl (+1 forward, -1 backward, 0 not known), each an array sorted by frequency.
    basis : str
        Which controller gains it holds, in words (the recording's own, or the model's defaults).
    assumed : bool
        The gains are the model's defaults, not what the recording says its controller ran.
    response : callable or None
        ``response(rpm)`` (rpm): the rotor's steady 1X there from the model's own unbalance and
        runout, a phasor (m) per bearing axis by name (API 684's unbalance response analysis);
        None: the model does not give it.
    """

    at: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]]
    basis: str
    assumed: bool
    response: Callable[[float], dict[str, complex]] | None = None


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
        The kinds of device it serves on transports, in order (:data:`ambdaq.sim.served.KINDS`:
        ``controller``, ``can``, ``shaker``); empty: it serves none (``ambdaq sim generate`` only).
    modes : callable or None
        Its rotordynamic model: ``modes(calibration)`` gives the :class:`LoopModel` at the controller
        gains a recording's calibration states (``runup --model NAME``); None: the profile has no
        such model.
    lms : DesignModels or None
        The loops its LMS feedforward is designed on (``ambdaq lms --plant``,
        :class:`~ambdaq.analysis.lms.DesignModels`); None: it has none.
    """

    name: str
    rig: type
    firmware: Any = None
    devices: tuple = ()
    modes: Callable[[Mapping[str, str]], LoopModel] | None = None
    lms: Any = None

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
