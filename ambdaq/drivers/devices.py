"""Open a device from its URL: the scheme picks the driver (one entry per scheme)."""

from __future__ import annotations

from ..errors import BadInputError
from .sim import SimSource
from .url import parse_device_url


def open_device(url: str, *, name: str = "rig", speed: str | None = None, truth: bool | None = None, paced: bool = True,
                calibration: dict[str, str] | None = None):
    """Open the device at ``url`` as a sample source for the recorder.

    Parameters
    ----------
    url : str
        Device URL (``sim://spindle?seed=3`` ...).
    name : str
        Device name in the recording.
    speed : str, optional
        Rotor speed spec (rpm) to command before recording.
    truth : bool, optional
        Record ground truth topics (simulated rigs only).
    paced : bool
        Stream in real time (simulated rigs can also run unpaced).
    calibration : dict, optional
        Calibration entries from the rig file.
    """
    parsed = parse_device_url(url)
    if parsed.scheme == "sim":
        return SimSource(parsed, name=name, speed=speed, truth=truth, paced=paced, calibration=calibration)
    raise BadInputError(f"no driver for {parsed.scheme}:// devices")
