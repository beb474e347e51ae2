"""Jeong et al.'s rotor on two cone-shaped AMBs, as ambdaq knows it: the rotor and its PD control,
current loop and eddy-current lag (:mod:`ambdaq.analysis.cone_rotor`, eq. 2-16), the rig's
amplifier, supply, touchdown bearings and noise, and the loop's modes (``runup --model cone``).
The simulator (:mod:`ambdaq.sim.rigs.cone`) steps this machine."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ..analysis.cone_rotor import AXES, ConeControl, ConeRotor, closed_loop_state_space
from ..analysis.orders import loop_modes
from ..units import RPM_TO_RAD_S
from .models import LoopModel


@dataclass(frozen=True)
class ConeParams:
    """The cone rig (SI).  Rotor and gains from Jeong et al. Tables 1 and 3 where given; the
    amplifier's Ka, Kf, R are chosen for tau_c = 6e-5 s (the paper's example) and Kc from the
    sensor gain so the axial loop sits near the paper's design (see docs/cone.md)."""

    sample_rate: float = 10_000.0
    rotor: ConeRotor = ConeRotor()
    control: ConeControl = ConeControl(ks=2000.0, kc=0.36)
    resistance: float = 2.0  # coil, ohm
    supply: float = 25.0  # V (Table 1)
    clearance: float = 0.25e-3  # touchdown bearings (round, radial; and the axial stop), m
    contact_stiffness: float = 2e7  # N/m
    contact_damping: float = 400.0  # N s/m
    gap_noise: float = 0.1e-6  # m RMS
    hammer_noise: float = 0.05  # N RMS

    @property
    def amp_gain(self) -> float:
        """Ka (V/V) from Kc = Ka / (Ka Kf + R) and tau_c = L / (Ka Kf + R) (eq. 15)."""
        return self.control.kc * self.rotor.inductance / self.control.tau_c

    @property
    def current_feedback(self) -> float:
        """Kf (V/A)."""
        return (self.rotor.inductance / self.control.tau_c - self.resistance) / self.amp_gain


CONE = ConeParams()


BEARING_PAIRS = ((AXES.index("y1"), AXES.index("z1")), (AXES.index("y2"), AXES.index("z2")))
"""Each bearing's (x, y) of the full spectrum in ``AXES``: the spin turns y towards z."""


def campbell_modes(rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Jeong et al.'s coupled 5-DOF cone rotor under its PD control, current loop and eddy-current
    lag (eq. 10-16) at ``rpm`` (rpm): its lightly damped modes (ζ <= 0.5, below 2 kHz), their
    damping, and their whirl from their shape at the two bearings (:func:`loop_modes`, on the loop
    sampled at the rig's rate): the axial mode whirls neither way, and is no 1X critical speed."""
    M, C, K, Kib = CONE.rotor.bearing_model(float(rpm) * RPM_TO_RAD_S)
    A, _B, Cq = closed_loop_state_space(M, C, K, Kib, CONE.control)
    h = 1.0 / CONE.sample_rate
    return loop_modes(expm(A * h), h, fmax_hz=2000.0, outputs=Cq, pairs=BEARING_PAIRS)


def loop_model(_calibration: Mapping[str, str]) -> LoopModel:
    """Jeong et al.'s loop (:func:`campbell_modes`): the simulated cone rig's controller has no
    gains to retune, so a recording's calibration changes nothing."""
    return LoopModel(campbell_modes, "Jeong et al.'s PD control, current loop and eddy-current lag (eq. 10-16)",
                     assumed=False)
