"""A rotor drop on a simulated rig: its amplifiers off for a while (a power loss, a tripped
amplifier), so the rotor falls onto its touchdown bearings, then on again (it levitates from
where it lies).  The rigs that have touchdown bearings (``cone``, ``spindle``) take one through
``set_drop``; ``ambdaq sim generate --drop AT_S:DURATION_S``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import BadInputError


@dataclass(frozen=True)
class Drop:
    """A rotor drop: the amplifiers off from ``at_s`` for ``duration_s`` (a power loss, a tripped
    amplifier), the rotor falling onto its touchdown bearings, then enabled again (it levitates
    from where it lies, as from the touchdown start)."""

    at_s: float
    duration_s: float

    @classmethod
    def parse(cls, spec: str) -> "Drop":
        """``AT_S:DURATION_S``."""
        try:
            at, duration = (float(x) for x in spec.split(":"))
        except ValueError:
            raise BadInputError(f"bad drop {spec!r}: expected AT_S:DURATION_S, e.g. 0.3:0.2") from None
        if not (np.isfinite(at) and np.isfinite(duration) and at >= 0 and 0 < duration <= 10):
            raise BadInputError(f"bad drop {spec!r}: AT_S >= 0 and 0 < DURATION_S <= 10")
        return cls(at, duration)

    def enabled(self, t: np.ndarray) -> np.ndarray:
        """1 where the amplifiers run at times ``t`` (s), 0 where they are off."""
        return np.where((t >= self.at_s) & (t < self.at_s + self.duration_s), 0.0, 1.0)


__all__ = ["Drop"]
