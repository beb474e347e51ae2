"""Every rotor drop on record: what a snapshot file around a touchdown says of it (ISO 14839-5,
touchdown-bearing condition monitoring; docs/live.md).

A snapshot recording keeps, for each file it writes, the samples it wrote of the device that
records the machine's gap; when the file is finished, the drop in it is characterised
(:func:`ambdaq.analysis.touchdown.characterise`: speed at the first contact, time on the bearing
and whether the rotor levitated again, peak excursion over Cmin and where, whirl, the amplifier
at its limit, impact speed and energy) and written into the file as ``ambdaq.touchdown``, so the
fleet scan collects every drop of every machine without reading the samples again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..analysis.touchdown import AT_CLEARANCE, IMPACT_WINDOW_S, Touchdown, characterise
from ..drivers.signals import SampleBlock
from ..machines.machine import Machine
from .triggers import Device, GapLayout, amplifier_outputs

RECORD = "ambdaq.touchdown"  # the metadata record of a snapshot file's drop
TAIL_S = 2 * IMPACT_WINDOW_S  # what is kept before a first contact: the impact's window, and a margin


class DropRecords:
    """What a drop in a snapshot file was, from that file's samples of the gap's device.

    Parameters
    ----------
    machine : Machine
        Where the gap, the rotor angle and the amplifier outputs are recorded, the bearings, Cmin
        and the limits.
    devices : list of Device
        The recording's devices and their signal groups.
    cmin_m : float, optional
        Minimum clearance, m, where given (``--cmin``); else the machine's.
    """

    def __init__(self, machine: Machine, devices: list[Device], cmin_m: float | None = None) -> None:
        self.cmin_m = cmin_m if cmin_m is not None else machine.cmin_m
        found = next(((d, g) for d in devices if (g := GapLayout.of(d, machine)) is not None), (None, None))
        device, self.layout = found
        self.device = None if device is None else device.name
        rotor = machine.role("rotor")
        column = None if device is None or rotor is None or "speed" not in rotor.fields else \
            device.field(rotor.topic, rotor.fields["speed"])
        self.speed = None if column is None else (rotor.topic, column)
        self.amplifier = None if device is None else amplifier_outputs(device, machine)
        self._gap_fields = 0 if device is None else len(device.fields(self.layout.topic))
        self.mass_kg = machine.rotor_mass_kg

    @property
    def possible(self) -> bool:
        """A drop can be characterised: the gap is recorded and Cmin known."""
        return self.layout is not None and self.cmin_m is not None

    @property
    def bytes_per_sample(self) -> int:
        """What a file keeps per sample of the gap's device for its drop (:class:`DropSamples`)."""
        if not self.possible:
            return 0
        return 8 * (1 + self._gap_fields + (self.speed is not None) + (0 if self.amplifier is None else len(self.amplifier[1])))

    def samples(self, end_ns: int) -> "DropSamples":
        """The drop samples of a file whose span ends at ``end_ns`` on the host clock."""
        return DropSamples(self, end_ns)

    def record(self, held: "DropSamples") -> dict[str, str] | None:
        """The ``ambdaq.touchdown`` record of a file's drop samples, or None where the rotor never
        reached its touchdown bearing in them."""
        if not held.parts:
            return None
        t_ns = np.concatenate([p[0] for p in held.parts])
        gap = np.concatenate([p[1] for p in held.parts])
        speed = None if self.speed is None else np.concatenate([p[2] for p in held.parts])
        amp = None if self.amplifier is None else np.concatenate([p[3] for p in held.parts])
        found = characterise((t_ns - held.first_ns) * 1e-9, gap, self.cmin_m, pairs=self.layout.pairs,
                             single=self.layout.single, names=self.layout.names, speed_rad_s=speed, amplifier=amp,
                             limit=None if self.amplifier is None else self.amplifier[2], mass_kg=self.mass_kg)
        if found is None:
            return None
        return {**found.record(), "contact_ns": str(int(held.first_ns + round(found.contact_s * 1e9))),
                "device": self.device, "cmin_m": repr(self.cmin_m)}


class DropSamples:
    """One snapshot file's samples of the gap's device, as few as its drop needs: only the columns
    :func:`characterise` reads (time, gap, speed, amplifier outputs), only up to the end of the
    file's span as first opened (a file extended by later triggers characterises its first drop),
    and before the first contact only the last ``TAIL_S`` (the impact's window)."""

    def __init__(self, records: DropRecords, end_ns: int) -> None:
        self._records, self._end_ns = records, end_ns
        self.first_ns: int | None = None  # the file's first sample of the device: times are from it
        self.parts: list[tuple] = []
        self.nbytes = 0  # what the parts hold
        self._contact = False

    def add(self, block: SampleBlock) -> None:
        """Keep what ``block`` (the device's next samples written to the file) holds of the drop."""
        r = self._records
        t = block.host_time_ns
        n = int(np.searchsorted(t, self._end_ns, "left"))
        if n == 0 or r.layout.topic not in block.values:
            return
        if self.first_ns is None:
            self.first_ns = int(t[0])
        raw = block.values[r.layout.topic][:n]
        part = (t[:n].copy(), raw.copy(),
                None if r.speed is None else block.values[r.speed[0]][:n, r.speed[1]].copy(),
                None if r.amplifier is None else block.values[r.amplifier[0]][:n][:, r.amplifier[1]])
        self.parts.append(part)
        self.nbytes += _nbytes(part)
        if not self._contact:
            self._contact = bool(np.any(r.layout.radii(raw) >= AT_CLEARANCE * r.cmin_m))
            if not self._contact:  # nothing on the bearing yet: only the impact's window is kept
                keep_from = int(t[n - 1]) - int(TAIL_S * 1e9)
                while self.parts[0][0][-1] < keep_from:
                    self.nbytes -= _nbytes(self.parts.pop(0))


def _nbytes(part: tuple) -> int:
    return sum(a.nbytes for a in part if a is not None)


@dataclass(frozen=True)
class RecordedDrop:
    """The drop a snapshot file holds (its ``ambdaq.touchdown``).

    Attributes
    ----------
    touchdown : Touchdown
        What it was (times from the file's first sample of ``device``).
    contact_ns : int
        The first contact, host clock, ns since the epoch.
    device : str
        The device that recorded the gap.
    cmin_m : float
        The minimum clearance it was judged against, m.
    """

    touchdown: Touchdown
    contact_ns: int
    device: str
    cmin_m: float


def recorded_drop(metadata: dict[str, dict[str, str]]) -> RecordedDrop | None:
    """The drop in a recording's metadata records (name -> record), or None if it holds none."""
    found = metadata.get(RECORD)
    if not found:
        return None
    return RecordedDrop(Touchdown.from_record(found), int(found["contact_ns"]), found["device"], float(found["cmin_m"]))


__all__ = ["DropRecords", "DropSamples", "RECORD", "RecordedDrop", "recorded_drop"]
