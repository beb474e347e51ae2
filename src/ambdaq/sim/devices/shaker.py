"""The simulated base shakers: a two-channel SCPI function generator whose outputs shake the
base-motion rig's base (what :class:`ambdaq.drivers.shaker.Shaker` drives).

It answers the SCPI subset of docs/protocol.md ("Shaker generator") on a byte stream (a PTY),
line by line, with an error queue read by ``SYST:ERR?``.  Channel 1 drives the shaker under base
accelerometer 1, channel 2 the one under accelerometer 2, each with ``SHAKER_GAIN`` m/s^2 per volt
and no dynamics of its own.  The base moves while both outputs are on with sines of one frequency
and no offset: d2 = gain V2 sin(wt + phi2), d1 = gain V1 sin(wt + phi1), so alpha = d1/d2 =
(V1/V2) exp(j(phi1 - phi2)) (Kang & Jung eq. A-10).  Otherwise it is held still (one shaker alone
would rock the base about the other, which the rig's model does not do).  Changes reach the rig at
a control-period boundary.
"""

from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass, replace

import numpy as np

from ..rigs.base_motion import BaseExcitation
from ...drivers.shaker import MAX_VPP
from .rig_server import RigServer

SHAKER_GAIN = 10.0  # m/s^2 per V: 1 m/s^2 peak is 0.2 Vpp
IDENTITY = "ambdaq,SIM-SHAKER-2CH,SIM-GEN-0001,1.0"
MAX_HZ = 1000.0

# SCPI nodes: long form; the short form is its upper-case part (SOURce -> SOUR)
_NODES = ("SOURce", "FUNCtion", "FREQuency", "VOLTage", "UNIT", "OFFSet", "PHASe", "SYNChronize",
          "OUTPut", "SYSTem", "ERRor")
_SHORT = {n.upper(): re.sub("[a-z]", "", n) for n in _NODES}
_CANON = {**_SHORT, **{short: short for short in _SHORT.values()}}  # either form -> the short one

ERRORS = {
    -102: "Syntax error",
    -113: "Undefined header",
    -221: "Settings conflict",
    -222: "Data out of range",
    -224: "Illegal parameter value",
}


@dataclass
class Channel:
    """One output's settings (SCPI units: Hz, V peak to peak, V, degrees)."""

    func: str = "SIN"
    freq_hz: float = 1000.0
    vpp: float = 0.1
    offset_v: float = 0.0
    phase_deg: float = 0.0
    on: bool = False


class SimShaker:
    """Serve the generator on ``port`` and move ``server``'s rig base accordingly.

    Parameters
    ----------
    port : FdPort
        The instrument's end of the line.
    server : RigServer
        The running base-motion rig.
    gain : float
        Shaker gain, in m/s^2 per V.
    """

    def __init__(self, port, server: RigServer, *, gain: float = SHAKER_GAIN) -> None:
        self.port, self.server, self.gain = port, server, gain
        self.channels = {1: Channel(), 2: Channel()}
        self.errors: list[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="simshaker", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

    def _loop(self) -> None:
        pending = b""
        while not self._stop.is_set():
            pending += self.port.read(0.1)
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                answers = self.handle(line.decode("ascii", "replace"))
                if answers:
                    self.port.write((";".join(answers) + "\n").encode("ascii"))

    # --- SCPI ------------------------------------------------------------------------------------

    def handle(self, line: str) -> list[str]:
        """Run one line of ``;``-joined commands; returns the answers to its queries."""
        answers: list[str] = []
        (before, _), settings = self.motion(), {n: replace(c) for n, c in self.channels.items()}
        for command in line.strip().split(";"):
            command = command.strip()
            if command:
                answer = self._command(command)
                if answer is not None:
                    answers.append(answer)
        after, conflict = self.motion()
        if conflict and self.channels != settings:  # reported once, when the settings make it
            self._error(conflict)
        if after != before:
            self.server.at_boundary(lambda rig: rig.set_base_motion(after))
        return answers

    def _error(self, code: int) -> None:
        if len(self.errors) < 20:
            self.errors.append(code)

    def _command(self, command: str) -> str | None:
        header, _, arg = command.partition(" ")
        arg = arg.strip().upper()
        header = header.lstrip(":").upper()
        if header in ("*IDN?", "*RST", "*CLS", "*OPC?"):
            return self._common(header)
        query = header.endswith("?")
        nodes = header.rstrip("?").split(":")
        parsed = []
        for node in nodes:
            m = re.fullmatch(r"([A-Z]+)([12]?)", node)
            if m is None or m.group(1) not in _CANON:
                self._error(-113)
                return None
            parsed.append((_CANON[m.group(1)], int(m.group(2) or 1)))
        if parsed[0][0] == "SYST" and [n for n, _ in parsed] == ["SYST", "ERR"] and query:
            code = self.errors.pop(0) if self.errors else 0
            return f'{code:+d},"{ERRORS.get(code, "No error")}"'
        if parsed[0][0] == "OUTP" and len(parsed) == 1:
            return self._output(self.channels[parsed[0][1]], arg, query)
        ch = 1
        if parsed[0][0] == "SOUR":
            ch = parsed[0][1]
            parsed = parsed[1:]
        return self._source(self.channels[ch], tuple(n for n, _ in parsed), arg, query)

    def _common(self, header: str) -> str | None:
        if header == "*IDN?":
            return IDENTITY
        if header == "*OPC?":
            return "1"
        if header == "*RST":
            self.channels = {1: Channel(), 2: Channel()}
        self.errors.clear()  # *RST and *CLS
        return None

    def _output(self, c: Channel, arg: str, query: bool) -> str | None:
        if query:
            return "1" if c.on else "0"
        if arg not in ("ON", "OFF", "1", "0"):
            self._error(-224)
        else:
            c.on = arg in ("ON", "1")
        return None

    def _source(self, c: Channel, path: tuple[str, ...], arg: str, query: bool) -> str | None:
        if path == ("PHAS", "SYNC") and not query:
            return None  # the simulated channels share one time base: always in phase
        if path == ("VOLT", "UNIT"):
            if query:
                return "VPP"
            if arg != "VPP":
                self._error(-224)
            return None
        if path == ("FUNC",):
            if query:
                return c.func
            if arg not in ("SIN", "SINUSOID"):
                self._error(-224)  # the shakers are driven with sines only
            return None
        fields = {("FREQ",): ("freq_hz", 1e-3, MAX_HZ), ("VOLT",): ("vpp", 1e-3, MAX_VPP),
                  ("VOLT", "OFFS"): ("offset_v", -MAX_VPP / 2, MAX_VPP / 2), ("PHAS",): ("phase_deg", -360.0, 360.0)}
        if path not in fields:
            self._error(-113)
            return None
        name, lo, hi = fields[path]
        if query:
            return f"{getattr(c, name):+.9E}"
        try:
            value = float(arg)
        except ValueError:
            self._error(-102)
            return None
        if not (math.isfinite(value) and lo <= value <= hi):
            self._error(-222)
            return None
        setattr(c, name, value)
        return None

    # --- the base --------------------------------------------------------------------------------

    def motion(self) -> tuple[BaseExcitation | None, int]:
        """The base motion the outputs make now (None: still), and the SCPI error that holds it
        still when both outputs are on (0: none)."""
        c1, c2 = self.channels[1], self.channels[2]
        if not (c1.on and c2.on):
            return None, 0
        if c1.freq_hz != c2.freq_hz or c1.offset_v or c2.offset_v:
            return None, -221
        ratio = c1.vpp / c2.vpp * np.exp(1j * np.radians(c1.phase_deg - c2.phase_deg))
        motion = BaseExcitation("sine", self.gain * c2.vpp / 2, c1.freq_hz, complex(ratio))
        if motion.problem(self.server.rig.params.sample_rate):
            return None, -222
        return motion, 0
