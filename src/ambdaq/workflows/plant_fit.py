"""``ambdaq plant fit``: a parametric model of each axis's plant from its closed-loop measurement,
with the covariance of its parameters (issue 42, item 3; the model: :mod:`ambdaq.analysis.plant_model`).

Each element P_ij of the measured plant with enough trusted points (coherence 0.9 or more: at
standstill the x and y planes do not reach each other, and those elements hold only noise; where
they do, the rotor's gyroscopic coupling at speed, the measurement is refused: the model's modes
are planar) is fitted over them, weighted by its random error, every element with the same poles (they are the
rotor's) and its own residues: a diagonal element is named by its axis, another ``OUT<-IN``; the bending modes start at the measured resonances, the rigid-body modes at
``RIGID_START_HZ``.

A mode's residues over the bearings of one plane are the products of its shape at each sensor
and at each actuator, r_ij = c_i b_j: the mode's residue matrix has rank one (Ewins, Modal
Testing, 2nd ed., section 4.3: the modal constants of one mode are not independent), so where a
plane's two diagonal elements and both elements between them are fitted, each mode they share
holds r_ii r_jj = r_ij r_ji.  The fit states each element's residues on its own; the constraints
are then imposed by restricted (minimum-distance) least squares on the fitted parameters and
their covariance (Seber & Wild, Nonlinear Regression, section 3.2: the linearised projection,
iterated), which moves the poorly seen residues (the rear sensor near the first bending mode's
node: 3 % alone, under 1 % from the three others) and states the covariance that remains.  A Wald
test of the constraints at the unconstrained fit (chi-square, one degree per constraint) guards
it: a plant whose residues are not rank one beyond MODE_SHAPE_LEVEL keeps its unconstrained fit,
and the model says so (``mode_shapes``).  The model file is sealed JSON naming the plant file it came from (path,
SHA-256), its speed and the controller's gains the runs stated.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..analysis.closed_loop import window_bias
from ..analysis.frf import COHERENT, NEIGHBOUR_CORRELATION, interpolate_response
from ..analysis.plant_model import MAX_EVALUATIONS, ModalPlant, PlantFit, fit, mode_names, pole_names
from ..documents.coefficients import file_sha256
from ..documents.sealed import read_sealed, write_sealed
from ..errors import BadInputError
from .plant_identification import PlantMeasurement, load_measurement, resonances

FORMAT, VERSION = "ambdaq-plant-model", 1
STD_HOLDS = ("the measurement's noise, with the window's bias taken out, and for each bending mode's damping what "
             "the frequency step leaves of that bias (RESOLUTION_FLOOR, docs/tuning.md): their 95 % intervals held the "
             "flexible rotor's poles at 2.5 Hz steps over 10 s runs and at 5 Hz over 4 s (docs/validation.md)")
"""What the parameters' standard deviations hold (``plant fit`` says it beside them)."""
RESOLUTION_FLOOR = 0.05
"""A bending mode's damping is stated no better than ``RESOLUTION_FLOOR * (df / (2 zeta f))**2``
of itself, df the frequency step and 2 zeta f the mode's half-power bandwidth, added to its
variance: what is left of the window's bias once it is taken out, which grows as the square of
the kernel's width over the peak's. Measured on the flexible rotor at 5 Hz steps over 4 s, 16
seeds: the second mode (766 Hz, 7.7 Hz wide, 1.5 steps) scattered 1.5 times the deviation of its
noise alone (the others 0.8-1.15), 2.1 % of its damping, where this floor states 2.1 % beside
the noise's 1.8 %; at 2.5 Hz steps the floor is a quarter. It is a bound, conservative for the
narrowest mode (the first, 3.9 Hz wide: 8 % beside its 4 %), not a measured scatter."""
RIGID_START_HZ = (50.0, 90.0)
"""Where the fit starts the rigid-body modes' unstable poles, Hz: sqrt(k_neg / m) of an AMB rotor is
tens of hertz (the flexible rotor's are 61 and 83 Hz)."""
AMPLIFIER_START = (2000.0, 0.7)  # Hz, damping: a current amplifier's bandwidth is a few kHz


MERGE = 0.01  # resonances of different axes within 1 % are one mode
MIN_POINTS = 20  # trusted points an element needs to be fitted
MODE_SHAPE_LEVEL = 0.001
"""The Wald test's level: the mode-shape constraints are imposed unless the unconstrained fit
rejects them at this level (their chi-square beyond its 99.9 % quantile)."""
CHI2_LIMIT = 4.0
"""Largest reduced chi-square a model is kept at: its residual's RMS twice the measurement's random
error (the flexible rotor at standstill fits at 0.6-0.8); beyond, the model misses something the
measurement holds, and its parameters and their covariance mean nothing."""


@dataclass
class FittedPlant:
    """The model of the axes of one plant file: their poles shared, each axis its residues."""

    fit: PlantFit
    speed_rpm: float
    h: float
    source: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)
    mode_shapes: dict = field(default_factory=dict)
    """The mode-shape constraints (module docstring): how many, their Wald chi-square at the
    unconstrained fit, whether imposed; empty in a file from before them."""

    @property
    def responses(self) -> list[str]:
        """The elements fitted: ``AXIS`` on the diagonal, ``OUT<-IN`` across axes."""
        return self.fit.axes

    def rows(self) -> list[dict]:
        """Per parameter: value and standard deviation (what a table shows)."""
        f = self.fit
        return [{"parameter": n, "value": float(v), "std": float(s)} for n, v, s in zip(f.names, f.values, f.std)]

    def as_dict(self) -> dict:
        """What ``plant fit --json`` prints."""
        f = self.fit
        return {"speed_rpm": self.speed_rpm, "source": self.source, "responses": f.axes,
                "chi2_reduced": round(f.chi2_reduced, 3), "points": f.points, "std_holds": STD_HOLDS,
                "mode_shapes": self.mode_shapes,
                "parameters": {n: {"value": float(f"{v:.6g}"), "std": float(f"{s:.3g}")}
                               for n, v, s in zip(f.names, f.values, f.std)}}

    def response(self, output: str, freq_hz: np.ndarray, input_: str | None = None) -> np.ndarray:
        """The model's P[output, input] (default the diagonal, input = output) at ``freq_hz`` (Hz), m/V."""
        label = output if input_ in (None, output) else f"{output}<-{input_}"
        if label not in self.fit.axes:
            raise BadInputError(f"the model has no {label} (it has {', '.join(self.fit.axes)})")
        return self.fit.model.response(freq_hz)[:, self.fit.axes.index(label)]

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        f = self.fit
        doc = {"format": FORMAT, "version": VERSION, "speed_rpm": self.speed_rpm, "sample_period_s": self.h,
               "source": self.source, "controller": self.controller, "responses": f.axes,
               "rigid_modes": len(f.model.rigid), "bending_modes": len(f.model.bending),
               "names": f.names, "values": f.values.tolist(), "covariance": f.covariance.tolist(),
               "chi2_reduced": f.chi2_reduced, "points": f.points, "mode_shapes": self.mode_shapes}
        return write_sealed(path, doc, overwrite=overwrite)


def fit_measurement(measured: PlantMeasurement, h: float, axes: list[str] | None = None,
                    source: dict | None = None) -> FittedPlant:
    """Fit the elements of ``measured`` among ``axes`` (default every axis) together at control
    period ``h`` (s): each diagonal one (refused with fewer than MIN_POINTS trusted points) and each
    across axes with at least MIN_POINTS."""
    axes = axes or measured.axes
    data, cells, found, coupled = {}, {}, [], []
    f = measured.freq_hz
    for axis in axes:
        if axis not in measured.axes:
            raise BadInputError(f"the plant file has no axis {axis!r} (it has {', '.join(measured.axes)})")
    for out in axes:
        for inp in axes:
            i, j = measured.axes.index(out), measured.axes.index(inp)
            good = measured.plant.coherence[:, i, j] >= COHERENT
            if good.sum() < MIN_POINTS:
                if i == j:
                    raise BadInputError(f"{out}: {int(good.sum())} trusted points (coherence >= {COHERENT:g}); measure "
                                        "longer or with a larger test signal")
                continue
            label = out if i == j else f"{out}<-{inp}"
            data[label] = (measured.plant.response[:, i, j], measured.plant.sigma[:, i, j], good)
            cells[label] = (i, j)
            if None not in (_plane(out), _plane(inp)) and _plane(out) != _plane(inp):
                coupled.append(f"{out}<-{inp}")
            # a mode with a node at one axis's bearing or sensor is missing from that axis's own
            # response and not from another's: the modes are every element's resonances
            found += resonances(f, np.abs(measured.plant.response[:, i, j]), good)
    if coupled:
        raise BadInputError(
            f"the x and y planes reach each other in this measurement ({', '.join(coupled)} trusted): the rotor's "
            f"gyroscopic coupling at {measured.speed_rpm:g} rpm turns its modes into whirls with complex modal gains, "
            "which this model (modes in each plane, real gains) does not have yet: fit a standstill measurement")
    modes: list[float] = []
    for hz in sorted(found):
        if not modes or hz > modes[-1] * (1 + MERGE):
            modes.append(hz)
    cross = {(a, b): measured.plant.covariance[:, *cells[a], *cells[b]] for a in cells for b in cells if a < b}
    result = fit(f, data, h, rigid_hz=list(RIGID_START_HZ), bending_hz=modes, amplifier_hz=AMPLIFIER_START[0],
                 amplifier_zeta=AMPLIFIER_START[1], neighbour_correlation=NEIGHBOUR_CORRELATION, cross_covariance=cross)
    _check(result, modes, measured.speed_rpm)
    # the window's bias, by the first model seen through the measured loop, taken from the
    # measurement, and the model fitted again from where the first one ended (one pass: a second
    # moves the parameters by a hundredth of their deviations on the flexible rotor)
    # (the recordings' sample rate taken as the control rate: the kernel's shape in frequency steps
    # hardly depends on how many samples a segment has, once it has hundreds)
    bias = window_bias(measured.plant, _matrix(result, cells, measured), 1.0 / h)
    data = {label: (p - bias[:, *cells[label]], sigma, good) for label, (p, sigma, good) in data.items()}
    named = dict(zip(result.names, result.values))
    m, b = len(RIGID_START_HZ), len(modes)
    result = fit(f, data, h, rigid_hz=[named[f"rigid{k + 1}_hz"] for k in range(m)],
                 bending_hz=[named[f"mode{k + 1}_hz"] for k in range(b)], amplifier_hz=named["amplifier_hz"],
                 amplifier_zeta=named["amplifier_zeta"], neighbour_correlation=NEIGHBOUR_CORRELATION,
                 cross_covariance=cross)
    _check(result, modes, measured.speed_rpm)
    result, shapes = _mode_shapes(result, h)
    return FittedPlant(_resolution_floor(result, float(np.median(np.diff(f)))), measured.speed_rpm, h, source or {},
                       measured.controller, shapes)


def _mode_shapes(result: PlantFit, h: float) -> tuple[PlantFit, dict]:
    """``result`` with each mode's residues over a plane's pair of bearings made rank one (the
    module docstring), and what was done; ``h`` the control period (s)."""
    index = {name: k for k, name in enumerate(result.names)}
    constraints = []  # the positions of (r_ii, r_jj, r_ij, r_ji), one mode and one pair each
    diagonal = [a for a in result.axes if "<-" not in a]
    for n, a in enumerate(diagonal):
        for b in diagonal[n + 1 :]:
            if _plane(a) is None or _plane(a) != _plane(b):
                continue
            for mode in mode_names(len(result.model.rigid), len(result.model.bending)):
                four = [f"{label}.{mode}_residue" for label in (a, b, f"{a}<-{b}", f"{b}<-{a}")]
                if all(name in index for name in four):
                    constraints.append([index[name] for name in four])
    if not constraints:
        return result, {}
    c = np.array(constraints)
    fitted, cov = result.values, result.covariance

    def residual_and_jacobian(v):  # g = r_ii r_jj - r_ij r_ji and its derivative
        g = v[c[:, 0]] * v[c[:, 1]] - v[c[:, 2]] * v[c[:, 3]]
        jac = np.zeros((len(c), v.size))
        rows = np.arange(len(c))
        jac[rows, c[:, 0]], jac[rows, c[:, 1]] = v[c[:, 1]], v[c[:, 0]]
        jac[rows, c[:, 2]], jac[rows, c[:, 3]] = -v[c[:, 3]], -v[c[:, 2]]
        return g, jac

    g, jac = residual_and_jacobian(fitted)
    wald = float(g @ np.linalg.solve(jac @ cov @ jac.T, g))
    from scipy.stats import chi2

    shapes = {"constraints": len(c), "wald_chi2": round(wald, 3),
              "limit": round(float(chi2.ppf(1 - MODE_SHAPE_LEVEL, len(c))), 3)}
    shapes["imposed"] = wald <= shapes["limit"]
    if not shapes["imposed"]:
        return result, shapes
    values = fitted
    for _ in range(20):  # Gauss-Newton on the linearised constraints, from the fit outward
        g, jac = residual_and_jacobian(values)
        spread = jac @ cov @ jac.T
        if np.all(np.abs(g) <= 1e-9 * np.sqrt(np.diag(spread))):  # each constraint held to a billionth of its deviation
            break
        values = fitted - cov @ jac.T @ np.linalg.solve(spread, g + jac @ (fitted - values))
    else:
        return result, {**shapes, "imposed": False, "unsettled": True}
    covariance = cov - cov @ jac.T @ np.linalg.solve(spread, jac @ cov)
    covariance = (covariance + covariance.T) / 2
    m, b = len(result.model.rigid), len(result.model.bending)
    model = model_from_values(Path("fit"), values, result.names, m, b, result.axes, h)
    return replace(result, model=model, values=values, covariance=covariance), shapes


def _resolution_floor(result: PlantFit, step_hz: float) -> PlantFit:
    """``result`` with RESOLUTION_FLOOR's variance added to each bending mode's damping, at a
    frequency step of ``step_hz`` (Hz)."""
    named = dict(zip(result.names, result.values))
    covariance = result.covariance.copy()
    for k in range(len(result.model.bending)):
        hz, zeta = named[f"mode{k + 1}_hz"], named[f"mode{k + 1}_zeta"]
        i = result.names.index(f"mode{k + 1}_zeta")
        covariance[i, i] += (RESOLUTION_FLOOR * (step_hz / (2 * zeta * hz)) ** 2 * zeta) ** 2
    return replace(result, covariance=covariance)


def _check(result: PlantFit, modes: list[float], speed_rpm: float) -> None:
    """Refuse a model that does not reach the measurement (CHI2_LIMIT) or did not settle."""
    if result.chi2_reduced > CHI2_LIMIT or not result.converged:
        spinning = (" At speed the gyroscopic coupling turns the rigid-body modes into whirls and gives the modes "
                    "complex modal gains, which this model does not have yet: fit a standstill measurement."
                    if speed_rpm > 0 else "")
        unsettled = "" if result.converged else f", the search unsettled after {MAX_EVALUATIONS} evaluations"
        raise BadInputError(f"the model does not reach the measurement: reduced chi-square {result.chi2_reduced:.1f} "
                            f"(at most {CHI2_LIMIT:g}){unsettled} with {len(modes)} bending modes at "
                            f"{', '.join(f'{hz:g}' for hz in modes)} Hz; no model written.{spinning}")


def _matrix(result: PlantFit, cells: dict[str, tuple[int, int]], measured: PlantMeasurement):
    """The whole plant as the window's bias needs it: the model's elements where it has them, the
    measurement between its frequencies elsewhere (the elements too noisy to fit)."""
    def plant(freq_hz: np.ndarray) -> np.ndarray:
        out = interpolate_response(measured.freq_hz, measured.plant.response, freq_hz)
        model = result.model.response(freq_hz)
        for n, label in enumerate(result.axes):
            out[:, *cells[label]] = model[:, n]
        return out
    return plant


def _plane(axis: str) -> str | None:
    """The plane an axis moves in, by its name (``front_x`` -> ``x``), or None."""
    tail = axis.rsplit("_", 1)[-1]
    return tail if tail in ("x", "y") else None


def fit_file(path: str | Path, h: float, axes: list[str] | None = None) -> tuple[PlantMeasurement, FittedPlant]:
    """The plant file ``plant identify`` wrote, and its fitted model."""
    measured = load_measurement(path)
    return measured, fit_measurement(measured, h, axes, {"path": str(path), "sha256": file_sha256(Path(path))})


def load_model(path: str | Path) -> FittedPlant:
    """Read a model file ``plant fit`` wrote; BadInputError naming what is wrong."""
    path = Path(path)
    doc = read_sealed(path, FORMAT, VERSION, "plant model file")
    try:
        h = float(doc["sample_period_s"])
        axes = doc["responses"]
        if not isinstance(axes, list) or not axes or not all(isinstance(a, str) for a in axes):
            raise ValueError("responses must be a list of names")
        names = doc["names"]
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ValueError("names must be a list of names")
        values = np.array(doc["values"], dtype=float)
        cov = np.array(doc["covariance"], dtype=float)
        m, b = doc["rigid_modes"], doc["bending_modes"]
        if not all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 64 for x in (m, b)):
            raise ValueError("rigid_modes and bending_modes must be integers from 0 to 64")
        if values.shape != (len(names),) or cov.shape != (values.size, values.size) or values.size < m + 2 * b + 3:
            raise ValueError(f"{values.size} values for {len(names)} names, {m} rigid and {b} bending modes")
        chi2, points, speed = float(doc["chi2_reduced"]), int(doc["points"]), float(doc.get("speed_rpm", 0.0))
        source, controller = doc.get("source", {}), doc.get("controller", {})
        shapes = doc.get("mode_shapes", {})
        if not all(isinstance(x, dict) for x in (source, controller, shapes)):
            raise ValueError("source, controller and mode_shapes must be objects")
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as err:
        raise BadInputError(f"{path}: malformed plant model file ({err})") from None
    if not (np.all(np.isfinite(values)) and np.all(np.isfinite(cov)) and np.isfinite(h) and h > 0 and np.isfinite(chi2)
            and np.isfinite(speed)):
        raise BadInputError(f"{path}: the plant model holds a value that is not a finite number")
    if np.any(values[: m + b] <= 0) or np.any(values[m + b : m + 2 * b] < 0) or values[m + 2 * b] <= 0:
        raise BadInputError(f"{path}: the plant model's frequencies must be above 0 and its damping at least 0")
    result = PlantFit(model_from_values(path, values, names, m, b, axes, h), list(axes), list(names), values, cov, chi2,
                      points)
    return FittedPlant(result, speed, h, source, controller, shapes)


def model_from_values(path: Path, values: np.ndarray, names: list[str], m: int, b: int, axes: list[str],
                      h: float) -> ModalPlant:
    """The model from its engineering values (Hz, damping, s, residues m/V/s^2, residuals m/V), each
    placed by its name (:func:`~ambdaq.analysis.plant_model.pole_names`, ``AXIS.modeK_residue``,
    ``AXIS.residual``); BadInputError naming one that is not the model's."""
    poles = pole_names(m, b)
    if list(names[: len(poles)]) != poles:
        raise BadInputError(f"{path}: the plant model's first parameters must be {', '.join(poles)}")
    modes = mode_names(m, b)
    residues, residual, seen = np.zeros((len(axes), m + b)), np.zeros(len(axes)), set()
    for name, value in zip(names[len(poles):], values[len(poles):]):
        axis, _, what = name.rpartition(".")
        if axis not in axes or name in seen or (what != "residual" and what.removesuffix("_residue") not in modes):
            raise BadInputError(f"{path}: the plant model has a parameter {name!r} that is not one of its responses' "
                                "residues or residuals (or has it twice)")
        seen.add(name)
        if what == "residual":
            residual[axes.index(axis)] = value
        else:
            residues[axes.index(axis), modes.index(what.removesuffix("_residue"))] = value
    two_pi = 2 * np.pi
    return ModalPlant(two_pi * values[:m], np.column_stack([two_pi * values[m : m + b], values[m + b : m + 2 * b]]),
                      residues, (float(two_pi * values[m + 2 * b]), float(values[m + 2 * b + 1])),
                      float(values[m + 2 * b + 2]), h, residual if any(n.endswith(".residual") for n in seen) else None)
