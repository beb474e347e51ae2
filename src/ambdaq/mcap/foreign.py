"""Topics of MCAP files ambdaq did not write (rosbag2, Foxglove, any MCAP writer), read through the
official decoders into the same :class:`~ambdaq.mcap.reader.TopicData` as ambdaq's own, so that
``load``, ``export`` and ``plot`` take them.

A ros2msg/CDR message is decoded by ``mcap-ros2-support``, a protobuf one by
``mcap-protobuf-support`` (what Foxglove's SDK and many robotics stacks write), a JSON one by the
standard library.
Its numeric fields (integers, floats, booleans as 0/1), nested and in arrays, become one column
each named by its path (``pose.position.x``, ``ranges[3]``, ``new_parameters[0].value.type``);
an element missing from a message (a shorter array) is NaN there.  Anything else (strings,
arrays beyond :data:`MAX_ELEMENTS`, columns beyond :data:`MAX_COLUMNS`) is listed in the topic's
``skipped`` and left out.  This is the slow path, one Python call per message (about 10^4
messages a second here): ambdaq's own fixed-layout topics are read block by block.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator

import numpy as np

from ..errors import BadInputError
from .mcapfile import McapFile

MAX_ELEMENTS = 1024  # elements of one array made columns; a longer one (an image, a point cloud) is skipped
MAX_COLUMNS = 4096  # columns of one topic
DECODABLE = {("ros2msg", "cdr"), ("protobuf", "protobuf"), ("jsonschema", "json"), ("", "json")}
"""(schema encoding, message encoding) pairs an official decoder here reads."""


def foreign_topics(f: McapFile, own: set[str]) -> dict[str, int]:
    """Topics of ``f`` that are not in ambdaq's layout (``own``) and that an official decoder reads:
    topic -> channel id.  A ros2msg schema the official decoder cannot parse (a service's
    definition with its ``---``, say) leaves its topic out, as the official reader could not
    decode it either."""
    out = {}
    for cid, ch in f.summary.channels.items():
        schema = f.summary.schemas.get(ch.schema_id)
        encoding = schema.encoding if schema is not None else ""
        if ch.topic not in own and (encoding, ch.message_encoding) in DECODABLE and _parses(schema, ch.message_encoding):
            out[ch.topic] = cid
    return out


def _parses(schema, message_encoding: str) -> bool:
    """Whether the official decoder builds a decoder for ``schema`` (ros2msg; the others parse
    their schemas per message)."""
    if schema is None or schema.encoding != "ros2msg":
        return True
    from mcap_ros2.decoder import DecoderFactory

    try:
        return DecoderFactory().decoder_for(message_encoding, schema) is not None
    except Exception:  # whatever the ROS 2 message parser says of a definition it cannot read
        return False


def _flatten(value, path: str, out: dict[str, float], skipped: set[str]) -> None:
    """The numeric leaves of a decoded message into ``out`` by path; other leaves' paths into ``skipped``."""
    if isinstance(value, bool):
        out[path] = float(value)
    elif isinstance(value, (int, float, np.integer, np.floating)):
        out[path] = float(value)
    elif isinstance(value, (bytes, bytearray, list, tuple, np.ndarray)):
        if len(value) > MAX_ELEMENTS:
            skipped.add(f"{path} ({len(value)} elements, over {MAX_ELEMENTS})")
            return
        for i, item in enumerate(value):
            _flatten(item, f"{path}[{i}]", out, skipped)
    elif isinstance(value, dict):
        for key, item in value.items():
            _flatten(item, f"{path}.{key}" if path else str(key), out, skipped)
    elif hasattr(value, "DESCRIPTOR") and hasattr(value, "ListFields"):  # a protobuf message: every field
        for f in value.DESCRIPTOR.fields:
            item = getattr(value, f.name)
            repeated = f.is_repeated if hasattr(f, "is_repeated") else f.label == f.LABEL_REPEATED  # protobuf 7 / older
            _flatten(list(item) if repeated else item, f"{path}.{f.name}" if path else f.name,
                     out, skipped)
    elif hasattr(value, "__slots__") or hasattr(value, "__dict__"):
        names = getattr(value, "__slots__", None) or list(vars(value))
        for key in names:
            _flatten(getattr(value, key), f"{path}.{key}" if path else key, out, skipped)
    elif value is not None:
        skipped.add(f"{path} ({type(value).__name__})")


def _messages(f: McapFile, topics: list[str], lo: int | None, hi: int | None) -> Iterator[tuple]:
    """(topic, log_time, publish_time, sequence, decoded message) in file order."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
    from mcap_ros2.decoder import DecoderFactory

    class JsonDecoders:
        def decoder_for(self, message_encoding, schema):
            return (lambda data: json.loads(data)) if message_encoding == "json" else None

    with open(f.path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory(), ProtobufDecoders(), JsonDecoders()])
        try:
            for _schema, channel, message, decoded in reader.iter_decoded_messages(
                    topics=topics, start_time=lo, end_time=None if hi is None else hi + 1, log_time_order=True):
                yield channel.topic, message.log_time, message.publish_time, message.sequence, decoded
        except BadInputError:
            raise
        except Exception as err:  # the official reader's and decoders' errors, whatever their class
            raise BadInputError(f"{f.path}: cannot decode its messages ({type(err).__name__}: {err}); "
                                "try: ambdaq recover") from None


def load_foreign(f: McapFile, topics: list[str], lo: int | None, hi: int | None) -> dict[str, dict]:
    """The ``topics`` of ``f`` (foreign, see :func:`foreign_topics`) between host times ``lo`` and
    ``hi`` (ns, None: open), each as the columns of a TopicData: ``log_time``, ``device_time`` (the
    publish time), ``seq`` (the message sequence), ``fields`` by path and ``skipped``."""
    rows: dict[str, list] = {t: [] for t in topics}
    skipped: dict[str, set[str]] = {t: set() for t in topics}
    for topic, log_time, publish_time, sequence, decoded in _messages(f, topics, lo, hi):
        flat: dict[str, float] = {}
        _flatten(decoded, "", flat, skipped[topic])
        rows[topic].append((log_time, publish_time, sequence, flat))
    out = {}
    for topic in topics:
        got = rows[topic]
        columns: dict[str, None] = {}
        for *_head, flat in got:
            for key in flat:
                if key not in columns and len(columns) < MAX_COLUMNS:
                    columns[key] = None
                elif key not in columns:
                    skipped[topic].add(f"{key} (over {MAX_COLUMNS} columns)")
        n = len(got)
        fields = {key: np.full(n, math.nan) for key in columns}
        for i, (*_head, flat) in enumerate(got):
            for key, value in flat.items():
                column = fields.get(key)
                if column is not None:
                    column[i] = value
        out[topic] = {"log_time": np.array([r[0] for r in got], dtype=np.int64),
                      "device_time": np.array([r[1] for r in got], dtype=np.int64),
                      "seq": np.array([r[2] for r in got], dtype=np.int64).astype(np.uint32),
                      "fields": fields, "skipped": tuple(sorted(skipped[topic]))}
    return out


class NotFixed(Exception):
    """A topic whose schema has a fixed layout, but whose messages the block reader cannot take as
    they are (a chunk without a message index, a payload of another size or byte order): it is
    read through the official decoder instead."""


def fixed_topics(f: McapFile, own: set[str]) -> dict[str, tuple[int, np.dtype]]:
    """Topics of ``f`` of other writers whose ros2msg schema has a fixed CDR layout
    (:func:`~.cdr_layout.fixed_layout`): topic -> (channel id, record dtype of the payload)."""
    from .cdr_layout import fixed_layout

    out = {}
    for cid, ch in f.summary.channels.items():
        schema = f.summary.schemas.get(ch.schema_id)
        if ch.topic in own or schema is None or (schema.encoding, ch.message_encoding) != ("ros2msg", "cdr"):
            continue
        dtype = fixed_layout(schema.name, schema.data.decode(errors="replace"))
        if dtype is not None:
            out[ch.topic] = (cid, dtype)
    return out


MESSAGE_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log time, publish time


def load_fixed(f: McapFile, topic: str, cid: int, layout: np.dtype, lo: int | None, hi: int | None) -> dict:
    """One fixed-layout topic of another writer read in blocks: each chunk decompressed once, its
    message index's records gathered, every record checked (opcode, channel, length, log time,
    CDR header) and its fields copied out by the layout; the columns as :func:`load_foreign` gives
    them (64-bit integers exact).  NotFixed where the messages are not as the layout says."""
    from .cdr_layout import ENCAPSULATION

    head = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                     ("log_time", "<u8"), ("publish_time", "<u8"), ("cdr", "u1", (ENCAPSULATION,))])
    size = MESSAGE_HEAD + ENCAPSULATION + layout.itemsize
    parts = []
    for ci in sorted(f.chunks, key=lambda c: c.message_start_time):
        if (lo is not None and ci.message_end_time < lo) or (hi is not None and ci.message_start_time > hi):
            continue
        if cid not in ci.message_index_offsets:
            if ci.message_index_length == 0:
                raise NotFixed(f"{topic}: a chunk without message indexes")
            continue
        index = f.message_index(ci, cid)
        if not index.shape[0]:
            continue
        records = np.frombuffer(f.chunk_records(ci), dtype=np.uint8)
        offsets = index["offset"].astype(np.int64)
        if int(offsets.max()) + size > records.shape[0] or int(offsets.min()) < 0:
            raise BadInputError(f"{f.path}: a message index of {topic} points past its chunk; try: ambdaq recover")
        rows = np.ascontiguousarray(records[offsets[:, None] + np.arange(size)])
        h = rows[:, : head.itemsize].copy().view(head).ravel()
        # a payload may carry up to 3 bytes of CDR padding beyond the layout (its length is aligned to 4)
        payload = h["length"].astype(np.int64) - (MESSAGE_HEAD - 9)
        if not (np.all(h["opcode"] == 0x05) and np.all(h["channel"] == cid)
                and np.array_equal(h["log_time"], index["log_time"])):
            raise BadInputError(f"{f.path}: a message index of {topic} does not point at its messages; try: ambdaq recover")
        if np.any(payload < ENCAPSULATION + layout.itemsize) or np.any(payload > ENCAPSULATION + layout.itemsize + 3):
            raise NotFixed(f"{topic}: a message of another size than its schema's layout")
        if not (np.all(h["cdr"][:, 0] == 0) and np.all(h["cdr"][:, 1] == 1)):
            raise NotFixed(f"{topic}: a message not in little-endian plain CDR")
        parts.append((h, rows[:, MESSAGE_HEAD + ENCAPSULATION:].copy().view(layout).ravel()))
    h = np.concatenate([p[0] for p in parts]) if parts else np.empty(0, head)
    values = np.concatenate([p[1] for p in parts]) if parts else np.empty(0, layout)
    order = np.argsort(h["log_time"], kind="stable")  # as the official reader gives them: in log time
    h, values = h[order], values[order]
    keep = np.ones(h.shape[0], dtype=bool)
    if lo is not None:
        keep &= h["log_time"] >= lo
    if hi is not None:
        keep &= h["log_time"] <= hi
    h, values = h[keep], values[keep]
    fields = {}
    for name in layout.names:
        column = values[name]
        fields[name] = column.astype(column.dtype.newbyteorder("=")) if column.dtype.kind in "iu" and \
            column.dtype.itemsize == 8 else column.astype(np.float64)
    return {"log_time": h["log_time"].astype(np.int64), "device_time": h["publish_time"].astype(np.int64),
            "seq": h["sequence"].astype(np.uint32), "fields": fields, "skipped": ()}


__all__ = ["DECODABLE", "MAX_COLUMNS", "MAX_ELEMENTS", "NotFixed", "fixed_topics", "foreign_topics", "load_fixed",
           "load_foreign"]
