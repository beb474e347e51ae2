"""An AMB controller over ASAM XCP, with pyxcp as the master: measurements from its A2L file
recorded through a DAQ list on the controller's event, and ``ambdaq push`` into a calibration
page (docs/hardware.md, "XCP").

Recording: one dynamic DAQ list on event ``event`` (default 0) with the first-ODT timestamp,
holding the counter (``counter``, default ``control_period``) and the measurements asked for.
The counter is each sample's ``seq`` (gaps are drops, counted as for any device); the DAQ
timestamp is its device time; its arrival is what the recorder's clock map learns from.

Pushing (:class:`~ambdaq.drivers.interfaces.BankPort`, the same rules as every controller):
seed & key for CAL/PAG (the algorithm by name, :mod:`.keys`); the image is downloaded into the
inactive page of segment 0 (``coefficient_bank``: u32 length + image); the device's CRC-32 of
it comes from BUILD_CHECKSUM (XCP_CRC_32); the host's CRC-32 and its push record go to
``push_record``; SET_CAL_PAGE (ECU) to that page is the commit, which the controller does at a
control-period boundary or refuses (its reason in ``bank_status``); the push log and layout are
read from ``bank_status``; ``store=1`` then asks STORE_CAL_REQ (non-volatile memory).

Parameters (:class:`~ambdaq.drivers.interfaces.Parameters`): the A2L's writable FLOAT64
characteristics, uploaded and downloaded as they are (Intel byte order), checked against their
limits first.  A download needs CAL/PAG unlocked: with the key of a push in the same session, else
``$AMBDAQ_UNLOCK_KEY``.  What the controller can do (:class:`~ambdaq.drivers.interfaces.Capabilities`)
is what its A2L says: coefficient banks if it describes ``coefficient_bank``, a speed set-point
and a test-signal input if a parameter's ``ambdaq`` annotation names that role (:mod:`.a2l`).
"""

from __future__ import annotations

import json
import logging
import os
import struct
import time
from contextlib import contextmanager

import numpy as np

from ...errors import BadInputError, DeviceError
from ..can.bus import MAX_LOAD, bus_load
from ..interfaces import UNLOCK_KEY_ENV, Capabilities, Controller, ExcitationSpec
from ..rows import RowQueue
from ..signals import SampleBlock, SignalGroup
from .a2l import SIZES, A2lFile, A2lParameter
from .keys import KeyAlgorithm

COUNTER = "control_period"
RES_CALPAG = 0x01
LENGTH = struct.Struct("<I")
TIMESTAMP_WRAP_NS = (1 << 32) * 1000  # a 4-byte timestamp in 1 us ticks turns every 71.6 min
SILENT_S = 2.0
TIMEOUT_S = 0.5  # a command unanswered this long is a timeout (pyxcp's default is 2 s)


def tcp_transport(host: str, port: int) -> tuple[str, dict]:
    """pyxcp's transport settings for XCP on TCP to ``host``:``port``."""
    return "ETH", {"Eth": {"host": host, "port": port, "protocol": "TCP"}}


def sxi_transport(port: str, baud: int) -> tuple[str, dict]:
    """pyxcp's transport settings for XCP on SxI on serial ``port``: LEN and CTR words, no checksum."""
    return "SXI", {"SxI": {"port": port, "bitrate": baud, "header_format": "HEADER_LEN_CTR_WORD",
                           "tail_format": "NO_CHECKSUM"}}


def can_transport(interface: str, channel: str, id_master: int, id_slave: int, bitrate: int,
                  open_delay: float | None) -> tuple[str, dict]:
    """pyxcp's transport settings for XCP on CAN on python-can's ``interface`` and ``channel``."""
    settings: dict = {"CAN": {"interface": interface, "channel": channel, "can_id_master": id_master,
                              "can_id_slave": id_slave, "bitrate": bitrate}}
    if open_delay is not None:
        settings["SlCan"] = {"sleep_after_open": open_delay}
    return "CAN", settings


def _application(layer: str, settings: dict):
    """pyxcp's configuration for the transport ``layer`` with ``settings``.  Made before anything
    of pyxcp asks for one: its DAQ classes otherwise make their own from ``sys.argv``."""
    from pyxcp.config import create_application_from_config, set_application

    app = create_application_from_config({"Transport": {k: v for k, v in settings.items() if k != "SlCan"}},
                                         log_level=logging.CRITICAL)
    for key, value in settings.get("SlCan", {}).items():
        setattr(app.transport.can.slcan, key, value)
    app.transport.layer = layer
    app.transport.timeout = TIMEOUT_S
    set_application(app)  # pyxcp's DAQ classes take their settings from the global one
    return app


XCP_ERRORS = {
    # ASAM MCD-1 XCP Part 2, the error codes of a negative response, and what each means
    0x00: ("ERR_CMD_SYNCH", "command processor synchronisation"),
    0x10: ("ERR_CMD_BUSY", "command not executed: the slave is busy"),
    0x11: ("ERR_DAQ_ACTIVE", "command rejected while DAQ is running"),
    0x12: ("ERR_PGM_ACTIVE", "command rejected while programming is running"),
    0x20: ("ERR_CMD_UNKNOWN", "unknown command, or an optional one the slave lacks"),
    0x21: ("ERR_CMD_SYNTAX", "command syntax invalid"),
    0x22: ("ERR_OUT_OF_RANGE", "a command parameter is out of range"),
    0x23: ("ERR_WRITE_PROTECTED", "the memory location is write protected"),
    0x24: ("ERR_ACCESS_DENIED", "the memory location is not accessible"),
    0x25: ("ERR_ACCESS_LOCKED", "access denied: seed & key is required"),
    0x26: ("ERR_PAGE_NOT_VALID", "the page is not available"),
    0x27: ("ERR_MODE_NOT_VALID", "the page mode is not available"),
    0x28: ("ERR_SEGMENT_NOT_VALID", "the segment is not valid"),
    0x29: ("ERR_SEQUENCE", "commands out of sequence"),
    0x2A: ("ERR_DAQ_CONFIG", "the DAQ configuration is not valid"),
    0x30: ("ERR_MEMORY_OVERFLOW", "memory overflow"),
    0x31: ("ERR_GENERIC", "generic error"),
    0x32: ("ERR_VERIFY", "the slave's verification found an error"),
}


def _xcp_error_text(err) -> str:
    """``ERR_NAME (meaning)`` of a pyxcp error, else its own text."""
    code = getattr(err, "error_code", None)
    try:
        name, meaning = XCP_ERRORS[int(code)]
    except (TypeError, ValueError, KeyError):
        return str(err)
    return f"{name} ({meaning})"


@contextmanager
def xcp_errors(url: str, what: str):
    """pyxcp's errors (XCP error responses, timeouts, a refused or lost connection) while doing
    ``what`` with the slave at ``url``, as one DeviceError."""
    from pyxcp.master.errorhandler import SystemExit as XcpError
    from pyxcp.master.errorhandler import UnrecoverableError, set_suppress_xcp_error_log
    from pyxcp.types import XcpTimeoutError
    from serial import SerialException

    set_suppress_xcp_error_log(True)  # no log or frame dump of pyxcp's own: the one line below says it
    try:
        yield
    except (XcpError, UnrecoverableError) as err:
        raise DeviceError(f"{url}: {what}: the controller answered {_xcp_error_text(err)}") from None
    except XcpTimeoutError:
        raise DeviceError(f"{url}: {what}: no answer (timeout)") from None
    except (OSError, SerialException) as err:
        raise DeviceError(f"{url}: {what}: {err}") from None
    finally:
        set_suppress_xcp_error_log(False)


def _capabilities(url: str, a2l: A2lFile, control_rate_hz: float) -> Capabilities:
    """What the A2L says the controller can do (its parameters' ``ambdaq`` roles, :mod:`.a2l`);
    a role that cannot be read is a BadInputError naming the parameter."""
    speed, excitation = None, None
    for param in a2l.parameters.values():
        role = param.role.get("role")
        if role == "speed" and param.count == 1:
            speed = param.name
        elif role == "test-signal":
            try:
                if param.count != 3 or param.role["unit"] not in ("m", "V"):
                    raise ValueError("3 values and unit m or V")
                excitation = ExcitationSpec(param.name, tuple(param.role["axes"].split(",")), param.role["unit"],
                                            float(param.role["min_amplitude"]), float(param.role["max_amplitude"]),
                                            control_rate_hz)
            except (KeyError, ValueError) as err:
                raise BadInputError(f"A2L file {a2l.path}: {param.name}: a test-signal parameter needs 3 values and "
                                    f"axes=, unit=m|V, min_amplitude=, max_amplitude= in its ambdaq annotation "
                                    f"({type(err).__name__}: {err})") from None
    return Capabilities(banks="coefficient_bank" in a2l.blobs, excitation=excitation, speed_parameter=speed)


def ask_slave(url: str, transport: tuple[str, dict]) -> dict[str, str]:
    """Who answers XCP at ``url``: CONNECT, GET_ID (the A2L project), GET_STATUS and the first
    event channel; DeviceError if nothing does."""
    from pyxcp.master import Master

    with xcp_errors(url, "ask"):
        with Master(transport[0].lower(), config=_application(*transport)) as x:
            got = x.connect()
            out = {"url": url, "asap2_name": x.identifier(1), "max_cto": str(got.maxCto), "max_dto": str(got.maxDto),
                   "byte_order": str(got.commModeBasic.byteOrder),
                   "resources": ",".join(r for r in ("calpag", "daq", "stim", "pgm") if getattr(got.resource, r)),
                   "protected": ",".join(r for r in ("calpag", "daq", "stim", "pgm")
                                         if getattr(x.getStatus().resourceProtectionStatus, r))}
            if got.resource.daq:
                from pyxcp.daq_stim import event_channel_cycle_to_ns

                info = x.getDaqEventInfo(0)
                out["event_0_period_us"] = f"{event_channel_cycle_to_ns(info.eventChannelTimeCycle, info.eventChannelTimeUnit) / 1e3:g}"
            x.disconnect()
    return out


class XcpController(Controller):
    """The controller reached through ``transport``, described by ``a2l``.

    Parameters
    ----------
    url : str
        Its device URL (for messages and metadata).
    transport : (str, dict)
        pyxcp's transport layer and its settings (:func:`tcp_transport`, :func:`sxi_transport`).
    a2l : A2lFile
        Its A2L file.
    name : str
        Device name in the recording.
    measurements : list of str, optional
        A2L measurements to record (default: every one the A2L places in a topic, but the counter).
    counter : str
        The measurement that counts control periods (each sample's seq).
    event : int
        DAQ event channel to sample on.
    key_algorithm : callable
        The seed & key algorithm (:mod:`.keys`).
    store : bool
        After a push, ask the controller to store the page in non-volatile memory.
    prescaler : int
        Sample every this many events (the DAQ list's prescaler); each sample's seq is then the
        counter divided by it.
    bus_bitrate : int, optional
        On CAN: the bus's bit rate, to refuse a DAQ list the bus cannot carry (above 80 % load).
    """

    def __init__(self, url: str, transport: tuple[str, dict], a2l: A2lFile, *, name: str = "controller",
                 measurements: list[str] | None = None, counter: str = COUNTER, event: int = 0,
                 key_algorithm: KeyAlgorithm, store: bool = False, prescaler: int = 1,
                 bus_bitrate: int | None = None) -> None:
        from pyxcp.daq_stim import DaqList, DaqOnlinePolicy, event_channel_cycle_to_ns
        from pyxcp.master import Master

        app = _application(*transport)
        self.url, self.a2l, self.name, self.event, self.store = url, a2l, name, event, store
        if not 1 <= prescaler <= 255:
            raise BadInputError(f"{url}: prescaler must be 1..255, not {prescaler}")
        self.prescaler = prescaler
        self.key_algorithm = key_algorithm
        if counter not in a2l.measurements:
            raise DeviceError(f"{url}: the A2L has no counter measurement {counter!r} (counter=NAME names it)")
        self.counter = a2l.measurements[counter]
        chosen = measurements or [n for n in a2l.measurements if n != counter]
        missing = [n for n in chosen if n not in a2l.measurements]
        if missing:
            raise DeviceError(f"{url}: the A2L has no measurement {missing[0]!r}")
        by_topic: dict[str, list] = {}
        for n in chosen:  # grouped by topic, in the order topics first appear
            by_topic.setdefault(a2l.measurements[n].topic, []).append(a2l.measurements[n])
        self.fields = [m for group in by_topic.values() for m in group]
        self._groups = [SignalGroup(topic, ms[0].type_name, tuple(m.field for m in ms), tuple(m.unit for m in ms))
                        for topic, ms in by_topic.items()]
        self._columns, k = [], 1  # payload columns of each group (column 0: the counter)
        for ms in by_topic.values():
            self._columns.append(np.arange(k, k + len(ms)))
            k += len(ms)
        self._factor = np.array([1.0] + [m.factor for m in self.fields])
        self._offset = np.array([0.0] + [m.offset for m in self.fields])
        self._rows = RowQueue(SILENT_S)
        self._failure: str | None = None
        owner = self

        class Sink(DaqOnlinePolicy):
            """Every DAQ list sample as a row (seq, arrival ns, device ns, raw values)."""

            def initialize(self) -> None:
                pass

            def finalize(self) -> None:
                pass

            def on_daq_list(self, _daq_list: int, _ts0: int, ts1: int, payload: list) -> None:
                # the counter steps by the prescaler from one sample to the next
                owner._rows.rows.append((payload[0] // owner.prescaler, time.time_ns(), ts1, payload))

        self._sink = Sink([DaqList(name="ambdaq", event_num=event, stim=False, enable_timestamps=True,
                                   measurements=[(m.name, m.address, 0, m.datatype) for m in [self.counter, *self.fields]],
                                   priority=0, prescaler=prescaler)])
        self._xcp = None
        try:
            with self._errors("connect"):
                self._xcp = Master(transport[0].lower(), config=app, policy=self._sink)
                self._xcp.__enter__()
                self._xcp.connect()
                if self._xcp.slaveProperties.optionalCommMode:
                    self._xcp.getCommModeInfo()
                self.project = self._xcp.identifier(1)
                info = self._xcp.getDaqEventInfo(event)
                self._constants = {name: ",".join(repr(v) for v in struct.unpack(f"<{n}d", self._fetch(address, 8 * n)))
                                   for name, (address, n) in a2l.constants.items()}
            period_ns = event_channel_cycle_to_ns(info.eventChannelTimeCycle, info.eventChannelTimeUnit)
            if period_ns <= 0:
                raise DeviceError(f"{url}: event {event} is not cyclic; ambdaq records cyclic events only")
            if bus_bitrate is not None:
                self._check_bus_load(1e9 / period_ns, bus_bitrate)
            self._capabilities = _capabilities(url, a2l, 1e9 / period_ns)
        except (DeviceError, BadInputError):
            if self._xcp is not None:
                self._xcp.close()
            raise
        self.sample_rate = 1e9 / period_ns / prescaler
        self._key: str | None = None
        self._streaming = False
        self._session_over = False
        self._last_stamp: int | None = None
        self._wraps = 0

    # --- errors -----------------------------------------------------------------------------------

    def _errors(self, what: str):
        return xcp_errors(self.url, what)

    def _check_bus_load(self, event_hz: float, bitrate: int) -> None:
        """Refuse a DAQ list whose DTOs would load the CAN bus above MAX_LOAD: every sample
        is ceil((4-byte timestamp + entries) / 7) frames of PID + 7 bytes (ASAM XCP Part 3, CAN)."""
        frames = -(-(4 + sum(SIZES[m.datatype] for m in [self.counter, *self.fields])) // 7)
        load = bus_load([8] * frames, event_hz / self.prescaler, bitrate)
        if load > MAX_LOAD:
            fits = int(np.ceil(bus_load([8] * frames, event_hz, bitrate) / MAX_LOAD))
            raise BadInputError(f"{self.url}: {len(self.fields) + 1} measurements every {self.prescaler} event(s) "
                                f"are {frames} frames per sample, {load:.0%} of the {bitrate:,} bit/s bus; "
                                f"give prescaler={fits} or more, or fewer measurements")

    # --- Source -----------------------------------------------------------------------------------

    def signal_groups(self) -> list[SignalGroup]:
        return list(self._groups)

    def identity(self) -> dict[str, str]:
        return {"url": self.url, "kind": "xcp controller", "model": self.project, "a2l": self.a2l.path.name,
                "a2l_sha256": self.a2l.sha256, "sample_rate_hz": f"{self.sample_rate:g}", "event": str(self.event),
                "counter": self.counter.name}

    def device_calibration(self) -> dict[str, str]:
        """The controller's calibration constants (A2L FLOAT64 characteristics, read at open)."""
        return dict(self._constants)

    def start(self, n_samples: int | None) -> None:
        with self._errors("DAQ setup"):
            self._sink.setup()
            self._rows.start(n_samples)
            self._sink.start()
        self._streaming = True

    def read(self) -> SampleBlock | None:
        taken = self._rows.take(lambda: self._failure, lambda s: f"{self.url}: no DAQ data for {s:.1f} s")
        if taken is None:
            return None
        rows, seq = taken
        stamp = np.array([r[2] for r in rows], dtype=np.int64)
        # the 1 us timestamp turns every 71.6 min: unwrap it (pyxcp counts it from the first DTO)
        wraps = np.cumsum(np.diff(stamp, prepend=stamp[0] if self._last_stamp is None else self._last_stamp) < 0)
        device = stamp + (self._wraps + wraps) * TIMESTAMP_WRAP_NS
        self._wraps += int(wraps[-1])
        self._last_stamp = int(stamp[-1])
        raw = np.array([r[3] for r in rows], dtype=np.float64)
        values = raw * self._factor + self._offset
        return SampleBlock(device, (seq & 0xFFFFFFFF).astype(np.uint32),
                           {g.topic: values[:, cols] for g, cols in zip(self._groups, self._columns)},
                           received_ns=int(rows[-1][1]))

    # --- Controller -----------------------------------------------------------------------------

    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    def _parameter(self, name: str) -> A2lParameter:
        found = self.a2l.parameters.get(name)
        if found is None:
            known = ", ".join(self.a2l.parameters) or "none"
            raise DeviceError(f"{self.url}: the A2L describes no writable FLOAT64 parameter {name!r} (it has: {known})")
        return found

    def read_param(self, name: str) -> np.ndarray:
        param = self._parameter(name)
        with self._errors(f"read {name}"):
            raw = self._fetch(param.address, 8 * param.count)
        return np.array(struct.unpack(f"<{param.count}d", raw))

    def write_param(self, name: str, values) -> None:
        """Download ``values`` to parameter ``name`` after checking their number and its limits;
        unlocks CAL/PAG first if it is protected (the push's key, else $AMBDAQ_UNLOCK_KEY)."""
        param = self._parameter(name)
        values = np.atleast_1d(np.asarray(values, dtype=float))
        if values.shape != (param.count,):
            raise DeviceError(f"{self.url}: {name} takes {param.count} value(s), not {values.size}")
        if not np.all(np.isfinite(values)) or np.any(values < param.lower) or np.any(values > param.upper):
            raise DeviceError(f"{self.url}: {name}: values must be finite and within {param.lower:g} .. {param.upper:g} "
                              "(the A2L's limits)")
        if self._calibration_locked(f"write {name}"):
            key = self._key or os.environ.get(UNLOCK_KEY_ENV)
            if not key:
                raise DeviceError(f"{self.url}: writing {name} over XCP needs calibration unlocked (seed & key): "
                                  f"set {UNLOCK_KEY_ENV}")
            self._key = key
            self._answer_seed(key)
        with self._errors(f"write {name}"):
            self._download(param.address, struct.pack(f"<{param.count}d", *values))

    # --- BankPort -------------------------------------------------------------------------------

    def _blob(self, name: str) -> tuple[int, int]:
        if name not in self.a2l.blobs:
            raise DeviceError(f"{self.url}: the A2L describes no {name!r}, so this controller takes no push over XCP")
        return self.a2l.blobs[name]

    def _download(self, address: int, data: bytes) -> None:
        """DOWNLOAD ``data`` at ``address``, one command and its response at a time (pyxcp's own
        ``push`` sends full chunks without waiting for their responses, as in block mode, which
        this slave does not offer)."""
        self._xcp.setMta(address)
        step = self._xcp.slaveProperties.maxCto - 2
        for i in range(0, len(data), step):
            self._xcp.download(data[i : i + step])

    def _fetch(self, address: int, length: int) -> bytes:
        self._xcp.setMta(address)
        return bytes(self._xcp.fetch(length)) if length else b""

    def _pages(self) -> tuple[int, int]:
        """(active, inactive) page of segment 0: the ECU's page runs."""
        active = int(self._xcp.getCalPage(0x01, 0))
        return active, 1 - active

    def _page_image(self, page: int) -> tuple[int, int]:
        """Length and device-computed CRC-32 (BUILD_CHECKSUM, XCP_CRC_32) of the image on ``page``."""
        base, size = self._blob("coefficient_bank")
        self._xcp.setCalPage(0x02, 0, page)
        (length,) = LENGTH.unpack(self._fetch(base, 4))
        if not 0 < length <= size - 4:
            return 0, 0
        self._xcp.setMta(base + 4)
        got = self._xcp.buildChecksum(length)
        if got.checksumType != "XCP_CRC_32":
            raise DeviceError(f"{self.url}: BUILD_CHECKSUM answers {got.checksumType}, not XCP_CRC_32")
        return length, int(got.checksum)

    def _calibration_locked(self, what: str) -> bool:
        with self._errors(what):
            return bool(self._xcp.getStatus().resourceProtectionStatus.calpag)

    def unlock(self, key: str) -> None:
        self._key = key
        if self._calibration_locked("unlock"):
            self._answer_seed(key)

    def _answer_seed(self, key: str) -> None:
        """GET_SEED and UNLOCK for CAL/PAG with ``key`` (calibration is locked)."""
        with self._errors("unlock"):
            seed = self._xcp.getSeed(0, RES_CALPAG)
            answer = self.key_algorithm(RES_CALPAG, bytes(seed.seed or b""), key)
        try:
            with self._errors("unlock"):
                self._xcp.unlock(len(answer), answer)
        except DeviceError:
            self._session_over = True  # a slave refusing a key ends the session (ASAM XCP Part 2, UNLOCK)
            raise DeviceError(f"{self.url}: unlock refused: wrong key for calibration (seed & key)") from None

    def write_bank(self, image: bytes) -> None:
        base, size = self._blob("coefficient_bank")
        if len(image) + 4 > size:
            raise DeviceError(f"{self.url}: a {len(image)}-byte image does not fit the {size}-byte calibration page")
        with self._errors("write the inactive page"):
            _active, inactive = self._pages()
            self._xcp.setCalPage(0x02, 0, inactive)
            self._download(base, LENGTH.pack(len(image)) + image)

    def bank_status(self) -> dict:
        base, size = self._blob("bank_status")
        with self._errors("read the bank status"):
            (length,) = LENGTH.unpack(self._fetch(base, 4))  # SET_MTA at its start takes the snapshot
            if not 0 < length <= size - 4:
                raise DeviceError(f"{self.url}: bank_status holds no status (length {length})")
            status = json.loads(self._fetch(base + 4, length))
            active, inactive = self._pages()
            a_len, a_crc = self._page_image(active)
            i_len, i_crc = self._page_image(inactive)
        status.update(active_bank=active, active_crc32=f"{a_crc:08x}", active_length=a_len,
                      inactive_crc32=f"{i_crc:08x}", inactive_length=i_len)
        return status

    def commit_bank(self, crc: int, record: dict) -> int:
        base, size = self._blob("push_record")
        body = json.dumps({**record, "crc32": f"{crc:08x}"}).encode()
        if len(body) + 4 > size:
            raise DeviceError(f"{self.url}: the push record ({len(body)} bytes) does not fit push_record")
        with self._errors("write the push record"):
            _active, inactive = self._pages()
            self._download(base, LENGTH.pack(len(body)) + body)
        try:
            with self._errors("switch the page"):
                self._xcp.setCalPage(0x01, 0, inactive)
        except DeviceError as err:
            reason = self.bank_status().get("last_refusal") or str(err)
            raise DeviceError(f"{self.url}: the controller refused the page switch: {reason}") from None
        status = self.bank_status()
        if self.store:  # the switch locked calibration again: storing needs it unlocked
            self.unlock(self._key)
            with self._errors("store the page (STORE_CAL_REQ)"):
                self._xcp.setRequest(0x01, 0)
        return int(status.get("last_effective_sample", -1))

    def read_bank(self, which: str, length: int) -> bytes:
        base, _size = self._blob("coefficient_bank")
        with self._errors(f"read the {which} page"):
            active, inactive = self._pages()
            self._xcp.setCalPage(0x02, 0, active if which == "active" else inactive)
            return self._fetch(base + 4, length)

    def _close(self) -> None:
        self._rows.closed.set()
        try:
            if self._session_over:
                return
            if self._streaming:
                with self._errors("DAQ stop"):
                    self._sink.stop()
            with self._errors("disconnect"):
                self._xcp.disconnect()
        except DeviceError:
            pass
        finally:
            try:
                self._xcp.close()
            except Exception:  # a socket already gone
                pass
