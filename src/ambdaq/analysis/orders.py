"""Order tracking on the key-phasor angle: the 1X (and NX) vector of a signal against speed through
a run-up or a coast-down, its peaks and critical speeds, and the modes a loop model predicts
(Campbell).

A machinery engineer reads a run-up as Bently-style plots: the 1X vector's amplitude and phase
against speed (Bode) and the vector itself (polar), with the slow-roll vector taken out, and a
waterfall of spectra against speed with the order lines.  Here each vector is the least-squares
fit of ``a sin k theta + b cos k theta`` over a window of whole revolutions (the convention of
:mod:`.runout`: the phasor ``a + j b`` of ``R sin(k theta + phi)`` is ``R exp(j phi)``, the phase
measured from the key-phasor mark).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .runout import harmonic_fit

CRITICAL_AMPLIFICATION = 2.5
"""API 684: a mode amplified less than this (half-power method) is critically damped: not a
critical speed that needs a separation margin."""


@dataclass(frozen=True)
class OrderTrack:
    """Vectors of some orders of one or more signals, per window of whole revolutions.

    Attributes
    ----------
    rpm : ndarray, shape (w,)
        Mean speed of each window, in rpm.
    orders : tuple of int
        The orders (1 = 1X).
    vectors : ndarray of complex, shape (w, len(orders), signals)
        ``R exp(j phi)`` per window, order and signal, in the signals' unit.
    """

    rpm: np.ndarray
    orders: tuple[int, ...]
    vectors: np.ndarray

    def order(self, k: int) -> np.ndarray:
        """The vectors of order ``k``, shape (w, signals)."""
        return self.vectors[:, self.orders.index(k), :]

    def compensated(self, reference: np.ndarray) -> "OrderTrack":
        """This track with a reference vector per order and signal taken out (slow-roll compensation).

        Parameters
        ----------
        reference : ndarray of complex, shape (len(orders), signals)
            In the signals' unit.
        """
        return OrderTrack(self.rpm, self.orders, self.vectors - reference[None, :, :])


def phase_lag_deg(vector: np.ndarray) -> np.ndarray:
    """A vector's phase as engineers read it against speed: the lag behind the key-phasor.

    One convention for the run-up's table, its JSON and its Bode plot: the lag is ``-phi`` of
    ``R exp(j phi)``, in degrees, unwrapped along the run (it grows through each critical speed
    instead of jumping at +-180) and starting within 0..360.

    Parameters
    ----------
    vector : ndarray of complex, shape (w,)
        One order's vector per window along the run, in any unit.

    Returns
    -------
    ndarray, shape (w,)
        The lag, in degrees.
    """
    lag = -np.degrees(np.unwrap(np.angle(vector)))
    return lag - 360.0 * np.floor(lag[0] / 360.0) if lag.size else lag


def order_track(x: np.ndarray, theta: np.ndarray, speed_rpm: np.ndarray, *, orders=(1, 2), revolutions: int = 8,
                min_rpm: float = 60.0) -> OrderTrack:
    """Track the vectors of ``orders`` over windows of ``revolutions`` whole revolutions.

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, signals)
        Signals, any unit (gap sensors, in m).
    theta : ndarray, shape (n,)
        Key-phasor angle at each sample, in rad (wrapped or not).
    speed_rpm : ndarray, shape (n,)
        Speed at each sample, in rpm.
    orders : sequence of int
        Orders to track (1 = 1X).
    revolutions : int
        Revolutions per window: more averages noise away, fewer follow a fast ramp (8 at 5,000 rpm/s
        spans 96 rpm at 50,000 rpm).
    min_rpm : float
        Windows slower than this (in rpm; a rotor at rest has no revolutions to fit) are left out.

    Returns
    -------
    OrderTrack
    """
    x2 = np.asarray(x, dtype=float).reshape(len(theta), -1)
    turns = np.unwrap(np.asarray(theta, dtype=float)) / (2 * np.pi)
    turns -= turns[0]
    edges = np.searchsorted(turns, np.arange(0.0, turns[-1], revolutions))
    rpm, vecs = [], []
    for s, e in zip(edges[:-1], edges[1:]):
        if e - s < 4 * (2 * max(orders) + 1):  # too few samples per window to fit its orders
            continue
        speed = float(np.mean(speed_rpm[s:e]))
        if speed < min_rpm:
            continue
        rpm.append(speed)
        vecs.append(harmonic_fit(x2[s:e], theta[s:e], tuple(orders)).reshape(len(orders), -1))
    if not rpm:
        raise ValueError(f"no window of {revolutions} revolutions above {min_rpm:g} rpm")
    return OrderTrack(np.array(rpm), tuple(orders), np.array(vecs))


@dataclass(frozen=True)
class OneXPeak:
    """A peak of the 1X amplitude against speed, with its half-power band inside the run.

    Attributes
    ----------
    rpm : float
        Speed of the peak, in rpm.
    amplitude : float
        1X amplitude there, in the signal's unit.
    band_rpm : tuple of float
        The half-power band (amplitude above peak / sqrt 2), in rpm: each edge interpolated
        linearly between the two windows around it.
    phase_change_deg : float
        Phase change across that band, in degrees.
    amplification : float
        The peak's speed over the band's width, ``rpm / (high - low)``: the amplification factor
        of the half-power method (API 684).
    """

    rpm: float
    amplitude: float
    band_rpm: tuple[float, float]
    phase_change_deg: float
    amplification: float

    def is_critical(self, min_amplification: float = CRITICAL_AMPLIFICATION) -> bool:
        """A critical speed: amplified at least ``min_amplification`` (API 684 calls a mode with
        less critically damped) with the phase turning through the band, as at a resonance."""
        return self.amplification >= min_amplification and self.phase_change_deg >= 60.0


def one_x_peaks(rpm: np.ndarray, vector: np.ndarray, *, significance: float = 5.0) -> list[OneXPeak]:
    """Every local peak of ``|vector|`` against speed whose half-power band lies inside the run and
    that stands out of the estimate's scatter: the peak's rise above its half-power level must be at
    least ``significance`` times the window-to-window scatter of the vector (the median of
    ``|v[i+1] - v[i]| / sqrt 2`` over the run: a true vector changes little from one window to the
    next, so this is the estimate's noise).  A 1X that is only sensor noise has peaks everywhere,
    none of them significant.

    Parameters
    ----------
    rpm : ndarray, shape (w,)
        Speed per window, in rpm (a run-up or a coast-down; sorted here).
    vector : ndarray of complex, shape (w,)
        1X vector per window, any unit.
    significance : float
        Least rise of a peak above its half-power level, in units of the scatter.
    """
    order = np.argsort(rpm)
    r, v = np.asarray(rpm)[order], np.asarray(vector)[order]
    amp = np.abs(v)
    scatter = float(np.median(np.abs(np.diff(v)))) / np.sqrt(2.0) if v.shape[0] > 1 else 0.0
    phase = np.degrees(np.unwrap(np.angle(v)))
    peaks = []
    for i in range(1, amp.shape[0] - 1):
        if not (amp[i] >= amp[i - 1] and amp[i] > amp[i + 1]):
            continue
        half = amp[i] / np.sqrt(2.0)
        if amp[i] - half < significance * scatter:
            continue
        below = np.flatnonzero(amp[:i] <= half)
        above = np.flatnonzero(amp[i + 1:] <= half)
        if below.size == 0 or above.size == 0:  # a hump wider than the run: no half-power band here
            continue
        lo, hi = int(below[-1]), i + 1 + int(above[0])
        if np.any(amp[lo:hi + 1] > amp[i]):  # a higher peak inside: this one is its shoulder
            continue
        # each edge where the amplitude crosses the half-power level, linear between the two windows
        # around it (the windows alone would place it up to one window's speed step outside)
        low = _crossing(r[lo], r[lo + 1], amp[lo], amp[lo + 1], half)
        high = _crossing(r[hi - 1], r[hi], amp[hi - 1], amp[hi], half)
        peaks.append(OneXPeak(float(r[i]), float(amp[i]), (low, high), float(abs(phase[hi] - phase[lo])),
                              float(r[i] / max(high - low, 1e-9))))
    return peaks


def _crossing(r0: float, r1: float, a0: float, a1: float, level: float) -> float:
    """The speed (rpm) between ``r0`` and ``r1`` where the amplitude, ``a0`` and ``a1`` there, crosses
    ``level``, taken linear between them."""
    return float(r0 + (level - a0) / (a1 - a0) * (r1 - r0)) if a1 != a0 else float(r0)


SPEED_TOLERANCE = 0.05
"""A measured critical speed agrees with a predicted one within 5 % of it (the acceptance the
machinery practice of API 684 applies to a run-up against the rotordynamic model)."""

AMPLIFICATION_TOLERANCE = 0.05
"""A measured amplification factor is "no more than predicted" up to 5 % above it.  It rests on two
half-power edges read off a run-up, which sweeps through the mode instead of dwelling on it: the
simulated spindle with D halved measures 4.03 where its model's steady response gives 4.025, on
the true rotor as on the gap.  5 %, the tolerance the speed has, keeps a run that reproduces its
model from failing on that, and fails one a tenth more amplified (AF 4.4 against 4.0)."""


@dataclass(frozen=True)
class PredictedCritical:
    """Where a model's mode meets an order line: a critical speed the model predicts.

    Attributes
    ----------
    rpm : float
        The speed at which the mode's frequency equals ``order`` times the speed, in rpm.
    frequency_hz : float
        The mode's frequency there, in Hz.
    damping : float
        Its damping ratio there.
    amplification : float
        The amplification factor it predicts: ``1 / (2 zeta)``, a single mode's half-power factor;
        or, from :func:`from_response`, the half-power factor of the model's own 1X response.
    whirl : int
        +1 forward, 0 not known (planar or not given by the model).
    order : int
        The order line (1: 1X, the unbalance response).
    amplification_from : str
        ``"damping"`` (``1 / (2 zeta)``) or ``"response"`` (the model's 1X response).
    """

    rpm: float
    frequency_hz: float
    damping: float
    amplification: float
    whirl: int
    order: int = 1
    amplification_from: str = "damping"


def predicted_criticals(rpm: np.ndarray, freq_hz: np.ndarray, damping: np.ndarray, whirl: np.ndarray, *,
                        order: int = 1) -> list[PredictedCritical]:
    """The speeds where a model's modes cross the ``order`` line of a Campbell diagram.

    An unbalance drives forward whirl: where the model marks whirl, only a forward mode is taken
    (not a backward one, nor one with no whirl at the bearings, such as an axial mode); a model
    that marks none has each of its modes taken. The crossing is interpolated linearly between the
    two speeds it lies between.

    Parameters
    ----------
    rpm : ndarray, shape (s,)
        Speeds the modes were computed at, ascending, in rpm.
    freq_hz, damping : ndarray, shape (s, m)
        Each mode's frequency (Hz, NaN where absent) and damping ratio at each speed.
    whirl : ndarray of int, shape (s, m)
        +1 forward, -1 backward, 0 not known.
    order : int
        The order line.
    """
    out = []
    line = order * rpm / 60.0
    marked = bool(np.any(whirl != 0))
    for m in range(freq_hz.shape[1]):
        gap = freq_hz[:, m] - line
        for i in range(rpm.shape[0] - 1):
            a, b = gap[i], gap[i + 1]
            if not (np.isfinite(a) and np.isfinite(b)) or a * b > 0 or a == b:
                continue
            if marked and 1 not in (whirl[i, m], whirl[i + 1, m]):
                continue
            w = a / (a - b)  # where the gap is zero, between the two speeds
            zeta = float(damping[i, m] + w * (damping[i + 1, m] - damping[i, m]))
            speed = float(rpm[i] + w * (rpm[i + 1] - rpm[i]))
            out.append(PredictedCritical(speed, order * speed / 60.0, zeta, 1.0 / (2.0 * max(zeta, 1e-9)),
                                         int(max(whirl[i, m], whirl[i + 1, m])), order))
    return sorted(out, key=lambda c: c.rpm)


def from_response(predicted: list[PredictedCritical], rpm: np.ndarray, response: dict[str, np.ndarray], *,
                  tolerance: float = SPEED_TOLERANCE) -> list[PredictedCritical]:
    """Each 1X critical speed's amplification from the model's own 1X response where that shows
    the mode: the most amplified half-power peak (:func:`one_x_peaks`, the method the run is
    measured by) of any axis's response within ``tolerance`` of the crossing (API 684's unbalance
    response analysis); the others keep ``1 / (2 zeta)``.  ``1 / (2 zeta)`` is a single mode's
    factor: a loop's 1X response can be sharper or broader (the neighbouring modes, the forcing
    growing with the speed squared, the controller's damping changing with frequency; the
    spindle's loop with D halved: 4.03 in its response against 3.81).

    Parameters
    ----------
    predicted : list of PredictedCritical
    rpm : ndarray, shape (s,)
        Speeds the response was computed at, ascending, in rpm.
    response : dict of str to ndarray of complex, shape (s,)
        The model's 1X per axis at those speeds, any unit.
    tolerance : float
        The relative speed difference within which a response peak is the mode's.
    """
    peaks = [k for v in response.values() for k in one_x_peaks(rpm, v)]
    out = []
    for p in predicted:
        near = [k.amplification for k in peaks if abs(k.rpm - p.rpm) <= tolerance * p.rpm] if p.order == 1 else []
        out.append(replace(p, amplification=max(near), amplification_from="response") if near else p)
    return out


def separation_margin(amplification: float) -> tuple[float, float]:
    """The separation margin a critical speed needs from the operating range (API 617's rule, as
    API 684 explains it): none below an amplification factor of 2.5 (critically damped); 5 % below
    the minimum operating speed and 15 % above the maximum continuous speed up to 3.55; above that
    16 - 6/(AF - 3) % below and 26 - 6/(AF - 3) % above (continuous at 3.55).

    Parameters
    ----------
    amplification : float
        The mode's amplification factor (half-power), dimensionless.

    Returns
    -------
    (float, float)
        The margins below the minimum operating speed and above the maximum continuous speed, as
        fractions of those speeds.
    """
    if amplification < CRITICAL_AMPLIFICATION:
        return 0.0, 0.0
    if amplification <= 3.55:
        return 0.05, 0.15
    step = 6.0 / (amplification - 3.0)
    return (16.0 - step) / 100.0, (26.0 - step) / 100.0


@dataclass(frozen=True)
class Margin:
    """A critical speed's separation from the operating range against what API 617 asks.

    Attributes
    ----------
    rpm : float
        The critical speed taken (the measured one where measured, else the predicted), rpm.
    amplification : float
        Its amplification factor (measured where measured).
    actual : float
        Its distance from the operating range, as a fraction of the range's nearer end (below the
        minimum speed: of the minimum; above the maximum: of the maximum); negative inside it.
    required : float
        What :func:`separation_margin` asks on that side.
    """

    rpm: float
    amplification: float
    actual: float
    required: float

    @property
    def passed(self) -> bool:
        """Far enough from the operating range (a critically damped mode needs no margin)."""
        return self.required == 0.0 or self.actual >= self.required


def margin_from(rpm: float, amplification: float, operating_rpm: tuple[float, float]) -> Margin:
    """A critical speed's :class:`Margin` from the operating range ``operating_rpm`` (minimum
    operating speed, maximum continuous speed; rpm)."""
    lo, hi = operating_rpm
    below, above = separation_margin(amplification)
    if rpm <= lo:
        return Margin(rpm, amplification, (lo - rpm) / lo, below)
    if rpm >= hi:
        return Margin(rpm, amplification, (rpm - hi) / hi, above)
    inside = -min(rpm - lo, hi - rpm) / (lo if rpm - lo < hi - rpm else hi)
    return Margin(rpm, amplification, inside, below if rpm - lo < hi - rpm else above)


@dataclass(frozen=True)
class CriticalCheck:
    """A predicted critical speed against what the run-up measured, or a measured one the model
    does not predict.

    Attributes
    ----------
    predicted : PredictedCritical or None
    measured : OneXPeak or None
        The measured 1X peak within ``SPEED_TOLERANCE`` of the prediction (the most amplified), on
        ``axis``.
    axis : str or None
    passed : bool
    rule : str
        What was applied, in words, with its source.
    margin : Margin or None
        Its separation from the operating range, where one was given.
    """

    predicted: PredictedCritical | None
    measured: "OneXPeak | None"
    axis: str | None
    passed: bool
    rule: str
    margin: Margin | None = None

    def as_dict(self) -> dict:
        """As ``runup --json`` and the report give it: speeds to 0.1 rpm, factors to 0.01."""
        p, m = self.predicted, self.measured
        return {"predicted_rpm": None if p is None else round(p.rpm, 1),
                "predicted_hz": None if p is None else round(p.frequency_hz, 2),
                "predicted_amplification": None if p is None else round(p.amplification, 2),
                "predicted_amplification_from": None if p is None else p.amplification_from,
                "whirl": None if p is None or p.whirl <= 0 else "forward",
                "measured_rpm": None if m is None else round(m.rpm, 1), "axis": self.axis,
                "measured_amplification": None if m is None else round(m.amplification, 2),
                "deviation": None if p is None or m is None else round((m.rpm - p.rpm) / p.rpm, 4),
                "margin": None if self.margin is None else round(self.margin.actual, 4),
                "margin_required": None if self.margin is None else round(self.margin.required, 4),
                "passed": self.passed, "rule": self.rule}


@dataclass(frozen=True)
class CriticalLimits:
    """The limits a run-up's critical speeds are verified by (``runup`` and ``report`` options).

    Attributes
    ----------
    speed : float
        A measured critical speed is the predicted one within this share of its speed
        (:data:`SPEED_TOLERANCE`, API 684's 5 %).
    amplification : float
        How much more amplified than predicted, as a share, a measured one may be
        (:data:`AMPLIFICATION_TOLERANCE`).
    critically_damped : float
        The amplification factor below which a mode is critically damped
        (:data:`CRITICAL_AMPLIFICATION`, API 684's 2.5).
    """

    speed: float = SPEED_TOLERANCE
    amplification: float = AMPLIFICATION_TOLERANCE
    critically_damped: float = CRITICAL_AMPLIFICATION


def verify_criticals(predicted: list[PredictedCritical], peaks: dict[str, list["OneXPeak"]], rpm_range: tuple[float, float],
                     *, limits: CriticalLimits = CriticalLimits(),
                     operating_rpm: tuple[float, float] | None = None) -> list[CriticalCheck]:
    """Each predicted critical speed inside the run against the 1X peaks it measured (API 684).

    A mode the model amplifies less than ``limits.critically_damped`` is critically damped: it
    passes when no measured peak near it is a critical speed. One amplified more must be measured
    within ``limits.speed`` of the prediction and no more amplified than predicted (up to
    ``limits.amplification``). A measured critical speed (a peak amplified at least
    ``limits.critically_damped``) that no prediction explains fails.

    Parameters
    ----------
    predicted : list of PredictedCritical
    peaks : dict of str to list of OneXPeak
        Each axis's measured 1X peaks.
    rpm_range : (float, float)
        The run's speeds, in rpm: predictions outside it are not checked.
    limits : CriticalLimits
        The speed and amplification tolerances (shares) and the critically damped factor.
    operating_rpm : (float, float), optional
        The minimum operating and maximum continuous speeds, rpm: each critical speed (measured
        where measured) must also keep :func:`separation_margin` from them.
    """
    lo, hi = rpm_range
    tolerance, min_amplification = limits.speed, limits.critically_damped
    checks, explained = [], set()
    for p in predicted:
        if not lo <= p.rpm <= hi:
            continue
        near = [(a, k) for a, ps in peaks.items() for k in ps if abs(k.rpm - p.rpm) <= tolerance * p.rpm]
        for a, k in near:
            explained.add((a, k.rpm))
        axis, peak = max(near, key=lambda ak: ak[1].amplification) if near else (None, None)
        if p.amplification < min_amplification:
            ok = peak is None or not peak.is_critical(min_amplification)
            rule = (f"API 684: amplification {p.amplification:.2f} < {min_amplification:g}, critically damped: no "
                    f"critical speed within {tolerance * 100:g}%")
        else:
            ok = (peak is not None and peak.is_critical(min_amplification)
                  and peak.amplification <= p.amplification * (1 + limits.amplification))
            rule = (f"API 684: measured within {tolerance * 100:g}% of the predicted speed, amplified no more than "
                    f"predicted ({p.amplification:.2f}, {limits.amplification * 100:g}% allowed)")
        margin = None
        if operating_rpm is not None:
            seen = peak is not None and peak.is_critical(min_amplification)
            margin = margin_from(peak.rpm if seen else p.rpm, peak.amplification if seen else p.amplification,
                                 operating_rpm)
            ok = ok and margin.passed
            rule += f"; API 617 separation margin {margin.required:.1%} from {operating_rpm[0]:,.0f}-" \
                    f"{operating_rpm[1]:,.0f} rpm"
        checks.append(CriticalCheck(p, peak, axis, ok, rule, margin))
    for a, ps in peaks.items():
        for k in ps:
            if k.is_critical(min_amplification) and (a, k.rpm) not in explained:
                margin = None if operating_rpm is None else margin_from(k.rpm, k.amplification, operating_rpm)
                checks.append(CriticalCheck(None, k, a, False, f"a critical speed (amplification {k.amplification:.2f}) "
                                                                "the model does not predict", margin))
    return checks


WHIRL_RATIO = 1.5
"""A mode whirls forward (backward) when its forward circular part outweighs its backward one
(the reverse) by this much in energy; between, it is close to planar and not marked."""

RADIAL_SHARE = 1e-6
"""A mode whose radial bearings hold no more than this share of its energy at the sensors is not
radial (an axial mode), and whirls neither way: rounding leaves about 1e-30 there, a mode that
couples axial and radial motion (a cone bearing's) far more."""


def loop_modes(M: np.ndarray, h: float, *, max_damping: float = 0.5, fmax_hz: float | None = None,
               outputs: np.ndarray | None = None, pairs: tuple[tuple[int, int], ...] = ()
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies, damping ratios and whirl directions of a discrete loop's lightly damped modes.

    A mode's whirl is read from its shape at each radial bearing: the shape ``(v_x, v_y)`` of
    ``x + j y`` splits into a forward circle ``(v_x + j v_y) e^{j w t}`` and a backward one
    ``(v_x - j v_y) e^{-j w t}`` (the full spectrum's convention, :mod:`.spectrum`: positive
    frequencies whirl forward); the larger in energy over the bearings, by :data:`WHIRL_RATIO`,
    gives the direction.

    Parameters
    ----------
    M : ndarray, shape (n, n)
        The loop's state matrix, ``x[n+1] = M x[n] + ...``.
    h : float
        Sample period, in s.
    max_damping : float
        Modes with more damping than this are left out.
    fmax_hz : float, optional
        Highest frequency kept, in Hz (default: Nyquist).
    outputs : ndarray, shape (m, n), optional
        The gap sensors' rows (``y = C x``, in m), for the whirl.
    pairs : tuple of (int, int)
        The (x, y) rows of ``outputs`` of each radial bearing.

    Returns
    -------
    freq_hz, damping : ndarray
        Sorted by frequency; one per complex pair.
    whirl : ndarray of int
        +1 forward, -1 backward, 0 neither or not known (no ``outputs``).
    """
    z, vectors = np.linalg.eig(M)
    pick = (np.imag(z) > 0) & (np.abs(z) > 0)
    z, vectors = z[pick], vectors[:, pick]
    s = np.log(z) / h
    wn = np.abs(s)
    zeta = -np.real(s) / np.where(wn > 0, wn, 1.0)
    f = np.imag(s) / (2 * np.pi)
    keep = (zeta <= max_damping) & (f > 0) & (f <= (fmax_hz if fmax_hz is not None else 0.5 / h))
    idx = np.argsort(f[keep])
    whirl = np.zeros(int(keep.sum()), dtype=int)
    if outputs is not None and pairs:
        shape = outputs @ vectors[:, keep][:, idx]  # (m, modes): each mode at each sensor
        forward = sum(np.abs(shape[i] + 1j * shape[j]) ** 2 for i, j in pairs)
        backward = sum(np.abs(shape[i] - 1j * shape[j]) ** 2 for i, j in pairs)
        whirl = np.where(forward > WHIRL_RATIO * backward, 1, np.where(backward > WHIRL_RATIO * forward, -1, 0))
        # a mode that hardly moves the radial bearings (an axial mode: its radial parts are the
        # eigensolver's rounding) whirls neither way
        radial = (forward + backward) / 2
        whirl[radial <= RADIAL_SHARE * np.sum(np.abs(shape) ** 2, axis=0)] = 0
    return f[keep][idx], zeta[keep][idx], whirl


__all__ = ["AMPLIFICATION_TOLERANCE", "CRITICAL_AMPLIFICATION", "RADIAL_SHARE", "SPEED_TOLERANCE", "WHIRL_RATIO",
           "CriticalCheck", "CriticalLimits", "Margin", "OneXPeak", "OrderTrack", "PredictedCritical",
           "from_response", "loop_modes", "margin_from", "separation_margin", "one_x_peaks", "order_track",
           "phase_lag_deg", "predicted_criticals", "verify_criticals"]
