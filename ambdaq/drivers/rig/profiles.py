"""Registry of simulated rig profiles: name -> builder.

Each profile is one module in this package with a rig class: a :class:`.base.Rig` (``params``,
``seed``, ``speed``, ``step_index``, the period and the block it returns) that adds ``profile``,
``signal_groups()``, ``calibration()`` and ``run(n) -> SampleBlock``.
"""

from __future__ import annotations

from typing import Any

from ...errors import BadInputError

from .base_motion import BaseMotionRig
from .cone import ConeRig
from .lorentz import LorentzRig
from .spindle import SpindleRig

PROFILES: dict[str, type] = {
    "spindle": SpindleRig,
    "base-motion": BaseMotionRig,
    "cone": ConeRig,
    "lorentz": LorentzRig,
}


SERVED = {"spindle": ("serial", "can"), "base-motion": ("serial",), "cone": (), "lorentz": ()}  # transports each profile's devices use


def require_served(profile: str, transport: str) -> None:
    """BadInputError unless ``profile``'s devices can be served on ``transport`` ("serial", "can")."""
    if transport not in SERVED.get(profile, ()):
        how = " and ".join(SERVED.get(profile, ())) or "no transport (ambdaq sim generate only)"
        raise BadInputError(f"the {profile} rig's devices are served over {how}, not {transport}"
                            + (f": run `ambdaq sim serve --profile {profile}` and record serial://PTY"
                               if "serial" in SERVED.get(profile, ()) else ""))


def build_rig(profile: str, **options: Any):
    """Build the rig for ``profile`` with keyword ``options`` (seed, speed, truth, ff_mode, noise)."""
    return PROFILES[profile](**options)
