"""ISO 14839-3 stability margin, measured on the machine: per axis and speed, the sensitivity
function from the controller's test signal at the sensor summing point, its peak and zone.

Measuring runs the controller's excitation (:mod:`.frf`) as white noise, one axis at a time: white
noise reaches every frequency of the band in one recording, so each axis takes one run of
``duration`` seconds, and the coherence at each frequency says how far that point can be trusted
(a swept sine gives more signal per frequency, but needs a run per frequency and no less time for
the same resolution; the noise amplitude is the knob when coherence is short).  The speed is set
through the controller's speed parameter where it has one and checked on the recording either
way: a grade belongs to the speed the rotor really ran at.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..analysis.frf import h1_estimate
from ..analysis.runout import harmonic_fit, synthesise
from ..analysis.iso14839 import (STABILITY_LIMITS, StabilityGrade, ZoneLimits, closed_and_open_loop, grade_stability,
                                 sensitivity)
from ..documents.coefficients import file_sha256
from ..daq.quality import MAX_LOST, require_complete
from ..daq.recording import Recording
from ..acquisition.recorder import Recorder, RecordOptions
from ..documents.sealed import write_sealed
from ..drivers.excitation import ExcitationRequest
from ..drivers.interfaces import Controller
from ..drivers.registry import Opened, open_url
from ..errors import BadInputError, DeviceError
from ..units import RAD_S_TO_RPM
from .speed_restore import speed_restored
from .frf import excited_axis, excite

FORMAT, VERSION = "ambdaq-iso-stability", 1
SPEED_TOLERANCE = 0.01  # a run counts as at the requested speed within 1 % (and 20 rpm at standstill)
SPEED_FLOOR_RPM = 20.0
SYNCHRONOUS_ORDERS = 8  # the rotor's 1X .. 8X are fitted against the key-phasor and taken out


def _speed_ok(rpm: float, target: float) -> bool:
    return abs(rpm - target) <= max(SPEED_TOLERANCE * target, SPEED_FLOOR_RPM)


def _controller(sources) -> Controller:
    found = next((s for s in sources if isinstance(s, Controller) and s.capabilities.excitation), None)
    if found is None:
        raise BadInputError("no device here reports a test-signal input (iso stability needs an AMB controller "
                            "with one, as frf measure does)")
    return found


def wait_for_speed(controller: Controller, target_rpm: float, timeout_s: float, poll_s: float = 0.25) -> float:
    """Wait until the controller reports the rotor at ``target_rpm`` (rpm, within 1 % or 20 rpm).

    Parameters
    ----------
    controller : Controller
        A controller with a speed parameter (it reads the present speed, in rpm).
    target_rpm : float
        In rpm.
    timeout_s : float
        Longest wait, in s.
    poll_s : float
        Between reads, in s.

    Returns
    -------
    float
        The speed last read, in rpm.
    """
    param = controller.capabilities.speed_parameter
    deadline = time.monotonic() + timeout_s
    while True:
        rpm = float(controller.read_param(param)[0])
        if _speed_ok(rpm, target_rpm):
            return rpm
        if time.monotonic() >= deadline:
            raise DeviceError(f"the rotor did not reach {target_rpm:,.0f} rpm within {timeout_s:g} s "
                              f"(at {rpm:,.0f} rpm): raise --settle or check the drive")
        time.sleep(poll_s)


def measure(device: str, speeds_rpm: list[float] | None, axes: list[str] | None, amplitude: float,
            duration_s: float, out_dir: Path, *, settle_s: float = 60.0, overwrite: bool = False,
            on_run=None, description: dict | None = None, on_restore=None) -> list[Path]:
    """Record one excited run per axis at each speed; returns the recordings.

    With ``speeds_rpm`` the controller's speed is set for each; at the end, and when a run fails or
    is stopped, the speed it had before is set again (``on_restore`` is told), so the machine is
    not left at the last speed measured. The test signal is switched off after every run.

    Parameters
    ----------
    device : str
        The controller's URL (``sim://spindle``, ``serial:///dev/ttyACM0``, ...).
    speeds_rpm : list of float or None
        Speeds, in rpm, set through the controller's speed parameter; None: the present speed.
    axes : list of str or None
        Excited axes; None: every axis of the controller's test-signal input.
    amplitude : float
        RMS of the white noise, in um for a displacement input (else the input's unit).
    duration_s : float
        Per run, in s.
    out_dir : Path
        Where the recordings go, named ``gs_AXIS_RPMrpm.mcap`` (``gs_AXIS.mcap`` at the present speed).
    settle_s : float
        Longest wait for each speed, in s.
    on_run : callable, optional
        Called with (axis, rpm or None, path) before each run.
    description : dict, optional
        What the device's back-end reads beyond its URL (an XCP controller's A2L: ``{"a2l": path}``).
    on_restore : callable, optional
        Called with the speed set back, in rpm, or with an exception if that failed.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    with speed_restored(device, description, on_restore) if speeds_rpm else nullcontext():
        return _measure_runs(device, speeds_rpm, axes, amplitude, duration_s, out_dir, settle_s, overwrite, on_run,
                             description)


def _measure_runs(device: str, speeds_rpm: list[float] | None, axes: list[str] | None, amplitude: float,
                  duration_s: float, out_dir: Path, settle_s: float, overwrite: bool, on_run,
                  description: dict | None) -> list[Path]:
    paths = []
    names = list(axes) if axes else None  # else the controller's, learnt at the first run
    for rpm in speeds_rpm if speeds_rpm else [None]:
        i = 0
        while names is None or i < len(names):
            with Opened() as opened:
                opened.add(open_url(device, speed=None if rpm is None else f"{rpm:g}", description=description))
                controller = _controller(opened.sources)
                names = names or list(controller.capabilities.excitation.axes)
                axis = names[i]
                if rpm is not None:
                    wait_for_speed(controller, rpm, settle_s)
                path = out_dir / (f"gs_{axis}.mcap" if rpm is None else f"gs_{axis}_{rpm:g}rpm.mcap")
                if path.exists() and not overwrite:
                    raise BadInputError(f"{path} exists (a run of an earlier measurement): pass --runs DIR for "
                                        "another folder, or --overwrite")
                if on_run is not None:
                    on_run(axis, rpm, path)
                excited = excite(opened.sources, ExcitationRequest(axis, amplitude))
                result = Recorder(opened.sources, path, RecordOptions(duration_s=duration_s, records=excited.records()),
                                  overwrite=overwrite).run()
            if excited.switch_off_problem:
                raise DeviceError(f"could not switch the test signal off after {path}: {excited.switch_off_problem}")
            if result.stopped_by_user:  # Ctrl-C stops the whole measurement, not only this run
                raise DeviceError(f"stopped by the user during {path} (kept); the runs before it are in {out_dir}")
            paths.append(path)
            i += 1
    return paths


@dataclass
class AxisRun:
    """One excited axis at one speed: where it came from, its loop functions and grade."""

    axis: str
    speed_rpm: float
    source: dict
    segments: int
    freq_hz: np.ndarray
    gs: np.ndarray
    coherence: np.ndarray
    grade: StabilityGrade
    skipped_hz: list[float] = field(default_factory=list)

    def as_dict(self, curves: bool = True) -> dict:
        g = self.grade
        out = {"axis": self.axis, "speed_rpm": self.speed_rpm, "source": self.source, "segments": self.segments,
               "peak": None if np.isnan(g.peak) else round(g.peak, 4),
               "peak_db": None if np.isnan(g.peak) else round(g.peak_db, 2),
               "peak_hz": None if np.isnan(g.peak_hz) else g.peak_hz,
               "coherence_at_peak": None if np.isnan(g.coherence_at_peak) else round(g.coherence_at_peak, 4),
               "band_hz": list(g.band_hz), "zone": g.zone, "reason": g.reason,
               "synchronous_bins_skipped_hz": self.skipped_hz}
        if curves:  # the standard's three loop functions; Go is infinite where Gs is 0 (JSON null)
            gc, go = closed_and_open_loop(self.gs)
            out["curves"] = {"freq_hz": self.freq_hz.tolist(), "coherence": self.coherence.tolist(),
                             **{f"{name}_{part}": [None if not np.isfinite(v) else float(v) for v in getattr(g, part)]
                                for name, g in (("gs", self.gs), ("gc", gc), ("go", go)) for part in ("real", "imag")}}
        return out


def synchronous_bins(freq_hz: np.ndarray, speed_rpm: float, resolution_hz: float,
                     orders: int = SYNCHRONOUS_ORDERS) -> np.ndarray:
    """The bins within one resolution step of 1X .. ``orders``X, where the rotor's synchronous lines
    were taken out (so the loop's response there is not measured): a boolean mask.

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies, in Hz.
    speed_rpm : float
        In rpm.
    resolution_hz : float
        In Hz.
    orders : int
        Highest order.
    """
    mask = np.zeros(freq_hz.shape, dtype=bool)
    f1 = speed_rpm / 60.0
    if f1 < resolution_hz:  # standstill or slow roll: nothing taken out
        return mask
    for k in range(1, orders + 1):
        mask |= np.abs(freq_hz - k * f1) <= resolution_hz
    return mask


def evaluate(recs: list[Recording], *, resolution_hz: float = 10.0, band_hz: tuple[float, float] | None = None,
             limits: ZoneLimits = STABILITY_LIMITS, min_coherence: float = 0.9,
             input_axis: str | None = None, max_lost: float = MAX_LOST) -> list[AxisRun]:
    """The sensitivity function, its peak and zone, of each recording's excited axis.

    Parameters
    ----------
    recs : list of Recording
        Recordings with the test signal on one axis (``measure``, ``frf measure``): its input
        (role ``ff``) and the command error (role ``error``).
    resolution_hz : float
        Frequency step, in Hz.
    band_hz : (float, float), optional
        Band searched for the peak, in Hz; default: every frequency measured.
    limits : ZoneLimits
        Peak |Gs| at the zone boundaries.
    min_coherence : float
        Least coherence at the peak for a grade.
    input_axis : str, optional
        The excited axis, if a recording does not make it plain.
    max_lost : float
        The share of samples (0..1) a recording may have lost (:mod:`ambdaq.daq.quality`).
    """
    runs = []
    for rec in recs:
        path = rec.path
        spinning = rec.has_role("rotor")
        rec.load_roles(["ff", "error", "rotor"] if spinning else ["ff", "error"])
        x, y, *rot = rec.together("ff", "error", *(["rotor"] if spinning else []))
        rot = rot[0] if rot else None
        require_complete(rec, [x.topic, y.topic] + ([rot.topic] if spinning else []), "the sensitivity function",
                         max_lost)
        axis = excited_axis(rec, x, input_axis)
        if axis not in y.fields:
            raise BadInputError(f"{path}: the command error ({y.topic}) has no axis {axis}")
        n = len(x)
        on = np.flatnonzero(x[axis][:n])  # while the test signal ran (it may start after the recording)
        span = slice(int(on[0]), int(on[-1]) + 1)
        xs, ys = x[axis][span], y[axis][span]
        rpm = float(np.median(rot["speed"][span])) * RAD_S_TO_RPM if spinning else 0.0
        if rpm / 60.0 >= resolution_hz:
            # the rotor's own synchronous lines (runout, unbalance; a feedforward in the input) are
            # not the loop's answer to the test signal, and 40 dB above it they leak into the bins
            # beside them: fitted against the key-phasor angle and taken out of input and output
            theta = rot["angle"][span]
            orders = [k for k in range(1, SYNCHRONOUS_ORDERS + 1) if k * rpm / 60.0 < x.nominal_rate / 2]
            xs = xs - synthesise(harmonic_fit(xs, theta, orders), orders, theta)
            ys = ys - synthesise(harmonic_fit(ys, theta, orders), orders, theta)
        try:
            est = h1_estimate(xs, ys, fs=x.nominal_rate, resolution_hz=resolution_hz)
        except ValueError as err:
            raise BadInputError(f"{path}: {err}") from None
        gs = sensitivity(est.response[:, 0])
        coh = est.coherence[:, 0]
        sync = synchronous_bins(est.freq_hz, rpm, resolution_hz)
        keep = ~sync & np.isfinite(gs)
        grade = grade_stability(est.freq_hz[keep], gs[keep], coh[keep], est.segments, band_hz=band_hz,
                                limits=limits, min_coherence=min_coherence)
        runs.append(AxisRun(axis, round(rpm, 1), {"path": str(path), "sha256": file_sha256(path)}, est.segments,
                            est.freq_hz, gs, coh, grade, [float(f) for f in est.freq_hz[sync]]))
    return sorted(runs, key=lambda r: r.speed_rpm)  # stable: each speed's axes in the order measured


def check_speeds(runs: list[AxisRun], speeds_rpm: list[float] | None) -> None:
    """Each requested speed was run (the recording's median speed within 1 % or 20 rpm of it)."""
    for rpm in speeds_rpm or []:
        if not any(_speed_ok(r.speed_rpm, rpm) for r in runs):
            ran = ", ".join(sorted({f"{r.speed_rpm:,.0f}" for r in runs}))
            raise BadInputError(f"no run at {rpm:,.0f} rpm (the recordings ran at {ran} rpm): "
                                "set the drive to that speed and measure again")


def save(path: Path, runs: list[AxisRun], *, limits: ZoneLimits, min_coherence: float, resolution_hz: float,
         overwrite: bool = False) -> Path:
    """The results as a sealed ``ambdaq-iso-stability`` file (curves included, for the report)."""
    doc = {"format": FORMAT, "version": VERSION, "standard": "ISO 14839-3",
           "limits_peak_gs": limits.as_list(), "min_coherence": min_coherence, "resolution_hz": resolution_hz,
           "runs": [r.as_dict() for r in runs]}
    return write_sealed(path, doc, overwrite=overwrite)


def load_results(path: Path):
    """A results file of :func:`save`, checked (format, checksum, every value's type and range)."""
    from ..documents.sealed import read_sealed
    from ..documents.sealed_schemas import StabilityDocument, check_document

    return check_document(StabilityDocument, read_sealed(path, FORMAT, VERSION, "ISO 14839-3 results file"), path)


__all__ = ["AxisRun", "load_results", "check_speeds", "evaluate", "measure", "save", "synchronous_bins",
           "wait_for_speed"]
