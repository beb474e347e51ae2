"""A parametric model of one AMB axis's plant, fitted to its closed-loop measurement (issue 42,
item 3).

The plant from the controller's output u (V) to the gap y (m) is the amplifier, the rotor's
modes as the sensor sees them, a delay, all held over the control period::

    P(s) = e^{-s tau} A(s) sum_k r_k / (s^2 + c_k s + d_k),   A(s) = w_a^2 / (s^2 + 2 z_a w_a s + w_a^2)

A rigid-body mode on the magnets' negative stiffness is an unstable real pair, c = 0 and
d = -a^2 (a = sqrt(k_neg / m_modal), rad/s); a bending mode is c = 2 zeta w, d = w^2.  The residue
r_k (m/V/s^2) is the product of the mode's shape at the bearing and at the sensor, the amplifier's
gain, the current gain and the sensor's gain: one measured response holds only their product,
so the model states the residue and not its factors.  The model is compared with the measurement
exactly as the controller sees it: the continuous model zero-order-held over the period (its
states stepped by the matrix exponential), so the hold's phase is not fitted by the delay.

A bending mode well above a response's trusted band reaches it only as a compliance, the same
at every frequency there: its residue is not identifiable from that response (fitted anyway, a
pair of such modes cancel each other in residues a hundred times the truth, with tight stated
errors).  So each response fits the residues of the modes up to ``BAND_MARGIN`` times its highest
trusted frequency, and lumps those above (and the rotor's modes above the model's) into one
residual compliance R (m/V, through the amplifier and the delay: the "upper residual" of
experimental modal analysis); the residues it cannot identify are not stated.

The residues enter linearly: for given poles, amplifier and delay they are the weighted linear
least-squares solution (variable projection, Golub & Pereyra 1973), and the nonlinear search
(scipy's least_squares, trust region) runs over the poles alone.  The weights are the inverse
of the measurement's random error; its errors are correlated (neighbouring frequencies through
the window, the elements of one plant through the runs they share), so the covariance of all the
parameters is the sandwich (J^T J)^-1 J^T R J (J^T J)^-1 at the optimum, R the whitened errors'
correlation, scaled up by the reduced chi-square where the model does not reach the measurement's
noise (a conservative statement: never below what the noise alone gives).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .amb import zoh

MAX_EVALUATIONS = 60
"""The most evaluations of the residual (and of its Jacobian) the search may take: a model that
describes the measurement converges in a few (the flexible rotor at standstill in 7); one that
does not wanders for hundreds, and its refusal should not take a minute."""
BAND_MARGIN = 1.25
"""A bending mode up to this factor above a response's highest trusted frequency still shapes the
band's edge and has its residue fitted; above it, it is in the response's residual compliance."""
RIGID_MAX_HZ = 300.0
"""The highest a rigid-body mode's unstable pole may be fitted at, Hz: sqrt(k_neg / m) of an AMB rotor
is tens of hertz; a pole fitted higher stands in for an unmodelled mode, not the rigid body."""


@dataclass(frozen=True)
class ModalPlant:
    """A fitted axis (see the module docstring); SI units, frequencies in rad/s.

    Attributes
    ----------
    rigid : ndarray, shape (m,)
        a of each rigid-body mode's unstable pair +-a, rad/s.
    bending : ndarray, shape (b, 2)
        (w, zeta) of each bending mode.
    residues : ndarray, shape (responses, m + b)
        r_k of each response (an element of the plant), rigid modes first, m/V/s^2: every element
        of one rotor's plant has the same poles (they are the rotor's on its bearings), each its
        own residues; 0 where a mode is in the response's residual instead.
    amplifier : tuple of float
        (w_a rad/s, z_a).
    delay_s : float
    h : float
        The control period the model is held over, s.
    residual : ndarray, shape (responses,), optional
        Each response's residual compliance R (m/V) of the modes above its band; default none.
    """

    rigid: np.ndarray
    bending: np.ndarray
    residues: np.ndarray
    amplifier: tuple[float, float]
    delay_s: float
    h: float
    residual: np.ndarray | None = None

    def theta(self) -> np.ndarray:
        """The nonlinear parameters as the fit moves them: logs of a, w, zeta, w_a; z_a; delay."""
        return np.concatenate([np.log(self.rigid), np.log(self.bending[:, 0]), np.log(self.bending[:, 1]),
                               [np.log(self.amplifier[0]), self.amplifier[1], self.delay_s]])

    @classmethod
    def from_theta(cls, theta: np.ndarray, residues: np.ndarray, m: int, b: int, h: float,
                   residual: np.ndarray | None = None) -> "ModalPlant":
        rigid = np.exp(theta[:m])
        bending = np.column_stack([np.exp(theta[m : m + b]), np.exp(theta[m + b : m + 2 * b])])
        return cls(rigid, bending, residues, (float(np.exp(theta[m + 2 * b])), float(theta[m + 2 * b + 1])),
                   float(theta[m + 2 * b + 2]), h, residual)

    def basis(self, freq_hz: np.ndarray) -> np.ndarray:
        """Each mode's held response through the amplifier and delay with unit residue, (n, modes)."""
        return _basis(self.rigid, self.bending, self.amplifier, self.delay_s, self.h, freq_hz)

    def response(self, freq_hz: np.ndarray) -> np.ndarray:
        """Each response's P(e^{j w h}) at ``freq_hz`` (Hz), shape (n, responses), m/V."""
        out = self.basis(freq_hz) @ self.residues.T
        if self.residual is not None:
            out = out + _static_basis(self.amplifier, self.delay_s, self.h, freq_hz)[:, None] * self.residual[None, :]
        return out

    def state_space(self, axis: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Response ``axis``'s continuous model without its delay: (A, B, C), input V, output m;
        states: the amplifier's (2: its current, with unit DC gain, the residual's input), then
        each mode's displacement and velocity."""
        wa, za = self.amplifier
        modes = [(0.0, -a * a) for a in self.rigid] + [(2 * z * w, w * w) for w, z in self.bending]
        n = 2 + 2 * len(modes)
        A, B, C = np.zeros((n, n)), np.zeros((n, 1)), np.zeros((1, n))
        A[0, 1] = 1.0
        A[1, 0], A[1, 1] = -wa * wa, -2 * za * wa
        B[1, 0] = wa * wa
        for k, (c, d) in enumerate(modes):
            i = 2 + 2 * k
            A[i, i + 1] = 1.0
            A[i + 1, i], A[i + 1, i + 1], A[i + 1, 0] = -d, -c, 1.0
            C[0, i] = self.residues[axis, k]
        if self.residual is not None:
            C[0, 0] = self.residual[axis]
        return A, B, C


def _held(A: np.ndarray, B: np.ndarray, state: int, h: float, freq_hz, delay_s: float) -> np.ndarray:
    """State ``state`` of the continuous system (A, B) held over the period ``h`` (s), per unit of its
    input, then delayed by ``delay_s`` (s), at ``freq_hz`` (Hz): C (zI - Phi)^-1 Gam e^{-j w tau},
    C picking the state, by the eigen-decomposition of Phi, (n,)."""
    f = np.asarray(freq_hz, float)
    z = np.exp(2j * np.pi * f * h)
    phi, gam = zoh(A, B, h)
    lam, vec = np.linalg.eig(phi)
    left = vec[state] * (np.linalg.solve(vec, gam)[:, 0])  # C V and V^-1 Gam, per eigenvalue
    return (left[None, :] / (z[:, None] - lam[None, :])).sum(axis=1) * np.exp(-2j * np.pi * f * delay_s)


def _basis(rigid, bending, amplifier, delay_s, h, freq_hz) -> np.ndarray:
    """Each mode's displacement through the amplifier with unit residue, (n, modes)."""
    wa, za = amplifier
    B = np.array([[0.0], [wa * wa], [0.0], [0.0]])
    out = []
    for c, d in [(0.0, -a * a) for a in rigid] + [(2 * zeta * w, w * w) for w, zeta in bending]:
        A = np.array([[0.0, 1.0, 0.0, 0.0], [-wa * wa, -2 * za * wa, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0],
                      [1.0, 0.0, -d, -c]])
        out.append(_held(A, B, 2, h, freq_hz, delay_s))
    return np.stack(out, axis=1)


def _static_basis(amplifier, delay_s, h, freq_hz) -> np.ndarray:
    """A unit compliance's held response through the amplifier and the delay (its current), (n,)."""
    wa, za = amplifier
    return _held(np.array([[0.0, 1.0], [-wa * wa, -2 * za * wa]]), np.array([[0.0], [wa * wa]]), 0, h, freq_hz,
                 delay_s)


@dataclass(frozen=True)
class PlantFit:
    """A fitted model of one rotor's axes with the covariance of its parameters.

    Attributes
    ----------
    model : ModalPlant
    axes : list of str
        The responses fitted (elements of the plant, by name), in the order of the model's residues.
    names : list of str
        The parameters in the covariance's order (their units in :meth:`table`).
    values : ndarray
        Their values, SI (frequencies in Hz, the delay in s).
    covariance : ndarray
        Of ``values``.
    chi2_reduced : float
        The weighted residual's mean square per degree of freedom (1: the model reaches the noise).
    points : int
        Complex points fitted.
    converged : bool
        Whether the search met its tolerances within ``MAX_EVALUATIONS`` (if not, the parameters
        are not at an optimum and their covariance means nothing).
    """

    model: ModalPlant
    axes: list[str]
    names: list[str]
    values: np.ndarray
    covariance: np.ndarray
    chi2_reduced: float
    points: int
    converged: bool = True

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def pole_names(m: int, b: int) -> list[str]:
    """The shared parameters' names, in the fit's order: poles, damping, amplifier, delay."""
    return ([f"rigid{k + 1}_hz" for k in range(m)] + [f"mode{k + 1}_hz" for k in range(b)]
            + [f"mode{k + 1}_zeta" for k in range(b)] + ["amplifier_hz", "amplifier_zeta", "delay_s"])


def mode_names(m: int, b: int) -> list[str]:
    return [f"rigid{k + 1}" for k in range(m)] + [f"mode{k + 1}" for k in range(b)]


def _physical(theta: np.ndarray, lin: np.ndarray, fitted: np.ndarray, m: int, b: int,
              axes: list[str]) -> tuple[list[str], np.ndarray]:
    """(names, values) in engineering units from the fit's parameters: the shared poles, then each
    response's fitted residues (``AXIS.modeK_residue``) and its residual (``AXIS.residual``), the
    order :func:`_unpack` reads."""
    two_pi = 2 * np.pi
    modes = mode_names(m, b)
    names = pole_names(m, b)
    for i, axis in enumerate(axes):
        names += [f"{axis}.{mode}_residue" for k, mode in enumerate(modes) if fitted[i, k]] + [f"{axis}.residual"]
    values = np.concatenate([np.exp(theta[:m]) / two_pi, np.exp(theta[m : m + b]) / two_pi, np.exp(theta[m + b : m + 2 * b]),
                             [np.exp(theta[m + 2 * b]) / two_pi, theta[m + 2 * b + 1], theta[m + 2 * b + 2]], lin])
    return names, values


def _unpack(lin: np.ndarray, fitted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    residues, residual, pos = np.zeros(fitted.shape), np.zeros(fitted.shape[0]), 0
    for i in range(fitted.shape[0]):
        k = int(fitted[i].sum())
        residues[i, fitted[i]] = lin[pos : pos + k]
        residual[i] = lin[pos + k]
        pos += k + 1
    return residues, residual


def _couple(jn: np.ndarray, a: np.ndarray, b: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """J_a^T R_ab J_b + its transpose, for whitened residual rows of points ``a`` and ``b`` (each a
    pair of row indices: the real parts', the imaginary parts') whose complex errors have the
    correlation ``rho``: the real parts correlate by Re rho, as do the imaginary ones, and the
    imaginary part of one with the real part of the other by +-Im rho (a circular error)."""
    (xa, ya), (xb, yb) = a, b
    re, im = rho.real[:, None], rho.imag[:, None]
    m = (jn[xa] * re).T @ jn[xb] + (jn[ya] * re).T @ jn[yb] + (jn[ya] * im).T @ jn[xb] - (jn[xa] * im).T @ jn[yb]
    return m + m.T


def _correlated(jn: np.ndarray, where: list[np.ndarray], first: np.ndarray, data: list, axes: list[str],
                neighbour: float, cross: dict[tuple[str, str], np.ndarray]) -> np.ndarray:
    """The off-diagonal part of J^T R J: each response's neighbouring points (correlation
    ``neighbour``), and each pair of responses at one frequency (their errors' correlation from
    ``cross``) and at neighbouring ones (the product of the two)."""
    starts = np.cumsum([0] + [2 * len(idx) for idx in where])
    at = [first[idx] for idx in where]  # each response's points on the measurement's grid

    def rows(e, positions):  # response e's real and imaginary rows of its points ``positions``
        return starts[e] + positions, starts[e] + len(where[e]) + positions

    out = np.zeros((jn.shape[1], jn.shape[1]))
    for e in range(len(where)):
        if neighbour:
            adjacent = np.flatnonzero(np.diff(at[e]) == 1)
            out += _couple(jn, rows(e, adjacent), rows(e, adjacent + 1), np.full(adjacent.size, neighbour + 0j))
    for a in range(len(where)):
        for b in range(a + 1, len(where)):
            c = cross.get((axes[a], axes[b]))
            if c is None and (axes[b], axes[a]) in cross:
                c = cross[(axes[b], axes[a])].conj()
            if c is None:
                continue
            sigma = {}
            for e in (a, b):  # the complex error's deviation on the measurement's grid, from the weights
                keep, _, weight = data[e]
                sigma[e] = np.full(keep.size, np.nan)
                sigma[e][keep] = np.sqrt(2.0) / weight
            both = np.intersect1d(at[a], at[b])  # the frequencies both responses hold
            rho = np.zeros(len(data[a][0]), dtype=complex)
            rho[both] = c[both] / (sigma[a][both] * sigma[b][both])
            pos = {e: np.full(len(data[e][0]), -1) for e in (a, b)}
            for e in (a, b):
                pos[e][at[e]] = np.arange(at[e].size)
            for shift, scale in ((0, 1.0), (1, neighbour), (-1, neighbour)):
                # a at g, b at g + shift, both holding g and g + shift (their correlation the product)
                g = both if shift == 0 else np.intersect1d(both, both - shift)
                if scale and g.size:
                    out += _couple(jn, rows(a, pos[a][g]), rows(b, pos[b][g + shift]), scale * rho[g])
    return out


def fit(freq_hz: np.ndarray, measured: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], h: float, *,
        rigid_hz: list[float], bending_hz: list[float], amplifier_hz: float = 2000.0,
        amplifier_zeta: float = 0.7, neighbour_correlation: float = 0.0,
        cross_covariance: dict[tuple[str, str], np.ndarray] | None = None) -> PlantFit:
    """Fit the model to one or more measured responses (elements of one rotor's plant), their poles shared.

    Parameters
    ----------
    freq_hz : ndarray
        The measurement's frequencies, Hz.
    measured : dict
        Response name -> (P (complex, m/V), the standard deviation of its complex error (m/V), trusted (bool)) over ``freq_hz``.
    h : float
        Control period, s.
    rigid_hz, bending_hz : list of float
        Starting guesses: each rigid-body mode's unstable pole (Hz) and each bending mode's
        frequency (Hz, from the measurement's resonances); a response fits the residues of the
        bending modes up to ``BAND_MARGIN`` times its highest trusted frequency (by these
        guesses), and a residual compliance for those above.
    amplifier_hz, amplifier_zeta : float
        Starting guess of the amplifier's bandwidth (Hz) and damping.
    neighbour_correlation : float
        The correlation of a response's errors at neighbouring frequencies (the estimate's
        window spreads each frequency's noise over its neighbours: 4/9 for a Hann-windowed H1,
        :data:`~ambdaq.analysis.frf.NEIGHBOUR_CORRELATION`); the covariance holds it.
    cross_covariance : dict, optional
        (name a, name b) -> the covariance of the two responses' complex errors at each of
        ``freq_hz``, E[dP_a dP_b^*] (m^2/V^2): the elements of one measured plant share its runs'
        noise (:mod:`ambdaq.analysis.closed_loop`); the parameters' covariance holds it, with the
        neighbouring frequencies' correlation on top (the two taken as independent causes). A pair
        not given is uncorrelated.
    """
    from scipy.optimize import least_squares

    axes = list(measured)
    m, b = len(rigid_hz), len(bending_hz)
    modes = m + b
    # the real and imaginary parts of a response's error each have sigma / sqrt(2) (sigma the
    # complex error's standard deviation): weighted by sqrt(2) / sigma, each residual is one unit
    data = [(measured[a][2], measured[a][0][measured[a][2]], np.sqrt(2.0) / measured[a][1][measured[a][2]]) for a in axes]
    used = np.zeros(len(freq_hz), dtype=bool)
    for keep, _, _ in data:
        used |= keep
    grid = np.asarray(freq_hz, float)[used]
    where = [np.flatnonzero(keep[used]) for keep, _, _ in data]
    fitted = np.ones((len(axes), modes), dtype=bool)
    for i, (keep, _, _) in enumerate(data):
        fitted[i, m:] = np.asarray(bending_hz, float) <= BAND_MARGIN * float(np.asarray(freq_hz, float)[keep].max())
    theta0 = np.concatenate([np.log(2 * np.pi * np.asarray(rigid_hz, float)), np.log(2 * np.pi * np.asarray(bending_hz, float)),
                             np.log(np.full(b, 0.01)), [np.log(2 * np.pi * amplifier_hz), amplifier_zeta, 0.0]])

    def solve(theta):
        """Each response's linear parameters by weighted linear least squares, and the weighted residual."""
        model = ModalPlant.from_theta(theta, np.zeros((1, modes)), m, b, h)
        basis = model.basis(grid)
        static = _static_basis(model.amplifier, model.delay_s, h, grid)
        lin, out = [], []
        for i, (idx, (_, p, w)) in enumerate(zip(where, data)):
            cols = np.column_stack([basis[idx][:, fitted[i]], static[idx]])
            rows = cols * w[:, None]
            rows = np.vstack([rows.real, rows.imag])
            rhs = np.concatenate([(p * w).real, (p * w).imag])
            # columns to unit norm first: a residual compliance's column (m/V) and a residue's
            # (m/V/s^2) differ by eight orders, and lstsq's cut-off dropped the small one's direction
            norm = np.linalg.norm(rows, axis=0)
            norm[norm == 0] = 1.0
            r = np.linalg.lstsq(rows / norm, rhs, rcond=None)[0] / norm
            lin.append(r)
            out.append(rows @ r - rhs)
        return np.concatenate(lin), np.concatenate(out)

    # the search stays where each parameter means what its name says: a rigid-body mode's pole
    # below RIGID_MAX_HZ (above it, it would stand in for something else), a bending mode's damping
    # below 0.5, the amplifier between 100 Hz and 50 kHz, the delay not negative (nothing answers
    # before it is asked) and below five periods
    lower = np.concatenate([np.full(m, np.log(2 * np.pi * 1.0)), np.full(2 * b, -np.inf),
                            [np.log(2 * np.pi * 100.0), 0.05, 0.0]])
    upper = np.concatenate([np.full(m, np.log(2 * np.pi * RIGID_MAX_HZ)), np.full(2 * b, np.inf),
                            [np.log(2 * np.pi * 50e3), 3.0, 5 * h]])
    upper[m + b : m + 2 * b] = np.log(0.5)
    sol = least_squares(lambda t: solve(t)[1], np.clip(theta0, lower + 1e-9, upper - 1e-9), bounds=(lower, upper),
                        x_scale="jac", max_nfev=MAX_EVALUATIONS)
    lin, _ = solve(sol.x)
    n_theta = sol.x.size

    def model_of(params):
        residues, residual = _unpack(params[n_theta:], fitted)
        return ModalPlant.from_theta(params[:n_theta], residues, m, b, h, residual)

    def full(params):
        resp = model_of(params).response(grid)
        out = []
        for k, (idx, (_, p, w)) in enumerate(zip(where, data)):
            d = (resp[idx, k] - p) * w
            out += [d.real, d.imag]
        return np.concatenate(out)

    # the covariance of every parameter at once (poles, residues, residuals), by the Jacobian of the full residual
    p0 = np.concatenate([sol.x, lin])
    res0 = full(p0)
    jac = np.empty((res0.size, p0.size))
    # the smallest step of each: 1e-6 of the log-poles, 1e-3 of a residue (m/V/s^2, tens), 1e-12 of
    # a residual (m/V: a compliance of 1e-7 to 1e-5)
    floor = np.concatenate([np.full(n_theta, 1e-6)] + [np.r_[np.full(int(f.sum()), 1e-3), 1e-12] for f in fitted])
    for k in range(p0.size):
        step = 1e-6 * max(abs(p0[k]), floor[k])
        up, down = p0.copy(), p0.copy()
        up[k] += step
        down[k] -= step
        jac[:, k] = (full(up) - full(down)) / (2 * step)
    dof = max(res0.size - p0.size, 1)
    chi2 = float(res0 @ res0) / dof
    # each column to unit norm first: a residual's (m/V, 1e-8) and a log-pole's columns differ by
    # sixteen orders, and the pseudo-inverse would drop the small directions as if they were certain
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0] = 1.0
    jn = jac / norms
    inv = np.linalg.pinv(jn.T @ jn)
    # the points' errors are not independent: neighbouring frequencies of one response share a
    # part of their noise (correlation rho), and the responses of one plant share its runs' noise
    # at each frequency (their complex correlation), so the covariance is the sandwich
    # A^-1 J^T R J A^-1 (R the whitened residuals' correlation), not A^-1 (Seber & Wild, Nonlinear
    # Regression, section 2.1.4)
    middle = jn.T @ jn + _correlated(jn, where, np.flatnonzero(used), data, axes, neighbour_correlation,
                                     cross_covariance or {})
    cov_p = inv @ middle @ inv / np.outer(norms, norms) * max(chi2, 1.0)
    # to engineering units: the logs' derivative is the value itself, the rest are identities
    names, values = _physical(sol.x, lin, fitted, m, b, axes)
    scale = np.ones(p0.size)
    scale[: m + 2 * b + 1] = values[: m + 2 * b + 1]
    cov = cov_p * np.outer(scale, scale)
    return PlantFit(model_of(p0), axes, names, values, cov, chi2, int(sum(len(i) for i in where)), bool(sol.status > 0))
