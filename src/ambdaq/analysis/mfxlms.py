"""Kang & Jung: base-motion compensators by multiple filtered-x LMS, and their FIR fit.

Per plane the closed loop is y = B u + C d (eq. 14), with u the feedforward (2 amplifier inputs),
d the base accelerations at the two bearings (2 accelerometers) and y the two gap sensors; the
compensator u = W d (eq. 15) cancels the base-motion response when W = W* = -B^-1 C (eq. 17).

Step 1, per frequency w_i (eq. 18, A-4 to A-17): with the base moving harmonically at w_i, a
two-tap compensator W_jm(q) = w_jm^1 + w_jm^2 q^-1 per pair (j: actuator, m: accelerometer) is
adapted by the normalised MFXLMS update on the filtered references d^m_ij = (B_ij / A_i) d_m, here
the identified secondary path at w_i (eq. A-9). With d1 = alpha d2 only alpha W_j1 + W_j2 is
determined (eq. A-12), so two runs with alpha_1 != alpha_2 give W at w_i (eq. A-13 to A-17).

Step 2: a FIR W_lm(q) = sum_t h_t q^-t fitted to the points by weighted least squares (eq. 19);
a FIR is stable whatever its taps.

Three departures from the appendix as printed, each because the printed form does not converge
on this rig (docs/base-motion.md has the analysis):
- the two references of each compensator are d_m and its quadrature at w_i (:func:`quadrature`)
  instead of d_m(k) and d_m(k-1). It is the same two-parameter compensator at
  w_i (:func:`two_tap` gives the paper's w^1 + w^2 q^-1), but the references are orthogonal:
  two samples of a 5 Hz sine at 10 kHz are nearly equal, and the difference direction then
  adapts 1e5 times slower;
- one normaliser D (eq. A-8) for every term, the summed power of all filtered references
  averaged over one period: normalised term by term, the y2 terms, whose references pass
  through the small cross path B21, dominate y1's update and the iteration has a growing mode
  for any positive mu, eta (and D sample by sample vanishes twice per period);
- descent on the error (w -= ...): the printed + absorbs a sign convention.

The LMS here runs offline over a recording made with feedback alone: the error it minimises is
the recorded response plus the predicted effect of the compensator, e_i = y_i + sum_jm W_jm d^m_ij
(the filtered-x structure with the secondary path applied to the references).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


def two_tap(gain: complex, f_hz: float, fs: float) -> tuple[float, float]:
    """The real two-tap filter c0 + c1 q^-1 whose response at ``f_hz`` equals ``gain``.

    Parameters
    ----------
    gain : complex
        Response to match, any unit.
    f_hz, fs : float
        Frequency and sample rate, in Hz; 0 < f_hz < fs / 2.

    Returns
    -------
    (c0, c1) : tuple of float

    Examples
    --------
    >>> c0, c1 = two_tap(0.5 - 0.5j, 1000.0, 10000.0)
    >>> w = 2 * np.pi * 1000.0 / 10000.0
    >>> complex(np.round(c0 + c1 * np.exp(-1j * w), 12))
    (0.5-0.5j)
    """
    w = 2 * np.pi * f_hz / fs
    c1 = -gain.imag / np.sin(w)
    return float(gain.real - c1 * np.cos(w)), float(c1)


def quadrature(x: np.ndarray, f_hz: float, fs: float) -> np.ndarray:
    """The quadrature (Hilbert transform) of the component of ``x`` at ``f_hz``, from two samples
    a quarter period apart: H[x](k) = (x(k - M) - cos(w M) x(k)) / sin(w M), M = round(fs / 4 f).

    Exact at ``f_hz`` for any M; with w M near 90 degrees the noise is not amplified (the
    one-step form, M = 1, would amplify it 1 / sin(w T) = 318 times at 5 Hz and 10 kHz). The first
    M samples are zero.

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, channels)
        Signal(s), any unit.
    f_hz, fs : float
        Frequency and sample rate, in Hz.

    Examples
    --------
    >>> k = np.arange(2000)
    >>> q = quadrature(np.sin(2 * np.pi * 30 * k / 1e4), 30.0, 1e4)
    >>> bool(np.allclose(q[100:], -np.cos(2 * np.pi * 30 * k[100:] / 1e4)))
    True
    """
    w = 2 * np.pi * f_hz / fs
    M = max(1, int(round(fs / (4 * f_hz))))
    out = np.zeros_like(x, dtype=float)
    out[M:] = (x[:-M] - np.cos(w * M) * x[M:]) / np.sin(w * M)
    return out


@njit(cache=True, fastmath=True, nogil=True)
def _mfxlms(y, d, dq, gr, gi, mu, eta, period, w, err):
    """Normalised MFXLMS (Kang & Jung eq. A-4 to A-9), offline, on in-phase and quadrature references.

    y (n, 2) gap responses with feedback alone; d, dq (n, 2) base accelerations and their
    quadrature; gr, gi (2, 2) the secondary path B_ij at this frequency; period: samples per
    period; w (2, 2, 2) per (actuator j, accelerometer m): [Re, Im] of W_jm, updated in place;
    err (n, 2) out.
    """
    n = y.shape[0]
    lam = 1.0 / period
    r = np.empty((2, 2, 2, 2))  # filtered references per (output i, actuator j, accelerometer m, part)
    power = 0.0  # D of eq. A-8, summed over all references and averaged over a period
    for k in range(n):
        tot = 0.0
        for i in range(2):
            for j in range(2):
                for m in range(2):
                    # u_j = Re(W_jm z_m) = w_re d_m - w_im dq_m; through B_ij (eq.)
                    a = gr[i, j] * d[k, m] - gi[i, j] * dq[k, m]
                    b = -(gi[i, j] * d[k, m] + gr[i, j] * dq[k, m])
                    r[i, j, m, 0] = a
                    r[i, j, m, 1] = b
                    tot += a * a + b * b
        power += lam * (tot - power)
        e0 = y[k, 0]
        e1 = y[k, 1]
        for j in range(2):  # the error with the compensator in place (eq.)
            for m in range(2):
                for q in range(2):
                    e0 += w[j, m, q] * r[0, j, m, q]
                    e1 += w[j, m, q] * r[1, j, m, q]
        err[k, 0] = e0
        err[k, 1] = e1
        if k >= 2 * period:  # once D has settled: eq., descent on mu e1^2 + eta e2^2
            s0 = mu * e0 / power
            s1 = eta * e1 / power
            for j in range(2):
                for m in range(2):
                    for q in range(2):
                        w[j, m, q] -= s0 * r[0, j, m, q] + s1 * r[1, j, m, q]


@dataclass(frozen=True)
class MfxlmsResult:
    """One MFXLMS run at one frequency.

    Attributes
    ----------
    response : ndarray of complex, shape (2, 2)
        W_jm(e^{j w T}) per actuator j and accelerometer m, in V per m/s^2: alpha W_j1 + W_j2
        is what one run determines (eq. A-12).
    taps : ndarray, shape (2, 2, 2)
        The same as the paper's two-tap compensators w_jm^1 + w_jm^2 q^-1 (eq. 18).
    error : ndarray, shape (n, 2)
        The compensated response during adaptation, in m.
    """

    response: np.ndarray
    taps: np.ndarray
    error: np.ndarray


def mfxlms(y: np.ndarray, d: np.ndarray, path: np.ndarray, f_hz: float, fs: float, *, mu: float = 0.01,
           eta: float = 0.01) -> MfxlmsResult:
    """Adapt the compensator at ``f_hz`` by the normalised MFXLMS (Kang & Jung eq. A-4 to A-9).

    Parameters
    ----------
    y : ndarray, shape (n, 2)
        Gap-sensor responses of one plane with feedback alone, in m.
    d : ndarray, shape (n, 2)
        Base accelerations at the two bearings, in m/s^2; harmonic at ``f_hz``.
    path : ndarray of complex, shape (2, 2)
        The identified secondary path B_ij at ``f_hz``: gap i per feedforward j, in m/V.
    f_hz, fs : float
        Frequency and sample rate, in Hz.
    mu, eta : float
        Normalised step sizes on the errors of gap 1 and gap 2 (0 < mu, eta << 1).

    Returns
    -------
    MfxlmsResult
    """
    d = np.ascontiguousarray(d, dtype=float)
    dq = quadrature(d, f_hz, fs)
    path = np.asarray(path, dtype=complex)
    w = np.zeros((2, 2, 2))
    err = np.empty((d.shape[0], 2))
    _mfxlms(np.ascontiguousarray(y, dtype=float), np.ascontiguousarray(d), dq, np.ascontiguousarray(path.real),
            np.ascontiguousarray(path.imag), mu, eta, max(2.0, fs / f_hz), w, err)
    response = w[..., 0] + 1j * w[..., 1]
    taps = np.array([[two_tap(complex(response[j, m]), f_hz, fs) for m in range(2)] for j in range(2)])
    return MfxlmsResult(response, taps, err)


def separate(beta_1: np.ndarray, alpha_1: complex, beta_2: np.ndarray, alpha_2: complex) -> np.ndarray:
    """W (2, 2) at one frequency from two runs with disturbance ratios alpha_1 != alpha_2
    (Kang & Jung eq. A-13 to A-17).

    Each run determines beta_j = alpha W_j1 + W_j2 (eq. A-14, A-16): ``beta`` is that run's
    ``MfxlmsResult.response`` combined as ``alpha * R[:, 0] + R[:, 1]``. Eq. A-17 as printed
    repeats alpha_1 in its last two rows; they hold alpha_2.
    """
    if abs(alpha_1 - alpha_2) < 1e-9:
        raise ValueError("the two runs need different disturbance ratios")
    A = np.array([[alpha_1, 1.0], [alpha_2, 1.0]])
    W = np.empty((2, 2), dtype=complex)
    for j in range(2):
        W[j] = np.linalg.solve(A, np.array([beta_1[j], beta_2[j]]))
    return W


def run_beta(result: MfxlmsResult, alpha: complex) -> np.ndarray:
    """beta_j = alpha W_j1 + W_j2 of one run (eq. A-14), shape (2,)."""
    return alpha * result.response[:, 0] + result.response[:, 1]


def fit_fir(f_hz: np.ndarray, points: np.ndarray, order: int, fs: float,
            weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """FIR taps h_0 .. h_order fitted to frequency-response points (Kang & Jung eq. 19).

    Minimises J = sum_k lambda_k |sum_t h_t e^{-j w_k t T} - W_k|^2 over real taps.

    Parameters
    ----------
    f_hz : ndarray, shape (n,)
        Frequencies of the points, in Hz.
    points : ndarray of complex, shape (n,)
        Compensator response at each frequency, any unit (V per m/s^2).
    order : int
        FIR order (order + 1 taps).
    fs : float
        Sample rate, in Hz.
    weights : ndarray, shape (n,), optional
        lambda_k; default 1 / |W_k|^2 (relative error).

    Returns
    -------
    taps : ndarray, shape (order + 1,)
    cost : float
        J at the optimum (with the weights used).
    """
    f_hz = np.asarray(f_hz, dtype=float)
    points = np.asarray(points, dtype=complex)
    lam = 1.0 / np.maximum(np.abs(points), 1e-30) ** 2 if weights is None else np.asarray(weights, dtype=float)
    E = np.exp(-2j * np.pi * np.outer(f_hz / fs, np.arange(order + 1)))
    s = np.sqrt(lam)[:, None]
    A = np.vstack([(E * s).real, (E * s).imag])
    b = np.concatenate([(points * s[:, 0]).real, (points * s[:, 0]).imag])
    taps, *_ = np.linalg.lstsq(A, b, rcond=None)
    resid = E @ taps - points
    return taps, float(np.sum(lam * np.abs(resid) ** 2))


def knee(orders: np.ndarray, costs: np.ndarray, n_points: int, *, gain: float = 2.0, floor: float = 1e-3) -> int:
    """The order at the knee of the cost-versus-order curve (Kang & Jung step 2): the first order
    where one more tap no longer cuts the cost by ``gain`` or more, or whose relative RMS fit error
    sqrt(J / n) is already under ``floor`` (points are not known better than that).

    Parameters
    ----------
    orders : ndarray of int
        Orders scanned, increasing by one.
    costs : ndarray
        J per order (:func:`fit_fir` with relative weights).
    n_points : int
        Number of frequency points J sums over.
    gain, floor : float
        Least worthwhile cost reduction per tap; relative RMS error counted as exact.
    """
    for i, o in enumerate(orders):
        if np.sqrt(costs[i] / n_points) < floor:
            return int(o)
        if i + 1 < len(orders) and costs[i + 1] > costs[i] / gain:
            return int(o)
    return int(orders[-1])
