"""Ro et al.'s sign-switched LMS schedule against the phase-compensated update, on the simulator.

Two measures, from coefficient files as ``ambdaq push`` would load them into the controller:

* a run-up from 0 to 50,000 rpm: the 1X and 2X command error and its RMS in speed bands;
* constant speeds from zero weights (whatever weights the file holds, so every schedule starts
  alike): the time until the 1X error stays 20 dB below its value with the feedforward off
  (never, where the schedule holds the weights).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..documents.coefficients import Coefficients
from ..drivers.coefbank import BankImage
from ..speed import SpeedProfile
from ..sim.rigs.spindle import AXES, N_HARMONICS, SPINDLE, RunoutFeedforward, SpindleRig  # the rig compared on
from ..roles import ERROR, ROTOR
from ..units import RAD_S_TO_RPM
from ..workflows.push import image_from

WINDOW_S = 0.2  # demodulation window, s


def controller_image(coef: Coefficients, where: str) -> BankImage:
    """What the simulated controller would run from ``coef`` (validated as ``ambdaq push`` does)."""
    return image_from(coef, {"axes": list(AXES), "harmonics": N_HARMONICS}, source_sha256="", where=where)


def _rig(image: BankImage | None, speed: SpeedProfile, seed: int) -> SpindleRig:
    rig = SpindleRig(speed=speed, seed=seed)
    if image is not None:
        RunoutFeedforward().apply(rig, image)
    return rig


def _components(block, window: int) -> np.ndarray:
    """Per window: mean speed (rpm), worst radial |1X|, |2X| of the command error and its RMS (m)."""
    th = block.values[ROTOR][:, 0]
    rpm = block.values[ROTOR][:, 1] * RAD_S_TO_RPM
    e = block.values[ERROR][:, :4]
    out = []
    for i in range(0, len(th) - window + 1, window):
        s = slice(i, i + window)
        c = [[2 * abs(np.mean(e[s, a] * np.exp(-1j * k * th[s]))) for a in range(4)] for k in (1, 2)]
        out.append((rpm[s].mean(), max(c[0]), max(c[1]), np.sqrt(np.mean(e[s] ** 2))))
    return np.array(out)


@dataclass
class RunUp:
    """Command error over a run-up: rows of (rpm, |1X| m, |2X| m, RMS m) per window."""

    name: str
    windows: np.ndarray

    def band(self, lo: float, hi: float) -> np.ndarray:
        """Worst |1X|, |2X| and RMS (m) over the windows whose speed lies in lo .. hi rpm."""
        sel = (self.windows[:, 0] >= lo) & (self.windows[:, 0] < hi)
        return self.windows[sel, 1:].max(axis=0)


def run_up(image: BankImage | None, *, seconds: float = 10.0, rpm_max: float = 50000.0, hold_s: float = 2.0,
           seed: int = 0, name: str = "") -> RunUp:
    """Run the simulated spindle from 0 to ``rpm_max`` in ``seconds`` (then hold) with the
    coefficient file's feedforward (None: feedforward off).

    Parameters
    ----------
    image : BankImage or None
        What the controller runs (:func:`controller_image`).
    seconds : float
        Ramp time, s.
    rpm_max : float
        Final speed, rpm.
    hold_s : float
        Time held at ``rpm_max`` after the ramp, s.
    seed : int
        Noise seed.
    name : str
        Label.
    """
    rig = _rig(image, SpeedProfile(0.0, rpm_max, seconds), seed)
    block = rig.run(int((seconds + hold_s) * rig.params.sample_rate))
    return RunUp(name, _components(block, int(WINDOW_S * rig.params.sample_rate)))


def time_to_converge(image: BankImage, rpm: float, *, limit_s: float = 10.0, seed: int = 0) -> float:
    """Seconds until the worst radial 1X command error stays 20 dB below its value with the
    feedforward off, at constant ``rpm`` from zero weights (``inf`` if not within ``limit_s``)."""
    speed = SpeedProfile(rpm, rpm)
    fs = SPINDLE.sample_rate
    window = int(WINDOW_S * fs)
    off = _components(_rig(None, speed, seed).run(window * 5), window)[1:, 1].mean()
    start = replace(image, weights=np.zeros_like(image.weights))
    comp = _components(_rig(start, speed, seed).run(int(limit_s * fs)), window)
    ok = comp[:, 1] < 0.1 * off
    bad = np.flatnonzero(~ok)
    if bad.size == 0:
        return WINDOW_S
    if bad[-1] == len(ok) - 1:
        return float("inf")
    return float((bad[-1] + 2) * WINDOW_S)


BANDS_RPM = [(0, 5000), (5000, 10000), (10000, 15000), (15000, 20000), (20000, 30000), (30000, 40000), (40000, 50001)]


def compare(files: list[Path], *, seconds: float = 10.0, speeds: list[float]) -> tuple[dict, list, dict]:
    """Coefficient files on the simulated spindle (``ambdaq lms runup``): each file's command error
    over a 0 -> 50,000 rpm run-up beside the feedforward off's, and its time to converge at each of
    ``speeds`` (rpm); runs are named by the files' names.

    Returns
    -------
    (dict, list of RunUp, dict)
        The report (``bands_rpm``, per run the worst |1X| / |2X| / RMS in um per band,
        ``time_to_converge_s``), the run-ups, and file -> speed -> seconds (inf: never).
    """
    images = {Path(f).name: controller_image(Coefficients.load(f), str(f)) for f in files}
    runs = [run_up(None, seconds=seconds, name="feedforward off")]
    runs += [run_up(image, seconds=seconds, name=name) for name, image in images.items()]
    conv = {name: {str(int(r)): time_to_converge(image, r) for r in speeds} for name, image in images.items()}
    report = {"bands_rpm": BANDS_RPM, "runs": {r.name: [[round(v * 1e6, 3) for v in r.band(*b)] for b in BANDS_RPM]
                                               for r in runs},
              "time_to_converge_s": conv}
    return report, runs, conv
