"""The checksums of BUILD_CHECKSUM (ASAM MCD-1 XCP Part 2, BUILD_CHECKSUM, and the A2L's
``CHECKSUM`` of a memory segment), computed on the host to verify what a slave holds."""

from __future__ import annotations

import binascii
import zlib

import numpy as np

ADDS = {"XCP_ADD_11": (1, 1), "XCP_ADD_12": (1, 2), "XCP_ADD_14": (1, 4), "XCP_ADD_22": (2, 2),
        "XCP_ADD_24": (2, 4), "XCP_ADD_44": (4, 4)}
"""ADD_xy: the sum of x-byte elements, kept in y bytes."""


def _crc16_arc(data: bytes) -> int:
    """CRC-16 (XCP_CRC_16): polynomial 0x8005 reflected (0xA001), initial 0, no final XOR."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def checksum(kind: str, data: bytes, byte_order: str = "<") -> int:
    """The checksum ``kind`` (XCP_CRC_16, XCP_CRC_16_CITT, XCP_CRC_32, XCP_ADD_11 ... XCP_ADD_44)
    of ``data``, elements of an ADD in ``byte_order``; ValueError for another kind or a length
    an ADD's elements do not divide."""
    if kind == "XCP_CRC_32":
        return zlib.crc32(data)
    if kind == "XCP_CRC_16_CITT":  # polynomial 0x1021, initial 0xFFFF, not reflected
        return binascii.crc_hqx(data, 0xFFFF)
    if kind == "XCP_CRC_16":
        return _crc16_arc(data)
    if kind in ADDS:
        size, result = ADDS[kind]
        if len(data) % size:
            raise ValueError(f"{kind} sums {size}-byte elements; {len(data)} bytes do not divide")
        elements = np.frombuffer(data, dtype=f"{byte_order}u{size}").astype(np.uint64)
        return int(elements.sum() % (1 << (8 * result)))
    raise ValueError(f"checksum {kind} is not one ambdaq computes")
