"""The magnetic bearings' actuator gains from the measured plant (issue 42, item 3):
``ambdaq plant gains PLANT.json --machine flexible``.

The plant P (controller output, V, to gap, m) holds each bearing's actuator as the force it makes
per volt, ki ka (current gain times the amplifier's gain, N/V), and its negative stiffness kx
(N/m): the first scales the rotor's every response to that bearing's input, the second sets the
unstable rigid-body poles (sqrt(kx / m) for one mass on one magnet). Neither is identifiable from
the modal model alone (its residues mix ki ka with the mode shapes, its rigid-body poles mix kx
with the rotor's mass and inertia); with the rotor's model (the beam elements of
:mod:`ambdaq.machines.flexible_spindle`: mass, inertia, where the bearings and sensors sit) they
are. So the machine's model is fitted to the measurement with the four bearing values free (front
and rear; x and y share a bearing's magnet), by weighted least squares over the elements of each
plane the coherence trusts, below :data:`BAND` of the first bending mode, where the rotor's
rigid-body dynamics carry them and a lightly damped mode's window bias does not reach. What the
fit holds apart is ki ka: ki alone needs ka, the amplifier's DC gain. Where the runs recorded the
coil currents, the plant file holds each axis's amplifier (current per controller volt,
:mod:`ambdaq.analysis.amplifier`): its fitted ka (a bearing's two axes weighed by their variances)
divides ki ka into ki. A sensor's scale error would read as a scale on ki ka and ki, not on ka.

Their covariance is the weighted Jacobian's, sandwiched with the correlation of the H1 errors at
neighbouring frequencies (:data:`~ambdaq.analysis.frf.NEIGHBOUR_CORRELATION`), as :mod:`plant_fit`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..analysis import amplifier
from ..analysis.closed_loop import window_bias
from ..analysis.frf import COHERENT, NEIGHBOUR_CORRELATION
from ..errors import BadInputError
from ..machines.flexible_spindle import AXES, FlexibleLoop, FlexibleSpindleParams
from .plant_identification import PlantMeasurement

BAND = 0.8
"""The fit's band ends at this fraction of the first free-free bending mode: the flexible rotor's
394 Hz gives 315 Hz, the longer rotor's 301 Hz 241 Hz."""
NAMES = ("front_ki_ka", "front_kx", "rear_ki_ka", "rear_kx")
SPLIT_NAMES = ("front_ka", "front_ki", "rear_ka", "rear_ki")  # from the coil currents, where recorded
UNITS = {"ki_ka": "N/V", "kx": "N/m", "ka": "A/V", "ki": "N/A"}
MIN_POINTS = 20  # trusted points per plane the fit needs
MODEL_FLOOR = 0.001
"""Each value is stated no better than this fraction of itself, added to its variance: what the fit
leaves beside the noise (the window's bias taken out to first order, the recordings' rate taken as
the control rate). Measured on the simulator at 10 s and 2.5 Hz (8 seeds, both rotors): errors
0.03-0.09 % high in the median and 1.0-1.5 times the noise's deviation of 0.1 % (95 % intervals
holding the truth in 84-88 %); at 4 s and 5 Hz, where the noise's deviation is 0.18 %, 0.9-1.1.
A bound, not a measured scatter (docs/validation.md)."""
CHI2_LIMIT = 4.0
"""Largest reduced chi-square the gains are stated at (plant_fit's rule: the residual's RMS twice the
measurement's random error); the right rotor fits at 1.1, the other flexible rotor's model at 258."""


@dataclass
class BearingGains:
    """The bearings' actuator gains fitted to one plant measurement."""

    machine: str
    values: np.ndarray  # NAMES' order, SI
    covariance: np.ndarray
    nominal: np.ndarray  # the machine's own values (its data), same order
    chi2_reduced: float
    points: int
    band_hz: float
    split: np.ndarray | None = None  # SPLIT_NAMES' order, SI: ka and ki per bearing, or None
    split_std: np.ndarray | None = None
    split_nominal: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    def rows(self) -> list[dict]:
        """Per parameter: value, standard deviation, unit, the machine's data and the ratio to it
        (ki ka and kx per bearing; ka and ki where the coil currents were recorded)."""
        table = list(zip(NAMES, self.values, self.std, self.nominal))
        if self.split is not None:
            table += list(zip(SPLIT_NAMES, self.split, self.split_std, self.split_nominal))
        return [{"parameter": n, "value": float(v), "std": float(s), "unit": UNITS[n.split("_", 1)[1]],
                 "machine": float(m), "ratio": float(v / m)} for n, v, s, m in table]

    def as_dict(self) -> dict:
        """What ``plant gains --json`` prints."""
        return {"machine": self.machine, "band_hz": round(self.band_hz, 1), "points": self.points,
                "chi2_reduced": round(self.chi2_reduced, 3),
                "parameters": {r["parameter"]: {k: (float(f"{v:.6g}") if isinstance(v, float) else v)
                                                for k, v in r.items() if k != "parameter"} for r in self.rows()}}


def with_bearings(params: FlexibleSpindleParams, values: np.ndarray) -> FlexibleSpindleParams:
    """``params`` with the front and rear bearings' ki ka (N/V) and kx (N/m) of ``values`` (NAMES'
    order): ki set to ki ka over the amplifier's gain, which stays the machine's."""
    front, rear = params.front, params.rear
    return replace(params, front=replace(front, ki=values[0] / front.amp_gain, kx=values[1]),
                   rear=replace(rear, ki=values[2] / rear.amp_gain, kx=values[3]))


def nominal(params: FlexibleSpindleParams) -> np.ndarray:
    """The machine's own bearing values, NAMES' order."""
    f, r = params.front, params.rear
    return np.array([f.ki * f.amp_gain, f.kx, r.ki * r.amp_gain, r.kx])


def fit_bearing_gains(measured: PlantMeasurement, params: FlexibleSpindleParams, machine: str,
                      start: np.ndarray | None = None) -> BearingGains:
    """Fit the bearings' ki ka and kx of ``params``'s rotor to ``measured`` (module docstring).

    Parameters
    ----------
    measured : PlantMeasurement
        ``plant identify``'s plant, measured at standstill on every radial axis.
    params : FlexibleSpindleParams
        The machine: its rotor, sensors and amplifiers, and the bearing values the fit starts from.
    machine : str
        Its name, for the record.
    start : ndarray, optional
        Where the fit starts (NAMES' order, SI); default the machine's own values.
    """
    from scipy.optimize import least_squares

    if measured.speed_rpm != 0.0:
        raise BadInputError(f"the plant was measured at {measured.speed_rpm:g} rpm: the bearings' gains are fitted "
                            "at standstill (the rotor model's gyroscopic coupling is not fitted)")
    missing = [a for a in AXES if a not in measured.axes]
    if missing:
        raise BadInputError(f"the plant file has no {', '.join(missing)}: measure every radial axis")
    f = measured.freq_hz
    band_hz = BAND * float(FlexibleLoop(params).free_hz[2])
    cells = [(measured.axes.index(o), measured.axes.index(i)) for o in AXES for i in AXES
             if AXES.index(o) % 2 == AXES.index(i) % 2]  # each plane's own elements
    inband = (f > 0) & (f <= band_hz)
    runs, data, sigma = [], [], []
    for i, j in cells:
        good = inband & (measured.plant.coherence[:, i, j] >= COHERENT)
        runs.append(good)
        data.append(measured.plant.response[good, i, j])
        sigma.append(measured.plant.sigma[good, i, j] / np.sqrt(2))  # each of the real and imaginary parts
    points = int(sum(g.sum() for g in runs))
    if points < 2 * MIN_POINTS:
        raise BadInputError(f"{points} trusted points below {band_hz:.0f} Hz: measure longer or with a larger "
                            "test signal")
    y, w = np.concatenate(data), 1.0 / np.concatenate(sigma)
    base = nominal(params)
    at = [(AXES.index(measured.axes[i]), AXES.index(measured.axes[j])) for i, j in cells]  # in the model's order
    trusted = [g[inband] for g in runs]  # each element's trusted points among the band's

    def residual(scale: np.ndarray) -> np.ndarray:
        model = FlexibleLoop(with_bearings(params, scale * base)).plant_response(0.0, f[inband])
        r = (np.concatenate([model[g, i, j] for g, (i, j) in zip(trusted, at)]) - y) * w
        return np.concatenate([r.real, r.imag])

    def whole(scale: np.ndarray):
        """The model's plant in the measurement's axis order (window_bias's model): up to ten steps
        beyond the band, where the window's kernel around the fitted points reaches; zero above,
        where no point is fitted and the bias is not used."""
        loop = FlexibleLoop(with_bearings(params, scale * base))
        index = [AXES.index(a) for a in measured.axes]
        limit = band_hz + 10 * float(f[1] - f[0])

        def plant(freq_hz: np.ndarray) -> np.ndarray:
            out = np.zeros((freq_hz.size, len(index), len(index)), dtype=complex)
            near = freq_hz <= limit
            out[near] = loop.plant_response(0.0, freq_hz[near])[:, index][:, :, index]
            return out
        return plant

    x0 = np.ones(4) if start is None else np.asarray(start, dtype=float) / base
    sol = least_squares(residual, x0, x_scale=np.full(4, 0.1), diff_step=1e-6)
    # the window's bias, by the first fit seen through the measured loop, taken from the
    # measurement, and the gains fitted again from there (plant_fit's two passes; the recordings'
    # sample rate taken as the control rate)
    bias = window_bias(measured.plant, whole(sol.x), params.sample_rate)
    y = np.concatenate([measured.plant.response[g, i, j] - bias[g, i, j] for g, (i, j) in zip(runs, cells)])
    sol = least_squares(residual, sol.x, x_scale=np.full(4, 0.1), diff_step=1e-6)
    J = sol.jac  # d residual / d scale
    # the sandwich with neighbouring points' errors correlated: the same part of one element at
    # adjacent frequencies (plant_fit's rule, frf.NEIGHBOUR_CORRELATION)
    n = y.size
    starts = np.cumsum([0] + [int(g.sum()) for g in runs])[:-1]
    pair = np.concatenate([s + np.flatnonzero(np.diff(np.flatnonzero(g)) == 1) for s, g in zip(starts, runs)])
    bread = np.linalg.inv(J.T @ J)
    meat = J.T @ J
    for part in (0, n):  # the real parts, then the imaginary parts
        a, b = J[part + pair], J[part + pair + 1]
        meat += NEIGHBOUR_CORRELATION * (a.T @ b + b.T @ a)
    cov_scale = bread @ meat @ bread
    chi2 = float(sol.fun @ sol.fun / (2 * n - 4))
    if not sol.success or chi2 > CHI2_LIMIT:
        raise BadInputError(f"the {machine} rotor model does not reach the measurement below {band_hz:.0f} Hz (reduced "
                            f"chi-square {chi2:.1f}, at most {CHI2_LIMIT:g}, with the bearings' gains free): is it "
                            "this machine's model? No gains stated.")
    values = sol.x * base
    covariance = cov_scale * np.outer(base, base) + np.diag((MODEL_FLOOR * values) ** 2)
    gains = BearingGains(machine, values, covariance, base, chi2, points, band_hz)
    if measured.amplifier is not None:
        _split(gains, measured, params)
    return gains


def _split(gains: BearingGains, measured: PlantMeasurement, params: FlexibleSpindleParams) -> None:
    """ka per bearing from its axes' amplifiers (each fitted over the points the plant's own
    element trusts, from the machine's amplifier data), weighed by their variances, and ki = ki ka
    / ka, their relative variances added (the currents' errors and the gaps' are of different runs'
    parts: independent to first order)."""
    f = measured.freq_hz
    ka, var = {}, {}
    for i, axis in enumerate(measured.axes):
        good = measured.plant.coherence[:, i, i] >= COHERENT
        data = params.axes[AXES.index(axis)]
        if good.sum() < MIN_POINTS:
            raise BadInputError(f"{good.sum()} trusted points of {axis}'s amplifier: measure longer or with a larger "
                                "test signal")
        fitted = amplifier.fit(f[good], measured.amplifier[good, i], measured.amplifier_variance[good, i],
                               params.sample_rate, (data.amp_gain, data.amp_wn_hz, data.amp_zeta))
        ka[axis], var[axis] = fitted.values[0], fitted.covariance[0, 0]
    split, std = [], []
    for b, bearing in enumerate(("front", "rear")):
        w = {a: 1 / var[a] for a in (f"{bearing}_x", f"{bearing}_y")}
        ka_b = sum(w[a] * ka[a] for a in w) / sum(w.values())
        var_ka = 1 / sum(w.values())
        ki_ka, var_ki_ka = gains.values[2 * b], gains.covariance[2 * b, 2 * b]
        ki = ki_ka / ka_b
        split += [ka_b, ki]
        std += [np.sqrt(var_ka), abs(ki) * np.sqrt(var_ki_ka / ki_ka**2 + var_ka / ka_b**2)]
    f_ax, r_ax = params.front, params.rear
    gains.split, gains.split_std = np.array(split), np.array(std)
    gains.split_nominal = np.array([f_ax.amp_gain, f_ax.ki, r_ax.amp_gain, r_ax.ki])
