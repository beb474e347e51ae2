"""A flexible rotor's controller designed to an ISO 14839-3 target (issue 42, item 4):
``ambdaq controller design MODEL.json --machine flexible -o controller.json``.

What it starts from, and what each part of the check rests on:

- **The identified plant** (``plant fit``'s model file: the rotor's poles and every element's
  residues, with their covariance), at standstill. The design's sections are placed on its bending
  modes, its nominal loop is checked, and ``draws`` plants drawn from its covariance (a normal
  distribution of the parameters, the fit's own statement of what it knows) are each closed with
  the design: how many stay stable, and the spread of their peak |Gs|.
- **The machine's rotor model** (``machines/``) for what a standstill measurement cannot hold: how
  the modes move with speed (the impeller's spin lifts a bending mode's forward whirl by hundreds
  of hertz) and the bearing calibration that turns a stiffness into a gain. Every design is
  checked on it on a 1 % speed grid from standstill to the maximum speed.

**PID gains for a stated stiffness and damping** (Schweitzer & Maslen, *Magnetic Bearings*
(2009), ch. 7): a PD on the sensor's gap gives the bearing a force ``-(ki ka ks P - kx) x -
ki ka ks D x'``, ki the current gain, ka the amplifier's (A/V), ks the sensor's (V/m), kx the
magnet's negative stiffness; so ``P = (k + kx) / (ki ka ks)`` and ``D = c / (ki ka ks)``. The
integral gain stays the controller's.

**The sections** (at most the firmware's ``MAX_SECTIONS`` per axis, one chain per bearing, its x
and y axes alike) are chosen greedily: each step tries every candidate (a notch on each identified
bending mode at two widths and two depths, low-passes, lead and lag sections across the band) on
each bearing and keeps the one that lowers most the worst peak |Gs| over the search speeds and
the identified loop at standstill; it stops when none lowers it by ``MIN_GAIN_DB``, and where its
design misses the target it starts again from the next-best first sections (``RESTARTS``).
A greedy search does not promise the best chain; it promises one whose every figure is checked after.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..analysis import sections as sec
from ..analysis.amb import zoh
from ..analysis.iso14839 import STABILITY_LIMITS, db, model_sensitivity_peaks
from ..analysis.plant_model import ModalPlant
from ..documents.sealed import write_sealed
from ..errors import BadInputError
from ..machines.flexible_spindle import AXES, FlexibleLoop, FlexibleSpindleParams, close_loop, flexible_machine
from .plant_fit import FittedPlant, model_from_values

FORMAT = "ambdaq.controller_design"
VERSION = 1
MAX_SECTIONS = 4
"""Second-order sections per axis the controllers ambdaq designs for run (the flexible rig's firmware)."""
SEARCH_SPEEDS = 7
"""Speeds the search grades each candidate at, evenly from standstill to the maximum; the design is
then checked on the 1 % grid."""
GRID_STEPS = 100
"""The check's speed grid: 1 % of the maximum speed."""
SEARCH_DRAWS = 32
"""Plants drawn within the identified uncertainty whose worst peak |Gs| the search counts beside the
nominal's: a section that lowers the nominal peak and raises a drawn plant's (or makes it
unstable) is not taken."""
MIN_GAIN_DB = 0.05
"""A section that lowers the worst peak by less than this is not worth its place in the chain."""
RESTARTS = 8
"""How many other first sections a search whose design misses its target starts again from (best first):
the longer rotor at seed 2 (--damping 4000) needed more than four (zone D after four, zone A after
eight); a target that cannot be met then takes nine searches before the design says so."""
UNSTABLE_COST = 100.0
"""What an unstable loop costs in the search, in dB, plus a thousand times how far its largest pole is
outside the unit circle (so the search can still tell a less unstable loop)."""
BEARINGS = {"front": ("front_x", "front_y"), "rear": ("rear_x", "rear_y")}


@dataclass(frozen=True)
class Section:
    """One designed section: what it is, in words, and its coefficients (b0, b1, b2, a1, a2)."""

    label: str
    coefficients: tuple[float, float, float, float, float]


def _bearing_gain(params: FlexibleSpindleParams, axis: int) -> float:
    """ki ka ks of ``axis``: N of bearing force per m of gap, per unit of P (V/V)."""
    a = params.axes[axis]
    return a.ki * a.amp_gain * params.sensor_gain


def pid_for(stiffness: float, damping: float, params: FlexibleSpindleParams, axis: int) -> tuple[float, float]:
    """P (V/V) and D (s) that give ``axis``'s bearing ``stiffness`` (N/m) and ``damping`` (N s/m)
    (the module docstring's relation)."""
    gain = _bearing_gain(params, axis)
    return (stiffness + params.axes[axis].kx) / gain, damping / gain


def candidates(bending_hz: np.ndarray, fs: float) -> list[Section]:
    """The sections the search tries: notches on each identified bending mode (Q 1 and 3, full and
    -10 dB deep), second-order low-passes and lead and lag sections of a factor 2.5 across the band."""
    out = []
    for f in bending_hz:
        if f < 0.45 * fs:
            for q in (1.0, 3.0):
                for depth in (0.0, 0.3):
                    out.append(Section(f"notch {f:.1f} Hz, Q {q:g}, depth {depth:g}", sec.notch(f, q, fs, depth)))
    for f0 in (400.0, 600.0, 900.0, 1300.0, 2000.0):
        out.append(Section(f"low-pass {f0:g} Hz, Q 0.707", sec.lowpass(f0, 0.707, fs)))
    for f in (150.0, 300.0, 600.0, 1200.0):
        out.append(Section(f"lead {f:g}-{2.5 * f:g} Hz", sec.lead_lag(f, 2.5 * f, fs)))
        out.append(Section(f"lag {2.5 * f:g}-{f:g} Hz", sec.lead_lag(2.5 * f, f, fs)))
    return out


PLANES = (("front_x", "rear_x"), ("front_y", "rear_y"))
"""The axes of each plane: at standstill a plane's bearings reach each other, the planes do not."""


def identified_plant(model: ModalPlant, responses: list[str], h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The identified plant (:func:`identified_continuous`) over the period ``h`` (s), zero-order
    held: x[n+1] = Phi x + Gam u, gap = Cs x."""
    A, B, C = identified_continuous(model, responses)
    Phi, Gam = zoh(A, B, h)
    return Phi, Gam, C


def identified_continuous(model: ModalPlant, responses: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The identified plant of every axis in ``AXES`` as one continuous state space, x' = A x + B u,
    gap = C x (u V per axis, gap m): each input's amplifier, and each mode once per plane, driven
    by and seen at both of its bearings.

    A mode's residues in one plane form a 2 x 2 matrix (sensors x bearings) that is the product of
    its shape at the sensors and at the bearings: rank one.  A mode realised once per input instead
    is a copy per bearing, and the copies of an unstable rigid-body mode that the controller cannot
    tell apart stay unstable in any closed loop.  So each plane's matrix is taken at its rank-one
    part (its largest singular value; the fit's own is rank one within its noise), and that mode is
    one pair of states.  The fitted delay (microseconds, within its deviation of zero on the
    simulator) is left out."""
    modes = [(0.0, -a * a) for a in model.rigid] + [(2 * z * w, w * w) for w, z in model.bending]
    na, nm = len(AXES), len(modes)
    n = 2 * na + 2 * nm * len(PLANES)
    A, B, C = np.zeros((n, n)), np.zeros((n, na)), np.zeros((na, n))
    wa, za = model.amplifier
    for j in range(na):  # the amplifiers: states 2j (its output, unit DC gain) and 2j + 1
        A[2 * j, 2 * j + 1] = 1.0
        A[2 * j + 1, 2 * j], A[2 * j + 1, 2 * j + 1] = -wa * wa, -2 * za * wa
        B[2 * j + 1, j] = wa * wa
    where = {label: r for r, label in enumerate(responses)}
    for q, plane in enumerate(PLANES):
        idx = [AXES.index(a) for a in plane]
        labels = [[o if o == i else f"{o}<-{i}" for i in plane] for o in plane]
        absent = [lb for row in labels for lb in row if lb not in where]
        if absent:
            raise BadInputError(f"the plant model has no {', '.join(absent)}: a design needs every element of each "
                                "plane (measure every axis; plant fit fits the elements across a plane's bearings)")
        for k, (c, d) in enumerate(modes):
            R = np.array([[model.residues[where[lb], k] for lb in row] for row in labels])
            u, sv, vt = np.linalg.svd(R)
            i = 2 * na + 2 * (q * nm + k)
            A[i, i + 1] = 1.0
            A[i + 1, i], A[i + 1, i + 1] = -d, -c
            for col, j in enumerate(idx):
                A[i + 1, 2 * j] = vt[0, col]  # driven by the amplifiers' outputs along the bearings' shape
                C[j, i] = sv[0] * u[col, 0]
        if model.residual is not None:
            for r_, row in enumerate(labels):
                for c_, lb in enumerate(row):
                    C[idx[r_], 2 * idx[c_]] += model.residual[where[lb]]
    return A, B, C


def _draws(fitted: FittedPlant, count: int, seed: int) -> list[ModalPlant]:
    """``count`` models with parameters drawn from the fit's normal distribution (its values and
    covariance); a draw that leaves the physical range (a negative frequency) is drawn again."""
    f = fitted.fit
    w, v = np.linalg.eigh((f.covariance + f.covariance.T) / 2)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    rng = np.random.default_rng(seed)
    m, b = len(f.model.rigid), len(f.model.bending)
    out: list[ModalPlant] = []
    while len(out) < count:
        values = f.values + root @ rng.standard_normal(f.values.size)
        if np.any(values[: m + 2 * b + 1] <= 0):
            continue
        out.append(model_from_values(Path("draw"), values, f.names, m, b, f.axes, fitted.h))
    return out


PERTURBATION = (0.10, 0.20, 0.05)
"""The perturbed plants every design is also closed with (issue 42): each mode's frequency (and each
rigid-body pole) within +-10 %, each bending mode's damping within +-20 %, each residue (the
product of the modal, current, amplifier and sensor gains) within +-5 %, uniformly and
independently: far wider than a good measurement's deviations, what a machine may drift by
between the measurement and the years it runs."""


def _perturbed(model: ModalPlant, count: int, seed: int) -> list[ModalPlant]:
    """``count`` plants perturbed from ``model`` by :data:`PERTURBATION`."""
    freq, damping, gain = PERTURBATION
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        b = len(model.bending)
        bending = model.bending * np.column_stack([rng.uniform(1 - freq, 1 + freq, b), rng.uniform(1 - damping, 1 + damping, b)])
        out.append(ModalPlant(model.rigid * rng.uniform(1 - freq, 1 + freq, model.rigid.size), bending,
                              model.residues * rng.uniform(1 - gain, 1 + gain, model.residues.shape), model.amplifier,
                              model.delay_s, model.h, model.residual))
    return out


@dataclass
class ControllerDesign:
    """A designed controller and everything predicted of it (what ``--json`` prints, what the file
    holds, what the report shows)."""

    machine: str
    gains: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]
    chains: dict[str, list[Section]]
    speeds_rpm: np.ndarray
    peak_db: np.ndarray  # (speeds, axes); NaN where unstable
    at_hz: np.ndarray
    radius: np.ndarray  # (speeds,)
    stock_peak_db: np.ndarray  # the machine's stock controller (PID, no sections), same grid
    stock_radius: np.ndarray
    identified_db: np.ndarray  # (axes,): the identified loop at standstill with the design
    draws: int
    stable_draws: int
    draw_peak_db: np.ndarray  # (stable draws,): each draw's worst axis
    perturbed: int = 0
    stable_perturbed: int = 0
    perturbed_peak_db: np.ndarray = field(default_factory=lambda: np.zeros(0))
    target_zone: str = "A"
    source: dict = field(default_factory=dict)

    @property
    def stable(self) -> bool:
        return bool(np.all(self.radius < 1.0))

    @property
    def robust(self) -> bool:
        """Stable on the whole speed grid, with every plant drawn within the identified uncertainty
        and with every perturbed plant (:data:`PERTURBATION`)."""
        return self.stable and self.stable_draws == self.draws and self.stable_perturbed == self.perturbed

    @property
    def zone(self) -> str | None:
        """The worst ISO 14839-3 zone over every axis and speed of the grid (None: unstable somewhere)."""
        return _zone(float(np.max(self.peak_db))) if self.stable else None

    @property
    def meets_target(self) -> bool:
        """Robust, and no axis at any speed beyond the target zone."""
        return self.robust and self.zone is not None and self.zone <= self.target_zone

    def biquads(self) -> np.ndarray:
        """(axes, MAX_SECTIONS, 5): every axis's chain, the unused places passing through."""
        out = np.tile(np.array([1.0, 0.0, 0.0, 0.0, 0.0]), (len(AXES), MAX_SECTIONS, 1))
        for i, a in enumerate(AXES):
            for k, s in enumerate(_chain(self.chains, a)):
                out[i, k] = s.coefficients
        return out

    def rows(self) -> list[dict]:
        """Per axis: the worst predicted peak over the speed grid, where, its zone; the stock's."""
        out = []
        for i, a in enumerate(AXES):
            k = int(np.nanargmax(self.peak_db[:, i])) if self.stable else int(np.argmax(self.radius))
            stock = self.stock_peak_db[:, i]
            out.append({"axis": a, "peak_db": _r(self.peak_db[k, i]), "at_hz": _r(self.at_hz[k, i]),
                        "at_rpm": float(self.speeds_rpm[k]), "zone": _zone(self.peak_db[k, i]),
                        "identified_standstill_db": _r(self.identified_db[i]),
                        "stock_peak_db": None if np.isnan(stock).any() else _r(np.max(stock)),
                        "stock_unstable_from_rpm": _unstable_from(self.speeds_rpm, self.stock_radius)})
        return out

    def as_dict(self) -> dict:
        return {"machine": self.machine, "source": self.source, "stable_on_the_grid": self.stable,
                "robust": self.robust, "zone": self.zone, "target_zone": self.target_zone,
                "meets_target": self.meets_target,
                "speed_grid_rpm": [float(self.speeds_rpm[0]), float(self.speeds_rpm[-1]), len(self.speeds_rpm)],
                "pid": {name: list(map(float, g)) for name, g in zip(("p", "i", "d"), self.gains)},
                "sections": {name: [s.label for s in c] for name, c in self.chains.items()},
                "axes": self.rows(),
                "robustness": {"draws": self.draws, "stable": self.stable_draws, **_spread(self.draw_peak_db)},
                "perturbed": {"plants": self.perturbed, "stable": self.stable_perturbed,
                              "frequency_damping_gain": list(PERTURBATION), **_spread(self.perturbed_peak_db)}}

    def document(self) -> dict:
        """The sealed file: the controller as the firmware takes it, and its prediction."""
        return {"format": FORMAT, "version": VERSION, **self.as_dict(), "axis_names": list(AXES),
                "pid_per_axis": np.column_stack(self.gains).tolist(), "biquads": self.biquads().tolist(),
                "prediction": {"speeds_rpm": self.speeds_rpm.tolist(),
                               "peak_db": [[_r(v) for v in row] for row in self.peak_db],
                               "at_hz": [[_r(v) for v in row] for row in self.at_hz],
                               "stock_peak_db": [[_r(v) for v in row] for row in self.stock_peak_db]}}

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        return write_sealed(path, self.document(), overwrite=overwrite)


def _spread(worst_db: np.ndarray) -> dict:
    """The median and 95th percentile of stable plants' worst peaks, dB."""
    if not worst_db.size:
        return {"worst_peak_db_median": None, "worst_peak_db_95": None}
    return {"worst_peak_db_median": _r(np.median(worst_db)), "worst_peak_db_95": _r(np.percentile(worst_db, 95))}


def _r(value: float) -> float | None:
    return None if not np.isfinite(value) else round(float(value), 2)


def _zone(peak_db: float) -> str | None:
    return None if not np.isfinite(peak_db) else STABILITY_LIMITS.zone(10 ** (peak_db / 20))


def _unstable_from(speeds: np.ndarray, radius: np.ndarray) -> float | None:
    bad = np.flatnonzero(radius >= 1.0)
    return float(speeds[bad[0]]) if bad.size else None


def _chain(chains: dict[str, list[Section]], axis: str) -> list[Section]:
    """``axis``'s chain: its bearing's."""
    return next(c for name, c in chains.items() if axis in BEARINGS[name])


def _per_axis(chains: dict[str, list[Section]]) -> list[list[tuple]]:
    return [[s.coefficients for s in _chain(chains, a)] for a in AXES]


def design(fitted: FittedPlant, machine: str = "flexible", *, stiffness: float | None = None,
           damping: float | None = None, max_rpm: float | None = None, draws: int = 200,
           seed: int = 0, target_zone: str = "A", perturbed: int = 200) -> ControllerDesign:
    """Design the controller of ``machine`` on the identified plant ``fitted`` (module docstring).

    Parameters
    ----------
    fitted : FittedPlant
        ``plant fit``'s model, measured at standstill.
    machine : str
        The rotor model the design is checked on over speed
        (:data:`~ambdaq.machines.flexible_spindle.FLEXIBLE_MACHINES`).
    stiffness : float, optional
        Bearing stiffness, N/m; default the one the machine's PID gives.
    damping : float, optional
        Bearing damping, N s/m; default the one the machine's PID gives.
    max_rpm : float, optional
        The top of the speed grid, rpm; default the machine's maximum speed.
    draws : int
        Plants drawn from the identified covariance for the robustness check.
    seed : int
        Seed of those draws.
    target_zone : str
        The ISO 14839-3 zone every axis must reach at every speed ("A" ... "D").
    perturbed : int
        Plants perturbed by :data:`PERTURBATION` the design is also closed with.
    """
    if fitted.speed_rpm != 0.0:
        raise BadInputError(f"the plant was measured at {fitted.speed_rpm:g} rpm: a design starts from a measurement "
                            "at standstill (the model has no gyroscopic coupling)")
    params, top = flexible_machine(machine)
    top = float(max_rpm if max_rpm is not None else top)
    if not (np.isfinite(top) and top > 0):
        raise BadInputError(f"--max-rpm must be a speed above 0, not {top:g}")
    if abs(fitted.h * params.sample_rate - 1.0) > 1e-6:
        raise BadInputError(f"the plant was measured at {1 / fitted.h:g} Hz, the {machine} controller runs at "
                            f"{params.sample_rate:g} Hz")
    missing = [a for a in AXES if a not in fitted.responses]
    if missing:
        raise BadInputError(f"the plant model has no response for {', '.join(missing)}: measure every axis")
    stock = (tuple(a.pid_p for a in params.axes), tuple(a.pid_i for a in params.axes),
             tuple(a.pid_d for a in params.axes))
    P, D = list(stock[0]), list(stock[2])
    if stiffness is not None or damping is not None:
        for i, a in enumerate(params.axes):
            gain = _bearing_gain(params, i)
            k = stiffness if stiffness is not None else P[i] * gain - a.kx
            c = damping if damping is not None else D[i] * gain
            if not (np.isfinite(k) and k > 0 and np.isfinite(c) and c > 0):
                raise BadInputError(f"stiffness and damping must be above 0, not {k:g} N/m and {c:g} N s/m")
            P[i], D[i] = pid_for(k, c, params, i)
    gains = (tuple(P), stock[1], tuple(D))
    plant = FlexibleLoop(params)
    model = fitted.fit.model
    ident = identified_plant(model, fitted.responses, fitted.h)
    band = (5.0, 0.5 * params.sample_rate - 1.0)

    def closed_identified(plant_ss, per_axis):
        return close_loop(*plant_ss, gains, per_axis, sensor_gain=params.sensor_gain, nd=params.derivative_filter,
                          h=fitted.h)

    # the plants the search grades beside the nominal: drawn within the identified uncertainty, other draws
    # than the check's (a design chosen on the check's own draws would pass it by construction)
    guards = [identified_plant(drawn, fitted.responses, fitted.h) for drawn in _draws(fitted, SEARCH_DRAWS, seed + 1)]

    def worst(chains: dict[str, list[Section]], speeds) -> float:
        per_axis = _per_axis(chains)
        out = []
        for closed in ([closed_identified(g, per_axis) for g in [ident, *guards]]
                       + [plant.closed(n, gains, per_axis) for n in speeds]):
            radius, peak, _ = model_sensitivity_peaks(*closed, plant.h, band, points=300)
            if radius >= 1.0:
                return UNSTABLE_COST + 1000.0 * (radius - 1.0)
            out.append(float(db(peak.max())))
        return max(out)

    search = np.linspace(0.0, top, SEARCH_SPEEDS)
    options = candidates(model.bending[:, 0] / (2 * np.pi), params.sample_rate)

    def steps(chains: dict[str, list[Section]]) -> list[tuple[float, str, Section]]:
        """Every chain one candidate longer, with its cost, best first."""
        return sorted(((worst({**chains, name: chains[name] + [s]}, search), name, s)
                       for name in BEARINGS if len(chains[name]) < MAX_SECTIONS for s in options),
                      key=lambda t: t[0])

    def grow(chains: dict[str, list[Section]], best: float,
             trials: list[tuple[float, str, Section]]) -> tuple[dict[str, list[Section]], float]:
        """The greedy search from ``chains`` (cost ``best``), its first step's ``trials`` given."""
        while trials and trials[0][0] <= best - MIN_GAIN_DB:
            best, name, s = trials[0]
            chains = {**chains, name: chains[name] + [s]}
            trials = steps(chains)
        return chains, best

    speeds = np.linspace(0.0, top, GRID_STEPS + 1)
    stock_grid = [model_sensitivity_peaks(*plant.closed(n, stock, [[] for _ in AXES]), plant.h, band) for n in speeds]

    def worst_peaks(plants: list[ModalPlant], per_axis) -> np.ndarray:
        """Each stable plant's worst axis peak with the design, dB (the unstable ones left out)."""
        out = []
        for other in plants:
            radius, peak, _ = model_sensitivity_peaks(*closed_identified(identified_plant(other, fitted.responses,
                                                                                           fitted.h), per_axis),
                                                      fitted.h, band, points=300)
            if radius < 1.0:
                out.append(float(db(peak.max())))
        return np.array(out)

    checked_draws, checked_perturbed = _draws(fitted, draws, seed), _perturbed(model, perturbed, seed)

    def checked(chains: dict[str, list[Section]]) -> ControllerDesign:
        """The design of ``chains`` on the 1 % grid, the identified loop and the checked plants."""
        per_axis = _per_axis(chains)
        grid = [model_sensitivity_peaks(*plant.closed(n, gains, per_axis), plant.h, band) for n in speeds]
        _, ident_peak, _ = model_sensitivity_peaks(*closed_identified(ident, per_axis), fitted.h, band)
        draw_peaks = worst_peaks(checked_draws, per_axis)
        perturbed_peaks = worst_peaks(checked_perturbed, per_axis)
        return ControllerDesign(
            machine, gains, chains, speeds, np.array([db(g[1]) for g in grid]), np.array([g[2] for g in grid]),
            np.array([g[0] for g in grid]), np.array([db(g[1]) for g in stock_grid]),
            np.array([g[0] for g in stock_grid]), np.asarray(db(ident_peak)), draws, draw_peaks.size, draw_peaks,
            perturbed, perturbed_peaks.size, perturbed_peaks, target_zone, dict(fitted.source))

    empty: dict[str, list[Section]] = {name: [] for name in BEARINGS}
    first = steps(empty)
    result = checked(grow(empty, worst(empty, search), first)[0])
    # a design that misses its target may owe it to the search's first section, which the rest could
    # not recover from (the flexible rotor, seed 1, --damping 4000: a full notch on the front's first
    # mode, then a loop unstable from 11,160 rpm): the search starts again from the next-best first
    # sections, up to RESTARTS, and the first design that meets the target is kept (none: the first)
    for cost, name, s in first[1 : RESTARTS + 1]:
        if result.meets_target:
            break
        again = {**empty, name: [s]}
        tried = checked(grow(again, cost, steps(again))[0])
        if tried.meets_target:
            result = tried
    return result


def source_of(path: str | Path) -> dict:
    """The model file a design came from: its name and SHA-256."""
    path = Path(path)
    return {"plant_model": path.name, "plant_model_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


@dataclass(frozen=True)
class ControllerFile:
    """A design file as ``push`` takes it: the controller per axis and what was predicted of it."""

    axes: list[str]
    pid: np.ndarray  # (axes, 3): P V/V, I 1/s, D s
    biquads: np.ndarray  # (axes, sections, 5)
    speeds_rpm: np.ndarray
    peak_db: np.ndarray  # (speeds, axes), NaN where the design was predicted unstable
    meets_target: bool
    stock_peak_db: np.ndarray  # (speeds, axes): the stock controller's, NaN where unstable
    summary: dict  # what ``controller design --json`` printed (sections, axes, robustness)

    def predicted_db(self, axis: str, rpm: float) -> float:
        """The predicted peak |Gs| (dB) of ``axis`` at ``rpm``, linear between the grid's speeds;
        BadInputError beyond the grid (the design was not checked there)."""
        half = 0.5 * float(self.speeds_rpm[1] - self.speeds_rpm[0])  # a measured speed a little off the grid's ends
        if not self.speeds_rpm[0] - half <= rpm <= self.speeds_rpm[-1] + half:
            raise BadInputError(f"the design was predicted from {self.speeds_rpm[0]:g} to {self.speeds_rpm[-1]:g} rpm, "
                                f"not at {rpm:g}")
        return float(np.interp(rpm, self.speeds_rpm, self.peak_db[:, self.axes.index(axis)]))


def load_design(path: str | Path) -> ControllerFile:
    """Read a file ``controller design`` wrote; BadInputError naming what is wrong (a controller that
    could not run: a gain out of range, a section whose poles are outside the unit circle)."""
    from ..documents.sealed import read_sealed
    from ..drivers.coefbank import controller_problem

    path = Path(path)
    doc = read_sealed(path, FORMAT, VERSION, "controller design file")
    try:
        axes = doc["axis_names"]
        if not isinstance(axes, list) or not all(isinstance(a, str) for a in axes):
            raise ValueError("axis_names must be a list of names")
        pid = np.array(doc["pid_per_axis"], dtype=float)
        biquads = np.array(doc["biquads"], dtype=float)
        pred = doc["prediction"]
        speeds = np.array(pred["speeds_rpm"], dtype=float)
        peak = np.array([[np.nan if v is None else v for v in row] for row in pred["peak_db"]], dtype=float)
        stock = np.array([[np.nan if v is None else v for v in row] for row in pred["stock_peak_db"]], dtype=float)
        if (peak.shape != (speeds.size, len(axes)) or stock.shape != peak.shape or speeds.size < 2
                or np.any(np.diff(speeds) <= 0)):
            raise ValueError("the prediction must hold one row per speed, increasing, one column per axis")
        meets = doc["meets_target"]
        if not isinstance(meets, bool):
            raise ValueError("meets_target must be true or false")
    except (KeyError, TypeError, ValueError) as err:
        raise BadInputError(f"{path}: malformed controller design file ({err})") from None
    if pid.shape[0] != len(axes):
        raise BadInputError(f"{path}: {pid.shape[0]} PID rows for {len(axes)} axes")
    problem = controller_problem(pid, biquads)
    if problem:
        raise BadInputError(f"{path}: {problem}")
    summary = {k: doc[k] for k in ("machine", "source", "zone", "target_zone", "pid", "sections", "axes", "robustness",
                                   "perturbed") if k in doc}
    return ControllerFile(list(axes), pid, biquads, speeds, peak, meets, stock, summary)


COMPARE_TOLERANCE_DB = 0.5
"""How far a measured peak |Gs| may be from the design's prediction before the machine is said not to
behave as predicted, dB: the measured peak's stated accuracy (docs/validation.md), which issue 42
asks of the prediction. A peak a few hertz wide needs a grid as fine for it (docs/tuning.md)."""


def compare(design: ControllerFile, runs: list[tuple[str, float, float, str | None]]) -> list[dict]:
    """Each graded ``iso stability`` run, (axis, speed rpm, peak dB, zone), beside the design's
    prediction there: ``within`` where they differ by at most :data:`COMPARE_TOLERANCE_DB`.  A run
    the measurement could not grade (zone None: its coherence at the peak too low) is not
    compared: its peak is not a measurement of the loop."""
    out = []
    for axis, rpm, peak_db, zone in runs:
        if axis not in design.axes or zone is None:
            continue
        predicted = design.predicted_db(axis, float(rpm))
        diff = float(peak_db) - predicted
        out.append({"axis": axis, "speed_rpm": float(rpm), "measured_db": round(float(peak_db), 2),
                    "predicted_db": round(predicted, 2), "difference_db": round(diff, 2),
                    "within": bool(abs(diff) <= COMPARE_TOLERANCE_DB)})
    return out
