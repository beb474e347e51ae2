"""The loops an LMS design is made on, by name (``--plant``), for ``ambdaq lms`` and ``ambdaq push``.

=========  ========================================================================================
name       loop
=========  ========================================================================================
front      seed 000's one-axis model of the front bearing (Table 1, PID P 1.6, I 1, D 0.0015)
rear       the same for the rear bearing (D 0.002, amplifier 2,500 Hz)
bearings   both one-axis models (a schedule must converge on both)
rig        the simulated spindle's own five-axis loop, linearised from its kernel at each speed
tf:N/D     any plant G(s), V in -> sensor V out, as comma-separated coefficients of s (descending),
           in the loop of seed 000's front PID, e.g. ``tf:2184000/1.5,0,-1770000``
=========  ========================================================================================
"""

from __future__ import annotations

from ..analysis.lms import BEARINGS, PlantLoop, StateSpaceLoop
from ..drivers.rig.spindle import SpindleRig
from ..errors import BadInputError

PLANT_NAMES = ("front", "rear", "bearings", "rig", "tf:NUM/DEN")
_RIG: dict[str, StateSpaceLoop] = {}


def rig_loop() -> StateSpaceLoop:
    """The simulated spindle's loop (one per process: its linearisations are cached)."""
    if "spindle" not in _RIG:
        _RIG["spindle"] = StateSpaceLoop(SpindleRig().loop_matrices)
    return _RIG["spindle"]


def resolve_plant(spec: str) -> dict:
    """``spec`` -> {name: (loop, controller axes it stands for)}."""
    if spec == "front":
        return {"front": (BEARINGS["front"], (0, 1))}
    if spec == "rear":
        return {"rear": (BEARINGS["rear"], (2, 3))}
    if spec == "bearings":
        return {"front": (BEARINGS["front"], (0, 1)), "rear": (BEARINGS["rear"], (2, 3))}
    if spec == "rig":
        return {"rig": (rig_loop(), (0, 1, 2, 3, 4))}
    if spec.startswith("tf:"):
        try:
            num, den = (tuple(float(x) for x in part.split(",")) for part in spec[3:].split("/"))
        except ValueError:
            raise BadInputError(f"plant {spec!r}: expected tf:NUM/DEN with comma-separated coefficients of s") from None
        if not den or den[0] == 0:
            raise BadInputError(f"plant {spec!r}: the denominator's leading coefficient must not be 0")
        return {"tf": (PlantLoop(num=num, den=den), (0, 1, 2, 3, 4))}
    raise BadInputError(f"unknown plant {spec!r}: expected one of {', '.join(PLANT_NAMES)}")
