"""Jeon et al.'s flux-linkage angle estimator run offline over a recording, against its encoder
(``ambdaq selfsense``): when the error converges, its steady-state statistics, and the sweep of
initial errors against the Lyapunov bound (eq. 18)."""

from __future__ import annotations

import math

import numpy as np

from ..analysis.selfsense import angle_error, estimate_angle, lyapunov_bound
from ..daq.recording import Recording
from ..errors import BadInputError
from ..units import RAD_S_TO_RPM

VOLTAGE, CURRENT, ENCODER = "/coil/voltage", "/coil/current", "/motor/encoder"
CONVERGED_DEG = 1.0
SWEEP_DEG = np.arange(-85, 150, 5)


def _model(rec: Recording, overrides: dict) -> dict:
    """R, L and the back-EMF constant: the options, else the recording's calibration."""
    path = rec.path
    cal = next((d.calibration for d in rec.devices.values() if "emf_constant_v_s" in d.calibration), {})
    out = {}
    for key, name in (("resistance", "resistance_ohm"), ("inductance", "inductance_h"), ("emf_constant", "emf_constant_v_s")):
        value = overrides[key] if overrides[key] is not None else cal.get(name)
        if value is None:
            raise BadInputError(f"{path}: no {name} in the recording's calibration; give --{key.replace('_', '-')}")
        value = float(value)
        if not (math.isfinite(value) and (value > 0 or key == "inductance" and value == 0)):
            raise BadInputError(f"{path}: {key} must be a positive number, not {value!r}")
        out[key] = value
    return out


def analyse(rec: Recording, initial_error_deg: float, settle_s: float, overrides: dict, sweep: bool) -> dict:
    """Jeon et al.'s flux-linkage angle estimator (eq. 10-13) over one recording, against its encoder.

    Parameters
    ----------
    rec : Recording
        A recording with six coil voltages (``/coil/voltage``, V), currents (``/coil/current``, A)
        and the encoder (``/motor/encoder``, rad) at the same instants.
    initial_error_deg : float
        The estimator starts this far from the encoder's angle, in mechanical degrees.
    settle_s : float
        Steady-state statistics start after this, in s (and after the error stays below 1 deg).
    overrides : dict
        ``resistance`` (ohm), ``inductance`` (H), ``emf_constant`` (V s): each None to take the
        recording's calibration.
    sweep : bool
        Also run from initial errors -85..145 deg and compare with the Lyapunov bound (eq. 18).

    Returns
    -------
    dict
        What ``ambdaq selfsense --json`` prints, and ``_series`` (time s, true and estimated angle
        rad, error deg, speed rpm) for the figure.
    """
    path = rec.path
    rec.load([VOLTAGE, CURRENT, ENCODER])  # one line and exit 2 if a topic is missing
    v, i, enc = rec[VOLTAGE], rec[CURRENT], rec[ENCODER]
    if len(v) != len(i) or len(v) != len(enc) or len(v) < 100:
        raise BadInputError(f"{path}: voltages, currents and encoder must be the same sample instants (at least 100)")
    model = _model(rec, overrides)
    rate = rec[VOLTAGE].nominal_rate
    V = np.column_stack([v[f] for f in v.fields])
    I = np.column_stack([i[f] for f in i.fields])
    true = enc["angle"]
    t = (v.log_time - v.log_time[0]) * 1e-9
    est = estimate_angle(V, I, rate, theta0=true[0] + np.deg2rad(initial_error_deg), **model)
    err = np.rad2deg(angle_error(est, true))
    above = np.flatnonzero(np.abs(err) >= CONVERGED_DEG)
    if not above.size:
        converged_s: float | None = 0.0  # never off by 1 deg
    elif above[-1] + 1 < t.size:
        converged_s = float(t[above[-1] + 1])  # the last sample still off, and after it below
    else:
        converged_s = None  # still off at the end
    steady = t >= max(settle_s, converged_s if converged_s is not None else settle_s)
    speed = np.gradient(np.unwrap(true), t) * RAD_S_TO_RPM
    out = {"file": str(path), "samples": int(t.size), "initial_error_deg": initial_error_deg,
           "converged_s": converged_s, "model": model,
           "speed_rpm": {"start": round(float(np.mean(speed[: max(1, int(0.05 * rate))])), 1),
                         "end": round(float(np.mean(speed[-max(1, int(0.05 * rate)):])), 1)}}
    if steady.sum() > 0:
        e = err[steady]
        out["steady"] = {"from_s": round(float(t[steady][0]), 4), "speed_rpm": round(float(np.mean(speed[steady])), 1),
                         "mean_deg": round(float(np.mean(e)), 4), "mean_abs_deg": round(float(np.mean(np.abs(e))), 4),
                         "std_deg": round(float(np.std(e)), 4), "max_abs_deg": round(float(np.max(np.abs(e))), 4)}
    if sweep:
        finals = []
        for e0 in SWEEP_DEG:
            run = estimate_angle(V, I, rate, theta0=true[0] + np.deg2rad(e0), **model)
            finals.append(float(np.rad2deg(run[-1] - true[-1])))
        bound = lyapunov_bound(rate)
        converges = [bool(abs(f) < CONVERGED_DEG) for f in finals]
        inside = [bool(bound.eps_low_deg < e0 < bound.eps_high_deg) for e0 in SWEEP_DEG]
        # on a bound the error sits on the unstable equilibrium: either way is right
        edge = [min(abs(e0 - bound.eps_low_deg), abs(e0 - bound.eps_high_deg)) < 0.5 for e0 in SWEEP_DEG]
        out["sweep"] = {"initial_deg": SWEEP_DEG.tolist(), "final_deg": [round(f, 2) for f in finals],
                        "converges": converges, "lyapunov_deg": [round(bound.eps_low_deg, 2), round(bound.eps_high_deg, 2)],
                        "lyapunov_max_rpm": round(bound.max_rpm),
                        "agrees": all(c == n for c, n, x in zip(converges, inside, edge) if not x)}
    out["_series"] = (t, true, est, err, speed)
    return out


__all__ = ["CONVERGED_DEG", "SWEEP_DEG", "analyse"]
