"""A magnetic bearing's power amplifier from its measured response, coil current per controller
volt (issue 42: ki apart from ka).

The plant a closed-loop measurement gives holds each bearing's actuator as ki ka, the force per
controller volt; its coil currents hold ka alone. Where a run records them, the response from the
controller's output u to the coil current i of the excited axis is the amplifier's, referred to
the test signal r like the plant (A = H_ri / H_ru: the feedback's noise, in u and i alike, does
not bias it). This module fits it with the amplifier of Ro et al. (eq. 2), a second-order current
loop ka wn^2 / (s^2 + 2 zeta wn s + wn^2), seen as the controller sees it: its output held over
each period and the current sampled at the next period's start, with the gap (the zero-order hold
of the continuous loop, C (zI - Phi)^-1 Gamma). Its DC gain ka divides ki ka into ki.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .amb import zoh

START = (1.0, 2000.0, 0.7)
"""Where the fit of (ka in A/V, wn in Hz, zeta) starts where the machine's data gives none."""
MODEL_FLOOR = 1e-4
"""Each fitted value is stated no better than this fraction of itself, added to its variance: the
ratio of two estimates from one test signal leaves little noise where the current follows the
output exactly (the simulator's coils have no noise of their own), and the Welch window's leakage
is then of its size: ka came out 2-5e-5 low on the four axes of the simulated flexible rotor (seed
5, 4 s at 5 Hz), one to two times the noise's deviation, with a reduced chi-square of 0.96-1.05;
a bound, not a measured scatter."""


def response(h_ri: np.ndarray, h_ru: np.ndarray, cov_ii: np.ndarray, cov_iu: np.ndarray,
             cov_uu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The amplifier's response A = H_ri / H_ru (A/V) and its error's variance, to first order.

    Parameters
    ----------
    h_ri, h_ru : ndarray of complex, shape (n,)
        H1 from the test signal (m) to the coil current (A/m) and to the controller's output (V/m).
    cov_ii, cov_uu : ndarray, shape (n,)
        Their errors' variances (A^2/m^2, V^2/m^2).
    cov_iu : ndarray of complex, shape (n,)
        E[d_ri d_ru^*], A V/m^2.

    Returns
    -------
    ndarray of complex, ndarray
        A (A/V) and Var(dA) = E|d_ri - A d_ru|^2 / |H_ru|^2 (A^2/V^2).
    """
    a = h_ri / h_ru
    var = (cov_ii + np.abs(a) ** 2 * cov_uu - 2 * np.real(np.conj(a) * cov_iu)) / np.abs(h_ru) ** 2
    return a, np.maximum(var, 0.0)


def model(freq_hz: np.ndarray, ka: float, wn_hz: float, zeta: float, fs: float) -> np.ndarray:
    """The sampled amplifier C (zI - Phi)^-1 Gamma at ``freq_hz`` (Hz): ``ka`` A/V, ``wn_hz`` Hz,
    ``zeta``, the output held over each period of ``fs`` (Hz) and the current sampled at the start
    of the next."""
    wn = 2 * np.pi * wn_hz
    phi, gam = zoh(np.array([[0.0, 1.0], [-wn**2, -2 * zeta * wn]]), np.array([[0.0], [wn**2 * ka]]), 1.0 / fs)
    z = np.exp(2j * np.pi * np.asarray(freq_hz) / fs)
    det = (z - phi[0, 0]) * (z - phi[1, 1]) - phi[0, 1] * phi[1, 0]
    return ((z - phi[1, 1]) * gam[0, 0] + phi[0, 1] * gam[1, 0]) / det  # first row of (zI - Phi)^-1 Gamma


@dataclass
class AmplifierFit:
    """One amplifier's fitted (ka, wn, zeta)."""

    values: np.ndarray  # ka (A/V), wn (Hz), zeta
    covariance: np.ndarray
    chi2_reduced: float
    points: int

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def fit(freq_hz: np.ndarray, measured: np.ndarray, variance: np.ndarray, fs: float,
        start: tuple[float, float, float] = START) -> AmplifierFit:
    """Weighted least squares of :func:`model` to ``measured`` (A/V) at ``freq_hz`` (Hz), each
    point weighted by its deviation (``variance``, A^2/V^2, floored at 1e-6 of the response's
    magnitude: an exact current would otherwise weigh one point over all), ``fs`` the sample rate
    (Hz); the covariance is the weighted Jacobian's, scaled by the reduced chi-square where the fit
    leaves more than the noise, with :data:`MODEL_FLOOR` added."""
    from scipy.optimize import least_squares

    sigma = np.sqrt(np.maximum(variance / 2, (1e-6 * np.abs(measured)) ** 2))  # each of the real and imaginary parts
    x0 = np.array(start, dtype=float)

    def residual(scale: np.ndarray) -> np.ndarray:
        r = (model(freq_hz, *(scale * x0), fs) - measured) / sigma
        return np.concatenate([r.real, r.imag])

    sol = least_squares(residual, np.ones(3), x_scale=np.full(3, 0.1), diff_step=1e-7)
    values = sol.x * x0
    dof = max(2 * freq_hz.size - 3, 1)
    chi2 = float(sol.fun @ sol.fun / dof)
    cov = np.linalg.inv(sol.jac.T @ sol.jac) * max(chi2, 1.0) * np.outer(x0, x0)
    return AmplifierFit(values, cov + np.diag((MODEL_FLOOR * values) ** 2), chi2, int(freq_hz.size))
