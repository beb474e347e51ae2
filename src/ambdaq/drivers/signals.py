"""Signal groups and sample blocks: the seam between devices and the recorder.

A device declares the signal groups it produces (:class:`SignalGroup`, one MCAP topic each) and
then yields :class:`SampleBlock` objects: a run of consecutive sample instants with the device's
clock, its sequence numbers, and one ``(n, n_fields)`` array per group.  The recorder never knows
whether a block came from the in-process simulator or from a driver on a real bus.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np


HEADER_FIELDS = ("device_time", "seq", "status")
"""The members every ambdaq message begins with (:mod:`ambdaq.mcap.schema`): no signal's field."""
ROS_FIELD = re.compile(r"[a-z](?:[a-z0-9]|_(?!_))*(?<!_)")
"""A field name ROS 2 and Foxglove accept: lower case, no double or trailing underscore."""


def ros_field(name: str) -> str:
    """``name`` (a DBC signal's, an A2L measurement's, an EDS object's) as a field name ROS 2 and
    Foxglove accept: ``[a-z][a-z0-9_]*`` without a double or trailing underscore (``HU_date_year``
    -> ``hu_date_year``, ``Motor.Speed`` -> ``motor_speed``, ``gapX`` -> ``gap_x``), and not one of
    the :data:`HEADER_FIELDS` (a signal ``Status`` -> ``status_value``)."""
    text = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)
    text = re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")
    text = text if text[:1].isalpha() else ("f_" + text).rstrip("_")
    return text + "_value" if text in HEADER_FIELDS else text


def field_problem(name: str) -> str | None:
    """Why ``name`` cannot be a recorded field (a rig file's ``field = ...``), or None."""
    if name in HEADER_FIELDS:
        return f"field {name!r} is a member every message has ({', '.join(HEADER_FIELDS)})"
    if not ROS_FIELD.fullmatch(name):
        return f"field {name!r} is not a ROS 2 field name (lower case letters, digits, single underscores)"
    return None


def ros_type(name: str) -> str:
    """``name`` as a message type name ROS 2 accepts: ``[A-Z][A-Za-z0-9]*`` (``DbcMessage63big_1``
    -> ``DbcMessage63big1``)."""
    text = "".join(p[:1].upper() + p[1:] for p in re.split(r"[^A-Za-z0-9]+", name) if p)
    return text if text[:1].isalpha() else "T" + text


FIELD_TYPES = {"float64": "<f8", "int64": "<i8", "uint64": "<u8"}  # ros2msg type -> its CDR (little-endian) dtype


@dataclass(frozen=True)
class SignalGroup:
    """One group of signals sampled at the same instants, recorded as one MCAP topic.

    Parameters
    ----------
    topic : str
        MCAP topic, e.g. ``"/amb/gap"``.
    type_name : str
        Message type name, e.g. ``"Gap"``; the schema is ``ambdaq_msgs/msg/<type_name>``.
    fields : tuple of str
        Field names, named after the rig's axes (``front_x`` ...).
    units : tuple of str
        SI unit of each field (``m``, ``A``, ``m/s^2``, ``rad`` ...).
    types : tuple of str, optional
        The ros2msg type of each field, one of :data:`FIELD_TYPES`; empty (the default) where
        every field is ``float64``.  A 64-bit integer (a DBC signal of 54 bits and more, an A2L
        A_INT64 or A_UINT64 recorded as its raw value) is ``int64`` or ``uint64``: float64 holds
        integers exactly only up to 2**53.
    """

    topic: str
    type_name: str
    fields: tuple[str, ...]
    units: tuple[str, ...]
    types: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if len(self.fields) != len(self.units):
            raise ValueError(f"{self.topic}: {len(self.fields)} fields but {len(self.units)} units")
        if self.types and (len(self.types) != len(self.fields) or not set(self.types) <= set(FIELD_TYPES)):
            raise ValueError(f"{self.topic}: field types {self.types} are not one of {', '.join(FIELD_TYPES)} per field")
        problems = [p for p in map(field_problem, self.fields) if p] + (
            [f"fields repeat: {', '.join(self.fields)}"] if len(set(self.fields)) != len(self.fields) else [])
        if problems:
            raise ValueError(f"{self.topic}: {problems[0]}")
        if self.types and set(self.types) == {"float64"}:
            object.__setattr__(self, "types", ())  # one spelling of "all float64"

    @property
    def field_types(self) -> tuple[str, ...]:
        """The ros2msg type of every field (``float64`` where :attr:`types` is empty)."""
        return self.types or ("float64",) * len(self.fields)

    @property
    def value_dtype(self) -> np.dtype:
        """The dtype of one sample's values: ``(n_fields,) float64``, or a packed structured dtype
        naming each field where the group has 64-bit integer fields (every member is 8 bytes, so
        the CDR layout is the same size and alignment either way)."""
        if not self.types:
            return np.dtype(("<f8", (len(self.fields),)))
        return np.dtype([(f, FIELD_TYPES[t]) for f, t in zip(self.fields, self.types)])

    def values_array(self, rows: "list[list] | list[tuple]") -> np.ndarray:
        """``rows`` (one list of Python numbers per sample, in field order) as the group's values:
        an ``(n, n_fields)`` float64 array, or an ``(n,)`` structured array of :attr:`value_dtype`
        whose integer fields hold Python ints exactly."""
        if not self.types:
            return np.array(rows, dtype=np.float64).reshape(len(rows), len(self.fields))
        return np.array([tuple(r) for r in rows], dtype=self.value_dtype)

    def values_from_columns(self, columns: list[np.ndarray]) -> np.ndarray:
        """One array per field (each of n samples, in field order) as the group's values (see
        :meth:`values_array`)."""
        n = columns[0].shape[0] if columns else 0
        if not self.types:
            return np.stack(columns, axis=1) if columns else np.empty((n, 0))
        out = np.empty(n, dtype=self.value_dtype)
        for f, c in zip(self.fields, columns):
            out[f] = c
        return out



@dataclass(frozen=True)
class SampleBlock:
    """Consecutive samples of one device.

    Parameters
    ----------
    device_time_ns : ndarray of int64, shape (n,)
        Sample instants on the device's clock, in ns.
    seq : ndarray of uint32, shape (n,)
        Device sequence numbers; a gap means lost samples.
    values : dict of str to ndarray
        One array per topic, SI units: ``(n, n_fields)`` float64 with columns in the order of the
        group's ``fields``, or for a group with 64-bit integer fields an ``(n,)`` structured array
        of its :attr:`SignalGroup.value_dtype` (:meth:`SignalGroup.values_array` builds either).
    host_time_ns : ndarray of int64, shape (n,)
        Sample instants mapped to the host clock, in ns (MCAP ``log_time``); set by the recorder.
    received_ns : int, optional
        Host time at which the block's last sample arrived, in ns: what the recorder's clock map
        learns the device clock from.  ``None`` for in-process sources that share the host clock.
    status : ndarray of uint32, shape (n,), optional
        Device status word of each sample (the messages' ``status`` field), 0 if not given.
    """

    device_time_ns: np.ndarray
    seq: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    host_time_ns: np.ndarray | None = None
    received_ns: int | None = None
    status: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.device_time_ns.shape[0])

    def slice(self, start: int, stop: int) -> "SampleBlock":
        """Samples ``start`` to ``stop`` (exclusive) of this block."""
        return self.select(slice(start, stop))

    def select(self, which: "slice | np.ndarray") -> "SampleBlock":
        """The samples ``which`` picks (a slice, a boolean mask or indices), in order."""
        return SampleBlock(
            self.device_time_ns[which],
            self.seq[which],
            {k: v[which] for k, v in self.values.items()},
            None if self.host_time_ns is None else self.host_time_ns[which],
            self.received_ns,
            None if self.status is None else self.status[which],
        )


@dataclass(frozen=True)
class Event:
    """Something a device or bus reported: a fault, an error frame, a bus-state change, a gap.

    Parameters
    ----------
    device_time_ns : int
        When, on the device clock (ns); 0 if the device gave no time.
    kind : str
        ``fault``, ``error-frame``, ``bus-state``, ``reconnect`` ...
    code : int
        Device or protocol code (EMCY code, NAK code ...), 0 if none.
    text : str
        What happened, in words.
    topic : str
        Where it is recorded: ``/amb/events`` for device events, ``/can/bus`` for the bus's.
    """

    device_time_ns: int
    kind: str
    code: int
    text: str
    topic: str = "/amb/events"
