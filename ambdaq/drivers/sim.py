"""The simulated rig as a device: ``sim://PROFILE`` yields sample blocks from the rig physics.

Paced (``record``) it releases each block when the wall clock reaches the block's end, as a
device streaming at its sample rate would; unpaced (``sim generate``) it runs as fast as the
physics allows.
"""

from __future__ import annotations

import time

from ..errors import BadInputError
from .rig.profiles import PROFILES, build_rig
from .rig.speed import SpeedProfile
from .signals import SampleBlock, SignalGroup
from .url import DeviceURL

FF_CHOICES = ("off", "table", "lms")


def sim_options(url: DeviceURL, *, speed: str | None = None, truth: bool | None = None) -> dict:
    """Check a ``sim://`` URL's profile and options; returns the rig's keyword options
    (seed, speed, truth, ff_mode, noise), ``speed`` and ``truth`` overriding the URL's."""
    if url.target not in PROFILES:
        raise BadInputError(f"unknown simulated rig {url.target!r}: profiles are {', '.join(sorted(PROFILES))}")
    try:
        seed = int(url.options.get("seed", "0"))
    except ValueError:
        raise BadInputError(f"option seed={url.options['seed']!r} in {url.text!r}: expected an integer") from None
    ff = url.options.get("ff", "off")
    if ff not in FF_CHOICES:
        raise BadInputError(f"option ff={ff!r} in {url.text!r}: expected one of {', '.join(FF_CHOICES)}")
    return {
        "seed": seed,
        "speed": SpeedProfile.parse(speed if speed is not None else url.options.get("rpm", "0")),
        "truth": _flag(url, "truth", False) if truth is None else truth,
        "ff_mode": ff,
        "noise": _flag(url, "noise", True),
    }


def _flag(url: DeviceURL, name: str, default: bool) -> bool:
    value = url.options.get(name)
    if value is None:
        return default
    if value not in ("0", "1", "true", "false"):
        raise BadInputError(f"option {name}={value!r} in {url.text!r}: expected 0 or 1")
    return value in ("1", "true")


class SimSource:
    """A simulated rig addressed by a ``sim://`` URL.

    Parameters
    ----------
    url : DeviceURL
        ``sim://PROFILE?...``.
    name : str
        Device name in the recording.
    speed : str, optional
        Speed spec overriding the URL's ``rpm`` option (see :mod:`ambdaq.drivers.rig.speed`).
    truth : bool, optional
        Overrides the URL's ``truth`` option.
    paced : bool
        Release blocks in real time.
    block_s : float, optional
        Block length, in s; default 10 ms paced (a device's streaming granularity), 1 s
        unpaced (the writer encodes whole blocks).
    calibration : dict, optional
        Calibration notes from the rig file, stored with the device's calibration.
    """

    def __init__(
        self,
        url: DeviceURL,
        *,
        name: str = "rig",
        speed: str | None = None,
        truth: bool | None = None,
        paced: bool = True,
        block_s: float | None = None,
        calibration: dict[str, str] | None = None,
    ) -> None:
        options = sim_options(url, speed=speed, truth=truth)
        self.url = url
        self.name = name
        self.speed = options["speed"]
        self.rig = build_rig(url.target, **options)
        self.sample_rate = self.rig.params.sample_rate
        self.paced = paced
        if block_s is None:
            block_s = 0.01 if paced else 1.0
        self.block = max(1, int(round(block_s * self.sample_rate)))
        self._rig_calibration = dict(calibration or {})
        self._remaining: int | None = None
        self._t0 = 0.0

    def signal_groups(self) -> list[SignalGroup]:
        return self.rig.signal_groups()

    def identity(self) -> dict[str, str]:
        return {
            "url": self.url.text,
            "kind": "simulated rig",
            "profile": self.rig.profile,
            "seed": str(self.rig.seed),
            "speed_rpm": self.speed.spec(),
            "sample_rate_hz": f"{self.sample_rate:g}",
        }

    def calibration(self) -> dict[str, str]:
        return {**self.rig.calibration(), **self._rig_calibration}

    def start(self, n_samples: int | None) -> None:
        """Begin streaming; stop after ``n_samples`` samples (``None``: until closed)."""
        self._remaining = n_samples
        if n_samples is not None and not self.speed.constant:
            self.rig.speed = self.speed.resolved(n_samples / self.sample_rate)
        self._t0 = time.monotonic()

    def read(self) -> SampleBlock | None:
        """The next block, or ``None`` when the requested samples are done."""
        n = self.block if self._remaining is None else min(self.block, self._remaining)
        if n <= 0:
            return None
        block = self.rig.run(n)
        if self._remaining is not None:
            self._remaining -= n
        if self.paced:
            due = self._t0 + self.rig.step_index / self.sample_rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        return block

    def close(self) -> None:
        self._remaining = 0
