"""Jeong et al.: the cone-shaped AMB, its linearised gains, the analogue PD loop and its stability.

One decoupled axis (Jeong et al. section 3): rotor m s^2 - Ky against the magnets' current gain Ki,
controlled by a PD with filtered derivative through a current-feedback amplifier (eq. 11, 15,
17):

    G(s) = N(s) / D(s) = Ks Kc [(Kp tau + Kd) s + Kp] / ((tau s + 1)(tau_c s + 1)),

optionally with the eddy-current lag 1 / (1 + tau_e s) on the force (eq. 16). The closed loop's
characteristic equation is (m s^2 - Ky) D(s) + Ki N(s) = 0 (eq. 22).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MU0 = 4e-7 * np.pi  # H/m


def force_factor(theta1: float, theta2: float) -> float:
    """alpha_g = (sin theta2 - sin theta1) / (theta2 - theta1) (Jeong et al. eq. 3); angles of the pole
    faces' edges, in rad. alpha_g <= shape_factor always."""
    if theta1 == theta2:
        return float(np.cos(theta1))
    return float((np.sin(theta2) - np.sin(theta1)) / (theta2 - theta1))


def shape_factor(theta1: float, theta2: float) -> float:
    """c = cos((theta1 + theta2) / 2) (Jeong et al. eq. 3); angles in rad."""
    return float(np.cos((theta1 + theta2) / 2))


def magnet_force(current: float | np.ndarray, gap: float | np.ndarray, *, area: float, turns: int,
                 alpha_g: float = 1.0) -> np.ndarray:
    """Attractive force of one magnet, F = alpha_g mu0 A N^2 I^2 / (4 g^2) (Jeong et al. eq. 1b, 3).

    Parameters
    ----------
    current : float or ndarray
        Coil current, in A.
    gap : float or ndarray
        Air gap, in m (> 0).
    area : float
        Pole face area, in m^2.
    turns : int
        Coil turns.
    alpha_g : float
        Force factor (:func:`force_factor`).

    Returns
    -------
    ndarray
        Force, in N.
    """
    return alpha_g * MU0 * area * turns**2 * np.asarray(current) ** 2 / (4 * np.asarray(gap) ** 2)


@dataclass(frozen=True)
class MagnetGains:
    """Linearised magnet at its operating point (Jeong et al. eq. 4): F = F0 + Ki i + Kq dg."""

    ki: float  # N/A
    kq: float  # N/m
    f0: float  # N


def linear_gains(*, area: float, turns: int, gap: float, bias: float, alpha_g: float = 1.0,
                 c: float = 1.0) -> MagnetGains:
    """Ki = alpha_g mu0 A N^2 I0 / (2 g0^2), Kq = c alpha_g mu0 A N^2 I0^2 / (2 g0^3) (Jeong et al. eq. 4),
    F0 from eq. 1b.

    Parameters
    ----------
    area : float
        Pole face area, in m^2.
    turns : int
        Coil turns.
    gap : float
        Nominal gap g0, in m.
    bias : float
        Bias current I0, in A.
    alpha_g, c : float
        Force and shape factors (eq. 3).

    Examples
    --------
    >>> g = linear_gains(area=155e-6, turns=400, gap=0.5e-3, bias=1.03)
    >>> round(g.ki, 1), round(g.kq)
    (64.2, 132250)
    """
    k = alpha_g * MU0 * area * turns**2
    return MagnetGains(k * bias / (2 * gap**2), c * k * bias**2 / (2 * gap**3), k * bias**2 / (4 * gap**2))


@dataclass(frozen=True)
class PdLoop:
    """One decoupled axis with the analogue PD loop (Jeong et al. eq. 11-17).

    Attributes (SI): m (kg), ky (N/m, the negative stiffness), ki (N/A), ks (V/m sensor), kc (A/V
    amplifier), kp (V/V), kd (s), tau (s, derivative filter), tau_c (s, current loop), tau_e
    (s, eddy-current lag; 0: none).
    """

    m: float
    ky: float
    ki: float
    ks: float
    kc: float
    kp: float
    kd: float
    tau: float
    tau_c: float
    tau_e: float = 0.0

    def controller(self, s: np.ndarray) -> np.ndarray:
        """G(s) of eq. 17 (A per m), with the eddy-current lag of eq. 16 when tau_e > 0."""
        s = np.asarray(s, dtype=complex)
        g = self.ks * self.kc * ((self.kp * self.tau + self.kd) * s + self.kp) / ((self.tau * s + 1) * (self.tau_c * s + 1))
        return g / (1 + self.tau_e * s)

    def characteristic(self) -> np.ndarray:
        """Coefficients (highest power first) of (m s^2 - Ky) D(s) + Ki N(s) (eq. 22)."""
        den = np.polymul([self.tau, 1.0], [self.tau_c, 1.0])
        if self.tau_e > 0:
            den = np.polymul(den, [self.tau_e, 1.0])
        num = self.ks * self.kc * np.array([self.kp * self.tau + self.kd, self.kp])
        return np.polyadd(np.polymul([self.m, 0.0, -self.ky], den), self.ki * num)

    def poles(self) -> np.ndarray:
        """Closed-loop eigenvalues, in rad/s."""
        return np.roots(self.characteristic())

    def stable(self) -> bool:
        """All poles in the left half plane (Routh-Hurwitz, by the Routh array)."""
        return routh_stable(self.characteristic())

    def stiffness_damping(self, f_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keq(w) = -Ky + Ki Re G(jw) (N/m), Ceq(w) = Ki Im G(jw) / w (N s/m) (eq. 19)."""
        w = 2 * np.pi * np.asarray(f_hz, dtype=float)
        g = self.controller(1j * w)
        return -self.ky + self.ki * g.real, self.ki * g.imag / w


def routh_stable(coefficients: np.ndarray) -> bool:
    """Whether a real polynomial (highest power first) has all roots in the open left half plane,
    from its Routh array (no zero in the first column, no sign change)."""
    a = np.trim_zeros(np.asarray(coefficients, dtype=float), "f")
    if a.shape[0] < 2:
        return True
    return bool(routh_stable_many(a[None])[0])


def routh_stable_many(coefficients: np.ndarray) -> np.ndarray:
    """:func:`routh_stable` of each row of ``coefficients`` (N, degree + 1), polynomials of one
    degree whose leading coefficient is not zero, their Routh arrays built side by side."""
    a = np.asarray(coefficients, dtype=float)
    a = np.where(a[:, :1] < 0, -a, a)
    count, n = a.shape
    cols = (n + 1) // 2
    p, q = np.zeros((count, cols)), np.zeros((count, cols))
    p[:, : len(range(0, n, 2))] = a[:, 0::2]
    q[:, : len(range(1, n, 2))] = a[:, 1::2]
    ok = p[:, 0] > 0
    for _ in range(n - 2):
        lead = q[:, 0]
        ok &= lead > 0  # a zero or a sign change in the first column
        r = np.zeros((count, cols))
        r[:, :-1] = (lead[:, None] * p[:, 1:] - p[:, :1] * q[:, 1:]) / np.where(lead > 0, lead, 1.0)[:, None]
        p, q = q, r
    return ok & (q[:, 0] > 0) & (p[:, 0] > 0)


def stable_map(loop: "PdLoop", kp: np.ndarray, kd: np.ndarray) -> np.ndarray:
    """Whether ``loop`` is stable at each (Kp, Kd) of the grid ``kp`` (V/V) x ``kd`` (s): shape
    (len(kp), len(kd)), every point's characteristic polynomial (eq. 22) tested at once."""
    from dataclasses import replace

    base = replace(loop, kp=0.0, kd=0.0).characteristic()
    P, D = np.meshgrid(np.asarray(kp, dtype=float), np.asarray(kd, dtype=float), indexing="ij")
    char = np.broadcast_to(base, (*P.shape, base.shape[0])).copy()
    char[..., -2] += loop.ki * (loop.ks * loop.kc * (P * loop.tau + D))  # characteristic()'s order of operations
    char[..., -1] += loop.ki * (loop.ks * loop.kc * P)
    return routh_stable_many(char.reshape(-1, base.shape[0])).reshape(P.shape)


@dataclass(frozen=True)
class StableRegion:
    """The (Kp, Kd) region where the PD loop is stable (Jeong et al. eq. 23, derived exactly)."""

    kd_min: float  # s
    kd_max: float  # s
    kp_min: float  # V/V

    def kp_max(self, loop: PdLoop) -> float:
        """The largest stable Kp at ``loop.kd`` (from the last Routh condition, found by bisection on
        the Routh array), in V/V; inf if none bounds it, NaN if no Kp is stable at this Kd."""
        def ok(kp: float) -> bool:
            return PdLoop(**{**loop.__dict__, "kp": kp}).stable()

        lo = self.kp_min * (1 + 1e-9)
        if not ok(lo):
            return float("nan")
        hi = lo * 2
        while ok(hi):
            hi *= 2
            if hi > 1e9:
                return float("inf")
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        return lo


def stable_region(loop: PdLoop) -> StableRegion:
    """Routh-Hurwitz bounds of the PD loop without eddy lag (Jeong et al. eq. 23):

    tau tau_c < m / Ky;  Ky (tau + tau_c) / G < Kp tau + Kd < (tau + tau_c) m / (tau tau_c G);
    Kp > Ky / G;  with G = Ks Kc Ki. The Kd bounds here are those of Kp tau + Kd at Kp = Kp_min.
    These are necessary; the last Routh condition, an upper bound on Kp that grows with Kd, completes
    them (:meth:`StableRegion.kp_max`). Eq. 23 as printed writes that bound with K_a; the paper's
    example (Kp < 34.7 at Kd = 0.005 s) evaluates it with K_a = Kd, dropping Kp tau; exactly, it is 72.0.
    """
    g = loop.ks * loop.kc * loop.ki
    if not loop.tau * loop.tau_c < loop.m / loop.ky:
        return StableRegion(float("nan"), float("nan"), float("nan"))
    kp_min = loop.ky / g
    ka_lo = loop.ky * (loop.tau + loop.tau_c) / g
    ka_hi = (loop.tau + loop.tau_c) * loop.m / (loop.tau * loop.tau_c * g)
    return StableRegion(ka_lo - kp_min * loop.tau, ka_hi - kp_min * loop.tau, kp_min)
