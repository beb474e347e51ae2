"""What a recording shows while it runs: per device its sample rate and losses, per bearing the gap's
DC and 1X amplitude from the key-phasor, the speed, the file size and the time to the next split.

It is a sink of the acquisition (:mod:`ambdaq.acquisition.acquisition`): every block received goes to
:meth:`LiveView.received` (a reference kept in a short ring, no copy, no arithmetic on the
acquisition's thread), before its clock is mapped, so a controller's figures show from its first block; they are computed only when the terminal is
redrawn, over the device's last ``WINDOW_S`` seconds of samples.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ..analysis.runout import harmonic_fit
from ..acquisition.acquisition import Sink
from ..machines.machine import Machine
from ..units import RAD_S_TO_RPM

WINDOW_S = 0.2  # the window the gap figures are computed over: 100 revolutions at 30,000 rpm
ORBIT_POINTS = 400  # an orbit's points on the live view


@dataclass(frozen=True)
class BearingStatus:
    """One radial bearing's gap over the last window.

    Attributes
    ----------
    device : str
        The device that measures it.
    bearing : str
        ``front``, ``rear``, ``de`` ...: the machine's radial bearing.
    dc_um : tuple of float
        Mean gap of x and y, in um.
    one_x : tuple of complex or None
        1X vector of x and y from the key-phasor, ``R exp(j phi)`` in um (phase from the mark);
        None below one revolution.
    speed_rpm : float or None
        Mean speed, in rpm (None without a rotor angle).
    orbit_um : tuple of ndarray
        The window's x and y about their mean, in um, at most ``ORBIT_POINTS`` points each.
    """

    device: str
    bearing: str
    dc_um: tuple[float, float]
    one_x: tuple[complex, complex] | None
    speed_rpm: float | None
    orbit_um: tuple[np.ndarray, np.ndarray]

    @property
    def one_x_um(self) -> tuple[float, float] | None:
        """1X amplitude (0-peak) of x and y, in um."""
        return None if self.one_x is None else (abs(self.one_x[0]), abs(self.one_x[1]))


class LiveView(Sink):
    """The recent gap and rotor blocks of each device, and the figures computed from them.

    Parameters
    ----------
    rates : dict of str to float or None
        Each device's sample rate, Hz (None for a device without one, not shown).
    groups : dict
        Device -> topic -> field names, as its signal groups give them.
    machine : Machine
        Where the gap and the rotor angle are recorded, and the radial bearings.
    window_s : float
        The window the figures are computed over, s.
    """

    def __init__(self, rates: dict[str, float | None], groups: dict[str, dict[str, list[str]]], machine: Machine,
                 window_s: float = WINDOW_S) -> None:
        self.window = {d: int(round(r * window_s)) for d, r in rates.items() if r}
        self.groups, self.machine = groups, machine
        gap = machine.role("gap")
        self._gap = gap.topic if gap is not None else None
        self._blocks: dict[str, deque] = {}

    def received(self, device: str, block) -> None:
        """Keep a received block that carries the gap (the acquisition hands it every block)."""
        if self._gap not in block.values or len(block) == 0 or device not in self.window:
            return
        ring = self._blocks.setdefault(device, deque())
        ring.append(block)
        held = sum(len(b) for b in ring)
        while len(ring) > 1 and held - len(ring[0]) >= self.window[device]:
            held -= len(ring.popleft())

    def bearings(self) -> list[BearingStatus]:
        """The status of every radial bearing of the machine, from the device that records its gap."""
        out = []
        gap_role, rot_role = self.machine.role("gap"), self.machine.role("rotor")
        for device, ring in self._blocks.items():
            blocks = list(ring)  # the recorder's thread may append meanwhile
            names = self.groups.get(device, {}).get(self._gap)
            rotor = self.groups.get(device, {}).get(rot_role.topic, []) if rot_role is not None else []
            if not blocks or not names:
                continue
            recent = slice(-self.window[device], None)
            gap = np.concatenate([b.values[self._gap] for b in blocks])[recent]
            theta = speed = None
            angle, rate = (rot_role.fields["angle"], rot_role.fields["speed"]) if rot_role is not None else ("", "")
            if angle in rotor and rate in rotor and all(rot_role.topic in b.values for b in blocks):
                rot = np.concatenate([b.values[rot_role.topic] for b in blocks])[recent]
                theta, speed = np.unwrap(rot[:, rotor.index(angle)]), rot[:, rotor.index(rate)]
            for b in sorted(self.machine.bearings, key=lambda b: b.name):
                bearing = b.name
                cols = gap[:, [names.index(gap_role.fields[b.x]), names.index(gap_role.fields[b.y])]]
                one_x = None
                if theta is not None and theta[-1] - theta[0] >= 2 * np.pi:
                    one_x = tuple(complex(v) * 1e6 for v in harmonic_fit(cols, theta, (1,))[0])
                mean = cols.mean(axis=0)
                step = max(1, -(-cols.shape[0] // ORBIT_POINTS))  # ceil: at most ORBIT_POINTS
                orbit = (cols[::step, 0] - mean[0]) * 1e6, (cols[::step, 1] - mean[1]) * 1e6
                out.append(BearingStatus(device, bearing, tuple(float(v) * 1e6 for v in mean), one_x,
                                         None if speed is None else float(speed.mean()) * RAD_S_TO_RPM, orbit))
        return out


__all__ = ["BearingStatus", "LiveView", "WINDOW_S"]
