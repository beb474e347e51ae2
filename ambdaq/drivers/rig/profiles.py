"""Registry of simulated rig profiles: name -> builder.

Each profile is one module in this package with a rig class exposing ``params``, ``profile``,
``seed``, ``speed``, ``step_index``, ``signal_groups()`` and ``run(n) -> SampleBlock``.
Later profiles plug in here, one module and one line each: ``cone`` (seed 001's conical
bearing) and ``lorentz`` (seed 003's integrated motor-bearing).
"""

from __future__ import annotations

from typing import Any

from ...errors import BadInputError

from .base_motion import BaseMotionRig
from .spindle import SpindleRig

PROFILES: dict[str, type] = {
    "spindle": SpindleRig,
    "base-motion": BaseMotionRig,
}


SERVED = ("spindle",)  # profiles whose devices are served on real transports (sim://, sim serve)


def require_served(profile: str) -> None:
    """BadInputError unless ``profile``'s devices can be served on real transports."""
    if profile not in SERVED:
        raise BadInputError(f"the {profile} rig runs unpaced only for now (ambdaq sim generate, ambdaq fx "
                            f"campaign); its controller is not served on a transport yet (served: {', '.join(SERVED)})")


def build_rig(profile: str, **options: Any):
    """Build the rig for ``profile`` with keyword ``options`` (seed, speed, truth, ff_mode, noise)."""
    return PROFILES[profile](**options)
