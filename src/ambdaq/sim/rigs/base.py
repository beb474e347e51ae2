"""What every simulated rig shares: its parameters, noise seed, speed profile, control-period
clock and the way a run of steps becomes a :class:`~ambdaq.drivers.signals.SampleBlock`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from ...drivers.signals import SampleBlock, SignalGroup
from ...speed import SpeedProfile


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
    ``"base"`` (a moving base), ``"impact"`` (hammer strikes and a touchdown start)."""

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
