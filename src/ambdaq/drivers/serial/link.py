"""The host end of an ambdaq serial line: framing, requests with ACK/NAK, liveness.

A reader thread decodes frames as bytes arrive (pyserial, any ``serial_for_url`` URL), routes
replies to the request waiting for them, queues sample blocks with their arrival time, and keeps
fault events.  The line counts as lost when the port fails or nothing arrives for ``alive_s``
(the device sends a heartbeat every 100 ms).
"""

from __future__ import annotations

import queue
import struct
import threading
import time
from dataclasses import dataclass
from urllib.parse import urlsplit

import serial

from ...errors import BadInputError, DeviceError, DeviceTimeout
from . import protocol as proto
from .framing import FrameDecoder, encode_frame
from .protocol import MsgType

PING_S = 0.1  # a time exchange every 100 ms ...
PING_KEEP = 100  # ... the least round trip of the last 10 s counts
SAMPLE_BACKLOG = 1000  # SAMPLES frames held for the reader (10 s of 100-sample frames at 10 kHz)


@dataclass(frozen=True)
class Fault:
    """A fault event reported by a device."""

    device_time_ns: int
    code: int
    severity: int
    message: str


class SerialLink:
    """An open serial line to one device.

    Parameters
    ----------
    port : str
        Port name or pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/3``, ``socket://127.0.0.1:7001``).
    baudrate : int
        Line rate, in bit/s (ignored by pseudo-terminals and sockets).
    alive_s : float
        Silence after which the device counts as gone, in s.
    """

    def __init__(self, port: str, *, baudrate: int = 3_000_000, alive_s: float = 1.0) -> None:
        self.port_name = port
        self.baudrate = baudrate
        try:  # exclusive: a second program on the same port is refused at once, not left to garble it
            if "://" in port:  # a pyserial URL: a malformed host or port is the URL's fault, not the
                urlsplit(port).port  # device's (pyserial reports it as a failure to open the port)
            self._port = serial.serial_for_url(port, baudrate=baudrate, timeout=0.05, write_timeout=1.0,
                                               exclusive=True)
        except ValueError as err:
            raise BadInputError(f"serial port {port!r}: {err}") from None
        except (serial.SerialException, OSError) as err:
            busy = " (is another program using it?)" if "lock" in str(err).lower() else ""
            raise DeviceError(f"cannot open serial port {port}{busy}: {err}") from None
        self.alive_s = alive_s
        self.decoder = FrameDecoder()
        # bounded: a reader that stops taking them (a stalled recorder) costs the newest frames,
        # counted (``overflow``) and seen by the recorder as a gap in the sample index
        self.samples: queue.Queue = queue.Queue(maxsize=SAMPLE_BACKLOG)
        self.overflow = 0
        self.faults: queue.Queue[Fault] = queue.Queue()
        self.sync_pairs: queue.Queue[tuple[int, int]] = queue.Queue()  # (device ns, host arrival ns)
        self.lost_frames = 0
        self.failure: str | None = None
        self.last_rx = time.monotonic()
        self._rx_seq: int | None = None
        self._tx_seq = 0
        self._tx_lock = threading.Lock()
        self._pending: dict[int, list] = {}
        self._identity: list = []
        self._identity_event = threading.Event()
        self._stop = threading.Event()
        self._round_trips: list[int] = []  # ns, the last PING_KEEP
        self._reader = threading.Thread(target=self._read_loop, name=f"serial-{port}", daemon=True)
        self._reader.start()
        self._pinger = threading.Thread(target=self._ping_loop, name=f"serial-ping-{port}", daemon=True)

    def start_time_sync(self) -> None:
        """Measure the round trip every PING_S (TIME_REQUEST / TIME_REPLY) from now on."""
        if not self._pinger.is_alive():
            self._pinger.start()

    def _ping_loop(self) -> None:
        while not self._stop.wait(PING_S):
            with self._tx_lock:
                seq = self._tx_seq
                self._tx_seq = (self._tx_seq + 1) & 0xFFFF
                try:  # stamped t1 as it is written
                    self._port.write(encode_frame(proto.pack(MsgType.TIME_REQUEST, seq, proto.time_request(time.time_ns()))))
                except (serial.SerialException, OSError, TypeError):  # TypeError: pyserial closed the port
                    return  # meanwhile (its fd is None): the link is going away

    @property
    def one_way_latency_ns(self) -> int | None:
        """Half the least round trip of the recent time exchanges (NTP), or None before one."""
        with self._tx_lock:
            return min(self._round_trips) // 2 if self._round_trips else None

    # --- receive -----------------------------------------------------------------------------------

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._port.read(max(1, self._port.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as err:
                if not self._stop.is_set():
                    self.failure = f"serial port {self.port_name} failed: {err}"
                return
            if not data:
                if time.monotonic() - self.last_rx > self.alive_s and self.failure is None:
                    self.failure = f"no data from {self.port_name} for {self.alive_s:g} s"
                continue
            arrived = time.time_ns()
            for raw in self.decoder.feed(data):
                try:
                    self._route(proto.unpack(raw), arrived)
                except (ValueError, IndexError, KeyError):
                    self.decoder.stats.cobs_errors += 1  # well-framed but malformed: count, drop
            self.last_rx = time.monotonic()

    def _route(self, frame: proto.Frame, arrived: int) -> None:
        if self._rx_seq is not None:
            self.lost_frames += (frame.seq - self._rx_seq - 1) & 0xFFFF
        self._rx_seq = frame.seq
        t = frame.type
        if t == MsgType.SAMPLES:
            try:
                self.samples.put_nowait((proto.parse_samples(frame.body), arrived))
            except queue.Full:
                self.overflow += 1
        elif t in proto.REPLIES:
            req = int.from_bytes(frame.body[:2], "little")
            slot = self._pending.get(req)
            if slot is not None:
                slot.append(frame)
                slot[0].set()
        elif t == MsgType.IDENTITY:
            self._identity.append(frame)
            self._identity_event.set()
        elif t == MsgType.FAULT:
            code, severity, dev_t, msg = proto.parse_fault(frame.body)
            self.faults.put(Fault(dev_t, code, severity, msg))
        elif t == MsgType.TIME_REPLY:
            t1, t2, t3 = proto.parse_time_reply(frame.body)
            with self._tx_lock:
                self._round_trips.append((arrived - t1) - (t3 - t2))
                del self._round_trips[:-PING_KEEP]
        elif t == MsgType.HEARTBEAT:  # stamped as it left the device: a clock-sync pair
            (dev_t,) = struct.unpack_from("<q", frame.body, 0)
            self.sync_pairs.put((dev_t, arrived))

    # --- send --------------------------------------------------------------------------------------

    def send(self, msg_type: MsgType, body: bytes = b"", *, reply_slot: list | None = None) -> int:
        """Send one frame; returns its sequence number.

        ``reply_slot`` is registered for the reply under the same lock that gives the frame its
        sequence number, so a ping sent from another thread cannot take the number in between.
        """
        with self._tx_lock:
            seq = self._tx_seq
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF
            if reply_slot is not None:
                self._pending[seq] = reply_slot
            try:
                self._port.write(encode_frame(proto.pack(msg_type, seq, body)))
            except (serial.SerialException, OSError) as err:
                self._pending.pop(seq, None)
                raise DeviceError(f"serial port {self.port_name}: write failed: {err}") from None
        return seq

    def request(self, msg_type: MsgType, body: bytes = b"", *, timeout: float = 1.0, what: str = "",
                attempts: int = 3) -> proto.Frame:
        """Send a request and wait for its ACK, NAK or PARAM_VALUE; NAK raises DeviceError.

        A request or its reply lost on a noisy line (CRC rejection) is sent again, up to
        ``attempts`` times: every request of this protocol is idempotent (stream on/off, a
        parameter read, writing the same value again).
        """
        rejected = self.decoder.stats.rejected
        for _attempt in range(attempts):
            slot: list = [threading.Event()]
            seq = None
            try:
                seq = self.send(msg_type, body, reply_slot=slot)
                if slot[0].wait(timeout):
                    break
            finally:
                if seq is not None:
                    self._pending.pop(seq, None)
        else:
            damaged = self.decoder.stats.rejected - rejected
            raise DeviceTimeout(f"{self.port_name}: no answer to {what or msg_type.name} within {timeout:g} s "
                                f"({attempts} attempts; {damaged} damaged frames from the device meanwhile)")
        reply = slot[1]
        if reply.type == MsgType.NAK:
            _req, code, msg = proto.parse_nak(reply.body)
            raise DeviceError(f"{self.port_name}: device refused {what or msg_type.name}: {msg} (code {code})")
        return reply

    def identify(self, timeout: float = 2.0) -> dict:
        """Ask the device who it is."""
        self._identity_event.clear()
        self._identity.clear()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:  # a line just opened may still carry junk: ask again
            self.send(MsgType.IDENTIFY)
            if self._identity_event.wait(0.3):
                try:
                    return proto.parse_json(self._identity[-1].body, "IDENTITY")
                except ValueError as err:
                    raise DeviceError(f"{self.port_name}: the device answered IDENTIFY, but {err}") from None
        raise DeviceError(f"{self.port_name}: no device answered IDENTIFY within {timeout:g} s (is it powered and "
                          "connected, at this baud rate, and not in use by another program?)")

    def close(self) -> None:
        self._stop.set()
        self._reader.join(timeout=1.0)
        try:
            self._port.close()
        except (serial.SerialException, OSError):
            pass
