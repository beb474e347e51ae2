"""COBS framing with CRC-32: round trips, corruption, resynchronisation."""

import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ambdaq.drivers.serial.framing import FrameDecoder, cobs_decode, cobs_encode, encode_frame

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


@settings(deadline=None)  # the first call compiles the numba kernels
@given(st.binary(max_size=2000))
def test_cobs_round_trip_and_no_zero_bytes(data):
    enc = cobs_encode(data)
    assert 0 not in enc
    assert cobs_decode(enc) == data
    assert len(enc) <= len(data) + len(data) // 254 + 1


def test_cobs_reference_vectors():
    # from the COBS paper / Wikipedia examples
    assert cobs_encode(b"\x00") == b"\x01\x01"
    assert cobs_encode(b"\x00\x00") == b"\x01\x01\x01"
    assert cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert cobs_encode(b"\x11\x22\x33\x44") == b"\x05\x11\x22\x33\x44"
    assert cobs_encode(bytes(range(1, 255))) == b"\xff" + bytes(range(1, 255))
    assert cobs_encode(b"\x00" + bytes(range(1, 255))) == b"\x01\xff" + bytes(range(1, 255))
    assert cobs_encode(bytes(range(1, 256))) == b"\xff" + bytes(range(1, 255)) + b"\x02\xff"


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(min_size=1, max_size=300), min_size=1, max_size=20), st.integers(1, 64))
def test_decoder_reassembles_frames_split_anywhere(bodies, chunk):
    wire = b"".join(encode_frame(b) for b in bodies)
    dec = FrameDecoder()
    got = []
    for i in range(0, len(wire), chunk):
        got += dec.feed(wire[i : i + chunk])
    assert got == bodies and dec.stats.rejected == 0


def test_corrupted_frames_are_counted_and_dropped_then_resync():
    rng = random.Random(7)
    bodies = [struct.pack("<I", i) + bytes(rng.randrange(256) for _ in range(40)) for i in range(500)]
    frames = [bytearray(encode_frame(b)) for b in bodies]
    damaged = set()
    for i in range(0, 500, 5):  # flip one bit inside every fifth frame (never the delimiter)
        pos = rng.randrange(len(frames[i]) - 1)
        frames[i][pos] ^= 1 << rng.randrange(8)
        if frames[i][pos] == 0:  # a flip that makes a new delimiter splits the frame in two
            frames[i][pos] ^= 0x80
        damaged.add(i)
    wire = b"".join(bytes(f) for f in frames)
    wire = b"\x13\x37garbage" + wire[:1000] + b"\xff" * 50 + wire[1000:]  # garbage and a burst
    dec = FrameDecoder()
    got = dec.feed(wire)
    # every delivered frame is a good one, in order
    good = [b for i, b in enumerate(bodies) if i not in damaged]
    assert all(g in good for g in got)
    assert len(got) >= len(good) - 2  # the burst may take out the frame it landed in
    assert dec.stats.rejected >= len(damaged)


def test_truncated_frame_is_rejected():
    f = encode_frame(b"hello world, a sample block")
    dec = FrameDecoder()
    assert dec.feed(f[:10] + b"\x00" + f) == [b"hello world, a sample block"]
    assert dec.stats.rejected == 1
