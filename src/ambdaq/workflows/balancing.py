"""Influence-coefficient balancing (issue 43, item 2; ISO 21940-13's procedure):
``ambdaq balance influence REFERENCE TRIAL... --mass PLANE:GRAMS@DEG ... -o balance.json``.

A reference run and one run per plane with a known trial mass on it, all at one steady speed.
Each run's vector is the rotor's 1X from its unbalance at each radial axis: the gaps' 1X with the
sensor runout taken out (a slow roll's runout coefficients, :mod:`ambdaq.workflows.apht`'s windows
averaged), less the motion that runout drives through the loop (the machine's loop model). The influence
coefficient of plane p at axis a is what the trial mass did there per unit of its unbalance,
A[a, p] = (V_trial_p[a] - V_ref[a]) / U_trial_p (m per kg m); the correction is the unbalance per
plane that cancels the reference vector in the least-squares sense over the axes,
U = -A^+ V_ref, and the residual it predicts is V_ref + A U. A correction mass is U as grams at the
plane's radius and the angle of U from the key-phasor's mark in the direction of rotation, for
the rotor as it ran in the reference run: the trial masses come off.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..daq import load
from ..documents.coefficients import Coefficients, file_sha256
from ..documents.sealed import read_sealed, write_sealed
from ..errors import BadInputError
from ..machines.balance_masses import BalanceMass
from ..machines.models import loop_model
from ..units import RPM_TO_RAD_S
from .apht import apht
from .runout import runout_1x_deviation, runout_phasors, unbalance_held

SAME_SPEED = 0.01
"""Runs more than this fraction apart in speed are not one balancing speed: refused."""

SIGNALS = {"gaps": ("um", 1e6), "forces": ("N", 1.0)}
"""What a run's 1X vector is of, and the unit (with its scale from SI) that --json and the figure
give it in: the gaps' 1X with the runout out (m), or the 1X force each bearing applies (N)."""


@dataclass
class RunVector:
    """One run's 1X per radial axis (runout out), m, with its standard error."""

    path: str
    rpm: float
    axes: list[str]
    one_x: np.ndarray  # complex, per axis: the rotor's 1X from unbalance alone
    std: np.ndarray  # of each part, per axis: the windows' scatter and the runout model's (RUNOUT_MODEL)
    rotor_mass_kg: float | None = None  # the recording's rotor model's
    noise: np.ndarray | None = None  # of each part, per axis: the windows' scatter alone
    feedforward: bool = False  # the controller's feedforward ran (its loop: FF_SETTLE)
    runout_removed: bool = True  # a slow roll's runout coefficients were taken out (False: --no-runout)
    signal: str = "gaps"  # what the vector is of (SIGNALS): the gaps' 1X (m) or the bearings' forces (N)
    held: np.ndarray | None = None  # (axes, planes): what the vector lost per kg m of the slow roll's unbalance


@dataclass
class InfluenceNoise:
    """The noise the influence coefficients were measured with: each part's deviation, m, of the
    reference run's vector (``reference``, per axis) and of each trial run's (``trials``, axes x
    planes), and the trial unbalances (``trial_unbalance``, per plane, kg m)."""

    reference: np.ndarray
    trials: np.ndarray
    trial_unbalance: np.ndarray
    same_run: bool  # the run being corrected is the influence job's reference (its noise in both)

    def variance(self, correction: np.ndarray, run_noise: np.ndarray | None) -> np.ndarray:
        """Per axis, each part's variance that dA U adds to the run's vector, m^2 (Balancing.
        correction_std): sum_p |w_p|^2 s_tp^2 + |sum_p w_p|^2 s_r0^2, w_p = U_p / U_tp, or with the
        reference's noise counted once where the run is that reference."""
        w = correction / self.trial_unbalance
        out = (np.abs(w) ** 2 * self.trials**2).sum(axis=1)
        if self.same_run and run_noise is not None:  # V_r (1 - sum w): its noise enters once
            return out + (np.abs(1 - w.sum()) ** 2 - 1) * run_noise**2
        return out + np.abs(w.sum()) ** 2 * self.reference**2


FORCE_RUNOUT_MODEL = 0.005
"""RUNOUT_MODEL for the bearings' forces: the force that follows the runout-driven motion is taken
out no better than this fraction of itself. On the spindle at 20,000 rpm the bearings' 1X from the
rotor's unbalance is 17-24 N, beside 150-225 N that follow the motion its runout drives (25-33 um):
what the runout's model leaves weighs more in the forces than in the gaps, and at 0.2 % (the
gaps' RUNOUT_MODEL) the validation campaign's 95 % intervals held the unbalance in 72 % of 20
jobs, error / stated 1.45. At 0.5 % they held it in all of 100, error / stated 0.64: a bound."""
FF_ON = 1e-9  # a feedforward 1X above this (its unit per axis) is a running feedforward
RUNOUT_MODEL = 0.002
"""The runout-driven 1X is taken out no better than this fraction of itself (a linear loop model of
a machine), added to the reference vector's deviation: on the simulated spindle at 20,000 rpm (its
runout drives 33 um) the corrections came within 3.6e-8 kg m of the truth, 0.1 % of that 1X seen
through the influence coefficients; set at twice that, from one seed: a bound, not a scatter."""
LINEARITY = 0.005
"""Each plane's correction is known no better than this fraction of itself, beside the noise: what
the influence coefficients' linear model misses. On the simulated cone rig (no runout) its 1X of
tens of micrometres in a 0.5 mm gap is where the force law is no longer linear, and the
influence coefficients move with the unbalance: the corrections of 30 jobs (2-30 g mm per plane at
6,000 rpm) were off by up to 1.7 % (median -0.02 %), hundreds of times their noise; this floor
held 98 % of them in their 95 % intervals, the errors 0.52 times the stated deviations. On the
simulated spindle, once the slow roll's part of the unbalance is given back (:func:`_correct`),
the corrections come within 0.1 % in the median (0.1 g trial masses, the validation campaign's 100
jobs at 20,000 rpm) and this floor is conservative there (the errors 0.51 of the stated deviations
with the feedforward off, 0.36 on): it stays for the trial masses and force laws the campaign did
not try."""


FF_WINDOW_S = 0.05
"""With the feedforward on, the 1X is taken in windows this long (FORCE_WINDOW_S's): enough of them
to tell where the rotor's 1X has settled (:func:`settled`)."""
FF_SETTLE = 5.0
"""A window's 1X within this many of the settled windows' deviations of their mean is settled."""


def settled(v: np.ndarray) -> int:
    """The first window of ``v`` (windows x axes, complex) from which the 1X holds still: the
    feedforward adapts after a start (Ro et al.'s LMS: about 0.5 s at 20,000 rpm on the simulated
    spindle), and the rotor's 1X moves with it until it has. Every window from the first one
    within FF_SETTLE deviations of the last half's mean (each axis's deviation from that half),
    and then as many again: the transient decays, and the windows just inside the bound still hold
    some of it."""
    tail = v[v.shape[0] // 2:]
    mean = tail.mean(axis=0)
    sigma = np.sqrt((np.var(tail.real, axis=0, ddof=1) + np.var(tail.imag, axis=0, ddof=1)) / 2)
    outside = np.flatnonzero(np.any(np.abs(v - mean) > FF_SETTLE * np.maximum(sigma, 1e-300), axis=1))
    first = int(outside[-1]) + 1 if outside.size else 0
    return 2 * first


SLOW_ROLL = 0.01
"""The slow roll's runout holds the rotor's response to the unbalance it had then (8-18 nm at 800
rpm on the simulated spindle), which read as about 1 % less unbalance at speed until it was given
back (:func:`_correct`). An influence file from before its runs' runout coefficients were kept
(no ``runout_sha256``) cannot say whose unbalance that was: ``balance correct`` with it states
this fraction of the job's unbalance beside its other deviations instead (the validation
campaign's grade after had held the truth within its 95 % interval in 20-40 % of the jobs
without it, in all with it)."""


def run_vector(path: str | Path, coefficients: Path | None, machine: str = "spindle",
               signal: str = "gaps") -> RunVector:
    """The rotor's 1X at ``path``'s steady speed from its unbalance alone: the gaps' 1X with the
    runout of ``coefficients`` taken out, less what that runout itself drives through the loop
    (the controller follows its sensors: at 20,000 rpm the spindle's runout moves the rotor by up to
    33 um at 1X, ten times its unbalance), by ``machine``'s loop model at the gains the recording
    states. ``coefficients`` None: the gaps' 1X as it is (a machine whose sensors have no runout
    to speak of; ``balance --no-runout``, which warns).

    With the feedforward on, its loop is another: the feedforward takes the 1X out of the
    command error (Ro et al.'s LMS), so the controller follows neither the runout nor the rotor at
    1X, and the runout drives nothing; the rotor's 1X is its response to the unbalance with no
    control force at 1X. That holds once the feedforward has adapted: the windows before
    (:func:`settled`) are left out, in windows of FF_WINDOW_S.

    ``signal`` "forces": the same for the 1X force each bearing applies to the rotor (N), from the
    gap's 1X with the runout out and the coil currents' through ``machine``'s force law (its
    ``bearing_force``, where the currents are recorded), less the force that follows the motion the
    runout drives (the rigid rotor's inertia through it, ``inertia_force``): influence coefficients
    of the bearing forces (issue 43, item 2)."""
    if signal not in SIGNALS:
        raise BadInputError(f"signal {signal!r}: one of {', '.join(SIGNALS)}")
    forces = signal == "forces"
    rec = load(path)
    model = loop_model(machine, rec.metadata.get("ambdaq.calibration.rig", {}))
    if forces and (model.bearing_force is None or model.inertia_force is None):
        raise BadInputError(f"the {machine} model has no force law for its bearings: balance with the gaps")
    currents = tuple(rec.role("current").fields) if forces and rec.has_role("current") else ()
    # the axes (and current channels) APHT reads: refused before it runs
    model.require(machine, path, list(rec.machine.radial), currents)

    def vectors(result) -> np.ndarray:  # (windows, axes): the gaps' 1X, or the bearings' forces
        if not forces:
            return result.gap[:, 0, :]
        axes, channels = list(result.axes), result.current_names
        return np.array([[f[a] for a in axes] for f in
                         (model.bearing_force(result.rpm, dict(zip(axes, result.gap[w, 0])),
                                              dict(zip(channels, result.current[w, 0])))
                          for w in range(result.gap.shape[0]))]).reshape(-1, len(axes))

    result = apht(rec, orders=(1,), coefficients=coefficients, currents=forces)
    on = result.feedforward is not None and bool(np.abs(result.feedforward).max() > FF_ON)
    if on:
        result = apht(rec, orders=(1,), coefficients=coefficients, window_s=FF_WINDOW_S, currents=forces)
        v = vectors(result)
        if v.shape[0] < 8:
            raise BadInputError(f"{path}: {v.shape[0]} windows of {FF_WINDOW_S:g} s with the feedforward on; record "
                                "longer (it adapts for about 0.5 s)")
        start = settled(v)
        if v.shape[0] - start < 4:
            raise BadInputError(f"{path}: the rotor's 1X still moved at the end of the run ({start * FF_WINDOW_S:.2f} s "
                                "to settle twice over): the feedforward was adapting; record longer")
        v = v[start:]
    else:
        v = vectors(result)
    if v.shape[0] < 2:
        raise BadInputError(f"{path}: one window of 1X; record at least two ({result.window_s:g} s each)")
    noise = (np.var(v.real, axis=0, ddof=1) + np.var(v.imag, axis=0, ddof=1)) / 2 / v.shape[0]
    coef = None if coefficients is None else Coefficients.load(coefficients)
    if on or coef is None:
        driven_1x = np.zeros(len(result.axes), dtype=complex)
    else:
        if model.runout_response is None:
            raise BadInputError(f"the {machine} model does not give the loop's response to runout: no balancing with it")
        runout = (runout_phasors(coef, list(result.axes))[coef.harmonics.index(1)] if 1 in coef.harmonics
                  else np.zeros(len(result.axes), dtype=complex))
        driven = model.runout_response(result.rpm, dict(zip(result.axes, runout)))
        if forces:  # the bearings' force that moves the rotor as the runout drives it (no unbalance in it)
            driven = model.inertia_force(result.rpm, driven)
        driven_1x = np.array([driven[a] for a in result.axes])
    std = np.sqrt(noise + ((FORCE_RUNOUT_MODEL if forces else RUNOUT_MODEL) * np.abs(driven_1x)) ** 2)
    held = None
    if coef is not None:
        axes = list(result.axes)
        held = _held(model, machine, rec, result.rpm, axes, coef, on, forces)
        std = np.hypot(std, _runout_error(model, result.rpm, axes, coef, on, forces))
    return RunVector(str(path), result.rpm, list(result.axes), v.mean(axis=0) - driven_1x, std,
                     rec.machine.rotor_mass_kg, np.sqrt(noise), on, coefficients is not None, signal, held)


def _through_loop(model, rpm: float, axes: list[str], runout: Mapping[str, complex], on: bool,
                  forces: bool) -> np.ndarray:
    """What a 1X runout error ``runout`` (m per axis by name) changes a run's vector by (per axis:
    m, or N for the bearings' forces), :func:`run_vector`'s path: taken out of the gap it moves
    the gap's 1X by itself and, with the feedforward off, by the motion it would drive through the
    loop (``runout_response``); of the bearings' forces, the magnets' force on it (``bearing_force``
    at no current) and, feedforward off, the inertia's on what it drives."""
    driven = {a: 0j for a in axes} if on else model.runout_response(rpm, runout)
    if forces:
        magnets, follows = model.bearing_force(rpm, runout, {}), model.inertia_force(rpm, driven)
        return np.array([magnets[a] + (0j if on else follows[a]) for a in axes])
    return np.array([runout.get(a, 0j) + driven[a] for a in axes])


def _held(model, machine: str, rec, rpm: float, axes: list[str], coef: Coefficients, on: bool,
          forces: bool) -> np.ndarray:
    """What a run's vector (:func:`run_vector`) loses per kg m of the unbalance the rotor had at the
    runout's slow roll, on each plane (axes x planes): the coefficients' 1X holds the rotor's
    response to it there (:func:`~ambdaq.workflows.runout.unbalance_held`), taken out as runout
    (:func:`_through_loop`)."""
    if len(model.balance_planes) != 2:
        raise BadInputError(f"the {machine} model's planes ({', '.join(model.balance_planes)}) are not a rigid rotor's "
                            "two at its bearings: its runout coefficients' slow roll cannot be told from its unbalance")
    s = unbalance_held(coef, rec, axes)
    return np.column_stack([_through_loop(model, rpm, axes, dict(zip(axes, s[:, k])), on, forces)
                            for k in range(s.shape[1])])


def _runout_error(model, rpm: float, axes: list[str], coef: Coefficients, on: bool, forces: bool) -> np.ndarray:
    """Per axis, the deviation (m or N, each part) a run's vector takes from the runout
    coefficients' own 1X error (:func:`~ambdaq.workflows.runout.runout_1x_deviation`), each axis's
    independent of the others', through :func:`_through_loop`."""
    e = runout_1x_deviation(coef, axes)
    moved = [_through_loop(model, rpm, axes, {a: complex(e[b])}, on, forces) for b, a in enumerate(axes)]
    return np.sqrt(np.sum(np.abs(moved) ** 2, axis=0))


def limited_correction(A: np.ndarray, v: np.ndarray, free: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """The correction u (kg m per plane) that leaves the least 1X, ||v + A u||, with every plane's
    |u_p| at most ``limit`` (kg m): ``free`` (the unconstrained least squares) where it is within,
    otherwise the convex problem solved by SLSQP from ``free`` drawn back inside the limits."""
    if np.all(np.abs(free) <= limit):
        return free
    from scipy.optimize import minimize

    n, scale = len(free), float(np.linalg.norm(v)) or 1.0
    unit = limit.max()  # the variables in units of the largest limit, the objective in the 1X's

    def residual(x: np.ndarray) -> float:
        u = (x[:n] + 1j * x[n:]) * unit
        return float(np.sum(np.abs(v + A @ u) ** 2)) / scale**2

    start = free * np.minimum(1.0, limit / np.abs(free)) / unit
    bounds = [{"type": "ineq", "fun": (lambda x, p=p: (limit[p] / unit) ** 2 - x[p] ** 2 - x[n + p] ** 2)}
              for p in range(n)]
    found = minimize(residual, np.concatenate([start.real, start.imag]), method="SLSQP", constraints=bounds,
                     options={"ftol": 1e-14, "maxiter": 500})
    u = (found.x[:n] + 1j * found.x[n:]) * unit
    over = np.abs(u) > limit
    u[over] *= limit[over] / np.abs(u[over])  # the solver's tolerance, not beyond the limit
    return u


def balance_grade(unbalance_kg_m: float | np.ndarray, rotor_mass_kg: float, max_rpm: float) -> float | np.ndarray:
    """ISO 21940-11's e_per Omega_max, mm/s, of an unbalance (kg m) on a rotor of ``rotor_mass_kg``
    (kg) at its maximum service speed ``max_rpm`` (rpm)."""
    return unbalance_kg_m / rotor_mass_kg * max_rpm * RPM_TO_RAD_S * 1e3


def plane_masses(planes: list[str], correction: np.ndarray, radius_m: dict[str, float], holes: int) -> list[BalanceMass]:
    """A correction (kg m per plane) as masses at each plane's radius (m): one per plane at the
    correction's angle, or, with ``holes`` per plane, split between the two holes either side of
    it (each plane's unbalance the same vector sum, so the predicted residual holds)."""
    out = []
    for p, u in zip(planes, correction):
        r = radius_m[p]
        if not holes:
            out.append(BalanceMass(p, float(abs(u)) / r * 1e3, float(np.degrees(np.angle(u))) % 360.0, r))
            continue
        pitch = 2 * np.pi / holes
        k = int(np.floor((np.angle(u) % (2 * np.pi)) / pitch))
        lo, hi = k * pitch, (k + 1) * pitch
        # u = a e^{j lo} + b e^{j hi}, a and b >= 0: the two holes' share of the vector
        a, b = np.linalg.solve(np.array([[np.cos(lo), np.cos(hi)], [np.sin(lo), np.sin(hi)]]), [u.real, u.imag])
        for share, at in ((a, lo), (b, hi)):
            if share * 1e3 / r > 1e-6:  # a microgram: the hole is not used
                out.append(BalanceMass(p, float(share) / r * 1e3, float(np.degrees(at)) % 360.0, r))
    return out


def mass_rows(masses: list[BalanceMass]) -> list[dict]:
    """Correction masses as every balance command's --json gives them: g to 4 decimals, degrees to 2."""
    return [{"plane": m.plane, "grams": round(m.grams, 4), "deg": round(m.deg, 2), "radius_mm": m.radius_m * 1e3}
            for m in masses]


@dataclass(frozen=True)
class MassTolerance:
    """The errors of the correction's own making (ISO 21940-14, clause 4's sources in the masses):
    the largest weighing error of each correction mass, g, and the largest error of the angle it
    is fitted at, degrees; each taken as equally likely anywhere within its bound. A radius off
    by dr counts as a mass off by m dr / r."""

    grams: float = 0.0
    deg: float = 0.0


PREDICTION_DRAWS = 20000
"""Draws of the estimate's error and the masses' from which the grade after a correction is
predicted: the 95th percentile's own scatter over draws is then about 0.5 % of it (sqrt(p (1 - p)
/ N) over the density there)."""
PREDICTION_LEVEL = 0.95
"""The grade after is stated as its median and the bound it stays within with this probability."""


def grade_after(planes: list[str], residual: np.ndarray, std: np.ndarray, masses: list[BalanceMass],
                tolerance: MassTolerance, rotor_mass_kg: float | None, max_rpm: float | None) -> dict | None:
    """The ISO 21940-11 grade the rotor is predicted to have once ``masses`` are on (ISO 21940-14's
    residual unbalance after balancing, with its errors): per plane, the unbalance the estimate
    says is left (``residual``, kg m, in the order of ``planes``: none unless a limit held a mass
    back), plus the estimate's own error (a circular normal of ``std`` per part, kg m, per plane:
    what the stated deviation means), plus each mass's weighing and fitting error within
    ``tolerance``; the grade of their
    magnitudes summed, drawn PREDICTION_DRAWS times. Its median and the bound it stays within with
    PREDICTION_LEVEL, mm/s, at ``max_rpm`` (rpm) for a rotor of ``rotor_mass_kg`` (kg); None
    without both. The draws are seeded: one job always predicts the same."""
    if not rotor_mass_kg or not max_rpm:
        return None
    rng = np.random.default_rng(0)
    shape = (PREDICTION_DRAWS, len(planes))
    after = residual + std * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    index = {p: k for k, p in enumerate(planes)}
    for m in masses:  # each mass as put on: its weight and angle each off within the tolerance
        grams = m.grams + tolerance.grams * rng.uniform(-1.0, 1.0, PREDICTION_DRAWS)
        deg = m.deg + tolerance.deg * rng.uniform(-1.0, 1.0, PREDICTION_DRAWS)
        placed = grams * 1e-3 * m.radius_m * np.exp(1j * np.radians(deg))
        after[:, index[m.plane]] += placed - m.unbalance
    grades = balance_grade(np.abs(after).sum(axis=1), rotor_mass_kg, max_rpm)
    median, bound = np.quantile(grades, [0.5, PREDICTION_LEVEL])
    return {"grade_mm_s": round(float(median), 3), "at_most_mm_s": round(float(bound), 3),
            "level": PREDICTION_LEVEL, "grade": _grade_class(float(bound)),
            "mass_tolerance_g": tolerance.grams, "angle_tolerance_deg": tolerance.deg}


@dataclass
class Balancing:
    """Influence coefficients and the correction they give."""

    planes: list[str]
    axes: list[str]
    rpm: float
    influence: np.ndarray  # (axes, planes) complex, m per kg m
    reference: np.ndarray  # (axes,) complex, m
    correction: np.ndarray  # (planes,) complex, kg m: the least squares', the whole unbalance's negative
    radius_m: dict[str, float]
    trials: list[BalanceMass]
    holes: int = 0  # holes per plane, evenly spaced from the key-phasor's mark; 0: a mass at any angle
    rotor_mass_kg: float | None = None  # the recording's rotor model's (rotor.mass_kg)
    max_rpm: float | None = None  # the machine's maximum service speed, for the balance grade
    reference_std: np.ndarray | None = None  # (axes,): each part's deviation of the reference vector, m
    reference_noise: np.ndarray | None = None  # (axes,): the part of it that is the run's own noise, m
    influence_noise: InfluenceNoise | None = None  # the noise the influence coefficients were measured with
    max_grams: float | None = None  # the largest mass a plane takes, g (at its radius)
    feedforward: bool = False  # the runs' feedforward ran: the coefficients are of that loop
    speeds_rpm: list[float] | None = None  # at several speeds, each one's (the rows: an axis at a speed)
    target_mm_s: float | None = None  # the balance grade asked for (ISO 21940-14's acceptance), mm/s
    tolerance: MassTolerance = MassTolerance()  # the correction masses' own errors (predicted_after)
    slow_roll: np.ndarray | None = None  # (planes,): the slow roll's runout's part, kg m (SLOW_ROLL)
    runout_removed: bool = True  # the runs' runout coefficients were taken out (False: --no-runout)
    signal: str = "gaps"  # what the vectors are of (SIGNALS): m and m per kg m, or N and N per kg m

    @functools.cached_property
    def placed(self) -> np.ndarray:
        """The correction the masses put on the rotor, kg m per plane: the least squares', or where a
        plane's would need more than ``max_grams``, the best with every plane within it
        (:func:`limited_correction`, solved once: the fields it is of are set when the result is built)."""
        if self.max_grams is None:
            return self.correction
        limit = np.array([self.max_grams * 1e-3 * self.radius_m[p] for p in self.planes])
        return limited_correction(self.influence, self.reference, self.correction, limit)

    @property
    def limited(self) -> list[str]:
        """The planes whose correction ``max_grams`` holds back."""
        return [p for p, u, v in zip(self.planes, self.correction, self.placed) if abs(u - v) > 1e-9 * abs(u)]

    @property
    def residual(self) -> np.ndarray:
        """The 1X the placed correction leaves, predicted, per axis (complex, m)."""
        return self.reference + self.influence @ self.placed

    @property
    def correction_std(self) -> np.ndarray | None:
        """Each part's standard deviation of each plane's correction, kg m. To first order the
        correction U = -A^+ V moves by -A^+ (dV + dA U): the run's vector's deviation, and the
        influence coefficients' (each trial run's noise and its reference's, A_p = (V_tp - V_r0) /
        U_tp, carried by U_p / U_tp; where the run is that reference its noise enters once, as
        V_r (1 - sum w_p)), per axis through the least squares; then LINEARITY of each plane's
        correction, and from saved coefficients SLOW_ROLL of the job's unbalance, beside it."""
        if self.reference_std is None:
            return None
        var = self.reference_std**2
        if self.influence_noise is not None:
            var = var + self.influence_noise.variance(self.correction, self.reference_noise)
        pinv = np.linalg.pinv(self.influence)
        held = 0.0 if self.slow_roll is None else self.slow_roll**2
        return np.sqrt(np.abs(pinv) ** 2 @ var + (LINEARITY * np.abs(self.correction)) ** 2 + held)

    @property
    def grade_std_mm_s(self) -> float | None:
        """The grade's standard deviation, mm/s (the planes' magnitudes' deviations summed)."""
        if self.grade_mm_s is None or self.correction_std is None:
            return None
        return self._grade(float(self.correction_std.sum()))

    @property
    def grade_mm_s(self) -> float | None:
        """The rotor's balance quality now, ISO 21940-11: e_per Omega_max in mm/s, e_per the specific
        unbalance (the planes' estimated unbalances, the negative of the correction, summed in
        magnitude, over the rotor's mass) and Omega_max the maximum service speed; None without both."""
        if not self.rotor_mass_kg or not self.max_rpm:
            return None
        return self._grade(float(np.abs(self.correction).sum()))

    def _grade(self, unbalance_kg_m: float) -> float:
        return balance_grade(unbalance_kg_m, self.rotor_mass_kg, self.max_rpm)

    def masses(self) -> list[BalanceMass]:
        """The correction as masses at each plane's radius (:func:`plane_masses`)."""
        return plane_masses(self.planes, self.placed, self.radius_m, self.holes)

    @property
    def predicted_after(self) -> dict | None:
        """The grade once the masses are on (:func:`grade_after`): what a limit held back
        (placed less the least squares' correction), the correction's deviation, the masses' own
        errors."""
        if self.correction_std is None:
            return None
        return grade_after(self.planes, self.placed - self.correction, self.correction_std, self.masses(),
                           self.tolerance, self.rotor_mass_kg, self.max_rpm)

    def as_dict(self) -> dict:
        """What ``balance influence --json`` prints (the vectors in um, or N for the bearings' forces)."""
        unit, scale = SIGNALS[self.signal]

        def um(v: complex) -> dict:
            return {unit: round(abs(v) * scale, 4), "deg": round(float(np.degrees(np.angle(v))), 2)}

        return {"rpm": round(self.rpm, 1), "feedforward": self.feedforward, "runout_removed": self.runout_removed,
                "signal": self.signal, "planes": self.planes, "axes": self.axes,
                f"influence_{unit}_per_g_mm": {p: {a: um(self.influence[i, k] * 1e-6) for i, a in enumerate(self.axes)}
                                               for k, p in enumerate(self.planes)},
                "reference": {a: um(v) for a, v in zip(self.axes, self.reference)},
                "holes": self.holes or None,
                "unbalance_estimated": {p: {"g_mm": round(abs(u) * 1e6, 4), "deg": round(float(np.degrees(np.angle(-u))) % 360, 2)}
                                        for p, u in zip(self.planes, self.correction)},
                "grade_mm_s": None if self.grade_mm_s is None else round(self.grade_mm_s, 3),
                "grade_std_mm_s": None if self.grade_std_mm_s is None else round(self.grade_std_mm_s, 3),
                "correction_std_g_mm": None if self.correction_std is None else
                {p: round(float(sd) * 1e6, 4) for p, sd in zip(self.planes, self.correction_std)},
                "grade": _grade_class(self.grade_mm_s),
                "max_rpm": self.max_rpm,
                "correction": mass_rows(self.masses()),
                "max_grams": self.max_grams, "limited_by_max_grams": self.limited,
                "predicted_residual": {a: um(v) for a, v in zip(self.axes, self.residual)},
                "predicted_reduction": round(float(np.linalg.norm(self.residual) / np.linalg.norm(self.reference)), 4),
                **({"speeds_rpm": [round(r, 1) for r in self.speeds_rpm]} if self.speeds_rpm else {}),
                **_acceptance(self), **_prediction(self)}


def _acceptance(result) -> dict:
    """The ``acceptance`` member of a result's --json where a grade was asked for and one is stated."""
    if result.target_mm_s is None or result.grade_mm_s is None:
        return {}
    return {"acceptance": acceptance(result.grade_mm_s, result.grade_std_mm_s, result.target_mm_s)}


def _prediction(result) -> dict:
    """The ``predicted_after`` member of a result's --json where a grade is stated: with a grade
    asked for, whether the bound is within it (ISO 21940-14's e + de <= e_per, the bound as e + de);
    whether its median is below the grade now (``improves``)."""
    p = result.predicted_after
    if p is None:
        return {}
    if result.target_mm_s is not None:
        p["within_target"] = bool(p["at_most_mm_s"] <= result.target_mm_s)
    # a rotor within its noise: the masses carry the estimate's error on, and the median after is
    # not below the grade now
    p["improves"] = bool(p["grade_mm_s"] < result.grade_mm_s)
    return {"predicted_after": p}


GRADES = (0.4, 1.0, 2.5, 6.3, 16.0, 40.0, 100.0, 250.0, 630.0, 1600.0, 4000.0)
"""ISO 21940-11's balance quality grades G, mm/s."""


ERROR_COVERAGE = 2.0
"""The balance error ISO 21940-14 counts against the permissible residual unbalance, in the grade's
stated deviations: its random part (the runs' noise) and the bounds on its systematic ones
(RUNOUT_MODEL, LINEARITY; FORCE_MODEL, FORCE_RELATIVE) are in that deviation together, and twice it
held the truth in 95-100 % of the validation campaign's jobs (docs/validation.md)."""


def acceptance(grade_mm_s: float, std_mm_s: float, target_mm_s: float) -> dict:
    """ISO 21940-14's acceptance (clause 7) of a residual unbalance as a grade ``grade_mm_s`` with
    its deviation ``std_mm_s`` against the grade ``target_mm_s`` (all mm/s, ISO 21940-11's e_per
    Omega_max): directly after balancing the residual and its error must be within the permissible,
    e + de <= e_per; a user checking a balanced rotor accepts it within the permissible and the
    error, e <= e_per + de; de is ERROR_COVERAGE deviations."""
    error = ERROR_COVERAGE * std_mm_s
    return {"target": f"G{target_mm_s:g}", "permissible_mm_s": target_mm_s, "error_mm_s": round(error, 3),
            "after_balancing": bool(grade_mm_s + error <= target_mm_s), "check": bool(grade_mm_s <= target_mm_s + error)}


def _grade_class(g: float | None) -> str | None:
    """The finest grade G the value meets (``G2.5`` for 1.9 mm/s), or beyond the coarsest."""
    if g is None:
        return None
    return next((f"G{v:g}" for v in GRADES if g <= v), f"beyond G{GRADES[-1]:g}")


Job = tuple[RunVector, list[tuple[BalanceMass, RunVector]]]
"""One speed of a balancing job: its reference run and one trial run per plane with its mass."""


def influence_balancing(speeds: list[Job], *, holes: int = 0, max_rpm: float | None = None,
                        max_grams: float | None = None) -> Balancing:
    """Influence coefficients from a reference run and one trial run per plane at each of
    ``speeds``, and the correction that cancels the references' 1X over every speed and axis by
    least squares (module docstring; ISO 21940-13's several speeds), in ``holes`` per plane (0: at
    any angle), no mass above ``max_grams`` (g), graded at ``max_rpm`` (rpm). At several speeds
    each row of the coefficients is an axis at a speed (``front_x@30000rpm``), and every speed has
    the same trial masses, put on once and run at each speed, as the procedure has it."""
    if not speeds:
        raise BadInputError("no runs: a reference and one trial run per plane")
    parts = [_influence(reference, trials) for reference, trials in speeds]
    first, masses = speeds[0][0], [m for m, _ in speeds[0][1]]
    for reference, trials in speeds[1:]:
        if [m for m, _ in trials] != masses:
            raise BadInputError(f"{reference.path}: its trial masses are not the first speed's "
                                f"({', '.join(f'{m.plane}:{m.grams:g}@{m.deg:g}' for m in masses)}): put each on once "
                                "and run it at every speed")
        if reference.feedforward != first.feedforward:
            raise BadInputError(f"{reference.path} ran with the feedforward {_on_off(reference.feedforward)}, "
                                f"{first.path} with it {_on_off(first.feedforward)}: one loop for every run of a job")
    rpms = sorted(reference.rpm for reference, _ in speeds)
    if any(b / a - 1 <= SAME_SPEED for a, b in zip(rpms, rpms[1:])):
        raise BadInputError("two references ran at one speed (" + ", ".join(f"{r:,.0f}" for r in rpms)
                            + " rpm): one reference and its trial runs per speed")
    rows = stacked([reference for reference, _ in speeds])
    noise = InfluenceNoise(rows.noise, np.vstack([n.trials for _, n in parts]), parts[0][1].trial_unbalance,
                           same_run=True)
    result = _correct([m.plane for m in masses], rows, np.vstack([A for A, _ in parts]),
                      {m.plane: m.radius_m for m in masses}, masses, noise, holes, max_rpm, max_grams)
    result.speeds_rpm = [reference.rpm for reference, _ in speeds] if len(speeds) > 1 else None
    return result


def stacked(runs: list[RunVector]) -> RunVector:
    """Runs at several speeds as one vector: each row an axis at a speed (``front_x@30000rpm``), in
    the runs' order; one run as it is."""
    if len(runs) == 1:
        return runs[0]
    first = runs[0]
    return RunVector(", ".join(r.path for r in runs), first.rpm, [f"{a}@{r.rpm:.0f}rpm" for r in runs for a in r.axes],
                     np.concatenate([r.one_x for r in runs]), np.concatenate([r.std for r in runs]),
                     first.rotor_mass_kg, np.concatenate([r.noise for r in runs]), first.feedforward,
                     all(r.runout_removed for r in runs), first.signal,
                     None if any(r.held is None for r in runs) else np.vstack([r.held for r in runs]))


def _influence(reference: RunVector, trials: list[tuple[BalanceMass, RunVector]]) -> tuple[np.ndarray, InfluenceNoise]:
    """One speed's influence coefficients (axes x planes, m per kg m) and the noise they were
    measured with, each trial run checked against its reference."""
    planes = [m.plane for m, _ in trials]
    if len(set(planes)) != len(planes):
        raise BadInputError(f"one trial run per plane: {', '.join(planes)}")
    for _mass, run in trials:
        if run.axes != reference.axes:
            raise BadInputError(f"{run.path}: its axes are not the reference's ({', '.join(reference.axes)})")
        if abs(run.rpm / reference.rpm - 1) > SAME_SPEED:
            raise BadInputError(f"{run.path} ran at {run.rpm:,.0f} rpm, its reference at {reference.rpm:,.0f}: a "
                                "reference and its trial runs at one speed")
        if run.feedforward != reference.feedforward:
            raise BadInputError(f"{run.path} ran with the feedforward {_on_off(run.feedforward)}, the reference with it "
                                f"{_on_off(reference.feedforward)}: one loop for every run of a job")
        if run.signal != reference.signal:
            raise BadInputError(f"{run.path}: its vector is of the {run.signal}, the reference's of the {reference.signal}")
    A = np.column_stack([(run.one_x - reference.one_x) / mass.unbalance for mass, run in trials])
    moved = np.abs(A * np.array([m.unbalance for m, _ in trials])).max(axis=0)
    # a trial run less the reference: the runout's part is the same in both, only the noise moves
    noise = np.sqrt(2) * max(float(reference.noise.max()), *(float(r.noise.max()) for _, r in trials))
    unit, scale = SIGNALS[reference.signal]
    for (mass, run), m in zip(trials, moved):
        if m < 10 * noise:
            raise BadInputError(f"{run.path}: the trial mass on {mass.plane} moved the 1X by {m * scale:.3f} {unit} at "
                                f"most, less than ten times its noise ({noise * scale:.3f} {unit}): use a larger trial "
                                "mass")
    return A, InfluenceNoise(reference.noise, np.column_stack([r.noise for _, r in trials]),
                             np.array([m.unbalance for m, _ in trials]), same_run=True)


def _correct(planes: list[str], run: RunVector, A: np.ndarray, radius_m: dict[str, float],
             trials: list[BalanceMass], noise: InfluenceNoise | None, holes: int, max_rpm: float | None,
             max_grams: float | None, before: np.ndarray | None = None) -> Balancing:
    """The correction per plane that cancels ``run``'s 1X over its axes by least squares, with the
    part of the rotor's unbalance its runout coefficients' slow roll held (``run.held``) given back
    to it: of ``before`` (kg m per plane) where the slow roll was recorded with that unbalance on
    the rotor, else of the run's own, v = (A - H) U, solved as one least squares. The reference
    it keeps is the run's 1X with that part given back."""
    v = run.one_x
    if run.held is not None and before is not None:
        v = v + run.held @ before
    elif run.held is not None:
        v = v + run.held @ np.linalg.lstsq(A - run.held, v, rcond=None)[0]
    correction, *_ = np.linalg.lstsq(A, -v, rcond=None)
    return Balancing(planes, run.axes, run.rpm, A, v, correction, radius_m, trials,
                     holes=holes, rotor_mass_kg=run.rotor_mass_kg, max_rpm=max_rpm, reference_std=run.std,
                     reference_noise=run.noise, influence_noise=noise, max_grams=max_grams,
                     feedforward=run.feedforward, runout_removed=run.runout_removed, signal=run.signal)


def _on_off(on: bool) -> str:
    return "on" if on else "off"


FORMAT, VERSION = "ambdaq.balance_influence", 1
NOISE_KEY = {"gaps": "noise_m", "forces": "noise_N"}
"""The influence file's member with the deviations its runs were measured with, named by their unit."""


def save_influence(result: Balancing, path: str | Path, sources: list[str | Path], coefficients: str | Path | None = None,
                   *, overwrite: bool = False) -> Path:
    """The influence coefficients as a sealed file, to balance the same machine again from one run
    (``balance correct``): planes, axes, speed, coefficients (m per kg m), radii, the trial masses
    and the runs they came from (name and SHA-256); the unbalance the job estimated (magnitude and
    angle per plane) with the SHA-256 of the runout ``coefficients`` its runs were read with: a
    later run read with the same holds that unbalance's part of their slow roll."""
    doc = {"format": FORMAT, "version": VERSION, "rpm": result.rpm, "feedforward": result.feedforward,
           "signal": result.signal,
           **({"speeds_rpm": result.speeds_rpm} if result.speeds_rpm else {}), "planes": result.planes, "axes": result.axes,
           "influence_re": result.influence.real.tolist(), "influence_im": result.influence.imag.tolist(),
           "radius_m": result.radius_m, "trials": [f"{m.plane}:{m.grams:g}@{m.deg:g}:{m.radius_m * 1e3:g}"
                                                   for m in result.trials],
           "sources": [{"file": Path(f).name, "sha256": file_sha256(f)} for f in sources]}
    if result.influence_noise is not None:  # what the next job's deviation needs of this one's
        n = result.influence_noise
        doc["reference_unbalance_kg_m"] = {p: float(abs(u)) for p, u in zip(result.planes, result.correction)}
        doc["reference_unbalance_deg"] = {p: float(np.degrees(np.angle(-u))) for p, u in zip(result.planes,
                                                                                           result.correction)}
        doc["runout_sha256"] = None if coefficients is None else file_sha256(coefficients)
        doc[NOISE_KEY[result.signal]] = {"reference": n.reference.tolist(), "trials": n.trials.tolist(),
                                          "trial_unbalance_re": n.trial_unbalance.real.tolist(),
                                          "trial_unbalance_im": n.trial_unbalance.imag.tolist()}
    return write_sealed(path, doc, overwrite=overwrite)


def _complex(re, im) -> np.ndarray:
    """re + j im from two equally shaped lists of numbers; NaN where a part is not finite (then
    refused by the caller, without arithmetic on infinities)."""
    re, im = np.array(re, dtype=float), np.array(im, dtype=float)
    if re.shape != im.shape:
        raise ValueError("the real and imaginary parts differ in shape")
    out = np.full(re.shape, np.nan, dtype=complex)
    ok = np.isfinite(re) & np.isfinite(im)
    out[ok] = re[ok] + 1j * im[ok]
    return out


def influence_signal(path: str | Path) -> str:
    """What the influence file ``path`` holds coefficients of (SIGNALS: "gaps" or "forces"): the
    vector its next job's runs are to give (``balance correct`` takes it from the file)."""
    return _signal_of(read_sealed(path, FORMAT, VERSION, "influence file"), path)


def _signal_of(doc: dict, path: str | Path) -> str:
    """An influence file's signal, checked; a file from before it was kept holds the gaps'."""
    signal = doc.get("signal", "gaps")
    if not isinstance(signal, str) or signal not in SIGNALS:
        raise BadInputError(f"{path}: its signal is {signal!r}, not one of {', '.join(SIGNALS)}")
    return signal


def correct_with(path: str | Path, runs: list[RunVector], *, holes: int = 0, max_rpm: float | None = None,
                 max_grams: float | None = None, coefficients: str | Path | None = None) -> Balancing:
    """The correction for ``runs`` by the influence coefficients of the file ``path``: one run of
    the same machine at each of the file's speeds, instead of a reference and a trial run per plane
    at each; ``holes``, ``max_rpm`` and ``max_grams`` as :func:`influence_balancing`'s.

    The runs read with the runout ``coefficients`` of the influence job hold the part of its
    unbalance their slow roll held, given back (:func:`_correct`'s ``before``); read with others, a
    slow roll since, that of the rotor as it is now. A file that does not say which it was read with
    (from before this was kept) states SLOW_ROLL of its job's unbalance in the deviation instead."""
    doc = read_sealed(path, FORMAT, VERSION, "influence file")
    try:
        planes, axes, rpm = list(doc["planes"]), list(doc["axes"]), float(doc["rpm"])
        A = _complex(doc["influence_re"], doc["influence_im"])
        radius = {str(k): float(v) for k, v in doc["radius_m"].items()}
        feedforward = doc.get("feedforward", False)  # files before it was kept: the feedforward was off
        signal = _signal_of(doc, path)
        speeds = doc.get("speeds_rpm")
        noise, slow_roll, before = None, None, None
        if "reference_unbalance_kg_m" in doc and all(r.runout_removed for r in runs):
            # the job's unbalance, which the slow roll's runout taken out of the runs holds a part of
            job = np.array([float(doc["reference_unbalance_kg_m"][p]) for p in planes])
            if "runout_sha256" not in doc:
                slow_roll = SLOW_ROLL * job
            elif coefficients is not None and doc["runout_sha256"] == file_sha256(coefficients):
                before = job * np.exp(1j * np.radians([float(doc["reference_unbalance_deg"][p]) for p in planes]))
        if NOISE_KEY.get(signal) in doc:
            n = doc[NOISE_KEY[signal]]
            noise = InfluenceNoise(np.array(n["reference"], dtype=float), np.array(n["trials"], dtype=float),
                                   _complex(n["trial_unbalance_re"], n["trial_unbalance_im"]), same_run=False)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):
        raise BadInputError(f"{path}: an influence file needs planes, axes, rpm, influence_re/_im and radius_m") from None
    if not all(isinstance(n, str) for n in (*planes, *axes)) or not (np.isfinite(rpm) and rpm > 0):
        raise BadInputError(f"{path}: its planes and axes are not names, or its speed not one above 0 rpm")
    try:
        speeds = [rpm] if speeds is None else [float(v) for v in speeds]
    except (TypeError, ValueError):
        raise BadInputError(f"{path}: its speeds_rpm is not a list of speeds") from None
    if len(runs) != len(speeds):
        raise BadInputError(f"{len(runs)} run{'s' * (len(runs) != 1)} for influence coefficients of "
                            + " and ".join(f"{r:,.0f}" for r in speeds) + " rpm: one run at each speed")
    ordered = []
    for at in speeds:  # each speed's run, in the file's order
        match = next((r for r in runs if abs(r.rpm / at - 1) <= SAME_SPEED and all(r is not o for o in ordered)), None)
        if match is None:
            raise BadInputError(f"no run at {at:,.0f} rpm (the runs ran at "
                                + ", ".join(f"{r.rpm:,.0f}" for r in runs) + " rpm); the influence coefficients are of "
                                + " and ".join(f"{r:,.0f}" for r in speeds) + " rpm")
        ordered.append(match)
    run = stacked(ordered)
    if A.shape != (len(axes), len(planes)) or not np.all(np.isfinite(A)) or set(radius) != set(planes):
        raise BadInputError(f"{path}: its coefficients are not one finite value per axis and plane")
    if not all(np.isfinite(r) and r > 0 for r in radius.values()):
        raise BadInputError(f"{path}: a plane's radius is not above 0")
    if noise is not None and (noise.reference.shape != (len(axes),) or noise.trials.shape != A.shape
                              or noise.trial_unbalance.shape != (len(planes),)
                              or not all(np.all(np.isfinite(v)) for v in (noise.reference, noise.trials,
                                                                          noise.trial_unbalance))
                              or not np.all(np.abs(noise.trial_unbalance) > 0)):
        raise BadInputError(f"{path}: its {NOISE_KEY[signal]} is not one finite deviation per axis (and plane) and one "
                            "trial unbalance per plane")
    if run.axes != axes:
        raise BadInputError(f"{run.path}: axes {', '.join(run.axes)}; the influence file's are {', '.join(axes)}")
    if not isinstance(feedforward, bool):
        raise BadInputError(f"{path}: its feedforward is not true or false")
    if run.signal != signal:
        raise BadInputError(f"{path}: influence coefficients of the {signal}; the runs' vectors are of the {run.signal}")
    for r in ordered:
        if r.feedforward != feedforward:
            raise BadInputError(f"{r.path} ran with the feedforward {_on_off(r.feedforward)}; the influence "
                                f"coefficients are of the loop with it {_on_off(feedforward)}")
    if slow_roll is not None and not np.all(np.isfinite(slow_roll) & (slow_roll >= 0)):
        raise BadInputError(f"{path}: its reference_unbalance_kg_m is not one finite value of at least 0 per plane")
    if before is not None and not np.all(np.isfinite(before)):
        raise BadInputError(f"{path}: its reference_unbalance_kg_m and _deg are not one finite value per plane")
    result = _correct(planes, run, A, radius, [], noise, holes, max_rpm, max_grams, before)
    result.speeds_rpm = [r.rpm for r in ordered] if len(ordered) > 1 else None
    result.slow_roll = slow_roll
    return result


RECORD_FORMAT, RECORD_VERSION = "ambdaq.balancing_record", 1


def save_record(result: Balancing | ForceBalancing, path: str | Path, runs: list[tuple[str, str | Path]],
                coefficients: str | Path | None, machine: str, influence_file: str | Path | None = None, *,
                overwrite: bool = False) -> Path:
    """The balancing job as a sealed record (ISO 21940-13's record of a balancing): the machine,
    each run with its role (``reference``, ``trial PLANE:GRAMS@DEG:RADIUS_MM``, ``run``) and
    SHA-256, the runout coefficient file (null: none, ``--no-runout``) and, for ``balance
    correct``, the influence file used;
    then what ``--json`` prints (coefficients, correction masses, the unbalance and the grade)."""
    def source(f: str | Path) -> dict:
        return {"file": Path(f).name, "sha256": file_sha256(f)}

    doc = {"format": RECORD_FORMAT, "version": RECORD_VERSION, "machine": machine,
           "runs": [{"role": role, **source(f)} for role, f in runs],
           "runout_coefficients": None if coefficients is None else source(coefficients),
           "influence_file": None if influence_file is None else source(influence_file), "result": result.as_dict()}
    return write_sealed(path, doc, overwrite=overwrite, indent=1)


FORCE_MODEL = 0.002
"""Each plane's unbalance from the bearing forces is known no better than this fraction of the 1X
force its bearing applies (Ki times the coil currents' 1X, over Omega^2), beside the noise: the
force law is linearised and its gains are the machine's data, and with the feedforward off the
controller fights the runout with forces ten times the unbalance's (a 0.4 % error in them was
0.14e-6 kg m on the rear plane with no unbalance at all)."""
FORCE_RELATIVE = 0.001
"""... and no better than this fraction of itself: what the rigid rotor's force law misses (on the
cone rig its nonlinearity in a 0.5 mm gap). Sized on the cone rig (30 jobs at 6,000 rpm, 2-30 g
mm per plane, no runout): with the noise and FORCE_MODEL alone the errors were 1.28 times the
stated deviations, with 0.1 % of the unbalance 1.06; on the spindle, with the slow roll's part
given back and the runout coefficients' own 1X error counted, 1.00 with the feedforward off
(FORCE_MODEL dominates) and 1.06 with it on (the validation campaign's 100 jobs each at 20,000 rpm;
over 40 of them, 1.91 with neither this floor nor the runout's error, and 0.27 with the 1 % this
was while the slow roll's part was stated instead of given back)."""


FORCE_WINDOW_S = 0.05
"""The windows the force-based unbalance is averaged over, s (16 revolutions at 20,000 rpm; 20 in a
1 s run, so their scatter states the noise)."""


@dataclass
class ForceBalancing:
    """The unbalance per plane from one run's bearing forces (issue 43, item 3)."""

    path: str
    planes: list[str]
    rpm: float
    unbalance: np.ndarray  # (planes,) complex, kg m: the rotor's, as BalanceMass.unbalance
    std: np.ndarray  # (planes,): each part's deviation, kg m
    noise: np.ndarray  # (planes,): the part of it that is the windows' scatter, kg m
    windows: int
    radius_m: dict[str, float]
    feedforward: bool
    rotor_mass_kg: float | None = None
    max_rpm: float | None = None
    holes: int = 0
    runout_removed: bool = True  # the run's runout coefficients were taken out (False: --no-runout)
    target_mm_s: float | None = None  # the balance grade asked for (ISO 21940-14's acceptance), mm/s
    held: np.ndarray | None = None  # (planes,): the unbalance the slow roll's runout held, given back, kg m
    held_from: str | None = None  # whose unbalance that is: "before" (a record's) or "this run" (its own)
    tolerance: MassTolerance = MassTolerance()  # the correction masses' own errors (predicted_after)

    @property
    def predicted_after(self) -> dict | None:
        """The grade once the correction masses are on (:func:`grade_after`): the estimate's
        deviation and the masses' own errors."""
        return grade_after(self.planes, np.zeros(len(self.planes), dtype=complex), self.std,
                           plane_masses(self.planes, self.correction, self.radius_m, self.holes), self.tolerance,
                           self.rotor_mass_kg, self.max_rpm)

    @property
    def correction(self) -> np.ndarray:
        """The unbalance per plane a correction adds: the negative of the rotor's, kg m."""
        return -self.unbalance

    @property
    def grade_mm_s(self) -> float | None:
        """The ISO 21940-11 grade of the unbalance this run holds (:func:`balance_grade`)."""
        if not self.rotor_mass_kg or not self.max_rpm:
            return None
        return balance_grade(float(np.abs(self.unbalance).sum()), self.rotor_mass_kg, self.max_rpm)

    @property
    def grade_std_mm_s(self) -> float | None:
        if self.grade_mm_s is None:
            return None
        return balance_grade(float(self.std.sum()), self.rotor_mass_kg, self.max_rpm)

    def as_dict(self) -> dict:
        """What ``balance forces --json`` prints."""
        return {"method": "bearing forces (no trial run)", "recording": Path(self.path).name, "rpm": round(self.rpm, 1),
                "planes": self.planes, "feedforward": self.feedforward, "runout_removed": self.runout_removed,
                "windows": self.windows,
                "unbalance_estimated": {p: {"g_mm": round(abs(u) * 1e6, 4), "deg": round(float(np.degrees(np.angle(u))) % 360, 2),
                                            "std_g_mm": round(float(sd) * 1e6, 4)}
                                        for p, u, sd in zip(self.planes, self.unbalance, self.std)},
                "holes": self.holes or None,
                "correction": mass_rows(plane_masses(self.planes, self.correction, self.radius_m, self.holes)),
                "grade_mm_s": None if self.grade_mm_s is None else round(self.grade_mm_s, 3),
                "grade_std_mm_s": None if self.grade_std_mm_s is None else round(self.grade_std_mm_s, 3),
                "grade": _grade_class(self.grade_mm_s), "max_rpm": self.max_rpm,
                "slow_roll_held": None if self.held is None else {
                    "of": self.held_from, "planes": {p: {"g_mm": round(float(abs(v)) * 1e6, 4),
                                                         "deg": round(float(np.degrees(np.angle(v))) % 360, 2)}
                                                     for p, v in zip(self.planes, self.held)}},
                **_acceptance(self), **_prediction(self)}


def force_balancing(path: str | Path, coefficients: Path | None, machine: str = "spindle", *, holes: int = 0,
                    max_rpm: float | None = None, before: Mapping[str, complex] | None = None) -> ForceBalancing:
    """The unbalance per plane of the rotor in ``path`` (one run at a steady speed, the feedforward
    on or off) from its bearings' 1X forces: per APHT window, the gap's 1X with the runout of
    ``coefficients`` taken out (the rotor's motion; None: the gap's as it is) and the coil currents'
    1X, through ``machine``'s rigid rotor and force law (its ``plane_unbalance``); the windows
    averaged, their scatter the noise, FORCE_MODEL and FORCE_RELATIVE beside it, and the runout
    coefficients' own 1X error (:func:`~ambdaq.workflows.runout.runout_1x_deviation`, each
    axis's through the same law); ``holes`` and ``max_rpm`` as
    :func:`influence_balancing`'s.

    The runout coefficients' 1X holds the rotor's response to the unbalance it had at their slow
    roll (:func:`~ambdaq.workflows.runout.unbalance_held`), and taking it out of the gap takes P U0
    from each window's unbalance (P: that response through ``plane_unbalance``). It is given back:
    of ``before`` (the unbalance per plane by name, kg m phasors, the rotor had then: the estimate a
    correction since came from), else of the run's own unbalance, u = (I - P)^-1 u_window."""
    if before is not None and coefficients is None:
        raise BadInputError("an unbalance before (--before) is what a slow roll's runout held: with no runout "
                            "coefficients (--no-runout) there is none to give back")
    rec = load(path)
    model = loop_model(machine, rec.metadata.get("ambdaq.calibration.rig", {}))
    if model.plane_unbalance is None or not model.balance_planes:
        raise BadInputError(f"the {machine} model has no rotor and force law for balancing from the bearings' forces")
    if rec.has_role("current"):  # refused before APHT runs (without currents, APHT says so)
        model.require(machine, path, list(rec.machine.radial), tuple(rec.role("current").fields))
    result = apht(rec, orders=(1,), coefficients=coefficients, currents=True, window_s=FORCE_WINDOW_S)
    if result.gap.shape[0] < 2:
        raise BadInputError(f"{path}: one window of 1X; record at least two ({result.window_s:g} s each)")
    axes, channels = list(result.axes), result.current_names
    u = np.array([model.plane_unbalance(result.rpm, dict(zip(axes, result.gap[w, 0])),
                                        dict(zip(channels, result.current[w, 0])))
                  for w in range(result.gap.shape[0])])
    held = None
    if coefficients is not None:
        coef = Coefficients.load(coefficients)
        s = unbalance_held(coef, rec, axes)
        P = np.column_stack([model.plane_unbalance(result.rpm, dict(zip(axes, s[:, k])), {}) for k in range(s.shape[1])])
        # the coefficients' own 1X error, each axis's through the same law (independent)
        e = runout_1x_deviation(coef, axes)
        runout_error = np.sqrt(sum(np.abs(model.plane_unbalance(result.rpm, {a: complex(e[b])}, {})) ** 2
                                   for b, a in enumerate(axes)))
        if before is not None:
            if sorted(before) != sorted(model.balance_planes) or not all(np.isfinite(v) for v in before.values()):
                raise BadInputError(f"the unbalance before is of planes {', '.join(before)}; the {machine}'s are "
                                    f"{', '.join(model.balance_planes)}")
            held = P @ np.array([before[p] for p in model.balance_planes])
            u = u + held
        else:
            u = np.linalg.solve(np.eye(len(P)) - P, u.T).T
            held = P @ u.mean(axis=0)
    noise = np.sqrt((np.var(u.real, axis=0, ddof=1) + np.var(u.imag, axis=0, ddof=1)) / 2 / u.shape[0])
    current = np.abs(result.current[:, 0]).mean(axis=0)  # per channel, A
    # the scale of each bearing's 1X force as an unbalance, Ki |I| / Omega^2 (kg m): each current
    # channel's magnitude alone through the same law, root-sum-square (opposite coils of a cone
    # bearing would cancel if taken together)
    force = np.sqrt(sum(np.abs(model.plane_unbalance(result.rpm, {}, {c: i})) ** 2 for c, i in zip(channels, current)))
    unbalance = u.mean(axis=0)
    std = np.sqrt(noise**2 + (FORCE_MODEL * np.abs(force)) ** 2 + (FORCE_RELATIVE * np.abs(unbalance)) ** 2
                  + (runout_error**2 if coefficients is not None else 0.0))
    on = result.feedforward is not None and bool(np.abs(result.feedforward).max() > FF_ON)
    return ForceBalancing(str(path), list(model.balance_planes), result.rpm, unbalance, std, noise, u.shape[0],
                          {p: model.balance_radius_m for p in model.balance_planes}, on, rec.machine.rotor_mass_kg,
                          max_rpm, holes, runout_removed=coefficients is not None, held=held,
                          held_from="before" if before is not None else "this run" if held is not None else None)


def load_record(path: str | Path) -> dict:
    """A sealed balancing record (:func:`save_record`) as the commissioning report shows it: the
    record's file name, machine and runs, and its result as ``--json`` printed it."""
    doc = read_sealed(path, RECORD_FORMAT, RECORD_VERSION, "balancing record")
    try:
        result, runs = dict(doc["result"]), [dict(r) for r in doc["runs"]]
        masses = [{"plane": str(m["plane"]), "grams": float(m["grams"]), "deg": float(m["deg"]),
                   "radius_mm": float(m["radius_mm"])} for m in result["correction"]]
        unbalance = {str(p): {k: float(u[k]) for k in ("g_mm", "deg")} | {"std_g_mm": _optional(u.get("std_g_mm"))}
                     for p, u in dict(result["unbalance_estimated"]).items()}
        grade = {k: _optional(result.get(k)) for k in ("grade_mm_s", "grade_std_mm_s", "max_rpm")}
        rpm = float(result["rpm"])
    except (KeyError, TypeError, ValueError, AttributeError):
        raise BadInputError(f"{path}: a balancing record needs its runs and a result with rpm, unbalance_estimated "
                            "and correction") from None
    std = result.get("correction_std_g_mm") or {}  # influence coefficients state it under the correction
    for p, u in unbalance.items():
        if u["std_g_mm"] is None and isinstance(std, dict) and p in std:
            u["std_g_mm"] = _optional(std[p])
    runout = doc.get("runout_coefficients")
    return {"file": Path(path).name, "machine": str(doc.get("machine")), "runs": runs,
            "runout_sha256": runout.get("sha256") if isinstance(runout, dict) else None,
            "method": str(result.get("method", "influence coefficients (ISO 21940-13)")), "rpm": rpm,
            "unbalance": unbalance, "correction": masses, "grade": result.get("grade"), **grade,
            "acceptance": _record_acceptance(result.get("acceptance")),
            "predicted_after": _record_prediction(result.get("predicted_after"))}


def record_unbalance(record: dict) -> dict[str, complex]:
    """A balancing record's (:func:`load_record`) estimated unbalance per plane as phasors, kg m
    (as :attr:`~ambdaq.machines.balance_masses.BalanceMass.unbalance`)."""
    return {p: u["g_mm"] * 1e-6 * complex(np.exp(1j * np.radians(u["deg"]))) for p, u in record["unbalance"].items()}


def _record_prediction(value) -> dict | None:
    """A record's grade predicted after its correction (where it stated a grade), checked: None if
    absent (a record from before it was kept)."""
    if value is None:
        return None
    try:
        out = {k: float(value[k]) for k in ("grade_mm_s", "at_most_mm_s", "level", "mass_tolerance_g",
                                            "angle_tolerance_deg")}
    except (KeyError, TypeError, ValueError):
        raise BadInputError("a balancing record's predicted_after needs grade_mm_s, at_most_mm_s, level, "
                            "mass_tolerance_g and angle_tolerance_deg") from None
    if not all(np.isfinite(v) and v >= 0 for v in out.values()):
        raise BadInputError("a balancing record's predicted_after holds a value that is not a finite number >= 0")
    out["grade"] = _grade_class(out["at_most_mm_s"])
    return out


def _record_acceptance(value) -> dict | None:
    """A record's ISO 21940-14 acceptance (where its job asked for a grade), checked: None if absent."""
    if value is None:
        return None
    try:
        out = {"target": str(value["target"]), "permissible_mm_s": float(value["permissible_mm_s"]),
               "error_mm_s": float(value["error_mm_s"]), "after_balancing": value["after_balancing"],
               "check": value["check"]}
    except (KeyError, TypeError, ValueError):
        raise BadInputError("a balancing record's acceptance needs target, permissible_mm_s, error_mm_s, "
                            "after_balancing and check") from None
    if not isinstance(out["after_balancing"], bool) or not isinstance(out["check"], bool):
        raise BadInputError("a balancing record's acceptance states after_balancing and check as true or false")
    return out


def _optional(value) -> float | None:
    """A JSON number or null as a float or None (BadInputError's caller catches the rest)."""
    return None if value is None else float(value)
