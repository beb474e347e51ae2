"""The controller's excitation input: a test signal added to the feedforward r_c of one axis.

AMB controllers have such an injection point for measuring the loop's frequency response (the
sensitivity measurement of ISO 14839-3): the command error is ``e = s - (r_c + x)``, so the
recorded ``/amb/ff`` carries the input ``r_c + x`` and ``/amb/error`` the output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_AMPLITUDE_M = 20e-6  # a tenth of the air gap's safe range; more saturates the loop
MIN_AMPLITUDE_M = 0.01e-6  # a third of the 16-bit A/D's step (0.03 um): less is not a test signal


@dataclass(frozen=True)
class Excitation:
    """A test signal on one axis.

    Parameters
    ----------
    axis : int
        Axis index, 0 .. 4 (front_x, front_y, rear_x, rear_y, axial).
    amplitude : float
        Peak of a sine, or RMS of the broadband noise, in m.
    freq_hz : float
        Sine frequency, in Hz; 0 for broadband white noise up to the Nyquist frequency.
    """

    axis: int
    amplitude: float
    freq_hz: float = 0.0

    def problem(self, n_axes: int, sample_rate: float, max_amplitude: float = MAX_AMPLITUDE_M,
                min_amplitude: float = 0.0) -> str:
        """Why this excitation cannot run, or ''; ``max_amplitude`` and ``min_amplitude`` in m (a rig
        whose feedforward is a voltage gives its limits in V)."""
        if not 0 <= self.axis < n_axes:
            return f"axis must be 0 .. {n_axes - 1}, not {self.axis}"
        if 0 < self.amplitude < min_amplitude:
            if max_amplitude == MAX_AMPLITUDE_M:
                return (f"amplitude {self.amplitude * 1e6:g} um is below {min_amplitude * 1e6:g} um, what the gap "
                        f"sensor resolves: amplitudes are in um (for {self.amplitude:g} m give {self.amplitude * 1e6:g})")
            return f"amplitude {self.amplitude:g} V is below {min_amplitude:g} V, what the D/A resolves"
        if not 0 < self.amplitude <= max_amplitude:
            if max_amplitude == MAX_AMPLITUDE_M:
                return f"amplitude must be > 0 and <= {max_amplitude * 1e6:g} um, not {self.amplitude * 1e6:g} um"
            return f"amplitude must be > 0 and <= {max_amplitude:g}, not {self.amplitude:g}"
        if not 0 <= self.freq_hz < sample_rate / 2:
            return f"frequency must be 0 (noise) or below {sample_rate / 2:g} Hz, not {self.freq_hz:g} Hz"
        return ""

    def samples(self, steps: np.ndarray, h: float, rng: np.random.Generator) -> np.ndarray:
        """The signal at control steps ``steps`` (period ``h`` in s), in m; noise draws from ``rng``
        in step order, so the signal does not depend on how a run is cut into blocks."""
        if self.freq_hz > 0:
            return self.amplitude * np.sin(2 * np.pi * self.freq_hz * (steps * h))
        return self.amplitude * rng.standard_normal(steps.shape[0])


@dataclass(frozen=True)
class ExcitationRequest:
    """An excitation as a user names it: axis name, amplitude in the rig's feedforward unit
    (um for a gap feedforward, V for a voltage one), frequency in Hz (0: white noise)."""

    axis: str
    amplitude: float
    freq_hz: float = 0.0

    def resolve(self, axes: tuple[str, ...], unit_m: bool, sample_rate: float,
                max_amplitude: float = MAX_AMPLITUDE_M, min_amplitude: float = MIN_AMPLITUDE_M) -> Excitation:
        """The :class:`Excitation` on a rig with ``axes``; ``unit_m``: the amplitude was given in um.
        ValueError (one line) if the axis or the values do not fit."""
        if self.axis not in axes:
            raise ValueError(f"--excite {self.axis}: this rig's axes are {', '.join(axes)}")
        exc = Excitation(axes.index(self.axis), self.amplitude * (1e-6 if unit_m else 1.0), self.freq_hz)
        problem = exc.problem(len(axes), sample_rate, max_amplitude, min_amplitude)
        if problem:
            raise ValueError(f"--excite {self.axis}: {problem}")
        return exc


class ExcitationInput:
    """The test-signal input of a simulated controller, mixed into a rig class.

    The rig sets ``excitation_axes`` (its axis names), ``excitation_in_m`` (amplitudes in m, given
    in um; else V), ``excitation_max`` and ``excitation_min`` (largest and smallest amplitude, m or
    V) as class attributes, and
    ``self._exc_rng`` (its own noise stream) in ``__init__``.
    """

    excitation_axes: tuple[str, ...] = ()
    excitation_in_m: bool = True
    excitation_max: float = MAX_AMPLITUDE_M
    excitation_min: float = MIN_AMPLITUDE_M
    _excitation: Excitation | None = None

    def excitation_for(self, request: ExcitationRequest) -> Excitation:
        """A request (amplitude in um or V) on this rig's axes; ValueError if it does not fit."""
        return request.resolve(self.excitation_axes, self.excitation_in_m, self.params.sample_rate,
                               self.excitation_max, self.excitation_min)

    def set_excitation(self, excitation: Excitation | None) -> None:
        """Add a test signal to one axis's feedforward from the next block on, or stop it (None).

        Raises
        ------
        ValueError
            When the excitation is out of range (see :meth:`Excitation.problem`).
        """
        if excitation is not None:
            problem = excitation.problem(len(self.excitation_axes), self.params.sample_rate, self.excitation_max,
                                         self.excitation_min)
            if problem:
                raise ValueError(problem)
        self._excitation = excitation

    @property
    def excitation(self) -> Excitation | None:
        """The test signal now running, or None."""
        return self._excitation

    def excitation_block(self, steps: np.ndarray) -> np.ndarray:
        """The test signal at control steps ``steps``, shape (n, axes); zeros when none runs."""
        exc = np.zeros((steps.shape[0], len(self.excitation_axes)))
        excitation = self._excitation  # read once: a controller thread may replace it between blocks
        if excitation is not None:
            exc[:, excitation.axis] = excitation.samples(steps, self.h, self._exc_rng)
        return exc
