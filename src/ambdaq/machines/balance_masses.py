"""Masses put on a rotor's balancing planes (issue 43, item 1): a trial mass, a correction mass.

A mass m at radius r in a plane, at angle phi from the key-phasor's mark in the direction of
rotation, adds the unbalance m r e^{j phi} (kg m) to that plane's: its force m r Omega^2 turns
with the rotor, along theta + phi (ISO 21940-2's unbalance vector, its angle measured with the
rotation). A rotor's unbalance per plane is the sum of these phasors.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..errors import BadInputError

_SPEC = re.compile(r"^(?P<plane>[a-z_]+):(?P<grams>[^@:]+)@(?P<deg>[^@:]+)(?::(?P<radius>[^@:]+))?$")


@dataclass(frozen=True)
class BalanceMass:
    """One mass on one balancing plane.

    Parameters
    ----------
    plane : str
        The plane's name (the machine's: ``front``, ``rear`` on the spindle).
    grams : float
        The mass, g.
    deg : float
        Its angle from the key-phasor's mark, in the direction of rotation, degrees.
    radius_m : float
        Its radius, m.
    """

    plane: str
    grams: float
    deg: float
    radius_m: float

    @property
    def unbalance(self) -> complex:
        """m r e^{j phi}, kg m."""
        return self.grams * 1e-3 * self.radius_m * np.exp(1j * np.radians(self.deg))

    @classmethod
    def parse(cls, spec: str, planes: tuple[str, ...], radius_m: float) -> "BalanceMass":
        """``PLANE:GRAMS@DEG[:RADIUS_MM]`` (e.g. ``front:2.5@90``), on one of ``planes``; the radius
        ``radius_m`` (m) where the spec gives none."""
        m = _SPEC.match(spec.strip())
        if m is None:
            raise BadInputError(f"balance mass {spec!r}: PLANE:GRAMS@DEG[:RADIUS_MM], e.g. front:2.5@90")
        if m["plane"] not in planes:
            raise BadInputError(f"balance mass {spec!r}: no plane {m['plane']!r} (there is: {', '.join(planes)})")
        try:
            grams, deg = float(m["grams"]), float(m["deg"])
            radius = float(m["radius"]) * 1e-3 if m["radius"] else radius_m
        except ValueError:
            raise BadInputError(f"balance mass {spec!r}: GRAMS, DEG and RADIUS_MM are numbers") from None
        if not (np.isfinite(grams) and grams > 0 and np.isfinite(deg) and np.isfinite(radius) and radius > 0):
            raise BadInputError(f"balance mass {spec!r}: the mass and the radius must be above 0, the angle finite")
        return cls(m["plane"], grams, deg, radius)


def plane_unbalance(base: dict[str, complex], masses: list[BalanceMass]) -> dict[str, complex]:
    """Each plane's unbalance (kg m, phasor) after ``masses`` are added to ``base``."""
    out = dict(base)
    for mass in masses:
        out[mass.plane] = out[mass.plane] + mass.unbalance
    return out
