"""XCP on TCP as the test's own small slaves read it (ASAM XCP Part 3: each packet LEN CTR PACKET,
LEN and CTR little-endian words): written here, not taken from ambdaq, so that the master's framing
is checked against an independent reading."""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator


def commands(conn: socket.socket) -> Iterator[bytes]:
    """Each command packet the master sends on ``conn``, until it closes the connection."""
    buf = b""
    while True:
        while len(buf) < 4 or len(buf) < 4 + struct.unpack_from("<H", buf)[0]:
            data = conn.recv(4096)
            if not data:
                return
            buf += data
        n = struct.unpack_from("<H", buf)[0]
        packet, buf = buf[4 : 4 + n], buf[4 + n :]
        yield packet
