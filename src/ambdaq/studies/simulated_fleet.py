"""A fleet of simulated spindles recorded over days (``ambdaq sim fleet``): what ``fleet scan`` is tested
and benchmarked on without hardware (docs/fleet.md).

Each machine is Ro et al.'s spindle with its own sensor runout (the default table scaled by 0.6-1.4
and turned by up to +-60 degrees, per harmonic) and its own unbalance, which grows by 0-100 % a day
(a rotor that is wearing, or collecting deposit); one machine in four had a coefficient file pushed
(its recordings name its SHA-256 as the controller's).  Each recording is dated on its simulated day
and may have lost a run of samples (``drop_chance``), counted as a recording counts its drops.
Everything follows from ``seed``.
"""

from __future__ import annotations

import dataclasses
import hashlib
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from ..acquisition.recorder import Recorder, RecordOptions
from ..drivers.interfaces import PassThrough
from ..drivers.signals import SampleBlock
from ..machines.spindle import SPINDLE  # the simulated fleet is of spindles
from ..sim.source import SimSource
from ..speed import SpeedProfile
from ..machines.machine import ID_KEY
from ..workflows.fleet import COEFFICIENTS_KEY

FIRST_DAY = datetime(2026, 1, 5, 6, 0, tzinfo=timezone.utc)  # the fleet's commissioning


class _Losing(PassThrough):
    """A source that loses ``lost`` samples from ``at`` on (a line that dropped them): the recorder
    sees the gap in ``seq`` and counts it."""

    def __init__(self, inner: SimSource, at: int, lost: int) -> None:
        super().__init__(inner)
        self._at, self._lost, self._next = at, lost, 0

    def read(self) -> SampleBlock | None:
        block = self.inner.read()
        if block is None:
            return None
        first, self._next = self._next, self._next + len(block)
        idx = np.arange(first, self._next)
        keep = (idx < self._at) | (idx >= self._at + self._lost)
        return block if keep.all() else block.select(keep)


@dataclasses.dataclass(frozen=True)
class SimulatedMachine:
    """One spindle of the fleet: its id, its runout and unbalance, and its wear per day."""

    machine_id: str
    runout_scale: np.ndarray  # per harmonic
    runout_turn_rad: np.ndarray  # per harmonic
    unbalance_scale: float
    growth_per_day: float  # relative unbalance growth
    coefficients_sha256: str | None

    def params(self, day: int):
        """The machine's spindle on ``day`` (0: commissioning)."""
        u = self.unbalance_scale * (1.0 + self.growth_per_day * day)
        return dataclasses.replace(SPINDLE, runout_amp=SPINDLE.runout_amp * self.runout_scale,
                                   runout_phase=SPINDLE.runout_phase + self.runout_turn_rad,
                                   unbalance=tuple(u * x for x in SPINDLE.unbalance))


def machines(n: int, seed: int = 0) -> list[SimulatedMachine]:
    """The fleet's ``n`` machines, from ``seed``."""
    out = []
    for m in range(n):
        rng = np.random.default_rng([seed, m])
        h = SPINDLE.runout_amp.shape[-1]  # harmonics (the table is axes x harmonics)
        sha = hashlib.sha256(f"coefficients of machine {m}, seed {seed}".encode()).hexdigest() if m % 4 == 3 else None
        out.append(SimulatedMachine(f"AMB-{m + 1:02d}", rng.uniform(0.6, 1.4, h), rng.uniform(-np.pi / 3, np.pi / 3, h),
                                    float(rng.uniform(0.5, 1.5)), float(rng.uniform(0.0, 1.0)), sha))
    return out


def generate_fleet(folder: Path, *, n_machines: int, days: int, duration_s: float, rpm: float, seed: int = 0,
                   drop_chance: float = 0.15) -> list[Path]:
    """Record every machine once a day into ``folder/<machine>/<machine>_<date>.mcap``.

    Parameters
    ----------
    folder : Path
        Created if missing.
    n_machines, days : int
        The fleet's size and how many days it ran.
    duration_s : float
        Each recording's length, in s.
    rpm : float
        The speed every recording runs at, in rpm.
    seed : int
        Everything follows from it.
    drop_chance : float
        Chance that a recording lost a run of 1-200 samples.

    Returns
    -------
    list of Path
        The recordings, machine by machine, day by day.
    """
    paths = []
    for m, machine in enumerate(machines(n_machines, seed)):
        out = Path(folder) / machine.machine_id
        out.mkdir(parents=True, exist_ok=True)
        for day in range(days):
            rng = np.random.default_rng([seed, m, day])
            start = FIRST_DAY + timedelta(days=day, minutes=7 * m)
            source = SimSource("spindle", seed=int(rng.integers(1 << 31)), speed=SpeedProfile(rpm, rpm),
                               params=machine.params(day),
                               identity={COEFFICIENTS_KEY: machine.coefficients_sha256} if machine.coefficients_sha256
                               else None)
            source.add_calibration({ID_KEY: machine.machine_id})
            n = int(round(duration_s * source.sample_rate))
            if rng.random() < drop_chance:
                source = _Losing(source, int(rng.integers(n // 4, n // 2)), int(rng.integers(1, 201)))
            path = out / f"{machine.machine_id}_{start:%Y%m%dT%H%M}.mcap"
            # no fsync: a generated fleet is made again from its seed, it needs no power-cut safety
            Recorder([source], path, RecordOptions(duration_s=duration_s, start_ns=int(start.timestamp() * 1e9),
                                                   fsync=False),
                     command=f"ambdaq sim fleet (machine {machine.machine_id}, day {day})", overwrite=True).run()
            paths.append(path)
    return paths


__all__ = ["SimulatedMachine", "machines", "generate_fleet"]
