"""The ambdaq serial protocol: message types carried in COBS/CRC-32 frames (docs/protocol.md).

Every frame body starts with ``type u8, flags u8, seq u16`` (little-endian); ``seq`` counts the
sender's frames modulo 2^16, so the receiver counts lost frames from its gaps.

=====  ==================  =====  ==========================================================
type   name                dir    body after the 4-byte header
=====  ==================  =====  ==========================================================
0x01   IDENTIFY            h->d   (empty)
0x02   IDENTITY            d->h   UTF-8 JSON: model, serial, firmware, sample rate, groups
0x10   PARAM_READ          h->d   name (u8 length, UTF-8)
0x11   PARAM_WRITE         h->d   name, count u16, count x f64
0x12   PARAM_VALUE         d->h   request seq u16, name, count u16, count x f64
0x13   ACK                 d->h   request seq u16
0x14   NAK                 d->h   request seq u16, code u16, message (u8 length, UTF-8)
0x20   STREAM              h->d   enable u8
0x30   SAMPLES             d->h   first sample index u32, device time of the first sample i64
                                  (ns), period u32 (ns), n u16, channels u16, n x channels f32
0x40   FAULT               d->h   code u16, severity u8, device time i64, message
0x41   HEARTBEAT           d->h   device time i64 (ns) stamped as it is written, state u8
0x42   TIME_REQUEST        h->d   host time t1 i64 (ns) stamped as it is written
0x43   TIME_REPLY          d->h   t1 i64, device receive time t2 i64, device send time t3 i64
0x50   UNLOCK              h->d   key (u8 length, UTF-8); ACK or NAK LOCKED
0x51   BANK_WRITE          h->d   offset u32, image length u32, bytes (to the inactive bank)
0x52   BANK_COMMIT         h->d   expected CRC-32 u32, UTF-8 JSON push record; ACK carries the
                                  first sample index run with the new bank (u32 after the seq)
0x53   BANK_STATUS         h->d   (empty); answered by BANK_INFO
0x54   BANK_INFO           d->h   request seq u16, UTF-8 JSON: active bank, CRC-32s, log
0x55   BANK_READ           h->d   which u8 (0 active, 1 inactive), offset u32, length u16
0x56   BANK_DATA           d->h   request seq u16, offset u32, bytes
=====  ==================  =====  ==========================================================

HEARTBEATs give the host (device time, arrival) pairs for the clock's drift; TIME_REQUEST /
TIME_REPLY give the round trip (t4 - t1) - (t3 - t2), half of whose minimum is the one-way
latency the host subtracts from the mapping (NTP's symmetric-path assumption).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

HEADER = struct.Struct("<BBH")
SAMPLES_HEAD = struct.Struct("<IqIHH")


class MsgType(IntEnum):
    IDENTIFY = 0x01
    IDENTITY = 0x02
    PARAM_READ = 0x10
    PARAM_WRITE = 0x11
    PARAM_VALUE = 0x12
    ACK = 0x13
    NAK = 0x14
    STREAM = 0x20
    SAMPLES = 0x30
    FAULT = 0x40
    HEARTBEAT = 0x41
    TIME_REQUEST = 0x42
    TIME_REPLY = 0x43
    UNLOCK = 0x50
    BANK_WRITE = 0x51
    BANK_COMMIT = 0x52
    BANK_STATUS = 0x53
    BANK_INFO = 0x54
    BANK_READ = 0x55
    BANK_DATA = 0x56


class NakCode(IntEnum):
    """Why a device refused a request."""

    UNKNOWN_PARAMETER = 1
    BAD_VALUE = 2
    READ_ONLY = 3
    BAD_REQUEST = 4
    LOCKED = 5
    BUSY = 6
    CRC_MISMATCH = 7


REPLIES = (MsgType.ACK, MsgType.NAK, MsgType.PARAM_VALUE, MsgType.BANK_INFO, MsgType.BANK_DATA)
"""Messages that answer a request: their body starts with the request's sequence number."""
BANK_CHUNK = 192  # image bytes per BANK_WRITE
BANK_WRITE_HEAD = struct.Struct("<II")
BANK_READ_HEAD = struct.Struct("<BIH")


@dataclass(frozen=True)
class Frame:
    """A decoded frame: its type, sender sequence number and body (after the header)."""

    type: int
    seq: int
    body: bytes


def pack(msg_type: MsgType, seq: int, body: bytes = b"") -> bytes:
    """A frame body: header + ``body``; ``seq`` is taken modulo 2^16."""
    return HEADER.pack(msg_type, 0, seq & 0xFFFF) + body


def unpack(raw: bytes) -> Frame:
    """Split a frame body into header fields and payload; ``ValueError`` if too short."""
    if len(raw) < HEADER.size:
        raise ValueError("frame shorter than its header")
    t, _flags, seq = HEADER.unpack_from(raw)
    return Frame(t, seq, raw[HEADER.size :])


def _name(name: str) -> bytes:
    b = name.encode()
    if len(b) > 255:
        raise ValueError(f"parameter name too long: {name!r}")
    return bytes([len(b)]) + b


def _read_name(body: bytes, pos: int) -> tuple[str, int]:
    n = body[pos]
    return body[pos + 1 : pos + 1 + n].decode(), pos + 1 + n


def encode_values(values: np.ndarray) -> bytes:
    v = np.asarray(values, dtype="<f8").ravel()
    return struct.pack("<H", v.shape[0]) + v.tobytes()


def decode_values(body: bytes, pos: int) -> np.ndarray:
    (count,) = struct.unpack_from("<H", body, pos)
    end = pos + 2 + 8 * count
    if end > len(body):
        raise ValueError("value array runs past the frame")
    return np.frombuffer(body, dtype="<f8", count=count, offset=pos + 2).copy()


def param_read(name: str) -> bytes:
    return _name(name)


def param_write(name: str, values) -> bytes:
    return _name(name) + encode_values(np.asarray(values, dtype=float))


def parse_param_request(body: bytes) -> tuple[str, np.ndarray | None]:
    """(name, values) of a PARAM_READ (values None) or PARAM_WRITE body."""
    name, pos = _read_name(body, 0)
    return name, (decode_values(body, pos) if pos < len(body) else None)


def param_value(request_seq: int, name: str, values) -> bytes:
    return struct.pack("<H", request_seq) + _name(name) + encode_values(np.asarray(values, dtype=float))


def parse_param_value(body: bytes) -> tuple[int, str, np.ndarray]:
    (req,) = struct.unpack_from("<H", body, 0)
    name, pos = _read_name(body, 2)
    return req, name, decode_values(body, pos)


def ack(request_seq: int) -> bytes:
    return struct.pack("<H", request_seq)


def nak(request_seq: int, code: NakCode, message: str) -> bytes:
    return struct.pack("<HH", request_seq, code) + _name(message[:255])


def parse_nak(body: bytes) -> tuple[int, int, str]:
    req, code = struct.unpack_from("<HH", body, 0)
    msg, _ = _read_name(body, 4)
    return req, code, msg


def identity(info: dict) -> bytes:
    return json.dumps(info, separators=(",", ":")).encode()


def samples(first_index: int, device_time_ns: int, period_ns: int, values: np.ndarray) -> bytes:
    """A SAMPLES body for ``values`` of shape (n, channels), sent as float32."""
    n, c = values.shape
    return SAMPLES_HEAD.pack(first_index & 0xFFFFFFFF, device_time_ns, period_ns, n, c) + np.ascontiguousarray(
        values, dtype="<f4"
    ).tobytes()


@dataclass(frozen=True)
class Samples:
    """A decoded SAMPLES body."""

    first_index: int
    device_time_ns: int
    period_ns: int
    values: np.ndarray  # (n, channels) float64


def parse_samples(body: bytes) -> Samples:
    first, t0, period, n, c = SAMPLES_HEAD.unpack_from(body, 0)
    if len(body) != SAMPLES_HEAD.size + 4 * n * c:
        raise ValueError(f"SAMPLES body is {len(body)} bytes, expected {SAMPLES_HEAD.size + 4 * n * c}")
    vals = np.frombuffer(body, dtype="<f4", count=n * c, offset=SAMPLES_HEAD.size).reshape(n, c)
    return Samples(first, t0, period, vals.astype(np.float64))


def fault(code: int, severity: int, device_time_ns: int, message: str) -> bytes:
    return struct.pack("<HBq", code, severity, device_time_ns) + _name(message[:255])


def parse_fault(body: bytes) -> tuple[int, int, int, str]:
    code, severity, t = struct.unpack_from("<HBq", body, 0)
    msg, _ = _read_name(body, 11)
    return code, severity, t, msg


def heartbeat(device_time_ns: int, state: int) -> bytes:
    return struct.pack("<qB", device_time_ns, state)


def time_request(t1_ns: int) -> bytes:
    return struct.pack("<q", t1_ns)


def time_reply(t1_ns: int, t2_ns: int, t3_ns: int) -> bytes:
    return struct.pack("<qqq", t1_ns, t2_ns, t3_ns)


def parse_time_reply(body: bytes) -> tuple[int, int, int]:
    return struct.unpack_from("<qqq", body, 0)


def unlock(key: str) -> bytes:
    return _name(key)


def parse_unlock(body: bytes) -> str:
    return _read_name(body, 0)[0]


def bank_write(offset: int, total: int, data: bytes) -> bytes:
    return BANK_WRITE_HEAD.pack(offset, total) + data


def parse_bank_write(body: bytes) -> tuple[int, int, bytes]:
    offset, total = BANK_WRITE_HEAD.unpack_from(body, 0)
    return offset, total, body[BANK_WRITE_HEAD.size :]


def bank_commit(crc: int, record: dict) -> bytes:
    return struct.pack("<I", crc) + json.dumps(record, separators=(",", ":")).encode()


def parse_bank_commit(body: bytes) -> tuple[int, dict]:
    (crc,) = struct.unpack_from("<I", body, 0)
    return crc, json.loads(body[4:].decode() or "{}")


def parse_json(body: bytes, what: str) -> dict:
    """A body that holds a JSON object (IDENTITY, BANK_STATUS); ValueError naming ``what`` if its
    bytes are not UTF-8 JSON of an object (a peer's CRC-valid junk)."""
    try:
        doc = json.loads(bytes(body).decode())
    except ValueError:  # UnicodeDecodeError and JSONDecodeError alike
        raise ValueError(f"its {what} is not JSON text ({len(body)} bytes)") from None
    if not isinstance(doc, dict):
        raise ValueError(f"its {what} is JSON but not an object")
    return doc


def ack_value(request_seq: int, value: int) -> bytes:
    """An ACK that carries a u32 result (BANK_COMMIT: the first sample run with the new bank)."""
    return struct.pack("<HI", request_seq, value & 0xFFFFFFFF)


def bank_info(request_seq: int, info: dict) -> bytes:
    return struct.pack("<H", request_seq) + json.dumps(info, separators=(",", ":")).encode()


def bank_read(which: int, offset: int, length: int) -> bytes:
    return BANK_READ_HEAD.pack(which, offset, length)


def parse_bank_read(body: bytes) -> tuple[int, int, int]:
    return BANK_READ_HEAD.unpack_from(body, 0)


def bank_data(request_seq: int, offset: int, data: bytes) -> bytes:
    return struct.pack("<HI", request_seq, offset) + data
