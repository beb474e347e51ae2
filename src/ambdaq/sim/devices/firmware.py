"""What a simulated controller runs: the topics it streams, the parameters it answers to, what it
reports it can do, and how its coefficient banks load into the rig.

Each rig profile that serves a controller defines its :class:`Firmware` beside its physics (the
``PROFILE`` of its module in :mod:`ambdaq.sim.rigs`); :class:`~.controller.SimController` and
:class:`~.banks.CoefficientBanks` are the same for every profile.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...drivers.coefbank import BankImage
from ...drivers.excitation import OFF, Excitation
from ...drivers.interfaces import Capabilities
from ...speed import SpeedProfile

SPEED_RAMP_RPM_S = 5000.0  # how fast the simulated drive follows a speed set-point


@dataclass(frozen=True)
class Param:
    """A controller parameter.

    Parameters
    ----------
    size : int
        Number of values (0: any).
    read : callable
        rig -> values.
    write : callable, optional
        (rig, values) -> None; None: read-only.
    lo, hi : float
        Range of every value.
    doc : str
        What it is, with its unit (docs/protocol.md).
    problem : callable, optional
        (rig, values) -> why they cannot be taken, or ''.
    """

    size: int
    read: Callable
    write: Callable | None = None
    lo: float = -np.inf
    hi: float = np.inf
    doc: str = ""
    problem: Callable | None = None

    def check(self, rig, values: np.ndarray) -> str:
        """Why ``values`` cannot be written, or ''."""
        if self.size and values.shape[0] != self.size:
            return f"expected {self.size} values, got {values.shape[0]}"
        if not np.all(np.isfinite(values)):
            return "values must be finite"
        if np.any(values < self.lo) or np.any(values > self.hi):
            return f"values must be within {self.lo:g} .. {self.hi:g}"
        return self.problem(rig, values) if self.problem else ""


def _excitation_problem(rig, values: np.ndarray) -> str:
    if values[0] != int(values[0]):
        return "the axis must be an integer"
    exc = Excitation.from_values(values)
    return "" if exc is None else exc.problem(rig.excitation_spec())


def _read_excitation(rig) -> np.ndarray:
    return np.array(OFF if rig.excitation is None else rig.excitation.values())


EXCITATION = Param(3, _read_excitation, lambda rig, v: rig.set_excitation(Excitation.from_values(v)), -1.0, 5000.0,
                   "test signal added to one axis's feedforward: [axis (-1 off), amplitude m or V (sine peak, "
                   "noise RMS), frequency Hz (0: white noise)]; the rig's ExcitationSpec says which", _excitation_problem)
"""``exc.signal`` of a rig with a test-signal input (:class:`~ambdaq.sim.rigs.excitation.ExcitationInput`)."""


def _command_speed(rig, rpm: float) -> None:
    now = rig.run_speed_rpm()
    rig.command_speed(SpeedProfile(now, rpm, max(abs(rpm - now) / SPEED_RAMP_RPM_S, 1e-3)))


SPEED = Param(1, lambda rig: np.array([rig.run_speed_rpm()]), lambda rig, v: _command_speed(rig, float(v[0])),
              0.0, 60000.0, "speed: reads the present speed, writes a set-point (ramp at 5,000 rpm/s), rpm")
"""``speed.rpm`` of a rig whose drive takes a speed command."""


class Feedforward(ABC):
    """How the controller's coefficient banks load into its rig: what a bank holds, what the rig
    runs at start-up, and the switch itself (run between two control periods)."""

    @abstractmethod
    def layout(self, rig) -> dict:
        """Axes and harmonics the banks hold, and the FIR's shape if any (in the bank status)."""

    @abstractmethod
    def present(self, rig) -> BankImage:
        """What the rig runs now, as a bank image."""

    @abstractmethod
    def apply(self, rig, image: BankImage) -> None:
        """Make ``rig`` run ``image``."""

    def problem(self, rig, image: BankImage) -> str:
        """Why ``image`` does not fit this controller, or ''."""
        lay = self.layout(rig)
        problem = image.problem(len(lay["axes"]), lay["harmonics"])
        if problem:
            return problem
        if image.pid is not None:
            ctl = lay.get("controller")
            if ctl is None:
                return "this controller's bank holds no feedback controller (PID and sections)"
            if image.pid.shape[0] != len(lay["axes"]):
                return f"the controller section has {image.pid.shape[0]} axes, this controller {len(lay['axes'])}"
            if image.biquads is not None and image.biquads.shape[1] > ctl["max_sections"]:
                return (f"the controller has {image.biquads.shape[1]} sections per axis; this firmware runs at most "
                        f"{ctl['max_sections']}")
        fir = lay.get("fir")
        if image.fir_taps is None:
            return ""
        if fir is None:
            return "this controller runs no FIR feedforward"
        shape = (len(fir["planes"]), fir["outputs"], fir["inputs"])
        if image.fir_taps.shape[:3] != shape or image.fir_taps.shape[3] > fir["max_taps"]:
            return f"the FIR is {image.fir_taps.shape}; this controller runs {shape} x at most {fir['max_taps']} taps"
        if image.fir_rate_hz != fir["sample_rate_hz"]:
            return f"the FIR runs at {image.fir_rate_hz:g} Hz, this controller at {fir['sample_rate_hz']:g} Hz"
        return ""


@dataclass(frozen=True)
class Firmware:
    """What the simulated controller of one rig profile streams, answers to and runs.

    Parameters
    ----------
    model : str
        Model name in its IDENTITY.
    topics : tuple of str
        The rig's groups it streams, in order (``/truth/...`` are added on request).
    parameters : dict of str to Param
        What PARAM_READ and PARAM_WRITE reach.
    feedforward : Feedforward
        How its coefficient banks load into the rig.
    """

    model: str
    topics: tuple[str, ...]
    parameters: dict[str, Param]
    feedforward: Feedforward

    def capabilities(self, rig) -> Capabilities:
        """What the controller reports about itself (IDENTITY, docs/protocol.md)."""
        return Capabilities(
            banks=True,
            excitation=rig.excitation_spec() if "exc.signal" in self.parameters else None,
            fir_feedforward="fir" in self.feedforward.layout(rig),
            speed_parameter="speed.rpm" if "speed.rpm" in self.parameters else None,
        )
