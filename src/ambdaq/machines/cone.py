"""Jeong et al.'s rotor on two cone-shaped AMBs, as ambdaq knows it: the rotor and its PD control,
current loop and eddy-current lag (:mod:`ambdaq.analysis.cone_rotor`, eq. 2-16), the rig's
amplifier, supply, touchdown bearings and noise, and the loop's modes (``runup --model cone``).
The simulator (:mod:`ambdaq.sim.rigs.cone`) steps this machine."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ..analysis.cone_rotor import AXES, COILS, ConeControl, ConeRotor, closed_loop_state_space
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
    # assumed: balancing holes on a 25 mm radius in a plane at each bearing, inside the 30 mm core
    # (Jeong et al. give none)
    balance_radius: float = 0.025  # m

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
BALANCE_PLANES = ("upper", "lower")
"""The cone rotor's balancing planes, at bearings 1 (y1/z1) and 2 (y2/z2), where the rig's
unbalance acts: a plane's unbalance U pushes with U Omega^2 along theta + its angle, y = cos, z = sin."""


def campbell_modes(rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Jeong et al.'s coupled 5-DOF cone rotor under its PD control, current loop and eddy-current
    lag (eq. 10-16) at ``rpm`` (rpm): its lightly damped modes (ζ <= 0.5, below 2 kHz), their
    damping, and their whirl from their shape at the two bearings (:func:`loop_modes`, on the loop
    sampled at the rig's rate): the axial mode whirls neither way, and is no 1X critical speed."""
    M, C, K, Kib = CONE.rotor.bearing_model(float(rpm) * RPM_TO_RAD_S)
    A, _B, Cq = closed_loop_state_space(M, C, K, Kib, CONE.control)
    h = 1.0 / CONE.sample_rate
    return loop_modes(expm(A * h), h, fmax_hz=2000.0, outputs=Cq, pairs=BEARING_PAIRS)


def runout_response(rpm: float, runout: Mapping[str, complex]) -> dict[str, complex]:
    """The rotor's steady 1X at ``rpm`` (rpm) that a 1X sensor runout alone drives through Jeong et
    al.'s loop (eq. 10-16: the PD and the current loop act on what the sensor reads, q + r): per
    bearing coordinate by name, phasors ``a + j b`` of ``a sin theta + b cos theta`` (m), the
    runout's likewise (an axis it does not name has none)."""
    omega = float(rpm) * RPM_TO_RAD_S
    M, C, K, Kib = CONE.rotor.bearing_model(omega)
    A, _B, Cq = closed_loop_state_space(M, C, K, Kib, CONE.control)
    c, n = CONE.control, len(AXES)
    # the runout enters where q does on the controller's side: the derivative filter's input and
    # the current loop's PD (the rows of d and i in closed_loop_state_space)
    kp, kd = np.diag(c.kp), np.diag(c.kd)
    Br = np.vstack([np.zeros((2 * n, n)), np.eye(n) / c.tau, -(c.kc * c.ks / c.tau_c) * (kp + kd / c.tau),
                    np.zeros((n, n))])
    r = -1j * np.array([runout.get(a, 0j) for a in AXES], dtype=complex)  # Re(R exp(j theta)) phasors
    q = Cq @ np.linalg.solve(1j * omega * np.eye(A.shape[0]) - A, Br @ r)
    return dict(zip(AXES, 1j * q))


def plane_unbalance(rpm: float, position: Mapping[str, complex], current: Mapping[str, complex]) -> np.ndarray:
    """The unbalance on each balancing plane (:data:`BALANCE_PLANES`, kg m as
    :attr:`~ambdaq.machines.balance_masses.BalanceMass.unbalance`) that the rotor's 1X motion and
    its eight coils' 1X currents imply at ``rpm`` (rpm), from no model of the controller: Newton's
    law for the rigid rotor in bearing coordinates at 1X (Jeong et al. eq. 10 with the magnets
    linearised, eq. 4), (-Omega^2 M_b + j Omega C_b + K_b) q = K_ig' i_e + F_u, each coil's force
    following its current through the eddy-current lag (eq. 16, i_e = i / (1 + j Omega tau_e));
    solved for the unbalance force F_u = U Omega^2, each plane from its bearing's y and z averaged.

    Parameters
    ----------
    rpm : float
        The speed, rpm.
    position : mapping of str to complex
        The rotor's 1X position per bearing coordinate (``x``, ``y1``, ``y2``, ``z1``, ``z2``; m,
        the gap's with the runout out); one not given is 0.
    current : mapping of str to complex
        Each coil's 1X current (``m1`` to ``m8``, A); one not given is 0.

    Both as phasors ``a + j b`` of ``a sin theta + b cos theta``.
    """
    omega = float(rpm) * RPM_TO_RAD_S
    force = -1j * (_as_array(inertia_force(rpm, position)) - _as_array(bearing_force(rpm, position, current)))
    return np.array([(force[y] + 1j * force[z]) / 2 for y, z in BEARING_PAIRS]) / omega**2


def bearing_force(rpm: float, position: Mapping[str, complex], current: Mapping[str, complex]) -> dict[str, complex]:
    """The 1X force the magnets put on the rotor per bearing coordinate at ``rpm`` (rpm), N: their
    negative stiffness and the eight coils' forces, -K_b q + T^-T K_ig i_e (eq. 4 and 10), each
    coil's force following its current through the eddy-current lag (eq. 16); ``position`` and
    ``current`` as :func:`plane_unbalance`'s, the result per coordinate by name, phasors alike."""
    omega = float(rpm) * RPM_TO_RAD_S
    _inertia, stiffness, coils = _force_law(omega)
    q = np.array([position.get(a, 0j) for a in AXES], dtype=complex)
    i = np.array([current.get(c, 0j) for c in COILS], dtype=complex)
    return dict(zip(AXES, -stiffness @ q + coils @ (i / (1 + 1j * omega * CONE.control.tau_e))))


def inertia_force(rpm: float, position: Mapping[str, complex]) -> dict[str, complex]:
    """The force per bearing coordinate (N, phasors as :func:`bearing_force`'s) that moves the rigid
    rotor through its 1X ``position`` (m) at ``rpm`` (rpm): (-Omega^2 M_b + j Omega C_b) q (eq. 10)."""
    inertia, _stiffness, _coils = _force_law(float(rpm) * RPM_TO_RAD_S)
    q = -1j * np.array([position.get(a, 0j) for a in AXES], dtype=complex)  # Re(P exp(j theta)) phasors
    return dict(zip(AXES, 1j * (inertia @ q)))


def _as_array(by_axis: Mapping[str, complex]) -> np.ndarray:
    return np.array([by_axis[a] for a in AXES])


@functools.lru_cache(maxsize=8)
def _force_law(omega: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At spin ``omega`` (rad/s), in bearing coordinates at 1X: the rotor's inertial and gyroscopic
    stiffness -Omega^2 M_b + j Omega C_b, the magnets' negative stiffness K_b (eq. 10), and the eight
    coils' forces per ampere, T^-T K_ig (eq. 4): the same for every window of a run, so computed
    once per speed."""
    rotor = CONE.rotor
    M, C, K, _Kib = rotor.bearing_model(omega)
    _K, Kig = rotor.linearise()
    return -omega**2 * M + 1j * omega * C, K, np.linalg.inv(rotor.transform()).T @ Kig


def loop_model(_calibration: Mapping[str, str]) -> LoopModel:
    """Jeong et al.'s loop (:func:`campbell_modes`, :func:`runout_response`) and the rotor's force
    law for balancing (:func:`plane_unbalance`): the simulated cone rig's controller has no gains
    to retune, so a recording's calibration changes nothing."""
    return LoopModel(campbell_modes, "Jeong et al.'s PD control, current loop and eddy-current lag (eq. 10-16)",
                     assumed=False, runout_response=runout_response, balance_planes=BALANCE_PLANES,
                     balance_radius_m=CONE.balance_radius, plane_unbalance=plane_unbalance, axes=AXES,
                     currents=COILS, bearing_force=bearing_force, inertia_force=inertia_force)
