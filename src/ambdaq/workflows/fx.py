"""Base-motion compensators (Kang & Jung): the stepped-sine campaign, MFXLMS per frequency, the FIR
fit (docs/base-motion.md).

The campaign drives two devices by URL, the same on hardware and on the simulator: the shaker
generator (SCPI, :class:`~ambdaq.drivers.shaker.Shaker`) and the AMB controller, recorded for
every step.  A ``sim://`` URL is served in this process and reached over its transports.
"""

from __future__ import annotations

import json
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..analysis.frf import interpolate_response
from ..analysis.mfxlms import fit_fir, knee, mfxlms, run_beta, separate
from ..analysis.runout import harmonic_fit
from ..documents.coefficients import Coefficients, file_sha256, now_iso
from ..documents.compensator_points import PAIRS, load_points, save_points
from ..documents.frequency_response import FrequencyResponse
from ..daq.quality import MAX_LOST, require_complete
from ..daq.recording import load, same_instants
from ..acquisition.recorder import Recorder, RecordOptions
from ..drivers.registry import endpoints, open_device
from ..drivers.shaker import Shaker, drive_problem
from ..errors import BadInputError, DeviceError
from ..machines.base_motion import AXES, BASE_AXES, PLANES, SAMPLE_RATE

CAMPAIGN = "campaign.json"
TOPICS = ("/amb/gap", "/base/accel")  # what the controller must stream for the campaign
STEP_ATTEMPTS = 3  # recordings of a step that loses samples, before the campaign stops
MAX_FIT_ERROR_PCT = 25.0
"""A FIR fit may miss a point by this much (%): good campaigns leave the points within 7 % of W*
(the secondary path's error at 5 Hz, docs/base-motion.md) and the fit within 1 % of them."""
MAX_BASE_M_S2 = 50.0  # peak base acceleration a campaign step may ask for


def campaign(device: str, shaker: str | None, shaker_gain: float | None, freqs: list[float], amplitude: float,
             ratios: list[complex], seconds: float, settle: float, folder: Path,
             on_step: Callable[[float, complex, Path], None] | None = None, max_lost: float = MAX_LOST) -> Path:
    """Run the stepped sine: for every frequency and disturbance ratio alpha = d1/d2 (eq. A-10) set
    the shakers, wait ``settle`` s, record the controller for ``seconds`` s into its own file.

    Parameters
    ----------
    device : str
        The AMB controller's URL (it must stream /amb/gap and /base/accel), or ``sim://base-motion``.
    shaker : str, optional
        The generator's URL; a simulated rig serves its own.
    shaker_gain : float, optional
        Base acceleration per generator volt, m/s^2/V; a simulated rig reports its shakers'.
    freqs : list of float
        Step frequencies, Hz.
    amplitude : float
        Peak base acceleration at accelerometer 2, m/s^2.
    ratios : list of two complex
        The disturbance ratios each frequency is run with (eq. A-17 needs two).
    seconds, settle : float
        Recorded and waited per step, s.
    folder : Path
        Where the step files and ``campaign.json`` go.
    on_step : callable, optional
        Called with (frequency, alpha, file) after each step.
    max_lost : float
        The share of samples (0..1) a step may lose; a step that loses more is recorded again, up
        to STEP_ATTEMPTS times, and then the campaign stops naming it (DeviceError).

    Returns
    -------
    Path
        The campaign file.
    """
    if len(ratios) != 2 or abs(ratios[0] - ratios[1]) < 1e-9:
        raise BadInputError("--alphas: give two different ratios (Kang & Jung eq. A-17 needs both)")
    if not 0 < amplitude <= MAX_BASE_M_S2:
        raise BadInputError(f"amplitude must be > 0 and <= {MAX_BASE_M_S2:g} m/s^2, not {amplitude:g}")
    folder.mkdir(parents=True, exist_ok=True)
    with ExitStack() as stack:
        ep = stack.enter_context(endpoints(device))
        controller_url = ep.urls.get("controller", device)
        shaker_url = shaker or ep.urls.get("shaker")
        gain = shaker_gain or ep.facts.get("shaker_gain_m_s2_per_v")
        if shaker_url is None:
            if "controller" in ep.urls:  # a served simulated rig without a shaker generator
                raise BadInputError(f"{device}: this rig has no moving base: no shaker generator to drive")
            raise BadInputError("--shaker URL: give the generator that drives the base shakers "
                                "(scpi:///dev/ttyUSB1, scpi:socket://HOST:5025)")
        if gain is None:
            raise BadInputError("--shaker-gain: give your shakers' base acceleration per generator volt, m/s^2/V")
        for f in freqs:
            problem = drive_problem(amplitude, max(ratios, key=abs), gain)
            if problem:
                raise BadInputError(f"step {f:g} Hz: {problem}")
        shakers = Shaker(shaker_url, gain=gain)
        stack.callback(shakers.close)
        stack.callback(_at_rest, shakers)
        rate = _check_controller(controller_url)
        too_high = [f for f in freqs if not 0 < f < rate / 2]
        if too_high:
            raise BadInputError(f"step {too_high[0]:g} Hz: frequency must be > 0 and below {rate / 2:g} Hz, half the "
                                "controller's rate")
        steps = []
        for f in freqs:
            for a in ratios:
                shakers.sine(f, amplitude, a)
                time.sleep(settle)
                path = folder / f"step_{len(steps):03d}_{f:g}Hz.mcap"
                _record_step(controller_url, path, seconds, max_lost)
                steps.append({"file": path.name, "freq_hz": f, "alpha_commanded": [a.real, a.imag]})
                if on_step is not None:
                    on_step(f, a, path)
        shakers.stop()
        out = folder / CAMPAIGN
        out.write_text(json.dumps({"device": device, "shaker": shakers.identity, "shaker_gain_m_s2_per_v": gain,
                                   "amplitude_m_s2": amplitude, "steps": steps}, indent=2))
    return out


def _record_step(controller_url: str, path: Path, seconds: float, max_lost: float) -> None:
    """One step's recording, made again while it loses more than ``max_lost`` of its samples
    (MFXLMS runs sample by sample: a hole is a jump in its input), at most STEP_ATTEMPTS times."""
    for attempt in range(1, STEP_ATTEMPTS + 1):
        res = Recorder([open_device(controller_url, name="controller")], path, RecordOptions(duration_s=seconds),
                       overwrite=True).run()
        lost = res.drops / max(res.samples + res.drops, 1)
        if lost <= max_lost:
            return
    raise DeviceError(f"{path.name}: lost more than {max_lost:.1%} of its samples in each of {STEP_ATTEMPTS} attempts "
                      f"(the last: {res.drops:,} of {res.samples + res.drops:,}, {lost:.1%}; --max-lost): the "
                      "controller's stream cannot carry this step; the campaign stops here")


def _check_controller(url: str) -> float:
    """The controller's sample rate, once it is known to stream what the campaign records."""
    dev = open_device(url, name="controller")
    try:
        missing = [t for t in TOPICS if t not in {g.topic for g in dev.signal_groups()}]
        if missing:
            raise BadInputError(f"{url}: the device streams no {', '.join(missing)}: it has no moving base to shake "
                                f"(a base-motion campaign records {' and '.join(TOPICS)})")
        return dev.sample_rate
    finally:
        dev.close()


def _at_rest(shakers: Shaker) -> None:
    """Stop the shakers however the campaign ended; a failure here must not hide the one that ended it."""
    try:
        shakers.stop()
    except DeviceError:
        pass


def _path_at(frf: FrequencyResponse, plane: int, f_hz: float) -> np.ndarray:
    """The secondary path B (2 x 2, m/V) of ``plane`` at ``f_hz``, interpolated on the measured points."""
    out = np.empty((2, 2), dtype=complex)
    for i in range(2):
        for j in range(2):
            h, _ = frf.response(AXES[2 * plane + i], AXES[2 * plane + j])
            out[i, j] = interpolate_response(frf.freq_hz, h, np.array([f_hz]))[0]
    return out


def estimate(folder: Path, path_file: str, mu: float, output: str, *, overwrite: bool = False,
             on_frequency: Callable[[float, list[float]], None] | None = None,
             max_lost: float = MAX_LOST) -> tuple[Path, int]:
    """MFXLMS per frequency and plane over a campaign; the two alphas per frequency give W11, W21,
    W12, W22 (Kang & Jung eq. A-4 to A-17).  Writes the compensator points file.

    Parameters
    ----------
    folder : Path
        The campaign folder.
    path_file : str
        The secondary path: a frequency-response file from /amb/ff to /amb/gap.
    mu : float
        Normalised step on gap 1's error (eta, on gap 2's, is the same).
    output : str
        The points file.
    on_frequency : callable, optional
        Called with (frequency, residual per plane) after each frequency.
    max_lost : float
        The share of samples (0..1) a step's recording may have lost (:mod:`ambdaq.daq.quality`).

    Returns
    -------
    (Path, int)
        The points file and the number of frequencies.
    """
    try:
        plan = json.loads((folder / CAMPAIGN).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise BadInputError(f"{folder}: no readable {CAMPAIGN} ({err})") from None
    frf = FrequencyResponse.load(path_file)
    by_freq: dict[float, list] = {}
    try:
        for step in plan["steps"]:
            by_freq.setdefault(float(step["freq_hz"]), []).append(step)
    except (KeyError, TypeError, ValueError) as err:
        raise BadInputError(f"{folder / CAMPAIGN}: malformed campaign ({err})") from None
    freqs, W, residual = [], [], []
    for f, steps in sorted(by_freq.items()):
        if len(steps) != 2:
            raise BadInputError(f"{folder}: {f:g} Hz has {len(steps)} steps; eq. A-17 needs two alphas")
        runs = [_plane_runs(folder / step["file"], f, frf, mu, max_lost) for step in steps]
        freqs.append(f)
        W.append([separate(runs[0][p][0], runs[0][p][1], runs[1][p][0], runs[1][p][1]) for p in range(2)])
        residual.append([max(runs[0][p][2], runs[1][p][2]) for p in range(2)])
        if on_frequency is not None:
            on_frequency(f, residual[-1])
    source = {"campaign": str(folder), "path": str(path_file), "path_sha256": file_sha256(path_file), "mu": mu,
              "created": now_iso()}
    return save_points(output, freqs, np.array(W), residual, source, overwrite=overwrite), len(freqs)


def _plane_runs(path: Path, f: float, frf: FrequencyResponse, mu: float,
                max_lost: float) -> list[tuple[complex, complex, float]]:
    """One step's recording: per plane, MFXLMS's beta, the alpha the base really had and the residual."""
    rec = load(path, topics=list(TOPICS))
    require_complete(rec, list(TOPICS), f"MFXLMS at {f:g} Hz", max_lost)
    gap, acc = same_instants([rec["/amb/gap"], rec["/base/accel"]], ["gap", "base acceleration"], path)
    n = len(gap)
    fs = gap.nominal_rate
    theta = 2 * np.pi * f * np.arange(n) / fs
    out = []
    for p in range(2):
        y = np.stack([gap[AXES[2 * p + i]][:n] for i in range(2)], axis=1)
        d = np.stack([acc[BASE_AXES[2 * p + m]][:n] for m in range(2)], axis=1)
        ph = harmonic_fit(d, theta, (1,))[0]  # the ratio the base really had (eq. A-10)
        alpha = complex(ph[0] / ph[1])
        res = mfxlms(y, d, _path_at(frf, p, f), f, fs, mu=mu, eta=mu)
        tail = res.error[-n // 4:]
        out.append((run_beta(res, alpha), alpha, float(np.sqrt(np.mean(tail**2)) / np.sqrt(np.mean(y**2)))))
    return out


@dataclass
class Fit:
    """The FIR fit of the compensator points: the coefficient file's content and the figures.

    Attributes
    ----------
    coefficients : Coefficients
        With the FIR (planes x outputs x inputs x taps), ready to save.
    report : dict
        Order, taps, cost per order, fit error per frequency (and against W* when asked), %.
    freqs : ndarray
        The points' frequencies, Hz.
    points, fitted : ndarray of complex, shape (freq, plane, j, m)
        MFXLMS's W and the FIR's response there.
    taps : ndarray, shape (plane, j, m, taps)
        The FIR.
    costs : ndarray, shape (j, m, orders)
        Eq. 19's J of each compensator at every order tried.
    sample_rate : float
        The FIR's rate, Hz.
    """

    coefficients: Coefficients
    report: dict
    freqs: np.ndarray
    points: np.ndarray
    fitted: np.ndarray
    taps: np.ndarray
    costs: np.ndarray
    sample_rate: float


def fit(points: str, max_order: int, order: int | None = None, *,
        exact: Callable[[np.ndarray], np.ndarray] | None = None, max_fit_error_pct: float = MAX_FIT_ERROR_PCT) -> Fit:
    """Weighted least-squares FIR fit of each compensator W_jm (Kang & Jung eq. 19), of the order at the
    knee of cost against order unless ``order``; ``exact``, where given, is the compensator known to
    be exact (``exact(f_hz)``: W* = -B^-1 C per frequency (Hz), shape (n, 2, 2), V per m/s^2; the
    simulated rig's), and the fit and the points are also compared with it.

    A fit that misses a point by more than ``max_fit_error_pct`` (%, relative) is refused
    (BadInputError naming the frequency): a point that far from a smooth compensator is a bad step
    (lost samples, a shaker that did not follow), and the FIR would carry its error to the rig."""
    freqs, W = load_points(points)
    fs = SAMPLE_RATE
    orders = np.arange(0, max_order + 1)
    costs = np.array([[[sum(fit_fir(freqs, W[:, p, j, m], o, fs)[1] for p in range(2)) for o in orders]
                       for m in range(2)] for j in range(2)])  # (j, m, order), both planes together
    chosen = order if order is not None else max(knee(orders, costs[j, m], 2 * len(freqs)) for j, m in PAIRS)
    taps = np.zeros((2, 2, 2, chosen + 1))
    for p in range(2):
        for j, m in PAIRS:
            taps[p, j, m] = fit_fir(freqs, W[:, p, j, m], chosen, fs)[0]
    E = np.exp(-2j * np.pi * np.outer(freqs / fs, np.arange(chosen + 1)))
    fitted = np.einsum("ft,pjmt->fpjm", E, taps)
    miss = 100 * np.abs(fitted / W - 1)  # (freq, plane, j, m), %
    worst = np.unravel_index(int(np.argmax(miss)), miss.shape)
    if miss[worst] > max_fit_error_pct:
        f, p, j, m = worst
        raise BadInputError(f"{points}: the FIR of order {chosen} misses W{j + 1}{m + 1} ({PLANES[p]}) at {freqs[f]:g} Hz "
                            f"by {miss[worst]:.0f} % (limit {max_fit_error_pct:g} %, --max-fit-error): that point is "
                            "not a smooth compensator's; record its campaign step again")
    report = {"order": chosen, "taps": chosen + 1,
              "cost_per_order": {f"W{j + 1}{m + 1}": [float(c) for c in costs[j, m]] for j, m in PAIRS},
              "fit_error_pct": miss.max(axis=(1, 2, 3)).round(3).tolist()}
    if exact is not None:
        Wstar = exact(freqs)
        report["error_vs_exact_pct"] = (100 * np.abs(fitted / Wstar[:, None] - 1)).max(axis=(1, 2, 3)).round(3).tolist()
        report["points_vs_exact_pct"] = (100 * np.abs(W / Wstar[:, None] - 1)).max(axis=(1, 2, 3)).round(3).tolist()
    coef = Coefficients(
        target={"rig": "base-motion", "axes": list(AXES)},
        source={"points": str(points), "points_sha256": file_sha256(points), "created": now_iso(), "fit": "eq. 19"},
        harmonics=[], weights={},
        fir={"sample_rate_hz": fs, "unit": "V/(m/s^2)", "outputs": list(AXES), "inputs": list(BASE_AXES),
             "planes": {PLANES[p]: taps[p].tolist() for p in range(2)}},
    )
    return Fit(coef, report, freqs, W, fitted, taps, costs, fs)
