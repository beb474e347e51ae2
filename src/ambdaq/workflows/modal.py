"""Modal parameters from an impact test (``ambdaq identify modal``): each hammer strike's free
decay through the eigensystem realisation algorithm (:mod:`ambdaq.analysis.modal`), the model
order the lowest the next order confirms."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..analysis.modal import Mode, free_decays, stable_modes, strikes
from ..daq.recording import Recording
from ..errors import BadInputError

HAMMER = "/amb/hammer"


@dataclass(frozen=True)
class ModalResult:
    """What an impact test gives.

    Attributes
    ----------
    axes : list of str
        The gap axes analysed.
    strikes : int
        Strikes with a whole free decay after them.
    order : int
        The ERA model order the next order confirms.
    modes : list of Mode
        The damped modes found, the dominant first.
    unit : str
        The gap's unit (the modes' amplitudes are in it).
    """

    axes: list[str]
    strikes: int
    order: int
    modes: list[Mode]
    unit: str


def identify_modal(rec: Recording, axes: tuple[str, ...] = (), *, window_s: float = 0.05,
                   skip_s: float = 0.002) -> ModalResult:
    """Natural frequencies and damping ratios from the hammer strikes of one recording.

    Parameters
    ----------
    rec : Recording
        A recording with an instrumented hammer's force (``/amb/hammer``, N) and the gap sensors
        (role ``gap``, m).
    axes : tuple of str
        Gap axes to analyse; empty: every axis that moves at least a tenth as much as the most
        moved one in the first strike's 20 ms.
    window_s : float
        Free decay analysed after each strike, in s.
    skip_s : float
        Time left out after each strike ends (the fast poles), in s.
    """
    path = rec.path
    rec.load([HAMMER])  # one line and exit 2 if it is missing
    gap, hammer = rec.role("gap"), rec[HAMMER]
    rate = gap.nominal_rate
    force = np.interp(gap.log_time, hammer.log_time, hammer["hammer"]) if len(hammer) != len(gap) else hammer["hammer"]
    hits = strikes(force, rate)
    if not hits:
        raise BadInputError(f"{path}: no hammer strike found on {HAMMER}")
    names = list(gap.fields)
    for axis in axes:
        if axis not in names:
            raise BadInputError(f"--axis {axis!r}: the gap sensors are {', '.join(names)}")
    if not axes:
        a, _ = hits[0]
        swing = {n: np.ptp(gap[n][a: a + int(0.02 * rate)]) for n in names}
        axes = tuple(n for n in names if swing[n] >= 0.1 * max(swing.values()))
    decays = free_decays(np.column_stack([gap[n] for n in axes]), force, rate, window_s=window_s, skip_s=skip_s)
    if not decays:
        raise BadInputError(f"{path}: no strike has {window_s:g} s of free decay after it")
    found, order = stable_modes(decays, rate)
    if not found:
        raise BadInputError(f"{path}: no damped mode confirmed on {', '.join(axes)} (ERA orders 2-12 disagree)")
    return ModalResult(list(axes), len(decays), order, found, gap.units.get(axes[0], ""))


__all__ = ["HAMMER", "ModalResult", "identify_modal"]
