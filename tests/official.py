"""What a file holds according to the official MCAP stream reader and decoders only (``mcap``,
``mcap-ros2-support``, ``mcap-protobuf-support``, ``json``): no ambdaq code decides it.

:func:`official` gives, per topic, every message's log time, publish time, sequence and every
numeric leaf of the decoded message by path (``pose.position.x``, ``ranges[3]``); the tests compare
ambdaq's readers and exports against it, bit for bit.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

HEADER = ("device_time", "seq", "status")  # the leading members of every ambdaq message


def _leaves(value, path: str, out: dict) -> None:
    """Numeric leaves of a decoded message by path (booleans as 0/1), written here on its own."""
    if isinstance(value, bool):
        out[path] = int(value)
    elif isinstance(value, (int, float, np.integer, np.floating)):
        out[path] = value
    elif isinstance(value, (list, tuple, bytes, bytearray, np.ndarray)):
        for i, item in enumerate(value):
            _leaves(item, f"{path}[{i}]", out)
    elif isinstance(value, dict):
        for key, item in value.items():
            _leaves(item, f"{path}.{key}" if path else str(key), out)
    elif hasattr(value, "DESCRIPTOR") and hasattr(value, "ListFields"):  # protobuf: every field, set or not
        for f in value.DESCRIPTOR.fields:
            item = getattr(value, f.name)
            repeated = f.is_repeated if hasattr(f, "is_repeated") else f.label == f.LABEL_REPEATED
            _leaves(list(item) if repeated else item, f"{path}.{f.name}" if path else f.name, out)
    elif hasattr(value, "__slots__") or hasattr(value, "__dict__"):
        for key in getattr(value, "__slots__", None) or [k for k in vars(value) if not k.startswith("_")]:
            _leaves(getattr(value, key), f"{path}.{key}" if path else key, out)


class Topic:
    """One topic as the official reader gives it: log times, publish times, sequences, and each
    numeric leaf's values (Python numbers, as decoded) by path."""

    def __init__(self) -> None:
        self.log_time: list[int] = []
        self.publish_time: list[int] = []
        self.sequence: list[int] = []
        self.values: dict[str, list] = defaultdict(list)
        self.count = 0

    def add(self, log_time: int, publish_time: int, sequence: int, leaves: dict) -> None:
        for key in leaves.keys() - self.values.keys():  # a leaf first seen here: absent before
            self.values[key] = [None] * self.count
        for key, column in self.values.items():
            column.append(leaves.get(key))
        self.log_time.append(log_time)
        self.publish_time.append(publish_time)
        self.sequence.append(sequence)
        self.count += 1


def official(path: Path, topics: list[str] | None = None) -> dict[str, Topic]:
    """Every decodable message of ``path`` (of ``topics``), in the file's order, through the
    official stream reader (every record in order: it needs no index, and reads the conformance
    variants whose summary does not repeat the channels, where the official seeking reader fails)
    and decoders, with CRCs validated; a topic no official decoder reads is left out."""
    from mcap.reader import NonSeekingReader
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    class JsonDecoders:
        def decoder_for(self, message_encoding, schema):
            return json.loads if message_encoding == "json" else None

    factories = [Ros2Decoders(), ProtobufDecoders(), JsonDecoders()]
    decoders: dict[int, object] = {}
    out: dict[str, Topic] = {}
    with open(path, "rb") as fh:
        reader = NonSeekingReader(fh, validate_crcs=True)
        for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=False):
            if channel.id not in decoders:  # as iter_decoded_messages picks one, but a topic none reads is left out
                decoders[channel.id] = None
                for factory in factories:
                    try:
                        decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                    except Exception:  # a schema the official decoder cannot parse: it reads none of it
                        break
                    if decoders[channel.id] is not None:
                        break
            decode = decoders[channel.id]
            if decode is None:
                continue
            leaves: dict = {}
            _leaves(decode(message.data), "", leaves)
            out.setdefault(channel.topic, Topic()).add(message.log_time, message.publish_time, message.sequence, leaves)
    return out


def message_counts(path: Path) -> dict[str, int]:
    """Messages per topic as the official reader counts them (every message, decodable or not)."""
    from mcap.reader import NonSeekingReader

    counts: dict[str, int] = defaultdict(int)
    with open(path, "rb") as fh:
        for _schema, channel, _message in NonSeekingReader(fh, validate_crcs=True).iter_messages(log_time_order=False):
            counts[channel.topic] += 1
    return dict(counts)


def as_array(values: list, like: np.ndarray | None = None) -> np.ndarray:
    """A column of decoded values as numpy, in the dtype ``like`` has (a float64 field stays
    float64, a 64-bit integer stays exact), None as NaN."""
    if like is not None and like.dtype.kind in "iu":
        return np.array(values, dtype=like.dtype)
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bit for bit (a NaN equals the same NaN, -0.0 is not 0.0)."""
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    if a.shape != b.shape or a.dtype.itemsize != b.dtype.itemsize:
        return False
    kind = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}[a.dtype.itemsize]
    return bool(np.array_equal(a.view(kind), b.view(kind)))
