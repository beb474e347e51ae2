"""Second-order sections of an AMB controller's filter chain (notch, low-pass, lead-lag), discrete
at the control rate, and their state-space form.

Each section is ``H(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)``, run in the
transposed direct form II a controller's firmware uses (two states per section)::

    y = b0 x + s1,   s1' = b1 x - a1 y + s2,   s2' = b2 x - a2 y.

The notch and the low-pass are the bilinear transforms, prewarped at their centre frequency, of
the analogue prototypes in R. Bristow-Johnson's "Cookbook formulae for audio EQ biquad filter
coefficients"; the lead-lag is the bilinear transform of (1 + s/w_z) / (1 + s/w_p), prewarped at
the geometric mean of its corner frequencies, where its phase lead peaks.
"""

from __future__ import annotations

import numpy as np

Section = tuple[float, float, float, float, float]
"""(b0, b1, b2, a1, a2) of one section (a0 = 1)."""


def notch(f0_hz: float, q: float, fs_hz: float, depth: float = 0.0) -> Section:
    """A notch at ``f0_hz`` of quality ``q`` (its -3 dB width is f0/Q); ``depth`` is its gain at
    f0 (0: a full notch; 0.1: -20 dB).  Unity gain at DC and Nyquist."""
    w0 = 2 * np.pi * f0_hz / fs_hz
    alpha = np.sin(w0) / (2 * q)
    c = np.cos(w0)
    a0 = 1 + alpha
    # the cookbook's peaking form with the zeros' damping set by the depth (depth 0: its notch)
    return ((1 + alpha * depth) / a0, -2 * c / a0, (1 - alpha * depth) / a0, -2 * c / a0, (1 - alpha) / a0)


def lowpass(f0_hz: float, q: float, fs_hz: float) -> Section:
    """A second-order low-pass at ``f0_hz`` of quality ``q`` (0.707: Butterworth); unity at DC."""
    w0 = 2 * np.pi * f0_hz / fs_hz
    alpha = np.sin(w0) / (2 * q)
    c = np.cos(w0)
    a0 = 1 + alpha
    return ((1 - c) / 2 / a0, (1 - c) / a0, (1 - c) / 2 / a0, -2 * c / a0, (1 - alpha) / a0)


def lead_lag(f_zero_hz: float, f_pole_hz: float, fs_hz: float) -> Section:
    """(1 + s/w_z) / (1 + s/w_p): phase lead between ``f_zero_hz`` and ``f_pole_hz`` (a lead where
    the zero is below the pole, a lag otherwise); unity at DC."""
    fm = np.sqrt(f_zero_hz * f_pole_hz)
    k = 2 * np.pi * fm / np.tan(np.pi * fm / fs_hz)  # bilinear s = k (z - 1) / (z + 1), prewarped at fm
    wz, wp = 2 * np.pi * f_zero_hz, 2 * np.pi * f_pole_hz
    n0, n1 = 1 + k / wz, 1 - k / wz  # numerator (1 + s/wz) (z + 1) -> n0 z + n1
    d0, d1 = 1 + k / wp, 1 - k / wp
    return (n0 / d0, n1 / d0, 0.0, d1 / d0, 0.0)


def response(sections: list[Section], f_hz: np.ndarray, fs_hz: float) -> np.ndarray:
    """The chain's frequency response at ``f_hz`` (Hz), complex."""
    z = np.exp(-2j * np.pi * np.asarray(f_hz, float) / fs_hz)
    out = np.ones_like(z)
    for b0, b1, b2, a1, a2 in sections:
        out *= (b0 + b1 * z + b2 * z * z) / (1 + a1 * z + a2 * z * z)
    return out


def state_space(sections: list[Section]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The chain as one discrete state space (A, B, C, D): s' = A s + B x, y = C s + D x, two
    states per section, in the transposed direct form II each section runs."""
    n = 2 * len(sections)
    A, B, C, D = np.zeros((n, n)), np.zeros(n), np.zeros(n), 1.0
    # the chain so far: its output y_prev = Cp s + Dp x
    for k, (b0, b1, b2, a1, a2) in enumerate(sections):
        i = 2 * k
        Cp, Dp = C.copy(), D
        # this section's input is the chain so far; its output y = b0 u + s1
        # s1' = b1 u - a1 y + s2 = (b1 - a1 b0) u - a1 s1 + s2;  s2' = (b2 - a2 b0) u - a2 s1
        A[i] += (b1 - a1 * b0) * Cp
        A[i, i] += -a1
        A[i, i + 1] += 1.0
        A[i + 1] += (b2 - a2 * b0) * Cp
        A[i + 1, i] += -a2
        B[i] += (b1 - a1 * b0) * Dp
        B[i + 1] += (b2 - a2 * b0) * Dp
        C = b0 * Cp
        C[i] += 1.0
        D = b0 * Dp
    return A, B, C, D
