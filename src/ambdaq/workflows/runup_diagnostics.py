"""Run-up and coast-down diagnostics from a recording: order tracking on the key-phasor with the
sensor runout or the slow-roll vector taken out, 1X peaks and critical speeds, a waterfall of the
gap spectrum against speed, and the modes a model predicts over it (Campbell).

Two compensations, one at a time:

* ``coefficients`` (a runout coefficient file): the sensors' runout, identified with the rotor
  motion separated out (``ambdaq runout identify``), is taken out sample by sample. What is left is
  the rotor's own motion: right for an AMB, whose loop makes the rotor follow the runout at low
  speed.
* ``slow_roll`` (a slow-roll recording): its vector per order and axis is taken out of every
  window's, as machinery engineers do on fluid-film machines. On an AMB it also takes out what the
  rotor did at slow roll, so a rotor that follows the runout shows as still (docs/iso.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..analysis.orders import (SPEED_TOLERANCE, CriticalCheck, CriticalLimits, OneXPeak, OrderTrack, PredictedCritical,
                               from_response, one_x_peaks, order_track, phase_lag_deg, predicted_criticals,
                               verify_criticals)
from ..analysis.runout import harmonic_fit, synthesise
from ..analysis.spectrum import amplitude_spectrum, full_spectrum
from ..documents.coefficients import Coefficients
from ..daq.quality import MAX_LOST, require_complete
from ..daq.recording import Recording
from ..errors import BadInputError
from ..machines.machine import Bearing, Machine
from ..machines.models import loop_model
from ..units import RAD_S_TO_RPM
from .runout import runout_at, with_rotor

WATERFALL_S = 0.1  # one spectrum per 0.1 s of the run: 10 Hz bins at 10 kHz
MODEL_SPEEDS = 26  # speeds the model's modes are computed at over the run
RESPONSE_SPEEDS = 400  # and its 1X response: 30 rpm apart over 3,000-15,000 rpm, a tenth of a mode's half-power band


@dataclass
class RunupDiagnostics:
    """What :func:`analyse` found.

    Attributes
    ----------
    axes : list of str
        The radial gap axes tracked.
    track : OrderTrack
        Their order vectors per window, compensated, in m.
    compensation : str
        What was taken out (``none``, ``runout coefficients FILE``, ``slow-roll vector FILE``).
    peaks : dict
        Axis -> its 1X peaks.
    waterfall : tuple of ndarray
        (rpm per spectrum, frequency in Hz, amplitude in m with shape (spectra, bins)) of
        ``waterfall_axis``: its bearing's full spectrum (x + j y, two-sided: forward whirl at
        positive frequencies, backward at negative) where it has a partner axis, else its own.
    waterfall_axis : str
    modes : ModelModes or None
        The model's modes over the run, if one was given.
    criticals : list of CriticalCheck
        Each critical speed the model predicts inside the run against the 1X peaks measured, and
        each measured one it does not predict (API 684); empty without a model.
    centreline : Centreline
        Each bearing's mean position per window against speed and time.
    bearings : tuple of Bearing
        The machine's radial bearings among the tracked axes.
    limits : CriticalLimits
        What the critical speeds were verified by (a peak is a critical speed when amplified at
        least ``limits.critically_damped``).
    """

    axes: list[str]
    track: OrderTrack
    compensation: str
    peaks: dict[str, list[OneXPeak]]
    waterfall: tuple[np.ndarray, np.ndarray, np.ndarray]
    waterfall_axis: str
    modes: ModelModes | None
    notes: list[str]  # what the numbers are computed over, and what to distrust in them
    centreline: Centreline
    criticals: list[CriticalCheck]
    bearings: tuple[Bearing, ...] = ()
    limits: CriticalLimits = CriticalLimits()

    def peaks_1x(self) -> dict[str, list[dict]]:
        """Per axis, its 1X peaks as ``runup --json`` and the report give them: rpm, amplitude (um),
        half-power band (rpm), phase change (deg), amplification, and whether it is a critical speed."""
        return {a: [{"rpm": round(p.rpm, 1), "amplitude_um": round(p.amplitude * 1e6, 3),
                     "band_rpm": [round(v, 1) for v in p.band_rpm], "phase_change_deg": round(p.phase_change_deg, 1),
                     "amplification": round(p.amplification, 2), "critical": p.is_critical(self.limits.critically_damped)}
                    for p in peaks] for a, peaks in self.peaks.items()}

    def as_dict(self, recording: str, revolutions: int) -> dict:
        """The whole result, as ``ambdaq runup --json`` prints it: per axis and order the amplitude (um)
        and phase lag (deg) per window, the 1X peaks, the centreline (um), the model's modes and
        the critical speeds checked against it."""
        t = self.track
        c = self.centreline
        return {
            "recording": recording, "compensation": self.compensation, "notes": self.notes, "revolutions": revolutions,
            "rpm": np.round(t.rpm, 1).tolist(),
            "axes": {a: {f"{k}X": {"amplitude_um": np.round(np.abs(t.order(k)[:, i]) * 1e6, 4).tolist(),
                                   "phase_lag_deg": np.round(phase_lag_deg(t.order(k)[:, i]), 2).tolist()}
                         for k in t.orders} for i, a in enumerate(self.axes)},
            "peaks_1x": self.peaks_1x(),
            "centreline": {"rpm": np.round(c.rpm, 1).tolist(), "time_s": np.round(c.time_s, 4).tolist(),
                           "cmin_um": None if c.cmin_m is None else round(c.cmin_m * 1e6, 3),
                           "bearings": {b: {"x_um": np.round(x * 1e6, 4).tolist(), "y_um": np.round(y * 1e6, 4).tolist()}
                                        for b, (x, y) in c.bearings.items()}},
            "model_modes": None if self.modes is None else self.modes.as_dict(),
            "critical_speeds": [x.as_dict() for x in self.criticals],
        }


@dataclass(frozen=True)
class Centreline:
    """The shaft centreline: each radial bearing's mean gap (its position about the levitation
    set-point, the sensors' zero) per window of WATERFALL_S, against speed and time; the runout is
    taken out where the run's compensation took it out. Where the rotor sits in its clearance as
    the speed changes shows the static load it carries (a steady offset, gravity's direction) and
    how the controller holds the set-point (Bently Nevada's shaft centreline plot).

    Attributes
    ----------
    rpm, time_s : ndarray, shape (windows,)
        Mean speed (rpm) and start (s from the recording's start) of each window.
    bearings : dict
        Bearing name -> (x, y) mean positions per window, m.
    cmin_m : float or None
        The minimum clearance the recording reports, m (the circle it must stay in).
    """

    rpm: np.ndarray
    time_s: np.ndarray
    bearings: dict[str, tuple[np.ndarray, np.ndarray]]
    cmin_m: float | None


def _gap_and_angle(rec: Recording, max_lost: float, notes: list[str]):
    with_rotor(rec, "order tracking")
    gap, rot = rec.together("gap", "rotor")
    notes += require_complete(rec, [gap.topic, rot.topic], "order tracking", max_lost)
    n = len(gap)
    machine = rec.machine
    axes = list(machine.radial)  # the spin axis's gap: not tracked
    if not axes:
        raise BadInputError(f"{rec.path}: its gap has no radial axes")
    x = np.column_stack([gap[a][:n] for a in axes])
    return axes, x, rot["angle"][:n], rot["speed"][:n] * RAD_S_TO_RPM, gap.nominal_rate, machine, gap.time[:n]


CENTRELINE_ORDERS = (1, 2, 3, 4)
"""Orders fitted beside the DC of each centreline window: a window is not a whole number of
revolutions, and a plain mean lets the 1X (tens of um) leak into the DC by up to a third of a um."""
CENTRELINE_MIN_REVS = 4
"""Revolutions a window must hold for its orders to be fitted beside the DC (fewer, over a speed
that changes within the window, and the fit cannot tell them apart: a plain mean is taken)."""


def centreline(machine: Machine, axes: list[str], x: np.ndarray, rpm: np.ndarray, time_s: np.ndarray,
               window: int, theta: np.ndarray) -> Centreline:
    """Each bearing's position per ``window`` samples (:class:`Centreline`): the DC term of a
    least-squares fit of the DC and the first four orders in the rotor angle ``theta`` (rad),
    which no order leaks into whatever the window's share of a revolution (a plain mean where the
    rotor turned fewer than :data:`CENTRELINE_MIN_REVS` revolutions in the window: the orders cannot
    be told from the DC there);
    ``x`` (m) holds ``axes`` column by column, ``rpm`` and ``time_s`` the speed and time of each
    sample."""
    starts = np.arange(0, x.shape[0] - window + 1, window)
    dc = np.empty((starts.size, x.shape[1]))
    for i, s in enumerate(starts):
        xs, th = x[s:s + window], theta[s:s + window]
        if abs(float(th[-1] - th[0])) < 2 * np.pi * CENTRELINE_MIN_REVS:
            dc[i] = xs.mean(axis=0)
        else:  # the LS fit's DC: the mean of what its orders do not explain (the constant is a regressor)
            phasors = harmonic_fit(xs, th, CENTRELINE_ORDERS)
            dc[i] = (xs - synthesise(phasors, list(CENTRELINE_ORDERS), th)).mean(axis=0)
    rpm_means = np.add.reduceat(rpm[: starts[-1] + window], starts) / window if starts.size else np.empty(0)
    return Centreline(rpm_means, time_s[starts] if starts.size else np.empty(0),
                      {b.name: (dc[:, axes.index(b.x)], dc[:, axes.index(b.y)])
                       for b in machine.bearings if b.x in axes and b.y in axes}, machine.cmin_m)


@dataclass(frozen=True)
class ModelModes:
    """A model's lightly damped modes over a run's speeds (a Campbell diagram's lines).

    Attributes
    ----------
    rpm : ndarray, shape (s,)
        Speeds, in rpm.
    freq_hz, damping : ndarray, shape (s, m)
        Each mode's frequency (Hz) and damping ratio at each speed, sorted by frequency; NaN
        where a speed has fewer modes.
    whirl : ndarray of int, shape (s, m)
        +1 forward, -1 backward, 0 not known (planar, or a model that does not give it).
    basis : str
        The controller gains the model's loop holds, in words (:class:`~ambdaq.machines.models.LoopModel`).
    assumed : bool
        Those gains are the model's own, not what the recording says its controller ran.
    response_rpm : ndarray, shape (r,)
        Speeds of :attr:`response`, in rpm (empty where the model gives none).
    response : dict of str to ndarray of complex, shape (r,)
        The model's own 1X per radial axis (m, as ``a + j b`` of ``a sin theta + b cos theta``)
        from its unbalance and runout (API 684's unbalance response analysis); empty where the
        model gives none.
    """

    rpm: np.ndarray
    freq_hz: np.ndarray
    damping: np.ndarray
    whirl: np.ndarray
    basis: str
    assumed: bool
    response_rpm: np.ndarray
    response: dict[str, np.ndarray]

    def as_dict(self) -> dict:
        """The modes as ``runup --json`` gives them: the model's 1X response (um, deg), and each
        mode's frequency (Hz), damping ratio and whirl per speed (null where a speed has fewer)."""
        return {
            "basis": self.basis, "assumed": self.assumed,
            "response_1x": {"rpm": self.response_rpm.round(1).tolist(),
                            **{a: {"amplitude_um": np.round(np.abs(v) * 1e6, 4).tolist(),
                                   "phase_lag_deg": np.round(phase_lag_deg(v), 2).tolist()}
                               for a, v in self.response.items()}},
            "rpm": self.rpm.round(1).tolist(),
            "freq_hz": [[None if np.isnan(f) else round(float(f), 2) for f in row] for row in self.freq_hz],
            "damping": [[None if np.isnan(z) else round(float(z), 4) for z in row] for row in self.damping],
            "whirl": [[None if np.isnan(f) or not w else ("forward" if w > 0 else "backward")
                       for f, w in zip(row, ws)] for row, ws in zip(self.freq_hz, self.whirl)]}

    def criticals(self, order: int = 1, tolerance: float = SPEED_TOLERANCE) -> list[PredictedCritical]:
        """The critical speeds these modes predict on the ``order`` line, each amplified as the
        model's own 1X response shows it where it does, within ``tolerance`` of its speed
        (:func:`from_response`)."""
        found = predicted_criticals(self.rpm, self.freq_hz, self.damping, self.whirl, order=order)
        return (from_response(found, self.response_rpm, self.response, tolerance=tolerance) if self.response
                else found)


def model_modes(model: str, rpm_from: float, rpm_to: float, calibration: Mapping[str, str] | None = None,
                axes: tuple[str, ...] = ()) -> ModelModes:
    """The lightly damped modes (damping ratio <= 0.5, below 2 kHz) of a model's loop over speed,
    and which whirl forward and which backward, from the machine's model of that name
    (:mod:`ambdaq.machines.models`).

    Parameters
    ----------
    model : str
        A machine with a loop model: ``spindle``, Ro et al.'s spindle's five-axis loop (rotor,
        amplifiers, PID; :mod:`ambdaq.machines.spindle_loop`); ``cone``, Jeong et al.'s coupled 5-DOF cone rotor under its
        PD control, current loop and eddy-current lag (eq. 10-16).
    rpm_from, rpm_to : float
        Speed range, in rpm.
    calibration : mapping, optional
        The calibration of the recording's controller: the loop is built at the gains it states
        (the spindle's ``controller.pid.*``), else at the model's own.
    axes : tuple of str
        The radial axes whose 1X response the model gives, where it gives one (the run's).
    """
    loop = loop_model(model, calibration or {})
    speeds = np.linspace(rpm_from, rpm_to, MODEL_SPEEDS)
    rows = [loop.at(float(r)) for r in speeds]  # per speed: frequencies, damping, whirl
    width = max(len(f) for f, _z, _w in rows)
    table = np.full((speeds.shape[0], width), np.nan)
    damping = np.full((speeds.shape[0], width), np.nan)
    whirl = np.zeros((speeds.shape[0], width), dtype=int)
    for i, (f, z, w) in enumerate(rows):
        table[i, : len(f)], damping[i, : len(f)], whirl[i, : len(f)] = f, z, w
    response_rpm, response = np.empty(0), {}
    if loop.response is not None and axes:
        response_rpm = np.linspace(rpm_from, rpm_to, RESPONSE_SPEEDS)
        rows = [loop.response(float(r)) for r in response_rpm]
        response = {a: np.array([row[a] for row in rows]) for a in axes if a in rows[0]}
    return ModelModes(speeds, table, damping, whirl, loop.basis, loop.assumed, response_rpm, response)


def _loop_calibration(rec: Recording) -> Mapping[str, str]:
    """The calibration of the device that records the gap: the controller whose loop it is."""
    gap = rec.machine.role("gap")
    return next((d.calibration for d in rec.devices.values() if gap is not None and gap.topic in d.topics), {})


def analyse(rec: Recording, *, coefficients: Path | None = None, slow_roll: Recording | None = None, orders=(1, 2),
            revolutions: int = 8, speeds: tuple[float, float] | None = None, waterfall_axis: str | None = None,
            model: str | None = None, operating_rpm: tuple[float, float] | None = None,
            limits: CriticalLimits = CriticalLimits(),
            max_lost: float = MAX_LOST) -> RunupDiagnostics:
    """Order tracking, 1X peaks, waterfall and Campbell lines of a run-up or coast-down.

    Parameters
    ----------
    rec : Recording
        The recording (gap sensors and the rotor angle).
    coefficients : Path, optional
        Runout coefficient file: its runout is taken out sample by sample.
    slow_roll : Recording, optional
        Slow-roll recording: its vectors are taken out of every window's.
    orders : sequence of int
        Orders tracked (1 = 1X).
    revolutions : int
        Revolutions per window.
    speeds : (float, float), optional
        The speed range (rpm) the run must cover; one line, exit 2, if it does not.
    waterfall_axis : str, optional
        Gap axis of the waterfall; default: the first radial one.
    model : str, optional
        ``spindle`` or ``cone``: its loop's modes over the run's speeds (the Campbell diagram).
    limits : CriticalLimits
        The limits the critical speeds are verified by (API 684's by default).
    operating_rpm : (float, float), optional
        Minimum operating and maximum continuous speed, rpm: with ``model``, each critical speed
        must keep API 617's separation margin from them (:func:`~ambdaq.analysis.orders.separation_margin`).
    max_lost : float
        The share of samples (0..1) a recording may have lost (:mod:`ambdaq.daq.quality`).
    """
    if coefficients is not None and slow_roll is not None:
        raise BadInputError("give --coefficients or --slow-roll, not both: each takes the runout out its own way")
    path = rec.path
    notes: list[str] = []
    axes, x, theta, rpm, fs, machine, time_s = _gap_and_angle(rec, max_lost, notes)
    if speeds is not None and (rpm.min() > speeds[0] + 0.01 * speeds[1] or rpm.max() < 0.99 * speeds[1]):
        raise BadInputError(f"{path}: the run covers {rpm.min():,.0f}-{rpm.max():,.0f} rpm, not {speeds[0]:,.0f}-"
                            f"{speeds[1]:,.0f}: record a run-up (or coast-down) over the whole range")
    compensation = "none (the sensor signal as recorded)"
    if coefficients is not None:
        x = x - runout_at(Coefficients.load(coefficients), axes, theta, coefficients)
        compensation = f"runout coefficients {coefficients}"
    try:
        track = order_track(x, theta, rpm, orders=orders, revolutions=revolutions)
    except ValueError as err:
        raise BadInputError(f"{path}: {err}: the rotor never turned") from None
    if slow_roll is not None:
        s_axes, sx, s_theta, s_rpm, *_ = _gap_and_angle(slow_roll, max_lost, notes)
        if s_axes != axes:
            raise BadInputError(f"{slow_roll.path}: its axes ({', '.join(s_axes)}) are not the run's ({', '.join(axes)})")
        if np.median(s_rpm) > 0.1 * rpm.max():
            raise BadInputError(f"{slow_roll.path}: ran at {np.median(s_rpm):,.0f} rpm: a slow roll is below a tenth of the "
                                f"run's top speed ({rpm.max():,.0f} rpm)")
        track = track.compensated(harmonic_fit(sx, s_theta, tuple(orders)).reshape(len(orders), -1))
        compensation = f"slow-roll vector {slow_roll.path}"
        # on an AMB the loop makes the rotor follow the sensor runout at slow roll, so the
        # slow-roll vector holds rotor motion too, and taking it out hides that much (docs/iso.md)
        notes.append("a slow-roll vector on an active magnetic bearing holds the rotor's own motion: its loop makes "
                     "the rotor follow the sensor runout at slow roll, so the compensated 1X is off by that much "
                     "(docs/iso.md); --coefficients from `runout identify` takes out the runout alone")
    peaks = {a: one_x_peaks(track.rpm, track.order(1)[:, i]) for i, a in enumerate(axes)} if 1 in orders else {}
    w_axis = waterfall_axis or axes[0]
    if w_axis not in axes:
        raise BadInputError(f"--waterfall-axis {w_axis}: the radial axes are {', '.join(axes)}")
    n = int(round(WATERFALL_S * fs))
    bearing = next((b for b in machine.bearings if w_axis in (b.x, b.y)), None)
    if bearing is not None:  # the full spectrum: which way the rotor whirls at each frequency
        bx, by = x[:, axes.index(bearing.x)], x[:, axes.index(bearing.y)]
        rows = [(float(rpm[s:s + n].mean()), full_spectrum(bx[s:s + n], by[s:s + n], fs=fs))
                for s in range(0, x.shape[0] - n + 1, n)]
        w_axis = bearing.name
    else:
        col = x[:, axes.index(w_axis)]
        rows = [(float(rpm[s:s + n].mean()), amplitude_spectrum(col[s:s + n], fs=fs))
                for s in range(0, x.shape[0] - n + 1, n)]
    waterfall = (np.array([r for r, _ in rows]), rows[0][1][0], np.array([a for _, (_, a) in rows]))
    modes = None
    if model:
        modes = model_modes(model, float(track.rpm.min()), float(track.rpm.max()), _loop_calibration(rec), tuple(axes))
        if modes.assumed:
            notes.append(f"--model {model}: the loop at {modes.basis}; a controller retuned from them has other "
                         "critical speeds")
    checks = verify_criticals(modes.criticals(tolerance=limits.speed), peaks,
                              (float(track.rpm.min()), float(track.rpm.max())), limits=limits,
                              operating_rpm=operating_rpm) if modes is not None and peaks else []
    return RunupDiagnostics(axes, track, compensation, peaks, waterfall, w_axis, modes, notes,
                            centreline(machine, axes, x, rpm, time_s, n, np.unwrap(theta)), checks,
                            tuple(b for b in machine.bearings if b.x in axes and b.y in axes), limits)


__all__ = ["Centreline", "ModelModes", "RunupDiagnostics", "analyse", "centreline", "model_modes"]
