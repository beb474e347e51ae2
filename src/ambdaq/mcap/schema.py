"""Message schemas: ros2msg text and the fixed CDR layout of every ambdaq message.

Every topic carries one message per sample instant with the same fixed layout::

    int64   device_time   # device clock, ns
    uint32  seq           # device sequence number
    uint32  status        # device status bits, 0 = ok
    float64 <field>       # one per signal, SI units (int64 or uint64 for a 64-bit integer)

Encoded as little-endian CDR (4-byte encapsulation header ``00 01 00 00``), every member is
naturally aligned with no padding, so a message is a fixed-size byte record and a whole block of
messages is one numpy structured array.  Foxglove and ``mcap-ros2-support`` decode it from the
ros2msg schema stored in the file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..drivers.signals import FIELD_TYPES, SignalGroup

SCHEMA_PACKAGE = "ambdaq_msgs/msg"
CDR_LE_HEADER = 0x00000100  # bytes 00 01 00 00 read as little-endian uint32
# MCAP Message record: opcode u8, length u64, channel_id u16, sequence u32, log_time u64,
# publish_time u64, then the payload
MESSAGE_OPCODE = 0x05
MESSAGE_HEADER_SIZE = 1 + 8 + 2 + 4 + 8 + 8


@dataclass(frozen=True)
class TopicLayout:
    """The wire layout of one signal group's messages.

    Parameters
    ----------
    group : SignalGroup
        The signal group (topic, fields, units).
    """

    group: SignalGroup

    @property
    def schema_name(self) -> str:
        return f"{SCHEMA_PACKAGE}/{self.group.type_name}"

    @property
    def schema_text(self) -> str:
        lines = [
            f"# {self.group.topic}: one message per sample instant, SI units",
            "int64 device_time  # device clock, ns",
            "uint32 seq  # device sequence number",
            "uint32 status  # device status bits, 0 = ok",
        ]
        g = self.group
        lines += [f"{t} {f}  # {u}" for t, f, u in zip(g.field_types, g.fields, g.units)]
        return "\n".join(lines) + "\n"

    @property
    def payload_size(self) -> int:
        return 20 + 8 * len(self.group.fields)

    @property
    def message_dtype(self) -> np.dtype:
        """Packed structured dtype of one whole MCAP Message record (header and payload)."""
        return np.dtype(self.record_dtype())

    def record_dtype(self, prefix: str = "") -> list[tuple[str, str]]:
        """Fields of one whole MCAP Message record (header + payload), names prefixed."""
        return [
            (prefix + "opcode", "u1"),
            (prefix + "length", "<u8"),
            (prefix + "channel", "<u2"),
            (prefix + "sequence", "<u4"),
            (prefix + "log_time", "<u8"),
            (prefix + "publish_time", "<u8"),
            (prefix + "cdr_header", "<u4"),
            (prefix + "device_time", "<i8"),
            (prefix + "seq", "<u4"),
            (prefix + "status", "<u4"),
            (prefix + "values", self.group.value_dtype),
        ]


def parse_schema(name: str, text: str) -> SignalGroup | None:
    """Recover the signal group from an ambdaq ros2msg schema; ``None`` if it is not one of ours."""
    if not name.startswith(SCHEMA_PACKAGE + "/"):
        return None
    members = []
    for line in text.splitlines():
        body, _, comment = line.partition("#")
        parts = body.split()
        if len(parts) == 2:
            members.append((parts[0], parts[1], comment.strip()))
    head = [(t, n) for t, n, _ in members[:3]]
    if head != [("int64", "device_time"), ("uint32", "seq"), ("uint32", "status")]:
        return None
    values = members[3:]
    if not values or any(t not in FIELD_TYPES for t, _, _ in values):
        return None
    topic = text.splitlines()[0].lstrip("# ").split(":")[0] if text.startswith("#") else ""
    try:
        return SignalGroup(
            topic=topic,
            type_name=name.rsplit("/", 1)[-1],
            fields=tuple(n for _, n, _ in values),
            units=tuple(c for _, _, c in values),
            types=tuple(t for t, _, _ in values),
        )
    except ValueError:  # field names ambdaq never writes (a damaged schema): not one of ours
        return None


EVENT_SCHEMA_NAME = f"{SCHEMA_PACKAGE}/Event"
EVENT_SCHEMA_TEXT = """# events: device faults, CAN error frames and bus-state changes, reconnects
int64 device_time  # device clock, ns (0 if the device gave none)
string device  # device name in the rig
string kind  # fault, error-frame, bus-state, reconnect ...
uint32 code  # device or protocol code
string text  # what happened
"""


def _cdr_string(out: bytearray, text: str) -> None:
    while len(out) % 4:  # align the length to 4, counted from the end of the encapsulation header
        out.append(0)
    data = text.encode() + b"\x00"
    out += len(data).to_bytes(4, "little") + data


def encode_event(device_time_ns: int, device: str, kind: str, code: int, text: str) -> bytes:
    """CDR payload (with its encapsulation header) of one Event message."""
    out = bytearray(int(device_time_ns).to_bytes(8, "little", signed=True))
    _cdr_string(out, device)
    _cdr_string(out, kind)
    while len(out) % 4:
        out.append(0)
    out += int(code).to_bytes(4, "little")
    _cdr_string(out, text)
    return CDR_LE_HEADER.to_bytes(4, "little") + bytes(out)
