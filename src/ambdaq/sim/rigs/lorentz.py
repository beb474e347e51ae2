"""Jeon et al.'s rig: a disk-type Lorentz-force integrated motor-bearing (the ``lorentz`` profile).

Six coreless coils, 60 deg apart, sit between two 8-pole magnet disks (4 pole pairs).  Coil i's
flux linkage is lambda_i = Lambda cos(4 theta_r - 4 theta_i) (eq. 1, 6) with theta_i = i pi/3,
so its back-EMF is eq. 8, k_e B' omega cos(4 theta_r - 4 theta_i + pi/2), 4 Lambda = k_e B',
k_e = 2 k r l and B' = B sin(2 pi / 5).  (The paper prints theta_i = i pi/6; six coils evenly
spaced are pi/3 apart, and only that spacing makes the printed estimator (eq. 12) converge as
eq. 17 says; see docs/selfsense.md.)  The magnets are not perfect: each pole's strength varies
by a few per cent, which puts once- and twice-per-revolution ripple on every coil's flux.

Each coil carries a torque current (eq. 2) and a radial current (eq. 4) from a current-controlled
amplifier (a first-order lag).  The drive is open loop, as in the paper: the torque currents
follow a commanded electrical angle theta_d from the speed profile, and the rotor, a disk on a
viscous drag, is pulled along by T = K_t I_M sin(theta_d + phi - 4 theta_r) (eq. 3).  The radial
currents come from a PD on two gap sensors, pushing the rotor through F = 3 I_C B k l (eq. 5)
against a small unbalance.  The coil voltages are eq. 7 with each coil's true R and L, which
differ from the datasheet values the estimator uses (``mismatch``), averaged over each sample
period (an integrating measurement) and measured with noise.  An encoder gives the true angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ...drivers.signals import SampleBlock, SignalGroup
from ..profiles import Profile
from .base import Rig
from ...speed import SpeedProfile

N_COILS = 6
POLE_PAIRS = 4
SUBSTEPS = 10
COILS = tuple(f"c{i}" for i in range(N_COILS))
COIL_ANGLES = np.arange(N_COILS) * np.pi / 3  # theta_i, mechanical
ENCODER_COUNTS = 1 << 14
MACHINE_SEED = 3003  # the built machine's R, L and magnet variation: the same in every run


@dataclass(frozen=True)
class LorentzParams:
    """The integrated motor-bearing (SI).  Jeon et al. gives no numbers: these are a 60 mm disk
    motor.  ``resistance`` and ``inductance`` are the datasheet values (the estimator's); each
    coil's true values differ by up to ``r_mismatch`` and ``l_mismatch`` (fractions)."""

    sample_rate: float = 10_000.0
    flux: float = 0.45  # B, T
    turns: int = 100  # k
    radius: float = 0.02  # r, m
    side: float = 0.015  # l, m
    resistance: float = 1.5  # ohm
    inductance: float = 0.8e-3  # H
    r_mismatch: float = 0.02
    l_mismatch: float = 0.05
    pole_variation: float = 0.03  # RMS of the poles' relative strength
    torque_current: float = 0.6  # I_M, A
    torque_phase: float = np.pi / 2  # phi of eq. 2
    amp_tau: float = 50e-6  # current amplifier lag, s
    inertia: float = 1.0e-4  # kg m^2
    drag: float = 5.0e-5  # N m s
    rotor_mass: float = 0.3  # kg
    unbalance: float = 5e-6  # m (mass eccentricity)
    radial_kp: float = 2.0e4  # N/m
    radial_kd: float = 40.0  # N s/m
    magnet_stiffness: float = 2.0e3  # N/m, the disks' pull towards the stator (negative stiffness)
    voltage_noise: float = 5e-3  # V RMS
    current_noise: float = 2e-3  # A RMS
    gap_noise: float = 0.2e-6  # m RMS

    @property
    def k_e(self) -> float:
        """k_e = 2 k r l (eq. 11), m^2."""
        return 2 * self.turns * self.radius * self.side

    @property
    def emf_constant(self) -> float:
        """k_e B sin(2 pi / 5): back-EMF amplitude per rad/s (eq. 8), V s."""
        return self.k_e * self.flux * np.sin(2 * np.pi / 5)

    @property
    def torque_constant(self) -> float:
        """K_t = 6 B k r l sin(2 pi / 5) (eq. 3), N m/A."""
        return 6 * self.flux * self.turns * self.radius * self.side * np.sin(2 * np.pi / 5)

    @property
    def force_constant(self) -> float:
        """3 B k l (eq. 5), N/A."""
        return 3 * self.flux * self.turns * self.side


LORENTZ = LorentzParams()


def machine(params: LorentzParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The built machine: each coil's true R (ohm) and L (H), and the magnet ripple as
    (harmonic 1, 2) x (cos, sin) relative amplitudes, fixed by MACHINE_SEED."""
    rng = np.random.default_rng(MACHINE_SEED)
    r = params.resistance * (1 + params.r_mismatch * rng.uniform(-1, 1, N_COILS))
    ind = params.inductance * (1 + params.l_mismatch * rng.uniform(-1, 1, N_COILS))
    poles = 1 + params.pole_variation * rng.standard_normal(2 * POLE_PAIRS)
    # the poles' strengths as a function of angle: its 1st and 2nd harmonics ripple the flux
    ang = np.arange(2 * POLE_PAIRS) * 2 * np.pi / (2 * POLE_PAIRS)
    ripple = np.array([[2 * np.mean(poles * np.cos(h * ang)), 2 * np.mean(poles * np.sin(h * ang))] for h in (1, 2)])
    return r, ind, ripple


@njit(cache=True, fastmath=True, nogil=True)
def _flux(lam, ripple, a):
    """Coil flux linkage at electrical-position-relative angle a = theta_r - theta_i (mech), and
    its derivative d lambda / d theta_r: Lambda cos(4 a) (1 + ripple(a)) (eq. 1, 6)."""
    rho = ripple[0, 0] * np.cos(a) + ripple[0, 1] * np.sin(a) + ripple[1, 0] * np.cos(2 * a) + ripple[1, 1] * np.sin(2 * a)
    drho = -ripple[0, 0] * np.sin(a) + ripple[0, 1] * np.cos(a) - 2 * ripple[1, 0] * np.sin(2 * a) + 2 * ripple[1, 1] * np.cos(2 * a)
    return lam * np.cos(4 * a) * (1 + rho), lam * (-4 * np.sin(4 * a) * (1 + rho) + np.cos(4 * a) * drho)


@njit(cache=True, fastmath=True, nogil=True)
def _simulate(st, cmd, noise, c, res, ind, ripple, out_v, out_i, out_gap, out_true):
    """Advance st = [theta, omega, x, y, vx, vy, i_0 .. i_5, v_0 .. v_5] over len(cmd) samples;
    cmd (n, SUBSTEPS) is the commanded electrical angle theta_d at each substep; noise (n, 14).
    Sample k reports the currents at its instant and the voltages averaged over the period that
    ends there (an integrating converter), kept in st[12:18] between blocks."""
    h = c[0]
    hs = h / SUBSTEPS
    lam, im, phi, tau = c[1], c[2], c[3], c[4]
    J, drag, m, e_unb, kp, kd, kneg, kf = c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12]
    vn, inoise, gn = c[13], c[14], c[15]
    ea = np.exp(-hs / tau)
    i_start = np.empty(6)
    lam_start = np.empty(6)
    i_mean = np.empty(6)
    for k in range(cmd.shape[0]):
        for j in range(6):
            i_start[j] = st[6 + j]
            lam_start[j], _ = _flux(lam, ripple, st[0] - j * np.pi / 3)
            i_mean[j] = 0.0
        out_true[k, 0] = st[0]
        out_true[k, 1] = st[1]
        for j in range(6):
            out_v[k, j] = st[12 + j] + vn * noise[k, j]
            out_i[k, j] = st[6 + j] + inoise * noise[k, 6 + j]
        out_gap[k, 0] = st[2] + gn * noise[k, 12]
        out_gap[k, 1] = st[3] + gn * noise[k, 13]
        # radial PD on the sampled gaps: the force wanted, as a radial-current amplitude and phase
        fx = -kp * out_gap[k, 0] - kd * st[4]
        fy = -kp * out_gap[k, 1] - kd * st[5]
        ic = np.sqrt(fx * fx + fy * fy) / kf
        pc = np.arctan2(fy, fx)
        for sub in range(SUBSTEPS):
            thd = cmd[k, sub]
            torque = -drag * st[1]
            for j in range(6):
                # eq. 2 (torque) + eq. 4 (radial, referenced to where the rotor should be)
                iref = im * np.cos(thd + phi + 2 * np.pi * j / 3) + ic * np.cos(thd + phi + pc + np.pi * j / 3)
                i_old = st[6 + j]
                st[6 + j] = iref + (i_old - iref) * ea
                i_mean[j] += 0.5 * (i_old + st[6 + j]) / SUBSTEPS
                _, dl = _flux(lam, ripple, st[0] - j * np.pi / 3)
                torque += st[6 + j] * dl  # T = sum i dlambda/dtheta: eq. 3 when the magnets are ideal
            # eq. 5: the radial force, turned by the rotor's lag behind the pattern
            delta = thd + phi - 4 * st[0]
            st[1] += hs * torque / J
            st[0] += hs * st[1]
            ax = (kf * ic * np.cos(pc + delta) + kneg * st[2] + m * e_unb * st[1] * st[1] * np.cos(st[0])) / m
            ay = (kf * ic * np.sin(pc + delta) + kneg * st[3] + m * e_unb * st[1] * st[1] * np.sin(st[0])) / m
            st[4] += hs * ax
            st[5] += hs * ay
            st[2] += hs * st[4]
            st[3] += hs * st[5]
        for j in range(6):
            lam_end, _ = _flux(lam, ripple, st[0] - j * np.pi / 3)
            # eq. 7 averaged over the sample period: R mean(i) + L (i_k+1 - i_k) / h + (lambda_k+1 - lambda_k) / h
            st[12 + j] = res[j] * i_mean[j] + ind[j] * (st[6 + j] - i_start[j]) / h + (lam_end - lam_start[j]) / h


class LorentzRig(Rig):
    """Jeon et al.'s integrated motor-bearing, open-loop drive (see the module docstring).

    Parameters
    ----------
    params : LorentzParams
        Rig parameters.
    seed : int
        Noise seed; the machine itself (coil mismatch, magnets) is fixed by MACHINE_SEED.
    speed : SpeedProfile
        Commanded speed; at a constant speed the rotor starts in step with it.
    truth : bool
        Also produce ``/truth/rotor`` (unquantised angle and speed).
    noise : bool
        Measurement noise on voltages, currents and gaps.
    """

    profile = "lorentz"

    def __init__(self, params: LorentzParams = LORENTZ, *, seed: int = 0, speed: SpeedProfile = SpeedProfile(0.0, 0.0),
                 truth: bool = False, noise: bool = True) -> None:
        super().__init__(params, seed=seed, speed=speed, truth=truth, noise=noise)
        self.res, self.ind, self.ripple = machine(params)
        self.state = np.zeros(18)
        _, w0 = speed.angle_speed(np.zeros(1))
        p = params
        lag = np.arcsin(min(1.0, p.drag * float(w0[0]) / (p.torque_constant * p.torque_current)))
        self.state[0] = (p.torque_phase - lag) / POLE_PAIRS  # in step with the command
        self.state[1] = float(w0[0])
        thd0 = 0.0
        for j in range(N_COILS):
            self.state[6 + j] = p.torque_current * np.cos(thd0 + p.torque_phase + 2 * np.pi * j / 3)
            self.state[12 + j] = self.res[j] * self.state[6 + j]  # the voltage of the period before the first

    def signal_groups(self) -> list[SignalGroup]:
        groups = [
            SignalGroup("/coil/voltage", "Voltage", COILS, ("V",) * N_COILS),
            SignalGroup("/coil/current", "Current", COILS, ("A",) * N_COILS),
            SignalGroup("/amb/gap", "Gap", ("x", "y"), ("m", "m")),
            SignalGroup("/motor/encoder", "Angle", ("angle",), ("rad",)),
        ]
        if self.truth:
            groups.append(SignalGroup("/truth/rotor", "Rotor", ("angle", "speed"), ("rad", "rad/s")))
        return groups

    def calibration(self) -> dict[str, str]:
        """The datasheet values a self-sensing estimator works with (not the coils' true ones)."""
        p = self.params
        return {"resistance_ohm": f"{p.resistance:g}", "inductance_h": f"{p.inductance:g}",
                "emf_constant_v_s": f"{p.emf_constant:.6g}", "pole_pairs": str(POLE_PAIRS),
                "coil_spacing_deg": "60", "encoder_counts": str(ENCODER_COUNTS), "units": "SI: V, A, m, rad"}

    def run(self, n: int) -> SampleBlock:
        """Advance by ``n`` samples and return them."""
        p = self.params
        steps = self._steps(n)
        t = (steps[:, None] + np.arange(SUBSTEPS)[None, :] / SUBSTEPS) * self.h
        ref, _ = self.speed.angle_speed(t.ravel())
        cmd = (POLE_PAIRS * ref).reshape(t.shape)
        noise = self._rng.standard_normal((n, 14))
        if not self.noise:
            noise[:] = 0.0
        c = np.array([self.h, p.emf_constant / POLE_PAIRS, p.torque_current, p.torque_phase, p.amp_tau, p.inertia,
                      p.drag, p.rotor_mass, p.unbalance, p.radial_kp, p.radial_kd, p.magnet_stiffness,
                      p.force_constant, p.voltage_noise, p.current_noise, p.gap_noise])
        v, i, gap, true = np.empty((n, N_COILS)), np.empty((n, N_COILS)), np.empty((n, 2)), np.empty((n, 2))
        _simulate(self.state, cmd, noise, c, self.res, self.ind, self.ripple, v, i, gap, true)
        self.step_index += n
        counts = 2 * np.pi / ENCODER_COUNTS
        arrays = [v, i, gap, np.floor(true[:, :1] / counts) * counts] + ([true] if self.truth else [])
        return self._block(steps, arrays)


PROFILE = Profile("lorentz", LorentzRig)  # served on no transport: ambdaq sim generate only
