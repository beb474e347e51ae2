"""The validation campaign: each estimator ambdaq states a number from, run by Monte Carlo on the
simulator at the operating points the docs send users to, against the simulator's own truth.

A *point* is one operating point of one estimator (a slow roll of 4 s, a run-up to 20,000 rpm);
its runs differ only in their seed (the sensor and amplifier noise). Each point gives a
:class:`Row`: the stated accuracy, the measured bias and scatter, the runs and seeds, the command
that regenerates it, and whether it holds. ``tests/validation/test_validation.py`` runs a small
version of each in the default suite and the whole campaign under ``-m validation``;

    python tests/validation/campaign.py            # the whole campaign -> docs/validation.md
    python tests/validation/campaign.py --small    # what the default suite runs, printed

writes the table of docs/validation.md (never typed by hand).

Where the estimator states an uncertainty (runout's Cramér-Rao bound), the row compares the
scatter of the estimates about the truth with it: their ratio must be within 0.9-1.1 pooled over
axes and harmonics and 0.7-1.4 for every axis and harmonic (issue 39). Where it states a bound
(the ISO 14839-3 peak within 0.5 dB), the row counts the runs outside it. Where it states nothing,
the row says so and gives the bound measured here (what the docs may quote).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ambdaq.analysis.iso14839 import db, model_sensitivity
from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load
from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.sim.source import SimSource
from ambdaq.speed import SLOW_ROLL_RPM, SpeedProfile
from ambdaq.workflows.balancing import MassTolerance

AXES = ("front_x", "front_y", "rear_x", "rear_y", "axial")
POOLED = (0.9, 1.1)  # stated uncertainty / scatter, pooled over axes and harmonics (issue 39)
EACH = (0.7, 1.4)  # ... for every axis and harmonic


@dataclass
class Row:
    """One estimator at one operating point: what it states and what the campaign measured."""

    estimator: str
    point: str
    stated: str
    bias: str
    scatter: str
    runs: int
    seeds: str
    command: str
    holds: bool
    why: str = ""  # what failed, when it does not hold
    figures: dict = field(default_factory=dict)  # the numbers behind the text, for the tests


def _write(source: SimSource, path: Path, seconds: float) -> Path:
    """``seconds`` of ``source``, unpaced, as ``sim generate`` records it."""
    Recorder([source], path, RecordOptions(duration_s=seconds, fsync=False), overwrite=True).run()
    return path


def _record(path: Path, seconds: float, *, seed: int, speed: SpeedProfile, profile: str = "spindle", params=None,
            excite=None) -> Path:
    """``seconds`` of the simulated ``profile`` with its truth (:func:`_write`)."""
    source = SimSource(profile, seed=seed, speed=speed, truth=True, params=params)
    if excite is not None:
        source.rig.set_excitation(excite.resolve(source.rig.excitation_spec()))
    return _write(source, path, seconds)


def _ratios(err: np.ndarray, unc: np.ndarray) -> tuple[float, np.ndarray]:
    """Scatter about the truth over stated uncertainty: pooled, and per (harmonic, axis).

    ``err`` (run, harmonic, axis) complex, estimate less truth; ``unc`` (run, harmonic, axis) the
    standard uncertainty each run stated for each of the real and imaginary parts."""
    z2 = (err.real / unc) ** 2 + (err.imag / unc) ** 2  # two parts per value
    return float(np.sqrt(z2.mean() / 2)), np.sqrt(z2.mean(axis=0) / 2)


# --- runout ------------------------------------------------------------------------------------

def unbalance_at(rpm: float) -> np.ndarray:
    """The simulated spindle's 1X response to its own unbalance alone at ``rpm`` (m, per axis): what
    a 1X runout estimate at that speed holds beside the runout (the model's, not the campaign's)."""
    from ambdaq.sim.rigs.spindle import SpindleParams, SpindleRig

    quiet = dataclasses.replace(SpindleParams(), unbalance=(0.0, 0.0))
    return np.abs(SpindleRig().unbalance_response(rpm) - SpindleRig(quiet).unbalance_response(rpm))


def runout(seconds: float, rpm: float, seeds: range, *, unbalance: bool = True, harmonics=(1, 2, 3, 4, 5, 6),
           skip_s: float = 0.0) -> Row:
    """``runout identify`` of one recording per seed against the simulator's ``/truth/runout``
    (its harmonics fitted on the same samples): bias and scatter of each harmonic against the
    standard uncertainty each run states. The bias may reach the model bound identify states (bound_um),
    and for a 1X with unbalance the unbalance response at that speed (docs/coefficients.md)."""
    from ambdaq.sim.rigs.spindle import SpindleParams
    from ambdaq.workflows.runout import identify_recordings

    params = None if unbalance else dataclasses.replace(SpindleParams(), unbalance=(0.0, 0.0))
    err, unc, bound = [], [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            path = _record(Path(d) / f"r{seed}.mcap", seconds + skip_s, seed=seed, speed=SpeedProfile(rpm, rpm),
                           params=params)
            rec = load(path, start=skip_s or None)
            ident = identify_recordings([rec], list(harmonics), "fit")
            theta = rec["/amb/rotor"]["angle"]
            truth = rec["/truth/runout"]
            n = min(len(truth), len(theta))
            orders = list(range(1, max(harmonics) + 1))  # every order the truth holds up to the highest, or they leak
            true = harmonic_fit(np.column_stack([truth[a][:n] for a in AXES]), theta[:n], orders)[
                [orders.index(k) for k in harmonics]]
            err.append(ident.per_file[0] - true)
            unc.append(ident.uncertainty)
            bound.append(ident.model_bound)
    err, unc, bound = np.array(err), np.array(unc), np.array(bound)
    pooled, each = _ratios(err, unc)  # about the truth: noise and bias together
    about_mean, each_mean = _ratios(err - err.mean(axis=0), unc)  # the noise alone
    about_mean *= np.sqrt(len(err) / (len(err) - 1))  # the mean was estimated from the same runs
    each_mean *= np.sqrt(len(err) / (len(err) - 1))
    bias = np.abs(err.mean(axis=0))  # (harmonic, axis), m
    se = unc.mean(axis=0) * np.sqrt(2 / len(err))  # the standard error of the runs' mean, per part
    bias_z = float(np.max(bias / se))
    # the bias is within the model bound identify states, give or take 3 standard errors
    allowed = bound.mean(axis=0)
    if unbalance and 1 in harmonics:
        allowed[list(harmonics).index(1)] += unbalance_at(rpm)
    within_bound = bool(np.all(bias <= allowed + 3 * se))
    noise_holds = POOLED[0] <= about_mean <= POOLED[1] and bool(np.all((each_mean >= EACH[0]) & (each_mean <= EACH[1])))
    holds = noise_holds and within_bound
    worst = np.unravel_index(np.argmax(np.abs(np.log(each))), each.shape)
    what = f"{harmonics[worst[0]]}X {AXES[worst[1]]}"
    speed = "slow roll" if rpm == SLOW_ROLL_RPM else f"{rpm:,.0f} rpm"
    return Row(
        "runout per harmonic (`runout identify`)",
        f"{speed}, {seconds:g} s, {'with' if unbalance else 'without'} unbalance, "
        f"{harmonics[0]}X-{harmonics[-1]}X" + (f", first {skip_s:g} s left out" if skip_s else ""),
        f"u per part (Cramér-Rao), median {np.median(unc) * 1e9:.1f} nm; model bound up to "
        f"{bound.mean(axis=0).max() * 1e9:.1f} nm",
        f"largest {bias.max() * 1e9:.1f} nm ({bias_z:.1f} standard errors; "
        f"{'within' if within_bound else 'beyond'} the model bound"
        + (" and the unbalance response" if unbalance and 1 in harmonics else "") + ")",
        f"about the mean {about_mean:.2f} u pooled, {each_mean.min():.2f}-{each_mean.max():.2f} each; about the truth "
        f"{pooled:.2f} pooled, {each.min():.2f}-{each.max():.2f} each (worst {what})",
        len(err), f"{seeds.start}-{seeds.stop - 1}",
        f"sim generate --rpm {'slowroll' if rpm == SLOW_ROLL_RPM else f'{rpm:g}'} --duration {seconds + skip_s:g} "
        f"--seed S --truth; runout identify --json",
        holds, "" if holds else f"about the mean {about_mean:.2f} (0.9-1.1), each {each_mean.min():.2f}-{each_mean.max():.2f} "
                                f"(0.7-1.4); bias {'within' if within_bound else 'beyond'} the model bound",
        {"pooled": pooled, "each": each, "bias_z": bias_z, "pooled_about_mean": about_mean, "each_about_mean": each_mean,
         "within_bound": within_bound})


# --- shaft centreline ------------------------------------------------------------------------

def _dc(v: np.ndarray, th: np.ndarray) -> float:
    """The constant of the least-squares fit of a constant and orders 1-4 (a plain mean below 4
    revolutions), computed independently of ambdaq's own fit."""
    if th[-1] - th[0] < 8 * np.pi:
        return float(v.mean())
    cols = [np.ones_like(th)] + [f(k * th) for k in range(1, 5) for f in (np.sin, np.cos)]
    return float(np.linalg.lstsq(np.column_stack(cols), v, rcond=None)[0][0])


def centreline(seconds: float, top_rpm: float, seeds: range) -> Row:
    """``runup``'s shaft centreline (per 0.1 s window, runout taken out with coefficients from a
    slow roll) against the true rotor position reduced the same way."""
    from ambdaq.workflows.runout import identify_recordings
    from ambdaq.workflows.runup_diagnostics import WATERFALL_S, analyse

    errs = []
    with tempfile.TemporaryDirectory() as d:
        slow = _record(Path(d) / "slow.mcap", 2.0, seed=1000, speed=SpeedProfile(SLOW_ROLL_RPM, SLOW_ROLL_RPM))
        coef = identify_recordings([load(slow)], [1, 2, 3, 4, 5, 6], "fit").coef.save(Path(d) / "runout.json")
        for seed in seeds:
            path = _record(Path(d) / f"u{seed}.mcap", seconds, seed=seed, speed=SpeedProfile(0.0, top_rpm, seconds))
            rec = load(path)
            line = analyse(rec, coefficients=coef).centreline
            truth, theta = rec["/truth/position"], np.unwrap(rec["/amb/rotor"]["angle"])
            n = int(round(WATERFALL_S * rec["/amb/gap"].nominal_rate))
            for bearing, (xs, ys) in line.bearings.items():
                for axis, got in ((f"{bearing}_x", xs), (f"{bearing}_y", ys)):
                    want = [_dc(truth[axis][i * n:(i + 1) * n], theta[i * n:(i + 1) * n]) for i in range(len(got))]
                    errs.append((np.asarray(got) - np.asarray(want)) * 1e6)
    e = np.concatenate(errs)  # um
    bound = 0.05
    holds = float(np.abs(e).max()) < bound
    return Row("shaft centreline (`runup`)", f"run-up 0-{top_rpm:,.0f} rpm in {seconds:g} s, 0.1 s windows",
               f"none stated; docs quote {bound * 1e3:.0f} nm", f"{e.mean() * 1e3:+.1f} nm",
               f"RMS {np.sqrt(np.mean(e ** 2)) * 1e3:.1f} nm, largest {np.abs(e).max() * 1e3:.1f} nm",
               len(seeds), f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --rpm 0:{top_rpm:g}:{seconds:g} --duration {seconds:g} --seed S --truth; "
               "runup --coefficients C --json", holds,
               "" if holds else f"largest error {np.abs(e).max() * 1e3:.1f} nm (< {bound * 1e3:.0f})",
               {"largest_um": float(np.abs(e).max())})


# --- run-up: 1X order tracking, critical speed and amplification ----------------------------

def _slow_roll_coefficients(d: Path) -> Path:
    """Runout coefficients from a 2 s slow roll (seed 1000), as the docs have users make them."""
    from ambdaq.workflows.runout import identify_recordings

    slow = _record(d / "slow.mcap", 2.0, seed=1000, speed=SpeedProfile(SLOW_ROLL_RPM, SLOW_ROLL_RPM))
    return identify_recordings([load(slow)], [1, 2, 3, 4, 5, 6], "fit").coef.save(d / "runout.json")


def one_x(seconds: float, top_rpm: float, seeds: range) -> Row:
    """``runup``'s 1X and 2X vectors per window (runout taken out with slow-roll coefficients)
    against the true rotor's, tracked alike; 0.3 um is what docs/iso.md quotes."""
    from ambdaq.analysis.orders import order_track
    from ambdaq.units import RAD_S_TO_RPM
    from ambdaq.workflows.runup_diagnostics import analyse

    errs, amps = [], []
    with tempfile.TemporaryDirectory() as d:
        coef = _slow_roll_coefficients(Path(d))
        for seed in seeds:
            rec = load(_record(Path(d) / f"u{seed}.mcap", seconds, seed=seed, speed=SpeedProfile(0.0, top_rpm, seconds)))
            res = analyse(rec, coefficients=coef)
            truth, rot = rec["/truth/position"], rec["/amb/rotor"]
            true = order_track(np.column_stack([truth[a] for a in res.axes]), rot["angle"], rot["speed"] * RAD_S_TO_RPM)
            for k in (1, 2):
                errs.append(np.abs(res.track.order(k) - true.order(k)).ravel() * 1e6)
                amps.append(np.abs(true.order(k)).ravel() * 1e6)
    return _vector_row("1X and 2X vectors in a run-up (`runup`)",
                       f"run-up 0-{top_rpm:,.0f} rpm in {seconds:g} s, 8 revolutions a window, the runout out "
                       f"(slow-roll coefficients); vectors up to {np.concatenate(amps).max():.0f} µm", errs, seeds,
                       f"sim generate --rpm 0:{top_rpm:g}:{seconds:g} --duration {seconds:g} --seed S --truth; "
                       "runup --coefficients C --json")


def _vector_row(estimator: str, point: str, errs: list[np.ndarray], seeds: range, command: str,
                bound_um: float = 0.3) -> Row:
    """A row of vector errors (um) against the bound the docs quote for them (0.3 um)."""
    e = np.concatenate(errs)
    holds = float(e.max()) < bound_um
    return Row(estimator, point, f"none stated; docs quote {bound_um:g} µm", "-",
               f"error RMS {np.sqrt(np.mean(e ** 2)):.3f} µm, largest {e.max():.3f} µm", len(seeds),
               f"{seeds.start}-{seeds.stop - 1}", command, holds,
               "" if holds else f"largest {e.max():.3f} µm (< {bound_um:g})", {"largest_um": float(e.max())})


def apht_one_x(rpm: float, seeds: range, seconds: float = 2.0, window_s: float = 0.25, ff: str = "lms") -> Row:
    """``apht``'s 1X of the gap per window (runout out with slow-roll coefficients) at one speed,
    with the controller's LMS converging, against the true rotor's 1X fitted over the same window;
    0.3 um is what docs/iso.md quotes."""
    from ambdaq.workflows.apht import apht

    errs = []
    with tempfile.TemporaryDirectory() as d:
        coef = _slow_roll_coefficients(Path(d))
        for seed in seeds:
            source = SimSource("spindle", seed=seed, speed=SpeedProfile(rpm, rpm), truth=True, ff_mode=ff)
            rec = load(_write(source, Path(d) / f"a{seed}.mcap", seconds))
            out = apht(rec, window_s=window_s, coefficients=coef)
            truth, theta = rec["/truth/position"], rec["/amb/rotor"]["angle"]
            size = int(round(window_s * rec["/amb/gap"].nominal_rate))
            for w, start in enumerate(out.time_s):
                s = int(round(start * rec["/amb/gap"].nominal_rate))
                want = harmonic_fit(np.column_stack([truth[a][s:s + size] for a in out.axes]), theta[s:s + size], (1,))[0]
                errs.append(np.abs(out.gap[w, 0] - want) * 1e6)
    return _vector_row("1X per window at one speed (`apht`)",
                       f"{rpm:,.0f} rpm, {window_s:g} s windows ({rpm / 60 * window_s:.1f} revolutions), "
                       f"{'the LMS converging' if ff == 'lms' else 'no feedforward'}, the runout out", errs, seeds,
                       f"sim generate --rpm {rpm:g} --ff {ff} --duration {seconds:g} --seed S --truth; "
                       "apht --coefficients C --json")


def critical_speed(seeds: range) -> Row:
    """A critical speed measured in a run-up (the spindle's radial D halved: a forward mode near
    180 Hz, amplified past 2.5) against the true rotor's 1X peak, tracked alike: its speed and
    amplification factor (API 684's half-power method)."""
    from ambdaq.analysis.orders import one_x_peaks, order_track
    from ambdaq.units import RAD_S_TO_RPM
    from ambdaq.workflows.runup_diagnostics import analyse

    d_rpm, d_amp, grid, allowed = [], [], [], []
    detuned = [0.00075, 0.00075, 0.001, 0.001, 0.002]
    with tempfile.TemporaryDirectory() as d:
        coef = _slow_roll_coefficients(Path(d))
        for seed in seeds:
            source = SimSource("spindle", seed=seed, speed=SpeedProfile(3000.0, 15000.0, 6.0), truth=True)
            p, i, _ = source.rig.pid_gains
            source.rig.set_pid(p, i, np.array(detuned))
            rec = load(_write(source, Path(d) / f"c{seed}.mcap", 6.0))
            res = analyse(rec, coefficients=coef)
            grid.append(float(np.median(np.diff(res.track.rpm))))
            truth, rot = rec["/truth/position"], rec["/amb/rotor"]
            true = order_track(np.column_stack([truth[a] for a in res.axes]), rot["angle"], rot["speed"] * RAD_S_TO_RPM)
            for j, axis in enumerate(res.axes):
                got = [q for q in res.peaks[axis] if q.is_critical()]
                want = [q for q in one_x_peaks(true.rpm, true.order(1)[:, j]) if q.is_critical()]
                if not got and not want:  # an axis whose 1X has no critical peak, in the truth as measured
                    continue
                if len(got) != 1 or len(want) != 1:
                    d_rpm.append(np.inf)
                    d_amp.append(np.inf)
                    allowed.append(0.0)
                    continue
                d_rpm.append(got[0].rpm / want[0].rpm - 1)
                allowed.append(grid[-1] / want[0].rpm * 1.001)  # one window's spacing, at its speed
                d_amp.append(got[0].amplification / want[0].amplification - 1)
    d_rpm, d_amp = np.array(d_rpm) * 100, np.array(d_amp) * 100
    allowed_pct = np.array(allowed) * 100
    step_pct = float(allowed_pct.max()) if allowed_pct.size else 0.0
    holds = bool(np.all(np.abs(d_rpm) <= allowed_pct) and np.all(np.abs(d_amp) < 5.0))
    return Row("critical speed and amplification factor (`runup`, API 684)",
               "run-up 3,000-15,000 rpm in 6 s, radial D halved (a forward mode near 180 Hz), windows "
               f"{np.mean(grid):.0f} rpm apart",
               f"none stated; one window's spacing in speed (up to {step_pct:.1f} %: the peak is a window's, and "
               "two windows beside it can swap on the last bits), 5 % in amplification quoted here",
               f"{np.mean(d_rpm):+.3f} % speed, {np.mean(d_amp):+.2f} % amplification",
               f"largest {np.abs(d_rpm).max():.3f} % speed, {np.abs(d_amp).max():.2f} % amplification",
               len(d_rpm), f"{seeds.start}-{seeds.stop - 1}, each axis with a critical peak",
               "sim generate --rpm 3000:15000:6 --duration 6 --seed S --truth --param pid.d=...; runup --model spindle",
               holds, "" if holds else f"largest {np.abs(d_rpm).max():.3f} % speed (> a window), "
                                       f"{np.abs(d_amp).max():.2f} % amplification (< 5)",
               {"rpm_pct": d_rpm, "amp_pct": d_amp})


# --- ISO 14839-2 ------------------------------------------------------------------------

def orbit_maxima(seconds: float, top_rpm: float, seeds: range, band_rpm: float = 5000.0) -> Row:
    """``iso vibration``'s graded orbit maximum per bearing and speed band (runout out with
    slow-roll coefficients) against the true rotor's, windowed alike; iso.md quotes 1.5 um (the
    sensor noise's peak in a window, about 0.8 um, and the runout's residue)."""
    from ambdaq.units import RAD_S_TO_RPM
    from ambdaq.workflows.iso_vibration import WINDOW_S, evaluate, orbit_windows

    errs = []
    with tempfile.TemporaryDirectory() as d:
        coef = _slow_roll_coefficients(Path(d))
        for seed in seeds:
            rec = load(_record(Path(d) / f"v{seed}.mcap", seconds, seed=seed, speed=SpeedProfile(0.0, top_rpm, seconds)))
            grades, _info = evaluate([rec], cmin_m=None, band_rpm=band_rpm, coefficients=coef)
            truth, speed = rec["/truth/position"], rec["/amb/rotor"]["speed"] * RAD_S_TO_RPM
            n = int(round(WINDOW_S * rec["/amb/gap"].nominal_rate))
            for g in grades:
                s, true_max, _ = orbit_windows(truth[f"{g.bearing}_x"], truth[f"{g.bearing}_y"], speed, n)
                band = (s >= g.rpm_from) & (s < g.rpm_to)
                errs.append(g.max_um - true_max[band].max() * 1e6)
    e = np.array(errs)
    holds = float(np.abs(e).max()) < 1.5
    return Row("ISO 14839-2 orbit maximum per bearing and speed band (`iso vibration`)",
               f"run-up 0-{top_rpm:,.0f} rpm in {seconds:g} s, {band_rpm:,.0f} rpm bands, the runout out",
               "none stated; iso.md quotes 1.5 µm", f"{e.mean():+.2f} µm",
               f"RMS {np.sqrt(np.mean(e ** 2)):.2f} µm, largest {np.abs(e).max():.2f} µm", len(e),
               f"{seeds.start}-{seeds.stop - 1}, each bearing and band",
               f"sim generate --rpm 0:{top_rpm:g}:{seconds:g} --duration {seconds:g} --seed S --truth; "
               "iso vibration --coefficients C --json", holds, "" if holds else f"largest {np.abs(e).max():.2f} µm (< 1.5)",
               {"largest_um": float(np.abs(e).max())})


# --- self-sensing -----------------------------------------------------------------------

def self_sensing(rpm: float, seeds: range, seconds: float = 3.0) -> Row:
    """``selfsense``'s angle (Jeon et al.'s flux-linkage estimator) on the Lorentz motor against
    its encoder, steady state after 1 s: the error's mean and spread over seeds. Jeon et al. (Fig. 7)
    claim 1 deg or less from 100 to 1,000 rpm."""
    from ambdaq.workflows.selfsense import analyse

    means, worst = [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            rec = load(_record(Path(d) / f"l{seed}.mcap", seconds, seed=seed, speed=SpeedProfile(rpm, rpm),
                               profile="lorentz"))
            out = analyse(rec, 8.0, 1.0, {"resistance": None, "inductance": None, "emf_constant": None}, False)
            means.append(out["steady"]["mean_deg"])
            worst.append(out["steady"]["max_abs_deg"])
    means, worst = np.array(means), np.array(worst)
    holds = float(worst.max()) <= 1.0
    return Row("self-sensing rotor angle (`selfsense`, Jeon et al.)", f"Lorentz motor at {rpm:,.0f} rpm, steady state "
               f"after 1 s of {seconds:g} s, started 8 deg off", "1 deg (Jeon et al. Fig. 7)", f"{means.mean():+.3f} deg",
               f"mean over seeds spread {means.std(ddof=1) if len(means) > 1 else 0.0:.3f} deg; largest error {worst.max():.3f} deg", len(seeds),
               f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --profile lorentz --rpm {rpm:g} --duration {seconds:g} --seed S; selfsense --json", holds,
               "" if holds else f"largest {worst.max():.3f} deg (<= 1)", {"largest_deg": float(worst.max())})


# --- modal identification ---------------------------------------------------------------

def modal(spec: str, seeds: range, seconds: float = 3.2) -> Row:
    """``identify modal`` (ERA over each hammer strike's free decay) on the cone rig against the
    modes of its own linearised loop (``ConeRig.modes``): the dominant mode's frequency and damping.
    ``spec`` is ``sim generate --impact``'s (an axial ``x:50``, a radial ``y1:50:0.25``)."""
    from ambdaq.sim.rigs.cone import ConeRig, Impact
    from ambdaq.workflows.modal import identify_modal

    axial = spec.split(":")[0] == "x"
    f_true, z_true, _ = [m for m in ConeRig().modes() if (m[2] == 0) == axial][0]
    d_f, d_z = [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            source = SimSource("cone", seed=seed, truth=True)
            source.rig.set_impact(Impact.parse(spec))
            best = identify_modal(load(_write(source, Path(d) / f"m{seed}.mcap", seconds))).modes[0]
            d_f.append(best.freq_hz / f_true - 1)
            d_z.append(best.zeta / z_true - 1)
    d_f, d_z = np.array(d_f) * 100, np.array(d_z) * 100
    holds = bool(np.abs(d_f).max() < 2.0 and np.abs(d_z).max() < 2.0)
    return Row("modal frequency and damping (`identify modal`, ERA)",
               f"cone rig, {'axial' if axial else 'radial'} strikes `--impact {spec}`, {seconds:g} s "
               f"(truth {f_true:.2f} Hz, zeta {z_true:.3f})", "none stated; tests quote 2 %",
               f"{d_f.mean():+.2f} % frequency, {d_z.mean():+.2f} % damping",
               f"largest {np.abs(d_f).max():.2f} % frequency, {np.abs(d_z).max():.2f} % damping", len(seeds),
               f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --profile cone --impact {spec} --duration {seconds:g} --seed S; identify modal --json",
               holds, "" if holds else f"largest {np.abs(d_f).max():.2f} % frequency, {np.abs(d_z).max():.2f} % damping (< 2)",
               {"freq_pct": d_f, "zeta_pct": d_z})


# --- base-motion feedforward (MFXLMS) ----------------------------------------------------

def _identified_w(seed: int, f_hz: float, b: np.ndarray) -> np.ndarray:
    """The compensator W at ``f_hz`` (Hz) MFXLMS identifies on the base-motion rig (seed ``seed``)
    from two runs with other disturbance ratios (Kang et al., eq. A-4 to A-17), with the secondary
    path ``b`` at that frequency."""
    from ambdaq.analysis.mfxlms import mfxlms, run_beta, separate
    from ambdaq.sim.rigs.base_motion import BaseExcitation, BaseMotionRig

    betas = []
    for alpha in (1.0, -1.0 + 0.5j):
        rig = BaseMotionRig(seed=seed)
        rig.set_base_motion(BaseExcitation("sine", 1.0, f_hz, alpha))
        rig.run(5000)
        v = rig.run(30_000).values
        res = mfxlms(v["/amb/gap"][:, :2], v["/base/accel"][:, :2], b, f_hz, rig.params.sample_rate)
        betas.append((run_beta(res, alpha), alpha))
    return separate(betas[0][0], betas[0][1], betas[1][0], betas[1][1])


def mfxlms_compensator(f_hz: float, seeds: range) -> Row:
    """The base-motion compensator W identified by MFXLMS with two disturbance ratios (Kang et al.,
    eq. A-4 to A-17) on the base-motion rig, against its perfect compensator W* = -B^-1 C: the
    largest error relative to the matrix (its Frobenius norm) within 1 %, and each element's own
    within 5 % (the cross terms, 30 times smaller than the direct ones, carry the noise: 0.5-3.9 %
    at 100 Hz over 12 seeds, where tests/test_base_motion.py's one seed had 0.5 %)."""
    from ambdaq.sim.rigs.base_motion import BaseMotionRig

    B, _, wstar = BaseMotionRig().responses([f_hz])
    errs, norm = [], []
    for seed in seeds:
        w = _identified_w(seed, f_hz, B[0])
        errs.append(np.abs(w / wstar[0] - 1).max() * 100)
        norm.append(np.abs(w - wstar[0]).max() / np.linalg.norm(wstar[0]) * 100)
    e, m = np.array(errs), np.array(norm)
    holds = float(m.max()) < 1.0 and float(e.max()) < 5.0
    return Row("base-motion compensator (MFXLMS, Kang et al.)", f"base-motion rig, {f_hz:g} Hz sine, two "
               "disturbance ratios, 3 s each", "1 % of the matrix; 5 % of each element", "-",
               f"largest {m.max():.2f} % of the matrix; each element's own largest {e.max():.2f} %, median "
               f"{np.median(e):.2f} %", len(seeds), f"{seeds.start}-{seeds.stop - 1}",
               "ambdaq fx campaign (the identification inside it)", holds,
               "" if holds else f"largest {m.max():.2f} % of the matrix (< 1), {e.max():.2f} % of an element (< 5)",
               {"largest_pct": float(e.max()), "matrix_pct": float(m.max())})


# --- rotor drops (ISO 14839-5) -----------------------------------------------------------

def drop(rpm: float, lasting_s: float, seeds: range, at_s: float = 0.5) -> Row:
    """A drop onto the cone rig's touchdown bearings caught by ``record --snapshot --trigger
    touchdown`` (``sim generate``): its time on the bearing and impact speed against the true
    rotor's (the first and last samples at 0.9 Cmin of the true excursion, and its speed over the
    2 ms before the first contact); tests/test_touchdown.py quotes 2.5 samples and 10 %."""
    from click.testing import CliRunner

    from ambdaq.analysis.touchdown import AT_CLEARANCE, IMPACT_WINDOW_S
    from ambdaq.cli.main import cli
    from ambdaq.daq.recording import open_recording
    from ambdaq.acquisition.touchdowns import recorded_drop

    d_on, d_speed = [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            folder = Path(d) / f"s{seed}"
            folder.mkdir()
            r = CliRunner().invoke(cli, ["sim", "generate", "--profile", "cone", "--rpm", f"{rpm:g}", "--seed", str(seed),
                                         "--drop", f"{at_s}:{lasting_s}", "--truth", "--duration",
                                         f"{at_s + lasting_s + 0.6:g}", "--snapshot", "0.4s", "--post", "0.5s",
                                         "--trigger", "touchdown", "-q", "-o", str(folder / "drop.mcap")])
            if r.exit_code != 0:
                raise RuntimeError(r.output)
            path = next(folder.glob("drop_*_touchdown.mcap"))
            rec = open_recording(path)
            t = recorded_drop(rec.metadata).touchdown
            m, data = rec.machine, load(path, ["/truth/position"])["/truth/position"]
            pos = {a: np.asarray(data[a]) for a in data.fields}
            radii = np.column_stack([np.hypot(pos[b.x], pos[b.y]) for b in m.bearings]
                                    + [np.abs(pos[a]) for a in m.axes if a not in m.bearing_axes]) / m.cmin_m
            worst, time_s = radii.max(axis=1), np.asarray(data.time)
            rate = 1.0 / float(np.median(np.diff(time_s)))
            on = np.flatnonzero(worst >= AT_CLEARANCE)
            first, last = on[0], on[on < on[0] + int(lasting_s * rate) + 1000].max()
            k = int(round(IMPACT_WINDOW_S * rate))
            true_speed = (worst[first] - worst[first - k]) * m.cmin_m / (k / rate)
            d_on.append((t.on_bearing_s - (time_s[last] - time_s[first])) * rate)  # samples
            d_speed.append((t.impact_speed_m_s / true_speed - 1) * 100)
    d_on, d_speed = np.array(d_on), np.array(d_speed)
    holds = float(np.abs(d_on).max()) <= 5.0 and float(np.abs(d_speed).max()) < 10.0
    return Row("rotor drop: time on the bearing and impact speed (`record --snapshot --trigger touchdown`, "
               "ISO 14839-5)", f"cone rig at {rpm:,.0f} rpm, amplifiers off {lasting_s:g} s",
               "5 samples on the bearing (2.5 at each end); 10 % impact speed",
               f"{d_on.mean():+.1f} samples, {d_speed.mean():+.1f} % speed",
               f"largest {np.abs(d_on).max():.1f} samples, {np.abs(d_speed).max():.1f} % speed", len(seeds),
               f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --profile cone --rpm {rpm:g} --drop {at_s:g}:{lasting_s:g} --truth --snapshot 0.4s "
               "--trigger touchdown --seed S", holds,
               "" if holds else f"largest {np.abs(d_on).max():.1f} samples (<= 5), {np.abs(d_speed).max():.1f} % (< 10)",
               {"on_samples": d_on, "speed_pct": d_speed})


def fir_fit(seeds: range, freqs=(5.0, 20.0, 40.0, 70.0, 100.0)) -> Row:
    """``fx fit``'s FIR (Kang & Jung eq. 19, its order at the knee) fitted to the compensator MFXLMS
    estimates at each campaign frequency, its response against the perfect W* = -B^-1 C there:
    what the controller runs, from what a campaign measures (the noise of the estimates through the
    fit). Stated: 2 % of the matrix (the estimates' 1 % and the fit's)."""
    from ambdaq.analysis.mfxlms import fit_fir, knee
    from ambdaq.sim.rigs.base_motion import BaseMotionRig

    f = np.asarray(freqs)
    B, _, wstar = BaseMotionRig().responses(f)
    fs = BaseMotionRig().params.sample_rate
    errs, taps_used = [], []
    for seed in seeds:
        est = np.array([_identified_w(seed, f_hz, B[i]) for i, f_hz in enumerate(f)])
        worst = 0.0
        for j in range(2):
            for m in range(2):
                orders = np.arange(0, 16)
                costs = np.array([fit_fir(f, est[:, j, m], o, fs)[1] for o in orders])
                k = knee(orders, costs, len(f))
                taps, _ = fit_fir(f, est[:, j, m], k, fs)
                response = np.exp(-2j * np.pi * np.outer(f / fs, np.arange(k + 1))) @ taps
                worst = max(worst, float((np.abs(response - wstar[:, j, m]) / np.linalg.norm(wstar, axis=(1, 2))).max()))
                taps_used.append(k + 1)
        errs.append(worst * 100)
    e = np.array(errs)
    holds = float(e.max()) < 2.0
    return Row("FIR compensator fitted to the MFXLMS estimates (`fx fit`, Kang & Jung)",
               f"base-motion rig, W estimated at {', '.join(f'{x:g}' for x in f)} Hz, the FIR's order at the knee "
               f"({min(taps_used)}-{max(taps_used)} taps)", "2 % of the matrix", "-",
               f"largest {e.max():.2f} % of the matrix, median {np.median(e):.2f} %", len(seeds),
               f"{seeds.start}-{seeds.stop - 1}", "ambdaq fx campaign; fx estimate; fx fit", holds,
               "" if holds else f"largest {e.max():.2f} % (< 2)", {"largest_pct": float(e.max())})


# --- ISO 14839-3 ---------------------------------------------------------------------------

def stability(rpm: float, axes: tuple[str, ...], seeds: range, seconds: float = 1.5) -> Row:
    """``iso stability``'s peak |Gs| and its frequency, per axis, against the rig's own linearised
    loop (2 um RMS white noise, ``seconds`` per axis)."""
    from ambdaq.drivers.excitation import ExcitationRequest
    from ambdaq.sim.rigs.spindle import SpindleRig
    from ambdaq.workflows.iso_stability import evaluate

    rig = SpindleRig()
    M, B, C = rig.loop_matrices(rpm)
    grid = np.arange(5.0, 5000.0, 1.0)
    gs = np.abs(model_sensitivity(M, B, C, rig.h, grid))
    d_db, d_hz = [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            for axis in axes:
                path = _record(Path(d) / f"g{seed}{axis}.mcap", seconds, seed=seed, speed=SpeedProfile(rpm, rpm),
                               excite=ExcitationRequest(axis, 2.0))
                (run,) = evaluate([load(path)])
                i = AXES.index(axis)
                d_db.append(run.grade.peak_db - db(gs[i].max()))
                d_hz.append(run.grade.peak_hz - grid[np.argmax(gs[i])])
    d_db, d_hz = np.array(d_db), np.array(d_hz)
    holds = float(np.abs(d_db).max()) < 0.5 and float(np.abs(d_hz).max()) <= 40.0
    return Row("ISO 14839-3 peak \\|Gs\\| and its frequency (`iso stability`)",
               f"{rpm:,.0f} rpm, {', '.join(axes)}, 2 µm RMS noise, {seconds:g} s per axis, 10 Hz grid",
               "0.5 dB; the frequency within 4 grid steps (40 Hz: the radial peaks fall 0.3-0.4 dB over them)",
               f"{d_db.mean():+.2f} dB, {d_hz.mean():+.1f} Hz",
               f"{d_db.std(ddof=1):.2f} dB, {d_hz.std(ddof=1):.1f} Hz; largest {np.abs(d_db).max():.2f} dB, "
               f"{np.abs(d_hz).max():.0f} Hz", len(d_db), f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --rpm {rpm:g} --excite AXIS:2 --duration {seconds:g} --seed S; iso stability", holds,
               "" if holds else f"largest {np.abs(d_db).max():.2f} dB (< 0.5), {np.abs(d_hz).max():.0f} Hz (<= 40)",
               {"largest_db": float(np.abs(d_db).max())})


# --- the plant of a flexible rotor (issue 42) ------------------------------------------------

def plant(rpm: float, seeds: range, seconds: float = 4.0, resolution_hz: float = 5.0) -> Row:
    """``plant identify`` (the joint input-output estimate from one white-noise run per axis) on the
    flexible rotor against the machine's own plant: the diagonal where the coherence is 0.9 or more,
    its scatter about the truth against the stated random error, per axis and pooled, and the share
    of those points within 5 % and 5 degrees of the truth (issue 42 asks it "wherever the coherence
    is at least 0.9": reported, not required of the row, as the random error at a coherence of 0.9
    is near 5 % by itself)."""
    from ambdaq.drivers.excitation import ExcitationRequest
    from ambdaq.machines.flexible_spindle import AXES as FLEX_AXES, FlexibleLoop
    from ambdaq.workflows.plant_identification import identify

    loop = FlexibleLoop()
    norm: dict[str, list[np.ndarray]] = {a: [] for a in FLEX_AXES}
    rel: list[np.ndarray] = []
    close: list[np.ndarray] = []  # per point: within 5 % in magnitude and 5 degrees in phase
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            runs = [load(_record(Path(d) / f"p{seed}{a}.mcap", seconds, seed=seed, speed=SpeedProfile(rpm, rpm),
                                 profile="flexible", excite=ExcitationRequest(a, 2.0))) for a in FLEX_AXES]
            m = identify(runs, resolution_hz)
            truth = loop.plant_response(rpm, m.freq_hz)
            for i, a in enumerate(m.axes):
                good = m.plant.coherence[:, i, i] >= 0.9
                p, t, sd = m.plant.response[good, i, i], truth[good, i, i], m.plant.sigma[good, i, i]
                norm[a].append(np.abs(p - t) / sd)
                rel.append(np.abs(p / t - 1))
                close.append((np.abs(np.abs(p / t) - 1) <= 0.05) & (np.abs(np.degrees(np.angle(p / t))) <= 5.0))
    per_axis = {a: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for a, v in norm.items()}
    pooled = float(np.sqrt(np.mean(np.concatenate([np.concatenate(v) for v in norm.values()]) ** 2)))
    rel_all = np.concatenate(rel) * 100
    holds = POOLED[0] <= pooled <= POOLED[1] and all(EACH[0] <= r <= EACH[1] for r in per_axis.values())
    return Row("closed-loop plant P(jω) (`plant identify`, joint input-output)",
               f"flexible rotor, {rpm:,.0f} rpm, 2 µm RMS noise per axis, {seconds:g} s runs, {resolution_hz:g} Hz, "
               "where the coherence is 0.9 or more",
               "its random error (first order, per point, the gap's and the output's errors correlated)",
               f"median {np.median(rel_all):.2f} % of \\|P\\|",
               f"{pooled:.2f} x stated pooled; per axis {', '.join(f'{r:.2f}' for r in per_axis.values())}; "
               + (f"within 5 % and 5° at {np.mean(np.concatenate(close)) * 100:.1f} % of the points (issue 42 asks "
                  "every point)" if not np.all(np.concatenate(close)) else "within 5 % and 5° at every point"),
               len(seeds), f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --profile flexible --rpm {rpm:g} --excite AXIS:2 --duration {seconds:g} --seed S; "
               f"plant identify --resolution {resolution_hz:g}", holds,
               "" if holds else f"scatter / stated {pooled:.2f} pooled (0.9-1.1), per axis "
                                f"{min(per_axis.values()):.2f}-{max(per_axis.values()):.2f} (0.7-1.4)",
               {"pooled": pooled, **per_axis})


def plant_model(seeds: range, seconds: float = 4.0, resolution_hz: float = 5.0, pointwise: bool = False,
                machine: str = "flexible") -> Row:
    """``plant fit`` (the modal model, its poles shared by every element) of the flexible rotor at
    standstill against the machine's own poles: each bending mode's frequency and damping and each
    rigid-body pole, their errors against the stated standard deviations; issue 42 asks the 95 %
    intervals to cover the truth in 90 % of runs. And the identified plant the model is, against the
    machine's, wherever the measurement's coherence is 0.9 or more (every fitted element): issue 42
    asks 5 % and 5 degrees at every such point; the runs where it held are counted, and required
    of the row where ``pointwise`` (the measurement docs/tuning.md sends users to)."""
    from ambdaq.drivers.excitation import ExcitationRequest
    from ambdaq.machines.flexible_spindle import AXES as FLEX_AXES, FlexibleLoop, flexible_machine
    from ambdaq.workflows.plant_fit import fit_measurement
    from ambdaq.workflows.plant_identification import identify

    params, _top = flexible_machine(machine)
    loop = FlexibleLoop(params)
    poles = loop.plant_poles(0.0)
    largest: list[tuple[float, float]] = []  # per run: the model's largest error at a trusted point, %, deg
    # each pole twice at standstill (the x and the y plane): one of each
    rigid = sorted({round(p.real / (2 * np.pi), 6) for p in poles if abs(p.imag) < 1e-6 and p.real > 0})
    bend = sorted({(round(abs(p) / (2 * np.pi), 6), round(-p.real / abs(p), 9)) for p in poles
                   if p.imag > 0 and -p.real / abs(p) < 0.1 and abs(p) / (2 * np.pi) < 4000})
    z: dict[str, list[float]] = {"frequency": [], "damping": [], "rigid": []}
    rel: dict[str, list[float]] = {"frequency": [], "damping": [], "rigid": []}
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            runs = [load(_record(Path(d) / f"m{seed}{a}.mcap", seconds, seed=seed, speed=SpeedProfile(0.0, 0.0),
                                 profile=machine, excite=ExcitationRequest(a, 2.0))) for a in FLEX_AXES]
            measured = identify(runs, resolution_hz)
            fitted = fit_measurement(measured, 1.0 / params.sample_rate)
            got = {n: (v, s) for n, v, s in zip(fitted.fit.names, fitted.fit.values, fitted.fit.std)}
            truth_p = loop.plant_response(0.0, measured.freq_hz)
            worst = (0.0, 0.0)
            for label in fitted.responses:
                out, _, inp = label.partition("<-")
                i, j = measured.axes.index(out), measured.axes.index(inp or out)
                good = measured.plant.coherence[:, i, j] >= 0.9
                ratio = (fitted.response(out, measured.freq_hz[good], inp or None)
                         / truth_p[good, FLEX_AXES.index(out), FLEX_AXES.index(inp or out)])
                worst = (max(worst[0], float(np.abs(np.abs(ratio) - 1).max()) * 100),
                         max(worst[1], float(np.degrees(np.abs(np.angle(ratio))).max())))
            largest.append(worst)
            for k, (hz, zeta) in enumerate(bend, 1):
                for what, name, truth in (("frequency", f"mode{k}_hz", hz), ("damping", f"mode{k}_zeta", zeta)):
                    value, std = got[name]
                    z[what].append((value - truth) / std)
                    rel[what].append(value / truth - 1)
            for k, hz in enumerate(rigid, 1):
                value, std = got[f"rigid{k}_hz"]
                z["rigid"].append((value - hz) / std)
                rel["rigid"].append(value / hz - 1)
    cover = {k: float(np.mean(np.abs(v) <= 1.96)) for k, v in z.items()}
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in z.items()}
    within = sum(pct <= 5.0 and deg <= 5.0 for pct, deg in largest)
    holds = all(c >= 0.9 for c in cover.values()) and (within == len(largest) or not pointwise)
    return Row("modal model of the plant (`plant fit`): bending modes, their damping, rigid-body poles; the "
               "plant it gives where the coherence is 0.9 or more",
               f"{machine} rotor, 0 rpm, 2 µm RMS noise per axis, {seconds:g} s runs, {resolution_hz:g} Hz",
               "1σ per parameter (its covariance; each bending mode's damping with the frequency step's floor, "
               "plant_fit.RESOLUTION_FLOOR)",
               "median " + ", ".join(f"{k} {np.median(v) * 100:+.2f} %" for k, v in rel.items()),
               "error / stated RMS " + ", ".join(f"{k} {rms[k]:.1f}" for k in z) + "; 95 % intervals cover "
               + ", ".join(f"{k} {cover[k] * 100:.0f} %" for k in z)
               + f"; the plant within 5 % and 5° at every trusted point in {within} of {len(largest)} runs (largest "
               f"{max(p for p, _ in largest):.1f} %, {max(d for _, d in largest):.1f}°"
               + ("; issue 42 asks every run)" if pointwise else "; not required here: measure 20 s at 2.5 Hz)"),
               len(seeds), f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --profile {machine} --rpm 0 --excite AXIS:2 --duration {seconds:g} --seed S; "
               f"plant identify --resolution {resolution_hz:g}; plant fit", holds,
               "" if holds else "95 % intervals cover " + ", ".join(f"{k} {cover[k] * 100:.0f} %" for k in z)
               + f" (at least 90 %); the plant within 5 % and 5° in {within} of {len(largest)} runs",
               {**{f"cover_{k}": v for k, v in cover.items()}, **{f"rms_{k}": v for k, v in rms.items()},
                "pointwise_runs": within / len(largest)})


def bearing_gains(seeds: range, seconds: float = 4.0, resolution_hz: float = 5.0,
                  machine: str = "flexible") -> Row:
    """``plant gains`` (each bearing's ki ka and kx, fitted with the rotor's model, and ka and ki
    apart from the coil currents) on the flexible rotors at standstill against the machine's own
    bearings and amplifiers: the errors against the stated deviations, and how often the 95 %
    intervals hold the truth (issue 42 asks 90 %)."""
    from ambdaq.drivers.excitation import ExcitationRequest
    from ambdaq.machines.flexible_spindle import AXES as FLEX_AXES, flexible_machine
    from ambdaq.workflows.bearing_gains import NAMES, SPLIT_NAMES, fit_bearing_gains, nominal
    from ambdaq.workflows.plant_identification import identify

    params, _top = flexible_machine(machine)
    z, rel = [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in seeds:
            runs = [load(_record(Path(d) / f"g{seed}{a}.mcap", seconds, seed=seed, speed=SpeedProfile(0.0, 0.0),
                                 profile=machine, excite=ExcitationRequest(a, 2.0))) for a in FLEX_AXES]
            got = fit_bearing_gains(identify(runs, resolution_hz), params, machine)
            values = np.concatenate([got.values, got.split])
            truth = np.concatenate([nominal(params), got.split_nominal])
            z.append((values - truth) / np.concatenate([got.std, got.split_std]))
            rel.append(values / truth - 1)
    z, rel = np.array(z), np.array(rel) * 100
    cover = float(np.mean(np.abs(z) <= 1.96))
    rms = np.sqrt(np.mean(z**2, axis=0))
    holds = cover >= 0.9 and float(np.abs(rel).max()) < 5.0
    return Row("bearings' actuator gain ki·ka, negative stiffness kx, amplifier gain ka and current gain ki "
               "(`plant gains`)",
               f"{machine} rotor, 0 rpm, 2 µm RMS noise per axis, {seconds:g} s runs, {resolution_hz:g} Hz",
               "1σ per parameter (the noise's, and 0.1 % of the value: bearing_gains.MODEL_FLOOR; ka's 0.01 %: "
               "amplifier.MODEL_FLOOR); issue 42 asks 5 %",
               "median " + ", ".join(f"{n} {np.median(rel[:, k]):+.2f} %" for k, n in enumerate(NAMES + SPLIT_NAMES)),
               "largest " + f"{np.abs(rel).max():.2f} %; error / stated RMS "
               + ", ".join(f"{r:.1f}" for r in rms) + f"; 95 % intervals cover {cover * 100:.0f} %",
               len(seeds), f"{seeds.start}-{seeds.stop - 1}",
               f"sim generate --profile {machine} --rpm 0 --excite AXIS:2 --duration {seconds:g} --seed S; "
               f"plant identify --resolution {resolution_hz:g}; plant gains --machine {machine}", holds,
               "" if holds else f"95 % intervals cover {cover * 100:.0f} % (at least 90 %), largest error "
                                f"{np.abs(rel).max():.2f} % (below 5 %)",
               {"cover": cover, "largest_pct": float(np.abs(rel).max())})


# --- balancing -------------------------------------------------------------------------------

@dataclass(frozen=True)
class _BalancingRig:
    """A simulated rig balancing jobs run on: its balancing planes, their holes' radius (m), the
    random mass added per plane (g, uniform), and whether its sensors have runout (a slow roll per
    job) or none (``--no-runout``: the cone rig's, which Jeong et al. model without)."""

    planes: tuple[str, ...]
    radius_m: float
    added_g: tuple[float, float]
    runout: bool


BALANCING_RIGS = {
    # beside the rotor's own unbalance (2 and 3 g mm): a total of 0.01-0.4 g per plane at 30 mm
    "spindle": _BalancingRig(("front", "rear"), 0.03, (0.02, 0.3), True),
    # the only unbalance (the rig has none of its own): 2-30 g mm, G 0.7-11 mm/s at 6,000 rpm
    "cone": _BalancingRig(("upper", "lower"), 0.025, (0.08, 1.2), False),
}


MASS_TOLERANCE = {"spindle": MassTolerance(0.002, 1.0), "cone": MassTolerance(0.005, 1.0)}
"""How far each correction mass is off when a job puts it on (g, degrees; uniform within), and what
the grade predicted after the correction is told: its errors (ISO 21940-14's sources in the masses).
A 2 mg scale error and a degree on the spindle's 0.01-0.4 g masses; 5 mg on the cone's 0.1-1.2 g."""


@dataclass
class _BalancingJob:
    """One balancing job on a simulated rig (:data:`BALANCING_RIGS`), a campaign's case: a random
    mass per plane at any angle beside the rotor's own unbalance, and its runs, each with its own
    noise (seed 10 case + k), in the folder ``d``."""

    d: Path
    case: int
    added: list
    profile: str = "spindle"

    @classmethod
    def new(cls, tmp: str, case: int, profile: str = "spindle") -> "_BalancingJob":
        from ambdaq.machines.balance_masses import BalanceMass

        d = Path(tmp) / str(case)
        d.mkdir()
        rng, rig = np.random.default_rng(case), BALANCING_RIGS[profile]
        return cls(d, case, [BalanceMass(p, float(rng.uniform(*rig.added_g)), float(rng.uniform(0.0, 360.0)), rig.radius_m)
                             for p in rig.planes], profile)

    def run(self, name: str, k: int, speed: SpeedProfile, seconds: float, masses=(), ff: str = "off") -> Path:
        source = SimSource(self.profile, seed=10 * self.case + k, speed=speed, truth=True)
        source.rig.add_masses([*self.added, *masses])
        if ff != "off":
            source.rig.set_feedforward(ff)
        return _write(source, self.d / f"{name}.mcap", seconds)

    def placed(self, masses: list) -> list:
        """``masses`` as a workshop puts them on: each one's weight and angle off by up to the rig's
        MASS_TOLERANCE (uniform, seeded by the case), what ``balance`` is told with
        --mass-tolerance and --angle-tolerance."""
        from ambdaq.machines.balance_masses import BalanceMass

        rng, tol = np.random.default_rng(1000 + self.case), MASS_TOLERANCE[self.profile]
        return [BalanceMass(m.plane, m.grams + tol.grams * rng.uniform(-1, 1), m.deg + tol.deg * rng.uniform(-1, 1),
                            m.radius_m) for m in masses]

    def coefficients(self, slow_s: float) -> Path | None:
        """The job's runout: its own slow roll (run 0), identified as docs/balancing.md does; None
        on a rig whose sensors have none (--no-runout)."""
        from ambdaq.workflows.runout import identify_recordings

        if not BALANCING_RIGS[self.profile].runout:
            return None
        slow = self.run("slow", 0, SpeedProfile(SLOW_ROLL_RPM, SLOW_ROLL_RPM), slow_s)
        return identify_recordings([load(slow)], [1, 2, 3, 4, 5, 6], "fit").coef.save(self.d / "coef.json")

    def truth(self, path: Path) -> tuple[np.ndarray, float]:
        """The simulator's unbalance per plane in a recording of this job (kg m phasors) and its
        rotor's mass (kg)."""
        rec = load(path, topics=["/amb/rotor"])
        cal = rec.metadata["ambdaq.calibration.rig"]
        return np.array([float(cal[f"truth.unbalance.{p}_kg_m"]) * np.exp(1j * np.radians(float(cal[f"truth.unbalance.{p}_deg"])))
                         for p in BALANCING_RIGS[self.profile].planes]), float(rec.machine.rotor_mass_kg)

    def commands(self, rpm: float, seconds: float, ff: str, slow_s: float, trial_g: float | None) -> str:
        """The commands that regenerate its runs, up to the balancing command (with ``trial_g``, g,
        the trial runs')."""
        trial = "" if trial_g is None else f"[--trial PLANE:{trial_g:g}@0] "
        if not BALANCING_RIGS[self.profile].runout:
            return (f"sim generate --profile {self.profile} --rpm {rpm:g} --duration {seconds:g} {trial}"
                    "(a random mass per plane: seed S)")
        return (f"sim generate --rpm slowroll --duration {slow_s:g}; runout identify; sim generate --rpm {rpm:g} "
                f"--duration {seconds:g} --ff {ff} {trial}(a random mass per plane: seed S)")

    def setting(self, seconds: float, slow_s: float) -> str:
        """The job's runs and unbalance, in words (docs/validation.md's operating point)."""
        rig = BALANCING_RIGS[self.profile]
        if not rig.runout:
            return (f"{seconds:g} s runs, no sensor runout (--no-runout); unbalance {rig.added_g[0] * rig.radius_m * 1e3:g}-"
                    f"{rig.added_g[1] * rig.radius_m * 1e3:g} g mm per plane at any angle")
        return f"{seconds:g} s runs, a {slow_s:g} s slow roll per job; unbalance 0.01-0.4 g per plane at any angle"


def _prediction_check(predicted: list[tuple[float, dict]], profile: str) -> tuple[float, str]:
    """How often the simulator's grade after a correction (the masses on as :meth:`_BalancingJob.
    placed` put them) stayed within the bound predicted before it (``predicted_after``, told the
    rig's MASS_TOLERANCE), and the row's words for it. A 95 % bound over 100 jobs is held to 90 %:
    2.3 binomial deviations below 95 %."""
    true = np.array([t for t, _ in predicted])
    bound = np.array([p["at_most_mm_s"] for _, p in predicted])
    median = np.array([p["grade_mm_s"] for _, p in predicted])
    held = float(np.mean(true <= bound))
    tol = MASS_TOLERANCE[profile]
    return held, (f"grade after within the 95 % bound predicted before it (the masses put on within "
                  f"{tol.grams * 1e3:g} mg and {tol.deg:g}°, --mass-tolerance/--angle-tolerance) in {held * 100:.0f} %, "
                  f"true / predicted median {np.median(true / median):.2f}")


def balancing(cases: range, rpm: float = 20000.0, seconds: float = 1.0, slow_s: float = 4.0,
              max_rpm: float = 60000.0, trial_g: float = 0.1, ff: str = "off", also_rpm: float | None = None,
              profile: str = "spindle", signal: str = "gaps") -> Row:
    """``balance influence`` on the spindle as docs/balancing.md does it, one job per case: its own
    slow roll (the runout), a reference run and a 0.1 g trial run per plane, each with its own noise;
    the rotor's unbalance its own plus a random mass per plane (0.02-0.3 g at any angle on the 30 mm
    radius: a total of 0.01-0.4 g per plane); or on the cone rig (``profile``), no slow roll
    (:data:`BALANCING_RIGS`). Against the simulator's truth: the unbalance one
    correction leaves (issue 43: at most 10 % in 95 % of cases), the correction within 10 % and 10
    degrees of the one that cancels the whole unbalance, the stated 95 % intervals of the unbalance
    (circular, 2.45 deviations) holding it (at least 90 %), and the ISO 21940-11 grade before.
    With the controller's feedforward ``ff`` (``off``, or ``lms`` adapting from each run's start);
    with ``also_rpm``, the same runs at that speed too, one least squares over both; with
    ``signal`` "forces", influence coefficients of the bearings' forces instead of the gaps'.
    The default suite's version is tests/test_balancing.py (one job, the same checks)."""
    from ambdaq.machines.balance_masses import BalanceMass
    from ambdaq.workflows.balancing import balance_grade, correct_with, influence_balancing, run_vector, save_influence

    rig = BALANCING_RIGS[profile]
    trials = [BalanceMass(p, trial_g, 0.0, rig.radius_m) for p in rig.planes]
    left, mag_err, ang_err, z, grade_z, after_z, predicted = [], [], [], [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            job = _BalancingJob.new(tmp, case, profile)
            coef = job.coefficients(slow_s)
            speeds = [rpm] if also_rpm is None else [rpm, also_rpm]
            groups = []
            for j, at in enumerate(speeds):  # each speed's runs with their own noise (seeds 10 case + 1-3, + 5-7)
                steady, k0 = SpeedProfile(at, at), 1 + 4 * j
                ref = job.run(f"ref{j}", k0, steady, seconds, ff=ff)
                groups.append((run_vector(ref, coef, profile, signal), [
                    (m, run_vector(job.run(f"t{j}{k}", k0 + 1 + k, steady, seconds, [m], ff=ff), coef, profile, signal))
                    for k, m in enumerate(trials)]))
            ref = job.d / "ref0.mcap"
            result = influence_balancing(groups, max_rpm=max_rpm)
            result.tolerance = MASS_TOLERANCE[profile]
            truth, mass = job.truth(ref)
            left.append(np.abs(truth + result.correction) / np.abs(truth))  # the correction adds its vector
            mag_err.append(np.abs(result.correction) / np.abs(truth) - 1)
            ang_err.append(np.degrees(np.angle(-result.correction / truth)))
            z.append(np.abs(-result.correction - truth) / result.correction_std)
            true_grade = balance_grade(float(np.abs(truth).sum()), mass, max_rpm)
            grade_z.append((result.grade_mm_s - true_grade) / result.grade_std_mm_s)
            # the grade after, measured: the correction masses on, a new run at each speed (seeds 10
            # case + 4, + 8), balance correct with the job's saved coefficients, against the truth
            files = [job.d / f"ref{j}.mcap" for j in range(len(speeds))] + [
                job.d / f"t{j}{k}.mcap" for j in range(len(speeds)) for k in range(len(trials))]
            saved = save_influence(result, job.d / "influence.json", files, coef)
            on = job.placed(result.masses())
            fixed = [job.run(f"fixed{j}", 4 + 4 * j, SpeedProfile(at, at), seconds, on, ff=ff)
                     for j, at in enumerate(speeds)]
            after = correct_with(saved, [run_vector(f, coef, profile, signal) for f in fixed], max_rpm=max_rpm,
                                 coefficients=coef)
            left_truth, _mass = job.truth(fixed[0])
            true_after = balance_grade(float(np.abs(left_truth).sum()), mass, max_rpm)
            after_z.append((after.grade_mm_s - true_after) / after.grade_std_mm_s)
            predicted.append((true_after, result.predicted_after))
    left, mag_err, ang_err, z = (np.array(v) for v in (left, mag_err, ang_err, z))
    grade_z, after_z = np.array(grade_z), np.array(after_z)
    after_cover = float(np.mean(np.abs(after_z) <= 1.96))
    one_step = float(np.mean(left.max(axis=1) <= 0.10))
    within = float(np.mean((np.abs(mag_err) < 0.10) & (np.abs(ang_err) < 10.0)))
    cover = float(np.mean(z <= 2.45))
    grade_cover = float(np.mean(np.abs(grade_z) <= 1.96))
    bound, prediction = _prediction_check(predicted, profile)
    # issue 43's goals for one step hold the gaps' coefficients to them; the forces' (item 2's
    # parenthesis) to what they state, their one step reported (FORCE_RUNOUT_MODEL)
    holds = ((one_step >= 0.95 and within >= 0.95 if signal == "gaps" else True) and cover >= 0.90
             and after_cover >= 0.90 and bound >= 0.90)
    return Row("correction masses and unbalance per plane (`balance influence`"
               + (", influence coefficients of the bearing forces" if signal == "forces" else "")
               + "), ISO 21940-11 grade before and after",
               f"{profile} at {' and '.join(f'{r:,.0f}' for r in speeds)} rpm{' (one least squares)' if also_rpm else ''}, "
               f"feedforward {ff}, {trial_g:g} g trial masses, " + job.setting(seconds, slow_s),
               "1σ per part of each plane's unbalance (the runs' noise, "
               + (("0.5 % of the force that follows the runout-driven 1X, FORCE_RUNOUT_MODEL, " if signal == "forces"
                   else "0.2 % of the runout-driven 1X, RUNOUT_MODEL, ") if rig.runout else "")
               + "and 0.5 % of the correction, LINEARITY); issue 43: one step leaves ≤ 10 % in 95 % of cases",
               f"magnitude median {np.median(mag_err) * 100:+.2f} %, angle median {np.median(ang_err):+.2f}°",
               f"left after one step: median {np.median(left) * 100:.1f} %, largest {left.max() * 100:.1f} %; "
               f"≤ 10 % in {one_step * 100:.0f} % of cases; within 10 % and 10° in {within * 100:.0f} %; "
               f"95 % intervals cover {cover * 100:.0f} % (error / stated RMS {np.sqrt(np.mean(z ** 2) / 2):.2f}); "
               f"grade within its 95 % interval in {grade_cover * 100:.0f} % before, in {after_cover * 100:.0f} % "
               "after (measured: the correction on, a new run, balance correct); " + prediction,
               len(cases), f"{cases.start}-{cases.stop - 1}",
               job.commands(rpm, seconds, ff, slow_s, trial_g) + "; balance influence "
               + ("" if rig.runout else f"--machine {profile} --no-runout ") + f"--max-rpm {max_rpm:g}"
               + (" --signal forces" if signal == "forces" else ""), holds,
               "" if holds else f"one step ≤ 10 % in {one_step * 100:.0f} % (95 %), within 10 %/10° in "
                                f"{within * 100:.0f} % (95 %), intervals cover {cover * 100:.0f} % (90 %), the grade "
                                f"after within its interval in {after_cover * 100:.0f} % (90 %), within its predicted "
                                f"bound in {bound * 100:.0f} % (90 %)",
               {"one_step": one_step, "within": within, "cover": cover, "grade_cover": grade_cover,
                "after_cover": after_cover, "predicted_bound": bound})


def force_balancing(cases: range, rpm: float = 20000.0, ff: str = "off", seconds: float = 1.0,
                    slow_s: float = 4.0, profile: str = "spindle", max_rpm: float = 60000.0) -> Row:
    """``balance forces`` (no trial run) on the spindle or the cone rig (``profile``), one job per
    case as :func:`balancing`'s (its own slow roll where the rig has runout, its noise, a random
    mass per plane), with the controller's feedforward ``ff`` (``off`` or ``lms``): the unbalance
    per plane against the simulator's, its stated 95 % intervals, and what one correction by it
    leaves; then the correction put on, a new run (seed 10 case + 2) and ``balance forces --before``
    the first estimate again (on a rig with runout; without, no slow roll's part to give back): its ISO 21940-11 grade at ``max_rpm`` against the truth's (reported,
    not required of the row)."""
    from ambdaq.workflows.balancing import balance_grade, force_balancing as estimate, plane_masses

    left, rel, z, after_z, predicted = [], [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            job = _BalancingJob.new(tmp, case, profile)
            coef = job.coefficients(slow_s)
            steady = SpeedProfile(rpm, rpm)
            got = estimate(job.run("run", 1, steady, seconds, ff=ff), coef, profile, max_rpm=max_rpm)
            got.tolerance = MASS_TOLERANCE[profile]
            truth, mass = job.truth(job.d / "run.mcap")
            left.append(np.abs(truth - got.unbalance) / np.abs(truth))
            rel.append(got.unbalance / truth - 1)
            z.append(np.abs(got.unbalance - truth) / got.std)
            fix = plane_masses(got.planes, got.correction, got.radius_m, 0)
            after = estimate(job.run("fixed", 2, steady, seconds, job.placed(fix), ff=ff), coef, profile,
                             max_rpm=max_rpm, before=None if coef is None else dict(zip(got.planes, got.unbalance)))
            left_truth, _mass = job.truth(job.d / "fixed.mcap")
            true_after = balance_grade(float(np.abs(left_truth).sum()), mass, max_rpm)
            after_z.append((after.grade_mm_s - true_after) / after.grade_std_mm_s)
            predicted.append((true_after, got.predicted_after))
    left, rel, z = np.array(left), np.array(rel), np.array(z)
    after_cover = float(np.mean(np.abs(np.array(after_z)) <= 1.96))
    one_step = float(np.mean(left.max(axis=1) <= 0.10))
    within = float(np.mean((np.abs(np.abs(rel + 1) - 1) < 0.10) & (np.abs(np.degrees(np.angle(rel + 1))) < 10.0)))
    cover = float(np.mean(z <= 2.45))
    ratio = float(np.sqrt(np.mean(z**2) / 2))
    bound, prediction = _prediction_check(predicted, profile)
    # what it states; the 95 % one-step goal is reported
    holds = cover >= 0.90 and 0.7 <= ratio <= 1.4 and bound >= 0.90
    return Row("unbalance per plane from the bearing forces, no trial run (`balance forces`)",
               f"{profile} at {rpm:,.0f} rpm, feedforward {ff}, " + job.setting(seconds, slow_s),
               "1σ per part (the windows' scatter, and FORCE_MODEL of the bearing's 1X force); issue 43: one step "
               "leaves ≤ 10 % in 95 % of cases",
               f"magnitude median {np.median(np.abs(rel + 1) - 1) * 100:+.2f} %, angle median "
               f"{np.median(np.degrees(np.angle(rel + 1))):+.2f}°",
               f"left after one step: median {np.median(left) * 100:.1f} %, largest {left.max() * 100:.1f} %; "
               f"≤ 10 % in {one_step * 100:.0f} % of cases; within 10 % and 10° in {within * 100:.0f} %; "
               f"95 % intervals cover {cover * 100:.0f} % (error / stated RMS {np.sqrt(np.mean(z ** 2) / 2):.2f}); "
               f"grade after (the correction on, a new run, balance forces --before again) within its 95 % "
               f"interval in {after_cover * 100:.0f} %; " + prediction,
               len(cases), f"{cases.start}-{cases.stop - 1}",
               job.commands(rpm, seconds, ff, slow_s, None) + "; balance forces"
               + ("" if BALANCING_RIGS[profile].runout else f" --machine {profile} --no-runout"), holds,
               "" if holds else f"intervals cover {cover * 100:.0f} % (at least 90 %), error / stated {ratio:.2f} "
                                f"(0.7-1.4), the grade after within its predicted bound in {bound * 100:.0f} % (90 %)",
               {"one_step": one_step, "within": within, "cover": cover, "ratio": ratio, "after_cover": after_cover,
                "predicted_bound": bound})


# --- the campaign --------------------------------------------------------------------------

SMALL: list[Callable[[], Row]] = [
    lambda: runout(1.0, SLOW_ROLL_RPM, range(1, 9)),
    lambda: runout(0.3, 30000.0, range(1, 9), harmonics=(2, 3, 4), skip_s=0.05),
    lambda: centreline(2.0, 20000.0, range(1, 2)),
    lambda: stability(12000.0, ("front_x",), range(1, 3)),
    lambda: one_x(3.0, 30000.0, range(1, 2)),
    lambda: critical_speed(range(1, 2)),
    lambda: apht_one_x(3100.0, range(1, 2), ff="off"),
    lambda: orbit_maxima(3.0, 30000.0, range(1, 2)),
    lambda: self_sensing(300.0, range(1, 2)),
    lambda: modal("x:50", range(1, 2)),
    lambda: drop(600.0, 0.1, range(1, 2)),
    lambda: mfxlms_compensator(100.0, range(1, 2)),
    lambda: fir_fit(range(1, 2)),
]
FULL: list[Callable[[], Row]] = [
    lambda: runout(1.0, SLOW_ROLL_RPM, range(1, 31), unbalance=False),
    lambda: runout(4.0, SLOW_ROLL_RPM, range(1, 31), unbalance=False),
    lambda: runout(10.0, SLOW_ROLL_RPM, range(1, 21), unbalance=False),
    lambda: runout(4.0, SLOW_ROLL_RPM, range(31, 61)),
    lambda: runout(0.3, 30000.0, range(1, 31), harmonics=(2, 3, 4, 5, 6), skip_s=0.05),
    lambda: runout(0.3, 30000.0, range(1, 31), unbalance=False, skip_s=0.05),
    lambda: centreline(3.0, 20000.0, range(1, 6)),
    lambda: centreline(3.0, 30000.0, range(1, 6)),
    lambda: one_x(3.0, 30000.0, range(1, 6)),
    lambda: one_x(10.0, 50000.0, range(1, 4)),
    lambda: critical_speed(range(1, 6)),
    lambda: apht_one_x(30000.0, range(1, 6)),
    lambda: apht_one_x(3100.0, range(1, 6), ff="off"),
    lambda: orbit_maxima(3.0, 30000.0, range(1, 6)),
    lambda: self_sensing(100.0, range(1, 6)),
    lambda: self_sensing(1000.0, range(1, 6)),
    lambda: modal("x:50", range(1, 7)),
    lambda: modal("y1:50:0.25", range(1, 7)),
    lambda: drop(600.0, 0.1, range(1, 6)),
    lambda: drop(1200.0, 0.3, range(11, 16)),
    lambda: mfxlms_compensator(5.0, range(1, 6)),
    lambda: mfxlms_compensator(40.0, range(1, 6)),
    lambda: mfxlms_compensator(100.0, range(1, 13)),
    lambda: fir_fit(range(1, 6)),
    lambda: stability(0.0, AXES, range(1, 5)),
    lambda: stability(12000.0, AXES, range(1, 5)),
    lambda: stability(30000.0, AXES, range(1, 5)),
    lambda: plant(0.0, range(1, 9)),
    lambda: plant(20000.0, range(1, 9)),
    lambda: plant(0.0, range(1, 5), seconds=10.0, resolution_hz=2.5),  # where docs/tuning.md sends users
    lambda: plant_model(range(1, 17)),
    lambda: plant_model(range(1, 9), seconds=10.0, resolution_hz=2.5),  # where docs/tuning.md sends a design
    # where docs/tuning.md sends users who need the plant within 5 % and 5 degrees at every trusted point
    lambda: plant_model(range(1, 9), seconds=20.0, resolution_hz=2.5, pointwise=True),
    lambda: plant_model(range(1, 7), seconds=20.0, resolution_hz=2.5, pointwise=True, machine="flexible-long"),
    lambda: bearing_gains(range(1, 13)),
    lambda: bearing_gains(range(1, 9), seconds=10.0, resolution_hz=2.5),
    lambda: bearing_gains(range(1, 9), seconds=10.0, resolution_hz=2.5, machine="flexible-long"),
    lambda: balancing(range(1, 101)),
    lambda: balancing(range(101, 151), rpm=30000.0),
    lambda: balancing(range(151, 251), ff="lms", seconds=3.0),
    lambda: balancing(range(251, 301), also_rpm=30000.0),
    lambda: balancing(range(1, 101), signal="forces"),
    lambda: balancing(range(151, 251), ff="lms", seconds=3.0, signal="forces"),
    lambda: force_balancing(range(1, 101)),
    lambda: force_balancing(range(1, 101), ff="lms"),
    lambda: balancing(range(1, 101), rpm=6000.0, max_rpm=6000.0, trial_g=0.5, profile="cone"),
    lambda: balancing(range(1, 101), rpm=6000.0, max_rpm=6000.0, trial_g=0.5, profile="cone", signal="forces"),
    lambda: force_balancing(range(1, 101), rpm=6000.0, profile="cone", max_rpm=6000.0),
]


def table(rows: list[Row]) -> str:
    """The rows as docs/validation.md's Markdown table."""
    head = ("| estimator | operating point | stated accuracy | bias | scatter | runs | seeds | holds | regenerate |\n"
            "|---|---|---|---|---|---|---|---|---|\n")
    return head + "".join(
        f"| {r.estimator} | {r.point} | {r.stated} | {r.bias} | {r.scatter} | {r.runs} | {r.seeds} | "
        f"{'yes' if r.holds else '**no**: ' + r.why} | `{r.command}` |\n" for r in rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="the default suite's version, printed only")
    ap.add_argument("--doc", type=Path, default=Path(__file__).resolve().parents[2] / "docs" / "validation.md")
    ap.add_argument("--rows", help="re-run only these rows of the full campaign (1-based, comma-separated: "
                                   "what a change touched) and put them in place in --doc's table; its stamp says so")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    chosen = [int(k) for k in args.rows.split(",")] if args.rows else []
    if any(not 1 <= k <= len(FULL) for k in chosen):
        ap.error(f"--rows are 1 to {len(FULL)}")
    rows = []
    for make in [FULL[k - 1] for k in chosen] if chosen else SMALL if args.small else FULL:
        rows.append(make())
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    took = time.monotonic() - t0
    if chosen:
        _replace_rows(args.doc, dict(zip(chosen, table(rows).splitlines()[2:])), took)
    elif not args.small:
        text = args.doc.read_text()
        begin, end = "<!-- campaign table: tests/validation/campaign.py -->", "<!-- end of the campaign table -->"
        stamp = (f"Last run {datetime.date.today().isoformat()} on this project's 2-core machine, "
                 f"{took / 60:.0f} min, ambdaq at `{_head()}`.\n\n")
        before, rest = text.split(begin)
        _, after = rest.split(end)
        args.doc.write_text(before + begin + "\n" + stamp + table(rows) + end + after)
    return 0 if all(r.holds for r in rows) else 1


def _replace_rows(doc: Path, lines: dict[int, str], took: float) -> None:
    """Put the re-run rows ``lines`` (1-based row -> Markdown line) in place in ``doc``'s campaign
    table, a stamp beside the whole run's saying which rows were re-run, when and at which commit."""
    text = doc.read_text()
    begin, end = "<!-- campaign table: tests/validation/campaign.py -->", "<!-- end of the campaign table -->"
    before, rest = text.split(begin)
    inside, after = rest.split(end)
    kept = inside.strip("\n").split("\n")  # a stamp of rows re-run before stays: they were run then
    start = next(k for k, line in enumerate(kept) if line.startswith("|---")) + 1
    if len(kept) - start != len(FULL):
        raise SystemExit(f"{doc}: its table has {len(kept) - start} rows, the campaign {len(FULL)}: run it whole")
    for k, line in lines.items():
        kept[start + k - 1] = line
    stamp = (f"Rows {', '.join(str(k) for k in sorted(lines))} re-run {datetime.date.today().isoformat()}, "
             f"{took / 60:.0f} min, ambdaq at `{_head()}`.")
    head = [line for line in kept[:start - 2] if line.strip()]
    doc.write_text(before + begin + "\n" + "\n\n".join(head + [stamp]) + "\n\n" + "\n".join(kept[start - 2:]) + "\n"
                   + end + after)


def _head() -> str:
    import subprocess

    where = Path(__file__).resolve().parent
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=where)
    changed = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", "src", "tests"],
                             capture_output=True, text=True, cwd=where).stdout.strip()
    return (out.stdout.strip() or "unknown") + (" with uncommitted changes to src/ or tests/" if changed else "")


if __name__ == "__main__":
    sys.exit(main())
