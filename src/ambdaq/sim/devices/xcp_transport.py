"""The simulated XCP slave's transport layers (ASAM XCP Part 3): how its packets travel.

On TCP (Ethernet) and on SxI (a serial line, here a pseudo-terminal) each packet is framed LEN
(u16) CTR (u16) PACKET on a byte stream, the SxI header format LEN_CTR_WORD without checksum
(:class:`StreamTransport` over a :class:`TcpLink` or a :class:`PtyLink`); on CAN a packet is one
classic frame's data, master to slave on one identifier and slave to master on another, with
MAX_CTO = MAX_DTO = 8 (:class:`CanTransport`).  The protocol layer above is :mod:`.xcp`'s.
"""

from __future__ import annotations

import os
import select
import socket

import numpy as np

from ...drivers.xcp.wire import HEADER

MAX_CTO = 255  # on TCP and SxI
MAX_DTO = 1024
READ_WAIT_S, WRITE_WAIT_S = 0.1, 0.5


class TcpLink:
    """One master's TCP connection: bytes in and out."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn
        conn.settimeout(READ_WAIT_S)

    def read(self) -> bytes | None:
        """What came (b"" for nothing yet); None when the master closed the connection."""
        try:
            return self.conn.recv(65536) or None
        except socket.timeout:
            return b""
        except OSError:
            return None

    def write(self, data: bytes) -> None:
        self.conn.sendall(data)


class PtyLink:
    """The slave's end of a serial line, a pseudo-terminal's master: bytes in and out."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def read(self) -> bytes | None:
        r, _, _ = select.select([self.fd], [], [], READ_WAIT_S)
        if not r:
            return b""
        try:
            return os.read(self.fd, 65536)
        except OSError:
            return None

    def write(self, data: bytes) -> None:
        """Write ``data``; OSError when the line takes nothing for WRITE_WAIT_S (no master reads
        it any more: a line, unlike a socket, does not say when its other end went away)."""
        view = memoryview(data)
        while view:
            _, w, _ = select.select([], [self.fd], [], WRITE_WAIT_S)
            if not w:
                raise OSError("the master reads no more")
            view = view[os.write(self.fd, view[:4096]) :]


class StreamTransport:
    """XCP on TCP and on SxI (LEN_CTR_WORD, no checksum): each packet framed LEN CTR PACKET on a
    byte stream (ASAM XCP Part 3)."""

    max_cto, max_dto = MAX_CTO, MAX_DTO

    def __init__(self, link: TcpLink | PtyLink) -> None:
        self.link = link
        self._buf = b""

    def packets(self) -> list[bytes] | None:
        """The packets that came (none yet: []); None when the link closed."""
        chunk = self.link.read()
        if chunk is None:
            return None
        self._buf += chunk
        out = []
        while len(self._buf) >= HEADER.size:
            length, _ctr = HEADER.unpack_from(self._buf)
            if len(self._buf) < HEADER.size + length:
                break
            out.append(self._buf[HEADER.size : HEADER.size + length])
            self._buf = self._buf[HEADER.size + length :]
        return out

    def send(self, packet: bytes, ctr: int) -> None:
        self.link.write(HEADER.pack(len(packet), ctr) + packet)

    def send_dtos(self, rows: list[np.ndarray], included: np.ndarray, ctr: int) -> None:
        """The DTO ``rows`` (one array per ODT, a period per row, its header's CTR still to fill) of
        the periods ``included`` samples, numbered from ``ctr``."""
        n, k = included.shape
        number = ((ctr + np.cumsum(included.ravel()) - 1) & 0xFFFF).astype("<u2").reshape(n, k)
        for j, row in enumerate(rows):
            row[:, 2:4] = number[:, j : j + 1].view(np.uint8)
        # one packet per ODT per period that samples it, in order of period, then list and ODT
        keep = np.concatenate([np.repeat(included[:, j : j + 1], r.shape[1], axis=1) for j, r in enumerate(rows)],
                              axis=1)
        self.link.write(np.concatenate(rows, axis=1)[keep].tobytes())


class CanTransport:
    """XCP on CAN (ASAM XCP Part 3): a packet per frame, no header, master to slave on
    ``id_master``, slave to master on ``id_slave``; MAX_CTO = MAX_DTO = 8."""

    max_cto = max_dto = 8

    def __init__(self, bus, id_master: int, id_slave: int) -> None:
        self.bus, self.id_master, self.id_slave = bus, id_master, id_slave

    def packets(self) -> list[bytes]:
        msg = self.bus.recv(READ_WAIT_S)
        return [bytes(msg.data)] if msg is not None and msg.arbitration_id == self.id_master else []

    def send(self, packet: bytes, _ctr: int) -> None:
        import can

        self.bus.send(can.Message(arbitration_id=self.id_slave, data=packet, is_extended_id=self.id_slave > 0x7FF))

    def send_dtos(self, rows: list[np.ndarray], included: np.ndarray, _ctr: int) -> None:
        for i in range(included.shape[0]):
            for j in np.flatnonzero(included[i]):
                self.send(rows[j][i, HEADER.size :].tobytes(), 0)
