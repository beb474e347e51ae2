"""A simulated SLCAN (Lawicel) USB-CAN adapter: the ASCII protocol of CANable, USBtin and CANUSB
adapters on a pseudo-terminal, bridged to the simulated devices' CAN bus.

The host side is whatever speaks SLCAN (python-can's ``slcan`` interface, ``slcand``), in any
process: this is how the simulated CANopen devices cross a process boundary here, where there is
no ``vcan``.  Commands (Lawicel CANUSB manual, section "ASCII commands"), each ended by CR; the
adapter answers CR (done) or BEL (refused)::

    Sn        bit rate, n = 0..8 (10 kbit/s .. 1 Mbit/s)     O   open      L   open listen-only
    sxxyy     bit timing registers (BTR0, BTR1)              C   close
    tiiildd.. standard frame (id 3 hex, dlc, data)           Tiiiiiiiildd.. extended frame
    riiil     standard remote frame                          Riiiiiiiil     extended remote frame
    diiil..   CAN FD frame, DLC code 0..F (to the host only)  Diiiiiiiil..  extended; b/B: with bit-rate switch
    V / v     hardware and software version                  N   serial number
    F         status flags (bit 3: a frame was lost)         Z0 / Z1  time stamps off / on

While open, every frame on the bus goes to the host as the same line (``t``/``T``/``r``/``R``, and
``d``/``D``/``b``/``B`` for CAN FD),
with a 16-bit millisecond time stamp appended when ``Z1`` asked for it.  Like the adapters' own
receive FIFO, the pseudo-terminal holds a bounded backlog: a frame that finds it full is dropped
and counted (status flag bit 3), never written half.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time

import can

BITRATES = {"0": 10_000, "1": 20_000, "2": 50_000, "3": 100_000, "4": 125_000, "5": 250_000,
            "6": 500_000, "7": 750_000, "8": 1_000_000}
OK, REFUSED = b"\r", b"\a"
VERSION = "V1013"  # hardware 1.0, software 1.3
FLAG_DATA_OVERRUN = 0x08  # Lawicel "F" status bit 3
BATCH = 256  # frames taken off the bus per write to the terminal


def frame_line(msg: can.Message, stamp_ms: int | None = None) -> bytes:
    """The SLCAN line of ``msg`` (without the CR), with a 16-bit ms time stamp if given. A CAN FD
    frame goes as ``d``/``D`` (``b``/``B`` with bit-rate switch), its length as the FD DLC code in
    one hex digit (0..F for 0..64 bytes), as CANable 2.0's FD firmware sends it."""
    kind = ("b" if msg.bitrate_switch else "d") if msg.is_fd else "r" if msg.is_remote_frame else "t"
    dlc = can.util.len2dlc(len(msg.data)) if msg.is_fd else msg.dlc
    if msg.is_extended_id:
        head = f"{kind.upper()}{msg.arbitration_id:08X}{dlc:X}"
    else:
        head = f"{kind}{msg.arbitration_id:03X}{dlc:X}"
    body = "" if msg.is_remote_frame else bytes(msg.data).hex().upper()
    tail = "" if stamp_ms is None else f"{stamp_ms % 60000:04X}"
    return (head + body + tail).encode()


def parse_frame(line: str) -> can.Message:
    """The frame an SLCAN transmit command asks for; ValueError if it is malformed."""
    kind = line[0]
    extended = kind in "TR"
    id_len = 8 if extended else 3
    ident = int(line[1 : 1 + id_len], 16)
    dlc = int(line[1 + id_len])
    if dlc > 8 or ident >= (1 << (29 if extended else 11)):
        raise ValueError(line)
    if kind in "rR":
        return can.Message(arbitration_id=ident, is_extended_id=extended, is_remote_frame=True, dlc=dlc)
    data = bytes.fromhex(line[2 + id_len :])
    if len(data) != dlc:
        raise ValueError(line)
    return can.Message(arbitration_id=ident, is_extended_id=extended, data=data)


class SimSlcanAdapter:
    """An SLCAN adapter on the PTY master ``fd``, attached to python-can ``virtual`` ``channel``.

    Parameters
    ----------
    fd : int
        The pseudo-terminal's master end (the host opens the slave).
    channel : str
        The virtual bus the simulated devices are on.
    serial : str
        What ``N`` answers.
    """

    def __init__(self, fd: int, channel: str, *, serial: str = "A3BD") -> None:
        self.fd = fd
        self.serial = serial
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.is_open = False
        self.listen_only = False
        self.bitrate: int | None = None
        self.timestamps = False
        self.frames_to_host = 0
        self.frames_from_host = 0
        self.lost = 0  # frames that found the terminal's backlog full
        self._flags = 0
        self._pending = b""  # the unwritten end of a line the terminal took only part of
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        os.set_blocking(fd, False)
        self._threads = [threading.Thread(target=self._commands, name="slcan-commands", daemon=True),
                         threading.Thread(target=self._forward, name="slcan-forward", daemon=True)]

    def start(self) -> None:
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=1.0)
        self.bus.shutdown()

    # --- host -> adapter ------------------------------------------------------------------------------

    def _commands(self) -> None:
        buf = b""
        while not self._stop.is_set():
            r, _, _ = select.select([self.fd], [], [], 0.05)
            if not r:
                continue
            try:
                chunk = os.read(self.fd, 4096)
            except BlockingIOError:
                continue
            except OSError:  # no host has the terminal open
                time.sleep(0.05)
                continue
            buf += chunk
            *lines, buf = buf.split(b"\r")
            for line in lines:
                self._reply(self._command(line.decode("ascii", errors="replace").strip("\n")))

    def _command(self, line: str) -> bytes:
        """Carry out one command; its answer (CR, BEL, or a line and CR)."""
        if not line:
            return OK
        op = line[0]
        if op in "tTrR":
            if not self.is_open or self.listen_only:
                return REFUSED
            try:
                msg = parse_frame(line)
            except (ValueError, IndexError):
                return REFUSED
            self.bus.send(msg)
            self.frames_from_host += 1
            return (b"z" if op in "tr" else b"Z") + OK
        if op == "S" and len(line) == 2 and line[1] in BITRATES and not self.is_open:
            self.bitrate = BITRATES[line[1]]
            return OK
        if op == "s" and len(line) == 5 and not self.is_open:
            self.bitrate = None  # a custom bit timing: accepted, the simulated bus has no bit rate
            return OK
        if op in "OL" and len(line) == 1 and not self.is_open:
            self.is_open, self.listen_only = True, op == "L"
            self._flags = 0
            return OK
        if op == "C" and len(line) == 1:  # closing a closed channel is harmless, as on the adapters
            self.is_open = False
            return OK
        if op in "Vv" and len(line) == 1:
            return VERSION.encode() + OK
        if op == "N" and len(line) == 1:
            return f"N{self.serial}".encode() + OK
        if op == "F" and len(line) == 1:
            flags, self._flags = self._flags, 0
            return f"F{flags:02X}".encode() + OK
        if op == "Z" and line[1:] in ("0", "1"):
            self.timestamps = line[1] == "1"
            return OK
        return REFUSED

    # --- adapter -> host ------------------------------------------------------------------------------

    def _forward(self) -> None:
        """Every frame on the bus, while open, to the host; bursts go in one write."""
        recv = self.bus.recv
        while not self._stop.is_set():
            msg = recv(0.05)
            if msg is None:
                continue
            lines = []
            while msg is not None and len(lines) < BATCH:
                if self.is_open:
                    stamp = int(msg.timestamp * 1000) if self.timestamps else None
                    lines.append(frame_line(msg, stamp) + OK)
                msg = recv(0)
            if lines:
                self._send_frames(lines)

    def _send_frames(self, lines: list[bytes]) -> None:
        """Write whole lines; those that do not fit in the terminal's backlog are lost and counted."""
        with self._write_lock:
            if self._pending and not self._write(self._pending):
                self.lost += len(lines)
                self._flags |= FLAG_DATA_OVERRUN
                return
            data = b"".join(lines)
            n = self._write_some(data)
            if n == len(data):
                self.frames_to_host += len(lines)
                return
            end = n if n == 0 or data[n - 1 : n] == OK else data.find(OK, n) + 1  # finish the line it is in
            self._pending = data[n:end]
            sent = data[:end].count(OK)
            self.frames_to_host += sent
            self.lost += len(lines) - sent
            self._flags |= FLAG_DATA_OVERRUN

    def send_line(self, line: bytes) -> None:
        """Send ``line`` to the host as it is: a garbled line of a faulty adapter (tests)."""
        self._send_frames([line])

    def _reply(self, answer: bytes) -> None:
        with self._write_lock:
            pending, self._pending = self._pending, b""
            self._write_all(pending + answer)  # never inside a frame's line

    def _write_some(self, data: bytes) -> int:
        try:
            return os.write(self.fd, data)
        except BlockingIOError:
            return 0
        except OSError as err:  # EIO: nobody holds the slave end
            if err.errno != errno.EIO:
                raise
            return len(data)

    def _write(self, pending: bytes) -> bool:
        """Try to finish the pending line; True when it is out."""
        n = self._write_some(pending)
        self._pending = pending[n:]
        return not self._pending

    def _write_all(self, data: bytes) -> None:
        """An answer to a command: short, and the host is waiting for it, so wait for room."""
        deadline = time.monotonic() + 1.0
        while data and time.monotonic() < deadline:
            n = self._write_some(data)
            data = data[n:]
            if data:
                select.select([], [self.fd], [], 0.01)
