"""Kang & Jung's rig: a shaft on two radial AMBs on a moving base (the ``base-motion`` profile).

The shaft (mass m, transverse inertia I) is held by AMB-1 at b1 and AMB-2 at b2 from its centre
of mass, in a vertical (y, with gravity) and a horizontal (z) plane that do not couple (Kang & Jung
eq. 4). Per plane, in centre-of-mass coordinates q = [y, theta] relative to the base (eq. 6):

    M q'' - K q = Ka Bi u - M T d - [m g, 0],     M = diag(m, I),
    K  = [[Kd1 + Kd2, -b1 Kd1 + b2 Kd2], [-b1 Kd1 + b2 Kd2, b1^2 Kd1 + b2^2 Kd2]]   (eq. 5)
    Bi = [[Ki1, Ki2], [-b1 Ki1, b2 Ki2]]

with u the amplifier input voltages and d = [d1, d2] the base accelerations at the two bearings,
measured by two accelerometers on the base: the base's translation A = (b2 d1 + b1 d2)/(b1 + b2)
and rotation alpha = (d2 - d1)/(b1 + b2) (so T maps d to [A, alpha]). The base-rate torque T_z of
eq. 2 is left out (a gimbal's base rates are small). The gap sensors see y1 = y - b1 theta and
y2 = y + b2 theta (eq. 7). The current amplifiers follow u with a first-order lag.

The controller is Kang & Jung's state feedback with integral action (eq. 10-13), digital: an LQR
on the ZOH model augmented with the integral of [y, theta], its state from a predictor observer
on the two gap sensors. The feedforward u_ff = W d (eq. 15) is a 2 x 2 FIR per plane on the
accelerometer signals; a test signal can be added to one axis's u_ff (the secondary-path
measurement). Everything is linear, so the closed loop's frequency responses B (u_ff -> gap)
and C (d -> gap) and the perfect compensator W* = -B^-1 C (eq. 17) are exact: :meth:`responses`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ...drivers.signals import SampleBlock, SignalGroup
from ...drivers.coefbank import BankImage
from ..devices.firmware import EXCITATION, Feedforward, Firmware, Param
from ..profiles import Profile
from .base import Rig
from .excitation import ExcitationInput
from ...speed import SpeedProfile
from ...machines.base_motion import AXES, BASE_AXES, MAX_FIR_TAPS, PLANES, SAMPLE_RATE
from ...units import GRAVITY
from ...analysis.amb import zoh

MAX_TEST_SIGNAL_V = 1.0  # the secondary-path test signal; a tenth of the D/A range
MIN_TEST_SIGNAL_V = 1e-3  # a fifth of a 12-bit +-10 V D/A's step: less is not a test signal
N_STATE = 6  # y, theta, y', theta', i1, i2


@dataclass(frozen=True)
class BaseMotionParams:
    """The base-motion rig (Kang & Jung gives no numbers; these are a gimbal-axis-sized shaft).

    Attributes are SI: kg, kg m^2, m, N/m, N/A, A/V, Hz, m and m/s^2 RMS noise, V.
    """

    sample_rate: float = SAMPLE_RATE
    mass: float = 2.4
    inertia: float = 0.021
    b1: float = 0.075
    b2: float = 0.105
    kd: tuple[float, float] = (2.0e5, 1.9e5)
    ki: tuple[float, float] = (48.0, 45.0)
    amp_gain: float = 0.5
    amp_bandwidth_hz: float = 1500.0
    gap_noise: float = 0.05e-6
    accel_noise: float = 0.005
    dac_range: float = 10.0
    # LQR weights: position (m, rad), velocity, integral of position, control (V)
    lqr_position: float = 1e10
    lqr_velocity: float = 1e3
    lqr_integral: float = 1e12
    lqr_control: float = 1.0

    def plane_matrices(self) -> dict[str, np.ndarray]:
        """Continuous plant of one plane: A (6, 6), Bu, Bd (6, 2), Bg (6,) per m/s^2 of gravity,
        Cm (2, 6) gap sensors, Tq (2, 2) gap sensors -> [y, theta]."""
        m, inertia, b1, b2 = self.mass, self.inertia, self.b1, self.b2
        kd1, kd2 = self.kd
        ki1, ki2 = self.ki
        M = np.diag([m, inertia])
        K = np.array([[kd1 + kd2, -b1 * kd1 + b2 * kd2], [-b1 * kd1 + b2 * kd2, b1**2 * kd1 + b2**2 * kd2]])
        Bi = np.array([[ki1, ki2], [-b1 * ki1, b2 * ki2]])
        T = np.array([[b2, b1], [-1.0, 1.0]]) / (b1 + b2)
        wa = 2 * np.pi * self.amp_bandwidth_hz
        A = np.zeros((N_STATE, N_STATE))
        A[0:2, 2:4] = np.eye(2)
        A[2:4, 0:2] = np.linalg.solve(M, K)
        A[2:4, 4:6] = np.linalg.solve(M, Bi)
        A[4:6, 4:6] = -wa * np.eye(2)
        Bu = np.zeros((N_STATE, 2))
        Bu[4:6] = wa * self.amp_gain * np.eye(2)
        Bd = np.zeros((N_STATE, 2))
        Bd[2:4] = -T
        Bg = np.zeros(N_STATE)
        Bg[2] = -1.0
        Cm = np.zeros((2, N_STATE))
        Cm[:, 0:2] = [[1.0, -b1], [1.0, b2]]
        Tq = np.linalg.inv(Cm[:, 0:2])
        return {"A": A, "Bu": Bu, "Bd": Bd, "Bg": Bg, "Cm": Cm, "Tq": Tq}


BASE_MOTION = BaseMotionParams()


@dataclass(frozen=True)
class BaseExcitation:
    """Base motion applied by the (simulated) shaker, the same in both planes.

    Parameters
    ----------
    kind : {"sine", "noise"}
        Harmonic motion, or broadband noise band-limited to ``band_hz``.
    amplitude : float
        Peak of d2 (sine) or RMS of each of d1, d2 (noise), in m/s^2.
    freq_hz : float
        Sine frequency, in Hz.
    ratio : complex
        Sine: the disturbance ratio alpha = d1 / d2 (Kang & Jung eq. A-10).
    band_hz : tuple of float
        Noise: the band, in Hz (4th-order Butterworth band-pass).
    """

    kind: str
    amplitude: float
    freq_hz: float = 0.0
    ratio: complex = 1.0
    band_hz: tuple[float, float] = (5.0, 100.0)

    @classmethod
    def parse(cls, spec: str) -> "BaseExcitation":
        """``sine:HZ:AMP[:ALPHA_MAG[:ALPHA_DEG]]`` or ``noise:LO-HI:RMS`` (m/s^2); ValueError if not."""
        parts = spec.split(":")
        try:
            if parts[0] == "sine" and 3 <= len(parts) <= 5:
                mag = float(parts[3]) if len(parts) > 3 else 1.0
                deg = float(parts[4]) if len(parts) > 4 else 0.0
                exc = cls("sine", float(parts[2]), float(parts[1]), mag * np.exp(1j * np.radians(deg)))
            elif parts[0] == "noise" and len(parts) == 3:
                lo, hi = (float(v) for v in parts[1].split("-"))
                exc = cls("noise", float(parts[2]), band_hz=(lo, hi))
            else:
                raise ValueError
        except ValueError:
            raise ValueError(f"base motion {spec!r}: expected sine:HZ:AMP[:ALPHA_MAG[:ALPHA_DEG]] or "
                             "noise:LO-HI:RMS (m/s^2)") from None
        problem = exc.problem(BASE_MOTION.sample_rate)
        if problem:
            raise ValueError(f"base motion {spec!r}: {problem}")
        return exc

    def problem(self, sample_rate: float) -> str:
        """Why this motion cannot run, or ''."""
        if not 0 < self.amplitude <= 50.0:
            return f"amplitude must be > 0 and <= 50 m/s^2, not {self.amplitude:g}"
        if self.kind == "sine" and not 0 < self.freq_hz < sample_rate / 2:
            return f"frequency must be > 0 and below {sample_rate / 2:g} Hz"
        if self.kind == "noise" and not 0 < self.band_hz[0] < self.band_hz[1] < sample_rate / 2:
            return f"band must be 0 < LO < HI < {sample_rate / 2:g} Hz"
        return ""


@njit(cache=True, fastmath=True, nogil=True)
def _simulate(
    d_true, noise, exc,  # per-step inputs: base acceleration (n, 4), unit normals (gap 0:4, accel 4:8), test signal
    x, xh, eta, hist, pos,  # state: plant, observer, integrators, accelerometer history ring, ring position
    Phi, Gu, Gd, Gg, K, Keta, L, Cm, Tq, grav, W, ntaps, c,  # c = [h, gap_sd, acc_sd, dac_range]
    out_gap, out_cur, out_ff, out_u, out_acc, out_pos,
):
    h = c[0]
    gap_sd = c[1]
    acc_sd = c[2]
    dac = c[3]
    nring = hist.shape[1]
    ym = np.empty(2)
    u = np.empty(2)
    xn = np.empty(6)
    xhn = np.empty(6)
    for k in range(d_true.shape[0]):
        p0 = pos[0]
        for ch in range(4):  # the accelerometers, into the FIR's history
            hist[ch, p0] = d_true[k, ch] + acc_sd * noise[k, 4 + ch]
        for pl in range(2):
            o = 2 * pl
            for i in range(2):
                s = 0.0
                for j in range(6):
                    s += Cm[i, j] * x[pl, j]
                out_pos[k, o + i] = s
                ym[i] = s + gap_sd * noise[k, o + i]
            for j in range(2):  # eq. 15: u_ff = W d, a 2 x 2 FIR on this plane's accelerometers
                ff = exc[k, o + j]
                for m in range(2):
                    for t in range(ntaps):
                        ff += W[pl, j, m, t] * hist[o + m, (p0 - t) % nring]
                # eq. 10: u = -K q - k_i eta, with q from the observer
                v = ff
                for i in range(6):
                    v -= K[j, i] * xh[pl, i]
                v -= Keta[j, 0] * eta[pl, 0] + Keta[j, 1] * eta[pl, 1]
                if v > dac:
                    v = dac
                elif v < -dac:
                    v = -dac
                u[j] = v
                out_ff[k, o + j] = ff
                out_u[k, o + j] = v
                out_gap[k, o + j] = ym[j]
                out_cur[k, o + j] = x[pl, 4 + j]
                out_acc[k, o + j] = hist[o + j, p0]
            # observer (predictor form), integrators of [y, theta] (eq. 11), plant step
            inn0 = ym[0] - (Cm[0, 0] * xh[pl, 0] + Cm[0, 1] * xh[pl, 1])
            inn1 = ym[1] - (Cm[1, 0] * xh[pl, 0] + Cm[1, 1] * xh[pl, 1])
            for i in range(6):
                a = Gg[i] * grav[pl] + Gu[i, 0] * u[0] + Gu[i, 1] * u[1]
                b = a + Gd[i, 0] * d_true[k, o] + Gd[i, 1] * d_true[k, o + 1]
                a += L[i, 0] * inn0 + L[i, 1] * inn1
                for j in range(6):
                    a += Phi[i, j] * xh[pl, j]
                    b += Phi[i, j] * x[pl, j]
                xhn[i] = a
                xn[i] = b
            for i in range(6):
                xh[pl, i] = xhn[i]
                x[pl, i] = xn[i]
            eta[pl, 0] += h * (Tq[0, 0] * ym[0] + Tq[0, 1] * ym[1])
            eta[pl, 1] += h * (Tq[1, 0] * ym[0] + Tq[1, 1] * ym[1])
        pos[0] = (p0 + 1) % nring


class BaseMotionRig(Rig, ExcitationInput):
    """Kang & Jung's shaft on a moving base, closed loop, sample by sample (see the module docstring).

    Parameters
    ----------
    params : BaseMotionParams
        Rig parameters.
    seed : int
        Seed of the noise generators; the run is deterministic for a given seed.
    speed : SpeedProfile
        Kept for the recorder's identity; the shaft's rotation is not modelled (Kang & Jung assumes
        a small spin rate).
    truth : bool
        Also produce ``/truth/base`` (the true base accelerations) and ``/truth/position``.
    noise : bool
        Gap-sensor and accelerometer noise.
    """

    profile = "base-motion"
    inputs = frozenset({"excitation", "fir", "base"})
    excitation_axes = AXES  # test signal on the amplifier inputs, in V
    excitation_unit = "V"
    excitation_max = MAX_TEST_SIGNAL_V
    excitation_min = MIN_TEST_SIGNAL_V

    def __init__(self, params: BaseMotionParams = BASE_MOTION, *, seed: int = 0,
                 speed: SpeedProfile = SpeedProfile(0.0, 0.0), truth: bool = False, noise: bool = True) -> None:
        super().__init__(params, seed=seed, speed=speed, truth=truth, noise=noise)
        self._exc_rng = np.random.default_rng([seed, 1])
        self._base_rng = np.random.default_rng([seed, 2])
        self._base: BaseExcitation | None = None
        self._base_sos = None
        self._base_zi = None
        self._design()
        self._W = np.zeros((2, 2, 2, MAX_FIR_TAPS))
        self._ntaps = 1
        self._hist = np.zeros((4, MAX_FIR_TAPS))
        self._pos = np.zeros(1, dtype=np.int64)
        self._init_state()

    # --- design ---------------------------------------------------------------------------

    def _design(self) -> None:
        """ZOH model, LQR with integral action (eq. 10-13) and the observer's gain."""
        from scipy.linalg import solve_discrete_are  # here: every served or recorded rig imports this module (0.3 s)

        p = self.params
        m = p.plane_matrices()
        h = self.h
        Phi, G = zoh(m["A"], np.hstack([m["Bu"], m["Bd"], m["Bg"][:, None]]), h)
        self.Phi, self.Gu, self.Gd, self.Gg = Phi, G[:, 0:2], G[:, 2:4], G[:, 4]
        self.Cm, self.Tq = m["Cm"], m["Tq"]
        # augmented with eta[k+1] = eta[k] + h Tq y  (eq. 11-12)
        Pa = np.zeros((N_STATE + 2, N_STATE + 2))
        Pa[:N_STATE, :N_STATE] = Phi
        Pa[N_STATE:, :N_STATE] = h * self.Tq @ self.Cm
        Pa[N_STATE:, N_STATE:] = np.eye(2)
        Ga = np.vstack([self.Gu, np.zeros((2, 2))])
        Q = np.diag([p.lqr_position, p.lqr_position * p.b1 * p.b2, p.lqr_velocity, p.lqr_velocity * p.b1 * p.b2,
                     0.0, 0.0, p.lqr_integral, p.lqr_integral * p.b1 * p.b2])
        R = p.lqr_control * np.eye(2)
        S = solve_discrete_are(Pa, Ga, Q, R)
        Ka = np.linalg.solve(R + Ga.T @ S @ Ga, Ga.T @ S @ Pa)
        self.K, self.Keta = Ka[:, :N_STATE], Ka[:, N_STATE:]
        # predictor observer x^[k+1] = Phi x^ + Gu u + L (y - Cm x^): steady-state Kalman gain
        Qo = np.diag([1e-14, 1e-14, 1e-6, 1e-6, 1e-4, 1e-4])
        Ro = max(p.gap_noise, 1e-9) ** 2 * np.eye(2)
        So = solve_discrete_are(Phi.T, self.Cm.T, Qo, Ro)
        self.L = Phi @ So @ self.Cm.T @ np.linalg.inv(self.Cm @ So @ self.Cm.T + Ro)
        self._grav = np.array([GRAVITY, 0.0])

    def _init_state(self) -> None:
        """Start levitated at the static equilibrium: gravity carried by the integrators."""
        self._x = np.zeros((2, N_STATE))
        self._xh = np.zeros((2, N_STATE))
        self._eta = np.zeros((2, 2))
        # at rest with q = 0: the coil currents hold gravity, u = i / Ka, and -Keta eta supplies u
        Bi_force = np.linalg.solve(self.params.plane_matrices()["A"][2:4, 4:6], np.array([GRAVITY, 0.0]))
        i0 = Bi_force
        u0 = i0 / self.params.amp_gain
        for pl in range(2):
            g = self._grav[pl]
            self._x[pl, 4:6] = i0 * (g / GRAVITY)
            self._xh[pl] = self._x[pl]
            self._eta[pl] = np.linalg.solve(-self.Keta, u0 * (g / GRAVITY) + self.K @ self._x[pl])

    # --- commands -------------------------------------------------------------------------

    def set_feedforward_fir(self, taps: np.ndarray | None) -> None:
        """Load the feedforward u = W d: taps (2 planes, 2 outputs u_j, 2 inputs d_m, n <= 64),
        in V per m/s^2, tap t acting on d(k - t); None clears it."""
        if taps is None:
            self._W[:] = 0.0
            self._ntaps = 1
            return
        t = np.asarray(taps, dtype=float)
        if t.ndim != 4 or t.shape[:3] != (2, 2, 2) or not 1 <= t.shape[3] <= MAX_FIR_TAPS:
            raise ValueError(f"FIR taps must be (2, 2, 2, 1..{MAX_FIR_TAPS}), not {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("FIR taps must be finite")
        W = np.zeros_like(self._W)
        W[..., : t.shape[3]] = t
        self._W, self._ntaps = W, t.shape[3]

    @property
    def feedforward_fir(self) -> np.ndarray:
        """The loaded taps, shape (2, 2, 2, n)."""
        return self._W[..., : self._ntaps].copy()

    def set_base_motion(self, motion: BaseExcitation | None) -> None:
        """Shake the base from the next block on (both planes); None holds it still."""
        if motion is not None:
            problem = motion.problem(self.params.sample_rate)
            if problem:
                raise ValueError(problem)
            if motion.kind == "noise":
                from scipy.signal import butter, sosfreqz  # 1.1 s to import: only for noise

                self._base_sos = butter(4, motion.band_hz, btype="bandpass", fs=self.params.sample_rate,
                                        output="sos")
                self._base_zi = np.zeros((self._base_sos.shape[0], 2, 4))  # at rest
                # unit RMS after the filter: its noise bandwidth relative to the Nyquist band
                f = np.linspace(0, self.params.sample_rate / 2, 20001)
                _, resp = sosfreqz(self._base_sos, worN=f, fs=self.params.sample_rate)
                self._base_gain = 1.0 / np.sqrt(np.mean(np.abs(resp) ** 2))
        self._base = motion

    @property
    def base_motion(self) -> BaseExcitation | None:
        return self._base

    def _base_accel(self, steps: np.ndarray) -> np.ndarray:
        n = steps.shape[0]
        d = np.zeros((n, 4))
        motion = self._base
        if motion is None:
            return d
        if motion.kind == "sine":
            ph = 2 * np.pi * motion.freq_hz * steps * self.h
            d2 = motion.amplitude * np.sin(ph)
            d1 = motion.amplitude * abs(motion.ratio) * np.sin(ph + np.angle(motion.ratio))
            d[:] = np.stack([d1, d2, d1, d2], axis=1)
        else:
            from scipy.signal import sosfilt  # loaded by set_base_motion already

            white = self._base_rng.standard_normal((n, 4)) * motion.amplitude * self._base_gain
            d, self._base_zi = sosfilt(self._base_sos, white, axis=0, zi=self._base_zi)
        return np.ascontiguousarray(d)  # sosfilt may return F order; the kernel is compiled for C

    # --- stepping -------------------------------------------------------------------------

    def signal_groups(self) -> list[SignalGroup]:
        groups = [
            SignalGroup("/amb/gap", "Gap", AXES, ("m",) * 4),
            SignalGroup("/amb/current", "Current", AXES, ("A",) * 4),
            SignalGroup("/amb/ff", "Feedforward", AXES, ("V",) * 4),
            SignalGroup("/amb/control", "Control", AXES, ("V",) * 4),
            SignalGroup("/base/accel", "BaseAccel", BASE_AXES, ("m/s^2",) * 4),
        ]
        if self.truth:
            groups += [SignalGroup("/truth/base", "BaseAccel", BASE_AXES, ("m/s^2",) * 4),
                       SignalGroup("/truth/position", "Position", AXES, ("m",) * 4)]
        return groups

    def calibration(self) -> dict[str, str]:
        p = self.params
        return {"mass_kg": f"{p.mass:g}", "inertia_kg_m2": f"{p.inertia:g}", "b1_m": f"{p.b1:g}",
                "b2_m": f"{p.b2:g}", "units": "SI: m, A, V, m/s^2"}

    def run(self, n: int) -> SampleBlock:
        """Advance the closed loop by ``n`` control periods and return their samples."""
        steps = self._steps(n)
        d = self._base_accel(steps)
        noise = self._rng.standard_normal((n, 8), dtype=np.float32)
        if not self.noise:
            noise[:] = 0.0
        exc = self.excitation_block(steps)
        outs = [np.empty((n, 4)) for _ in range(6)]
        c = np.array([self.h, self.params.gap_noise, self.params.accel_noise, self.params.dac_range])
        c[1:3] *= 1.0 if self.noise else 0.0
        _simulate(d, noise, exc, self._x, self._xh, self._eta, self._hist, self._pos,
                  self.Phi, self.Gu, self.Gd, self.Gg, self.K, self.Keta, self.L, self.Cm, self.Tq, self._grav,
                  self._W, self._ntaps, c, *outs)
        self.step_index += n
        arrays = outs[:5] + ([d, outs[5]] if self.truth else [])
        return self._block(steps, arrays)

    # --- exact linear analysis --------------------------------------------------------------

    def closed_loop(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One plane's closed loop without noise: z[k+1] = Acl z + Bff u_ff + Bd d, y = Ccl z, with
        z = [x (6), observer (6), eta (2)], exactly as the kernel steps it (below the D/A limit)."""
        n = N_STATE
        Acl = np.zeros((2 * n + 2, 2 * n + 2))
        # u = -K xh - Keta eta + u_ff
        Ku = np.hstack([np.zeros((2, n)), -self.K, -self.Keta])
        Acl[:n, :n] = self.Phi
        Acl[:n] += self.Gu @ Ku
        Acl[n:2 * n, :n] = self.L @ self.Cm
        Acl[n:2 * n, n:2 * n] = self.Phi - self.L @ self.Cm
        Acl[n:2 * n] += self.Gu @ Ku
        Acl[2 * n:, :n] = self.h * self.Tq @ self.Cm
        Acl[2 * n:, 2 * n:] = np.eye(2)
        Bff = np.vstack([self.Gu, self.Gu, np.zeros((2, 2))])
        Bd = np.vstack([self.Gd, np.zeros((n + 2, 2))])
        Ccl = np.hstack([self.Cm, np.zeros((2, n + 2))])
        return Acl, Bff, Bd, Ccl

    def responses(self, f_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact frequency responses of one plane at ``f_hz`` (Hz): B (n, 2, 2) gap per u_ff (m/V),
        C (n, 2, 2) gap per base acceleration (m per m/s^2), and W* = -B^-1 C (n, 2, 2) in V per
        m/s^2, the compensator that cancels the base-motion response (Kang & Jung eq. 17; the
        paper's sign convention folds the minus into C)."""
        Acl, Bff, Bd, Ccl = self.closed_loop()
        f_hz = np.atleast_1d(np.asarray(f_hz, dtype=float))
        B = np.empty((f_hz.shape[0], 2, 2), dtype=complex)
        C = np.empty_like(B)
        eye = np.eye(Acl.shape[0])
        for i, f in enumerate(f_hz):
            z = np.exp(2j * np.pi * f * self.h)
            X = np.linalg.solve(z * eye - Acl, np.hstack([Bff, Bd]))
            G = Ccl @ X
            B[i], C[i] = G[:, :2], G[:, 2:]
        return B, C, -np.linalg.solve(B, C)


# --- what its simulated controller runs (sim://base-motion, ambdaq sim serve) -----------------------


class FirFeedforward(Feedforward):
    """Kang & Jung's feedforward u = W d as the coefficient banks hold it: FIR taps per plane, output
    and input (docs/base-motion.md); no runout harmonics."""

    def layout(self, rig) -> dict:
        return {"axes": list(AXES), "harmonics": 0,
                "fir": {"planes": list(PLANES), "outputs": 2, "inputs": 2, "max_taps": MAX_FIR_TAPS,
                        "sample_rate_hz": rig.params.sample_rate}}

    def present(self, rig) -> BankImage:
        taps = rig.feedforward_fir
        return BankImage(np.zeros((len(AXES), 0, 2)), "off", [], "", None, 10.0, taps if np.any(taps) else None,
                         rig.params.sample_rate)

    def apply(self, rig, image: BankImage) -> None:
        rig.set_feedforward_fir(image.fir_taps)  # None: no feedforward


FIRMWARE = Firmware(
    "AMB controller (simulated, Kang & Jung shaft on a moving base)",
    ("/amb/gap", "/amb/current", "/amb/ff", "/amb/control", "/base/accel"),
    {
        # the FIR is read here and changed only through the coefficient banks (BANK_*)
        "ff.fir": Param(0, lambda r: r.feedforward_fir.ravel(),
                        doc="present feedforward taps [plane][output][input][tap], V per m/s^2"),
        "exc.signal": EXCITATION,
    },
    FirFeedforward(),
)

PROFILE = Profile("base-motion", BaseMotionRig, FIRMWARE, ("controller", "shaker"))
