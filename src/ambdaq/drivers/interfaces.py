"""What a device offers, declared: a streaming source, parameters, coefficient banks, and the
capabilities a controller reports about itself.

The recorder, ``frf measure``, ``push`` and ``fx campaign`` talk to these interfaces only, so they
work on any device that implements them, whatever its transport (serial, CANopen, a simulated
one) and however many axes or whatever rate it has.  A device reports its capabilities itself
(the serial controller in its IDENTITY, a CANopen port in its object dictionary): nothing here
assumes a machine.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import DeviceError
from .signals import Event, SampleBlock, SignalGroup


class Source(ABC):
    """A device that streams samples to the recorder.

    Attributes
    ----------
    name : str
        Device name in the recording.
    sample_rate : float or None
        Samples per second it declares, in Hz; None for a device whose samples come as they
        come (a CAN bus's unknown frames), which the recorder reads for the duration by the host
        clock.
    duration_in_samples : bool
        Whether a recording's duration is counted in its sample periods (a device that samples at
        its stated rate, every period numbered); False where the rate is only declared (an XCP
        event's cycle: the ECU task may run slower or skip) and the host clock ends the recording.
    paced : bool
        Whether it runs against the wall clock, so that a pause of the host's reading loses its
        samples (every device; not a simulation run as fast as it goes, which waits for the host).
    """

    name: str
    sample_rate: float | None
    duration_in_samples = True
    paced = True
    _notes: dict[str, str] | None = None
    _released = False
    _close_hooks: list | None = None

    @abstractmethod
    def signal_groups(self) -> list[SignalGroup]:
        """The groups (one MCAP topic each) its blocks carry, in order."""

    @abstractmethod
    def identity(self) -> dict[str, str]:
        """URL, kind, model, serial, firmware, sample rate ...: the recording's device metadata."""

    @abstractmethod
    def device_calibration(self) -> dict[str, str]:
        """The calibration the device reports."""

    def calibration(self) -> dict[str, str]:
        """The device's calibration with the notes given to it (:meth:`add_calibration`)."""
        return {**self.device_calibration(), **(self._notes or {})}

    def add_calibration(self, notes: dict[str, str]) -> None:
        """Notes stored with the device's calibration (a rig file's ``[device.calibration]``)."""
        self._notes = {**(self._notes or {}), **notes}

    @abstractmethod
    def start(self, n_samples: int | None) -> None:
        """Begin streaming; stop after ``n_samples`` sample periods (``None``: until closed)."""

    @abstractmethod
    def read(self) -> SampleBlock | None:
        """The next block; ``None`` when the requested periods are done or the device is closed."""

    def close(self) -> None:
        """Run the close hooks (:meth:`before_close`), then stop streaming and release the
        device; safe to call twice."""
        if self._released:
            return
        self._released = True
        for hook in self._close_hooks or ():
            hook(self)
        self._close()

    def before_close(self, hook) -> None:
        """Have ``hook(source)`` run when the device is closed, before it is released, however that
        comes (the recording's end, Ctrl-C, a failure): to leave the device as it was found."""
        self._close_hooks = [*(self._close_hooks or []), hook]

    @property
    def closed(self) -> bool:
        return self._released

    @abstractmethod
    def _close(self) -> None:
        """Stop streaming and release the device (once)."""

    def events(self) -> list[Event]:
        """Faults and bus events since the last call."""
        return []

    def clock_pairs(self) -> list[tuple[int, int]] | None:
        """(device ns, host arrival ns) pairs since the last call, stamped as they left the device;
        ``None``: the device has none, and its blocks' arrival times serve."""
        return None

    def clock_latency_ns(self) -> int | None:
        """One-way latency of the link, in ns, where the device measures it."""
        return None

    def link_statistics(self) -> dict[str, str]:
        """Frames, errors ... of the link, stored in the recording's metadata."""
        return {}

    @property
    def can_reconnect(self) -> bool:
        """Whether :meth:`reconnect` can bring the device back after it was lost."""
        return False

    def reconnect(self) -> None:
        """Reopen a lost device and resume streaming (DeviceError if it cannot)."""
        raise DeviceError(f"{self.name}: this device cannot be reopened")

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PassThrough(Source):
    """A source that streams another's blocks as they come: a subclass changes what it must (a
    simulated line that loses samples, a device that reboots, one that names its axes otherwise).

    Parameters
    ----------
    inner : Source
        The source passed through; its name and sample rate are this one's.
    """

    def __init__(self, inner: Source) -> None:
        self.inner, self.name, self.sample_rate = inner, inner.name, inner.sample_rate

    def signal_groups(self) -> list[SignalGroup]:
        return self.inner.signal_groups()

    def identity(self) -> dict[str, str]:
        return self.inner.identity()

    def device_calibration(self) -> dict[str, str]:
        return self.inner.calibration()

    def start(self, n_samples: int | None) -> None:
        self.inner.start(n_samples)

    def read(self) -> SampleBlock | None:
        return self.inner.read()

    def _close(self) -> None:
        self.inner.close()


class Parameters(ABC):
    """Named device parameters (docs/protocol.md lists the controller's; a CANopen device's are
    its EDS objects)."""

    @abstractmethod
    def read_param(self, name: str) -> np.ndarray:
        """The parameter's values (one for a scalar)."""

    def read_axes(self, name: str) -> dict[str, np.ndarray]:
        """The axis points a parameter stores with its values (an A2L STD_AXIS CURVE or MAP:
        ``x``, ``y``), physical; empty where it stores none."""
        return {}

    @abstractmethod
    def write_param(self, name: str, values: ArrayLike) -> None:
        """Write the parameter (a scalar or its values); the device refuses with DeviceError."""

    def parameter_names(self) -> list[str]:
        """The parameters' names, where the device or its description lists them."""
        raise DeviceError(f"{getattr(self, 'name', 'this device')} does not list its parameters: docs/protocol.md "
                          "names the controller's")


class CalibrationPages(ABC):
    """Parameters that live on calibration pages (an XCP controller's working and reference page):
    which page a read or write goes to."""

    @abstractmethod
    def on_page(self, page: int):
        """A context in which :meth:`Parameters.read_param` and ``write_param`` use page ``page``
        (the XCP page number); the page the device presented before is restored after."""

    @abstractmethod
    def copy_page(self, parameter: str, source: int, target: int) -> None:
        """Copy the whole calibration segment that holds ``parameter`` from page ``source`` to page
        ``target`` (a working page back to its reference values)."""


UNLOCK_KEY_ENV = "AMBDAQ_UNLOCK_KEY"
"""Where a user may keep the controller's unlock key (``--key`` and the rig file are the others)."""


class BankPort(ABC):
    """A controller's two coefficient banks (docs/push.md): what ``ambdaq push`` talks to."""

    @abstractmethod
    def unlock(self, key: str) -> None:
        """Unlock the banks with the controller's key (refused: DeviceError)."""

    @abstractmethod
    def write_bank(self, image: bytes) -> None:
        """Write ``image`` into the inactive bank."""

    @abstractmethod
    def bank_status(self) -> dict:
        """Axes, harmonics, the FIR it runs, active bank, device-computed CRC-32s, the push log."""

    @abstractmethod
    def commit_bank(self, crc: int, record: dict) -> int:
        """Switch to the inactive bank if it holds ``crc``; the first sample index run with it."""

    @abstractmethod
    def read_bank(self, which: str, length: int) -> bytes:
        """``length`` bytes of the ``active`` or ``inactive`` bank."""

    @abstractmethod
    def close(self) -> None:
        """Release the port; safe to call twice."""

    def __enter__(self) -> "BankPort":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class ExcitationSpec:
    """A controller's test-signal input (the sensitivity measurement of ISO 14839-3), as it
    reports it.

    Parameters
    ----------
    parameter : str
        The parameter that sets it: [axis index (-1 off), amplitude, frequency Hz].
    axes : tuple of str
        Axes it can excite, by index.
    unit : {"m", "V"}
        Unit of the amplitude: a displacement added to the feedforward r_c, or a voltage.
    min_amplitude, max_amplitude : float
        What it resolves and what it allows, in ``unit``.
    sample_rate_hz : float
        The control rate it runs at, in Hz (a sine must be below half of it).
    """

    parameter: str
    axes: tuple[str, ...]
    unit: str
    min_amplitude: float
    max_amplitude: float
    sample_rate_hz: float

    def as_dict(self) -> dict:
        return {"parameter": self.parameter, "axes": list(self.axes), "unit": self.unit,
                "min_amplitude": self.min_amplitude, "max_amplitude": self.max_amplitude,
                "sample_rate_hz": self.sample_rate_hz}

    @classmethod
    def from_dict(cls, d: dict) -> "ExcitationSpec":
        return cls(str(d["parameter"]), tuple(str(a) for a in d["axes"]), str(d["unit"]),
                   float(d["min_amplitude"]), float(d["max_amplitude"]), float(d["sample_rate_hz"]))


@dataclass(frozen=True)
class Capabilities:
    """What a controller reports it can do, beyond streaming.

    Parameters
    ----------
    banks : bool
        Two coefficient banks written by ``ambdaq push`` (:class:`BankPort`).
    excitation : ExcitationSpec or None
        A test-signal input (``ambdaq frf measure``).
    fir_feedforward : bool
        A FIR feedforward from measured accelerations (``ambdaq fx``; its shape is in the bank
        status).
    speed_parameter : str or None
        The parameter that takes a speed set-point in rpm (``--rpm`` on a recording).
    """

    banks: bool = False
    excitation: ExcitationSpec | None = None
    fir_feedforward: bool = False
    speed_parameter: str | None = None

    def as_dict(self) -> dict:
        return {"coefficient_banks": self.banks, "fir_feedforward": self.fir_feedforward,
                "speed_parameter": self.speed_parameter,
                "excitation": None if self.excitation is None else self.excitation.as_dict()}

    @classmethod
    def from_dict(cls, d: dict | None) -> "Capabilities":
        """From a device's report; what it does not mention it does not have."""
        d = d or {}
        exc = d.get("excitation")
        return cls(bool(d.get("coefficient_banks", False)), None if exc is None else ExcitationSpec.from_dict(exc),
                   bool(d.get("fir_feedforward", False)), d.get("speed_parameter"))


class Controller(Source, Parameters, BankPort):
    """An AMB controller: it streams, has parameters and, where :attr:`capabilities` says so,
    coefficient banks, a test-signal input and a FIR feedforward."""

    @property
    @abstractmethod
    def capabilities(self) -> Capabilities:
        """What this controller reported about itself."""
