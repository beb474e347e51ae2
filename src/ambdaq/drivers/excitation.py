"""The controller's test signal, as the host asks for it and the device checks it.

AMB controllers have an injection point for measuring the loop's frequency response (the
sensitivity measurement of ISO 14839-3): the signal is added to one axis's feedforward r_c, so
the command error is ``e = s - (r_c + x)``, the recorded ``/amb/ff`` carries the input and
``/amb/error`` the output.  The device reports where and how much (:class:`ExcitationSpec`); the
same check runs on the host before anything is sent and in the device before anything runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .interfaces import ExcitationSpec

OFF = (-1.0, 0.0, 0.0)  # the parameter's values for "no test signal"
TEST_SIGNAL_RECORD = "ambdaq.test_signal"
"""The metadata record of a recording made with the test signal on: the device, the excited axis,
the signal and its amplitude, as the workflow that switched it on wrote them (:meth:`Excitation.record`).
With a feedforward running every axis's input is not zero: this, not the data, says which was excited."""


@dataclass(frozen=True)
class Excitation:
    """A test signal on one axis.

    Parameters
    ----------
    axis : int
        Axis index in the controller's excitation axes.
    amplitude : float
        Peak of a sine, or RMS of broadband white noise, in the spec's unit (m or V).
    freq_hz : float
        Sine frequency, in Hz; 0 for white noise up to the Nyquist frequency.
    """

    axis: int
    amplitude: float
    freq_hz: float = 0.0

    def problem(self, spec: ExcitationSpec) -> str:
        """Why this excitation cannot run on a controller with ``spec``, or ''."""
        n = len(spec.axes)
        if not 0 <= self.axis < n:
            return f"axis must be 0 .. {n - 1}, not {self.axis}"
        show = (lambda v: f"{v * 1e6:g} um") if spec.unit == "m" else (lambda v: f"{v:g} {spec.unit}")
        if 0 < self.amplitude < spec.min_amplitude:
            hint = (f": amplitudes are in um (for {self.amplitude:g} m give {self.amplitude * 1e6:g})"
                    if spec.unit == "m" else "")
            return f"amplitude {show(self.amplitude)} is below {show(spec.min_amplitude)}, what the controller resolves{hint}"
        if not 0 < self.amplitude <= spec.max_amplitude:
            return f"amplitude must be > 0 and <= {show(spec.max_amplitude)}, not {show(self.amplitude)}"
        if not 0 <= self.freq_hz < spec.sample_rate_hz / 2:
            return f"frequency must be 0 (noise) or below {spec.sample_rate_hz / 2:g} Hz, not {self.freq_hz:g} Hz"
        return ""

    def record(self, device: str, spec: ExcitationSpec) -> dict[str, str]:
        """What runs, as the :data:`TEST_SIGNAL_RECORD` metadata record: device, axis name,
        signal, amplitude and frequency in the spec's units."""
        return {"device": device, "axis": spec.axes[self.axis],
                "signal": f"sine at {self.freq_hz:g} Hz" if self.freq_hz else "white noise",
                "amplitude": f"{self.amplitude:.6g}", "unit": spec.unit, "freq_hz": f"{self.freq_hz:g}"}

    def values(self) -> list[float]:
        """The parameter's values: [axis, amplitude, frequency]."""
        return [float(self.axis), self.amplitude, self.freq_hz]

    @classmethod
    def from_values(cls, values: np.ndarray) -> "Excitation | None":
        """From the parameter's values; None for "off" (axis < 0)."""
        axis = int(values[0])
        return None if axis < 0 else cls(axis, float(values[1]), float(values[2]))


@dataclass(frozen=True)
class ExcitationRequest:
    """An excitation as a user names it: axis name, amplitude in um for a displacement input or in
    the input's unit (V) otherwise, frequency in Hz (0: white noise)."""

    axis: str
    amplitude: float
    freq_hz: float = 0.0

    def resolve(self, spec: ExcitationSpec) -> Excitation:
        """The :class:`Excitation` on a controller with ``spec``; ValueError (one line) if the axis
        or the values do not fit."""
        if self.axis not in spec.axes:
            raise ValueError(f"--excite {self.axis}: the controller's axes are {', '.join(spec.axes)}")
        exc = Excitation(spec.axes.index(self.axis), self.amplitude * (1e-6 if spec.unit == "m" else 1.0), self.freq_hz)
        problem = exc.problem(spec)
        if problem:
            raise ValueError(f"--excite {self.axis}: {problem}")
        return exc
