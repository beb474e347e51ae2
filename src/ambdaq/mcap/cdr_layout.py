"""Fixed CDR layouts of other writers' ros2msg schemas: where every member of a message type is a
number, a fixed-size array of numbers or a nested type of such (``geometry_msgs/msg/Vector3``, an
IMU's three axes, a custom ``float64 x, int32 n ...``), every message of the topic is the same
byte record, and its fields are read in blocks like ambdaq's own topics instead of one Python call
per message.

The layout follows the OMG CDR encoding of ROS 2 (XCDR1 plain, ``rmw``'s default): after the
4-byte encapsulation header (its second byte gives the byte order: 0 big-endian, 1 little-endian),
each primitive is aligned to its own size counted from the end of that header, a nested type is
laid out member by member in place, and a fixed array ``T[n]`` is n of them back to back with no
length prefix.  A ``string``, a ``wstring``, a sequence ``T[]`` or ``T[<=n]`` or a bounded string
has a length prefix and makes the layout variable: such a topic stays on the official decoder.
"""

from __future__ import annotations

import re

import numpy as np

PRIMITIVES = {"bool": "u1", "byte": "u1", "char": "u1", "uint8": "u1", "int8": "i1", "uint16": "u2", "int16": "i2",
              "uint32": "u4", "int32": "i4", "uint64": "u8", "int64": "i8", "float32": "f4", "float64": "f8"}
ENCAPSULATION = 4  # bytes of the CDR header before the payload
MAX_FIELDS = 4096  # columns of one topic (as foreign.MAX_COLUMNS)
_MEMBER = re.compile(r"^\s*([A-Za-z][\w/]*)(\[(\d*)\])?\s+([A-Za-z]\w*)\s*(=.*)?$")


def _types(text: str, name: str) -> dict[str, list[str]]:
    """The message types a ros2msg schema text defines: its own (``name``), then each ``MSG:``
    section, each as its member lines (comments and constants dropped)."""
    sections = re.split(r"^=+\s*$", text, flags=re.M)
    out: dict[str, list[str]] = {}
    for i, section in enumerate(sections):
        lines = section.strip().splitlines()
        if i == 0:
            key = name
        else:
            if not lines or not lines[0].startswith("MSG:"):
                continue
            key = lines[0][4:].strip()
            lines = lines[1:]
        members = []
        for line in lines:
            body = line.split("#", 1)[0].strip()
            if body:
                members.append(body)
        out[key] = members
    return out


def _resolve(type_name: str, owner: str, types: dict[str, list[str]]) -> str | None:
    """The key of ``type_name`` among ``types`` as ROS 2 resolves it: ``pkg/Name``, ``pkg/msg/Name``,
    or a bare ``Name`` of the owner's package."""
    candidates = [type_name]
    if "/" in type_name:
        pkg, _, base = type_name.rpartition("/")
        candidates += [f"{pkg.split('/')[0]}/msg/{base}", f"{pkg.split('/')[0]}/{base}"]
    else:
        pkg = owner.split("/")[0]
        candidates += [f"{pkg}/msg/{type_name}", f"{pkg}/{type_name}"]
    return next((c for c in candidates if c in types), None)


def fixed_layout(name: str, text: str) -> np.dtype | None:
    """The record of one message of ros2msg type ``name`` (schema ``text``) as a numpy dtype whose
    field names are the members' paths (``position.x``, ``arr[2]``), offsets counted from the start
    of the CDR payload after its encapsulation header, little-endian; None where the layout is not
    fixed (a string, a sequence) or the text cannot be read."""
    types = _types(text, name)
    names: list[str] = []
    formats: list[str] = []
    offsets: list[int] = []
    pos = 0

    def lay(type_key: str, prefix: str, depth: int) -> bool:
        nonlocal pos
        if depth > 16:
            return False
        for member in types.get(type_key, []):
            m = _MEMBER.match(member)
            if m is None:
                return False
            kind, array, count, field, constant = m.groups()
            if constant is not None:  # a constant: no bytes on the wire
                continue
            if array is not None and not count:  # a sequence (T[] or T[<=n]): a length prefix
                return False
            repeat = int(count) if count else 1
            if repeat > MAX_FIELDS:
                return False
            for k in range(repeat):
                path = f"{prefix}{field}" + (f"[{k}]" if array is not None else "")
                if kind in PRIMITIVES:
                    size = int(PRIMITIVES[kind][1])
                    pos = -(-pos // size) * size  # aligned to its own size
                    names.append(path)
                    formats.append("<" + PRIMITIVES[kind])
                    offsets.append(pos)
                    pos += size
                    if len(names) > MAX_FIELDS:
                        return False
                else:
                    nested = _resolve(kind, type_key, types)
                    if nested is None or not lay(nested, path + ".", depth + 1):  # string, wstring, unknown
                        return False
        return True

    if name not in types or not lay(name, "", 0) or not names:
        return None
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": pos})


__all__ = ["ENCAPSULATION", "fixed_layout"]
