"""``ambdaq plant identify``: the plant of a levitated machine, measured in closed loop (issue 42,
item 2), from one excited run per axis (the runs ``iso stability`` records: white noise at the
sensor summing point).

Per run, the H1 responses from the test signal to the gap, to the controller's output and to
the command error in one estimate (:func:`~ambdaq.workflows.frf.estimate_run`); over the excited axes, the
plant by the joint input-output estimator (:mod:`ambdaq.analysis.closed_loop`: unbiased by the
feedback, and independent of the controller), with its random error; per axis, the sensitivity
S = -e/r and the complementary sensitivity T = 1 - S.  The plant file is sealed JSON with every
run's path and SHA-256, the speed and the controller's gains the recordings state.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..analysis import amplifier
from ..analysis.closed_loop import ClosedLoopPlant, joint_input_output
from ..analysis.frf import COHERENT
from ..daq.quality import MAX_LOST
from ..daq.recording import Recording
from ..documents.sealed import read_sealed, write_sealed
from ..errors import BadInputError
from ..roles import CONTROL, CURRENT, ERROR, FF, GAP
from .frf import ExcitedRun, check_runs, estimate_run

FORMAT, VERSION = "ambdaq-plant-frf", 2  # 2: the error covariance across elements, the controller's response
SPEED_TOLERANCE = 0.01  # the runs of one plant ran within 1 % (and 20 rpm) of each other
SPEED_FLOOR_RPM = 20.0
FLANK = 6  # points on either side of a resonance's top, one of which must be trusted


@dataclass
class PlantMeasurement:
    """The plant and the loop's sensitivities of one machine at one speed.

    Attributes
    ----------
    axes : list of str
        The excited axes, the plant's inputs and outputs in this order.
    plant : ClosedLoopPlant
        P[output, input] (m/V) with its random error and coherence.
    sensitivity : ndarray of complex, shape (n, axes)
        S per axis, S = -e / r (dimensionless).
    sensitivity_coherence : ndarray, shape (n, axes)
    speed_rpm : float
        The runs' median speed.
    sources : list of dict
        Per run: path, sha256, speed_rpm, segments, the axis it excited.
    controller : dict
        The controller's gains the recordings state (``controller.pid.*`` of their calibration).
    amplifier : ndarray of complex, shape (n, axes), optional
        Per axis, its coil current per controller output (A/V), where every run records the coil
        currents (:func:`ambdaq.analysis.amplifier.response`); None otherwise.
    amplifier_variance : ndarray, shape (n, axes), optional
        Its error's variance, A^2/V^2.
    """

    axes: list[str]
    plant: ClosedLoopPlant
    sensitivity: np.ndarray
    sensitivity_coherence: np.ndarray
    speed_rpm: float
    sources: list[dict] = field(default_factory=list)
    controller: dict = field(default_factory=dict)
    amplifier: np.ndarray | None = None
    amplifier_variance: np.ndarray | None = None

    @property
    def freq_hz(self) -> np.ndarray:
        return self.plant.freq_hz

    def subset(self, axes: list[str]) -> "PlantMeasurement":
        """The diagonal view of some axes (their own responses, sensitivities and sources)."""
        idx = [self.axes.index(a) for a in axes]
        amp = None if self.amplifier is None else (self.amplifier[:, idx], self.amplifier_variance[:, idx])
        return PlantMeasurement(list(axes), self.plant.subset(idx), self.sensitivity[:, idx], self.sensitivity_coherence[:, idx],
                                self.speed_rpm, [s for s in self.sources if s.get("excited") in axes], self.controller,
                                *(amp or (None, None)))

    def rows(self) -> list[dict]:
        """Per axis, what a table shows: the sensitivity's peak (dB, Hz), the plant's coherent band
        and its resonances there (local maxima of |P| on the diagonal, Hz)."""
        out = []
        f = self.freq_hz
        for i, axis in enumerate(self.axes):
            s_db = 20 * np.log10(np.abs(self.sensitivity[:, i]))
            trusted = self.sensitivity_coherence[:, i] >= COHERENT
            peak = int(np.argmax(np.where(trusted, s_db, -np.inf))) if trusted.any() else int(np.argmax(s_db))
            p = np.abs(self.plant.response[:, i, i])
            good = self.plant.coherence[:, i, i] >= COHERENT
            band = (float(f[good][0]), float(f[good][-1])) if good.any() else None
            maxima = resonances(f, p, good)
            out.append({"axis": axis, "sensitivity_peak_db": round(float(s_db[peak]), 2),
                        "sensitivity_peak_hz": float(f[peak]),
                        "plant_coherent_band_hz": list(band) if band else None,
                        "plant_resonances_hz": maxima,
                        "plant_median_relative_error": round(float(np.median(
                            (self.plant.sigma[:, i, i] / np.maximum(p, 1e-300))[good])), 4) if good.any() else None})
        return out

    def as_dict(self) -> dict:
        """What ``plant identify --json`` prints."""
        return {"axes": self.axes, "speed_rpm": round(self.speed_rpm, 1),
                "resolution_hz": float(self.freq_hz[1] - self.freq_hz[0]), "points": int(len(self.freq_hz)),
                "estimator": "joint input-output: P = H_RY H_RU^-1, both referred to the test signal",
                "rows": self.rows(), "sources": self.sources}

    def to_document(self) -> dict:
        p = self.plant
        k = len(self.axes)
        cells = {out: {inp: {"re": p.response[:, i, j].real.tolist(), "im": p.response[:, i, j].imag.tolist(),
                             "coherence": p.coherence[:, i, j].tolist()}
                       for j, inp in enumerate(self.axes)} for i, out in enumerate(self.axes)}
        h_ru = {out: {inp: {"re": p.controller_response[:, i, j].real.tolist(),
                            "im": p.controller_response[:, i, j].imag.tolist()}
                      for j, inp in enumerate(self.axes)} for i, out in enumerate(self.axes)}
        # the covariance of the elements' errors (Hermitian): its upper triangle, row by row, per
        # frequency, to seven digits (a deviation needs two)
        upper = np.triu_indices(k * k)
        tri = p.covariance.reshape(-1, k * k, k * k)[:, upper[0], upper[1]]
        sens = {a: {"re": self.sensitivity[:, i].real.tolist(), "im": self.sensitivity[:, i].imag.tolist(),
                    "coherence": self.sensitivity_coherence[:, i].tolist()} for i, a in enumerate(self.axes)}
        return {"format": FORMAT, "version": VERSION, "axes": self.axes, "speed_rpm": self.speed_rpm,
                "input": CONTROL, "output": GAP, "unit": "m/V", "freq_hz": self.freq_hz.tolist(),
                "plant": cells, "controller_response": h_ru,
                "error_covariance": {"elements": [[out, inp] for out in self.axes for inp in self.axes],
                                     "re": _digits(tri.real), "im": _digits(tri.imag)},
                "sensitivity": sens, "sources": self.sources, "controller": self.controller,
                **({} if self.amplifier is None else {"amplifier": {
                    "input": CONTROL, "output": CURRENT, "unit": "A/V",
                    **{a: {"re": self.amplifier[:, i].real.tolist(), "im": self.amplifier[:, i].imag.tolist(),
                           "variance": _digits(self.amplifier_variance[:, i])} for i, a in enumerate(self.axes)}}})}

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        return write_sealed(path, self.to_document(), overwrite=overwrite)


def _digits(values: np.ndarray) -> list:
    """Nested lists of ``values`` to seven significant digits."""
    return np.vectorize(lambda v: float(f"{v:.7g}"), otypes=[float])(values).tolist()


def resonances(freq_hz: np.ndarray, magnitude: np.ndarray, trusted: np.ndarray, *, above_hz: float = 150.0,
               prominence: float = 2.0) -> list[float]:
    """The plant's resonances: peaks of ``magnitude`` standing ``prominence`` times above their
    surroundings (scipy's peak prominence, on the log of the magnitude) above ``above_hz`` (Hz;
    below it the rigid-body modes' roll-off has no peak), where the points on either side are
    trusted (a lightly damped mode's top loses coherence to the window's leakage, its flanks do
    not; noise peaks have no trusted flanks), in Hz."""
    from scipy.signal import find_peaks

    peaks, _ = find_peaks(np.log(np.maximum(magnitude, 1e-300)), prominence=np.log(prominence))
    flanked = [k for k in peaks if trusted[max(k - FLANK, 0) : k].any() and trusted[k + 1 : k + 1 + FLANK].any()]
    return [float(freq_hz[k]) for k in flanked if freq_hz[k] > above_hz]


def _controller_gains(rec: Recording) -> dict:
    return {k: v for device in rec.devices.values() for k, v in device.calibration.items()
            if k.startswith("controller.pid.")}


def identify(recs: list[Recording], resolution_hz: float = 10.0, max_lost: float = MAX_LOST) -> PlantMeasurement:
    """The plant over the axes ``recs`` excited, one run each (see the module docstring).

    Parameters
    ----------
    recs : list of Recording
        One run per excited axis, white noise on the controller's test-signal input, each with the
        gap, the controller's output (``/amb/control``), the command error and the test signal.
    resolution_hz : float
        Frequency step, Hz.
    max_lost : float
        Share of samples a run may have lost (a hole is a jump inside a Welch segment).
    """
    if not recs:
        raise BadInputError("no recordings: give one excited run per axis (iso stability --runs DIR keeps them)")
    for rec in recs:
        if CONTROL not in rec:
            raise BadInputError(f"{rec.path}: no controller output ({CONTROL}): the plant is measured from what the "
                                "controller sent to the amplifiers, which this controller does not stream")
    runs: list[ExcitedRun] = []
    currents = all(rec.has_role("current") for rec in recs)  # the amplifiers too (ka apart from ki)
    for rec in recs:  # each checked against those before it as it comes
        runs.append(estimate_run(rec, resolution_hz, None, FF, [GAP, CONTROL, ERROR] + [CURRENT] * currents, max_lost))
        check_runs(runs)
    axes = [run.axis for run in runs]
    speeds = [run.source["speed_rpm"] for run in runs]
    median = float(np.median(speeds))
    if any(abs(s - median) > max(SPEED_TOLERANCE * median, SPEED_FLOOR_RPM) for s in speeds):
        raise BadInputError("the runs ran at different speeds (" + ", ".join(f"{a} {s:,.0f} rpm" for a, s in
                                                                              zip(axes, speeds)) + "): one plant is one speed")
    # each run's outputs in the order gaps, controller outputs, command errors, each in ``axes``' order
    order = []
    for role in (GAP, CONTROL, ERROR):
        for a in axes:
            try:
                order.append([run.outputs.index((role, a)) for run in runs])
            except ValueError:
                raise BadInputError(f"the {role} has no field {a}: the plant is measured between the same axes at the "
                                    "gaps, the controller's outputs and the command errors") from None
    order = np.array(order)  # (3 axes, runs)
    k = len(axes)

    def matrix(what, block):  # (n, outputs, runs) of one role
        return np.stack([getattr(run.estimate, what)[:, order[block * k : (block + 1) * k, j]]
                         for j, run in enumerate(runs)], axis=-1)

    error = np.stack([run.estimate.error[:, order[: 2 * k, j]][:, :, order[: 2 * k, j]] for j, run in enumerate(runs)])
    try:
        plant = joint_input_output(matrix("response", 0), matrix("response", 1), matrix("coherence", 0),
                                   matrix("coherence", 1), error, runs[0].estimate.freq_hz)
    except ValueError as err:
        raise BadInputError(f"the plant cannot be solved: {err}") from None
    sens = -np.stack([run.estimate.response[:, order[2 * k + j, j]] for j, run in enumerate(runs)], axis=1)
    sens_coh = np.stack([run.estimate.coherence[:, order[2 * k + j, j]] for j, run in enumerate(runs)], axis=1)
    sources = [{**run.source, "excited": run.axis} for run in runs]
    amp = _amplifiers(runs) if currents else (None, None)
    return PlantMeasurement(axes, plant, sens, sens_coh, median, sources, _controller_gains(recs[0]), *amp)


def _amplifiers(runs: list[ExcitedRun]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Per run, its excited axis's coil current per controller output (A/V) and the variance of
    its error, both referred to the test signal; (None, None) where a run's currents do not name
    its axis (a rig file that maps other fields)."""
    out, var = [], []
    for run in runs:
        try:
            i, u = run.outputs.index((CURRENT, run.axis)), run.outputs.index((CONTROL, run.axis))
        except ValueError:
            return None, None
        est = run.estimate
        a, v = amplifier.response(est.response[:, i], est.response[:, u], est.error[:, i, i].real,
                                  est.error[:, i, u], est.error[:, u, u].real)
        out.append(a)
        var.append(v)
    return np.stack(out, axis=1), np.stack(var, axis=1)


def load_measurement(path: str | Path) -> PlantMeasurement:
    """Read and check a plant file ``plant identify`` wrote: format, version, checksum, shapes,
    finite values; BadInputError naming what is wrong."""
    path = Path(path)
    doc = read_sealed(path, FORMAT, VERSION, "plant file")
    try:
        axes = doc["axes"]
        if not isinstance(axes, list) or not axes or not all(isinstance(a, str) for a in axes) or len(set(axes)) < len(axes):
            raise ValueError("axes must be a list of distinct names")
        f = np.array(doc["freq_hz"], dtype=float)
        n, k = f.shape[0], len(axes)
        resp, h_ru, coh = (np.empty((n, k, k), dtype=complex), np.empty((n, k, k), dtype=complex), np.empty((n, k, k)))
        for i, out in enumerate(axes):
            for j, inp in enumerate(axes):
                cell, ctl = doc["plant"][out][inp], doc["controller_response"][out][inp]
                resp[:, i, j] = np.array(cell["re"], dtype=float) + 1j * np.array(cell["im"], dtype=float)
                coh[:, i, j] = np.array(cell["coherence"], dtype=float)
                h_ru[:, i, j] = np.array(ctl["re"], dtype=float) + 1j * np.array(ctl["im"], dtype=float)
        errors = doc["error_covariance"]
        if errors["elements"] != [[out, inp] for out in axes for inp in axes]:
            raise ValueError("the error covariance's elements must be every [output, input] of the axes, row by row")
        upper = np.triu_indices(k * k)
        tri = np.array(errors["re"], dtype=float) + 1j * np.array(errors["im"], dtype=float)
        if tri.shape != (n, upper[0].size):
            raise ValueError(f"the error covariance must hold {upper[0].size} values at each of {n} frequencies")
        cov = np.zeros((n, k * k, k * k), dtype=complex)
        cov[:, upper[0], upper[1]] = tri
        cov[:, upper[1], upper[0]] = tri.conj()
        sens = np.stack([np.array(doc["sensitivity"][a]["re"], float) + 1j * np.array(doc["sensitivity"][a]["im"], float)
                         for a in axes], axis=1)
        sens_coh = np.stack([np.array(doc["sensitivity"][a]["coherence"], float) for a in axes], axis=1)
        speed = float(doc["speed_rpm"])
        sources, controller = doc.get("sources", []), doc.get("controller", {})
        amp = amp_var = None
        if "amplifier" in doc:  # written where the runs recorded the coil currents
            amp = np.stack([np.array(doc["amplifier"][a]["re"], float) + 1j * np.array(doc["amplifier"][a]["im"], float)
                            for a in axes], axis=1)
            amp_var = np.stack([np.array(doc["amplifier"][a]["variance"], float) for a in axes], axis=1)
            if amp.shape != (n, k) or amp_var.shape != (n, k) or np.any(amp_var < 0) or not (
                    np.all(np.isfinite(amp)) and np.all(np.isfinite(amp_var))):
                raise ValueError("the amplifier's response must be finite, one value per frequency and axis, "
                                 "its variances at least 0")
        if not isinstance(sources, list) or not all(isinstance(x, dict) for x in sources) or not isinstance(controller, dict):
            raise ValueError("sources must be a list of objects, controller an object")
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as err:
        raise BadInputError(f"{path}: malformed plant file ({err})") from None
    if not all(np.all(np.isfinite(v)) for v in (f, resp, h_ru, cov, coh, sens, sens_coh)) or not np.isfinite(speed):
        raise BadInputError(f"{path}: the plant file holds a value that is not a finite number")
    var = cov.diagonal(axis1=1, axis2=2).real
    # a covariance: variances at least 0, no correlation above 1 (beyond the stored digits' rounding)
    if (f.ndim != 1 or n < 2 or np.any(np.diff(f) <= 0) or f[0] <= 0 or speed < 0 or np.any(var < 0)
            or np.any(np.abs(cov) ** 2 > var[:, :, None] * var[:, None, :] * (1 + 1e-5) + 1e-300)
            or np.any((coh < 0) | (coh > 1)) or np.any((sens_coh < 0) | (sens_coh > 1))):
        raise BadInputError(f"{path}: the plant file's frequencies must rise from above 0, its error covariance be "
                            "one (variances at least 0, correlations at most 1), its coherences within 0..1 and its "
                            "speed at least 0")
    plant = ClosedLoopPlant(f, resp, cov.reshape(n, k, k, k, k), coh, h_ru)
    return PlantMeasurement(list(axes), plant, sens, sens_coh, speed, sources, controller, amp, amp_var)
