"""A machine as its recording describes it, for any machine: its radial bearings (each a pair of
gap axes), its axial axes, where each signal role is recorded, the minimum clearance, the
amplifier's limits, the sensor gain and the rotor's constants.  The host side takes its bearings,
axes and signals from here, never from one machine's constants, so a blower whose probes are
``de_x, de_y, nde_x, nde_y, thrust`` is read as the spindle's ``front_x ... axial`` is.

Where the description comes from (:meth:`Machine.describe`), first to last:

* the devices that know: ambdaq's controllers declare ``machine.*`` and ``rotor.*`` entries in
  their calibration, and record each role on its topic (:data:`ambdaq.roles.ROLE_TOPICS`) with
  fields named after the axes;
* a rig file's ``[machine]`` table (docs/device-urls.md): an id, the bearings, the axial axes, the
  limits, the rigid rotor's constants (``[machine.rigid_rotor]``), and for devices no one here
  wrote which recorded field plays which role: ``gap.de_x = "/xcp/mainloop.probe_de_x"``
  (``TOPIC.FIELD``, as ``ambdaq info`` lists them; ``rotor.angle`` and ``rotor.speed`` for the
  key-phasor).

The recorder writes the result into every recording (metadata ``ambdaq.machine``,
:meth:`Machine.record`); a recording made before that is described from its devices' calibration
in the same way.

One home for pairing a bearing's axes: ``NAME_x`` with ``NAME_y`` unless the description names
the pairs.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from ..analysis.rotor import RigidRotor
from ..errors import BadInputError
from ..roles import ROLE_TOPICS, ROTOR_FIELDS

CMIN_KEY = "machine.min_clearance_m"  # in a device's calibration: the touchdown bearings' radial clearance, m
CURRENT_LIMIT_KEY = "machine.current_limit_a"  # the amplifier's current limit, A
VOLTAGE_LIMIT_KEY = "machine.voltage_limit_v"  # the amplifier's supply: the coil voltage's limit, V
SENSOR_GAIN_KEY = "machine.sensor_gain_v_per_m"  # the gap sensors' gain, V/m
AXIAL_KEY = "machine.axial_axes"  # the gap axes along the spin axis, comma-separated (the cone's "x")
BEARINGS_KEY = "machine.bearings"  # the radial bearings' axes where not NAME_x/NAME_y: "NAME=X/Y, ..." (the cone's)
ID_KEY = "machine.id"  # the machine's identity in a fleet (a rig file's [device.calibration] or [machine] id)
RECORD = "ambdaq.machine"  # the metadata record a recording describes its machine in
MASS_KEY = "machine.rotor_mass_kg"  # the rotor's mass, kg, where no rigid rotor is described
LIMITS = {"min_clearance_m": CMIN_KEY, "current_limit_a": CURRENT_LIMIT_KEY, "voltage_limit_v": VOLTAGE_LIMIT_KEY,
          "sensor_gain_v_per_m": SENSOR_GAIN_KEY, "rotor_mass_kg": MASS_KEY}  # a [machine] key -> its calibration entry
TABLE_KEYS = ("id", "bearings", "axial", "rigid_rotor", *LIMITS, *ROLE_TOPICS)


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


def orbit_partner(axis: str, bearings: Sequence[Bearing]) -> str | None:
    """The other radial axis of ``axis``'s bearing (``front_x`` <-> ``front_y``), or None."""
    for b in bearings:
        if axis == b.x:
            return b.y
        if axis == b.y:
            return b.x
    return None


@dataclass(frozen=True)
class Role:
    """Where one signal role is recorded: a topic, and each axis's field in it (in axis order).

    A role's axes come from one topic: its samples are one instant each, so a bearing's x and y
    are read at the same instant."""

    topic: str
    fields: Mapping[str, str]  # axis -> the recorded field

    @property
    def axes(self) -> tuple[str, ...]:
        return tuple(self.fields)

    @property
    def renamed(self) -> bool:
        """Some axis is recorded under another name."""
        return any(a != f for a, f in self.fields.items())


@dataclass(frozen=True)
class Machine:
    """A machine as its recording describes it.

    Attributes
    ----------
    axes : tuple of str
        Its gap axes, in the order of the gap role.
    bearings : tuple of Bearing
        The radial bearings among them.
    axial : tuple of str
        The axes along the spin axis (thrust, axial): those the description declares, else those
        of no radial bearing.
    radial : tuple of str
        The other axes, in order (the bearings' x and y, or radial axes named otherwise, as the
        cone's y1, z1).
    cmin_m : float or None
        Minimum clearance (the touchdown bearings'), m.
    current_limit_a : float or None
        The amplifier's current limit, A.
    voltage_limit_v : float or None
        The amplifier's supply, the coil voltage's limit, V.
    sensor_gain_v_per_m : float or None
        The gap sensors' gain, V/m.
    rotor_mass_kg : float or None
        The rotor's mass, kg (the rigid rotor's where described).
    rotor : RigidRotor or None
        The rigid rotor on its bearings, where the description gives its constants.
    roles : mapping of str to Role
        Where each signal role (:data:`ambdaq.roles.ROLE_TOPICS`) is recorded.
    id : str or None
        The machine's identity in a fleet.
    """

    axes: tuple[str, ...]
    bearings: tuple[Bearing, ...]
    axial: tuple[str, ...]
    radial: tuple[str, ...]
    cmin_m: float | None = None
    current_limit_a: float | None = None
    voltage_limit_v: float | None = None
    sensor_gain_v_per_m: float | None = None
    rotor_mass_kg: float | None = None
    rotor: RigidRotor | None = None
    roles: Mapping[str, Role] = field(default_factory=dict)
    id: str | None = None

    # --- building one -----------------------------------------------------------------------------

    @classmethod
    def describe(cls, topics: Mapping[str, Sequence[str]], calibrations: Sequence[Mapping[str, str]] = (),
                 table: Mapping | None = None, where: str = "[machine]") -> Machine:
        """The machine the devices declare, with a rig file's ``[machine]`` table over it.

        Parameters
        ----------
        topics : mapping of str to sequence of str
            The recorded topics and their fields.
        calibrations : sequence of mapping
            The devices' calibrations (``machine.*``, ``rotor.*`` entries), first one first.
        table : mapping, optional
            A rig file's ``[machine]`` table (keys :data:`TABLE_KEYS`).
        where : str
            Where the table is, for messages.

        Raises
        ------
        BadInputError
            The table names a topic or field no device records, pairs axes the gap role does not
            have, or holds a value of the wrong kind: one line naming the key.
        """
        table = dict(table or {})
        bad = sorted(set(table) - set(TABLE_KEYS))
        if bad:
            raise BadInputError(f"{where}: unknown key {bad[0]!r} (keys: {', '.join(TABLE_KEYS)})")
        roles = {}
        for role, topic in ROLE_TOPICS.items():
            if role in table:
                roles[role] = _mapped_role(role, table[role], topics, where)
            elif topic in topics:
                names = ROTOR_FIELDS if role == "rotor" else tuple(topics[topic])
                roles[role] = Role(topic, {n: n for n in names if n in topics[topic]})
        axes = roles["gap"].axes if "gap" in roles else ()

        def first(key: str) -> str | None:
            return next((c[key] for c in calibrations if key in c), None)

        if "bearings" in table:
            bearings = tuple(_bearings(table["bearings"], axes, where))
        elif first(BEARINGS_KEY) is not None:
            bearings = tuple(_declared_bearings(first(BEARINGS_KEY), axes))
        else:
            bearings = tuple(radial_bearings(axes))
        paired = {a for b in bearings for a in (b.x, b.y)}
        declared = table.get("axial")
        if declared is None and first(AXIAL_KEY) is not None:
            declared = [a.strip() for a in first(AXIAL_KEY).split(",")]
        if declared is not None:
            if isinstance(declared, str) or not all(isinstance(a, str) for a in declared):
                raise BadInputError(f"{where}: axial is a list of gap axes, e.g. axial = [\"thrust\"]")
            unknown = [a for a in declared if a not in axes and "axial" in table]
            if unknown:
                raise BadInputError(f"{where}: axial names {unknown[0]!r}, not a gap axis ({', '.join(axes)})")
            axial = tuple(a for a in axes if a in set(declared))
        else:
            axial = tuple(a for a in axes if a not in paired) if bearings else ()
        limits = {}
        for key, entry in LIMITS.items():
            value = table.get(key, first(entry))
            limits[key] = None if value is None else _positive(value, key, where)
        rotor = _rotor(table["rigid_rotor"], where) if "rigid_rotor" in table else _rotor_of(calibrations)
        ident = table.get("id", first(ID_KEY))
        mass = rotor.mass if rotor is not None else limits["rotor_mass_kg"]
        return cls(tuple(axes), bearings, axial, tuple(a for a in axes if a not in axial), limits["min_clearance_m"],
                   limits["current_limit_a"], limits["voltage_limit_v"], limits["sensor_gain_v_per_m"], mass, rotor,
                   roles, None if ident is None else str(ident))

    @classmethod
    def from_record(cls, record: Mapping[str, str]) -> Machine:
        """The machine a recording's ``ambdaq.machine`` record describes (:meth:`record`)."""
        try:
            roles = {r: Role(v["topic"], dict(v["fields"])) for r, v in json.loads(record["roles"]).items()}
            bearings = tuple(Bearing(*b) for b in json.loads(record.get("bearings", "[]")))
            axes = tuple(a for a in record.get("axes", "").split(",") if a)
            axial = tuple(a for a in record.get("axial", "").split(",") if a)
            limits = {k: float(record[k]) if record.get(k) else None for k in LIMITS}
            rotor = RigidRotor.from_metadata(record) if "rotor.mass_kg" in record else None
        except (KeyError, ValueError, TypeError, AttributeError) as err:
            raise BadInputError(f"the recording's machine description ({RECORD}) is damaged ({err})") from None
        return cls(axes, bearings, axial, tuple(a for a in axes if a not in axial), limits["min_clearance_m"],
                   limits["current_limit_a"], limits["voltage_limit_v"], limits["sensor_gain_v_per_m"],
                   limits["rotor_mass_kg"], rotor, roles, record.get("id") or None)

    def record(self) -> dict[str, str]:
        """This description as the ``ambdaq.machine`` metadata record (strings; docs/data-format.md)."""
        out = {"axes": ",".join(self.axes), "axial": ",".join(self.axial),
               "bearings": json.dumps([[b.name, b.x, b.y] for b in self.bearings]),
               "roles": json.dumps({r: {"topic": v.topic, "fields": dict(v.fields)} for r, v in self.roles.items()})}
        if self.id is not None:
            out["id"] = self.id
        for key in LIMITS:
            value = getattr(self, {"min_clearance_m": "cmin_m"}.get(key, key))
            if value is not None:
                out[key] = repr(value)
        if self.rotor is not None:
            out.update(self.rotor.metadata())
        return out

    # --- reading it -------------------------------------------------------------------------------

    @property
    def bearing_axes(self) -> tuple[str, ...]:
        """The radial bearings' axes, bearing by bearing (x, y)."""
        return tuple(a for b in self.bearings for a in (b.x, b.y))

    def role(self, name: str) -> Role | None:
        """Where role ``name`` is recorded, or None."""
        return self.roles.get(name)

    def partner(self, axis: str) -> str | None:
        """The other radial axis of ``axis``'s bearing, or None."""
        return orbit_partner(axis, self.bearings)


def _mapped_role(role: str, entries, topics: Mapping[str, Sequence[str]], where: str) -> Role:
    """A ``[machine]`` role table: ``axis = "TOPIC.FIELD"`` per axis, all on one topic."""
    if not isinstance(entries, Mapping) or not entries:
        raise BadInputError(f"{where}: {role} maps axes to recorded fields, e.g. {role}.de_x = \"/probes/probes.de_x\"")
    topic, fields = None, {}
    for axis, value in entries.items():
        if not isinstance(value, str) or "." not in value:
            raise BadInputError(f"{where}: {role}.{axis} is \"TOPIC.FIELD\" (as ambdaq info lists them), not {value!r}")
        t, f = value.rsplit(".", 1)
        if t not in topics:
            raise BadInputError(f"{where}: {role}.{axis}: no device records {t} (topics: {', '.join(topics)})")
        if f not in topics[t]:
            raise BadInputError(f"{where}: {role}.{axis}: {t} has no field {f!r} (fields: {', '.join(topics[t])})")
        if topic is not None and t != topic:
            raise BadInputError(f"{where}: {role}'s axes come from one topic (one sample instant each), "
                                f"not from {topic} and {t}")
        topic, fields[str(axis)] = t, f
    if role == "rotor" and set(fields) != set(ROTOR_FIELDS):
        raise BadInputError(f"{where}: rotor maps {' and '.join(ROTOR_FIELDS)} (rad, rad/s), not {', '.join(fields)}")
    return Role(topic, fields)


def _bearings(entries, axes: Sequence[str], where: str) -> list[Bearing]:
    """A ``[machine]`` table's ``bearings = [{name = "de", x = "de_x", y = "de_y"}, ...]``."""
    if not isinstance(entries, list) or not all(isinstance(e, Mapping) and set(e) == {"name", "x", "y"} for e in entries):
        raise BadInputError(f"{where}: bearings is a list of {{name, x, y}}, e.g. "
                            "bearings = [{name = \"de\", x = \"de_x\", y = \"de_y\"}]")
    out = []
    for e in entries:
        for a in (e["x"], e["y"]):
            if a not in axes:
                raise BadInputError(f"{where}: bearing {e['name']!r} names {a!r}, not a gap axis ({', '.join(axes)})")
        out.append(Bearing(str(e["name"]), str(e["x"]), str(e["y"])))
    return out


def _declared_bearings(text: str, axes: Sequence[str]) -> list[Bearing]:
    """A device's ``machine.bearings`` (``"1=y1/z1, 2=y2/z2"``): the pairs among ``axes``; a pair
    naming an axis not recorded is left out."""
    out = []
    for item in text.split(","):
        name, _, pair = item.strip().partition("=")
        x, _, y = pair.partition("/")
        if name and x in axes and y in axes:
            out.append(Bearing(name.strip(), x.strip(), y.strip()))
    return out


def _positive(value, key: str, where: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise BadInputError(f"{where}: {key} must be a positive number, not {value!r}")
    return v


def _rotor(table, where: str) -> RigidRotor:
    """A ``[machine.rigid_rotor]`` table: the ``rotor.*`` calibration entries without their prefix."""
    if not isinstance(table, Mapping):
        raise BadInputError(f"{where}: rigid_rotor is a table (mass_kg, jt_kgm2, jp_kgm2, a_m, b_m, kx_n_per_m, "
                            "ki_n_per_a)")
    entries = {f"rotor.{k}": ",".join(repr(float(x)) for x in v) if isinstance(v, list) else str(v)
               for k, v in table.items()}
    try:
        return RigidRotor.from_metadata(entries)
    except ValueError as err:
        raise BadInputError(f"{where}: rigid_rotor: {err}") from None


def _rotor_of(calibrations: Sequence[Mapping[str, str]]) -> RigidRotor | None:
    """The rotor a device's calibration describes (``rotor.*``), or None; a damaged one is None
    here and an error where a computation needs it."""
    for c in calibrations:
        if "rotor.mass_kg" in c:
            try:
                return RigidRotor.from_metadata(c)
            except ValueError:
                return None
    return None


__all__ = ["AXIAL_KEY", "BEARINGS_KEY", "Bearing", "CMIN_KEY", "CURRENT_LIMIT_KEY", "ID_KEY", "Machine", "RECORD", "Role",
           "SENSOR_GAIN_KEY", "VOLTAGE_LIMIT_KEY", "orbit_partner", "radial_bearings"]
