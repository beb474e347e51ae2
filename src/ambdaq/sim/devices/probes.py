"""A simulated third-party eddy-current probe conditioner that sends raw CAN frames described by
its vendor's DBC file (``ambdaq/sim/vendor/probe_conditioner.dbc``), no CANopen.

Free-running, as such conditioners are: every FRAME_PERIOD_S it samples the rig's gap at that
instant and sends ``FrontGap`` (Motorola signals) and ``RearGap`` (Intel signals), each with a
4-bit rolling counter; every 100 ms a ``Diagnostics`` frame, multiplexed (page 0: probe
temperatures, page 1: supply voltage and uptime); and every 100 ms a frame of the vendor's own
(0x7F0) that the DBC does not describe.  What it meant to send is kept (:attr:`sent`), so a test
can check a recording against it.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import deque
from pathlib import Path

import can

from ...machines.spindle import AXES
from .rig_server import RigServer

DBC_PATH = Path(__file__).parent.parent / "vendor" / "probe_conditioner.dbc"
FRAME_PERIOD_S = 0.002  # 500 frames/s per bearing
DIAG_EVERY = 50  # frames: 10 Hz
VENDOR_ID = 0x7F0  # a frame the DBC does not describe
GAP_AXES = {"FrontGap": ("front_x", "front_y"), "RearGap": ("rear_x", "rear_y")}
SENT_KEPT = 20_000


class SimProbeConditioner:
    """The conditioner on python-can ``virtual`` ``channel``, fed by ``server``'s rig."""

    def __init__(self, channel: str, server: RigServer) -> None:
        import cantools

        self.db = cantools.database.load_file(str(DBC_PATH))
        self.server = server
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.sent: deque[tuple[int, str, dict]] = deque(maxlen=SENT_KEPT)  # (time ns, message, values)
        self._columns = {a: AXES.index(a) for axes in GAP_AXES.values() for a in axes}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-probes", daemon=True)
        self._started = time.monotonic()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.bus.shutdown()

    def _send(self, name: str, values: dict, t_ns: int) -> None:
        msg = self.db.get_message_by_name(name)
        self.bus.send(can.Message(arbitration_id=msg.frame_id, is_extended_id=False, data=msg.encode(values)))
        self.sent.append((t_ns, name, values))

    def _run(self) -> None:
        nxt = time.monotonic()
        for n in itertools.count():
            nxt += FRAME_PERIOD_S
            if self._stop.wait(max(0.0, nxt - time.monotonic())):
                return
            t_ns = time.time_ns()
            try:
                _step, rows = self.server.sample_at(t_ns)
            except LookupError:
                continue  # the rig has not started: the conditioner has nothing to say yet
            gap = rows["/amb/gap"]
            for name, (ax, ay) in GAP_AXES.items():
                # the conditioner's 0.02 um counts: what it sends is its own rounding of the gap
                x, y = (round(float(gap[self._columns[a]]) * 1e6 / 0.02) * 0.02 for a in (ax, ay))
                self._send(name, {"gap_x": x, "gap_y": y, "counter": n % 16, "probe_ok": 1}, t_ns)
            if n % DIAG_EVERY == 0:
                page = (n // DIAG_EVERY) % 2
                values = ({"page": 0, "temperature_front": 41, "temperature_rear": 44} if page == 0 else
                          {"page": 1, "supply": 24.012, "uptime": int(time.monotonic() - self._started) % 256})
                self._send("Diagnostics", values, t_ns)
                self.bus.send(can.Message(arbitration_id=VENDOR_ID, is_extended_id=False, data=bytes([n % 256, 0xA5])))
