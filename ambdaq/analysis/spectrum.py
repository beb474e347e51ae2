"""Amplitude spectra of sampled signals."""

from __future__ import annotations

import numpy as np
from scipy.signal import get_window


def amplitude_spectrum(x: np.ndarray, *, fs: float, window: str = "hann") -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum, scaled so a sinusoid of amplitude A shows a peak of A.

    Parameters
    ----------
    x : ndarray
        Signal, any unit; the mean is removed.
    fs : float
        Sample rate, in Hz.
    window : str
        Window name for :func:`scipy.signal.get_window`.

    Returns
    -------
    f : ndarray
        Frequencies, in Hz.
    amplitude : ndarray
        Amplitude per bin, in the unit of ``x``.

    Examples
    --------
    >>> t = np.arange(10000) / 10000.0
    >>> f, a = amplitude_spectrum(3.0 * np.sin(2 * np.pi * 500 * t), fs=10000.0)
    >>> round(float(a[np.argmax(a)]), 2), float(f[np.argmax(a)])
    (3.0, 500.0)
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or x.shape[0] < 2:
        raise ValueError("x must be a 1-D signal of at least 2 samples")
    if not fs > 0:
        raise ValueError(f"fs must be > 0 Hz, got {fs}")
    w = get_window(window, x.shape[0])
    spec = np.fft.rfft((x - x.mean()) * w)
    amp = 2.0 * np.abs(spec) / w.sum()
    amp[0] /= 2.0
    return np.fft.rfftfreq(x.shape[0], 1.0 / fs), amp
