"""A simulated socketcand gateway: a CAN bus served over TCP in socketcand's raw mode, as a
Raspberry Pi or an industrial PC beside the machine serves its CAN interface to the lab network.

The host side is python-can's ``socketcand`` interface (or socketcand's own client), in any
process: with it, CAN devices whose samples are timed by the bus (EDS devices, whose replies are
matched to their SYNC by time) cross a process boundary with bus time stamps, which an SLCAN
adapter does not give.  The protocol is socketcand's (``doc/protocol.md`` of linux-can/socketcand),
the subset a raw-mode client uses::

    server: < hi >                       client: < open CHANNEL >      server: < ok >
    client: < rawmode >                  server: < ok >
    server: < frame ID SECS.USECS DATA >   every frame on the bus (ID 3 hex digits, 8 if extended)
    client: < send ID LEN B0 B1 ... >      a frame to put on the bus

Like socketcand, the gateway does not return a frame the client sends, and stamps the others
with its own clock: ``clock_offset_s`` sets that clock apart from the host's, as a gateway's
clock is, so that a client is seen to map the gateway's time rather than trust it.  The server
listens on 127.0.0.1 only and serves one client at a time.
"""

from __future__ import annotations

import re
import socket
import threading
import time

import can

SEND = re.compile(r"< send ([0-9A-Fa-f]{1,8}) ([0-9A-Fa-f]) ((?:[0-9A-Fa-f]{1,2} ?){0,8})>")
RAWMODE_SETTLE_S = 0.05
"""Pause between the ``< ok >`` to ``< rawmode >`` and the first frame: python-can's client reads
that ``< ok >`` with one ``recv`` and fails if a frame shares the segment."""


def frame_text(msg: can.Message, stamp_s: float) -> str:
    """The ``< frame ... >`` line of ``msg`` at the gateway time ``stamp_s`` (s), as socketcand
    writes it (``state_raw.c``: ``%03X`` or ``%08X``, ``%lld.%06lld``, the data as ``%02X`` each)."""
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    whole = int(stamp_s)
    return f"< frame {ident} {whole}.{int(round((stamp_s - whole) * 1e6)):06d} {bytes(msg.data).hex().upper()} >"


class SimSocketcand:
    """A socketcand gateway for python-can's virtual bus ``channel``, on 127.0.0.1.

    Parameters
    ----------
    channel : str
        python-can virtual channel of the simulated bus.
    port : int
        TCP port; 0 picks a free one (see :attr:`port`).
    clock_offset_s : float
        The gateway clock's offset from the host clock, in s.
    """

    def __init__(self, channel: str, port: int = 0, clock_offset_s: float = 0.0) -> None:
        self.channel, self.clock_offset_s = channel, clock_offset_s
        self._server = socket.create_server(("127.0.0.1", port))
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="sim-socketcand", daemon=True)
        self.sent = self.received = self.refused = 0  # frames to the client, from it, lines not understood

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._server.close()
        self._thread.join(timeout=2.0)

    def _serve(self) -> None:
        self._server.settimeout(0.2)
        while not self._stop.is_set():
            try:
                conn, _addr = self._server.accept()
            except (TimeoutError, OSError):
                continue
            with conn:
                self._session(conn)

    def _session(self, conn: socket.socket) -> None:
        """One client: the handshake, then frames both ways until it closes."""
        conn.sendall(b"< hi >")
        buffer = ""
        state = "open"
        bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        conn.settimeout(0.001)
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                    if not data:
                        return
                    buffer += data.decode("ascii", errors="replace")
                except TimeoutError:
                    pass
                while ">" in buffer:
                    line, _, buffer = buffer.partition(">")
                    line = line[line.find("<"):] + ">"
                    if state == "open" and line.startswith("< open "):
                        conn.sendall(b"< ok >")
                        state = "rawmode"
                    elif state == "rawmode" and line == "< rawmode >":
                        conn.sendall(b"< ok >")
                        time.sleep(RAWMODE_SETTLE_S)
                        state = "raw"
                    elif state == "raw" and (m := SEND.fullmatch(line)):
                        data_bytes = bytes(int(b, 16) for b in m.group(3).split())
                        ident = int(m.group(1), 16)
                        bus.send(can.Message(arbitration_id=ident, data=data_bytes[: int(m.group(2), 16)],
                                             is_extended_id=len(m.group(1)) > 3 or ident > 0x7FF))
                        self.received += 1
                    else:
                        self.refused += 1
                        conn.sendall(b"< error bad command >")
                if state == "raw":
                    out = []
                    while (msg := bus.recv(0)) is not None:
                        out.append(frame_text(msg, msg.timestamp + self.clock_offset_s))
                    if out:
                        conn.sendall("".join(out).encode())
                        self.sent += len(out)
        except OSError:
            return
        finally:
            bus.shutdown()
