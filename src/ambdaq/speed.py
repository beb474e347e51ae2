"""Rotor speed profiles: constant, linear ramp (run-up), slow roll.

A profile is written as a short spec, the same on the command line and in a ``sim://`` URL:

``30000``            constant 30,000 rpm
``0:50000``          linear ramp from 0 to 50,000 rpm over the whole run
``0:50000:20``       linear ramp over 20 s, then hold 50,000 rpm
``slowroll``         800 rpm, Ro et al.'s slow-roll speed for runout measurement
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import BadInputError
from .units import RPM_TO_RAD_S

SLOW_ROLL_RPM = 800.0
MAX_RPM = 60_000.0


@dataclass(frozen=True)
class SpeedProfile:
    """Rotor speed as a function of time.

    Parameters
    ----------
    rpm_start : float
        Speed at t = 0, in rpm.
    rpm_end : float
        Speed at the end of the ramp, in rpm (equal to ``rpm_start`` for constant speed).
    ramp_s : float or None
        Ramp duration in s; ``None`` means "over the whole run" and is resolved by
        :meth:`resolved` once the run length is known.
    """

    rpm_start: float
    rpm_end: float
    ramp_s: float | None = None

    @classmethod
    def parse(cls, spec: str | float) -> "SpeedProfile":
        """Parse ``N``, ``A:B``, ``A:B:T`` or ``slowroll`` (rpm, s) into a profile."""
        text = str(spec).strip().lower()
        if text in ("slowroll", "slow-roll", "slow_roll"):
            return cls(SLOW_ROLL_RPM, SLOW_ROLL_RPM)
        parts = text.split(":")
        try:
            nums = [float(p) for p in parts]
        except ValueError:
            nums = []
        if len(nums) not in (1, 2, 3) or any(not np.isfinite(v) for v in nums):
            raise BadInputError(
                f"bad speed {spec!r}: expected RPM, FROM:TO, FROM:TO:SECONDS or 'slowroll'"
            )
        for rpm in nums[:2]:
            if not 0.0 <= rpm <= MAX_RPM:
                raise BadInputError(f"bad speed {spec!r}: rpm must be within 0..{MAX_RPM:.0f}")
        if len(nums) == 1:
            return cls(nums[0], nums[0])
        if len(nums) == 3 and nums[2] <= 0:
            raise BadInputError(f"bad speed {spec!r}: ramp time must be > 0 s")
        return cls(nums[0], nums[1], nums[2] if len(nums) == 3 else None)

    @property
    def constant(self) -> bool:
        return self.rpm_start == self.rpm_end

    def resolved(self, duration_s: float) -> "SpeedProfile":
        """The same profile with an open ramp time fixed to the run length ``duration_s`` (s)."""
        if self.ramp_s is not None or self.constant:
            return self
        return SpeedProfile(self.rpm_start, self.rpm_end, max(duration_s, 1e-9))

    def angle_speed(self, t: np.ndarray, theta0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Rotor angle and speed at times ``t``.

        Parameters
        ----------
        t : ndarray
            Times since the start of the run, in s.
        theta0 : float
            Angle at t = 0, in rad.

        Returns
        -------
        theta : ndarray
            Unwrapped rotor angle, in rad (exact integral of the speed).
        omega : ndarray
            Rotor speed, in rad/s.
        """
        w0 = self.rpm_start * RPM_TO_RAD_S
        if self.constant:
            return theta0 + w0 * t, np.full_like(t, w0)
        ramp = self.ramp_s if self.ramp_s is not None else np.inf
        alpha = (self.rpm_end - self.rpm_start) * RPM_TO_RAD_S / ramp
        tr = np.minimum(t, ramp)
        omega = w0 + alpha * tr
        theta = theta0 + w0 * tr + 0.5 * alpha * tr**2 + omega * (t - tr)
        return theta, omega

    def spec(self) -> str:
        """The profile written back as a spec string."""
        if self.constant:
            return f"{self.rpm_start:g}"
        tail = f":{self.ramp_s:g}" if self.ramp_s is not None else ""
        return f"{self.rpm_start:g}:{self.rpm_end:g}{tail}"
