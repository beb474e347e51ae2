"""A simulated rig run as fast as its physics goes, straight into the recorder (``ambdaq sim
generate``): no transport, no clock but its own.  (Its devices on real transports, in real
time, are what ``sim://`` opens: :mod:`.backend`.)"""

from __future__ import annotations

from ..drivers.interfaces import Source
from ..drivers.signals import SampleBlock, SignalGroup
from ..speed import SpeedProfile
from .profiles import profile as rig_profile

FF_CHOICES = ("off", "table", "lms")


class SimSource(Source):
    """The rig of ``profile``, unpaced (it waits for the recorder: nothing of it is lost to a pause).

    Parameters
    ----------
    profile : str
        Rig profile (``spindle``, ``base-motion``, ``cone``, ``lorentz``).
    seed : int
        Noise seed; the run is deterministic for it.
    speed : SpeedProfile
        Rotor speed over the run.
    truth : bool
        Also the rig's ``/truth/...`` groups.
    ff_mode : {"off", "table", "lms"}
        The simulated controller's feedforward.
    noise : bool
        Sensor noise and converter quantisation.
    name : str
        Device name in the recording.
    block_s : float
        Block length, in s: the writer encodes whole blocks.
    params : optional
        The rig's parameters (its profile's dataclass, e.g. another machine's runout and
        unbalance); default: the profile's.
    identity : dict, optional
        More identity entries (e.g. ``active_coefficients_sha256``).
    """

    def __init__(self, profile: str, *, seed: int = 0, speed: SpeedProfile = SpeedProfile(0.0, 0.0),
                 truth: bool = False, ff_mode: str = "off", noise: bool = True, name: str = "rig",
                 block_s: float = 1.0, params=None, identity: dict[str, str] | None = None) -> None:
        self.name = name
        self.speed = speed
        extra = {} if params is None else {"params": params}
        self.rig = rig_profile(profile).build(seed=seed, speed=speed, truth=truth, ff_mode=ff_mode, noise=noise,
                                              **extra)
        self._identity = dict(identity or {})
        self.sample_rate = self.rig.params.sample_rate
        self.block = max(1, int(round(block_s * self.sample_rate)))
        self._remaining: int | None = None

    paced = False

    def signal_groups(self) -> list[SignalGroup]:
        return self.rig.signal_groups()

    def identity(self) -> dict[str, str]:
        return {
            "url": f"sim://{self.rig.profile}?seed={self.rig.seed}",
            "kind": "simulated rig (unpaced)",
            "profile": self.rig.profile,
            "seed": str(self.rig.seed),
            "speed_rpm": self.speed.spec(),
            "sample_rate_hz": f"{self.sample_rate:g}",
            **self._identity,
        }

    def device_calibration(self) -> dict[str, str]:
        return self.rig.calibration()

    def start(self, n_samples: int | None) -> None:
        """Run ``n_samples`` control periods (``None``: until closed); a ramp over the whole run
        is resolved to that length."""
        self._remaining = n_samples
        if n_samples is not None and not self.speed.constant:
            self.rig.speed = self.speed.resolved(n_samples / self.sample_rate)

    def read(self) -> SampleBlock | None:
        """The next block, or ``None`` when the requested samples are done."""
        n = self.block if self._remaining is None else min(self.block, self._remaining)
        if n <= 0:
            return None
        if self._remaining is not None:
            self._remaining -= n
        return self.rig.run(n)

    def _close(self) -> None:
        self._remaining = 0
