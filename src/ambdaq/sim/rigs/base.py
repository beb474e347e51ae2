"""What every simulated rig shares: its parameters, noise seed, speed profile, control-period
clock and the way a run of steps becomes a :class:`~ambdaq.drivers.signals.SampleBlock`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from ...drivers.signals import SampleBlock, SignalGroup
from ...machines.balance_masses import BalanceMass
from ...speed import SpeedProfile
from ...units import RPM_TO_RAD_S


class Rig(ABC):
    """Base of the rig classes in this package (see :mod:`.profiles`): what every rig provides is
    its signal groups, its calibration and :meth:`run`; what can act on it besides its speed it
    declares in :attr:`inputs`.

    Parameters
    ----------
    params : dataclass with ``sample_rate`` (Hz)
        The rig's parameters.
    seed : int
        Seed of the noise generator ``_rng``; a run is deterministic for a given seed.
    speed : SpeedProfile
        Rotor speed over time.
    truth : bool
        Also produce the rig's ``/truth/*`` groups.
    noise : bool
        Measurement noise on.
    """

    profile: str
    inputs: frozenset[str] = frozenset()
    """What can act on the rig besides its speed, declared by each rig class: ``"excitation"``
    (the controller's test signal, :class:`~.excitation.ExcitationInput`), ``"feedforward"`` (Ro
    et al.'s runout feedforward, ``ff_mode`` table or lms), ``"fir"`` (FIR feedforward u = W d),
    ``"base"`` (a moving base), ``"impact"`` (hammer strikes and a touchdown start), ``"balancing"``
    (masses on its balancing planes, ``balance_planes``: :class:`~ambdaq.machines.balance_masses.BalanceMass`)."""

    def __init__(self, params: Any, *, seed: int, speed: SpeedProfile, truth: bool, noise: bool) -> None:
        self.params = params
        self.seed = seed
        self.speed = speed
        self.truth = truth
        self.noise = noise
        self.h = 1.0 / params.sample_rate  # control period, s
        self.period_ns = int(round(1e9 / params.sample_rate))
        self.step_index = 0
        self._rng = np.random.default_rng(seed)

    @abstractmethod
    def signal_groups(self) -> list[SignalGroup]:
        """The topics it records, in the order of its blocks' arrays (fields named after its axes)."""

    @abstractmethod
    def calibration(self) -> dict[str, str]:
        """What its simulated devices report of the machine (``machine.*``, ``rotor.*``) and of
        themselves, as text."""

    @abstractmethod
    def run(self, n: int) -> SampleBlock:
        """The next ``n`` control periods of the closed loop, as one block."""

    def _steps(self, n: int) -> np.ndarray:
        """Indices of the next ``n`` control steps."""
        return self.step_index + np.arange(n, dtype=np.int64)

    def _block(self, steps: np.ndarray, arrays: list[np.ndarray]) -> SampleBlock:
        """The samples of ``steps``: one array per signal group, in :meth:`signal_groups` order."""
        return SampleBlock(device_time_ns=steps * self.period_ns, seq=(steps & 0xFFFFFFFF).astype(np.uint32),
                           values={g.topic: a for g, a in zip(self.signal_groups(), arrays)})


class CommandedSpeed:
    """Mixed into a rig whose drive takes a speed set-point (its firmware's ``speed.rpm``): the
    speed profile runs from ``_speed_t0`` (s) and the angle ``_theta0`` (rad), so a new set-point
    keeps the angle continuous.  The rig's ``run`` takes its angle and speed from
    :meth:`_angle_speed`."""

    _speed_t0 = 0.0
    _theta0 = 0.0

    def command_speed(self, speed: SpeedProfile) -> None:
        """Follow ``speed`` from now on, its time 0 being the present step; the angle is continuous
        (a drive taking a new set-point, ``speed.rpm``)."""
        t = self.step_index * self.h
        theta, _ = self.speed.angle_speed(np.array([t - self._speed_t0]), self._theta0)
        self._speed_t0, self._theta0 = t, float(theta[0])
        self.speed = speed

    def run_speed_rpm(self) -> float:
        """The rotor speed at the present step, in rpm."""
        _, omega = self.speed.angle_speed(np.array([self.step_index * self.h - self._speed_t0]), self._theta0)
        return float(omega[0]) / RPM_TO_RAD_S

    def _angle_speed(self, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rotor's angle (rad) and speed (rad/s) at control steps ``steps``."""
        return self.speed.angle_speed(steps * self.h - self._speed_t0, self._theta0)


def balancing_truth(masses: list[BalanceMass], unbalance: dict[str, complex] | None) -> dict[str, str]:
    """A rig's calibration entries of a balancing job: the masses put on its planes
    (``sim.mass.K``) and, where ``unbalance`` is given (the rig's truth), the unbalance per plane
    they leave (``truth.unbalance.PLANE_kg_m`` and ``_deg`` from the key-phasor's mark): what a
    balancing job is checked against."""
    out = {f"sim.mass.{k}": f"{m.plane}:{m.grams:g}@{m.deg:g}:{m.radius_m * 1e3:g}" for k, m in enumerate(masses)}
    for plane, u in (unbalance or {}).items():
        out[f"truth.unbalance.{plane}_kg_m"] = repr(float(abs(u)))
        out[f"truth.unbalance.{plane}_deg"] = repr(float(np.degrees(np.angle(u))))
    return out
