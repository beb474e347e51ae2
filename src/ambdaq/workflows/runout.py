"""Sensor runout from recordings: identify it per axis and harmonic into a coefficient file, and
prove on a new recording that the command error went down (docs/push.md, docs/coefficients.md)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..analysis.runout import (harmonic_fit, lms_offline, runout_from_sensor, runout_uncertainty, model_bound,
                               separate_unbalance, unbalance_in_runout,
                               synchronous_average, synthesise)
from ..documents.coefficients import Coefficients, file_sha256, now_iso
from ..daq.quality import MAX_LOST, require_complete, require_same_machine, require_same_speed
from ..daq.recording import Recording
from ..errors import AmbdaqWarning, BadInputError
from ..units import RAD_S_TO_RPM, RPM_TO_RAD_S, phasor_um_deg

UNBALANCE_NEGLIGIBLE_RPM = 2000.0  # at or below this the rotor's unbalance response at 1X is negligible:
# a recording this slow is a slow roll for identification (the speed spec's `slowroll` is 800 rpm)
RUNOUT_REMOVED = ("runout taken out: these are the rotor's own motion, not what the sensors read; at low speed, where "
                  "the loop makes the rotor follow the sensor runout (no runout feedforward running), they are larger "
                  "than the sensors alone show (docs/iso.md, 'The sensor is not the rotor')")
METHODS = {  # x (samples, columns) -> phasors (harmonic, column)
    "fit": lambda x, th, k: harmonic_fit(x, th, k),  # every column in one pass
    "average": lambda x, th, k: np.stack([synchronous_average(c, th, harmonics=k) for c in x.T], axis=1),
    "lms": lambda x, th, k: np.stack([lms_offline(c, th, harmonics=k).phasors for c in x.T], axis=1),
}


def with_rotor(rec: Recording, purpose: str) -> Recording:
    """``rec`` with its gap and rotor angle and speed loaded; one line, exit 2, if it has no rotor
    signals (``purpose`` says what needed them)."""
    if not rec.has_role("rotor"):
        raise BadInputError(f"{rec.path}: no rotor angle and speed (/amb/rotor): {purpose} needs the "
                            "key-phasor; record with the controller's rotor angle")
    return rec.load_roles(["gap", "rotor"])


def rotor_axis_order(rec: Recording, purpose: str) -> list[str]:
    """The gap axes of ``rec`` in the order the rigid-rotor model takes them: two radial bearings
    (x, y each) and one axial axis, whatever their names. One line, exit 2, for a machine of another
    shape, which this model does not describe (``purpose``: what needed it, in words)."""
    machine = rec.machine
    if len(machine.bearings) != 2 or len(machine.axial) != 1:
        raise BadInputError(f"{rec.path}: {purpose} with a rigid rotor on two radial bearings and one axial axis; its "
                            f"gap axes are {', '.join(machine.axes)}")
    return [*machine.bearing_axes, *machine.axial]


def rigid_rotor_axes(rec: Recording) -> list[str]:
    """:func:`rotor_axis_order` for runout identification, each axis with its coil current recorded
    under the same name (the rotor's motion is told from the currents); one line, exit 2, where one
    has none."""
    axes = rotor_axis_order(rec, "runout identification separates the rotor's motion")
    missing = [a for a in axes if a not in rec.role("current").fields]
    if missing:
        raise BadInputError(f"{rec.path}: the coil currents have no {', '.join(missing)}: each gap axis needs its coil "
                            "current")
    return axes


def held_unbalance(coef: Coefficients, where: Path | str) -> str | None:
    """Why a coefficient file's 1X is not the runout alone, or None: identified from recordings at
    one speed above UNBALANCE_NEGLIGIBLE_RPM (no slow roll, no second speed to separate them), it
    holds the rotor's unbalance response at that speed (what ``runout identify`` warned)."""
    if 1 not in coef.harmonics:
        return None
    speeds = [float(r.get("speed_rpm", 0.0)) for r in coef.source.get("recordings", []) if isinstance(r, dict)]
    if not speeds or min(speeds) <= UNBALANCE_NEGLIGIBLE_RPM or len({round(s) for s in speeds}) >= 2:
        return None
    return (f"{where}: its 1X was identified at {speeds[0]:,.0f} rpm and holds the rotor's unbalance response there; "
            "taken out as runout it takes that response out too (identify from a slow roll for the runout alone)")


def unbalance_held(coef: Coefficients, rec: Recording, axes: list[str]) -> np.ndarray:
    """How much of the rotor's unbalance ``coef``'s 1X holds, per kg m on each balancing plane (front,
    rear), at ``axes`` (m per kg m; shape (len(axes), 2)): the rotor's response to it at the speed
    its 1X was identified at, which the coil currents do not explain
    (:func:`~ambdaq.analysis.runout.unbalance_in_runout`, through ``rec``'s rigid rotor). From slow
    rolls, their speeds' mean (8-18 nm for the simulated spindle's 2-3 g mm at 800 rpm); from one
    faster speed, that speed's; separated over several speeds (no slow roll), none. The rotor's
    unbalance then times this is in the runout the file takes out of a recording."""
    if 1 not in coef.harmonics:
        return np.zeros((len(axes), 2), dtype=complex)
    rotor = rec.machine.rotor
    if rotor is None:
        raise BadInputError(f"{rec.path}: no rotor model (rotor.* calibration) in the recording: the runout's slow "
                            "roll cannot be told from the unbalance it held")
    # no coil currents needed: the gaps' balancing reads none
    order = rotor_axis_order(rec, "the runout's slow roll is told from the unbalance it held")
    missing = [a for a in axes if a not in order]
    if missing:
        raise BadInputError(f"{rec.path}: no rigid-rotor axis {', '.join(missing)}")
    speeds = [float(r.get("speed_rpm", 0.0)) for r in coef.source.get("recordings", []) if isinstance(r, dict)]
    slow = [w for w in speeds if 0 < w <= UNBALANCE_NEGLIGIBLE_RPM]
    if not speeds:
        warnings.warn(f"{rec.path}: the runout coefficients do not say the speed their 1X was identified at: the "
                      "part of the unbalance it holds (about 1 % from an 800 rpm slow roll) is not given back",
                      AmbdaqWarning, stacklevel=2)
    if not slow and len({round(w) for w in speeds}) != 1:
        return np.zeros((len(axes), 2), dtype=complex)  # separated over the speeds, or not said (warned)
    held = np.mean([unbalance_in_runout(w * RPM_TO_RAD_S, rotor) for w in (slow or speeds[:1])], axis=0)
    return held[[order.index(a) for a in axes]]


def runout_1x_deviation(coef: Coefficients, axes: list[str]) -> np.ndarray:
    """Each of ``axes``' 1X runout's deviation (m, of each part) as ``coef`` states it: its standard
    uncertainty and its bound on what the noise does not cover (``model_bound_m``, read as the
    limit of an error equally likely anywhere within it: bound / sqrt(3), GUM 4.3.7), root sum
    of squares; zero where the file states neither or has no 1X."""
    if 1 not in coef.harmonics:
        return np.zeros(len(axes))
    i = coef.harmonics.index(1)

    def stated(key: str, axis: str) -> float:
        values = (coef.source.get(key) or {}).get(axis) or []
        v = values[i] if i < len(values) else None
        return float(v) if v is not None and np.isfinite(float(v)) else 0.0

    return np.array([np.hypot(stated("uncertainty_m", a), stated("model_bound_m", a) / np.sqrt(3)) for a in axes])


def runout_at(coef: Coefficients, axes: list[str], theta: np.ndarray, where: Path) -> np.ndarray:
    """The sensor runout a coefficient file describes, at the rotor angles ``theta`` (rad), for
    ``axes``: shape (n, len(axes)), in m. A file whose 1X holds an unbalance response
    (:func:`held_unbalance`) is warned about (an ``ambdaq: warning:`` line on the command line)."""
    missing = [a for a in axes if a not in coef.weights]
    if missing:
        raise BadInputError(f"{where}: no runout for {', '.join(missing)}")
    problem = held_unbalance(coef, where)
    if problem is not None:
        warnings.warn(problem, AmbdaqWarning, stacklevel=2)
    return synthesise(runout_phasors(coef, axes), coef.harmonics, theta)


def runout_phasors(coef: Coefficients, axes: list[str]) -> np.ndarray:
    """The runout phasors of ``coef`` for ``axes``, m: shape (len(coef.harmonics), len(axes)), in
    :func:`~ambdaq.analysis.runout.harmonic_fit`'s convention."""
    return np.array([[complex(*coef.weights[a][i]) for a in axes] for i in range(len(coef.harmonics))])


def _rotor(rec: Recording):
    """The rigid rotor the recording's machine describes, with the device whose calibration gave it."""
    rotor = rec.machine.rotor
    if rotor is None:
        raise BadInputError(f"{rec.path}: no rotor model (rotor.* calibration, or a rig file's [machine.rotor]) in the "
                            "recording; the rig file must give one")
    device = next((d for d in rec.devices.values() if "rotor.mass_kg" in d.calibration),
                  next((d for d in rec.devices.values() if d.kind == "controller"), None))
    return rotor, device


@dataclass(frozen=True)
class Identification:
    """What ``runout identify`` found: the coefficients, and each recording's own estimate."""

    coef: Coefficients
    warnings: list[str]
    paths: list[Path]
    first: Recording  # the first recording's gap, current and rotor, for the report
    spins: np.ndarray  # rad/s, per recording
    per_file: np.ndarray  # complex m, (recording, harmonic, axis): runout seen at that speed alone
    uncertainty: np.ndarray  # m, (harmonic, axis): each part's standard uncertainty (NaN: not propagated)
    model_bound: np.ndarray  # m, (harmonic, axis): a bound on the error the noise does not cover (NaN: not propagated)


def identify_recordings(recs: list[Recording], harmonics: list[int], method: str, *,
                        max_lost: float = MAX_LOST, uncertainty: bool = True) -> Identification:
    """Runout per axis and harmonic from recordings at constant speed (one speed per file), each
    with its gap, coil currents and rotor angle (roles ``gap``, ``current``, ``rotor``).

    Harmonics above 1X come from every file (averaged); 1X comes from a slow roll if there is
    one, else from separating runout and unbalance over the speeds, else (one fast recording)
    with a warning that it holds the unbalance response. A recording that lost more than
    ``max_lost`` of its samples (a share, 0..1), or recordings of different machines, are refused
    (:mod:`ambdaq.daq.quality`). Each harmonic's standard uncertainty is estimated unless
    ``uncertainty`` is False (then NaN: a caller that does not report it skips its spectra).
    """
    per_file, warnings, sources, u_file, b_file = [], [], [], [], []
    rotor = device = axes = None
    for rec in recs:
        rec.load_roles(["gap", "current", "rotor"])
        gap, cur, rot = rec.together("gap", "current", "rotor")
        warnings += require_complete(rec, [gap.topic, cur.topic, rot.topic], "runout identification", max_lost)
        path = rec.path
        rotor, device = _rotor(rec)
        here = rigid_rotor_axes(rec)
        if axes is not None and here != axes:
            raise BadInputError(f"{path}: its axes ({', '.join(here)}) are not the first recording's "
                                f"({', '.join(axes)}): one machine's recordings are identified together")
        axes = here
        n = len(gap)
        speed = rot["speed"][:n]
        w = float(np.median(speed))
        if w <= 0 or np.std(speed) > 0.01 * w:
            raise BadInputError(f"{path}: runout identification needs a constant speed; this recording runs from "
                                f"{speed.min() * RAD_S_TO_RPM:.0f} to {speed.max() * RAD_S_TO_RPM:.0f} rpm")
        theta = rot["angle"][:n]
        fit = METHODS[method]
        # every axis's gap and current at once: (harmonic, axis) each. Every order up to the highest
        # asked is in the fit: an order left out of it (the 1X, 18 um on a slow roll, when 2X-6X are
        # asked) leaks into the others over a recording that is not whole revolutions (306 nm, 74
        # standard errors, on a 1 s slow roll)
        orders = sorted(set(range(1, max(harmonics) + 1)) | set(harmonics))
        fitted = fit(np.column_stack([gap[a][:n] for a in axes] + [cur[a][:n] for a in axes]), theta, orders)
        G, I = np.split(fitted[[orders.index(k) for k in harmonics]], 2, axis=1)
        r = np.array([runout_from_sensor(G[i], I[i], k * w, w, rotor) for i, k in enumerate(harmonics)])
        per_file.append((w, r))
        # the rotor motion the currents explain is what runout_from_sensor took out: G - r
        b_file.append(np.array([model_bound(G[i] - r[i], k * w / (2 * np.pi), gap.nominal_rate)
                                for i, k in enumerate(harmonics)]))
        u_file.append(runout_uncertainty(np.column_stack([gap[a][:n] for a in axes]),
                                         np.column_stack([cur[a][:n] for a in axes]), theta, gap.nominal_rate, w,
                                         list(harmonics), rotor) if uncertainty
                      else np.full((len(harmonics), len(axes)), np.nan))
        sources.append({"path": str(path), "sha256": file_sha256(path), "speed_rpm": round(w * RAD_S_TO_RPM, 1)})
    require_same_machine(recs, "runout identification")
    spins = np.array([w for w, _ in per_file])
    est = np.mean([r for _, r in per_file], axis=0)  # (harmonic, axis)
    # the mean of independent estimates: its uncertainty is the root sum of squares over their count
    u = np.sqrt(np.sum(np.square(u_file), axis=0)) / len(u_file)
    bound = np.mean(b_file, axis=0)  # a bound on each estimate's error from the currents' sampling bounds their mean's
    if 1 in harmonics:
        i1 = harmonics.index(1)
        slow = [i for i, (w, _r) in enumerate(per_file) if w * RAD_S_TO_RPM <= UNBALANCE_NEGLIGIBLE_RPM]
        if slow:
            est[i1] = np.mean([per_file[i][1][i1] for i in slow], axis=0)
            u[i1] = np.sqrt(np.sum([u_file[i][i1] ** 2 for i in slow], axis=0)) / len(slow)
            bound[i1] = np.mean([b_file[i][i1] for i in slow], axis=0)
        elif len(set(np.round(spins))) >= 2:
            est[i1] = separate_unbalance(np.array([r[i1] for _, r in per_file]), spins, rotor).runout
            u[i1] = bound[i1] = np.nan  # not propagated through the separation of runout and unbalance
        else:
            warnings.append(f"1X at {spins[0] * RAD_S_TO_RPM:.0f} rpm also holds the rotor's unbalance response "
                            "(right for feedforward at this speed); add a slow roll (--rpm slowroll) or recordings "
                            "at other speeds to separate the runout")
    weights = {axis: [[float(est[i, a].real), float(est[i, a].imag)] for i in range(len(harmonics))]
               for a, axis in enumerate(axes)}
    identity = device.identity if device is not None else {}
    coef = Coefficients(
        target={"rig": identity.get("profile", identity.get("model", "")), "device": device.name if device else "",
                "serial": identity.get("serial", ""), "axes": list(axes)},
        source={"recordings": sources, "method": method, "created": now_iso(),
                # each harmonic's standard uncertainty per axis, m (None: not estimated or not propagated)
                "uncertainty_m": {axis: [None if not np.isfinite(u[i, a]) else float(u[i, a])
                                         for i in range(len(harmonics))] for a, axis in enumerate(axes)},
                # each harmonic's bound on the error the noise does not cover per axis, m
                # (analysis.runout.MODEL_BOUND; None: not propagated)
                "model_bound_m": {axis: [None if not np.isfinite(bound[i, a]) else float(bound[i, a])
                                            for i in range(len(harmonics))] for a, axis in enumerate(axes)}},
        harmonics=list(harmonics),
        weights=weights,
    )
    return Identification(coef, warnings, [r.path for r in recs], recs[0], spins, np.array([r for _, r in per_file]), u,
                          bound)


def runout_table(coef: Coefficients) -> dict[str, list[dict]]:
    """A runout coefficient file as ``runout identify`` prints it (``--json``) and the commissioning
    report shows it: per axis and harmonic the amplitude and phase of R sin(k theta + phi) (µm,
    degrees), the standard uncertainty identify stated (``u_um``, µm) and the bound on the error
    the noise does not cover (``bound_um``, µm); None where the file does not say (not propagated,
    or a file from elsewhere)."""
    def stated(key: str, axis: str, n: int) -> list:
        return (coef.source.get(key) or {}).get(axis) or [None] * n

    def um(v, digits: int):
        return None if v is None else round(float(v) * 1e6, digits)

    return {axis: [{"harmonic": k, "amplitude_um": round(amp, 4), "phase_deg": round(deg, 2),
                    "u_um": um(u, 5), "bound_um": um(b, 5)}
                   for k, (amp, deg), u, b in zip(coef.harmonics, map(phasor_um_deg, rows),
                                                   stated("uncertainty_m", axis, len(rows)),
                                                   stated("model_bound_m", axis, len(rows)))]
            for axis, rows in coef.weights.items()}


def _synchronous(rec: Recording, harmonics: list[int]) -> dict:
    """Per radial axis: harmonic phasors of the command error and the gap sensor (m), the error's RMS (m)."""
    err, gap, rot = rec.together("error", "gap", "rotor")
    n = len(err)
    if n < 2:
        raise BadInputError(f"{rec.path}: too short to check ({n} samples)")
    theta = rot["angle"][:n]
    out = {"rpm": float(np.median(rot["speed"][:n])) * RAD_S_TO_RPM, "axes": {}}
    for a in rec.machine.bearing_axes:
        if a in err.fields and a in gap.fields:
            out["axes"][a] = {"error": harmonic_fit(err[a][:n], theta, harmonics),
                              "gap": harmonic_fit(gap[a][:n], theta, harmonics),
                              "rms": float(np.sqrt(np.mean(err[a][:n] ** 2)))}
    return out


def _db(after: float, before: float) -> float:
    return float(20 * np.log10(after / before))




@dataclass
class Check:
    """What ``runout check`` found: per radial axis the command error's harmonics and RMS before
    and after, in um, and what falls short of the asked reduction."""

    before: dict
    after: dict
    axes: dict[str, dict]
    failures: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # samples lost within the limit, per input


def check_recordings(before: Recording, after: Recording, harmonics: list[int], *, min_db: float | None = None,
                     max_rms_um: float | None = None, max_lost: float = MAX_LOST) -> Check:
    """The command error's 1X..NX and RMS per radial axis before and after, and the failures.

    Parameters
    ----------
    before, after : Recording
        With the command error, gap and rotor angle, of one machine at one speed (within
        1 %; else BadInputError: the harmonics would compare different frequencies).
    harmonics : list of int
        Orders to compare.
    min_db : float, optional
        Every harmonic must fall by at least this, in dB.
    max_rms_um : float, optional
        The RMS after must be below this, in um.
    max_lost : float
        The share of samples (0..1) either recording may have lost.
    """
    notes = []
    for rec in (before, after):
        rec.load_roles(["error", "gap", "rotor"])
        topics = [rec.role(r).topic for r in ("error", "gap", "rotor")]
        notes += require_complete(rec, topics, "runout check", max_lost)
    require_same_machine([before, after], "runout check")
    b, a = _synchronous(before, harmonics), _synchronous(after, harmonics)
    require_same_speed([before, after], [b["rpm"], a["rpm"]], "runout check")
    rows, failures = {}, []
    for axis, rb in b["axes"].items():
        ra = a["axes"][axis]
        eb, ea = np.abs(rb["error"]) * 1e6, np.abs(ra["error"]) * 1e6
        rows[axis] = {
            "harmonics": [{"harmonic": k, "before_um": round(float(eb[i]), 4), "after_um": round(float(ea[i]), 4),
                           "change_db": round(_db(ea[i], eb[i]), 2)} for i, k in enumerate(harmonics)],
            "rms_before_um": round(rb["rms"] * 1e6, 4), "rms_after_um": round(ra["rms"] * 1e6, 4),
            "sensor_1x_after_um": round(float(abs(ra["gap"][0])) * 1e6, 4),
        }
        for h in rows[axis]["harmonics"]:
            if min_db is not None and not h["change_db"] <= -min_db:
                failures.append(f"{axis} {h['harmonic']}X fell {-h['change_db']:.1f} dB (< {min_db:g} dB)")
        if max_rms_um is not None and not rows[axis]["rms_after_um"] < max_rms_um:
            failures.append(f"{axis} RMS {rows[axis]['rms_after_um']:.2f} um after (>= {max_rms_um:g} um)")
    return Check({"path": str(before.path), "rpm": round(b["rpm"], 1)}, {"path": str(after.path), "rpm": round(a["rpm"], 1)},
                 rows, failures, notes)
