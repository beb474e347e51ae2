"""The 50,000 rpm AMB grinding spindle of Ro et al. (Table 1 and section 2), as ambdaq knows it:
axes, rates, the rotor, the five bearing axes with their amplifiers and PID, the sensors and
converters, the (simulated) runout and unbalance, and its controller's feedforward tables.

The simulator (:mod:`ambdaq.sim.rigs.spindle`), the analysis defaults (Ro et al.'s one-axis loops
in :mod:`ambdaq.analysis.lms`, the rigid rotor of :mod:`ambdaq.analysis.rotor`) and the command
line read it from here.  Where Ro et al. gives no number the value is an assumption, marked.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..analysis.lms import OneAxis
from ..analysis.rotor import RigidRotor
from ..units import GRAVITY

AXES = ("front_x", "front_y", "rear_x", "rear_y", "axial")  # bearing coordinates, gap sensors co-located
N_AXES = 5
RADIAL = AXES[:4]
SAMPLE_RATE = 10_000.0  # Hz, the DSP's control rate
N_HARMONICS = 8  # harmonics 1X..8X carried by the runout model and the feedforward
MU_BIN_RPM = 100.0  # resolution of the LMS step-size schedule over speed
MU_BINS = 601  # 0 .. 60,000 rpm
PHASE_BIN_HZ = 10.0  # resolution of the LMS phase compensation over loop frequency
PHASE_BINS = 501  # 0 .. 5,000 Hz (the Nyquist frequency at 10 kHz)

# Ro et al., section 3.3: mu = -0.001 below 5,500 rpm, 0 (weights held) to 6,500, +0.001 above.
PAPER_MU_SCHEDULE = ((0.0, 5500.0, -0.001), (5500.0, 6500.0, 0.0), (6500.0, 60000.0, 0.001))


@dataclass(frozen=True)
class BearingAxis:
    """One AMB control axis: magnet, amplifier and PID.

    Parameters
    ----------
    ki : float
        Current gain, in N/A.
    kx : float
        Position (negative) stiffness, in N/m.
    bias : float
        Bias current I0, in A.
    amp_gain : float
        Amplifier DC gain Kamp, in A/V.
    amp_wn_hz : float
        Amplifier natural frequency, in Hz.
    amp_zeta : float
        Amplifier damping ratio.
    pid_p : float
        Proportional gain, in V/V.
    pid_i : float
        Integral gain, in 1/s.
    pid_d : float
        Derivative gain, in s.
    housing_mass : float
        Effective housing mass the bearing reaction acts on, in kg.
    """

    ki: float
    kx: float
    bias: float
    amp_gain: float
    amp_wn_hz: float
    amp_zeta: float
    pid_p: float
    pid_i: float
    pid_d: float
    housing_mass: float


def _runout_table(amps_um: list[float], phases_deg: list[float]) -> tuple[np.ndarray, np.ndarray]:
    amp = np.zeros(N_HARMONICS)
    ph = np.zeros(N_HARMONICS)
    amp[: len(amps_um)] = np.asarray(amps_um) * 1e-6
    ph[: len(phases_deg)] = np.deg2rad(phases_deg)
    return amp, ph


def _default_runout() -> tuple[np.ndarray, np.ndarray]:
    """Electrical runout, amplitude (m) and phase (rad) per axis and harmonic (1X first).

    Ro et al. measured 15 um (front) and 30 um (rear) on the spindle, 1X and 2X dominant.
    """
    front = _runout_table([9.0, 5.0, 1.5, 1.0, 0.5, 0.3], [30, 110, 200, 300, 45, 160])
    rear = _runout_table([16.0, 9.0, 3.0, 1.5, 0.8, 0.4], [250, 20, 140, 75, 330, 210])
    axial = _runout_table([1.5, 0.8, 0.3], [90, 10, 270])
    k = np.arange(1, N_HARMONICS + 1)
    amp = np.zeros((N_AXES, N_HARMONICS))
    ph = np.zeros((N_AXES, N_HARMONICS))
    for a, (track, shift) in enumerate(
        [(front, 0.0), (front, -np.pi / 2), (rear, 0.0), (rear, -np.pi / 2), (axial, 0.0)]
    ):
        amp[a] = track[0]
        # the y sensor is 90 deg round from x on the same track: r_y(theta) = r_x(theta - pi/2)
        ph[a] = np.mod(track[1] + k * shift, 2 * np.pi)
    return amp, ph


@dataclass(frozen=True)
class SpindleParams:
    """Parameters of the simulated spindle rig (defaults: Ro et al., Table 1 and section 2)."""

    mass: float = 4.38  # kg
    jp: float = 0.0014  # kg m^2, polar
    jt: float = 0.0362  # kg m^2, transverse
    a: float = 0.11  # m, centre of mass to front bearing
    b: float = 0.11  # m, centre of mass to rear bearing
    front: BearingAxis = BearingAxis(273.0, 1.77e6, 2.1, 0.8, 1800.0, 1.7, 1.6, 1.0, 0.0015, 12.0)
    rear: BearingAxis = BearingAxis(182.0, 1.18e6, 2.1, 0.8, 2500.0, 1.7, 1.6, 1.0, 0.002, 12.0)
    # assumed: Ro et al. gives no thrust-bearing data
    axial: BearingAxis = BearingAxis(200.0, 0.8e6, 2.1, 0.8, 2500.0, 1.7, 1.6, 1.0, 0.002, 25.0)
    sample_rate: float = SAMPLE_RATE  # Hz
    sensor_gain: float = 1.0e4  # V/m
    adc_bits: int = 16
    adc_range: float = 10.0  # +-V
    dac_bits: int = 12
    dac_range: float = 10.0  # +-V
    coil_max_current: float = 8.0  # A
    derivative_filter: float = 15.0  # Nd
    gap_noise: float = 0.2e-6  # m rms
    current_noise: float = 2e-3  # A rms
    accel_noise: float = 0.05  # m/s^2 rms
    runout_amp: np.ndarray = field(default_factory=lambda: _default_runout()[0])  # m
    runout_phase: np.ndarray = field(default_factory=lambda: _default_runout()[1])  # rad
    unbalance: tuple[float, float] = (2.0e-6, 3.0e-6)  # kg m, front and rear planes
    unbalance_phase: tuple[float, float] = (0.0, 2.0)  # rad
    # assumed: balancing holes on a 30 mm radius in the front and rear planes (Ro et al. give none)
    balance_radius: float = 0.03  # m
    # assumed: Ro et al. gives no touchdown bearings; their radial clearance is commonly half the
    # magnetic air gap (0.3 mm, Table 1)
    min_clearance: float = 0.15e-3  # m, Cmin of ISO 14839-2
    # assumed, the touchdown bearings themselves (round radial ones and an axial stop at Cmin): a
    # ball bearing's stiffness (its mode 5.8 krad/s on the tilt mode's 1.5 kg, 0.03 rad in one of
    # the 5 us steps the rig takes in contact), damped at about 0.2
    contact_stiffness: float = 5e7  # N/m
    contact_damping: float = 4000.0  # N s/m
    coil_time_constant: float = 0.005  # s, L/R: how fast the bias decays with the amplifiers off

    @property
    def axes(self) -> tuple[BearingAxis, ...]:
        return (self.front, self.front, self.rear, self.rear, self.axial)

    def runout_sin_cos(self) -> tuple[np.ndarray, np.ndarray]:
        """Runout as sin and cos coefficients: R sin(k theta + phi) = A sin k theta + B cos k theta."""
        return self.runout_amp * np.cos(self.runout_phase), self.runout_amp * np.sin(self.runout_phase)

    @property
    def rotor(self) -> RigidRotor:
        """The rigid rotor on its five bearing axes (one model for the simulator and the analysis)."""
        return RigidRotor(self.mass, self.jt, self.jp, self.a, self.b, tuple(ax.kx for ax in self.axes),
                          tuple(ax.ki for ax in self.axes))

    def rotor_metadata(self) -> dict[str, str]:
        """The rotor model as ``rotor.*`` calibration entries (docs/coefficients.md): what runout
        identification needs to tell rotor motion from runout."""
        return self.rotor.metadata()

    def bearing_gravity(self) -> np.ndarray:
        """Static gravity load per axis in bearing coordinates, in N (negative: downwards)."""
        span = self.a + self.b
        f = np.zeros(N_AXES)
        f[1] = -self.mass * GRAVITY * self.b / span
        f[3] = -self.mass * GRAVITY * self.a / span
        return f


BALANCE_PLANES = ("front", "rear")
"""The spindle's balancing planes, at its bearings, where its unbalance acts (SpindleParams.unbalance)."""
SPINDLE = SpindleParams()



ONE_AXIS_MASS = 1.5
"""kg: the mass of Ro et al.'s one-axis model (eq. 1), as the paper prints it; the rotor's tilt
mode has Jt / (2 a^2) = 1.496 kg per bearing with a = b = 0.11 m (why we took that span)."""


def one_axis_loop(axis: BearingAxis, p: SpindleParams = SPINDLE) -> OneAxis:
    """Ro et al.'s one-axis loop of one of the spindle's bearing axes (m = 1.5 kg, eq. 1; the
    sensor, derivative filter and control rate of ``p``)."""
    return OneAxis(m=ONE_AXIS_MASS, ki=axis.ki, kx=axis.kx, ks=p.sensor_gain, amp_gain=axis.amp_gain,
                   amp_wn_hz=axis.amp_wn_hz, amp_zeta=axis.amp_zeta, p=axis.pid_p, i=axis.pid_i, d=axis.pid_d,
                   nd=p.derivative_filter, h=1.0 / p.sample_rate)


FRONT_LOOP = one_axis_loop(SPINDLE.front)
"""Ro et al.'s front bearing: m 1.5 kg, Table 1 front, PID P 1.6, I 1, D 0.0015, Nd 15, h 100 us."""
REAR_LOOP = one_axis_loop(SPINDLE.rear)
"""The same for the rear bearing (D 0.002, amplifier 2,500 Hz)."""
