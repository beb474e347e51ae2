"""The simulated grinding spindle of Ro et al.: a rigid rotor on five AMB axes under digital PID.

Physics (all SI):

* Rigid rotor, mass 4.38 kg, Jp 0.0014 kg m^2, Jt 0.0362 kg m^2 (Ro et al., section 2.2), radial
  bearings at ``a`` and ``b`` from the centre of mass; the gyroscopic moment Jp*Omega couples the
  two tilt planes.  The state is kept in bearing coordinates (front_x, front_y, rear_x, rear_y,
  axial), so the gap sensors, which we take as co-located with the bearings, read states directly.
  Ro et al. gives no bearing positions; we take a = b = 0.11 m, where the tilt mode's effective
  mass per bearing Jt/(2a^2) is 1.50 kg, the one-axis model's m of Ro et al. eq. 1.  (With a wider
  span, e.g. 0.15 m, the tilt mode's mass drops to 0.8 kg and the mode lands near 480 Hz with
  zeta 0.08, where the amplifier and D/A lags have eaten the derivative's phase lead.)
* Linearised magnet force F = Kx x + Ki i (Table 1: front Ki 273 N/A, Kx 1.77e6 N/m; rear 182,
  1.18e6).  The coil pair is driven differentially about the bias I0 with each coil current
  limited to 0..8 A; the force uses the differential law ((I0+i)^2 - (I0-i)^2)/(4 I0), which is
  exactly i while both coils conduct and saturates as the amplifier does.
* Amplifier G_A(s) = wn^2 Kamp / (s^2 + 2 zeta wn s + wn^2) (Ro et al. eq. 2), Kamp 0.8 A/V,
  zeta 1.7, wn 1800 Hz front / 2500 Hz rear.
* Controller at h = 100 us: 16-bit A/D on the sensor voltage (Ks = 10,000 V/m, +-10 V),
  PID with P 1.6, I 1, D 0.0015 s front / 0.002 s rear (Ro et al. eq. 3).  The printed eq. 3 is
  garbled, so we use the standard parallel PID with a Tustin integrator (the readable term
  I h(z+1)/(2(z-1)) of eq. 3) and a backward-Euler filtered derivative D s/(1 + s Tf) with
  Tf = (D/P)/Nd, Nd = 15.  Output on a 12-bit D/A (+-10 V), held for one period (ZOH).
* Sensor signal s = x + r(theta) + noise, with electrical runout r(theta) = sum R_k sin(k theta +
  phi_k) fixed to the rotor angle (eq. 5); the y sensor sits 90 deg from the x sensor on the same
  target track, so r_y(theta) = r_x(theta - pi/2).
* Command error e = (s - r_c) - x_ref with feedforward r_c = sum w_k0 sin k theta + w_k1 cos k theta
  (eq. 10); the LMS mode adapts w_k <- w_k + mu e [sin k theta, cos k theta] (eq. 9).
* Mass unbalance per bearing plane, force U Omega^2 at angle theta + phase; gravity on y.
* Housing accelerometers read the bearing reaction force on an effective housing mass (the housing
  on soft mounts, above their resonance): a = -(F_mag - F_static)/M_h.
* Touchdown bearings (assumed; Ro et al. has none): round at each radial bearing and an axial
  stop, at the clearance Cmin; a contact force along the normal with damping, no friction.  A
  drop (:class:`~.drop.Drop`) switches the amplifiers off: no output, and the bias decays with
  the coils' L/R; as the bias b goes, the force constant goes with b and the negative stiffness
  with b^2 (the linear plant holds Kx at the full bias, so the difference (1 - b^2) Kx x is
  taken back).  The controller runs on; when the amplifiers return it lifts the rotor.

The axial bearing is not described in Ro et al.; its values here are assumptions, marked below.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numba import njit

from ...drivers.signals import SampleBlock, SignalGroup
from ...drivers.coefbank import BankImage
from ..devices.firmware import EXCITATION, SPEED, Feedforward, Firmware, Param
from ..profiles import Profile
from .base import CommandedSpeed, Rig, balancing_truth
from .drop import Drop
from .excitation import ExcitationInput
from ...machines.balance_masses import BalanceMass, plane_unbalance
from ...machines.spindle import (AXES, BALANCE_PLANES, MU_BIN_RPM, MU_BINS, N_AXES, N_HARMONICS, PAPER_MU_SCHEDULE,
                                  PHASE_BIN_HZ, PHASE_BINS, SPINDLE, SpindleParams)
from ...machines.spindle_loop import (GAIN_KEYS, GAIN_LEAST, SpindleLoop, amplifier_matrices, derivative_filter,
                                       rotor_matrices, rotor_through_amplifiers, zoh)
from ...speed import SpeedProfile
from ...units import RAD_S_TO_RPM, RPM_TO_RAD_S

SPEED_BUCKET_RAD_S = 50.0 * RPM_TO_RAD_S  # gyroscopic matrices re-discretised every 50 rpm
FF_OFF, FF_TABLE, FF_LMS = 0, 1, 2
FF_MODES = {"off": FF_OFF, "table": FF_TABLE, "lms": FF_LMS}
FF_NAMES = {v: k for k, v in FF_MODES.items()}


Schedule = dict[int, tuple[tuple[float, float, float], ...]]


def per_harmonic(schedule) -> Schedule:
    """The LMS step-size schedule as the rig holds it, harmonic (1-based) -> rows (rpm_from, rpm_to,
    mu), from rows for every harmonic or from such a mapping (harmonics it does not name are held)."""
    if schedule is None:
        return {}
    if isinstance(schedule, dict):
        return {int(k): tuple(tuple(float(x) for x in r) for r in rs) for k, rs in schedule.items()}
    rows = tuple(tuple(float(x) for x in r) for r in schedule)
    return {k: rows for k in range(1, N_HARMONICS + 1)}


def schedule_rows(schedule: Schedule) -> list[tuple[float, float, float, float]]:
    """The schedule as bank rows (harmonic, rpm_from, rpm_to, mu); harmonic 0 where every harmonic
    has the same rows (docs/coefficients.md)."""
    if len({schedule.get(k, ()) for k in range(1, N_HARMONICS + 1)}) == 1 and len(schedule) == N_HARMONICS:
        return [(0.0, *r) for r in schedule[1]]
    return [(float(k), *r) for k, rs in schedule.items() for r in rs]


def mu_table(schedule: Schedule) -> np.ndarray:
    """LMS step size per harmonic and 100-rpm speed bin (what the kernel looks up)."""
    table = np.zeros((N_HARMONICS, MU_BINS))
    centres = (np.arange(MU_BINS) + 0.5) * MU_BIN_RPM
    for k, rows in schedule.items():
        for lo, hi, mu in rows:
            table[k - 1, (centres >= lo) & (centres < hi)] = mu
    return table


@njit(cache=True, inline="always")
def _converter(v, full_scale, lsb, inv_lsb):
    """A/D or D/A: clip to +-full_scale (V) and round to the converter's step ``lsb`` (0: ideal)."""
    if v > full_scale:
        v = full_scale
    elif v < -full_scale:
        v = -full_scale
    if lsb > 0.0:
        v = np.floor(v * inv_lsb + 0.5) * lsb
    return v


CONTACT_SUBSTEPS = 20  # 5 us steps while on a touchdown bearing: its contact mode (5.8 krad/s) 0.03 rad a step


@njit(cache=True, inline="always")
def _near_touchdown(z, within):
    """Whether a radial bearing's orbit radius or the axial gap is beyond ``within`` (m)."""
    return (z[0] * z[0] + z[1] * z[1] > within * within or z[2] * z[2] + z[3] * z[3] > within * within
            or abs(z[4]) > within)


@njit(cache=True, inline="always")
def _contact(z, clr, kcon, ccon, fc):
    """The touchdown bearings' forces on the rotor in bearing coordinates (N) into ``fc``: round at
    each radial bearing, an axial stop; stiffness ``kcon`` along the normal past the clearance
    ``clr``, damping ``ccon``, pushing only."""
    for a in range(5):
        fc[a] = 0.0
    for a, b in ((0, 1), (2, 3)):
        r = np.sqrt(z[a] * z[a] + z[b] * z[b])
        if r > clr:
            na = z[a] / r
            nb = z[b] / r
            normal = kcon * (r - clr) + ccon * (z[5 + a] * na + z[5 + b] * nb)
            if normal > 0.0:
                fc[a] = -normal * na
                fc[b] = -normal * nb
    if abs(z[4]) > clr:
        sgn = 1.0 if z[4] > 0 else -1.0
        normal = kcon * (abs(z[4]) - clr) + ccon * z[9] * sgn
        if normal > 0.0:
            fc[4] = -normal * sgn


@njit(cache=True, fastmath=True, nogil=True)
def _simulate(
    theta, omega, enabled, noise, noise_sd,  # per-step inputs; enabled: 1 amplifiers on, 0 off (a drop);
    # noise: unit normals, gap 0:5, current 5:10, accel 10:15
    z, amp, ctl, w, st,  # state (modified in place); st: [revolution count, bias level 0..1]
    Phi, Gam, Psq, Psu, Ac, Bc, Pa, Ga,  # the plant discretised (through the amplifiers: Psq, Psu) and
    # continuous (in contact), the amplifiers
    ki, kx, bias, pid_p, pid_i, ad, bd, mh, fstat, fgrav, unb, unb_ph, run_s, run_c,
    mu_tab, ph_cos, ph_sin, ff_mode, exc, c,  # exc: excitation added to r_c per step and axis; c: constants
    out_gap, out_cur, out_err, out_ff, out_acc, out_rot, out_run, out_pos,
):
    # c = [h, Ks, adc_lsb, adc_range, dac_lsb, dac_range, imax, phase_bin_hz, clearance, contact k, contact c,
    #      exp(-h / coil time constant)]
    h = c[0]
    ks = c[1]
    adc_lsb = c[2]
    adc_rng = c[3]
    dac_lsb = c[4]
    dac_rng = c[5]
    imax = c[6]
    phase_bin = c[7]
    clr = c[8]
    kcon = c[9]
    ccon = c[10]
    e_coil = c[11]
    fc = np.empty(5)
    inv_ks = 1.0 / ks
    inv_adc = 1.0 / adc_lsb if adc_lsb > 0.0 else 0.0
    inv_dac = 1.0 / dac_lsb if dac_lsb > 0.0 else 0.0
    inv_4b = 1.0 / (4.0 * bias)
    inv_mh = 1.0 / mh
    nh = run_s.shape[1]
    sk = np.empty(nh)
    ck = np.empty(nh)
    F = np.empty(5)
    Fo = np.empty(5)  # the forces the currents' step (Psq, Psu) does not hold: unbalance, gravity, the coils' law
    q0 = np.empty(10)  # the amplifiers' states at the step's start, axis-major [i, di/dt]
    uu = np.empty(5)  # the controller's outputs held over the step, V
    znew = np.empty(10)
    two_pi = 2.0 * np.pi
    for k in range(theta.shape[0]):
        th = theta[k]
        om = omega[k]
        s1 = np.sin(th)
        c1 = np.cos(th)
        sk[0] = s1
        ck[0] = c1
        for j in range(1, nh):  # sin/cos of k*theta by the angle-addition recurrence
            sk[j] = sk[j - 1] * c1 + ck[j - 1] * s1
            ck[j] = ck[j - 1] * c1 - sk[j - 1] * s1
        rev = np.floor(th / two_pi)
        out_rot[k, 0] = th - rev * two_pi
        out_rot[k, 1] = om
        out_rot[k, 2] = 1.0 if rev > st[0] else 0.0
        st[0] = rev
        mbin = int(om * RAD_S_TO_RPM / MU_BIN_RPM)
        if mbin >= mu_tab.shape[1]:
            mbin = mu_tab.shape[1] - 1
        th_mid = th + 0.5 * h * om
        on = enabled[k] >= 0.5
        level = st[1]  # the bias, as a share of its own, over this step
        st[1] = (1.0 if on else 0.0) + (level - (1.0 if on else 0.0)) * e_coil
        lost_kx = 1.0 - level * level  # the negative stiffness goes with the bias squared
        for a in range(5):
            pos = z[a]
            r = 0.0
            for j in range(nh):
                r += run_s[a, j] * sk[j] + run_c[a, j] * ck[j]
            # sensor voltage through the 16-bit A/D
            s_meas = _converter(ks * (pos + r + noise_sd[0] * noise[k, a]), adc_rng, adc_lsb, inv_adc) * inv_ks
            # feedforward r_c with the weights of the previous step (eq. 10)
            rc = 0.0
            if ff_mode > 0:
                for j in range(nh):
                    rc += w[a, j, 0] * sk[j] + w[a, j, 1] * ck[j]
            rc += exc[k, a]  # the excitation input enters where r_c does (sim/rigs/excitation.py)
            e = s_meas - rc
            if ff_mode == 2:  # LMS update, eq. 9, its step turned by the phase compensation g
                for j in range(nh):
                    mu = mu_tab[j, mbin]
                    if mu != 0.0:
                        fb = int((j + 1) * om / two_pi / phase_bin + 0.5)
                        if fb >= ph_cos.shape[1]:
                            fb = ph_cos.shape[1] - 1
                        gr = ph_cos[a, fb]
                        gi = ph_sin[a, fb]
                        # phasor W = w0 + j w1 moves by mu e (sin + j cos) g
                        w[a, j, 0] += mu * e * (sk[j] * gr - ck[j] * gi)
                        w[a, j, 1] += mu * e * (ck[j] * gr + sk[j] * gi)
            # PID on the error voltage: Tustin integral, backward-Euler filtered derivative
            ev = ks * e
            integ = ctl[a, 0] + pid_i[a] * h * 0.5 * (ev + ctl[a, 2])
            if integ > dac_rng:
                integ = dac_rng
            elif integ < -dac_rng:
                integ = -dac_rng
            deriv = ad[a] * ctl[a, 1] + bd[a] * (ev - ctl[a, 2])
            ctl[a, 0] = integ
            ctl[a, 1] = deriv
            ctl[a, 2] = ev
            u = _converter(-(pid_p[a] * ev + integ + deriv), dac_rng, dac_lsb, inv_dac)
            if not on:
                u = 0.0  # the amplifier off: the controller's output goes nowhere
            # amplifier step and the differential coil-current law with 0..imax per coil
            i0 = amp[a, 0]
            q0[2 * a] = i0
            q0[2 * a + 1] = amp[a, 1]
            uu[a] = u
            i1 = Pa[a, 0, 0] * i0 + Pa[a, 0, 1] * amp[a, 1] + Ga[a, 0] * u
            amp[a, 1] = Pa[a, 1, 0] * i0 + Pa[a, 1, 1] * amp[a, 1] + Ga[a, 1] * u
            amp[a, 0] = i1
            b0 = bias[a] * level
            hi0 = min(max(b0 + i0, 0.0), imax)
            lo0 = min(max(b0 - i0, 0.0), imax)
            hi1 = min(max(b0 + i1, 0.0), imax)
            lo1 = min(max(b0 - i1, 0.0), imax)
            ieff0 = (hi0 * hi0 - lo0 * lo0) * inv_4b[a]
            ieff1 = (hi1 * hi1 - lo1 * lo1) * inv_4b[a]
            fmag = (1.0 - lost_kx) * kx[a] * pos + ki[a] * ieff0
            # unbalance: x axes cos, y axes sin of (theta + phase), evaluated mid-step
            fu = unb[a] * om * om * np.cos(th_mid + unb_ph[a])
            F[a] = ki[a] * 0.5 * (ieff0 + ieff1) + fu + fgrav[a]
            # through Psq and Psu the rotor sees the linear coil current as it moves within the
            # step; what the coils' law (clipping, a bias decaying) takes from it is held over it
            Fo[a] = ki[a] * 0.5 * ((ieff0 - i0) + (ieff1 - i1)) + fu + fgrav[a]
            out_gap[k, a] = s_meas
            out_cur[k, a] = i0 + noise_sd[1] * noise[k, 5 + a]
            out_err[k, a] = e
            out_ff[k, a] = rc
            out_acc[k, a] = -(fmag - fstat[a]) * inv_mh[a] + noise_sd[2] * noise[k, 10 + a]
            out_run[k, a] = r
            out_pos[k, a] = pos
        if lost_kx > 1e-3 or _near_touchdown(z, 0.8 * clr):
            # on (or about to reach) a touchdown bearing, or the bias not all there: the contact is
            # stiff and switches, and the plant's Kx is not the bias's, so the rotor is integrated
            # through the step in CONTACT_SUBSTEPS semi-implicit Euler steps of its continuous model
            # (Ac, Bc), the contact force and the negative stiffness lost with the bias at each
            hs = h / CONTACT_SUBSTEPS
            for _ in range(CONTACT_SUBSTEPS):
                _contact(z, clr, kcon, ccon, fc)
                for i in range(5, 10):
                    acc = 0.0
                    for j in range(10):
                        acc += Ac[i, j] * z[j]
                    for j in range(5):
                        acc += Bc[i, j] * (F[j] + fc[j] - lost_kx * kx[j] * z[j])
                    znew[i] = z[i] + hs * acc
                for i in range(5):
                    z[5 + i] = znew[5 + i]
                    z[i] += hs * z[5 + i]
        else:
            for i in range(10):
                acc = 0.0
                for j in range(10):
                    acc += Phi[i, j] * z[j]
                for j in range(5):
                    acc += Gam[i, j] * Fo[j] + Psu[i, j] * uu[j]
                for j in range(10):
                    acc += Psq[i, j] * q0[j]
                znew[i] = acc
            for i in range(10):
                z[i] = znew[i]


def _groups(truth: bool) -> list[SignalGroup]:
    m5 = ("m",) * 5
    groups = [
        SignalGroup("/amb/gap", "Gap", AXES, m5),
        SignalGroup("/amb/current", "Current", AXES, ("A",) * 5),
        SignalGroup("/amb/error", "Error", AXES, m5),
        SignalGroup("/amb/ff", "Feedforward", AXES, m5),
        SignalGroup("/amb/accel", "Accel", AXES, ("m/s^2",) * 5),
        SignalGroup("/amb/rotor", "Rotor", ("angle", "speed", "keyphasor"), ("rad", "rad/s", "1")),
    ]
    if truth:
        groups += [
            SignalGroup("/truth/runout", "Runout", AXES, m5),
            SignalGroup("/truth/position", "Position", AXES, m5),
        ]
    return groups


SETTLE_S = 0.1
"""Seconds the loop runs before a rig's first sample (:meth:`SpindleRig.settle`): three times its
start-up transient from rest (30 ms)."""


class SpindleRig(CommandedSpeed, Rig, ExcitationInput):
    """Closed-loop simulation of the Ro et al. spindle, stepped in blocks of control periods.

    Parameters
    ----------
    params : SpindleParams
        Rig parameters (defaults: Ro et al.).
    seed : int
        Seed of the noise generator; the run is deterministic for a given seed.
    speed : SpeedProfile
        Rotor speed profile.
    truth : bool
        Also produce the ``/truth/runout`` and ``/truth/position`` groups.
    ff_mode : {"off", "table", "lms"}
        Feedforward of the simulated controller.
    mu_schedule : rows of (rpm_from, rpm_to, mu), optional
        LMS step-size schedule; default: Ro et al.'s sign-switched schedule.
    noise : bool
        Add sensor, current and accelerometer noise and quantise on the A/D and D/A.
    settle_s : float
        Seconds the loop runs before the first sample (:meth:`settle`), s; 0 starts at rest.
    """

    profile = "spindle"
    inputs = frozenset({"excitation", "feedforward", "drop", "balancing"})
    balance_planes = BALANCE_PLANES
    excitation_axes = AXES  # test signal added to r_c, in m (asked for in um)
    excitation_unit = "m"
    excitation_min = 0.01e-6  # a third of the 16-bit A/D's step (0.03 um): less is not a test signal
    excitation_max = 20e-6  # a tenth of the air gap's safe range; more saturates the loop

    def __init__(
        self,
        params: SpindleParams = SPINDLE,
        *,
        seed: int = 0,
        speed: SpeedProfile = SpeedProfile(0.0, 0.0),
        truth: bool = False,
        ff_mode: str = "off",
        mu_schedule=PAPER_MU_SCHEDULE,
        noise: bool = True,
        settle_s: float = SETTLE_S,
    ) -> None:
        super().__init__(params, seed=seed, speed=speed, truth=truth, noise=noise)
        self.mu_schedule = per_harmonic(mu_schedule)
        self._mu = mu_table(self.mu_schedule)
        self._ph_cos = np.ones((N_AXES, PHASE_BINS))
        self._ph_sin = np.zeros((N_AXES, PHASE_BINS))
        self._ff_mode = FF_MODES["off"]
        self.set_feedforward(ff_mode)
        self._exc_rng = np.random.default_rng([seed, 1])  # its own stream: the rig's noise stays as it was
        self._rotor_cache: dict[int, tuple[np.ndarray, ...]] = {}
        self._linear: SpindleLoop | None = None  # the loop at the present gains (loop_matrices)
        self.drop: Drop | None = None
        self.masses: list[BalanceMass] = []  # put on its planes (add_masses)
        self._init_constants()
        self._init_state()
        self.settle(settle_s)

    # --- configuration -------------------------------------------------------------------

    def settle(self, seconds: float) -> None:
        """Run the closed loop for ``seconds`` at the start speed, unrecorded, and start the clock
        at 0 from there: the rotor is levitated and its loop in its steady state when the first
        sample is taken, as on a machine running before a recording starts (from rest, its first
        30 ms are a start-up transient that every seed shares; a runout identified over it stated
        an uncertainty 1.2-3x its scatter).  The angle runs on continuously."""
        n = int(round(seconds / self.h))
        if n <= 0:
            return
        speed = self.speed
        self.speed = SpeedProfile(speed.rpm_start, speed.rpm_start)
        self.run(n)
        theta, _ = self.speed.angle_speed(np.array([n * self.h - self._speed_t0]), self._theta0)
        self.step_index, self._speed_t0, self._theta0 = 0, 0.0, float(theta[0] % (2 * np.pi))
        self.speed = speed

    def _init_constants(self) -> None:
        p = self.params
        axes = p.axes
        h = self.h
        self._ki = np.array([ax.ki for ax in axes])
        self._kx = np.array([ax.kx for ax in axes])
        self._bias = np.array([ax.bias for ax in axes])
        self._pid_p = np.array([ax.pid_p for ax in axes])
        self._pid_i = np.array([ax.pid_i for ax in axes])
        kd = np.array([ax.pid_d for ax in axes])
        self._ad, self._bd = derivative_filter(self._pid_p, kd, p.derivative_filter, h)
        self._mh = np.array([ax.housing_mass for ax in axes])
        self._fgrav = p.bearing_gravity()
        self._fstat = -self._fgrav
        self._Pa = np.empty((5, 2, 2))
        self._Ga = np.empty((5, 2))
        for i, ax in enumerate(axes):
            self._Pa[i], self._Ga[i] = amplifier_matrices(ax, h)
        self._set_unbalance_arrays()
        self._run_s, self._run_c = p.runout_sin_cos()
        adc_lsb = 2 * p.adc_range / 2**p.adc_bits if self.noise else 0.0
        dac_lsb = 2 * p.dac_range / 2**p.dac_bits if self.noise else 0.0
        self._c = np.array([h, p.sensor_gain, adc_lsb, p.adc_range, dac_lsb, p.dac_range, p.coil_max_current,
                            PHASE_BIN_HZ, p.min_clearance, p.contact_stiffness, p.contact_damping,
                            np.exp(-h / p.coil_time_constant)])
        self._noise_sd = np.array([p.gap_noise, p.current_noise, p.accel_noise]) * (1.0 if self.noise else 0.0)

    def _set_unbalance_arrays(self) -> None:
        """The kernel's unbalance per axis from the params' per plane: x axes cos, y axes sin."""
        p = self.params
        self._unb = np.array([p.unbalance[0], p.unbalance[0], p.unbalance[1], p.unbalance[1], 0.0])
        ph = np.array(p.unbalance_phase)
        self._unb_ph = np.array([ph[0], ph[0] - np.pi / 2, ph[1], ph[1] - np.pi / 2, 0.0])

    def plane_unbalance(self) -> dict[str, complex]:
        """The rotor's unbalance per balancing plane now, kg m as a phasor (its angle from the
        key-phasor's mark in the direction of rotation)."""
        p = self.params
        return {plane: u * np.exp(1j * ph) for plane, u, ph in zip(self.balance_planes, p.unbalance, p.unbalance_phase)}

    def add_masses(self, masses: list[BalanceMass]) -> None:
        """Put ``masses`` (trial or correction) on the balancing planes before a recording: the
        unbalance changes, and the loop settles again (SETTLE_S, the clock back at 0)."""
        u = plane_unbalance(self.plane_unbalance(), masses)
        self.params = replace(self.params, unbalance=tuple(float(abs(u[k])) for k in self.balance_planes),
                              unbalance_phase=tuple(float(np.angle(u[k])) for k in self.balance_planes))
        self.masses = [*self.masses, *masses]
        self._set_unbalance_arrays()
        self._linear = None  # its unbalance response is the new unbalance's
        self.settle(SETTLE_S)

    def _init_state(self) -> None:
        """Start at the static equilibrium: rotor centred, gravity carried by the integrators."""
        self._z = np.zeros(10)
        self._amp = np.zeros((5, 2))
        self._ctl = np.zeros((5, 3))  # integral, derivative, previous error voltage
        i_static = self._fstat / self._ki
        self._amp[:, 0] = i_static
        amp_gain = np.array([ax.amp_gain for ax in self.params.axes])
        self._ctl[:, 0] = -i_static / amp_gain  # u = -integral at zero error
        self._w = np.zeros((5, N_HARMONICS, 2))
        theta0, _ = self.speed.angle_speed(np.zeros(1))
        self._st = np.array([np.floor(theta0[0] / (2 * np.pi)), 1.0])  # revolutions, bias level

    def set_feedforward(self, mode: str, table: np.ndarray | None = None) -> None:
        """Switch the controller's feedforward.

        Parameters
        ----------
        mode : {"off", "table", "lms"}
            ``table`` applies fixed weights, ``lms`` adapts them from the present ones (eq. 9).
        table : ndarray, shape (5, n_harmonics, 2), optional
            Weights [sin, cos] per axis and harmonic (1X first), in m; loaded before switching.
        """
        if mode not in FF_MODES:
            raise ValueError(f"feedforward mode must be one of {sorted(FF_MODES)}, not {mode!r}")
        if table is not None:
            t = np.asarray(table, dtype=float)
            if t.ndim != 3 or t.shape[0] != N_AXES or t.shape[2] != 2 or t.shape[1] > N_HARMONICS:
                raise ValueError(f"feedforward table must be (5, <= {N_HARMONICS}, 2), not {t.shape}")
            self._w[:] = 0.0
            self._w[:, : t.shape[1], :] = t
        self._ff_mode = FF_MODES[mode]

    def set_drop(self, drop: Drop | None) -> None:
        """Drop the rotor as ``drop`` says (None: the amplifiers always on); its times are the
        rig's, from the start of the run."""
        self.drop = drop

    def set_pid(self, p: np.ndarray, i: np.ndarray, d: np.ndarray) -> None:
        """Replace the PID gains of the five axes (V/V, 1/s, s); the derivative filter follows."""
        p, i, d = (np.asarray(v, dtype=float).reshape(5) for v in (p, i, d))
        self._pid_p, self._pid_i = p.copy(), i.copy()
        self._ad, self._bd = derivative_filter(p, d, self.params.derivative_filter, self.h)

    def set_mu_schedule(self, schedule) -> None:
        """Replace the LMS step-size schedule: rows of (rpm_from, rpm_to, mu) for every harmonic, or a
    mapping harmonic -> rows (harmonics not named are held)."""
        self.mu_schedule = per_harmonic(schedule)
        self._mu = mu_table(self.mu_schedule)

    def set_lms_phase(self, phase_rad: np.ndarray | None) -> None:
        """Turn each axis's LMS step by a phase over loop frequency (the phase-compensated update:
        w_k moves by mu e [sin, cos](k theta) rotated by g = exp(j phase(k Omega))).

        Parameters
        ----------
        phase_rad : ndarray, shape (5, PHASE_BINS), or None
            Phase per axis at 0, 10, 20 ... 5,000 Hz, in rad; None: no compensation (Ro et al.'s
            plain update).
        """
        ph = np.zeros((N_AXES, PHASE_BINS)) if phase_rad is None else np.asarray(phase_rad, dtype=float)
        if ph.shape != (N_AXES, PHASE_BINS) or not np.all(np.isfinite(ph)):
            raise ValueError(f"LMS phase table must be finite, shape ({N_AXES}, {PHASE_BINS}), not {ph.shape}")
        # C order whatever the caller's layout, so the kernel is compiled for one array type
        self._ph_cos, self._ph_sin = np.ascontiguousarray(np.cos(ph)), np.ascontiguousarray(np.sin(ph))

    @property
    def lms_phase(self) -> np.ndarray:
        """The LMS phase compensation per axis and 10 Hz bin, in rad (zeros: none)."""
        return np.arctan2(self._ph_sin, self._ph_cos)

    @property
    def pid_gains(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present (P, I, D) per axis, in V/V, 1/s, s."""
        d = self._bd * (self._ad * self.h / (1 - self._ad) + self.h)
        return self._pid_p.copy(), self._pid_i.copy(), d

    @property
    def feedforward_mode(self) -> str:
        return {v: k for k, v in FF_MODES.items()}[self._ff_mode]

    @property
    def feedforward_weights(self) -> np.ndarray:
        """Present feedforward weights, shape (5, 8, 2): [sin, cos] per axis and harmonic, in m."""
        return self._w.copy()

    def signal_groups(self) -> list[SignalGroup]:
        """The signal groups this rig produces, in the order of the block's values."""
        return _groups(self.truth)

    def calibration(self) -> dict[str, str]:
        """What a recording stores as the rig's calibration: sensor, converters, rotor model."""
        p = self.params
        return {
            "gap_sensor_gain_v_per_m": f"{p.sensor_gain:g}",
            "adc_bits": str(p.adc_bits),
            "dac_bits": str(p.dac_bits),
            "units": "SI: m, A, m/s^2, rad, rad/s",
            "machine.min_clearance_m": repr(p.min_clearance),
            # the control current at which one coil of a pair stops conducting: the force saturates
            "machine.current_limit_a": repr(min(ax.bias for ax in p.axes)),
            **p.rotor_metadata(),
            # the gains the loop runs at now (a retune through `controller param` included): what
            # `runup --model spindle` predicts the critical speeds at
            **{GAIN_KEYS[k]: ",".join(repr(float(v)) for v in g) for k, g in enumerate(self.pid_gains)},
            **balancing_truth(self.masses, self.plane_unbalance() if self.truth else None),
        }

    # --- stepping --------------------------------------------------------------------------

    def _rotor(self, omega: float) -> tuple[np.ndarray, ...]:
        """The rotor's ZOH matrices (Phi, Gamma), its step through the amplifiers (Psi_q, Psi_u:
        :func:`rotor_through_amplifiers`) and its continuous matrices at the speed bucket of
        ``omega`` (rad/s), cached per rig."""
        key = round(omega / SPEED_BUCKET_RAD_S)
        if key not in self._rotor_cache:
            A, B = rotor_matrices(self.params, key * SPEED_BUCKET_RAD_S)
            self._rotor_cache[key] = (*zoh(A, B, self.h), *rotor_through_amplifiers(A, B, self.params, self.h), A, B)
        return self._rotor_cache[key]

    def run(self, n: int) -> SampleBlock:
        """Advance the closed loop by ``n`` control periods and return their samples."""
        steps = self._steps(n)
        t = steps * self.h
        theta, omega = self._angle_speed(steps)
        # unit normals in float32 (half the cost of float64), scaled to SI inside the kernel; one
        # row of 15 per step, so the stream does not depend on how the run is cut into blocks
        noise = self._rng.standard_normal((n, 15), dtype=np.float32)
        if not self.noise:
            noise[:] = 0.0
        exc = self.excitation_block(steps)
        enabled = self.drop.enabled(t) if self.drop is not None else np.ones(n)
        outs = [np.empty((n, 5)) for _ in range(4)] + [np.empty((n, 5)), np.empty((n, 3))]
        out_run = np.empty((n, 5))
        out_pos = np.empty((n, 5))
        # split the block where the speed crosses into another gyroscopic bucket
        bucket = np.round(omega / SPEED_BUCKET_RAD_S)
        edges = np.concatenate(([0], np.flatnonzero(np.diff(bucket)) + 1, [n]))
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi <= lo:
                continue
            Phi, Gam, Psq, Psu, Ac, Bc = self._rotor(float(omega[lo]))
            sl = slice(lo, hi)
            _simulate(
                theta[sl], omega[sl], enabled[sl], noise[sl], self._noise_sd,
                self._z, self._amp, self._ctl, self._w, self._st,
                Phi, Gam, Psq, Psu, Ac, Bc, self._Pa, self._Ga,
                self._ki, self._kx, self._bias, self._pid_p, self._pid_i, self._ad, self._bd,
                self._mh, self._fstat, self._fgrav, self._unb, self._unb_ph, self._run_s, self._run_c,
                self._mu, self._ph_cos, self._ph_sin, self._ff_mode, exc[sl], self._c,
                outs[0][sl], outs[1][sl], outs[2][sl], outs[3][sl], outs[4][sl], outs[5][sl],
                out_run[sl], out_pos[sl],
            )
        self.step_index += n
        return self._block(steps, outs + ([out_run, out_pos] if self.truth else []))

    # --- linear analysis of the simulated loop --------------------------------------------------

    def loop_matrices(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The loop this rig runs, linear, at ``rpm`` (rpm) and its present PID gains: the machine's
        model (:class:`~ambdaq.machines.spindle_loop.SpindleLoop`), which the kernel steps exactly
        with noise, runout, unbalance, gravity and quantisation off (:meth:`probe_loop`, at the
        speeds of its rotor matrices: multiples of 50 rpm).

        Returns
        -------
        M : ndarray, shape (35, 35)
        B : ndarray, shape (35, 5)
        C : ndarray, shape (5, 35)
        """
        return self._loop().matrices(rpm)

    def unbalance_response(self, rpm: float) -> np.ndarray:
        """The rotor's steady 1X at ``rpm`` (rpm) from this rig's unbalance and runout
        (:meth:`~ambdaq.machines.spindle_loop.SpindleLoop.unbalance_response`), m per axis."""
        return self._loop().unbalance_response(rpm)

    def _loop(self) -> SpindleLoop:
        gains = tuple(tuple(float(v) for v in g) for g in self.pid_gains)
        if self._linear is None or self._linear.gains != gains:
            self._linear = SpindleLoop(self.params, gains)
        return self._linear

    def probe_loop(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`loop_matrices` at ``rpm`` by stepping the kernel from every unit perturbation
        (35 + 5 one-step runs): the reference the fast path is built on and tested against."""
        quiet = replace(
            self.params, unbalance=(0.0, 0.0), runout_amp=np.zeros_like(self.params.runout_amp)
        )
        probe = SpindleRig(quiet, speed=SpeedProfile(rpm, rpm), noise=False, settle_s=0.0)  # its angle 0 at step 0
        probe.set_pid(*self.pid_gains)  # the loop as it runs now (ISO 14839-3 predictions after a retune)
        probe._fgrav = np.zeros(5)
        probe._fstat = np.zeros(5)
        n_state = 10 + 10 + 15
        scale = 1e-9  # small enough that nothing saturates

        def step(x: np.ndarray, rc_axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
            probe._z[:] = x[:10]
            probe._amp[:] = x[10:20].reshape(5, 2)
            probe._ctl[:] = x[20:35].reshape(5, 3)
            probe.step_index = 0
            table = np.zeros((N_AXES, 1, 2))
            if rc_axis >= 0:  # at step 0 the angle is 0: r_c = the cos weight of 1X
                table[rc_axis, 0, 1] = scale
            probe.set_feedforward("table" if rc_axis >= 0 else "off", table)
            block = probe.run(1)
            nxt = np.concatenate([probe._z, probe._amp.ravel(), probe._ctl.ravel()])
            return nxt, block.values["/amb/error"][0]

        M = np.empty((n_state, n_state))
        C = np.empty((N_AXES, n_state))
        for col in range(n_state):
            x = np.zeros(n_state)
            x[col] = scale
            nxt, err = step(x)
            M[:, col], C[:, col] = nxt / scale, err / scale
        B = np.empty((n_state, N_AXES))
        for a in range(N_AXES):
            nxt, err = step(np.zeros(n_state), a)
            B[:, a] = nxt / scale
        return M, B, C


# --- what its simulated controller runs (sim://spindle, ambdaq sim serve) ---------------------------


class RunoutFeedforward(Feedforward):
    """Ro et al.'s runout feedforward as the coefficient banks hold it: weights per axis and
    harmonic (a fixed table, or where the LMS starts), the step-size schedule over speed and the
    phase compensation (docs/push.md)."""

    def layout(self, rig) -> dict:
        return {"axes": list(AXES), "harmonics": N_HARMONICS}

    def present(self, rig) -> BankImage:
        rows = schedule_rows(rig.mu_schedule)
        phase = rig.lms_phase
        return BankImage(rig.feedforward_weights, rig.feedforward_mode, rows, "", phase if np.any(phase) else None,
                         PHASE_BIN_HZ)

    def apply(self, rig, image: BankImage) -> None:
        """Schedule and phase first, then weights and mode: one boundary."""
        rig.set_mu_schedule(image.per_harmonic_schedule())
        phase = None
        if image.phase_rad is not None:  # the image's table resampled onto the controller's own bins (nearest)
            f = np.arange(PHASE_BINS) * PHASE_BIN_HZ
            phase = image.phase_rad[:, np.minimum(np.round(f / image.phase_bin_hz).astype(int),
                                                  image.phase_rad.shape[1] - 1)]
        rig.set_lms_phase(phase)
        rig.set_feedforward(image.mode, image.weights)


"""The least P (V/V), I (1/s) and D (s) the controller takes."""


def _set_pid(which: int):
    def write(rig, values):
        gains = list(rig.pid_gains)
        gains[which] = values
        rig.set_pid(*gains)

    return write


def _read_schedule(rig) -> np.ndarray:
    """``lms.schedule``: the rows (harmonic, rpm_from, rpm_to, mu) of every harmonic, flattened."""
    return np.array([(k, *row) for k, rows in rig.mu_schedule.items() for row in rows], dtype=float).ravel()


FIRMWARE = Firmware(
    "AMB controller (simulated, Ro et al. spindle)",
    ("/amb/gap", "/amb/current", "/amb/error", "/amb/ff", "/amb/rotor"),  # /amb/accel: a CANopen device
    {
        # P and D above zero: the derivative filter's time constant is D / P / Nd
        "pid.p": Param(N_AXES, lambda r: r.pid_gains[0], _set_pid(0), GAIN_LEAST[0], 100.0,
                       "proportional gain per axis, V/V"),
        "pid.i": Param(N_AXES, lambda r: r.pid_gains[1], _set_pid(1), GAIN_LEAST[1], 1e4,
                       "integral gain per axis, 1/s"),
        "pid.d": Param(N_AXES, lambda r: r.pid_gains[2], _set_pid(2), GAIN_LEAST[2], 1.0,
                       "derivative gain per axis, s"),
        # the feedforward's weights change only through the coefficient banks (BANK_*); its mode may
        # be switched here (ambdaq controller ff): off, held at the present weights, or adapting
        # from them, the bank untouched
        "ff.mode": Param(1, lambda r: np.array([FF_MODES[r.feedforward_mode]]),
                         lambda r, v: r.set_feedforward(FF_NAMES[int(v[0])]), 0.0, 2.0,
                         "feedforward: 0 off, 1 table (held at the present weights), 2 LMS",
                         lambda r, v: "" if float(v[0]).is_integer() else "0 off, 1 table, 2 LMS"),
        "ff.table": Param(N_AXES * N_HARMONICS * 2, lambda r: r.feedforward_weights.ravel(),
                          doc="present feedforward weights [axis][harmonic][sin, cos] (LMS: as adapted), m"),
        "lms.schedule": Param(0, _read_schedule, doc="LMS step-size rows (harmonic, rpm_from, rpm_to, mu)"),
        "speed.rpm": SPEED,
        "exc.signal": EXCITATION,
    },
    RunoutFeedforward(),
)

PROFILE = Profile("spindle", SpindleRig, FIRMWARE, ("controller", "can"))
