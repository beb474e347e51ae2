"""ISO 14839 evaluations: zones, the stability margin from a measured sensitivity function (part 3),
rotor displacement against the minimum clearance (part 2).

Part 3 grades an AMB loop's stability margin by the peak of its sensitivity function
``Gs = Vout / Vin``, measured with an excitation ``Vin`` added at the sensor summing point and
``Vout`` the signal just after it (what the controller sees).  With the open loop ``Go`` (plant
and controller around the loop) the standard's three loop functions are

    Gs = 1 / (1 + Go),    Gc = Go / (1 + Go) = 1 - Gs,    Go = Gc / Gs,

so one measurement gives all three.  ambdaq's controllers add the test signal ``x`` to the
feedforward, and the command error is ``e = s - (r_c + x)`` (docs/frf.md): the signal after the
summing point in the standard's sign is ``x - s = -e``, hence ``Gs = -e / x``.

The zone limits are options; the defaults are the commonly cited ones (ISO 14839-3 annex: peak
sensitivity 3, 4 and 5, i.e. 9.5, 12 and 14 dB; ISO 14839-2: 0.3, 0.4 and 0.5 of the minimum
clearance Cmin), see docs/iso.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ZONES = ("A", "B", "C", "D")


@dataclass(frozen=True)
class ZoneLimits:
    """The three zone boundaries A/B, B/C and C/D, increasing (a value on a boundary is in the
    higher zone's side: zone A is ``value < ab``).

    Parameters
    ----------
    ab, bc, cd : float
        Boundaries, in the graded quantity's unit (peak |Gs|, or displacement per Cmin).
    """

    ab: float
    bc: float
    cd: float

    def __post_init__(self) -> None:
        if not (np.isfinite([self.ab, self.bc, self.cd]).all() and 0 < self.ab < self.bc < self.cd):
            raise ValueError(f"zone limits must be finite, above 0 and increasing, not {self.ab:g}, {self.bc:g}, {self.cd:g}")

    def zone(self, value: float) -> str:
        """``A`` .. ``D`` for ``value``."""
        return ZONES[int(np.searchsorted([self.ab, self.bc, self.cd], value, side="right"))]

    def as_list(self) -> list[float]:
        return [self.ab, self.bc, self.cd]


STABILITY_LIMITS = ZoneLimits(3.0, 4.0, 5.0)
"""Peak sensitivity |Gs| at the A/B, B/C and C/D boundaries (9.5, 12.0 and 14.0 dB), ISO 14839-3."""

VIBRATION_LIMITS = ZoneLimits(0.3, 0.4, 0.5)
"""Rotor displacement per minimum clearance Cmin at the A/B, B/C and C/D boundaries, ISO 14839-2."""


def db(gain: np.ndarray | float) -> np.ndarray | float:
    """20 log10 of a gain."""
    return 20.0 * np.log10(gain)


def sensitivity(h_error_per_input: np.ndarray) -> np.ndarray:
    """ISO 14839-3's sensitivity function from the measured response of the command error to the
    test signal (``e / x``, the H1 estimate of ``frf``): ``Gs = -e/x`` (the module docstring).

    Parameters
    ----------
    h_error_per_input : ndarray of complex
        ``e / x`` at each frequency, in m/m (or V/V).
    """
    return -np.asarray(h_error_per_input)


def closed_and_open_loop(gs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closed-loop ``Gc = 1 - Gs`` and open-loop ``Go = Gc / Gs`` functions of a sensitivity
    function ``gs`` (dimensionless, complex); ``Go`` is infinite where ``Gs`` is 0."""
    gc = 1.0 - np.asarray(gs)
    with np.errstate(divide="ignore", invalid="ignore"):
        return gc, gc / gs


def model_sensitivity(M: np.ndarray, B: np.ndarray, C: np.ndarray, h: float, freq_hz: np.ndarray) -> np.ndarray:
    """The sensitivity function ``Gs`` of each axis of a discrete loop with the feedforward as its
    input, ``x[n+1] = M x + B r_c``, ``e = C x - r_c`` (the simulated spindle's linearisation,
    ``SpindleRig.loop_matrices``): ``Gs = -e/r_c = 1 - diag(C (zI - M)^-1 B)``.

    Parameters
    ----------
    M, B, C : ndarray
        Loop matrices, shapes (n, n), (n, axes), (axes, n).
    h : float
        Sample period, in s.
    freq_hz : ndarray
        Frequencies, in Hz.

    Returns
    -------
    ndarray of complex, shape (axes, len(freq_hz))
    """
    eye = np.eye(M.shape[0])
    out = [1.0 - np.diag(C @ np.linalg.solve(np.exp(2j * np.pi * f * h) * eye - M, B)) for f in np.asarray(freq_hz, float)]
    return np.array(out).T


def model_sensitivity_peaks(M: np.ndarray, B: np.ndarray, C: np.ndarray, h: float,
                            band_hz: tuple[float, float], points: int = 700) -> tuple[float, np.ndarray, np.ndarray]:
    """Each axis's peak |Gs| over ``band_hz`` of the loop :func:`model_sensitivity` takes, and the
    largest pole's modulus; fast enough to search a design with (one eigen-decomposition per loop).

    With M = V diag(lambda) V^-1, ``Gs_aa(z) = 1 - sum_i (C V)_ai (V^-1 B)_ia / (z - lambda_i)``: the
    log-spaced grid (``points`` frequencies) with every pole's own frequency added, so a lightly
    damped mode's peak, narrower than the grid's step, is not stepped over.

    Parameters
    ----------
    M, B, C : ndarray
        Loop matrices, shapes (n, n), (n, axes), (axes, n).
    h : float
        Sample period, in s.
    band_hz : (float, float)
        The band graded, Hz (ISO 14839-3: the loop's whole operating band).
    points : int
        Grid frequencies before the poles' own are added.

    Returns
    -------
    radius : float
        The largest pole's modulus: the loop is stable where it is below 1.
    peak : ndarray, shape (axes,)
        Peak |Gs| per axis (a ratio; :func:`db` for dB); NaN where the loop is not stable.
    at_hz : ndarray, shape (axes,)
        Where each peak is, Hz.
    """
    lam, V = np.linalg.eig(M)
    radius = float(np.abs(lam).max())
    axes = C.shape[0]
    if radius >= 1.0:
        return radius, np.full(axes, np.nan), np.full(axes, np.nan)
    lo, hi = band_hz
    own = np.abs(np.angle(lam)) / (2 * np.pi * h)
    f = np.concatenate([np.geomspace(lo, hi, points), own[(own > lo) & (own < hi)]])
    z = np.exp(2j * np.pi * f * h)
    try:
        # each pole's residue in each axis's C (zI - M)^-1 B, (n, axes); with repeated poles (alike
        # axes) the eigenvectors may be nearly dependent and the sum loses digits: the peaks it finds
        # are solved directly at their frequencies, and where they differ by 1e-6 every frequency is
        # solved directly (50 times slower)
        residue = (C @ V).T * np.linalg.solve(V, B)
        gain = np.abs(1.0 - (residue[None] / (z[:, None, None] - lam[None, :, None])).sum(axis=1))
        at = gain.argmax(axis=0)
        check = np.abs(model_sensitivity(M, B, C, h, f[at]))[np.arange(len(at)), np.arange(len(at))]
        if not np.allclose(gain[at, np.arange(len(at))], check, rtol=1e-6, atol=0.0):
            raise np.linalg.LinAlgError("the eigen-decomposition lost digits")
    except np.linalg.LinAlgError:
        gain = np.abs(model_sensitivity(M, B, C, h, f)).T
    at = gain.argmax(axis=0)
    return radius, gain[at, np.arange(axes)], f[at]


def magnitude_upper_bound(gain: np.ndarray, coherence: np.ndarray, segments: int) -> np.ndarray:
    """A 95 % upper bound of the true |H| at each point of an H1 estimate: the estimate plus two of
    its normalised random errors, ``eps = sqrt(1 - g2) / (sqrt(g2) sqrt(2 n))`` (Bendat and Piersol,
    Random Data, eq. 9.90; ``g2`` the coherence, ``n`` the averaged segments).  Where the
    coherence is so low that this is meaningless (eps > 0.5) the bound is infinite.

    Parameters
    ----------
    gain : ndarray
        Estimated |H|, any unit.
    coherence : ndarray
        Magnitude-squared coherence, 0 .. 1.
    segments : int
        Number of averaged segments.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 1e-12, 1.0)
    eps = np.sqrt(1.0 - g2) / (np.sqrt(g2) * np.sqrt(2.0 * segments))
    return np.where(eps > 0.5, np.inf, np.asarray(gain) * (1.0 + 2.0 * eps))


@dataclass(frozen=True)
class StabilityGrade:
    """The ISO 14839-3 evaluation of one axis at one speed.

    Attributes
    ----------
    peak : float
        Peak |Gs| over the band (dimensionless); NaN if the band holds no point.
    peak_hz : float
        Its frequency, in Hz.
    coherence_at_peak : float
        The coherence there, 0 .. 1.
    band_hz : tuple of float
        The band searched, in Hz.
    zone : str or None
        ``A`` .. ``D``; None when the data cannot support a grade (``reason`` says why).
    reason : str
        Why there is no grade, or ''.
    """

    peak: float
    peak_hz: float
    coherence_at_peak: float
    band_hz: tuple[float, float]
    zone: str | None
    reason: str = ""

    @property
    def peak_db(self) -> float:
        return float(db(self.peak))


def grade_stability(freq_hz: np.ndarray, gs: np.ndarray, coherence: np.ndarray, segments: int, *,
                    band_hz: tuple[float, float] | None = None, limits: ZoneLimits = STABILITY_LIMITS,
                    min_coherence: float = 0.9) -> StabilityGrade:
    """Peak |Gs| over ``band_hz`` and its ISO 14839-3 zone, if the measurement supports one.

    A grade is given only if the coherence at the peak is at least ``min_coherence`` and no poorly
    measured point of the band could hide a higher peak: at every point whose coherence is below
    ``min_coherence`` the 95 % upper bound of |Gs| (:func:`magnitude_upper_bound`) must stay below
    the peak found.  Points where the excitation explains little of the output because |Gs| is
    small there (low frequencies) pass that test; a resonance drowned in noise does not.

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies, in Hz, increasing.
    gs : ndarray of complex
        Sensitivity function at ``freq_hz`` (dimensionless).
    coherence : ndarray
        Coherence of the measurement at ``freq_hz``, 0 .. 1.
    segments : int
        Number of averaged segments of the estimate.
    band_hz : (float, float), optional
        Band searched, in Hz; default: every measured frequency.
    limits : ZoneLimits
        Peak |Gs| at the zone boundaries.
    min_coherence : float
        Least coherence at the peak for a grade, 0 .. 1.
    """
    freq_hz = np.asarray(freq_hz, dtype=float)
    lo, hi = (float(freq_hz[0]), float(freq_hz[-1])) if band_hz is None else (float(band_hz[0]), float(band_hz[1]))
    inside = (freq_hz >= lo) & (freq_hz <= hi)
    if not inside.any():
        return StabilityGrade(float("nan"), float("nan"), float("nan"), (lo, hi), None,
                              f"no measured frequency within {lo:g}-{hi:g} Hz")
    gain = np.abs(np.asarray(gs))
    at = int(np.argmax(np.where(inside, gain, -np.inf)))
    peak, coh = float(gain[at]), float(coherence[at])
    result = dict(peak=peak, peak_hz=float(freq_hz[at]), coherence_at_peak=coh, band_hz=(lo, hi))
    if coh < min_coherence:
        return StabilityGrade(**result, zone=None,
                              reason=f"coherence {coh:.3f} at the peak ({freq_hz[at]:g} Hz) is below {min_coherence:g}: "
                                     "excite with a larger amplitude or for longer")
    bound = magnitude_upper_bound(gain, coherence, segments)
    hidden = inside & (np.asarray(coherence) < min_coherence) & (bound > peak)
    if hidden.any():
        worst = int(np.flatnonzero(hidden)[np.argmin(np.asarray(coherence)[hidden])])
        return StabilityGrade(**result, zone=None,
                              reason=f"at {freq_hz[worst]:g} Hz the coherence is {coherence[worst]:.3f}: a higher peak "
                                     "could hide there; excite with a larger amplitude or for longer, or narrow --band")
    return StabilityGrade(**result, zone=limits.zone(peak))


__all__ = ["STABILITY_LIMITS", "VIBRATION_LIMITS", "ZONES", "StabilityGrade", "ZoneLimits", "db", "model_sensitivity_peaks",
           "closed_and_open_loop", "grade_stability", "magnitude_upper_bound", "model_sensitivity", "sensitivity"]
