"""XCP transport layers (ASAM MCD-1 XCP Part 3), master side: how packets travel to and from a
slave, parsed here in Python so that no byte a slave sends reaches compiled code.

- Ethernet (TCP and UDP) and SxI with the ``LEN_CTR_WORD`` header and no checksum frame each
  packet as LEN (u16) CTR (u16) PACKET, Intel byte order (Part 3, Ethernet: "the header is
  always Intel"); on UDP a datagram may carry several such messages, on TCP and SxI they follow
  each other on a byte stream.
- CAN carries one packet per frame: master to slave on ``CAN_ID_MASTER``, slave to master on
  ``CAN_ID_SLAVE``; a frame may be padded to its DLC, and there is no counter.

The slave's CTR counts every packet it sends (responses, events and DTOs alike), so a gap in it
is packets lost on the way (:attr:`Link.lost_packets`).  A malformed message (a length of 0, or
longer than the slave's maximum) cannot be skipped on a byte stream, whose framing is then gone:
the link ends with one line.  On UDP the rest of that datagram is counted as malformed and
skipped (:attr:`Link.malformed`), and the next datagram is read as usual.
"""

from __future__ import annotations

import socket
import threading
import time
from abc import ABC, abstractmethod
from collections import deque

from ...errors import DeviceError
from .wire import HEADER

LINK_MAX = 0xFFFF  # the largest LEN a header can state; before CONNECT the slave's limit is unknown
READ_WAIT_S = 0.05  # how long one receive waits, so that a closed link is noticed
MAX_BUFFER = 4 << 20  # bytes held of a stream that does not frame: a slave sending garbage is cut off
SEEN = 1024  # CTRs remembered to tell a datagram delivered twice (the CTR turns every 65,536 packets)


class Link(ABC):
    """A master's end of one transport: send a command packet; receive what the slave sent as
    (CTR or None, arrival ns, packet) messages.

    Attributes
    ----------
    max_packet : int
        The longest packet accepted, in bytes: MAX(CTO, DTO) once connected.
    lost_packets : int
        Packets the slave's CTR says were sent and never arrived.
    duplicates : int
        Packets that arrived twice (the same CTR among the last ones), dropped.
    malformed : int
        Messages that did not parse and were skipped (UDP, CAN).
    """

    has_counter = True
    datagrams = False  # True where the network may deliver a packet twice (UDP)
    max_packet = LINK_MAX

    def __init__(self, url: str) -> None:
        self.url = url
        self.lost_packets = 0
        self.malformed = 0
        self.received = 0
        self.duplicates = 0
        self._ctr: int | None = None
        self._seen: deque[int] = deque()  # the CTRs of the last SEEN packets, and as a set
        self._seen_set: set[int] = set()
        self._tx_ctr = 0
        self._tx_lock = threading.Lock()

    def frame(self, packet: bytes) -> bytes:
        """``packet`` with its LEN CTR header (the master counts its own packets)."""
        with self._tx_lock:
            ctr = self._tx_ctr
            self._tx_ctr = (ctr + 1) & 0xFFFF
        return HEADER.pack(len(packet), ctr) + packet

    def count(self, ctr: int) -> bool:
        """Learn the slave's CTR of one packet: a gap is packets lost on the way.  False for a
        packet whose CTR came already among the last :data:`SEEN` (a datagram the network
        delivered twice: UDP may): it is dropped and counted (:attr:`duplicates`), never taken for
        a sample of its own."""
        if self.datagrams:  # a byte stream (TCP, SxI) delivers each packet once
            if ctr in self._seen_set:
                self.duplicates += 1
                return False
            self._seen.append(ctr)
            self._seen_set.add(ctr)
            if len(self._seen) > SEEN:
                self._seen_set.discard(self._seen.popleft())
        if self._ctr is not None:
            gap = (ctr - self._ctr - 1) & 0xFFFF
            if gap and gap < 0x8000:
                self.lost_packets += gap
            if gap >= 0x8000:  # a late datagram (reordered): not lost, and not the newest
                self.lost_packets = max(0, self.lost_packets - 1)
                return True
        self._ctr = ctr
        return True

    @abstractmethod
    def send(self, packet: bytes) -> None:
        """Send one command packet."""

    @abstractmethod
    def receive(self) -> list[tuple[int, bytes]] | None:
        """What arrived within READ_WAIT_S as (arrival ns, packet); [] for nothing, None when the
        slave closed the link; DeviceError when its framing is lost."""

    @abstractmethod
    def close(self) -> None:
        """Release the link."""


class _StreamLink(Link):
    """LEN CTR PACKET messages on a byte stream (TCP, SxI): parsed as they come."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self._buf = bytearray()

    @abstractmethod
    def _read(self) -> bytes | None:
        """Bytes that came (b"" for none yet); None when closed."""

    def receive(self) -> list[tuple[int, bytes]] | None:
        data = self._read()
        if data is None:
            return None
        if not data:
            return []
        now = time.time_ns()
        buf = self._buf
        buf += data
        out, at = [], 0
        while len(buf) - at >= HEADER.size:
            length, ctr = HEADER.unpack_from(buf, at)
            if not 0 < length <= self.max_packet:
                raise DeviceError(f"{self.url}: the slave sent a message of length {length} (the limit is "
                                  f"{self.max_packet}): its framing is lost")
            end = at + HEADER.size + length
            if end > len(buf):
                break
            self.count(ctr)
            out.append((now, bytes(buf[at + HEADER.size : end])))
            at = end
        del buf[:at]
        if len(buf) > MAX_BUFFER:
            raise DeviceError(f"{self.url}: {len(buf)} bytes from the slave without a whole message")
        self.received += len(out)
        return out


class _SocketSend:
    """Sending and closing on a socket (``_sock``), for the Ethernet links."""

    _sock: socket.socket
    url: str

    def send(self, packet: bytes) -> None:
        try:
            self._sock.sendall(self.frame(packet))
        except OSError as err:
            raise DeviceError(f"{self.url}: send failed: {err.strerror or err}") from None

    def close(self) -> None:
        try:
            self._sock.close()
        except OSError:
            pass


class TcpLink(_SocketSend, _StreamLink):
    """XCP on TCP to ``host``:``port``."""

    def __init__(self, url: str, host: str, port: int, timeout_s: float) -> None:
        super().__init__(url)
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as err:
            raise DeviceError(f"{url}: cannot connect: {err.strerror or err}") from None
        self._sock.settimeout(READ_WAIT_S)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _read(self) -> bytes | None:
        try:
            return self._sock.recv(1 << 16) or None
        except socket.timeout:
            return b""
        except OSError:
            return None

class SerialLink(_StreamLink):
    """XCP on SxI over a serial port (pyserial URL or device), LEN_CTR_WORD header, no checksum."""

    def __init__(self, url: str, port: str, baud: int) -> None:
        super().__init__(url)
        import serial

        try:
            self._port = serial.serial_for_url(port, baudrate=baud, timeout=READ_WAIT_S)
        except (serial.SerialException, ValueError, OSError) as err:
            raise DeviceError(f"{url}: cannot open {port}: {err}") from None

    def _read(self) -> bytes | None:
        import serial

        try:
            first = self._port.read(1)
            return first + self._port.read(self._port.in_waiting) if first else b""
        except (serial.SerialException, OSError):
            return None

    def send(self, packet: bytes) -> None:
        import serial

        try:
            self._port.write(self.frame(packet))
        except (serial.SerialException, OSError) as err:
            raise DeviceError(f"{self.url}: send failed: {err}") from None

    def close(self) -> None:
        try:
            self._port.close()
        except Exception:  # a port already gone
            pass


class UdpLink(_SocketSend, Link):
    """XCP on UDP to ``host``:``port``: each datagram holds one or more LEN CTR PACKET messages."""

    datagrams = True

    def __init__(self, url: str, host: str, port: int) -> None:
        super().__init__(url)
        try:
            family = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0][0]
            self._sock = socket.socket(family, socket.SOCK_DGRAM)
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            self._sock.connect((host, port))
        except OSError as err:
            raise DeviceError(f"{url}: cannot reach {host}:{port}: {err.strerror or err}") from None
        self._sock.settimeout(READ_WAIT_S)

    def receive(self) -> list[tuple[int, bytes]] | None:
        out: list[tuple[int, bytes]] = []
        try:
            data = self._sock.recv(1 << 16)
        except socket.timeout:
            return out
        except ConnectionRefusedError:
            return out  # an ICMP "port unreachable" for a datagram sent before the slave listened
        except OSError:
            return None
        now = time.time_ns()
        while True:
            self._parse(data, now, out)
            try:
                self._sock.setblocking(False)
                data = self._sock.recv(1 << 16)
            except (BlockingIOError, ConnectionRefusedError):
                break
            except OSError:
                return None
            finally:
                self._sock.settimeout(READ_WAIT_S)
        self.received += len(out)
        return out

    def _parse(self, data: bytes, now: int, out: list) -> None:
        at = 0
        while len(data) - at >= HEADER.size:
            length, ctr = HEADER.unpack_from(data, at)
            end = at + HEADER.size + length
            if not 0 < length <= self.max_packet or end > len(data):
                self.malformed += 1  # the rest of this datagram cannot be framed
                return
            if self.count(ctr):
                out.append((now, data[at + HEADER.size : end]))
            at = end
        if at != len(data) and any(data[at:]):
            self.malformed += 1  # trailing bytes that are no message (zero fill is allowed)

class CanLink(Link):
    """XCP on CAN: one packet per frame, on a bus shared through :class:`~ambdaq.drivers.can.bus.CanHub`."""

    has_counter = False

    def __init__(self, url: str, interface: str, channel: str, bitrate: int, id_master: int, id_slave: int,
                 bus_options: dict) -> None:
        super().__init__(url)
        from ..can.bus import CanHub

        self.max_packet = 8
        self._id_master, self._id_slave = id_master, id_slave
        self._hub = CanHub.acquire(interface, channel, bitrate, **bus_options)
        self._frames: deque = deque()
        self._ready = threading.Event()
        self._hub.on_frame(id_slave, self._on_frame)

    def _on_frame(self, data: bytearray, timestamp: float) -> None:  # on the bus thread
        self._frames.append((time.time_ns(), bytes(data)))
        self._ready.set()

    def receive(self) -> list[tuple[int, bytes]] | None:
        if self._hub.failure:
            return None
        if not self._frames and not self._ready.wait(READ_WAIT_S):
            return []
        self._ready.clear()
        out = []
        while self._frames:
            arrived, data = self._frames.popleft()
            if data:
                out.append((arrived, data))
            else:
                self.malformed += 1
        self.received += len(out)
        return out

    def send(self, packet: bytes) -> None:
        import can

        msg = can.Message(arbitration_id=self._id_master, data=packet, is_extended_id=self._id_master > 0x7FF)
        try:
            self._hub.network.bus.send(msg)
        except (can.CanError, OSError) as err:
            raise DeviceError(f"{self.url}: send failed: {err}") from None

    def close(self) -> None:
        self._hub.on_frame(self._id_slave, lambda data, ts: None)
        self._hub.release()

