"""Amplitude spectra of sampled signals."""

from __future__ import annotations

import numpy as np


def periodic_hann(n: int) -> np.ndarray:
    """The periodic Hann window of ``n`` samples, 0.5 - 0.5 cos(2 pi k / n) (scipy's
    ``get_window("hann", n)``, without importing scipy.signal: 1.1 s in every process that does,
    the recorder and each command that estimates a spectrum or a frequency response)."""
    return 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n) / n)


def _window(n: int, fs: float, window: str) -> np.ndarray:
    """The ``window`` of ``n`` samples, after checking there are two and ``fs`` (Hz) is above 0."""
    if n < 2:
        raise ValueError("x must be a 1-D signal of at least 2 samples")
    if not fs > 0:
        raise ValueError(f"fs must be > 0 Hz, got {fs}")
    if window == "hann":  # the recorder characterises a rotor drop's whirl with it (analysis.touchdown)
        return periodic_hann(n)
    from scipy.signal import get_window

    return get_window(window, n)


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
    if x.ndim != 1:
        raise ValueError("x must be a 1-D signal of at least 2 samples")
    w = _window(x.shape[0], fs, window)
    spec = np.fft.rfft((x - x.mean()) * w)
    amp = 2.0 * np.abs(spec) / w.sum()
    amp[0] /= 2.0
    return np.fft.rfftfreq(x.shape[0], 1.0 / fs), amp


def full_spectrum(x: np.ndarray, y: np.ndarray, *, fs: float, window: str = "hann") -> tuple[np.ndarray, np.ndarray]:
    """Full (two-sided) spectrum of an orbit: the spectrum of ``x + j y``, whose positive
    frequencies are forward whirl (in the direction x turns towards y) and negative ones backward
    whirl, scaled so a circular orbit of radius R whirling at ``f`` shows a peak of R at ``f``
    (Bently Nevada's full spectrum; an elliptical orbit is a forward and a backward circle, its
    semi-axes their sum and difference).

    Parameters
    ----------
    x, y : ndarray, shape (n,)
        The bearing's two orthogonal gap signals, any unit (the same); their means are removed.
    fs : float
        Sample rate, in Hz.
    window : str
        Window name for :func:`scipy.signal.get_window`.

    Returns
    -------
    f : ndarray
        Frequencies, in Hz, from -fs/2 to below fs/2, increasing.
    amplitude : ndarray
        Radius of the circle whirling at each frequency, in the unit of ``x``.

    Examples
    --------
    >>> t = np.arange(10000) / 10000.0
    >>> f, a = full_spectrum(2.0 * np.cos(2 * np.pi * 50 * t), 2.0 * np.sin(2 * np.pi * 50 * t), fs=10000.0)
    >>> float(f[np.argmax(a)]), round(float(a.max()), 2)
    (50.0, 2.0)
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        raise ValueError("x and y must be 1-D signals of the same length, at least 2 samples")
    w = _window(x.shape[0], fs, window)
    z = (x - x.mean()) + 1j * (y - y.mean())
    spec = np.fft.fftshift(np.fft.fft(z * w))
    return np.fft.fftshift(np.fft.fftfreq(x.shape[0], 1.0 / fs)), np.abs(spec) / w.sum()
