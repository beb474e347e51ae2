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

from ..analysis.touchdown import Touchdown, characterise
from ..drivers.signals import SampleBlock, SignalGroup
from ..machines.machine import Machine

RECORD = "ambdaq.touchdown"  # the metadata record of a snapshot file's drop


class DropRecords:
    """What a drop in a snapshot file was, from that file's samples of the gap's device.

    Parameters
    ----------
    machine : Machine
        Where the gap, the rotor angle and the amplifier outputs are recorded, the bearings, Cmin
        and the limits.
    groups : dict of str to list of SignalGroup
        Each device's signal groups.
    cmin_m : float, optional
        Minimum clearance, m, where given (``--cmin``); else the machine's.
    """

    def __init__(self, machine: Machine, groups: dict[str, list[SignalGroup]], cmin_m: float | None = None) -> None:
        self.machine, self.cmin_m = machine, cmin_m if cmin_m is not None else machine.cmin_m
        gap = machine.role("gap")
        self.device = next((d for d, gs in groups.items() if gap is not None and any(g.topic == gap.topic for g in gs)),
                           None)
        fields = {g.topic: list(g.fields) for g in groups.get(self.device, [])}
        self.gap = None
        if self.device is not None:
            cols = {axis: fields[gap.topic].index(f) for axis, f in gap.fields.items()}
            self.gap = (gap.topic, [cols[a] for a in machine.axes])
            self.pairs = [(machine.axes.index(b.x), machine.axes.index(b.y)) for b in machine.bearings]
            self.single = [machine.axes.index(a) for a in machine.axes if a not in machine.bearing_axes]
            self.names = [b.name for b in machine.bearings] + [machine.axes[i] for i in self.single]
        rotor = machine.role("rotor")
        self.speed = (rotor.topic, fields[rotor.topic].index(rotor.fields["speed"])) \
            if rotor is not None and rotor.topic in fields else None
        self.amplifier = None
        for role, limit in (("current", machine.current_limit_a), ("voltage", machine.voltage_limit_v)):
            r = machine.role(role)
            if r is not None and limit is not None and r.topic in fields:
                self.amplifier = (r.topic, [fields[r.topic].index(f) for f in r.fields.values()], limit)
                break
        self.mass_kg = machine.rotor_mass_kg

    @property
    def possible(self) -> bool:
        """A drop can be characterised: the gap is recorded and Cmin known."""
        return self.gap is not None and self.cmin_m is not None

    def record(self, blocks: dict[str, list[SampleBlock]]) -> dict[str, str] | None:
        """The ``ambdaq.touchdown`` record of a file's samples (device -> its blocks, in order), or
        None where the rotor never reached its touchdown bearing in them."""
        mine = [b for b in blocks.get(self.device, []) if len(b)] if self.possible else []
        if not mine:
            return None
        t_ns = np.concatenate([b.host_time_ns for b in mine])
        topic, cols = self.gap
        gap = np.concatenate([b.values[topic][:, cols] for b in mine])
        speed = None if self.speed is None or any(self.speed[0] not in b.values for b in mine) else \
            np.concatenate([b.values[self.speed[0]][:, self.speed[1]] for b in mine])
        amp = limit = None
        if self.amplifier is not None and all(self.amplifier[0] in b.values for b in mine):
            amp = np.concatenate([b.values[self.amplifier[0]][:, self.amplifier[1]] for b in mine])
            limit = self.amplifier[2]
        found = characterise((t_ns - t_ns[0]) * 1e-9, gap, self.cmin_m, pairs=self.pairs, single=self.single,
                             names=self.names, speed_rad_s=speed, amplifier=amp, limit=limit, mass_kg=self.mass_kg)
        if found is None:
            return None
        return {**found.record(), "contact_ns": str(int(t_ns[0] + round(found.contact_s * 1e9))),
                "device": self.device, "cmin_m": repr(self.cmin_m)}


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


__all__ = ["DropRecords", "RECORD", "RecordedDrop", "recorded_drop"]
