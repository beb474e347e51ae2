"""Triggers of a snapshot recording (``ambdaq record --snapshot``): what makes the recorder write the
seconds around an event to a file of its own (docs/live.md).

A trigger is parsed from the text the user gives (:func:`parse_trigger`), armed against the
devices that will be recorded and their machine (their topics and fields, where the machine records
each signal role, its clearance and amplifier limits: an unknown field or a missing clearance is an
error before the recording starts), then shown every written block, with its
samples on the host clock, and every event.  It fires on a rising edge: when its condition turns
true, not for as long as it stays true, so a rotor that sits on its touchdown bearings is one
firing, not ten thousand a second.

Forms (``TOPIC.FIELD`` as ``ambdaq info`` lists them, values in the recording's SI units):

``fault``                 an EMCY (CANopen) or FAULT (the controller's serial line) event
``manual``                SIGUSR1 or Enter on the terminal (armed in every snapshot recording)
``excursion>F``           a bearing's orbit radius sqrt(x^2 + y^2), or an axial gap |z|, beyond F Cmin
                          (ISO 14839-2's minimum clearance: the touchdown bearings')
``touchdown[:LIMIT]``     an amplifier at its limit (|current| or |voltage| within 2 % of it) within
                          20 ms of a gap within 10 % of the clearance (the rotor on its touchdown bearing)
``speed:LO..HI``          the rotor speed enters the band [LO, HI] rpm
``TOPIC.FIELD>V``, ``<V`` a threshold on any field; ``|TOPIC.FIELD|>V`` on its magnitude
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..analysis.touchdown import AT_CLEARANCE, excursions
from ..machines.machine import CMIN_KEY, CURRENT_LIMIT_KEY, VOLTAGE_LIMIT_KEY, Machine, Role
from ..drivers.signals import Event, SampleBlock, SignalGroup
from ..errors import BadInputError
from ..units import RAD_S_TO_RPM
AT_LIMIT = 0.98  # an amplifier output this close to its limit is saturated
TOUCHDOWN_WINDOW_NS = 20_000_000  # saturation and contact this close together are one touchdown
NEVER = -(2**62)  # "no such sample yet", as a time in ns
REARM_NS = 250_000_000  # a condition must have been false this long before it fires again: a revolution
# of anything faster than 240 rpm is shorter, so a once-per-revolution crossing is one firing
FORMS = ("fault, manual, excursion>F (a fraction of Cmin), touchdown[:8A|:25V], speed:LO..HI (rpm), "
         "TOPIC.FIELD>V, TOPIC.FIELD<V, |TOPIC.FIELD|>V")


@dataclass(frozen=True)
class Firing:
    """A trigger that fired.

    Attributes
    ----------
    t_ns : int
        When, on the host clock (ns since the epoch).
    cause : str
        Short and safe in a file name: ``fault``, ``touchdown``, ``speed-20000-25000`` ...
    detail : str
        What happened, in words (stored in the snapshot's metadata).
    """

    t_ns: int
    cause: str
    detail: str


@dataclass(frozen=True)
class Device:
    """What a trigger is armed against: one device's signal groups."""

    name: str
    groups: list[SignalGroup]

    def field(self, topic: str, name: str) -> int | None:
        """Column of ``name`` in ``topic``'s samples, or None."""
        for g in self.groups:
            if g.topic == topic and name in g.fields:
                return g.fields.index(name)
        return None

    def fields(self, topic: str) -> tuple[str, ...]:
        return next((g.fields for g in self.groups if g.topic == topic), ())


class Trigger:
    """Base: a condition on the recorded samples or events (see the module docstring)."""

    text: str

    def arm(self, devices: list[Device], machine: Machine, cmin_m: float | None) -> None:
        """Check that the devices carry what the trigger needs (the machine says where each signal
        role is recorded); a BadInputError names what is missing."""

    def on_block(self, device: str, block: SampleBlock) -> list[Firing]:
        """Firings in a block of written samples (``host_time_ns`` set)."""
        return []

    def on_event(self, device: str, t_ns: int, event: Event) -> list[Firing]:
        """Firings for an event recorded at host time ``t_ns``."""
        return []


class _Edges:
    """Rising edges of a condition evaluated per sample, per device, with a re-arm time: after its
    condition was last true, a trigger fires again only once it has been false for ``REARM_NS`` (an
    orbit just at the limit crosses it every revolution: that is one event, not 500 a second).

    ``entering``: the condition must have been seen false first (a recording that starts inside a
    speed band has not entered it); otherwise a condition true at the first sample fires there (a
    rotor that is on its touchdown bearings when the recording starts).
    """

    def __init__(self, entering: bool = False) -> None:
        self.entering = entering
        self._last: dict[str, bool] = {}
        self._last_true: dict[str, int] = {}  # host time of the device's last sample where it held, ns

    def rising(self, device: str, condition: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
        """Indices of the samples (host times ``t_ns``) where ``condition`` fires."""
        if condition.size == 0:
            return np.empty(0, dtype=np.int64)
        before = self._last.get(device, bool(condition[0]) if self.entering else False)
        self._last[device] = bool(condition[-1])
        previous = np.concatenate(([before], condition[:-1]))
        true = np.flatnonzero(condition)
        out = []
        for i in np.flatnonzero(condition & ~previous).tolist():
            k = int(np.searchsorted(true, i))  # true[k] == i; true[k - 1] the last sample before it that held
            last = int(t_ns[true[k - 1]]) if k > 0 else self._last_true.get(device)
            if last is None or int(t_ns[i]) - last >= REARM_NS:
                out.append(i)
        if true.size:
            self._last_true[device] = int(t_ns[true[-1]])
        return np.array(out, dtype=np.int64)


class FaultTrigger(Trigger):
    """An EMCY or controller FAULT event (``Event.kind == "fault"``)."""

    text = "fault"

    def on_event(self, device: str, t_ns: int, event: Event) -> list[Firing]:
        if event.kind != "fault":
            return []
        return [Firing(t_ns, "fault", f"{device}: {event.text} (code 0x{event.code:04X})")]


class ManualTrigger(Trigger):
    """SIGUSR1 or Enter: fired by the recorder itself (:meth:`Recorder.trigger`), never by samples."""

    text = "manual"


def _cmin(machine: Machine, cmin_m: float | None, what: str) -> float:
    if cmin_m is not None:
        return cmin_m
    if machine.cmin_m is not None:
        return machine.cmin_m
    raise BadInputError(f"--trigger {what}: no minimum clearance in the devices' calibration ({CMIN_KEY}) or the rig "
                        "file's [machine]: pass --cmin UM")


@dataclass(frozen=True)
class GapLayout:
    """Where the machine's gap is in one device's samples: its topic, each radial bearing's (x, y)
    columns and every other axis's column, worked out once when armed, not for every block; and
    the name of each of those places (the bearings, then the other axes)."""

    topic: str
    pairs: tuple[tuple[int, int], ...]
    single: tuple[int, ...]
    names: tuple[str, ...]

    @classmethod
    def of(cls, device: Device, machine: Machine) -> "GapLayout | None":
        role = machine.role("gap")
        names = device.fields(role.topic) if role is not None else ()
        if not names:
            return None
        col = {axis: names.index(f) for axis, f in role.fields.items()}
        others = [a for a in machine.axes if a not in machine.bearing_axes]
        return cls(role.topic, tuple((col[b.x], col[b.y]) for b in machine.bearings), tuple(col[a] for a in others),
                   tuple(b.name for b in machine.bearings) + tuple(others))

    def radii(self, gap: np.ndarray) -> np.ndarray:
        """Per sample, the largest of each radial bearing's orbit radius and each other axis's |gap|, in m."""
        return np.max(excursions(gap, self.pairs, self.single), axis=1)


def amplifier_outputs(device: Device, machine: Machine, given: tuple[str, float] | None = None
                      ) -> tuple[str, list[int], float] | None:
    """(topic, columns, limit) of the amplifier outputs ``device`` records and their limit: ``given``
    (a role, ``current`` or ``voltage``, and its limit in A or V), else the coil currents against
    the machine's current limit, else the coil voltages against its supply; None if neither."""
    known = (("current", machine.current_limit_a), ("voltage", machine.voltage_limit_v))
    for role, limit in [given] if given is not None else known:
        where = _role_columns(device, machine.role(role))
        if where is not None and limit is not None:
            return (*where, limit)
    return None


def _role_columns(device: Device, role: Role | None) -> tuple[str, list[int]] | None:
    """(topic, columns) of ``role``'s axes in ``device``'s samples, or None if it does not record it."""
    if role is None or not device.fields(role.topic):
        return None
    names = device.fields(role.topic)
    return role.topic, [names.index(f) for f in role.fields.values()]


class ExcursionTrigger(Trigger):
    """A gap or orbit beyond ``fraction`` of Cmin, about the bearing's centre (ISO 14839-2 Cmin)."""

    def __init__(self, fraction: float, text: str) -> None:
        if not 0 < fraction <= 1.5:
            raise BadInputError(f"--trigger {text}: the fraction of Cmin must be in (0, 1.5], not {fraction:g}")
        self.fraction, self.text = fraction, text
        self._edges = _Edges()
        self._gaps: dict[str, GapLayout] = {}

    def arm(self, devices: list[Device], machine: Machine, cmin_m: float | None) -> None:
        self._gaps = {d.name: g for d in devices if (g := GapLayout.of(d, machine)) is not None}
        if not self._gaps:
            raise BadInputError(f"--trigger {self.text}: no device records the gap (/amb/gap, or the rig file's "
                                "[machine] gap)")
        self.limit_m = self.fraction * _cmin(machine, cmin_m, self.text)

    def on_block(self, device: str, block: SampleBlock) -> list[Firing]:
        layout = self._gaps.get(device)
        if layout is None or layout.topic not in block.values:
            return []
        r = layout.radii(block.values[layout.topic])
        return [Firing(int(block.host_time_ns[i]), "excursion",
                       f"{device}: gap {r[i] * 1e6:.1f} um beyond {self.limit_m * 1e6:.1f} um "
                       f"({self.fraction:g} Cmin)")
                for i in self._edges.rising(device, r > self.limit_m, block.host_time_ns)]


class TouchdownTrigger(Trigger):
    """An amplifier at its limit within 20 ms of a gap at the clearance: the rotor on its touchdown
    bearing with the controller pulling as hard as it can (a drop, or a lift-off from rest)."""

    def __init__(self, limit: str | None, text: str) -> None:
        self.text = text
        self._given = None
        if limit is not None:
            m = re.fullmatch(r"([0-9.eE+-]+)\s*([AV])", limit)
            if m is None:
                raise BadInputError(f"--trigger {text}: the limit is a current or a voltage, e.g. touchdown:8A "
                                    "or touchdown:25V")
            self._given = ("current" if m.group(2) == "A" else "voltage", float(m.group(1)))
        self._edges = _Edges()
        self._last_contact: int | None = None  # host time of the last sample at the clearance, ns
        self._last_saturation: int | None = None  # and of the last at an amplifier limit
        self._gaps: dict[str, GapLayout] = {}

    def arm(self, devices: list[Device], machine: Machine, cmin_m: float | None) -> None:
        self.clearance_m = _cmin(machine, cmin_m, self.text)
        self._gaps = {d.name: g for d in devices if (g := GapLayout.of(d, machine)) is not None}
        # device -> (topic, columns, limit): the amplifier outputs (current or voltage) and their limit
        self._limits = {d.name: found for d in devices if (found := amplifier_outputs(d, machine, self._given))}
        if not self._limits:
            raise BadInputError(f"--trigger {self.text}: no amplifier limit in the devices' calibration "
                                f"({CURRENT_LIMIT_KEY} with the coil currents, or {VOLTAGE_LIMIT_KEY} with the coil "
                                "voltages) or the rig file's [machine]: give it, e.g. touchdown:8A or touchdown:25V")
        if not self._gaps:
            raise BadInputError(f"--trigger {self.text}: no device records the gap (/amb/gap, or the rig file's "
                                "[machine] gap)")

    def on_block(self, device: str, block: SampleBlock) -> list[Firing]:
        layout, limit = self._gaps.get(device), self._limits.get(device)
        if layout is None and limit is None:
            return []
        t = block.host_time_ns
        never = np.full(t.shape, NEVER, dtype=np.int64)
        contact = saturation = never
        if layout is not None and layout.topic in block.values:
            contact = self._latest(t, layout.radii(block.values[layout.topic]) >= AT_CLEARANCE * self.clearance_m,
                                   self._last_contact)
        elif self._last_contact is not None:
            contact = np.full(t.shape, self._last_contact, dtype=np.int64)
        if limit is not None and limit[0] in block.values:
            saturated = np.max(np.abs(block.values[limit[0]][:, limit[1]]), axis=1) >= AT_LIMIT * limit[2]
            saturation = self._latest(t, saturated, self._last_saturation)
        elif self._last_saturation is not None:
            saturation = np.full(t.shape, self._last_saturation, dtype=np.int64)
        if t.size:
            self._last_contact = None if contact[-1] == NEVER else int(contact[-1])
            self._last_saturation = None if saturation[-1] == NEVER else int(saturation[-1])
        both = (t - contact <= TOUCHDOWN_WINDOW_NS) & (t - saturation <= TOUCHDOWN_WINDOW_NS)
        return [Firing(int(t[i]), "touchdown",
                       f"{device}: an amplifier at its limit with a gap within {100 - AT_CLEARANCE * 100:.0f} % "
                       f"of the clearance ({self.clearance_m * 1e6:.0f} um)")
                for i in self._edges.rising(device, both, t)]

    @staticmethod
    def _latest(t: np.ndarray, condition: np.ndarray, before: int | None) -> np.ndarray:
        """Per sample, the time of the last sample (this block's or earlier) where ``condition`` held."""
        stamped = np.where(condition, t, NEVER)
        start = NEVER if before is None else before
        return np.maximum.accumulate(np.concatenate(([start], stamped)))[1:]


class SpeedTrigger(Trigger):
    """The rotor speed (``/amb/rotor`` speed, rad/s) enters the band [lo, hi] rpm."""

    def __init__(self, lo: float, hi: float, text: str) -> None:
        if not 0 <= lo < hi:
            raise BadInputError(f"--trigger {text}: the band must be LO..HI rpm with 0 <= LO < HI")
        self.lo, self.hi, self.text = lo, hi, text
        self._edges = _Edges(entering=True)
        self._column: dict[str, int] = {}

    def arm(self, devices: list[Device], machine: Machine, cmin_m: float | None) -> None:
        role = machine.role("rotor")
        self._topic = role.topic if role is not None else ""
        self._column = {d.name: c for d in devices if role is not None
                        and (c := d.field(role.topic, role.fields["speed"])) is not None}
        if not self._column:
            raise BadInputError(f"--trigger {self.text}: no device records the rotor speed (the key-phasor's: "
                                "/amb/rotor speed, or the rig file's [machine] rotor)")

    def on_block(self, device: str, block: SampleBlock) -> list[Firing]:
        if device not in self._column or self._topic not in block.values:
            return []
        rpm = block.values[self._topic][:, self._column[device]] * RAD_S_TO_RPM
        inside = (rpm >= self.lo) & (rpm <= self.hi)
        return [Firing(int(block.host_time_ns[i]), f"speed-{self.lo:.0f}-{self.hi:.0f}",
                       f"{device}: {rpm[i]:.0f} rpm entered {self.lo:.0f}..{self.hi:.0f} rpm")
                for i in self._edges.rising(device, inside, block.host_time_ns)]


class ThresholdTrigger(Trigger):
    """``TOPIC.FIELD`` (or its magnitude) above or below a value, in the field's SI unit."""

    def __init__(self, topic: str, field: str, op: str, value: float, magnitude: bool, text: str) -> None:
        self.topic, self.field_name, self.op, self.value, self.magnitude, self.text = (
            topic, field, op, value, magnitude, text)
        self._edges = _Edges()
        self._column: dict[str, int] = {}

    def arm(self, devices: list[Device], machine: Machine, cmin_m: float | None) -> None:
        self._column = {d.name: c for d in devices if (c := d.field(self.topic, self.field_name)) is not None}
        if not self._column:
            known = sorted({f"{g.topic}.{f}" for d in devices for g in d.groups for f in g.fields})
            raise BadInputError(f"--trigger {self.text}: no device records {self.topic}.{self.field_name} "
                                f"(recorded: {', '.join(known[:12])}{' ...' if len(known) > 12 else ''})")
        unit = next(g.units[g.fields.index(self.field_name)] for d in devices for g in d.groups
                    if g.topic == self.topic and self.field_name in g.fields)
        self.unit = unit

    def on_block(self, device: str, block: SampleBlock) -> list[Firing]:
        if device not in self._column or self.topic not in block.values:
            return []
        v = block.values[self.topic][:, self._column[device]]
        if self.magnitude:
            v = np.abs(v)
        hit = v > self.value if self.op == ">" else v < self.value
        name = re.sub(r"[^A-Za-z0-9_]+", "-", f"{self.topic}.{self.field_name}").strip("-")
        return [Firing(int(block.host_time_ns[i]), name,
                       f"{device}: {self.topic}.{self.field_name} = {v[i]:.6g} {self.unit} {self.op} {self.value:g}")
                for i in self._edges.rising(device, hit, block.host_time_ns)]


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def parse_trigger(text: str) -> Trigger:
    """A trigger from its text (see the module docstring); BadInputError (exit 2) if it does not parse."""
    s = text.strip()
    if s == "fault":
        return FaultTrigger()
    if s == "manual":
        return ManualTrigger()
    if m := re.fullmatch(r"touchdown(?::(.+))?", s):
        return TouchdownTrigger(m.group(1), s)
    if m := re.fullmatch(rf"excursion\s*>\s*({_NUMBER})", s):
        return ExcursionTrigger(float(m.group(1)), s)
    if m := re.fullmatch(rf"speed:\s*({_NUMBER})\s*\.\.\s*({_NUMBER})", s):
        return SpeedTrigger(float(m.group(1)), float(m.group(2)), s)
    if m := re.fullmatch(rf"(\|)?\s*(/[\w/]+)\.(\w+)\s*(\|)?\s*([<>])\s*({_NUMBER})", s):
        if bool(m.group(1)) != bool(m.group(4)) or (m.group(1) and m.group(5) != ">"):
            raise BadInputError(f"--trigger {text!r}: a magnitude is written |TOPIC.FIELD|>V")
        return ThresholdTrigger(m.group(2), m.group(3), m.group(5), float(m.group(6)), bool(m.group(1)), s)
    raise BadInputError(f"--trigger {text!r} does not parse: give one of {FORMS}")


__all__ = ["Device", "Firing", "GapLayout", "Trigger", "amplifier_outputs", "parse_trigger", "FaultTrigger", "ManualTrigger", "ExcursionTrigger",
           "TouchdownTrigger", "SpeedTrigger", "ThresholdTrigger"]
