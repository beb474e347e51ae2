"""The base shakers of a base-motion rig, driven by a two-channel function generator over SCPI.

Kang & Jung's campaign moves the base harmonically with a chosen disturbance ratio alpha = d1/d2
(eq. A-10): channel 1 drives the shaker under base accelerometer 1, channel 2 the one under
accelerometer 2.  The generator is reached on any pyserial URL under its own scheme, ``scpi:``:
a USB or RS-232 port (``scpi:///dev/ttyUSB1``), or a LAN instrument's raw SCPI socket
(``scpi:socket://HOST:5025``); ``serial:`` is ambdaq's own controller protocol, another thing.
The commands are the common SCPI
subset of two-channel generators (docs/protocol.md, "Shaker generator"); ``ambdaq sim serve
--profile base-motion`` serves a simulated one that moves the simulated base.

Shaker gain: the base acceleration per generator volt (peak per peak), in m/s^2 / V, the same for
both channels; the recorded accelerometers give the motion actually reached.
"""

from __future__ import annotations

import cmath
import math

import serial

from ..errors import BadInputError, DeviceError
from .url import Scheme

MAX_VPP = 10.0  # the generator's output range into its shaker amplifier, V peak to peak
MAX_ERRORS = 32  # longer than any generator's error queue


def drive_problem(d2_peak: float, ratio: complex, gain: float) -> str:
    """Why the generator cannot make this motion ('' if it can).

    Parameters
    ----------
    d2_peak : float
        Peak base acceleration at accelerometer 2, in m/s^2.
    ratio : complex
        alpha = d1 / d2.
    gain : float
        Shaker gain, in m/s^2 per V.
    """
    vpp = 2 * d2_peak * max(1.0, abs(ratio)) / gain
    if vpp > MAX_VPP:
        return (f"{d2_peak:g} m/s^2 with |alpha| {abs(ratio):g} needs {vpp:.3g} Vpp at a shaker gain of "
                f"{gain:g} m/s^2/V; the generator gives {MAX_VPP:g} Vpp")
    return ""


SCPI = Scheme("scpi", "scpi:PORT[?baud=N] (PORT: anything pyserial opens)", ("baud",), opaque=True)
"""An SCPI instrument's URL: its own scheme, so that ``serial:`` means one protocol, ambdaq's."""


class Shaker:
    """A two-channel SCPI generator driving the base shakers.

    Parameters
    ----------
    url : str
        ``scpi:...`` URL of the generator (``?baud=`` for a serial port; default 115200).
    gain : float
        Shaker gain, base acceleration per generator volt, in m/s^2 / V.
    timeout : float
        How long a query may take, in s.
    """

    def __init__(self, url: str, *, gain: float, timeout: float = 1.0) -> None:
        if not url.startswith(SCPI.name + ":"):
            raise BadInputError(f"shaker {url!r}: the generator is reached on a scpi: URL "
                                f"({SCPI.form}: scpi:///dev/ttyUSB1, scpi:socket://HOST:5025)")
        parsed = SCPI.parse(url)
        if not (gain > 0 and math.isfinite(gain)):
            raise BadInputError(f"shaker gain {gain!r}: expected a positive number of m/s^2 per V")
        self.url, self.gain = url, gain
        try:
            baud = int(parsed.options.get("baud", "115200"))
        except ValueError:
            raise BadInputError(f"option baud={parsed.options['baud']!r} in {url!r}: expected an integer") from None
        try:
            self._port = serial.serial_for_url(parsed.target, baudrate=baud, timeout=timeout, write_timeout=timeout)
        except ValueError as err:
            raise BadInputError(f"shaker {url!r}: {err}") from None
        except (serial.SerialException, OSError) as err:
            raise DeviceError(f"cannot open the shaker generator at {url}: {err}") from None
        try:
            self._port.reset_input_buffer()
            self.identity = self.query("*IDN?")
            self.write("*CLS")
        except BaseException:
            self._port.close()
            raise

    def write(self, line: str) -> None:
        """Send one SCPI line (commands joined by ``;:``)."""
        try:
            self._port.write(line.encode("ascii") + b"\n")
        except (serial.SerialException, OSError) as err:
            raise DeviceError(f"shaker generator at {self.url} lost: {err}") from None

    def query(self, line: str) -> str:
        """Send a query and return its one-line answer."""
        self.write(line)
        try:
            answer = self._port.readline()
        except (serial.SerialException, OSError) as err:
            raise DeviceError(f"shaker generator at {self.url} lost: {err}") from None
        if not answer.endswith(b"\n"):
            raise DeviceError(f"shaker generator at {self.url} did not answer {line!r}")
        return answer.decode("ascii", "replace").strip()

    def check(self, what: str) -> None:
        """Read the generator's error queue empty (``SYST:ERR?``); DeviceError with the first error."""
        first = ""
        for _ in range(MAX_ERRORS):
            answer = self.query("SYST:ERR?")
            code, _, text = answer.partition(",")
            try:
                if int(code) == 0:
                    break
            except ValueError:
                raise DeviceError(f"shaker generator at {self.url}: unreadable error report {answer!r}") from None
            first = first or f"{code} {text.strip(chr(34))}"
        if first:
            raise DeviceError(f"shaker generator at {self.url} refused {what}: {first}")

    def sine(self, freq_hz: float, d2_peak: float, ratio: complex) -> None:
        """Move the base harmonically: d2 = ``d2_peak`` sin(wt), d1 = alpha d2 (Kang & Jung eq. A-10).

        Parameters
        ----------
        freq_hz : float
            Frequency, in Hz.
        d2_peak : float
            Peak base acceleration at accelerometer 2, in m/s^2.
        ratio : complex
            alpha = d1 / d2 (dimensionless).
        """
        problem = drive_problem(d2_peak, ratio, self.gain)
        if problem:
            raise BadInputError(problem)
        v2 = 2 * d2_peak / self.gain  # V peak to peak
        v1 = abs(ratio) * v2
        cmds = []
        for ch, vpp, deg in ((1, v1, math.degrees(cmath.phase(ratio))), (2, v2, 0.0)):
            cmds += [f"SOUR{ch}:FUNC SIN", f"SOUR{ch}:FREQ {freq_hz:.9g}", f"SOUR{ch}:VOLT:UNIT VPP",
                     f"SOUR{ch}:VOLT {vpp:.9g}", f"SOUR{ch}:VOLT:OFFS 0", f"SOUR{ch}:PHAS {deg:.9g}"]
        cmds += ["SOUR1:PHAS:SYNC", "OUTP1 ON", "OUTP2 ON"]
        self.write(";:".join(cmds))
        self.check(f"a {freq_hz:g} Hz sine")

    def stop(self) -> None:
        """Both outputs off: the base at rest."""
        self.write("OUTP1 OFF;:OUTP2 OFF")
        self.check("outputs off")

    def close(self) -> None:
        self._port.close()
