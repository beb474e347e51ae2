"""Linear models of one AMB control axis: digital PID, amplifier, equivalent stiffness and damping.

The controlled bearing acts on the rotor like a spring-damper whose coefficients depend on
frequency (Jeong et al. eq. 19 and 21):

    Keq(w) = -Kx + Ki Re G(jw),    Ceq(w) = Ki Im G(jw) / w,

with G the loop from rotor displacement to coil current: sensor gain Ks, the digital controller
C(z) at z = exp(jwh), the D/A's zero-order hold and the amplifier G_A (Ro et al. eq. 2).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np


def pid_z(*, p: float, i: float, d: float, nd: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The digital PID of the simulated controller as (num, den) in powers of z: the one statement
    of the law (the step kernel runs the same difference equation).

    Parallel form with a Tustin integrator I h (z+1) / (2 (z-1)) (the readable term of Ro et al.
    eq. 3) and a backward-Euler filtered derivative D (z - 1) / ((Tf + h) z - Tf), Tf = (D/P)/Nd.

    Parameters
    ----------
    p : float
        Proportional gain, in V/V.
    i : float
        Integral gain, in 1/s.
    d : float
        Derivative gain, in s.
    nd : float
        Derivative filter factor Nd.
    h : float
        Sample period, in s.
    """
    tf = d / p / nd
    d1 = np.array([1.0, -1.0])
    d2 = np.array([tf + h, -tf])
    num = np.polymul(p * d1, d2) + np.polymul(i * h / 2 * np.array([1.0, 1.0]), d2) + np.polymul(d * d1, d1)
    return num, np.polymul(d1, d2)


def pid_response(f: np.ndarray, *, p: float, i: float, d: float, nd: float, h: float) -> np.ndarray:
    """Frequency response of the digital PID (:func:`pid_z`).

    Parameters
    ----------
    f : ndarray
        Frequencies, in Hz.
    p, i, d, nd, h : float
        The law's gains (V/V, 1/s, s), derivative filter factor and sample period (s), as in
        :func:`pid_z`.

    Returns
    -------
    ndarray of complex
        C(exp(j 2 pi f h)), in V/V.
    """
    z = np.exp(1j * 2 * np.pi * np.asarray(f, dtype=float) * h)
    num, den = pid_z(p=p, i=i, d=d, nd=nd, h=h)
    return np.polyval(num, z) / np.polyval(den, z)


def amplifier_response(f: np.ndarray, *, gain: float, wn_hz: float, zeta: float) -> np.ndarray:
    """G_A(jw) = wn^2 Kamp / (s^2 + 2 zeta wn s + wn^2) (Ro et al. eq. 2).

    Parameters
    ----------
    f : ndarray
        Frequencies, in Hz.
    gain : float
        DC gain Kamp, in A/V.
    wn_hz : float
        Natural frequency, in Hz.
    zeta : float
        Damping ratio.
    """
    s = 1j * 2 * np.pi * np.asarray(f, dtype=float)
    wn = 2 * np.pi * wn_hz
    return wn**2 * gain / (s**2 + 2 * zeta * wn * s + wn**2)


def zoh_response(f: np.ndarray, *, h: float) -> np.ndarray:
    """Zero-order hold (1 - exp(-s h)) / (s h) of a D/A held for ``h`` s, at ``f`` Hz."""
    s = 1j * 2 * np.pi * np.asarray(f, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (1 - np.exp(-s * h)) / (s * h)
    return np.where(s == 0, 1.0, out)


@dataclass(frozen=True)
class StiffnessDamping:
    """Equivalent stiffness (N/m) and damping (N s/m) of a bearing axis over frequency (Hz)."""

    f: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray


def equivalent_stiffness_damping(
    f: np.ndarray,
    *,
    ki: float,
    kx: float,
    sensor_gain: float,
    p: float,
    i: float,
    d: float,
    nd: float,
    h: float,
    amp_gain: float,
    amp_wn_hz: float,
    amp_zeta: float,
) -> StiffnessDamping:
    """Keq and Ceq of a digitally controlled AMB axis (Jeong et al. eq. 19, 21).

    Parameters
    ----------
    f : ndarray
        Frequencies, in Hz (> 0 for the damping).
    ki : float
        Current gain, in N/A.
    kx : float
        Negative position stiffness, in N/m.
    sensor_gain : float
        Gap sensor gain Ks, in V/m.
    p, i, d, nd, h : float
        PID gains (V/V, 1/s, s), derivative filter factor and sample period (s); see
        :func:`pid_response`.
    amp_gain, amp_wn_hz, amp_zeta : float
        Amplifier gain (A/V), natural frequency (Hz) and damping ratio.

    Returns
    -------
    StiffnessDamping
    """
    f = np.asarray(f, dtype=float)
    g = (
        sensor_gain
        * pid_response(f, p=p, i=i, d=d, nd=nd, h=h)
        * zoh_response(f, h=h)
        * amplifier_response(f, gain=amp_gain, wn_hz=amp_wn_hz, zeta=amp_zeta)
    )
    w = 2 * np.pi * f
    with np.errstate(divide="ignore", invalid="ignore"):
        damping = ki * g.imag / w
    return StiffnessDamping(f, -kx + ki * g.real, damping)


ZOH_MEMO = 2048
"""The discretisations :func:`zoh` keeps per process (the least recently used go first): a rig steps
the same speeds again and again (each 50 rpm bucket of every run-up ``lms runup`` compares, every
spindle a process builds) and a 25-state matrix exponential is a third of a millisecond."""
_zoh_memo: OrderedDict[tuple, tuple[np.ndarray, np.ndarray]] = OrderedDict()
_zoh_lock = threading.Lock()


def zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: x[k+1] = Phi x[k] + Gamma u[k] for step ``h`` (s).

    The same (A, B, h) gives the same matrices, from the memo after the first time (fresh copies:
    a caller may change them)."""
    from scipy.linalg import expm  # 0.3 s to import: only where a model is discretised

    A, B = np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(B, dtype=float)
    key = (A.shape, B.shape, float(h), A.tobytes(), B.tobytes())
    with _zoh_lock:
        hit = _zoh_memo.get(key)
        if hit is not None:
            _zoh_memo.move_to_end(key)
    if hit is None:
        n, m = B.shape
        M = np.zeros((n + m, n + m))
        M[:n, :n] = A
        M[:n, n:] = B
        E = expm(M * h)
        hit = (E[:n, :n].copy(), E[:n, n:].copy())
        with _zoh_lock:
            _zoh_memo[key] = hit
            while len(_zoh_memo) > ZOH_MEMO:
                _zoh_memo.popitem(last=False)
    return hit[0].copy(), hit[1].copy()
