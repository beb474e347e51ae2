"""The loops an LMS design is made on, by name (``--plant``), for ``ambdaq lms`` and ``ambdaq push``.

A machine's named plants come with its models (``LMS`` in its module of :mod:`ambdaq.machines.models`,
an :class:`~ambdaq.analysis.lms.DesignModels`); the spindle of Ro et al. is the one that has them:

=========  ========================================================================================
name       loop
=========  ========================================================================================
front      Ro et al.'s one-axis model of the front bearing (Table 1, PID P 1.6, I 1, D 0.0015)
rear       the same for the rear bearing (D 0.002, amplifier 2,500 Hz)
bearings   both one-axis models (a schedule must converge on both)
rig        the simulated spindle's own five-axis loop, linearised from its kernel at each speed
tf:N/D     any plant G(s), V in -> sensor V out, as comma-separated coefficients of s (descending),
           in the loop of the machine's PID (Ro et al.'s front PID), e.g. ``tf:2184000/1.5,0,-1770000``
ss:FILE    any plant in state space, from a ``.npz`` or ``.json`` file (docs/lms.md):
           ``A, B, C[, D]`` a continuous one-input plant G(s) (V -> sensor V) in the loop of that
           PID; or ``M, B, C, h[, rpm]`` a discrete multi-axis loop with the feedforward as its
           input, x[n+1] = M x + B r_c, e = C x - r_c (one set, or one per speed in ``rpm``)
=========  ========================================================================================

Each loop stands for some of the controller's axes, by name; the controller's axes are the
design's (``DesignModels.axes``) unless the coefficient file it goes with names its own.
"""

from __future__ import annotations

import warnings
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from scipy.signal import ss2tf

from ..analysis.lms import DesignModels, PlantLoop, StateSpaceLoop
from ..documents.sealed import check_regular_file, read_json
from ..errors import BadInputError
from ..machines.models import design_models

DESIGN_MACHINE = "spindle"  # the machine whose models --plant names: the one with LMS design models
FORMS = ("tf:NUM/DEN", "ss:FILE")
MAX_ORDER = 64  # a plant model's order: the simulated spindle's discrete loop has 35 states
MAX_AXES = 16  # a discrete loop's feedforward inputs: a controller's axes


def plant_names(models: DesignModels | None = None) -> tuple[str, ...]:
    """The plants ``--plant`` takes: the machine's named ones, then the forms any machine may give."""
    return (*(models or design_models(DESIGN_MACHINE)).plants, *FORMS)


@contextmanager
def analysing(spec: str):
    """A plant the convergence map cannot be computed for (its numbers overflow, its matrices are
    singular) is bad input: one line naming it, not an internal error nor scipy's warnings before
    it (they are shown only when the map is computed after all)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        except (np.linalg.LinAlgError, FloatingPointError, OverflowError, ZeroDivisionError, ValueError) as err:
            hint = "; scipy: " + str(caught[0].message) if caught else ""
            raise BadInputError(f"plant {spec!r} cannot be analysed on the convergence map ({err}{hint})") from None
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def resolve_plant(spec: str, models: DesignModels | None = None) -> dict:
    """``spec`` -> {label: (loop, the controller axes it stands for, by name)}.

    Parameters
    ----------
    spec : str
        A named plant of ``models``, ``tf:NUM/DEN`` or ``ss:FILE`` (the module's table).
    models : DesignModels, optional
        The machine's design models; default the spindle's (:data:`DESIGN_MACHINE`).
    """
    models = models or design_models(DESIGN_MACHINE)
    if spec in models.plants:
        return models.plants[spec]()
    if spec.startswith("tf:"):
        try:
            num, den = (tuple(float(x) for x in part.split(",")) for part in spec[3:].split("/"))
        except ValueError:
            raise BadInputError(f"plant {spec!r}: expected tf:NUM/DEN with comma-separated coefficients of s") from None
        if not den or den[0] == 0:
            raise BadInputError(f"plant {spec!r}: the denominator's leading coefficient must not be 0")
        if not all(np.isfinite(num + den)) or len(den) > MAX_ORDER + 1:
            raise BadInputError(f"plant {spec!r}: finite coefficients, a denominator of order {MAX_ORDER} at most")
        if len(np.trim_zeros(np.array(num), "f")) > len(den):
            raise BadInputError(f"plant {spec!r}: improper (the numerator's order is above the denominator's)")
        return {"tf": (PlantLoop(**vars(models.pid), num=num, den=den), models.axes)}
    if spec.startswith("ss:"):
        return state_space_plant(Path(spec[3:]), models)
    raise BadInputError(f"unknown plant {spec!r}: expected one of {', '.join(plant_names(models))}")


MAX_SPEEDS = 1_000  # linearisations per discrete loop (the rig every 100 rpm to 60,000 would be 601)
# values a plant file may hold: MAX_SPEEDS sets of M (n, n), B and C at the largest order
MAX_PLANT_VALUES = MAX_SPEEDS * (MAX_ORDER**2 + 2 * MAX_ORDER * MAX_AXES)


def _npz_shapes(path: Path) -> dict[str, tuple[int, ...]]:
    """The shape of each array in a ``.npz``, from the headers of its members, before any is
    inflated: a few kilobytes of zip can hold gigabytes of zeros."""
    shapes = {}
    with zipfile.ZipFile(path) as z:
        for member in z.infolist():
            with z.open(member) as fh:
                version = np.lib.format.read_magic(fh)
                shape, _fortran, dtype = (np.lib.format.read_array_header_1_0(fh) if version == (1, 0)
                                          else np.lib.format.read_array_header_2_0(fh))
            if dtype.kind not in "biuf":
                raise ValueError(f"{member.filename} holds {dtype}, not numbers")
            shapes[member.filename.removesuffix(".npy")] = shape
    return shapes


def _arrays(path: Path) -> dict[str, np.ndarray]:
    """The named arrays of a ``.npz`` or ``.json`` plant file, of at most MAX_PLANT_VALUES numbers."""
    where = f"plant ss:{path}"
    check_regular_file(path, "plant file")
    try:
        if path.suffix == ".npz":
            shapes = _npz_shapes(path)
            total = sum(int(np.prod(shape, dtype=float)) for shape in shapes.values())
            if total > MAX_PLANT_VALUES:
                raise BadInputError(f"{where}: {total:,} values; a plant file holds at most {MAX_PLANT_VALUES:,} "
                                    f"(order {MAX_ORDER}, {MAX_SPEEDS} speeds)")
            with np.load(path, allow_pickle=False) as z:
                return {k: np.asarray(z[k], dtype=float) for k in z.files}
        doc = read_json(path, "plant file")
        if not isinstance(doc, dict):
            raise ValueError("the file is not a table of named arrays")
        return {k: np.asarray(v, dtype=float) for k, v in doc.items()}
    except (OSError, ValueError, TypeError, AttributeError, zipfile.BadZipFile, EOFError) as err:
        raise BadInputError(f"{where}: cannot read a .npz or .json of named arrays ({err})") from None


def state_space_plant(path: Path, models: DesignModels) -> dict:
    """A plant in state space from ``path`` (see the module table), checked for shape and finiteness.

    Parameters
    ----------
    path : Path
        ``.npz`` or ``.json`` file.  Continuous plant: ``A`` (n, n), ``B`` (n, 1), ``C`` (1, n),
        optional ``D`` (1, 1), in V and s.  Discrete loop: ``M`` (n, n) or (k, n, n), ``B``
        (n, p) or (k, n, p) in state per m of feedforward, ``C`` (p, n) or (k, p, n) in m of
        command error per state, ``h`` the sample period in s, and with k sets ``rpm`` (k,),
        increasing, in rpm: between them the matrices are interpolated linearly, beyond them held.
    models : DesignModels
        The machine's: its PID (for a continuous plant) and its axes (a discrete loop's p inputs
        stand for its first p axes).

    Returns
    -------
    dict
        {name: (loop, controller axes it stands for)}, as :func:`resolve_plant`.
    """
    a = _arrays(path)
    where = f"plant ss:{path}"
    bad = [k for k, v in a.items() if not np.all(np.isfinite(v))]
    if bad:
        raise BadInputError(f"{where}: {bad[0]} holds NaN or infinite values")
    order = max((a[k].shape[-1] for k in ("A", "M") if k in a and a[k].ndim), default=0)
    if order > MAX_ORDER:
        raise BadInputError(f"{where}: a plant of order {order}; at most {MAX_ORDER}")
    if "M" in a:
        missing = [k for k in "BC" if k not in a]
        if missing:
            raise BadInputError(f"{where}: a discrete loop needs M, B, C and h; {missing[0]} is missing")
        loop = _discrete_loop(a, where, len(models.axes))
        return {"ss": (loop, models.axes[: a["B"].shape[-1]])}
    if "A" not in a:
        raise BadInputError(f"{where}: expected arrays A, B, C[, D] (continuous plant) or M, B, C, h[, rpm] (loop)")
    A, B, C = (np.atleast_2d(a.get(k, np.zeros(0))) for k in "ABC")
    D = np.atleast_2d(a.get("D", np.zeros((1, 1))))
    n = A.shape[0]
    if A.shape != (n, n) or B.shape != (n, 1) or C.shape != (1, n) or D.shape != (1, 1):
        raise BadInputError(f"{where}: a continuous plant needs A (n, n), B (n, 1), C (1, n), D (1, 1); "
                            f"got {A.shape}, {B.shape}, {C.shape}, {D.shape}")
    num, den = ss2tf(A, B, C, D)
    loop = PlantLoop(**vars(models.pid), num=tuple(np.trim_zeros(num[0], "f")) or (0.0,), den=tuple(den))
    return {"ss": (loop, models.axes)}


def _discrete_loop(a: dict[str, np.ndarray], where: str, n_axes: int) -> StateSpaceLoop:
    """``M, B, C, h[, rpm]`` -> a :class:`StateSpaceLoop` interpolated over speed."""
    if "h" not in a or a["h"].size != 1 or not a["h"].item() > 0:
        raise BadInputError(f"{where}: a discrete loop needs h, its sample period in s (> 0)")
    rpm = np.atleast_1d(a.get("rpm", np.zeros(1)))
    k = rpm.size
    if k > MAX_SPEEDS:
        raise BadInputError(f"{where}: {k:,} speeds; a discrete loop is given at {MAX_SPEEDS:,} speeds at most")
    M, B, C = (a[name] if a[name].ndim == 3 else np.broadcast_to(a[name], (k, *a[name].shape)) for name in "MBC")
    n, p = M.shape[-1], B.shape[-1]
    if (M.shape != (k, n, n) or B.shape != (k, n, p) or C.shape != (k, p, n) or not 1 <= p <= n_axes
            or np.any(np.diff(rpm) <= 0)):
        raise BadInputError(f"{where}: a discrete loop needs M (k, n, n), B (k, n, p), C (k, p, n) with "
                            f"1 <= p <= {n_axes} (the controller's axes) and k increasing speeds in rpm; got M {M.shape}, B {B.shape}, "
                            f"C {C.shape}, rpm {rpm.shape}")

    def matrices(speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i = int(np.clip(np.searchsorted(rpm, speed) - 1, 0, max(k - 2, 0)))
        t = 0.0 if k == 1 else float(np.clip((speed - rpm[i]) / (rpm[i + 1] - rpm[i]), 0.0, 1.0))
        j = min(i + 1, k - 1)
        return tuple((1 - t) * X[i] + t * X[j] for X in (M, B, C))

    return StateSpaceLoop(matrices, h=a["h"].item())
