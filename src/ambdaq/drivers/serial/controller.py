"""Driver for the AMB controller on a serial line (docs/protocol.md).

As a recorder source it streams the groups the controller announces in its IDENTITY (gap,
current, error, feedforward, rotor); as a parameter interface it reads and writes PID gains,
feedforward mode and table, LMS schedule and speed set-point; as a coefficient-bank port
(``ambdaq push``) it unlocks, writes the inactive bank, reads the device's CRC and commits.
"""

from __future__ import annotations

import queue
import struct
import time

import numpy as np
from numpy.typing import ArrayLike

from ...errors import DeviceError
from ..interfaces import Capabilities, Controller
from ..signals import Event, SampleBlock, SignalGroup
from . import protocol as proto
from .link import Fault, SerialLink
from .protocol import MsgType

STREAM_ATTEMPTS = 5
"""Requests of "stream on" before the device is given up (idempotent: each restarts the stream at
the next sample). A noisy line loses a reply now and then, and a loaded host may hold one back; a
fresh-clone run lost all three of 1 s each once on a line damaging 7 % of the device's frames."""


class ControllerDriver(Controller):
    """The AMB controller behind ``link``: a source, its parameters, and what its IDENTITY says it
    can do (:attr:`capabilities`: coefficient banks, a test-signal input, a FIR feedforward).

    Parameters
    ----------
    link : SerialLink
        The open line.
    name : str
        Device name in recordings.
    url : str
        The device URL, for identity and error messages.
    """

    def __init__(self, link: SerialLink, *, name: str = "controller", url: str = "") -> None:
        self.link = link
        self.name = name
        self.url = url or link.port_name
        self.info = link.identify()
        if self.info.get("device_type") != "controller":
            raise DeviceError(f"{self.url}: expected an AMB controller, found {self.info.get('device_type')!r}")
        self.sample_rate = float(self.info["sample_rate_hz"])
        try:
            self._groups = [SignalGroup(g["topic"], g["type"], tuple(g["fields"]), tuple(g["units"]))
                            for g in self.info["groups"]]
        except (KeyError, TypeError, ValueError) as err:  # what the device says of its streams is checked
            raise DeviceError(f"{self.url}: the controller describes its streams badly: {err}") from None
        self._capabilities = Capabilities.from_dict(self.info.get("capabilities"))
        self._n_samples: int | None = None
        self._end_index: int | None = None  # stop at this sample index (device time, not count)

    # --- recorder source ---------------------------------------------------------------------------

    def signal_groups(self) -> list[SignalGroup]:
        return list(self._groups)

    def identity(self) -> dict[str, str]:
        out = {"url": self.url, "kind": self.info["device_type"], "model": self.info["model"],
               "serial": self.info["serial"], "firmware": self.info["firmware"],
               "sample_rate_hz": f"{self.sample_rate:g}"}
        if self.info.get("active_coefficients_sha256"):  # the coefficient file it runs (fleet scan reads it)
            out["active_coefficients_sha256"] = str(self.info["active_coefficients_sha256"])
        return out

    def device_calibration(self) -> dict[str, str]:
        return {"units": "SI: m, A, rad, rad/s (device sends float32)", **self.info.get("calibration", {})}

    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    def start(self, n_samples: int | None) -> None:
        """Stream ``n_samples`` sample periods of device time (lost samples included), or forever."""
        self._n_samples = n_samples
        self._end_index = None
        self.link.request(MsgType.STREAM, b"\x01", what="stream on", attempts=STREAM_ATTEMPTS)
        self.link.start_time_sync()

    def read(self) -> SampleBlock | None:
        """The next block of samples; ``None`` when the requested count is done or the driver was
        closed.  Samples that arrived before the line failed are returned before the failure is."""
        while True:
            if self.closed:
                return None
            try:
                s, arrived = self.link.samples.get(timeout=0.2 if self.link.failure is None else 0.0)
                break
            except queue.Empty:
                if self.link.failure is not None:
                    raise DeviceError(f"{self.name} ({self.url}) lost at {time.strftime('%H:%M:%S')}: "
                                      f"{self.link.failure}") from None
        if self._n_samples is not None and self._end_index is None:
            self._end_index = s.first_index + self._n_samples
        n = s.values.shape[0]
        if self._end_index is not None:
            n = max(0, min(n, self._end_index - s.first_index))
            if n == 0:
                return None
        idx = np.arange(n, dtype=np.int64)
        values, col = {}, 0
        for g in self._groups:
            k = len(g.fields)
            values[g.topic] = s.values[:n, col : col + k]
            col += k
        return SampleBlock(
            device_time_ns=s.device_time_ns + idx * s.period_ns,
            seq=((s.first_index + idx) & 0xFFFFFFFF).astype(np.uint32),
            values=values,
            received_ns=arrived,
        )

    def events(self) -> list[Event]:
        """Faults reported since the last call."""
        out = []
        while True:
            try:
                f: Fault = self.link.faults.get_nowait()
            except queue.Empty:
                return out
            out.append(Event(f.device_time_ns, "fault", f.code, f"severity {f.severity}: {f.message}"))

    def clock_pairs(self) -> list[tuple[int, int]]:
        """(device time, host arrival time) of the heartbeats since the last call, in ns."""
        out = []
        while True:
            try:
                out.append(self.link.sync_pairs.get_nowait())
            except queue.Empty:
                return out

    def clock_latency_ns(self) -> int | None:
        """One-way latency of the line (half the least round trip), subtracted from the clock map."""
        return self.link.one_way_latency_ns

    def link_statistics(self) -> dict[str, str]:
        st = self.link.decoder.stats
        return {"frames": str(st.frames), "crc_errors": str(st.crc_errors), "cobs_errors": str(st.cobs_errors),
                "lost_frames": str(self.link.lost_frames), "backlog_overflow": str(self.link.overflow)}

    def _close(self) -> None:
        """Stop the stream (one try: a device that does not answer in 0.3 s is gone anyway) and
        close the line."""
        try:
            if self.link.failure is None:
                self.link.request(MsgType.STREAM, b"\x00", what="stream off", timeout=0.3, attempts=1)
        except DeviceError:
            pass
        self.link.close()

    @property
    def can_reconnect(self) -> bool:
        return True

    def reconnect(self) -> None:
        """Reopen the line, check the device is the same one, and resume streaming."""
        port, baud, alive = self.link.port_name, self.link.baudrate, self.link.alive_s
        self.link.close()
        self.link = SerialLink(port, baudrate=baud, alive_s=alive)
        try:
            info = self.link.identify()
            if info.get("serial") != self.info.get("serial"):
                raise DeviceError(f"{self.url}: a different device answered (serial {info.get('serial')})")
            self.link.request(MsgType.STREAM, b"\x01", what="stream on", attempts=STREAM_ATTEMPTS)
            self.link.start_time_sync()
        except DeviceError:
            self.link.close()
            raise

    # --- parameters --------------------------------------------------------------------------------

    def read_param(self, name: str) -> np.ndarray:
        """Read a controller parameter (see docs/protocol.md for names and units)."""
        reply = self.link.request(MsgType.PARAM_READ, proto.param_read(name), what=f"read {name}")
        _req, got, values = proto.parse_param_value(reply.body)
        return values

    def parameter_names(self) -> list[str]:
        """The parameters its IDENTITY lists (docs/protocol.md)."""
        names = self.info.get("parameters")
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            return super().parameter_names()
        return list(names)

    def write_param(self, name: str, values: ArrayLike) -> None:
        """Write a controller parameter; the controller acknowledges or refuses (DeviceError)."""
        self.link.request(MsgType.PARAM_WRITE, proto.param_write(name, np.atleast_1d(values)), what=f"write {name}")

    # --- coefficient banks (docs/protocol.md) --------------------------------------------------------

    def unlock(self, key: str) -> None:
        """Unlock the coefficient banks with the controller's key (refused: DeviceError)."""
        self.link.request(MsgType.UNLOCK, proto.unlock(key), what="unlock")

    def write_bank(self, image: bytes) -> None:
        """Write ``image`` into the inactive bank, in BANK_CHUNK pieces (each one acknowledged)."""
        for off in range(0, len(image), proto.BANK_CHUNK):
            self.link.request(MsgType.BANK_WRITE, proto.bank_write(off, len(image), image[off : off + proto.BANK_CHUNK]),
                              what=f"bank write at byte {off}")

    def bank_status(self) -> dict:
        """Active bank, device-computed CRC-32s, the push log."""
        reply = self.link.request(MsgType.BANK_STATUS, what="bank status")
        try:
            return proto.parse_json(reply.body[2:], "BANK_STATUS")
        except ValueError as err:
            raise DeviceError(f"{self.name}: {err}") from None

    def commit_bank(self, crc: int, record: dict) -> int:
        """Switch to the inactive bank if the device finds ``crc`` in it; returns the first sample
        index run with it.  Sent once: a commit is not idempotent (the caller checks the status
        when no answer comes)."""
        reply = self.link.request(MsgType.BANK_COMMIT, proto.bank_commit(crc, record), what="commit", attempts=1,
                                  timeout=2.0)
        return struct.unpack_from("<I", reply.body, 2)[0]

    def read_bank(self, which: str, length: int) -> bytes:
        """``length`` bytes of the ``active`` or ``inactive`` bank."""
        out = bytearray()
        while len(out) < length:
            reply = self.link.request(MsgType.BANK_READ, proto.bank_read(0 if which == "active" else 1, len(out),
                                                                         min(proto.BANK_CHUNK, length - len(out))),
                                      what=f"bank read at byte {len(out)}")
            chunk = reply.body[6:]
            if not chunk:
                break
            out += chunk
        return bytes(out)
