"""The spindle's closed loop as designed, linear and discrete at the control rate: rotor, amplifiers
and the controller's PID (Ro et al. eq. 1-3 with the five-axis rigid rotor of
:class:`~ambdaq.analysis.rotor.RigidRotor`).

This is the machine's model that the host side reads (``runup --model spindle``, ``lms --plant rig``,
the ISO 14839-3 sensitivity an ``iso stability`` run is compared with) and that the simulator's
kernel steps (:mod:`ambdaq.sim.rigs.spindle`, which adds what is not linear: noise, quantisation,
saturation, the coils' law, touchdown).  tests/test_rig_physics.py holds the kernel, probed one
unit perturbation at a time with everything nonlinear off, to these matrices.

State, per control period (the kernel's order)::

    x = [rotor positions (5), velocities (5),
         amplifiers [i, di/dt] per axis (10),
         controller [integral, filtered derivative, previous error voltage] per axis (15)]

with the feedforward r_c (m per axis, subtracted from the sensor signal, Ro et al. eq. 10) as input
and the command error e (m per axis) as output:

    x[n+1] = M x[n] + B r_c[n],   e[n] = C x[n] - r_c[n].
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
import numpy as np

from ..analysis.amb import zoh
from ..analysis.lms import DesignModels, StateSpaceLoop
from ..analysis.orders import loop_modes
from ..errors import BadInputError
from ..units import RPM_TO_RAD_S
from .machine import radial_bearings
from .models import LoopModel
from .spindle import AXES, BALANCE_PLANES, FRONT_LOOP, N_AXES, PHASE_BIN_HZ, PHASE_BINS, REAR_LOOP, SPINDLE, BearingAxis, SpindleParams

N_STATE = 35  # rotor 10, amplifiers 10, controller 15

Gains = tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]
"""PID gains (P in V/V, I in 1/s, D in s), one tuple each, one value per axis in ``AXES`` order."""


def rotor_matrices(p: SpindleParams, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time rotor model in bearing coordinates.

    Parameters
    ----------
    p : SpindleParams
        Rig parameters.
    omega : float
        Rotor speed, in rad/s (sets the gyroscopic coupling Jp*Omega).

    Returns
    -------
    A : ndarray, shape (10, 10)
        State matrix for [positions (5), velocities (5)] in AXES order, with the negative
        magnet stiffness Kx included.
    B : ndarray, shape (10, 5)
        Input matrix for the bearing forces, in N.
    """
    M, G = p.rotor.mass_gyro(omega)  # the one rigid-rotor model (ambdaq.analysis.rotor)
    Minv = np.linalg.inv(M)  # bearing forces -> bearing accelerations
    kx = np.array([ax.kx for ax in p.axes])
    A = np.zeros((10, 10))
    A[:5, 5:] = np.eye(5)
    A[5:, :5] = Minv * kx[None, :]
    A[5:, 5:] = -Minv @ G  # the gyroscopic coupling of the tilt planes
    B = np.zeros((10, 5))
    B[5:, :] = Minv
    return A, B


def amplifier_continuous(ax: BearingAxis) -> tuple[np.ndarray, np.ndarray]:
    """The amplifier G_A (Ro et al. eq. 2) in continuous time: state [i, di/dt], input in V."""
    wn = 2 * np.pi * ax.amp_wn_hz
    return np.array([[0.0, 1.0], [-(wn**2), -2 * ax.amp_zeta * wn]]), np.array([[0.0], [wn**2 * ax.amp_gain]])


def amplifier_matrices(ax: BearingAxis, h: float) -> tuple[np.ndarray, np.ndarray]:
    """ZOH-discretised amplifier G_A (Ro et al. eq. 2): state [i, di/dt], input in V, step h (s)."""
    Phi, Gam = zoh(*amplifier_continuous(ax), h)
    return Phi, Gam[:, 0]


def rotor_through_amplifiers(A: np.ndarray, B: np.ndarray, p: SpindleParams, h: float) -> tuple[np.ndarray, np.ndarray]:
    """What one step does to the rotor through the coil currents as they move within it.

    The controller's output u is held over the step (its DAC); each amplifier's current follows
    it continuously and the magnet's force ``ki i(t)`` with it. Holding the current's average
    over the step instead is a force low-passed by cos(w h / 2) sinc(w h / 2): 6 % short at 1 kHz,
    24 % at 2 kHz at 10 kHz, and the rotor's 2X-4X at 30,000 rpm was then not what its currents
    say (a runout estimate 90 nm off the truth). The exact ZOH of rotor and amplifiers together
    (state [rotor (10), amplifiers 2 per axis (10)], input u):

        z[n+1] = Phi z[n] + Psi_q q[n] + Psi_u u[n] (+ Gamma F_other[n])

    Returns ``Psi_q`` (10, 10), on the amplifier states in axis-major order ([i, di/dt]), and
    ``Psi_u`` (10, 5), on u in V."""
    n = 20
    Af = np.zeros((n, n))
    Bu = np.zeros((n, 5))
    Af[:10, :10] = A
    for a, ax in enumerate(p.axes):
        Aa, Ba = amplifier_continuous(ax)
        Af[10 + 2 * a:12 + 2 * a, 10 + 2 * a:12 + 2 * a] = Aa
        Bu[10 + 2 * a:12 + 2 * a, a] = Ba[:, 0]
        Af[:10, 10 + 2 * a] = B[:, a] * ax.ki  # the force of the coil current, ki i
    Phi, Gam = zoh(Af, Bu, h)
    return Phi[:10, 10:].copy(), Gam[:10].copy()


def derivative_filter(p: np.ndarray, d: np.ndarray, nd: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The backward-Euler filtered derivative D s / (1 + s Tf), Tf = (D / P) / Nd, as the
    controller runs it: ``deriv[n] = ad deriv[n-1] + bd (ev[n] - ev[n-1])``.

    Parameters
    ----------
    p, d : ndarray
        Proportional (V/V) and derivative (s) gains per axis.
    nd : float
        Nd, the derivative filter's ratio (dimensionless).
    h : float
        Control period, in s.

    Returns
    -------
    ad, bd : ndarray
        The recursion's coefficients (dimensionless, s/s).
    """
    tf = d / p / nd
    return tf / (tf + h), d / (tf + h)


def default_gains(p: SpindleParams = SPINDLE) -> Gains:
    """Ro et al.'s PID gains (Table 1) of each axis of ``p``."""
    return (tuple(ax.pid_p for ax in p.axes), tuple(ax.pid_i for ax in p.axes), tuple(ax.pid_d for ax in p.axes))


class SpindleLoop:
    """The spindle's linear loop at given PID gains (see the module's docstring).

    Parameters
    ----------
    params : SpindleParams
        The machine (rotor, bearing axes, sensor gain, control rate).
    gains : Gains, optional
        PID gains per axis (P V/V, I 1/s, D s); default Ro et al.'s (:func:`default_gains`).
    """

    def __init__(self, params: SpindleParams = SPINDLE, gains: Gains | None = None) -> None:
        self.params = params
        self.gains = gains or default_gains(params)
        self.h = 1.0 / params.sample_rate  # control period, s
        self._fixed = self._controller_and_amplifiers()
        self._rotor_steps: dict[float, tuple[np.ndarray, ...]] = {}

    def _controller_and_amplifiers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The rows that do not depend on the speed: M and B of the amplifiers and the controller,
        and the controller's output u = U x + Ur r_c (V)."""
        p, h = self.params, self.h
        P, I, D = (np.asarray(g, dtype=float) for g in self.gains)
        ad, bd = derivative_filter(P, D, p.derivative_filter, h)
        ks = p.sensor_gain
        ci = I * h * 0.5  # Tustin integral: integ[n] = integ[n-1] + I h/2 (ev[n] + ev[n-1])
        M, B = np.zeros((N_STATE, N_STATE)), np.zeros((N_STATE, N_AXES))
        U, Ur = np.zeros((N_AXES, N_STATE)), np.zeros(N_AXES)
        for a in range(N_AXES):
            integ, deriv, prev = 20 + 3 * a, 21 + 3 * a, 22 + 3 * a
            # the error voltage ev = Ks (z_a - r_c,a) (Ro et al. eq. 10, the sensor at the bearing)
            M[integ, a], M[integ, integ], M[integ, prev], B[integ, a] = ci[a] * ks, 1.0, ci[a], -ci[a] * ks
            M[deriv, a], M[deriv, deriv], M[deriv, prev], B[deriv, a] = bd[a] * ks, ad[a], -bd[a], -bd[a] * ks
            M[prev, a], B[prev, a] = ks, -ks
            # u = -(P ev + integ[n] + deriv[n]) (eq. 3, the parallel PID)
            U[a] = -(M[integ] + M[deriv])
            U[a, a] -= P[a] * ks
            Ur[a] = P[a] * ks - B[integ, a] - B[deriv, a]
            Pa, Ga = amplifier_matrices(p.axes[a], h)
            rows = slice(10 + 2 * a, 12 + 2 * a)
            M[rows, rows] = Pa
            M[rows] += np.outer(Ga, U[a])
            B[rows, a] += Ga * Ur[a]
        return M, B, U, Ur

    def _rotor(self, rpm: float) -> tuple[np.ndarray, ...]:
        """The rotor's ZOH step at ``rpm``: Phi, Gamma (on the bearing forces) and Psi_q, Psi_u."""
        if rpm not in self._rotor_steps:
            A, Bf = rotor_matrices(self.params, rpm * RPM_TO_RAD_S)
            self._rotor_steps[rpm] = (*zoh(A, Bf, self.h), *rotor_through_amplifiers(A, Bf, self.params, self.h))
        return self._rotor_steps[rpm]

    def matrices(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M (35, 35), B (35, 5) and C (5, 35) at ``rpm`` (rpm): x[n+1] = M x + B r_c, e = C x - r_c."""
        M0, B0, U, Ur = self._fixed
        Phi, _Gam, Psq, Psu = self._rotor(float(rpm))
        M, B = M0.copy(), B0.copy()
        M[:10, :10] = Phi
        M[:10, 10:20] = Psq
        M[:10] += Psu @ U
        B[:10] = Psu * Ur[None, :]
        C = np.zeros((N_AXES, N_STATE))
        C[:, :N_AXES] = np.eye(N_AXES)
        return M, B, C

    def unbalance_response(self, rpm: float) -> np.ndarray:
        """The rotor's steady 1X at ``rpm`` (rpm): its position at each bearing axis as a phasor
        ``a + j b`` of ``a sin theta + b cos theta`` (m; as :func:`~ambdaq.analysis.runout.harmonic_fit`
        gives a recording's 1X), from the loop (:meth:`matrices`) driven by the machine's
        unbalance (a force ``U Omega^2`` per plane, held over each step from its mid-step angle,
        as the simulator applies it) and its 1X sensor runout (which the loop sees as a feedforward
        of the opposite sign): the unbalance response analysis of API 684 on this model.

        Returns
        -------
        ndarray of complex, shape (5,)
            In ``AXES`` order.
        """
        p = self.params
        M, B, _C = self.matrices(rpm)
        Gam = self._rotor(float(rpm))[1]
        omega = rpm * RPM_TO_RAD_S
        unb = np.array([p.unbalance[0], p.unbalance[0], p.unbalance[1], p.unbalance[1], 0.0])
        ph = np.array(p.unbalance_phase)
        unb_ph = np.array([ph[0], ph[0] - np.pi / 2, ph[1], ph[1] - np.pi / 2, 0.0])  # x: cos, y: sin
        run_s, run_c = p.runout_sin_cos()
        step = np.exp(1j * omega * self.h)  # the angle advances this much per step
        force = unb * omega**2 * np.exp(1j * unb_ph) * np.sqrt(step)
        runout = run_c[:, 0] - 1j * run_s[:, 0]  # A sin + B cos = Re((B - jA) exp(j theta))
        drive = np.zeros(M.shape[0], dtype=complex)
        drive[:10] = Gam @ force
        drive -= B @ runout
        state = np.linalg.solve(step * np.eye(M.shape[0]) - M, drive)
        return 1j * state[:5]  # Re(P exp(j theta)) = a sin theta + b cos theta with a + j b = j P

    def runout_response(self, rpm: float, runout: np.ndarray) -> np.ndarray:
        """The rotor's steady 1X at ``rpm`` (rpm) that a 1X sensor runout alone drives through the
        loop (the controller follows what its sensors read): ``runout`` and the result per axis as
        phasors ``a + j b`` of ``a sin theta + b cos theta`` (m), as :meth:`unbalance_response`."""
        M, B, _C = self.matrices(rpm)
        step = np.exp(1j * rpm * RPM_TO_RAD_S * self.h)
        state = np.linalg.solve(step * np.eye(M.shape[0]) - M, -B @ (-1j * np.asarray(runout, dtype=complex)))
        return 1j * state[:5]


    def bearing_force(self, rpm: float, position: np.ndarray, current: np.ndarray) -> np.ndarray:
        """The 1X force each bearing axis's magnet puts on the rotor at ``rpm`` (rpm), N: its
        linearised force law, kx q + ki i (Ro et al. eq. 1), from the rotor's 1X position (m; the
        gap's with the runout out) and the coil control current's (A), per axis in ``AXES`` order,
        all phasors ``a + j b`` of ``a sin theta + b cos theta``."""
        del rpm  # the spindle's magnets have no eddy-current lag: the same law at every speed
        p = self.params
        kx, ki = np.array([ax.kx for ax in p.axes]), np.array([ax.ki for ax in p.axes])
        return kx * np.asarray(position) + ki * np.asarray(current)

    def inertia_force(self, rpm: float, position: np.ndarray) -> np.ndarray:
        """The force per bearing axis (N, phasors as :meth:`bearing_force`'s) that moves the rigid
        rotor through its 1X ``position`` (m) at ``rpm`` (rpm): (-Omega^2 M + j Omega G) q, its mass,
        inertia and gyroscopic coupling at the bearings (the unbalance's force is its part not given
        by the bearings)."""
        omega = rpm * RPM_TO_RAD_S
        M, G = self.params.rotor.mass_gyro(omega)
        return 1j * ((-omega**2 * M + 1j * omega * G) @ (-1j * np.asarray(position)))

    def plane_unbalance(self, rpm: float, position: np.ndarray, current: np.ndarray) -> np.ndarray:
        """The unbalance on each balancing plane (at the bearings; kg m, as
        :attr:`~ambdaq.machines.balance_masses.BalanceMass.unbalance`) that the rotor's 1X motion
        and its bearings' 1X forces imply at ``rpm`` (rpm), from no model of the loop: Newton's law
        for the rigid rotor at 1X, (-Omega^2 M + j Omega G) q = Kx q + Ki i + F_u (the bearings'
        linearised force, Ro et al. eq. 1), solved for the unbalance force F_u = U Omega^2 along
        theta + phase (x: cos, y: sin), each plane from its bearing's x and y averaged.

        Parameters
        ----------
        rpm : float
            The speed, rpm.
        position, current : ndarray of complex, shape (5,)
            The rotor's 1X position at each bearing axis (m; the gap's with the runout out) and the
            coil control currents' (A), in ``AXES`` order, as phasors ``a + j b`` of
            ``a sin theta + b cos theta``.
        """
        omega = rpm * RPM_TO_RAD_S
        force = -1j * (self.inertia_force(rpm, position) - self.bearing_force(rpm, position, current))
        return np.array([(force[2 * k] + 1j * force[2 * k + 1]) / 2 for k in range(len(BALANCE_PLANES))]) / omega**2


GAIN_KEYS = ("controller.pid.p", "controller.pid.i", "controller.pid.d")
"""The calibration entries that state the PID gains the controller ran (its parameters ``pid.p``,
``pid.i``, ``pid.d``: V/V, 1/s, s), one value per axis in ``AXES`` order, comma-separated."""
GAIN_LEAST = (1e-6, 0.0, 1e-6)
"""The least P, I, D the spindle's controller accepts (V/V, 1/s, s): a PID with P or D of zero has
no derivative filter (Tf = D / P / Nd)."""


def recorded_gains(calibration: Mapping[str, str]) -> Gains | None:
    """The PID gains a recording's calibration states (:data:`GAIN_KEYS`), or None where it states
    none; BadInputError, naming the entry, where one is missing, not one per axis, not finite, or
    below what the controller accepts (:data:`GAIN_LEAST`)."""
    given = [calibration.get(k) for k in GAIN_KEYS]
    if all(v is None for v in given):
        return None
    gains = []
    for key, text, least in zip(GAIN_KEYS, given, GAIN_LEAST):
        try:
            values = tuple(float(v) for v in (text or "").split(","))
        except ValueError:
            values = ()
        if len(values) != N_AXES or not all(np.isfinite(v) and least <= v for v in values):
            raise BadInputError(f"the recording's {key} is {text!r}: {N_AXES} gains, one per axis "
                                f"({', '.join(AXES)}), each finite and at least {least:g}")
        gains.append(values)
    return tuple(gains)


def loop_model(calibration: Mapping[str, str]) -> LoopModel:
    """The spindle's loop (:class:`SpindleLoop`) at the PID gains the recording's controller ran
    (:func:`recorded_gains`), or at Ro et al.'s (Table 1) where the recording does not say: its
    lightly damped modes (ζ <= 0.5, below 2 kHz) at each speed, with their damping and whirl from
    their shape at the bearings (:func:`~ambdaq.analysis.orders.loop_modes`)."""
    gains = recorded_gains(calibration)
    loop = SpindleLoop(gains=gains)
    pairs = tuple((AXES.index(b.x), AXES.index(b.y)) for b in radial_bearings(AXES))

    def at(rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        M, _B, C = loop.matrices(float(rpm))
        return loop_modes(M, loop.h, fmax_hz=2000.0, outputs=C, pairs=pairs)

    def response(rpm: float) -> dict[str, complex]:
        return dict(zip(AXES, loop.unbalance_response(float(rpm))))

    def per_axis(values: Mapping[str, complex]) -> np.ndarray:  # phasors by axis name, in AXES order (0: none)
        return np.array([values.get(a, 0j) for a in AXES])

    def runout_response(rpm: float, runout: Mapping[str, complex]) -> dict[str, complex]:
        return dict(zip(AXES, loop.runout_response(float(rpm), per_axis(runout))))

    def plane_unbalance(rpm: float, position: Mapping[str, complex], current: Mapping[str, complex]) -> np.ndarray:
        return loop.plane_unbalance(float(rpm), per_axis(position), per_axis(current))

    def bearing_force(rpm: float, position: Mapping[str, complex],
                      current: Mapping[str, complex]) -> dict[str, complex]:
        return dict(zip(AXES, loop.bearing_force(float(rpm), per_axis(position), per_axis(current))))

    def inertia_force(rpm: float, position: Mapping[str, complex]) -> dict[str, complex]:
        return dict(zip(AXES, loop.inertia_force(float(rpm), per_axis(position))))

    extra = {"response": response, "runout_response": runout_response, "balance_planes": BALANCE_PLANES,
             "balance_radius_m": loop.params.balance_radius, "plane_unbalance": plane_unbalance, "axes": AXES,
             "currents": AXES, "bearing_force": bearing_force, "inertia_force": inertia_force}
    if gains is None:
        return LoopModel(at, "Ro et al.'s PID gains (Table 1): the recording does not state its controller's "
                             f"({', '.join(GAIN_KEYS)})", assumed=True, **extra)
    return LoopModel(at, "the PID gains the recording's controller ran (" + "; ".join(
        f"{k.removeprefix('controller.')} {', '.join(f'{v:g}' for v in g)}" for k, g in zip(GAIN_KEYS, gains)) + ")",
        assumed=False, **extra)


@functools.lru_cache(maxsize=1)
def rig_loop() -> StateSpaceLoop:
    """The spindle's five-axis loop at Ro et al.'s gains, as an LMS design plant (one per process:
    its matrices are cached per speed)."""
    return StateSpaceLoop(SpindleLoop().matrices)


LMS = DesignModels(
    plants={  # Ro et al.'s one-axis models (eq. 1-3) and the five-axis loop (docs/lms.md)
        "front": lambda: {"front": (FRONT_LOOP, AXES[0:2])},
        "rear": lambda: {"rear": (REAR_LOOP, AXES[2:4])},
        "bearings": lambda: {"front": (FRONT_LOOP, AXES[0:2]), "rear": (REAR_LOOP, AXES[2:4])},
        "rig": lambda: {"rig": (rig_loop(), AXES)},
    },
    pid=FRONT_LOOP, axes=AXES, phase_bins=PHASE_BINS, phase_bin_hz=PHASE_BIN_HZ)
"""The loops the spindle's LMS feedforward is designed on (``ambdaq lms --plant``)."""
