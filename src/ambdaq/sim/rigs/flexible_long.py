"""The second flexible rotor (:data:`~ambdaq.machines.flexible_spindle.LONG_ROTOR`): the flexible
rig's physics, firmware and devices on another machine's parameters."""

from __future__ import annotations

from ...machines.flexible_spindle import LONG_ROTOR, FlexibleSpindleParams
from ...speed import SpeedProfile
from ..profiles import Profile
from .flexible import FIRMWARE, FlexibleRig


class LongFlexibleRig(FlexibleRig):
    """:class:`~ambdaq.sim.rigs.flexible.FlexibleRig` with the longer rotor."""

    profile = "flexible-long"

    def __init__(self, params: FlexibleSpindleParams = LONG_ROTOR, *, seed: int = 0,
                 speed: SpeedProfile = SpeedProfile(0.0, 0.0), truth: bool = False, noise: bool = True) -> None:
        super().__init__(params, seed=seed, speed=speed, truth=truth, noise=noise)


PROFILE = Profile("flexible-long", LongFlexibleRig, FIRMWARE, ("controller",))
