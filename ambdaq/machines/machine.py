"""What a recording says about the machine it was made on, for any machine: its radial bearings
(each a pair of gap axes ``NAME_x``, ``NAME_y``), its other (axial) axes, the minimum clearance
and the amplifier's current limit its controller reports. The host side takes its bearings and
axes from here, never from one machine's constants, so a blower with ``de_x/de_y/nde_x/nde_y/thrust``
is read as the spindle's ``front_x ... axial`` is.

One home for pairing a bearing's axes: ``NAME_x`` with ``NAME_y`` (an engineer's naming; a rig
file can name the fields so).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

CMIN_KEY = "machine.min_clearance_m"  # in a device's calibration: the touchdown bearings' radial clearance, m
CURRENT_LIMIT_KEY = "machine.current_limit_a"  # the amplifier's current limit, A
AXIAL_KEY = "machine.axial_axes"  # the gap axes along the spin axis, comma-separated (the cone's "x")


@dataclass(frozen=True)
class Bearing:
    """A radial bearing: its name and its two gap axes."""

    name: str
    x: str
    y: str


def radial_bearings(axes: Sequence[str]) -> list[Bearing]:
    """Every radial bearing among ``axes`` (field names): each ``NAME_x`` whose ``NAME_y`` is there
    too, in the order of the x axes."""
    present = set(axes)
    return [Bearing(a[:-2], a, a[:-2] + "_y") for a in axes if a.endswith("_x") and a[:-2] + "_y" in present]


def orbit_partner(axis: str, axes: Sequence[str]) -> str | None:
    """The other radial axis of ``axis``'s bearing (``front_x`` <-> ``front_y``), or None."""
    for b in radial_bearings(axes):
        if axis == b.x:
            return b.y
        if axis == b.y:
            return b.x
    return None


@dataclass(frozen=True)
class Machine:
    """A machine as its recording describes it.

    Attributes
    ----------
    axes : tuple of str
        Its gap axes, in the order recorded.
    bearings : tuple of Bearing
        The radial bearings among them.
    axial : tuple of str
        The axes along the spin axis (thrust, axial): those a device declares (AXIAL_KEY), else
        those of no radial bearing.
    radial : tuple of str
        The other axes, in the order recorded (the bearings' x and y, or radial axes named
        otherwise, as the cone's y1, z1).
    cmin_m : float or None
        Minimum clearance, m, if a device reports it.
    current_limit_a : float or None
        The amplifier's current limit, A, if a device reports it.
    """

    axes: tuple[str, ...]
    bearings: tuple[Bearing, ...]
    axial: tuple[str, ...]
    radial: tuple[str, ...]
    cmin_m: float | None = None
    current_limit_a: float | None = None

    @classmethod
    def from_axes(cls, axes: Sequence[str], calibrations: Sequence[Mapping[str, str]] = ()) -> Machine:
        """The machine of gap ``axes`` (field names) and its devices' ``calibrations``."""
        bearings = tuple(radial_bearings(axes))
        paired = {a for b in bearings for a in (b.x, b.y)}
        declared = next((c[AXIAL_KEY] for c in calibrations if AXIAL_KEY in c), None)
        if declared is not None:
            along = {a.strip() for a in declared.split(",")}
            axial = tuple(a for a in axes if a in along)
        else:
            axial = tuple(a for a in axes if a not in paired) if bearings else ()

        def first(key: str) -> float | None:
            return next((float(c[key]) for c in calibrations if key in c), None)

        return cls(tuple(axes), bearings, axial, tuple(a for a in axes if a not in axial), first(CMIN_KEY),
                   first(CURRENT_LIMIT_KEY))

    @classmethod
    def from_metadata(cls, axes: Sequence[str], metadata: Mapping[str, Mapping[str, str]]) -> Machine:
        """The machine of gap ``axes`` and a recording's metadata (its devices' calibrations)."""
        return cls.from_axes(axes, [m for name, m in sorted(metadata.items()) if name.startswith("ambdaq.calibration.")])

    @property
    def bearing_axes(self) -> tuple[str, ...]:
        """The radial bearings' axes, bearing by bearing (x, y)."""
        return tuple(a for b in self.bearings for a in (b.x, b.y))


__all__ = ["AXIAL_KEY", "Bearing", "CMIN_KEY", "CURRENT_LIMIT_KEY", "Machine", "orbit_partner", "radial_bearings"]
