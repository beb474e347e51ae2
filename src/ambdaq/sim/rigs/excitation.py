"""The test-signal input of a simulated controller (the contract: :mod:`ambdaq.drivers.excitation`),
mixed into a rig class: the signal is added to one axis's feedforward r_c in the step kernel."""

from __future__ import annotations

import numpy as np

from ...drivers.excitation import Excitation
from ...drivers.interfaces import ExcitationSpec

EXCITATION_PARAMETER = "exc.signal"  # [axis (-1 off), amplitude, frequency Hz]; docs/protocol.md


class ExcitationInput:
    """The rig sets ``excitation_axes`` (its axis names), ``excitation_unit`` ("m": a displacement
    added to r_c; "V": a voltage), ``excitation_min`` and ``excitation_max`` (smallest and largest
    amplitude, in that unit) as class attributes, and ``self._exc_rng`` (its own noise stream) in
    ``__init__``.
    """

    excitation_axes: tuple[str, ...] = ()
    excitation_unit: str = "m"
    excitation_min: float = 0.0
    excitation_max: float = 0.0
    _excitation: Excitation | None = None

    def excitation_spec(self) -> ExcitationSpec:
        """What the simulated controller reports about its test-signal input."""
        return ExcitationSpec(EXCITATION_PARAMETER, tuple(self.excitation_axes), self.excitation_unit,
                              self.excitation_min, self.excitation_max, self.params.sample_rate)

    def set_excitation(self, excitation: Excitation | None) -> None:
        """Add a test signal to one axis's feedforward from the next block on, or stop it (None).

        Raises
        ------
        ValueError
            When the excitation is out of range (see :meth:`Excitation.problem`).
        """
        if excitation is not None:
            problem = excitation.problem(self.excitation_spec())
            if problem:
                raise ValueError(problem)
        self._excitation = excitation

    @property
    def excitation(self) -> Excitation | None:
        """The test signal now running, or None."""
        return self._excitation

    def excitation_block(self, steps: np.ndarray) -> np.ndarray:
        """The test signal at control steps ``steps``, shape (n, axes); zeros when none runs.  Noise
        draws from the rig's own stream in step order, so the signal does not depend on how a run
        is cut into blocks."""
        exc = np.zeros((steps.shape[0], len(self.excitation_axes)))
        excitation = self._excitation  # read once: a controller thread may replace it between blocks
        if excitation is not None:
            if excitation.freq_hz > 0:
                exc[:, excitation.axis] = excitation.amplitude * np.sin(2 * np.pi * excitation.freq_hz * (steps * self.h))
            else:
                exc[:, excitation.axis] = excitation.amplitude * self._exc_rng.standard_normal(steps.shape[0])
        return exc
