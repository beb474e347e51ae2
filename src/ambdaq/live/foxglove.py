"""The recording's topics served over the Foxglove WebSocket protocol while the file keeps every
sample (``ambdaq record --live``, docs/live.md).

The server is foxglove-sdk's (``foxglove.start_server``, in Rust on its own threads): each client
has a bounded queue that drops its oldest messages when the client is slow, so no viewer can stall
the recorder. It is a sink of the acquisition (:mod:`ambdaq.acquisition.acquisition`): every block received
goes to :meth:`FoxgloveLive.received`, which logs
every ``decimation``-th sample of each topic as JSON (a display rate a viewer can take: 100 Hz by
default against the devices' 10 kHz). A thread of its own publishes the derived topics five times
a second from the last 0.2 s: ``/live/1x`` (the 1X vector per radial axis from the key-phasor),
``/live/orbit/<bearing>`` (x and y about their mean) and ``/live/speed``.
"""

from __future__ import annotations

import logging
import threading
import time

from collections.abc import Callable

import numpy as np

from ..acquisition.acquisition import Sink
from ..machines.machine import Machine
from .view import LiveView

DERIVED_HZ = 5.0  # the derived topics' rate
BACKLOG = 1024  # messages queued per client before its oldest are dropped (foxglove-sdk's default)


SERVER_LOGGER = "foxglove.websocket.server"  # where foxglove-sdk's Rust server logs, through Python logging


class _FailedHandshakes(logging.Filter):
    """foxglove-sdk logs every client whose WebSocket handshake it refuses ("Dropping client ...:
    handshake failed"); a client that offers only the older ``foxglove.websocket.v1`` subprotocol
    gets that from this SDK, which speaks ``foxglove.sdk.v1`` only (checked with 0.30: it answers
    400 "Missing expected sec-websocket-protocol header"). Said once, in ambdaq's words."""

    def __init__(self, warn: Callable[[str], None]) -> None:
        super().__init__()
        self.failed = 0
        self.warn = warn

    def filter(self, record: logging.LogRecord) -> bool:
        if "handshake failed" not in record.getMessage():
            return True
        self.failed += 1
        if self.failed == 1:
            self.warn("a viewer's WebSocket handshake was refused: this server speaks the foxglove.sdk.v1 "
                      "subprotocol, and clients that offer only foxglove.websocket.v1 (older Foxglove apps) cannot "
                      "connect; update the viewer (further refusals are not shown)")
        return False


def _schema(name: str, fields: list[str], units: list[str]) -> dict:
    props = {f: {"type": "number", "description": u} for f, u in zip(fields, units)}
    props["seq"] = {"type": "integer", "description": "the device's sample number"}
    return {"title": name, "type": "object", "properties": props}


class FoxgloveLive(Sink):
    """A Foxglove WebSocket server for one recording.

    Parameters
    ----------
    sources : list of Source
        The recording's devices (their signal groups become the channels).
    machine : Machine
        Their machine: where its gap and rotor angle are recorded, its radial bearings (the
        derived orbit and 1X topics).
    host : str
        Address to bind (127.0.0.1 unless the user asks otherwise).
    port : int
        TCP port; 0 picks a free one (:attr:`port` tells which).
    display_hz : float
        Samples per second and topic sent to viewers.
    warn : callable
        Where what a viewer's failed connection means is said, once (the command line's stderr).
    """

    def __init__(self, sources, machine: Machine, host: str, port: int, display_hz: float = 100.0, *,
                 warn: Callable[[str], None] = lambda text: None) -> None:
        import foxglove

        self._handshakes = _FailedHandshakes(warn)
        logging.getLogger(SERVER_LOGGER).addFilter(self._handshakes)
        self._context = foxglove.Context()
        self.server = foxglove.start_server(name="ambdaq", host=host, port=port, context=self._context,
                                            message_backlog_size=BACKLOG)
        self.port = self.server.port
        self._channels: dict[tuple[str, str], object] = {}
        self._fields: dict[tuple[str, str], list[str]] = {}
        self._every: dict[str, int] = {}
        self._groups = {s.name: {g.topic: list(g.fields) for g in s.signal_groups()} for s in sources}
        for s in sources:
            rate = s.sample_rate or display_hz
            self._every[s.name] = max(1, int(round(rate / display_hz)))
            for g in s.signal_groups():
                key = (s.name, g.topic)
                shared = sum(g.topic in gs for gs in self._groups.values()) > 1  # every device's, not the first's
                topic = f"{g.topic}@{s.name}" if shared else g.topic
                self._channels[key] = foxglove.Channel(topic, schema=_schema(g.type_name, list(g.fields), list(g.units)),
                                                       message_encoding="json", context=self._context)
                self._fields[key] = list(g.fields)
        self._next: dict[str, int] = {}
        self.view = LiveView({s.name: s.sample_rate for s in sources}, self._groups, machine)
        # every channel is advertised from the start, so a client that connects early sees the orbits
        # without waiting for a new advertisement
        bearings = sorted(b.name for b in machine.bearings)
        self._derived = {name: foxglove.Channel(name, message_encoding="json", context=self._context)
                         for name in ("/live/1x", "/live/speed", *(f"/live/orbit/{b}" for b in bearings))}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._publish_derived, name="foxglove-derived", daemon=True)
        self._thread.start()

    def received(self, device: str, block) -> None:
        """Log every ``decimation``-th sample of the block's topics; keep it for the derived topics
        (the acquisition hands it every block it receives)."""
        self.view.received(device, block)
        every = self._every.get(device, 1)
        seq = block.seq.astype(np.int64)
        first = self._next.get(device, int(seq[0]))
        pick = np.flatnonzero((seq >= first) & ((seq - first) % every == 0))
        if pick.size == 0:
            return
        self._next[device] = int(seq[pick[-1]]) + every
        now = time.time_ns()
        for topic, values in block.values.items():
            channel = self._channels.get((device, topic))
            if channel is None:
                continue
            fields = self._fields[(device, topic)]
            rows = values[pick].tolist()
            for s, row in zip(seq[pick].tolist(), rows):
                channel.log({**dict(zip(fields, row)), "seq": s}, log_time=now)

    def _publish_derived(self) -> None:
        while not self._stop.wait(1.0 / DERIVED_HZ):
            now = time.time_ns()
            speeds = {}
            for b in self.view.bearings():
                if b.one_x is not None:
                    for axis, v in zip(("x", "y"), b.one_x):
                        self._derived["/live/1x"].log(
                            {"device": b.device, "axis": f"{b.bearing}_{axis}", "amplitude_um": abs(v),
                             "phase_deg": float(np.degrees(np.angle(v)))}, log_time=now)
                if b.speed_rpm is not None:
                    speeds[b.device] = b.speed_rpm
                self._derived[f"/live/orbit/{b.bearing}"].log({"device": b.device, "x_um": b.orbit_um[0].tolist(), "y_um": b.orbit_um[1].tolist()},
                                 log_time=now)
            for device, rpm in speeds.items():
                self._derived["/live/speed"].log({"device": device, "rpm": rpm}, log_time=now)

    def close(self) -> None:
        """Stop the derived topics and the server (once: the recording's end, or its caller)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2)
        self.server.stop()
        logging.getLogger(SERVER_LOGGER).removeFilter(self._handshakes)


__all__ = ["FoxgloveLive"]
