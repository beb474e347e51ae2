"""Frequency responses measured from recordings: the H1 estimate with its coherence.

With an input x (the excitation, as the device recorded it) and outputs y, averaged over Hann
windowed segments (Welch),

    H1(f) = S_xy(f) / S_xx(f),    gamma^2(f) = |S_xy|^2 / (S_xx S_yy),

H1 is unbiased by noise on the output (runout, sensor noise, the rotor's own response), and
gamma^2 says how much of the output the input explains at each frequency (1: all of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class H1Estimate:
    """An H1 estimate from one input to several outputs.

    Attributes
    ----------
    freq_hz : ndarray, shape (n,)
        Frequencies from ``resolution_hz`` to the Nyquist frequency, in Hz.
    response : ndarray of complex, shape (n, outputs)
        Output per input, in the outputs' unit per the input's.
    coherence : ndarray, shape (n, outputs)
        Magnitude-squared coherence, 0 .. 1.
    segments : int
        Number of averaged segments.
    """

    freq_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    segments: int


def h1_estimate(x: np.ndarray, y: np.ndarray, *, fs: float, resolution_hz: float) -> H1Estimate:
    """H1 frequency response and coherence from input ``x`` to outputs ``y`` (Welch, Hann, 50% overlap).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Input signal, any unit (e.g. the feedforward input r_c, in m).
    y : ndarray, shape (n,) or (n, outputs)
        Output signal(s), any unit (e.g. the command error, in m).
    fs : float
        Sample rate, in Hz.
    resolution_hz : float
        Frequency step, in Hz; the segment is ``fs / resolution_hz`` samples long.

    Returns
    -------
    H1Estimate

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x = rng.standard_normal(100_000)
    >>> y = 0.5 * np.roll(x, 1)                     # half, one sample late
    >>> est = h1_estimate(x, y, fs=10_000.0, resolution_hz=10.0)
    >>> h = est.response[np.searchsorted(est.freq_hz, 1250.0), 0]   # a sample's delay is 45 deg at fs / 8
    >>> print(f"{abs(h):.3f} {np.degrees(np.angle(h)):.1f}")
    0.500 -45.0
    """
    from scipy.signal import csd, welch  # 1 s to import: only where an estimate is made (not frf measure)

    x = np.asarray(x, dtype=float)
    y2 = np.asarray(y, dtype=float).reshape(x.shape[0], -1)
    nperseg = int(round(fs / resolution_hz))
    if not 8 <= nperseg <= x.shape[0]:
        raise ValueError(f"a {resolution_hz:g} Hz resolution needs segments of {nperseg} samples; "
                         f"the signal has {x.shape[0]}")
    kw = {"fs": fs, "window": "hann", "nperseg": nperseg, "noverlap": nperseg // 2, "detrend": "constant"}
    f, sxx = welch(x, **kw)
    _, syy = welch(y2, axis=0, **kw)
    _, sxy = csd(x[:, None], y2, axis=0, **kw)  # conj(X) Y
    keep = slice(1, None)  # the mean is removed per segment: DC carries nothing
    h = sxy[keep] / sxx[keep, None]
    coh = np.abs(sxy[keep]) ** 2 / (sxx[keep, None] * syy[keep])
    segments = 1 + (x.shape[0] - nperseg) // (nperseg - nperseg // 2)
    return H1Estimate(f[keep], h, coh, segments)


COHERENT = 0.9
"""Coherence above which a point of a frequency response is trusted (its random error in |H| is
then below about 8% for 10 averages: Bendat and Piersol, Random Data, eq. 9.90)."""


def coherent_band(freq_hz: np.ndarray, coherence: np.ndarray, threshold: float = COHERENT) -> tuple[float, float] | None:
    """The widest run of consecutive frequencies whose coherence is at least ``threshold``: where a
    measured response can be trusted, as (lowest, highest) in Hz; None if no point reaches it.

    Parameters
    ----------
    freq_hz : ndarray, shape (n,)
        Frequencies, in Hz, increasing.
    coherence : ndarray, shape (n,)
        Magnitude-squared coherence at each, 0 .. 1.
    threshold : float
        Least coherence, 0 .. 1.
    """
    good = np.concatenate(([False], np.asarray(coherence) >= threshold, [False]))
    edges = np.flatnonzero(np.diff(good.astype(np.int8)))
    if edges.size == 0:
        return None
    starts, stops = edges[0::2], edges[1::2]
    i = int(np.argmax(stops - starts))
    return float(freq_hz[starts[i]]), float(freq_hz[stops[i] - 1])
