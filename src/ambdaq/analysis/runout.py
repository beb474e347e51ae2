"""Runout identification from signals sampled with the rotor angle (Ro et al.).

Phasor convention: a harmonic ``R sin(k theta + phi)`` is the complex number ``R exp(j phi)``,
i.e. ``a sin k theta + b cos k theta`` with ``a + j b``; the feedforward weights of eq. 9-10
(``w_k0 sin + w_k1 cos``) are the same numbers.

Three estimates of the sensor signal's harmonics, all in the angle domain:

* :func:`synchronous_average`: angle-domain averaging over revolutions (slow-roll vector);
* :func:`harmonic_fit`: batch least squares on sin/cos of k theta;
* :func:`lms_offline`: Ro et al.'s LMS (eq. 9-10) run over the recording, converged weights.

In an AMB the runout is fed back: the rotor itself moves, so the sensor shows runout plus rotor
motion.  :func:`runout_from_sensor` removes the rotor motion reconstructed from the coil
currents through the rotor model (:mod:`ambdaq.analysis.rotor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from .rotor import RigidRotor


def synthesise(phasors: np.ndarray, harmonics: list[int], theta: np.ndarray) -> np.ndarray:
    """The signal a set of harmonic phasors describes, at the given rotor angles.

    Parameters
    ----------
    phasors : ndarray of complex, shape (harmonic,) or (harmonic, axis)
        ``a + j b`` for ``a sin k theta + b cos k theta`` (the convention of ``harmonic_fit``), any unit.
    harmonics : list of int
        Order k of each row (1 = 1X).
    theta : ndarray, shape (n,)
        Rotor angle, in rad.

    Returns
    -------
    ndarray, shape (n,) or (n, axis)
        ``sum_k Im(p_k exp(j k theta))``, in the unit of ``phasors``.
    """
    e = np.exp(1j * np.outer(theta, np.asarray(harmonics)))  # (n, harmonic)
    return (e @ phasors).imag


FIT_BLOCK = 32_768
"""Samples per block of :func:`_normal_equations`: one block's basis is a few MB of float64,
whatever the recording's length."""


def _normal_equations(s1: np.ndarray, c1: np.ndarray, x: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A^T A and A^T x of the least squares on the basis A = [sin k theta, cos k theta, 1], a block
    of samples at a time; sin and cos of m theta by angle addition from those of theta, written in
    place into the block's basis (numpy throughout: no compiled kernel for each process to load,
    1.1 s of numba's)."""
    kmax, nh = int(k.max()), k.shape[0]
    every_order = bool(np.array_equal(k, np.arange(1, kmax + 1)))  # harmonic_fit's usual case
    ata, atx = np.zeros((2 * nh + 1, 2 * nh + 1)), np.zeros((2 * nh + 1, x.shape[1]))
    for start in range(0, s1.shape[0], FIT_BLOCK):
        s, c = s1[start : start + FIT_BLOCK], c1[start : start + FIT_BLOCK]
        basis = np.empty((2 * kmax + 1, s.shape[0]))  # rows: sin 1..kmax, cos 1..kmax, 1
        sk, ck, tmp = basis[:kmax], basis[kmax : 2 * kmax], np.empty(s.shape[0])
        sk[0], ck[0], basis[2 * kmax] = s, c, 1.0
        for m in range(1, kmax):  # sin (m+1) theta = sin m theta cos theta + cos m theta sin theta ...
            np.multiply(sk[m - 1], c, out=sk[m])
            sk[m] += np.multiply(ck[m - 1], s, out=tmp)
            np.multiply(ck[m - 1], c, out=ck[m])
            ck[m] -= np.multiply(sk[m - 1], s, out=tmp)
        if not every_order:
            basis = np.concatenate([sk[k - 1], ck[k - 1], basis[-1:]])
        ata += basis @ basis.T
        atx += basis @ x[start : start + FIT_BLOCK]
    return ata, atx


GUARD_ORDERS = 8
"""Every order up to this one, and up to the highest asked, is in :func:`harmonic_fit`'s least
squares whichever are asked (those below 80 % of the Nyquist frequency): an order the signal holds
but the fit leaves out leaks into the ones it reports over a window that is not whole revolutions
(a slow roll's 18 um 1X leaked 306 nm into 2X-6X over 1 s; a 10 um 2X leaks about 0.25 um into
the 1X of a 12-revolution window)."""


def fitted_orders(harmonics, theta: np.ndarray) -> list[int]:
    """The orders :func:`harmonic_fit` fits to report ``harmonics``: those, and every order up to
    :data:`GUARD_ORDERS` and to the highest asked that lies below 80 % of the Nyquist frequency of
    the angle's median step per sample (rad, ``theta`` wrapped or not)."""
    asked = sorted({int(k) for k in harmonics})
    th = np.asarray(theta, dtype=float)
    if th.shape[0] < 2:
        return asked
    step = float(np.median(np.abs((np.diff(th) + np.pi) % (2 * np.pi) - np.pi)))
    limit = int(0.8 * np.pi / step) if step > 0 else 0
    return sorted(set(asked) | set(range(1, min(max(GUARD_ORDERS, asked[-1]), limit) + 1)))


def harmonic_fit(x: np.ndarray, theta: np.ndarray, harmonics=(1, 2, 3, 4, 5, 6)) -> np.ndarray:
    """Least-squares phasors of the harmonics of ``x`` in the rotor angle; every order of
    :func:`fitted_orders` is fitted, so none the signal holds leaks into those reported.

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, m)
        Signal(s), any unit.
    theta : ndarray, shape (n,)
        Rotor angle at each sample, in rad (wrapped or not).
    harmonics : sequence of int
        Orders k (1 = 1X).

    Returns
    -------
    ndarray of complex, shape (len(harmonics),) or (len(harmonics), m)
        ``a + j b`` per harmonic for ``a sin k theta + b cos k theta``, in the unit of ``x``.
        The mean is fitted and dropped.

    Examples
    --------
    >>> th = np.linspace(0, 40 * np.pi, 4000)
    >>> p = harmonic_fit(3e-6 * np.sin(th + 0.5), th, (1,))
    >>> round(float(abs(p[0])) * 1e6, 6), round(float(np.angle(p[0])), 6)
    (3.0, 0.5)
    """
    th = np.asarray(theta, dtype=float)
    orders = fitted_orders(harmonics, th)
    k = np.asarray(orders, dtype=np.int64)
    x2 = np.asarray(x, dtype=float)
    one = x2.ndim == 1
    ata, atx = _normal_equations(np.sin(th), np.cos(th), x2.reshape(x2.shape[0], -1), k)
    coef = np.linalg.solve(ata, atx)
    n = k.shape[0]
    out = (coef[:n] + 1j * coef[n : 2 * n])[[orders.index(int(h)) for h in harmonics]]
    return out[:, 0] if one else out


def synchronous_average(x: np.ndarray, theta: np.ndarray, *, bins: int = 512, harmonics=(1, 2, 3, 4, 5, 6)) -> np.ndarray:
    """Harmonic phasors of ``x`` by angle-domain synchronous averaging (slow-roll vector).

    Samples are averaged in ``bins`` equal angle bins over all revolutions (removing everything
    not locked to the rotor angle), and the harmonics read from the averaged revolution.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Signal.
    theta : ndarray, shape (n,)
        Rotor angle, in rad.
    bins : int
        Angle bins per revolution.
    harmonics : sequence of int
        Orders k.

    Returns
    -------
    ndarray of complex, shape (len(harmonics),)
        Phasors as in :func:`harmonic_fit`.
    """
    ang = np.mod(np.asarray(theta, dtype=float), 2 * np.pi)
    idx = np.minimum((ang / (2 * np.pi) * bins).astype(np.int64), bins - 1)
    sums = np.bincount(idx, weights=np.asarray(x, dtype=float), minlength=bins)
    counts = np.bincount(idx, minlength=bins)
    if np.any(counts == 0):
        raise ValueError(f"not every one of the {bins} angle bins has a sample: record more revolutions or use fewer bins")
    avg = sums / counts
    centres = (np.arange(bins) + 0.5) * 2 * np.pi / bins
    # discrete Fourier coefficients of the averaged revolution at the bin centres
    k = np.asarray(harmonics)
    a = 2 / bins * (np.sin(np.outer(k, centres)) @ avg)
    b = 2 / bins * (np.cos(np.outer(k, centres)) @ avg)
    # the bins average over their width: undo the sinc attenuation of each order
    gain = np.sinc(k / bins)
    return (a + 1j * b) / gain


@dataclass(frozen=True)
class LmsResult:
    """Offline LMS: converged weights (phasors) and the error signal it leaves."""

    phasors: np.ndarray
    error: np.ndarray


def lms_offline(x: np.ndarray, theta: np.ndarray, *, mu: float = 0.002, harmonics=(1, 2, 3, 4, 5, 6)) -> LmsResult:
    """Ro et al.'s LMS (eq. 9-10) run over a recorded signal; its weights converge to the phasors.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Signal the feedforward would cancel, any unit.
    theta : ndarray, shape (n,)
        Rotor angle, in rad.
    mu : float
        Step size (dimensionless); the weights settle in about 2/mu samples.
    harmonics : sequence of int
        Orders k.

    Returns
    -------
    LmsResult
        ``phasors`` (w_k0 + j w_k1, in the unit of ``x``) and the error x - r_c of eq. 10.
    """
    x = np.ascontiguousarray(x, dtype=float)
    w = np.zeros((len(harmonics), 2))
    out = np.empty_like(x)
    th = np.asarray(theta, dtype=float)
    from .runout_lms import lms_recursion  # numba, loaded by the offline LMS alone

    lms_recursion(x - x.mean(), np.sin(th), np.cos(th), np.asarray(harmonics, dtype=np.int64), float(mu), w, out)
    return LmsResult(w[:, 0] + 1j * w[:, 1], out)


def notch_filter(mu: float, k_omega_h: float) -> tuple[np.ndarray, np.ndarray]:
    """The LMS feedforward seen as a filter from signal to error (Ro et al. eq. 16).

    ``E/R = (1 - 2 cos(kΩh) z^-1 + z^-2) / (1 - (2 - mu) cos(kΩh) z^-1 + (1 - mu) z^-2)``: an IIR
    notch at the harmonic, narrower for smaller ``mu``.

    Parameters
    ----------
    mu : float
        LMS step size.
    k_omega_h : float
        Harmonic frequency times the sample period, k Omega h, in rad.

    Returns
    -------
    b, a : ndarray
        Numerator and denominator in powers of z^-1 (for :func:`scipy.signal.lfilter`).
    """
    c = np.cos(k_omega_h)
    return np.array([1.0, -2 * c, 1.0]), np.array([1.0, -(2 - mu) * c, 1 - mu])


def runout_uncertainty(gap: np.ndarray, current: np.ndarray, theta: np.ndarray, fs: float, spin: float,
                       harmonics: list[int], rotor: RigidRotor) -> np.ndarray:
    """Standard uncertainty of each runout phasor's real and imaginary parts (m), from the noise
    the recording holds at each harmonic: the Cramer-Rao bound for a sinusoid in noise.

    A harmonic's least-squares phasor from N samples in noise of power spectral density S at its
    frequency (S in m^2 per unit of normalised frequency, sigma^2 for white noise) has each part's
    variance 2 S / N, which no unbiased estimator beats (Kay, Fundamentals of Statistical Signal
    Processing, vol. 1, section 3.7; the least-squares fit attains it). The runout is the sensor
    phasor less the rotor motion the currents explain (:func:`runout_from_sensor`), so the noise
    that matters is the same combination of the residuals, ``gap - M(k Omega) current``, whose
    spectrum is averaged over the bins around each harmonic (the harmonics' own bins left out):
    sensor noise that the loop turns into rotor motion cancels in it, as it does in the runout.

    Parameters
    ----------
    gap : ndarray, shape (n, 5)
        Gap sensors, m, at constant speed.
    current : ndarray, shape (n, 5)
        Coil currents, A, at the same samples.
    theta : ndarray, shape (n,)
        Rotor angle, rad.
    fs : float
        Sample rate, Hz.
    spin : float
        Rotor speed, rad/s.
    harmonics : list of int
        Orders k.
    rotor : RigidRotor
        The rotor model.

    Returns
    -------
    ndarray, shape (harmonic, 5)
        Standard uncertainty of each part (real, imaginary) of each runout phasor, m.
    """
    n = gap.shape[0]
    orders = list(range(1, max(harmonics) + 1))

    def residual(x: np.ndarray) -> np.ndarray:
        x = x - x.mean(axis=0)
        return x - synthesise(harmonic_fit(x, theta, orders), orders, theta)

    g, c = np.fft.rfft(residual(gap), axis=0), np.fft.rfft(residual(current), axis=0)
    freq = np.fft.rfftfreq(n, 1.0 / fs)
    f_spin = spin / (2 * np.pi)
    step = fs / n
    half = max(5 * step, 0.1 * f_spin)  # a tenth of the speed either side, at least five bins
    near_order = np.abs(freq / f_spin - np.round(freq / f_spin)) * f_spin <= 2 * step
    out = np.empty((len(harmonics), gap.shape[1]))
    for i, k in enumerate(harmonics):
        band = (np.abs(freq - k * f_spin) <= half) & ~near_order
        w = k * spin
        M = np.column_stack([rotor.motion_from_currents(np.eye(gap.shape[1])[b], w, spin) for b in range(gap.shape[1])])
        z = g[band] - c[band] @ M.T  # (bins, axis): the runout's noise at these frequencies
        psd = np.mean(np.abs(z) ** 2, axis=0) / n  # per-sample noise power at k Omega
        out[i] = np.sqrt(2.0 * psd / n)
    return out


MODEL_BOUND = (2.0, 5e-4)
"""How well the rotor motion the currents explain is known, as shares of itself: ``a (f / fs)^2 + b``
at a harmonic of frequency f (Hz) sampled at fs (Hz).

``a``: the coil current moves between its samples (the controller's output held over each period
through the amplifier), and its images about the sample rate alias into the sampled current
without moving the rotor as much; 1.25-1.6 (f / fs)^2 measured on the simulated spindle
(amplifier 1.8 kHz, damping 1.7, at 10 kHz) over 1X-6X at 30,000 rpm. ``b``: what remains on slow
rolls, 0.02-0.04 % over 30 runs of 10 s without unbalance (its cause not identified: a converter's
or the model's). Both are bounds from tests/validation (docs/validation.md); a faster amplifier
for its sample rate aliases more."""


def model_bound(motion: np.ndarray, f_hz: float, fs: float) -> np.ndarray:
    """A bound on the error of :func:`runout_from_sensor` that its noise does not cover (m):
    :data:`MODEL_BOUND` of the rotor motion the currents explain.

    Parameters
    ----------
    motion : ndarray of complex
        Rotor motion phasors the currents explain at the harmonic, m.
    f_hz : float
        The harmonic's frequency, Hz.
    fs : float
        The sample rate, Hz.
    """
    a, b = MODEL_BOUND
    return (a * (f_hz / fs) ** 2 + b) * np.abs(motion)


def runout_from_sensor(gap: np.ndarray, current: np.ndarray, w: float, spin: float, rotor: RigidRotor) -> np.ndarray:
    """Runout phasors at one frequency: sensor phasors less the rotor motion the currents explain.

    Parameters
    ----------
    gap : ndarray of complex, shape (5,)
        Sensor phasors per axis at ``w``, in m.
    current : ndarray of complex, shape (5,)
        Coil current phasors per axis at ``w``, in A.
    w : float
        Harmonic angular frequency k Omega, in rad/s.
    spin : float
        Rotor speed Omega, in rad/s.
    rotor : RigidRotor
        The rotor model.
    """
    return np.asarray(gap) - rotor.motion_from_currents(current, w, spin)


@dataclass(frozen=True)
class Separation:
    """Electrical runout and mass unbalance separated over several speeds (1X).

    Attributes
    ----------
    runout : ndarray of complex, shape (5,)
        1X runout phasor per axis, in m (the same at every speed).
    unbalance : ndarray of complex, shape (2,)
        Unbalance per bearing plane (front, rear), in kg m, as U exp(j phi) for a force
        U Omega^2 cos(theta + phi) on x and U Omega^2 sin(theta + phi) on y.
    residual : float
        Rms misfit over the speeds, in m.
    """

    runout: np.ndarray
    unbalance: np.ndarray
    residual: float


PLANE_FORCES = np.array([[1j, 0], [1, 0], [0, 1j], [0, 1], [0, 0]], dtype=complex)
"""Unbalance per plane (front, rear; kg m, as Separation's) to the 1X force at each bearing axis per
Omega^2 (x, y of each bearing, then the axial): x gets j u, y gets u (see Separation)."""


def unbalance_in_runout(spin: float, rotor: RigidRotor) -> np.ndarray:
    """What a 1X runout estimate of :func:`runout_from_sensor` at ``spin`` (rad/s) holds of the
    rotor's unbalance, per kg m on each plane: H(Omega) B Omega^2, the force the currents do not
    explain through the rigid rotor's own dynamics, D(Omega) = -Omega^2 M + j Omega G - Kx.

    Returns
    -------
    ndarray of complex, shape (5, 2)
        Per axis (the rotor model's order: front x, y, rear x, y, axial), m per kg m on the front
        and rear planes.
    """
    M, G = rotor.mass_gyro(spin)
    D = -(spin**2) * M + 1j * spin * G - np.diag(rotor.kx)
    return np.linalg.solve(D, PLANE_FORCES) * spin**2


def separate_unbalance(estimates: np.ndarray, spins: np.ndarray, rotor: RigidRotor) -> Separation:
    """Split 1X runout estimates made at several speeds into runout and unbalance response.

    At speed the 1X estimate of :func:`runout_from_sensor` also holds the rotor's response to
    mass unbalance, a force the currents do not explain: r_est(Omega) = r + H(Omega) B u Omega^2,
    with u the unbalance per plane.  Electrical runout is fixed to the angle, the unbalance
    response grows with speed, so two or more speeds separate them by least squares.

    Parameters
    ----------
    estimates : ndarray of complex, shape (n_speeds, 5)
        1X runout estimates per speed and axis, in m.
    spins : ndarray, shape (n_speeds,)
        Rotor speeds, in rad/s.
    rotor : RigidRotor
        Rotor model.
    """
    est = np.asarray(estimates, dtype=complex)
    spins = np.asarray(spins, dtype=float)
    if est.shape[0] < 2 or np.ptp(spins) <= 0:
        raise ValueError("separating runout from unbalance needs recordings at two or more different speeds")
    rows, rhs = [], []
    for r_est, w in zip(est, spins):
        rows.append(np.concatenate([np.eye(5), unbalance_in_runout(w, rotor)], axis=1))
        rhs.append(r_est)
    A = np.concatenate(rows)
    y = np.concatenate(rhs)
    sol, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = float(np.sqrt(np.mean(np.abs(A @ sol - y) ** 2)))
    return Separation(sol[:5], sol[5:], resid)
