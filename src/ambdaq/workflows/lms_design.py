"""Ro et al.'s LMS feedforward designed for a plant (``ambdaq lms``): the per-axis phase
compensation from the design loops or a measured frequency response, and a coefficient file
whose step-size schedule converges on the plant's map (docs/lms.md)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..analysis.lms import (DesignModels, PhaseTable, StateSpaceLoop, convergence_radius, measured_phase_compensation,
                            mu_sign, phase_compensation, sign_changes, sign_schedule)
from ..documents.coefficients import Coefficients, file_sha256, now_iso
from ..documents.frequency_response import FrequencyResponse
from ..errors import BadInputError
from ..machines.models import design_models
from .plants import DESIGN_MACHINE, analysing, resolve_plant


def grid_step(loops: dict, fine: float) -> float:
    """A state-space loop is linearised per speed: a coarser grid keeps it to seconds."""
    return 100.0 if any(isinstance(lp, StateSpaceLoop) for lp, _ in loops.values()) else fine


def phase_table(loops: dict, models: DesignModels) -> PhaseTable:
    """Per-axis phase compensation from the design loops, a row per controller axis (``models.axes``):
    each loop fills the axes it stands for (a plant of one loop fills every axis; a one-axis
    loop's row is shared by its axes)."""
    axes = models.axes
    table = np.zeros((len(axes), models.phase_bins))
    for loop, names in loops.values():
        ph = phase_compensation(loop, models.phase_bins, models.phase_bin_hz).phase_rad
        rows = list(range(len(axes))) if len(loops) == 1 else [axes.index(a) for a in names]
        table[rows] = ph if ph.shape[0] == len(rows) else ph[0]
    return PhaseTable(table, models.phase_bin_hz, axes)


def measured_phase_table(path: str, axes: tuple[str, ...], models: DesignModels) -> PhaseTable:
    """Per-axis phase compensation from a measured T_aa (each of ``axes`` must have been excited)."""
    frf = FrequencyResponse.load(path)
    pairs = [frf.response(a, a) for a in axes]
    try:
        table = measured_phase_compensation(frf.freq_hz, np.array([h for h, _ in pairs]),
                                            np.array([c for _, c in pairs]), bins=models.phase_bins,
                                            bin_hz=models.phase_bin_hz)
    except ValueError as err:
        raise BadInputError(f"{path}: {err}") from None
    return PhaseTable(table.phase_rad, table.bin_hz, tuple(axes))


def schedule(plant: str, *, mu: float, dead_band: float, harmonics: int, compensated: bool = False,
             frf_file: str | Path | None = None, weights_file: str | Path | None = None,
             rpm_max: float = 60000.0) -> Coefficients:
    """A coefficient file whose LMS step-size schedule converges on ``plant``'s map.

    Parameters
    ----------
    plant : str
        The loop designed on (:func:`~.plants.plant_names`).
    mu : float
        Step size (its magnitude; the schedule gives its sign per speed range).
    dead_band : float
        Speed around a sign change left without adaptation, in rpm.
    harmonics : int
        Schedule 1X .. NX.
    compensated : bool
        The phase-compensated update (one row per harmonic over the whole range) instead of Ro
        et al.'s sign-switched one; implied by ``frf_file``.
    frf_file : str or Path, optional
        A measured frequency response whose phase compensates the update.
    weights_file : str or Path, optional
        A coefficient file whose weights (and target) the schedule goes with.
    rpm_max : float
        Top of the schedule, in rpm.
    """
    models = design_models(DESIGN_MACHINE)
    base = Coefficients.load(weights_file) if weights_file else None
    axes = tuple(base.target["axes"]) if base is not None else models.axes  # the controller the file goes to
    if plant not in models.plants:  # a plant the user gives (tf:, ss:) stands for the file's axes
        models = replace(models, axes=axes)
    loops = resolve_plant(plant, models)
    step = grid_step(loops, 10.0)
    compensated = compensated or frf_file is not None
    if compensated:
        with analysing(plant):
            phase = measured_phase_table(frf_file, axes, models) if frf_file else phase_table(loops, models)
        missing = [a for a in axes if a not in phase.axes]
        if missing:
            raise BadInputError(f"the plant {plant!r} has no loop for axis {missing[0]} of the coefficient file: "
                                "give --frf with every axis excited, or a plant of those axes")
        phase = phase.select(axes)
        rows = [[k, 0.0, rpm_max, mu] for k in range(1, harmonics + 1)]
        phase_doc = {"bin_hz": phase.bin_hz,
                     "phase_rad": {a: [round(float(v), 6) for v in phase.phase_rad[i]] for i, a in enumerate(axes)}}
    else:
        phase_doc = {}
        with analysing(plant):
            rows = [[k, *r] for k in range(1, harmonics + 1)
                    for r in sign_schedule([lp for lp, _ in loops.values()], mu=mu, dead_band=dead_band,
                                           rpm_max=rpm_max, harmonic=k, step=step)]
        rows = [r for r in rows if r[3] != 0.0]  # a harmonic not named in a speed range is held
    if base is not None:
        target, source, harm, weights = base.target, dict(base.source), base.harmonics, base.weights
    else:
        target, source, harm = {"axes": list(axes)}, {}, list(range(1, harmonics + 1))
        weights = {a: [[0.0, 0.0] for _ in harm] for a in axes}
    design = {"plant": plant, "mu": mu, "dead_band_rpm": dead_band, "compensated": compensated}
    if frf_file:
        design["phase_from"] = {"path": str(frf_file), "sha256": file_sha256(frf_file)}
    source.update({"lms_design": design,
                   "created": now_iso()})
    return Coefficients(target, source, harm, weights, rows, phase_doc, lms_plant=plant)


@dataclass
class ConvergenceMap:
    """What :func:`convergence_map` found (``ambdaq lms map``).

    Attributes
    ----------
    report : dict
        Per loop: the speeds where the sign of mu must flip, where no sign converges, the sign at
        a dozen speeds (what ``--json`` prints).
    rpm, mu : ndarray
        The map's speeds (rpm) and step sizes.
    radius : dict of str to ndarray
        Per loop, the spectral radius over (speed, mu), where asked for (the figure).
    """

    report: dict
    rpm: np.ndarray
    mu: np.ndarray
    radius: dict[str, np.ndarray]


def convergence_map(plant: str, *, harmonic: int, rpm_max: float, mu_max: float, compensated: bool = False,
                    radius: bool = False) -> ConvergenceMap:
    """Where Ro et al.'s LMS converges on ``plant``'s loops over speed and step size, and where the
    sign of mu must flip (Ro et al. Fig. 5).

    Parameters
    ----------
    plant : str
        The loop (:func:`~.plants.plant_names`).
    harmonic : int
        Order k.
    rpm_max : float
        Top of the map, rpm.
    mu_max : float
        The map spans -mu_max .. +mu_max; the signs are judged at mu_max / 10.
    compensated : bool
        The phase-compensated update instead of Ro et al.'s.
    radius : bool
        Also the whole map of spectral radii (for the figure; the signs alone need far less).
    """
    models = design_models(DESIGN_MACHINE)
    loops = resolve_plant(plant, models)
    with analysing(plant):  # the loops' numbers may overflow: one line, not an internal error
        phase = phase_table(loops, models) if compensated else None
        step = grid_step(loops, 50.0)
        rpm = np.arange(step, rpm_max + step / 2, step)
        mu = np.linspace(-mu_max, mu_max, 41)
        report = {"plant": plant, "harmonic": harmonic, "compensated": compensated, "loops": {}}
        maps = {}
        every = max(1, len(rpm) // 12)
        for name, (loop, axes) in loops.items():
            ph = None if phase is None else phase.select(axes)
            if radius:
                maps[name] = convergence_radius(loop, rpm, mu, harmonic, phase=ph)
            signs = mu_sign(loop, rpm, harmonic, mu_max / 10, phase=ph)
            none = rpm[signs == 0]
            report["loops"][name] = {
                "sign_flips_rpm": sign_changes(signs, rpm),
                "no_sign_converges_rpm": [float(none.min()), float(none.max())] if none.size else [],
                "sign_at_rpm": {str(int(n)): int(s) for n, s in zip(rpm[::every], signs[::every])},
            }
    return ConvergenceMap(report, rpm, mu, maps)


__all__ = ["ConvergenceMap", "convergence_map", "grid_step", "measured_phase_table", "phase_table", "schedule"]
