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

from .spectrum import periodic_hann


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
    error : ndarray of complex, shape (n, outputs, outputs)
        The covariance of the responses' complex errors, E[dH dH^H] (its diagonal is each
        response's error variance, E|dH|^2), in the outputs' unit per the input's, squared.
    """

    freq_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    segments: int
    error: np.ndarray


def h1_estimate(x: np.ndarray, y: np.ndarray, *, fs: float, resolution_hz: float) -> H1Estimate:
    """H1 frequency response and coherence from input ``x`` to outputs ``y`` (Welch, Hann, 50% overlap),
    with the covariance of the responses' errors.

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
    x = np.asarray(x, dtype=float)
    y2 = np.asarray(y, dtype=float).reshape(x.shape[0], -1)
    nperseg = int(round(fs / resolution_hz))
    if not 8 <= nperseg <= x.shape[0]:
        raise ValueError(f"a {resolution_hz:g} Hz resolution needs segments of {nperseg} samples; "
                         f"the signal has {x.shape[0]}")
    step = nperseg - nperseg // 2
    segments = 1 + (x.shape[0] - nperseg) // step
    window = periodic_hann(nperseg)  # periodic, as scipy's welch uses it
    starts = np.arange(segments) * step

    def spectra(s):  # (segments, n_freq, channels): each segment's mean removed, windowed, transformed
        frames = np.stack([s[k : k + nperseg] for k in starts])
        frames = frames - frames.mean(axis=1, keepdims=True)
        return np.fft.rfft(frames * window.reshape(1, -1, *([1] * (s.ndim - 1))), axis=1)[:, 1:]  # DC carries nothing

    xs, ys = spectra(x), spectra(y2)
    sxx = np.sum(np.abs(xs) ** 2, axis=0)
    sxy = np.einsum("kf,kfo->fo", xs.conj(), ys)
    syy = np.sum(np.abs(ys) ** 2, axis=0)
    h = sxy / sxx[:, None]
    # an output with no power at a frequency (a channel that stays at zero) is explained by nothing:
    # coherence 0, never trusted, rather than 0/0
    power = sxx[:, None] * syy
    coh = np.divide(np.abs(sxy) ** 2, power, out=np.zeros_like(power), where=power > 0)
    # the error of H1 is sum_k V_k X_k* / sum_k |X_k|^2, V the output the input does not explain
    # (Bendat & Piersol, Random Data, section 9.2.3); its covariance across outputs is the residuals'
    # cross-spectral matrix over sum |X_k|^2, the residuals losing one degree of freedom to H, and
    # neighbouring segments sharing half their samples correlate by c^2 (Welch 1967, c the window's
    # overlap correlation: 1/6 for Hann at 50 %)
    v = ys - h[None] * xs[:, :, None]
    c = float(window[step:] @ window[: nperseg - step] / (window @ window))
    overlap = 1.0 + 2.0 * c**2 * (segments - 1) / segments
    cov = np.einsum("kfa,kfb->fab", v, v.conj()) / max(segments - 1, 1) * overlap / sxx[:, None, None]
    f = np.fft.rfftfreq(nperseg, 1.0 / fs)[1:]
    return H1Estimate(f, h, coh, segments, cov)


def window_kernel(resolution_hz: float, fs: float, *, sub: int = 16, half: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`h1_estimate`'s window does to a response: with a white input, the H1 at f is
    the true response averaged over the frequencies around f, weighted by the Hann window's power
    spectrum, E[H1(f)] = sum_m K_m H(f + nu_m) (the expected cross-spectrum over the expected
    auto-spectrum: the resolution bias of a smoothed spectral estimate, Bendat & Piersol,
    Random Data, chapter 8).  A lightly
    damped mode narrower than a few frequency steps is broadened by it: its damping reads high.

    Parameters
    ----------
    resolution_hz : float
        The estimate's frequency step, Hz.
    fs : float
        Sample rate, Hz.
    sub : int
        Points per frequency step the kernel is sampled at.
    half : int
        Frequency steps on either side kept (the Hann window's power four steps out is below 1e-4
        of its peak).

    Returns
    -------
    offsets_hz, weights : ndarray, shape (2 half sub + 1,)
        nu_m (Hz) and K_m (summing to 1).
    """
    n = int(round(fs / resolution_hz))
    power = np.abs(np.fft.fft(periodic_hann(n), n * sub)) ** 2
    m = np.arange(-half * sub, half * sub + 1)
    k = power[m % (n * sub)]
    return m * resolution_hz / sub, k / k.sum()


def interpolate_response(freq_hz: np.ndarray, response: np.ndarray, at_hz: np.ndarray) -> np.ndarray:
    """A measured response (of a real system) between its frequencies: linear in the real and the
    imaginary parts, H(-f) = H(f)^* below 0 Hz, the nearest end elsewhere outside.

    Parameters
    ----------
    freq_hz : ndarray, shape (n,)
        The measurement's frequencies, Hz, rising.
    response : ndarray of complex, shape (n, ...)
    at_hz : ndarray, shape (m,)
        Where, Hz.

    Returns
    -------
    ndarray of complex, shape (m, ...)
    """
    flat = response.reshape(response.shape[0], -1)
    where = np.abs(at_hz)
    out = np.empty((at_hz.size, flat.shape[1]), dtype=complex)
    for col in range(flat.shape[1]):
        out[:, col] = np.interp(where, freq_hz, flat[:, col].real) + 1j * np.interp(where, freq_hz, flat[:, col].imag)
    out[at_hz < 0] = out[at_hz < 0].conj()
    return out.reshape((at_hz.size,) + response.shape[1:])


NEIGHBOUR_CORRELATION = 4.0 / 9.0
"""The correlation of an H1 estimate's errors at neighbouring frequencies with the Hann window
(:func:`h1_estimate`): |sum w^2 e^{-2 pi j n / N}|^2 / (sum w^2)^2 = (2/3)^2; measured on the
flexible rotor's plant 0.34-0.46 (two frequencies apart about 0.05, taken as 0)."""

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
