"""Stability of seed 000's LMS runout feedforward inside the AMB loop (Fig. 5).

The feedforward r_c is subtracted from the sensor signal, so the command error is
e = S (r - r_c) with S = 1 / (1 + C P) the sensitivity of the sampled loop.  For one harmonic the
LMS of eq. 9-10 is the linear filter r_c = G_ff e with

    G_ff(z) = mu (c z - 1) / (z^2 - 2 c z + 1),   c = cos(k Omega h)

(summing eq. 9 over time: r_c(t) = mu sum_{n>=1} cos(k Omega h n) e(t - n); eq. 15 as printed is
garbled, eq. 16 follows from this one).  With the loop, the characteristic polynomial is

    den_S den_ff + num_S num_ff = 0,

and the LMS converges where every root lies inside the unit circle.  Whether mu must be positive
or negative depends on the phase of S at k Omega: that is the sign flip of seed 000 section 3.3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import cont2discrete


@dataclass(frozen=True)
class OneAxis:
    """Seed 000's one-axis loop: G_R = Ki Ks / (m s^2 - Kx) (eq. 1), amplifier G_A (eq. 2),
    digital PID at h (eq. 3, parallel form, Tustin integral, filtered derivative).

    Parameters (SI): m kg, ki N/A, kx N/m, ks V/m, amplifier gain A/V, wn Hz, zeta, PID gains
    V/V, 1/s, s, derivative filter Nd, sample period s.
    """

    m: float = 1.5
    ki: float = 273.0
    kx: float = 1.77e6
    ks: float = 1.0e4
    amp_gain: float = 0.8
    amp_wn_hz: float = 1800.0
    amp_zeta: float = 1.7
    p: float = 1.6
    i: float = 1.0
    d: float = 0.0015
    nd: float = 15.0
    h: float = 1e-4

    def plant_z(self) -> tuple[np.ndarray, np.ndarray]:
        """ZOH-discretised amplifier + rotor + sensor, V in -> V out: (num, den) in powers of z."""
        wn = 2 * np.pi * self.amp_wn_hz
        num = np.array([self.amp_gain * wn**2 * self.ki * self.ks])
        den = np.polymul([1, 2 * self.amp_zeta * wn, wn**2], [self.m, 0, -self.kx])
        nz, dz, _ = cont2discrete((num, den), self.h, method="zoh")
        return np.trim_zeros(np.atleast_1d(np.squeeze(nz)), "f"), dz

    def controller_z(self) -> tuple[np.ndarray, np.ndarray]:
        """The digital PID as (num, den) in powers of z (same law as the simulated controller)."""
        h, tf = self.h, self.d / self.p / self.nd
        # P + I h (z + 1) / (2 (z - 1)) + D (z - 1) / ((Tf + h) z - Tf)
        d1 = np.array([1.0, -1.0])
        d2 = np.array([tf + h, -tf])
        num = (np.polymul(self.p * d1, d2) + np.polymul(self.i * h / 2 * np.array([1.0, 1.0]), d2)
               + np.polymul(self.d * d1, d1))
        return num, np.polymul(d1, d2)

    def sensitivity_z(self) -> tuple[np.ndarray, np.ndarray]:
        """S = 1 / (1 + C P) as (num, den) in powers of z."""
        pn, pd = self.plant_z()
        cn, cd = self.controller_z()
        den = np.polyadd(np.polymul(pd, cd), np.polymul(pn, cn))
        return np.polymul(pd, cd), den


BEARINGS = {
    "front": OneAxis(),
    "rear": OneAxis(ki=182.0, kx=1.18e6, amp_wn_hz=2500.0, d=0.002),
}
"""Seed 000's one-axis loops of the two radial bearings (Table 1, the PID gains; m = 1.5 kg)."""


def convergence_radius(loop: OneAxis, rpm: np.ndarray, mu: np.ndarray, harmonic: int = 1) -> np.ndarray:
    """Spectral radius of the loop with the LMS on ``harmonic``, over speed x step size.

    Parameters
    ----------
    loop : OneAxis
        The axis model.
    rpm : ndarray, shape (n,)
        Rotor speeds, in rpm.
    mu : ndarray, shape (m,)
        LMS step sizes (dimensionless, either sign).
    harmonic : int
        Order k.

    Returns
    -------
    ndarray, shape (n, m)
        Largest root magnitude; the LMS converges where it is < 1 (and the nearer 1, the slower).
    """
    sn, sd = loop.sensitivity_z()
    out = np.empty((len(rpm), len(mu)))
    for i, n in enumerate(np.asarray(rpm, dtype=float)):
        c = np.cos(harmonic * n * 2 * np.pi / 60 * loop.h)
        ff_den = np.array([1.0, -2 * c, 1.0])
        base = np.polymul(sd, ff_den)
        ff = np.polymul(sn, np.array([c, -1.0]))
        for j, m in enumerate(np.asarray(mu, dtype=float)):
            out[i, j] = np.abs(np.roots(np.polyadd(base, m * ff))).max()
    return out


def mu_sign(loop: OneAxis, rpm: np.ndarray, harmonic: int = 1, mu: float = 1e-4) -> np.ndarray:
    """Which sign of a small step size converges at each speed: +1, -1, or 0 (neither)."""
    r = convergence_radius(loop, rpm, np.array([mu, -mu]), harmonic)
    return np.where(r[:, 0] < 1, 1, np.where(r[:, 1] < 1, -1, 0))


RPM_MIN = 100.0  # below this the integrator's corner, not the rotor, sets the phase of S


def sign_flip_rpm(loop: OneAxis, harmonic: int = 1, rpm_min: float = RPM_MIN, rpm_max: float = 60000.0,
                  step: float = 10.0) -> list[float]:
    """Speeds (rpm) where the converging sign of mu changes (seed 000 reports about 6,000 rpm for
    the front bearing's 1X).  Below ``rpm_min`` the integrator's corner makes its own flips."""
    rpm = np.arange(rpm_min, rpm_max, step)
    s = mu_sign(loop, rpm, harmonic)
    return [float((rpm[i] + rpm[i + 1]) / 2) for i in np.flatnonzero(np.diff(s) != 0)]


def sign_schedule(loop: OneAxis, *, mu: float = 0.001, dead_band: float = 500.0, rpm_max: float = 60000.0,
                  harmonic: int = 1, step: float = 10.0) -> list[list[float]]:
    """A step-size schedule like seed 000's: +-mu where that sign converges, 0 (weights held) within
    ``dead_band`` rpm of a sign change, wherever neither sign converges, and below 100 rpm.

    Returns rows [rpm_from, rpm_to, mu] covering 0 .. ``rpm_max``.
    """
    rpm = np.arange(0.0, rpm_max + step, step)
    value = mu * mu_sign(loop, np.maximum(rpm, step), harmonic).astype(float)
    value[rpm < RPM_MIN] = 0.0  # near standstill (the integrator's corner) the weights are held
    for f in sign_flip_rpm(loop, harmonic, rpm_max=rpm_max, step=step):
        value[np.abs(rpm - f) <= dead_band] = 0.0
    rows = []
    start = 0
    for i in range(1, len(rpm) + 1):
        if i == len(rpm) or value[i] != value[start]:
            rows.append([float(rpm[start]), float(rpm[i] if i < len(rpm) else rpm_max), float(value[start])])
            start = i
    return rows


def schedule_problem(rows: list[tuple[float, float, float, float]], harmonics: int,
                     loops: dict[str, OneAxis] = BEARINGS, rpm_step: float = 100.0) -> str:
    """Why a step-size schedule is not stable on the convergence map ("" if it is).

    Parameters
    ----------
    rows : list of (harmonic, rpm_from, rpm_to, mu)
        The schedule; harmonic 0 applies the row to every harmonic 1 .. ``harmonics``.
    harmonics : int
        Number of harmonics the feedforward runs.
    loops : dict of str to OneAxis
        The loops to check (default: both bearings of seed 000).
    rpm_step : float
        Speed grid, in rpm.
    """
    for k, lo, hi, mu in rows:
        if mu == 0:
            continue
        rpm = np.arange(max(lo, rpm_step / 2), hi, rpm_step)
        for kk in range(1, harmonics + 1) if k == 0 else (int(k),):
            for name, loop in loops.items():
                r = convergence_radius(loop, rpm, np.array([mu]), kk)[:, 0]
                bad = np.flatnonzero(r >= 1.0)
                if bad.size:
                    return (f"step size {mu:g} on {kk}X diverges on the {name} bearing at {rpm[bad[0]]:.0f} rpm "
                            f"(radius {r[bad[0]]:.4f} on the convergence map)")
    return ""
