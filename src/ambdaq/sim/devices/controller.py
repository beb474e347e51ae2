"""Simulated AMB controller on a serial byte stream (the device side of docs/protocol.md).

It streams gap, coil current, command error, feedforward and rotor angle/speed at the rig's
10 kHz in SAMPLES frames of one rig block each, answers IDENTIFY, PARAM_READ and PARAM_WRITE
(PID gains, speed set-point; feedforward mode, table and LMS schedule read-only), holds its
feedforward coefficients in two banks written only through UNLOCK / BANK_WRITE / BANK_COMMIT
(:mod:`.banks`), sends a HEARTBEAT every 5 ms, stamped with its own clock as it leaves (the
host's clock-sync pairs), and FAULT events.
"""

from __future__ import annotations

import os
import queue
import random
import select
import struct
import threading
import time

import numpy as np

from ...drivers.serial import protocol as proto
from ...drivers.serial.framing import FrameDecoder, encode_frame
from ...drivers.serial.protocol import MsgType, NakCode
from ...drivers.signals import SampleBlock
from ..profiles import profile
from .banks import DEFAULT_UNLOCK_KEY, BankRefused, CoefficientBanks
from .firmware import Firmware
from .rig_server import DeviceClock, RigServer

HEARTBEAT_S = 0.005  # heartbeats are the clock-sync pairs: stamped as they leave, 200 per second
STOP_POLL_S = 0.05  # the writer looks at its stop flag at least this often, s
_WAKE = (None, b"")  # queued to wake the writer for an event or a time request


class FdPort:
    """The device end of a byte stream on a file descriptor (a PTY master, a socket)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def read(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.fd], [], [], timeout)
        if not r:
            return b""
        try:
            return os.read(self.fd, 65536)
        except OSError:  # the other end went away
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self.fd, view)
            view = view[n:]

    def close(self) -> None:
        try:
            os.close(self.fd)
        except OSError:
            pass


class SimController:
    """The simulated controller, serving ``port`` with data from ``server``'s rig.

    Parameters
    ----------
    port : FdPort
        The device's end of the serial line.
    server : RigServer
        The running rig.
    firmware : Firmware, optional
        What it streams, answers to and runs; default: the rig profile's.
    clock : DeviceClock
        The controller's own clock.
    serial : str
        Serial number reported in IDENTITY.
    truth : bool
        Also stream the simulator's ground truth topics.
    tx_queue : int
        Frames buffered for transmission; when the host stops reading, later frames are dropped
        (as a UART FIFO overflows) and the host sees the gap in the sequence numbers.
    unlock_key : str
        The key its coefficient banks want.
    """

    def __init__(self, port, server: RigServer, firmware: Firmware | None = None, *, clock: DeviceClock = DeviceClock(),
                 serial: str = "SIM-CTRL-0001", truth: bool = False, tx_queue: int = 64,
                 unlock_key: str = DEFAULT_UNLOCK_KEY) -> None:
        self.port = port
        self.server = server
        self.rig = server.rig
        self.clock = clock
        self.serial = serial
        self.firmware = firmware if firmware is not None else profile(self.rig.profile).firmware
        groups = {g.topic: g for g in self.rig.signal_groups()}
        truth_topics = [t for t in groups if t.startswith("/truth/")]
        if truth and not truth_topics:
            raise ValueError("truth topics need a rig built with truth=True")
        self.groups = [groups[t] for t in self.firmware.topics + (tuple(truth_topics) if truth else ())]
        self._streaming = threading.Event()
        self._stream_from = 0  # the first rig step a stream started now sends
        self._tx: queue.Queue[tuple[MsgType, bytes]] = queue.Queue(maxsize=tx_queue)
        # events go out before any queued frame and are never dropped: a lost sample shows as a gap
        # in the sample index, a lost fault would show nowhere (a fresh clone's starved host once
        # dropped the injected fault with the samples queued before it)
        self._events: queue.SimpleQueue[tuple[MsgType, bytes]] = queue.SimpleQueue()
        self._seq = 0
        self._time_requests: queue.SimpleQueue[tuple[int, int]] = queue.SimpleQueue()  # (t1, t2)
        self._stop = threading.Event()
        self.dropped_frames = 0
        self.decoder = FrameDecoder()
        # shared with a CANopen configuration port, if any
        self.banks = CoefficientBanks(server, self.firmware.feedforward, unlock_key, clock=self.now_ns)
        self._threads = [
            threading.Thread(target=self._rx_loop, name="simctl-rx", daemon=True),
            threading.Thread(target=self._tx_loop, name="simctl-tx", daemon=True),
        ]

    # --- lifecycle -------------------------------------------------------------------------------

    def start(self) -> None:
        self.server.subscribe(self._on_block)
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake()
        self.server.unsubscribe(self._on_block)
        for t in self._threads:
            t.join(timeout=1.0)

    # --- transmit ---------------------------------------------------------------------------------

    def now_ns(self) -> int:
        """The device clock now."""
        return self.clock.at(time.time_ns() - self.server.start_wall_ns)

    def _next_seq(self) -> int:
        seq = self._seq  # the tx thread numbers every frame as it writes it
        self._seq = (self._seq + 1) & 0xFFFF
        return seq

    def _send(self, msg_type: MsgType, body: bytes = b"") -> None:
        """Queue a message; it is numbered and framed as it is written, so sequence numbers on the
        wire always count up (a frame dropped here leaves no gap: the host counts lost samples
        from the sample index)."""
        try:
            self._tx.put_nowait((msg_type, body))
        except queue.Full:
            self.dropped_frames += 1

    def _write(self, msg_type: MsgType, body: bytes) -> None:
        self.port.write(encode_frame(proto.pack(msg_type, self._next_seq(), body)))

    def _wake(self) -> None:
        """Have the writer look at the events and time requests now (a full queue: it is busy)."""
        try:
            self._tx.put_nowait(_WAKE)
        except queue.Full:
            pass

    def _tx_loop(self) -> None:
        """Write queued frames; every HEARTBEAT_S stamp a heartbeat with the device clock at the
        moment it goes out, so the host can map the clock without the queueing latency.  It sleeps
        until a frame, an event or a time request comes (:meth:`_wake`) or the next heartbeat is
        due: polling every millisecond cost the host a thousand wake-ups a second per controller."""
        # each device has its own phase and a jittered period, as independent oscillators do
        rng = random.Random(self.serial)
        next_beat = time.monotonic() + rng.uniform(0, HEARTBEAT_S)
        while not self._stop.is_set():
            # no heartbeat before the rig's clock runs: until then only frames and requests wake it
            timeout = max(0.0, next_beat - time.monotonic()) if self.server.start_wall_ns else STOP_POLL_S
            try:
                queued = self._tx.get(timeout=min(timeout, STOP_POLL_S))
            except queue.Empty:
                queued = None
            if queued is _WAKE:
                queued = None
            try:
                while True:
                    try:
                        self._write(*self._events.get_nowait())
                    except queue.Empty:
                        break
                if queued is not None:
                    self._write(*queued)
                while True:  # time replies are stamped t3 as they are written
                    try:
                        t1, t2 = self._time_requests.get_nowait()
                    except queue.Empty:
                        break
                    self._write(MsgType.TIME_REPLY, proto.time_reply(t1, t2, self.now_ns()))
                if time.monotonic() >= next_beat and self.server.start_wall_ns:  # the clock runs once the rig does
                    next_beat += HEARTBEAT_S * rng.uniform(0.7, 1.3)
                    self._write(MsgType.HEARTBEAT, proto.heartbeat(self.now_ns(), int(self._streaming.is_set())))
            except OSError:
                return  # the line is gone

    def _on_block(self, block: SampleBlock) -> None:
        if not self._streaming.is_set() or int(block.seq[-1]) < self._stream_from:
            return
        if int(block.seq[0]) < self._stream_from:  # the stream starts with the sample after STREAM on
            block = block.slice(self._stream_from - int(block.seq[0]), len(block))
        values = np.concatenate([block.values[g.topic] for g in self.groups], axis=1)
        t0 = self.clock.at(int(block.device_time_ns[0]))
        period = round(self.rig.period_ns * (1 + self.clock.drift_ppm * 1e-6))
        self._send(MsgType.SAMPLES, proto.samples(int(block.seq[0]), t0, period, values))

    def fault(self, code: int, severity: int, message: str) -> None:
        """Report a fault event to the host: ahead of every queued frame, never dropped."""
        self._events.put((MsgType.FAULT, proto.fault(code, severity, self.now_ns(), message)))
        self._wake()

    # --- receive ----------------------------------------------------------------------------------

    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            data = self.port.read(0.1)
            received = self.now_ns()
            for raw in self.decoder.feed(data) if data else ():
                try:
                    frame = proto.unpack(raw)
                    self._handle(frame, received)
                except (ValueError, IndexError) as err:
                    self._send(MsgType.NAK, proto.nak(0, NakCode.BAD_REQUEST, str(err)))

    def identity(self) -> dict:
        return {
            "device_type": "controller",
            "model": self.firmware.model,
            "serial": self.serial,
            "firmware": "ambdaq-sim 0.1",
            "sample_rate_hz": self.rig.params.sample_rate,
            "groups": [
                {"topic": g.topic, "type": g.type_name, "fields": list(g.fields), "units": list(g.units)}
                for g in self.groups
            ],
            "parameters": sorted(self.firmware.parameters),
            "capabilities": self.firmware.capabilities(self.rig).as_dict(),
            "calibration": self.rig.calibration(),
            # the coefficient file the running bank came from, as the host's push named it
            **({"active_coefficients_sha256": self.banks.log[-1]["file_sha256"]}
               if self.banks.log and self.banks.log[-1].get("file_sha256") else {}),
        }

    def _handle(self, frame: proto.Frame, received_ns: int) -> None:
        t = frame.type
        if t == MsgType.TIME_REQUEST:
            (t1,) = struct.unpack_from("<q", frame.body, 0)
            self._time_requests.put((t1, received_ns))
            self._wake()
        elif t == MsgType.IDENTIFY:
            self._send(MsgType.IDENTITY, proto.identity(self.identity()))
        elif t == MsgType.STREAM:
            if frame.body[:1] == b"\x01":
                self._stream_from = (time.time_ns() - self.server.start_wall_ns) // self.rig.period_ns + 1
                self._streaming.set()
            else:
                self._streaming.clear()
            self._send(MsgType.ACK, proto.ack(frame.seq))
        elif t in (MsgType.PARAM_READ, MsgType.PARAM_WRITE):
            name, values = proto.parse_param_request(frame.body)
            spec = self.firmware.parameters.get(name)
            if spec is None:
                self._send(MsgType.NAK, proto.nak(frame.seq, NakCode.UNKNOWN_PARAMETER, f"no parameter {name!r}"))
                return
            if values is None:
                self._send(MsgType.PARAM_VALUE, proto.param_value(frame.seq, name, spec.read(self.rig)))
                return
            if spec.write is None:
                self._send(MsgType.NAK, proto.nak(frame.seq, NakCode.READ_ONLY, f"{name} is read-only"))
                return
            problem = spec.check(self.rig, values)
            if problem:
                self._send(MsgType.NAK, proto.nak(frame.seq, NakCode.BAD_VALUE, f"{name}: {problem}"))
                return
            spec.write(self.rig, values)
            self._send(MsgType.ACK, proto.ack(frame.seq))
        elif MsgType.UNLOCK <= t <= MsgType.BANK_DATA:
            self._handle_bank(frame)
        else:
            self._send(MsgType.NAK, proto.nak(frame.seq, NakCode.BAD_REQUEST, f"unexpected message type 0x{t:02x}"))

    def _handle_bank(self, frame: proto.Frame) -> None:
        t, seq = frame.type, frame.seq
        try:
            if t == MsgType.UNLOCK:
                self.banks.unlock(proto.parse_unlock(frame.body))
            elif t == MsgType.BANK_WRITE:
                self.banks.write(*proto.parse_bank_write(frame.body))
            elif t == MsgType.BANK_COMMIT:
                crc, record = proto.parse_bank_commit(frame.body)
                step = self.banks.commit(crc, record)
                self._send(MsgType.ACK, proto.ack_value(seq, step))
                return
            elif t == MsgType.BANK_STATUS:
                self._send(MsgType.BANK_INFO, proto.bank_info(seq, self.banks.status()))
                return
            elif t == MsgType.BANK_READ:
                which, offset, length = proto.parse_bank_read(frame.body)
                data = self.banks.read("active" if which == 0 else "inactive", offset, length)
                self._send(MsgType.BANK_DATA, proto.bank_data(seq, offset, data))
                return
            else:
                raise BankRefused("bad_value", f"message type 0x{t:02x} is sent by the device, not to it")
        except BankRefused as err:
            code = {"locked": NakCode.LOCKED, "crc": NakCode.CRC_MISMATCH, "busy": NakCode.BUSY}.get(
                err.reason, NakCode.BAD_VALUE)
            self._send(MsgType.NAK, proto.nak(seq, code, str(err)))
            return
        self._send(MsgType.ACK, proto.ack(seq))
