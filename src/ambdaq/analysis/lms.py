"""Stability of Ro et al.'s LMS runout feedforward inside the AMB loop (Fig. 5).

The feedforward r_c is subtracted from the sensor signal, so the command error is
e = S (r - r_c) with S = 1 / (1 + C P) the sensitivity of the sampled loop.  For one harmonic the
LMS of eq. 9-10 is the linear filter r_c = G_ff e with

    G_ff(z) = mu (c z - 1) / (z^2 - 2 c z + 1),   c = cos(k Omega h)

(summing eq. 9 over time: r_c(t) = mu sum_{n>=1} cos(k Omega h n) e(t - n); eq. 15 as printed is
garbled, eq. 16 follows from this one).  With the loop, the characteristic polynomial is

    den_S den_ff + num_S num_ff = 0,

and the LMS converges where every root lies inside the unit circle.  Whether mu must be positive
or negative depends on the phase of S at k Omega: that is the sign flip of Ro et al. section 3.3.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Mapping
from typing import Callable

import numpy as np

from ..units import RPM_TO_RAD_S
from .amb import pid_z
from .frf import interpolate_response


@dataclass(frozen=True)
class OneAxis:
    """Ro et al.'s one-axis loop: G_R = Ki Ks / (m s^2 - Kx) (eq. 1), amplifier G_A (eq. 2),
    digital PID at h (eq. 3, parallel form, Tustin integral, filtered derivative).

    Parameters (SI): m kg, ki N/A, kx N/m, ks V/m, amplifier gain A/V, wn Hz, zeta, PID gains
    V/V, 1/s, s, derivative filter Nd, sample period s.  A machine's own loops are built where
    the machine is described (the spindle's: :data:`ambdaq.machines.spindle.FRONT_LOOP`).
    """

    m: float
    ki: float
    kx: float
    ks: float
    amp_gain: float
    amp_wn_hz: float
    amp_zeta: float
    p: float
    i: float
    d: float
    nd: float
    h: float

    def plant_z(self) -> tuple[np.ndarray, np.ndarray]:
        """ZOH-discretised amplifier + rotor + sensor, V in -> V out: (num, den) in powers of z."""
        wn = 2 * np.pi * self.amp_wn_hz
        num = np.array([self.amp_gain * wn**2 * self.ki * self.ks])
        den = np.polymul([1, 2 * self.amp_zeta * wn, wn**2], [self.m, 0, -self.kx])
        from scipy.signal import cont2discrete  # here: scipy.signal takes 0.65 s to import, and
        # every served rig (which imports this module) would pay it at start-up for nothing

        nz, dz, _ = cont2discrete((num, den), self.h, method="zoh")
        return np.trim_zeros(np.atleast_1d(np.squeeze(nz)), "f"), dz

    def controller_z(self) -> tuple[np.ndarray, np.ndarray]:
        """The digital PID as (num, den) in powers of z (the simulated controller's law)."""
        return pid_z(p=self.p, i=self.i, d=self.d, nd=self.nd, h=self.h)

    def sensitivity_z(self) -> tuple[np.ndarray, np.ndarray]:
        """S = 1 / (1 + C P) as (num, den) in powers of z."""
        pn, pd = self.plant_z()
        cn, cd = self.controller_z()
        den = np.polyadd(np.polymul(pd, cd), np.polymul(pn, cn))
        return np.polymul(pd, cd), den


@dataclass(frozen=True)
class PlantLoop(OneAxis):
    """Any plant G(s) (V in -> sensor V out) as a transfer function, in the loop of a digital PID
    (gains and h as :class:`OneAxis`; its magnet, amplifier and sensor are not used).

    Parameters
    ----------
    num, den : tuple of float
        Coefficients of G(s) in descending powers of s.
    """

    num: tuple[float, ...] = (1.0,)
    den: tuple[float, ...] = (1.0,)

    def plant_z(self) -> tuple[np.ndarray, np.ndarray]:
        from scipy.signal import cont2discrete  # imported when used (OneAxis.plant_z)

        nz, dz, _ = cont2discrete((np.array(self.num, float), np.array(self.den, float)), self.h, method="zoh")
        return np.trim_zeros(np.atleast_1d(np.squeeze(nz)), "f"), dz


@dataclass(frozen=True)
class StateSpaceLoop:
    """A multi-axis loop in state space, x[n+1] = M x + B r_c, e = C x - r_c, linearised per speed
    (e.g. the simulated rig's own kernel: ``SpindleRig.loop_matrices``).

    Parameters
    ----------
    matrices : callable
        rpm -> (M, B, C).
    h : float
        Sample period, in s.
    axes : tuple of int
        Axes whose feedforward adapts (default: all).
    """

    matrices: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]]
    h: float = 1e-4
    axes: tuple[int, ...] | None = None
    _cache: dict = field(default_factory=dict, compare=False, hash=False)

    def at(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        key = round(float(rpm), 3)
        if key not in self._cache:
            self._cache[key] = self.matrices(float(rpm))
        return self._cache[key]


HOLD_TOL = 1e-9
"""A spectral radius within this of 1 means the weights *hold*: they neither converge nor
diverge.  With the weights frozen (mu = 0) the LMS poles lie on the unit circle by construction;
in the rotation form used here their radius comes out within 1e-14 of 1 at every speed, while
the slowest convergence that counts (mu = 1e-4 on Ro et al.'s bearings, 10 rpm from a sign flip)
is 2e-8 inside the circle, 20 times this tolerance.  At 10 kHz a radius 1e-9 from 1 changes the
error by 1/e in 10^9 samples, 28 hours: nothing a run can show."""


def _radius_text(r: float) -> str:
    """A spectral radius printed so that its side of 1 shows: ``1 + 3.0e-08``, not ``1.0000``."""
    return f"1 {'+' if r > 1 else '-'} {abs(r - 1):.1e}" if abs(r - 1) < 1e-3 else f"{r:.4f}"


def converges(radius: np.ndarray) -> np.ndarray:
    """+1 where the LMS converges (radius < 1 - HOLD_TOL), 0 where the weights hold (within
    HOLD_TOL of 1), -1 where it diverges."""
    r = np.asarray(radius)
    return np.where(r < 1.0 - HOLD_TOL, 1, np.where(r > 1.0 + HOLD_TOL, -1, 0))


def _lms_filters(phi: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """G_ff / mu for a harmonic at phi = k Omega h rad per sample with the update turned by g, as a
    state space (R, b, c) per point and axis: r_c[n] = mu sum_{d>=1} e[n-d] Re(g exp(j d phi)), so

        G_ff = mu ((g_r cos phi - g_i sin phi) z - g_r) / (z^2 - 2 cos phi z + 1).

    R is the rotation by phi, whose eigenvalues exp(+-j phi) have modulus 1 to the last bit; the
    companion form of the same denominator is nearly defective at low speed and puts its roots
    up to 6e-5 off the circle.  With b = [1, 0], c = [g_r cos phi - g_i sin phi,
    -(g_r sin phi + g_i cos phi)], c (zI - R)^-1 b is that numerator over that denominator.

    ``phi`` (K,) rad per sample, ``g`` (K, p) complex; returns R (K, 2, 2) and c (K, p, 2)."""
    c, s = np.cos(phi), np.sin(phi)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    out = np.stack([g.real * c[:, None] - g.imag * s[:, None], -(g.real * s[:, None] + g.imag * c[:, None])], -1)
    return R, out


RADIUS_BATCH = 256  # loops whose eigenvalues are taken in one call (a few MB of matrices)


def _radius(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, mu: np.ndarray, phi: np.ndarray,
            g: np.ndarray) -> np.ndarray:
    """Spectral radius of the loops e = T u (state space A, B, C, D, each (K, ...) or one for all;
    u = -r_c, one input per adapting axis) closed through the LMS filter of each axis at ``phi``
    (K,) (``g`` (K, p): its update's turn), for each step size in ``mu``: shape (K, len(mu)).  The
    feedforward uses the weights of the previous step, so G_ff is strictly proper and the loop
    has no algebraic part."""
    K, p = len(phi), g.shape[1]
    A, B, C = (np.broadcast_to(m, (K, *m.shape[-2:])) for m in (A, B, C))
    n, q = A.shape[1], 2 * p
    R, c = _lms_filters(phi, g)
    Bf = np.kron(np.eye(p), np.array([[1.0], [0.0]]))  # each filter's input: its axis's error
    Cf1 = np.zeros((K, p, q))  # G_ff's output for mu = 1
    for i in range(p):
        Cf1[:, i, 2 * i:2 * i + 2] = c[:, i]
    # the closed loop is affine in mu: fixed + mu per_mu, every point's and step size's eigenvalues at once
    fixed = np.zeros((K, n + q, n + q))
    fixed[:, :n, :n] = A
    fixed[:, n:, :n] = Bf @ C
    for i in range(p):
        fixed[:, n + 2 * i:n + 2 * i + 2, n + 2 * i:n + 2 * i + 2] = R
    per_mu = np.zeros((K, n + q, n + q))
    per_mu[:, :n, n:] = -B @ Cf1
    per_mu[:, n:, n:] = -(Bf @ D) @ Cf1
    mu = np.asarray(mu, dtype=float)
    out = np.empty((K, len(mu)))
    for lo in range(0, K, RADIUS_BATCH):
        closed = fixed[lo:lo + RADIUS_BATCH, None] + mu[None, :, None, None] * per_mu[lo:lo + RADIUS_BATCH, None]
        out[lo:lo + RADIUS_BATCH] = np.abs(np.linalg.eigvals(closed)).max(axis=-1)
    return out


@dataclass(frozen=True)
class DesignModels:
    """The loops one machine's LMS feedforward is designed on (``ambdaq lms --plant``).

    Parameters
    ----------
    plants : mapping of str to callable
        Named plants, each a factory of {label: (loop, the controller axes it stands for)}.
    pid : OneAxis
        The controller loop a transfer-function or continuous state-space plant is placed in
        (its PID gains, derivative filter and sample period).
    axes : tuple of str
        The controller's feedforward axes, in order: what a plant of every axis stands for.
    phase_bins : int
        Bins of the controller's phase-compensation table.
    phase_bin_hz : float
        Their spacing, in Hz.
    """

    plants: Mapping[str, Callable[[], dict]]
    pid: OneAxis
    axes: tuple[str, ...]
    phase_bins: int
    phase_bin_hz: float


def convergence_radius(loop, rpm: np.ndarray, mu: np.ndarray, harmonic: int = 1,
                       phase: "PhaseTable | None" = None) -> np.ndarray:
    """Spectral radius of the loop with the LMS on ``harmonic``, over speed x step size.

    Parameters
    ----------
    loop : OneAxis, PlantLoop or StateSpaceLoop
        The loop: a one-axis transfer-function model, or a multi-axis state-space one.
    rpm : ndarray, shape (n,)
        Rotor speeds, in rpm.
    mu : ndarray, shape (m,)
        LMS step sizes (dimensionless, either sign).
    harmonic : int
        Order k.
    phase : PhaseTable, optional
        Phase compensation of the update (:func:`phase_compensation`); default none (eq. 9).

    Returns
    -------
    ndarray, shape (n, m)
        Largest root magnitude; the LMS converges where it is below 1 (the nearer 1, the slower),
        holds where it is within :data:`HOLD_TOL` of 1 (see :func:`converges`).
    """
    rpm = np.asarray(rpm, dtype=float)

    def g_at(n: float, axes: int) -> np.ndarray:
        if phase is None:
            return np.ones(axes, dtype=complex)
        return np.exp(1j * phase.at(harmonic * n / 60.0))

    mu = np.asarray(mu, dtype=float)
    phi = harmonic * rpm * RPM_TO_RAD_S * loop.h
    if isinstance(loop, StateSpaceLoop):
        # the loop's input is r_c itself: e = C x - r_c, on the adapting axes
        at = [loop.at(float(n)) for n in rpm]
        axes = list(range(at[0][1].shape[1])) if loop.axes is None else list(loop.axes)
        return _radius(np.array([m for m, _, _ in at]), -np.array([b[:, axes] for _, b, _ in at]),
                       np.array([c[axes] for _, _, c in at]), np.eye(len(axes)), mu, phi,
                       np.array([g_at(n, at[0][1].shape[1])[axes] for n in rpm]).reshape(len(rpm), len(axes)))
    # e = S (r - r_c): the sensitivity in state space, its input u = -r_c
    from scipy.signal import tf2ss  # imported when used (OneAxis.plant_z)

    A, B, C, D = tf2ss(*loop.sensitivity_z())
    return _radius(A, B, C, D, mu, phi, np.array([g_at(n, 1) for n in rpm]).reshape(len(rpm), 1))


@dataclass(frozen=True)
class PhaseTable:
    """Phase compensation of the LMS update per axis over loop frequency.

    Parameters
    ----------
    phase_rad : ndarray, shape (axes, bins)
        Phase at 0, bin_hz, 2 bin_hz ... in rad.
    bin_hz : float
        Frequency step, in Hz.
    axes : tuple of str
        The axis of each row, by name.
    """

    phase_rad: np.ndarray
    bin_hz: float = 10.0
    axes: tuple[str, ...] = ()

    def at(self, f_hz: float) -> np.ndarray:
        """Phase per axis at ``f_hz`` (nearest bin, as the controller looks it up), in rad."""
        b = min(int(f_hz / self.bin_hz + 0.5), self.phase_rad.shape[1] - 1)
        return self.phase_rad[:, b]

    def select(self, axes: tuple[str, ...]) -> "PhaseTable":
        """The rows of ``axes`` (names), in that order."""
        return PhaseTable(self.phase_rad[[self.axes.index(a) for a in axes]], self.bin_hz, tuple(axes))


def error_response(loop, f_hz: np.ndarray) -> np.ndarray:
    """T_aa: the command error per feedforward on the same axis, e = T r_c, at loop frequencies
    ``f_hz`` (Hz); shape (axes, n).  One-axis loops: T = -S (the sensitivity).  A state-space
    loop is linearised at the speed whose 1X is ``f_hz`` (its gyroscopic terms are small)."""
    f_hz = np.asarray(f_hz, dtype=float)
    if isinstance(loop, StateSpaceLoop):
        out = []
        for f in f_hz:
            M, B, C = loop.at(60.0 * f)
            z = np.exp(2j * np.pi * f * loop.h)
            T = C @ np.linalg.solve(z * np.eye(M.shape[0]) - M, B)
            out.append(np.diag(T) - 1.0)
        return np.array(out).T
    sn, sd = loop.sensitivity_z()
    z = np.exp(2j * np.pi * f_hz * loop.h)
    return (-np.polyval(sn, z) / np.polyval(sd, z))[None, :]


def phase_compensation(loop, bins: int = 501, bin_hz: float = 10.0) -> PhaseTable:
    """The phase-compensated update (beyond Ro et al.): each axis's step turned by
    g = -conj(T_aa)/|T_aa|, the inverse phase of the loop at the harmonic's frequency, so that a
    positive mu converges at every speed (no sign flip, no dead band).

    Parameters
    ----------
    loop : OneAxis, PlantLoop or StateSpaceLoop
        The loop model; a measured frequency response can stand in through :class:`PhaseTable`.
    bins, bin_hz : int, float
        The table: ``bins`` frequencies ``bin_hz`` apart (Hz), from 0.
    """
    f = np.arange(bins) * bin_hz
    f[0] = bin_hz / 4  # DC itself is a pole of the LMS filter; its phase is the limit
    T = error_response(loop, f)
    return PhaseTable(np.angle(-np.conj(T)), bin_hz)


def measured_phase_compensation(freq_hz: np.ndarray, responses: np.ndarray, coherence: np.ndarray, *,
                                bins: int = 501, bin_hz: float = 10.0, min_coherence: float = 0.8) -> PhaseTable:
    """The phase-compensated update from a measured loop: g = -conj(T_aa)/|T_aa| as in
    :func:`phase_compensation`, with T_aa measured (``ambdaq frf estimate``) instead of modelled.

    Parameters
    ----------
    freq_hz : ndarray, shape (n,)
        Measured frequencies, in Hz (increasing).
    responses : ndarray of complex, shape (axes, n)
        T_aa per axis: command error per feedforward input on the same axis, in m/m.
    coherence : ndarray, shape (axes, n)
        Coherence of each point; points below ``min_coherence`` are not used.
    bins, bin_hz : int, float
        The table: ``bins`` frequencies ``bin_hz`` apart (Hz), from 0.
    min_coherence : float
        Least coherence of a point used, 0 .. 1.

    Returns
    -------
    PhaseTable
        Between good points the unit phasor is interpolated linearly; outside them it is held.
    """
    f = np.arange(bins) * bin_hz
    table = np.empty((responses.shape[0], bins))
    for a in range(responses.shape[0]):
        good = coherence[a] >= min_coherence
        if good.sum() < 2:
            raise ValueError(f"axis {a}: fewer than two points with coherence >= {min_coherence:g}")
        g = -np.conj(responses[a, good]) / np.abs(responses[a, good])
        fg = freq_hz[good]
        table[a] = np.angle(interpolate_response(fg, g, f))
    return PhaseTable(table, bin_hz)


def mu_sign(loop, rpm: np.ndarray, harmonic: int = 1, mu: float = 1e-4,
            phase: PhaseTable | None = None) -> np.ndarray:
    """Which sign of a small step size converges at each speed: +1, -1, or 0 (neither)."""
    state = converges(convergence_radius(loop, rpm, np.array([mu, -mu]), harmonic, phase=phase))
    return np.where(state[:, 0] == 1, 1, np.where(state[:, 1] == 1, -1, 0))


def sign_changes(signs: np.ndarray, rpm: np.ndarray) -> list[float]:
    """Speeds (rpm) midway between grid points where ``signs`` (from :func:`mu_sign`) changes."""
    return [float((rpm[i] + rpm[i + 1]) / 2) for i in np.flatnonzero(np.diff(signs) != 0)]


RPM_MIN = 100.0  # below this the integrator's corner, not the rotor, sets the phase of S


def sign_flip_rpm(loop: OneAxis, harmonic: int = 1, rpm_min: float = RPM_MIN, rpm_max: float = 60000.0,
                  step: float = 10.0) -> list[float]:
    """Speeds (rpm) where the converging sign of mu changes (Ro et al. reports about 6,000 rpm for
    the front bearing's 1X).  Below ``rpm_min`` the integrator's corner makes its own flips."""
    rpm = np.arange(rpm_min, rpm_max, step)
    return sign_changes(mu_sign(loop, rpm, harmonic), rpm)


def sign_schedule(loops, *, mu: float = 0.001, dead_band: float = 500.0, rpm_max: float = 60000.0,
                  harmonic: int = 1, step: float = 10.0) -> list[list[float]]:
    """A step-size schedule like Ro et al.'s: +-mu where that sign converges on every loop in
    ``loops`` (one loop or a list), 0 (weights held) within ``dead_band`` rpm of a sign change,
    wherever no sign converges on all of them, and below 100 rpm.

    Returns rows [rpm_from, rpm_to, mu] covering 0 .. ``rpm_max``.
    """
    loops = loops if isinstance(loops, (list, tuple)) else [loops]
    rpm = np.arange(0.0, rpm_max + step, step)
    signs = np.array([mu_sign(loop, np.maximum(rpm, step), harmonic, mu) for loop in loops])
    agreed = np.where(np.all(signs == signs[0], axis=0), signs[0], 0)
    value = mu * agreed.astype(float)
    value[rpm < RPM_MIN] = 0.0  # near standstill (the integrator's corner) the weights are held
    change = np.flatnonzero(np.diff(np.sign(value)) != 0)
    for i in change:  # hold the weights around every change of sign (and into every hold)
        f = (rpm[i] + rpm[i + 1]) / 2
        value[(np.abs(rpm - f) <= dead_band) & (rpm >= RPM_MIN + dead_band)] = 0.0
    rows = []
    start = 0
    for i in range(1, len(rpm) + 1):
        if i == len(rpm) or value[i] != value[start]:
            rows.append([float(rpm[start]), float(rpm[i] if i < len(rpm) else rpm_max), float(value[start])])
            start = i
    return rows


def schedule_problem(rows: list[tuple[float, float, float, float]], harmonics: int,
                     loops: dict, phase: PhaseTable | None = None, rpm_step: float = 100.0) -> str:
    """Why a step-size schedule is not stable on the convergence map ("" if it is).

    Parameters
    ----------
    rows : list of (harmonic, rpm_from, rpm_to, mu)
        The schedule; harmonic 0 applies the row to every harmonic 1 .. ``harmonics``.
    harmonics : int
        Number of harmonics the feedforward runs.
    loops : dict of str to (loop, axes)
        The loops to check, each with the controller axes (names) it stands for: their rows of
        ``phase``.
    phase : PhaseTable, optional
        The phase compensation the controller will run.
    rpm_step : float
        Speed grid, in rpm.
    """
    for k, lo, hi, mu in rows:
        if mu == 0:
            continue
        rpm = np.arange(max(lo, rpm_step / 2), hi, rpm_step)
        for kk in range(1, harmonics + 1) if k == 0 else (int(k),):
            for name, (loop, axes) in loops.items():
                ph = None if phase is None else phase.select(axes)
                r = convergence_radius(loop, rpm, np.array([mu]), kk, phase=ph)[:, 0]
                bad = np.flatnonzero(converges(r) < 1)
                if bad.size:
                    return (f"step size {mu:g} on {kk}X diverges on the {name} loop at {rpm[bad[0]]:.0f} rpm "
                            f"(radius {_radius_text(r[bad[0]])} on the convergence map)")
    return ""
