"""The simulated AMB controller's memory as its XCP slave shows it, and the A2L file that says so.

Addresses (byte granularity, Intel byte order)::

    0x0001_0000  control_period   ULONG         the control period's index (a sample's seq)
    0x0001_0004  amb.gap.front_x  FLOAT32_IEEE  every field of every group the rig streams, in
    ...                                         SI units, named TOPIC.FIELD with / turned to .
    0x0002_0000  coefficient_bank 32 KiB        calibration segment 0, pages 0 and 1: the two
                                                coefficient banks as u32 length + bank image
                                                (ambdaq/drivers/coefbank.py); page = bank
    0x0003_0000  push_record      1 KiB         u32 length + JSON the host writes before a page
                                                switch: the CRC-32 it expects and its push record
    0x0003_1000  bank_status      16 KiB        u32 length + JSON: active bank, layout, push log,
                                                the last refusal (read-only; a snapshot taken
                                                when the MTA is set to its start)
    0x0004_0000  rotor.mass_kg    FLOAT64_IEEE  the controller's calibration constants (its rig's
    ...                                         calibration that is numbers: sensor gain, rotor
                                                model), a VALUE or VAL_BLK each (read-only)
    0x0005_0000  pid.p            FLOAT64_IEEE  the controller's writable parameters (the serial
    ...                                         port's PARAM_WRITE ones of fixed size: gains,
                                                speed.rpm, exc.signal), a VALUE or VAL_BLK each

A read of measurement RAM returns the rig's newest sample, as a read of a controller's RAM
returns the values of its last control period; a DAQ list samples the same image at every
control period (:meth:`MeasurementMap.images`).  A read of a parameter returns what it reads now
(``speed.rpm``: the present speed), and a write is checked and taken as the serial port's
PARAM_WRITE takes it (:class:`ControllerParameters`).
"""

from __future__ import annotations

import json
import re
import struct
import time
from dataclasses import dataclass

import numpy as np

from ...drivers.coefbank import crc32
from ...drivers.xcp.wire import (ERR_ACCESS_LOCKED, ERR_CMD_BUSY, ERR_OUT_OF_RANGE,
                                 ERR_PAGE_NOT_VALID, ERR_SEGMENT_NOT_VALID, ERR_VERIFY, ERR_WRITE_PROTECTED)
from ..profiles import profile
from .banks import BankRefused, CoefficientBanks
from .firmware import Param
from .rig_server import RigServer

MEASUREMENT_BASE = 0x0001_0000
CAL_BASE, CAL_SIZE = 0x0002_0000, 0x8000
RECORD_BASE, RECORD_SIZE = 0x0003_0000, 0x400
STATUS_BASE, STATUS_SIZE = 0x0003_1000, 0x4000
CONSTANTS_BASE = 0x0004_0000
PARAMETERS_BASE = 0x0005_0000


def asap2_name(rig_profile: str) -> str:
    """The A2L's PROJECT name (what GET_ID type 1 answers) of the controller of a rig profile:
    ``AMBDAQ_SPINDLE``, ``AMBDAQ_FLEXIBLE`` ..."""
    return "AMBDAQ_" + re.sub(r"[^A-Z0-9]", "_", rig_profile.upper())


COUNTER = "control_period"
LENGTH = struct.Struct("<I")


@dataclass(frozen=True)
class Measurement:
    """One measurement variable: ``name`` (A2L), ``datatype`` (A2L), ``address``, ``unit``; the
    rig ``topic``, its message ``type_name`` and the ``field`` it holds ("" for the counter)."""

    name: str
    datatype: str
    address: int
    unit: str
    topic: str = ""
    type_name: str = ""
    field: str = ""


def measurement_map(rig) -> list[Measurement]:
    """The counter, then every field of every signal group ``rig`` streams, a FLOAT32 each."""
    out = [Measurement(COUNTER, "ULONG", MEASUREMENT_BASE, "")]
    address = MEASUREMENT_BASE + 4
    for group in rig.signal_groups():
        for field, unit in zip(group.fields, group.units):
            out.append(Measurement(f"{group.topic.strip('/').replace('/', '.')}.{field}", "FLOAT32_IEEE", address,
                                   unit, group.topic, group.type_name, field))
            address += 4
    return out


class MeasurementMap:
    """The controller's measurement RAM: the counter and each rig field at its address."""

    def __init__(self, server: RigServer) -> None:
        self.server = server
        self.measurements = measurement_map(server.rig)
        self.size = 4 * len(self.measurements)
        self.end = MEASUREMENT_BASE + self.size
        self._topics = [g.topic for g in server.rig.signal_groups()]

    def images(self, seq: np.ndarray, values: dict[str, np.ndarray]) -> np.ndarray:
        """The RAM image at each of ``len(seq)`` control periods: uint8, shape (n, size)."""
        n = seq.shape[0]
        out = np.empty((n, self.size), dtype=np.uint8)
        out[:, :4] = seq.astype("<u4").view(np.uint8).reshape(n, 4)
        floats = np.concatenate([values[t] for t in self._topics], axis=1).astype("<f4")
        out[:, 4:] = floats.view(np.uint8).reshape(n, self.size - 4)
        return out

    def read(self, address: int, length: int) -> bytes:
        """``length`` bytes from ``address`` of the newest sample; IndexError outside the map."""
        if address < MEASUREMENT_BASE or address + length > self.end:
            raise IndexError(address)
        step, rows = self.server.sample_at(time.time_ns())
        image = self.images(np.array([step], dtype=np.uint32), {t: rows[t][None, :] for t in self._topics})[0]
        return image[address - MEASUREMENT_BASE : address - MEASUREMENT_BASE + length].tobytes()


class CalibrationConstants:
    """The controller's calibration that is numbers, FLOAT64 each from CONSTANTS_BASE (read-only)."""

    def __init__(self, calibration: dict[str, str]) -> None:
        self.entries: list[tuple[str, int, list[float]]] = []  # (name, address, values)
        address, image = CONSTANTS_BASE, b""
        for name, text in calibration.items():
            try:
                values = [float(v) for v in str(text).split(",")]
            except ValueError:
                continue  # words ("units"), not numbers
            self.entries.append((name, address, values))
            image += struct.pack(f"<{len(values)}d", *values)
            address += 8 * len(values)
        self.image = image

    def owns(self, address: int) -> bool:
        return CONSTANTS_BASE <= address < CONSTANTS_BASE + len(self.image)

    def read(self, address: int, length: int) -> bytes:
        off = address - CONSTANTS_BASE
        if off < 0 or off + length > len(self.image):
            raise IndexError(address)
        return self.image[off : off + length]


class ControllerParameters:
    """The controller's writable parameters of fixed size, FLOAT64 each from PARAMETERS_BASE.

    A read returns what each parameter reads now.  A write is taken as the serial port's
    PARAM_WRITE takes it: checked first (ERR_OUT_OF_RANGE, nothing changed, if the firmware
    refuses it), then written to the rig.  Never half a value: a parameter takes its new values
    once the bytes written to it since it last changed make whole values, and keeps what it reads
    now for the rest.  A block written in one DOWNLOAD (TCP, SxI) changes at once; on CAN, whose
    DOWNLOAD carries 6 bytes, a block of three values (``exc.signal``: axis, amplitude,
    frequency) changes when its last piece arrives, a longer one by whole values as they come.
    """

    def __init__(self, rig, parameters: dict[str, Param]) -> None:
        self.rig = rig
        self.entries: list[tuple[str, int, Param]] = []  # (name, address, parameter)
        address = PARAMETERS_BASE
        for name, param in parameters.items():
            if param.write is not None and param.size > 0:
                self.entries.append((name, address, param))
                address += 8 * param.size
        self.end = address
        self._pending: dict[str, dict[int, int]] = {}  # name -> {byte offset: byte} written, not yet taken
        self._held: dict[str, bytes] = {}  # name -> the bytes last written and taken, as firmware RAM holds them

    def owns(self, address: int) -> bool:
        return PARAMETERS_BASE <= address < self.end

    def forget(self) -> None:
        """Drop what a session left half-written (a new session starts from whole values)."""
        self._pending.clear()

    def _image(self, name: str, param: Param) -> bytes:
        """A parameter's bytes: those last written while the rig still runs them (the rig keeps some
        gains in another form, and a double made back from it may differ in its last bit from the
        one written, which the firmware's RAM would hold), else the rig's values."""
        now = param.read(self.rig)
        held = self._held.get(name)
        if held is not None and np.allclose(struct.unpack(f"<{param.size}d", held), now, rtol=1e-12, atol=0.0):
            return held
        return struct.pack(f"<{param.size}d", *now)

    def read(self, address: int, length: int) -> bytes:
        if not (PARAMETERS_BASE <= address and address + length <= self.end):
            raise IndexError(address)
        image = b"".join(self._image(name, param) for name, _base, param in self.entries)
        off = address - PARAMETERS_BASE
        return image[off : off + length]

    def write(self, address: int, data: bytes, unlocked: bool) -> None:
        if not unlocked:
            raise Refused(ERR_ACCESS_LOCKED, "calibration is locked: unlock (seed & key) first")
        end = address + len(data)
        if not (PARAMETERS_BASE <= address and end <= self.end):
            raise Refused(ERR_OUT_OF_RANGE, f"no parameter memory at 0x{address:08X}..0x{end:08X}")
        for name, base, param in self.entries:
            lo, hi = max(address, base), min(end, base + 8 * param.size)
            if lo >= hi:
                continue
            pending = self._pending.setdefault(name, {})
            pending.update({i - base: data[i - address] for i in range(lo, hi)})
            if any(sum(8 * k + j in pending for j in range(8)) < 8 for k in {off // 8 for off in pending}):
                continue  # a value is still half-written
            image = bytearray(self._image(name, param))
            for off, byte in self._pending.pop(name).items():
                image[off] = byte
            values = np.array(struct.unpack(f"<{param.size}d", image))
            problem = param.check(self.rig, values)
            if problem:
                raise Refused(ERR_OUT_OF_RANGE, f"{name}: {problem}")
            param.write(self.rig, values)
            self._held[name] = bytes(image)


class Refused(Exception):
    """A calibration access the slave refuses: ``code`` is the XCP error code to answer."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


REFUSAL_CODES = {"locked": ERR_ACCESS_LOCKED, "crc": ERR_VERIFY, "bad_value": ERR_VERIFY, "busy": ERR_CMD_BUSY}


class CalibrationPages:
    """Calibration segment 0 over the controller's two coefficient banks.

    The ECU page is the active bank; the master reads and writes the page it selects for XCP
    access, and only the inactive one takes writes (ERR_WRITE_PROTECTED otherwise), so nothing
    written changes what runs until the ECU page is switched.  The switch (SET_CAL_PAGE, ECU) is
    the banks' commit: the CRC-32 the host wrote in ``push_record`` must match, the image must
    decode and pass the firmware's range checks, and the banks swap between two control periods.
    """

    def __init__(self, banks: CoefficientBanks) -> None:
        self.banks = banks
        self.xcp_page = banks.active
        self._staged = bytearray(CAL_SIZE)  # the inactive page as the master wrote it
        self._record = bytearray(RECORD_SIZE)
        self._status = b""
        self.last_refusal = ""
        self.last_effective_sample = -1
        self.stored: tuple[str, bytes] | None = None  # (CRC-32, image) kept in non-volatile memory
        self._reset_staged()

    @property
    def ecu_page(self) -> int:
        return self.banks.active

    def _reset_staged(self) -> None:
        held = self.banks.read("inactive", 0, CAL_SIZE)
        self._staged[:] = bytes(CAL_SIZE)
        self._staged[: 4 + len(held)] = LENGTH.pack(len(held)) + held

    def _page_bytes(self, page: int) -> bytes | bytearray:
        """Page ``page`` as the master reads it (the staged page itself, not a copy per upload)."""
        if page == self.banks.active:
            image = self.banks.read("active", 0, CAL_SIZE)
            return LENGTH.pack(len(image)) + image
        return self._staged

    # --- memory access ----------------------------------------------------------------------

    def owns(self, address: int) -> bool:
        return CAL_BASE <= address < CAL_BASE + CAL_SIZE or RECORD_BASE <= address < RECORD_BASE + RECORD_SIZE \
            or STATUS_BASE <= address < STATUS_BASE + STATUS_SIZE

    def read(self, address: int, length: int) -> bytes:
        """Bytes of the XCP page, the push record or the status snapshot; IndexError outside."""
        for base, size, data in ((CAL_BASE, CAL_SIZE, None), (RECORD_BASE, RECORD_SIZE, self._record),
                                 (STATUS_BASE, STATUS_SIZE, self._status)):
            if base <= address and address + length <= base + size:
                if data is None:
                    data = self._page_bytes(self.xcp_page)
                off = address - base
                return bytes(data[off : off + length]).ljust(length, b"\0")
        raise IndexError(address)

    def write(self, address: int, data: bytes, unlocked: bool) -> None:
        """Write ``data`` to the inactive XCP page or the push record."""
        if not unlocked:
            raise Refused(ERR_ACCESS_LOCKED, "calibration is locked: unlock (seed & key) first")
        end = address + len(data)
        if CAL_BASE <= address and end <= CAL_BASE + CAL_SIZE:
            if self.xcp_page == self.banks.active:
                raise Refused(ERR_WRITE_PROTECTED, "the page the controller runs takes no writes")
            self._staged[address - CAL_BASE : end - CAL_BASE] = data
        elif RECORD_BASE <= address and end <= RECORD_BASE + RECORD_SIZE:
            self._record[address - RECORD_BASE : end - RECORD_BASE] = data
        else:
            raise Refused(ERR_OUT_OF_RANGE, f"no writable memory at 0x{address:08X}")

    def snapshot_status(self) -> None:
        """Take the status snapshot uploads at STATUS_BASE read."""
        body = json.dumps({**self.banks.status(), "ecu_page": self.ecu_page, "xcp_page": self.xcp_page,
                           "last_refusal": self.last_refusal, "last_effective_sample": self.last_effective_sample,
                           "stored_crc32": self.stored[0] if self.stored else ""}).encode()
        self._status = LENGTH.pack(len(body)) + body[: STATUS_SIZE - 4]

    # --- pages ------------------------------------------------------------------------------

    def set_page(self, mode: int, segment: int, page: int) -> None:
        """SET_CAL_PAGE: mode bit 0 the ECU's page (a switch: the banks' commit), bit 1 XCP's."""
        if segment != 0 and not mode & 0x80:
            raise Refused(ERR_SEGMENT_NOT_VALID, f"no segment {segment}")
        if page not in (0, 1):
            raise Refused(ERR_PAGE_NOT_VALID, f"no page {page}")
        if mode & 0x02:
            self.xcp_page = page
        if mode & 0x01 and page != self.banks.active:
            self._switch(page)

    def _switch(self, page: int) -> None:
        (length,) = LENGTH.unpack_from(self._staged)
        (rec_len,) = LENGTH.unpack_from(self._record)
        try:
            record = json.loads(bytes(self._record[4 : 4 + rec_len]).decode()) if 0 < rec_len <= RECORD_SIZE - 4 else {}
            expected = int(record.get("crc32", ""), 16) if isinstance(record, dict) else -1
        except (ValueError, UnicodeDecodeError):
            record, expected = {}, -1
        try:
            if not 0 < length <= CAL_SIZE - 4:
                raise BankRefused("bad_value", f"page {page} holds no image (length {length})")
            if expected < 0:
                raise BankRefused("crc", "push_record names no crc32 the host expects")
            self.banks.write(0, length, bytes(self._staged[4 : 4 + length]))
            self.last_effective_sample = self.banks.commit(expected, record)
        except BankRefused as err:
            self.last_refusal = f"{err.reason}: {err}"
            raise Refused(REFUSAL_CODES[err.reason], str(err)) from None
        self.last_refusal = ""
        self._record[:] = bytes(RECORD_SIZE)
        self.xcp_page = self.banks.active
        self._reset_staged()

    def store(self) -> None:
        """SET_REQUEST STORE_CAL_REQ: the active page to non-volatile memory."""
        image = self.banks.read("active", 0, CAL_SIZE)
        self.stored = (f"{crc32(image):08x}", image)


def a2l_text(rig) -> str:
    """The ASAM MCD-2 MC (A2L) description of the memory of ``rig``'s controller."""
    measurements = measurement_map(rig)
    blocks = []
    for m in measurements:
        what = f"{m.topic} {m.field}" if m.topic else "index of the control period (a sample's seq)"
        limits = "-1e12 1e12" if m.datatype.startswith("FLOAT") else "0 4294967295"
        # where ambdaq records it (docs/hardware.md, "XCP"): an ANNOTATION, which A2L keeps for such notes
        words = f"topic={m.topic} type={m.type_name} field={m.field}" if m.topic else "role=counter"
        note = f"""
      /begin ANNOTATION
        ANNOTATION_LABEL "ambdaq"
        /begin ANNOTATION_TEXT
          "{words}"
        /end ANNOTATION_TEXT
      /end ANNOTATION"""
        blocks.append(f"""    /begin MEASUREMENT {m.name} "{what}"
      {m.datatype} CM_IDENTITY_{_unit_id(m.unit)} 0 0 {limits}
      ECU_ADDRESS 0x{m.address:08X}
      PHYS_UNIT "{m.unit}"{note}
    /end MEASUREMENT""")
    units = sorted({m.unit for m in measurements})
    methods = "\n".join(f"""    /begin COMPU_METHOD CM_IDENTITY_{_unit_id(u)} "identity, {u or 'counts'}"
      IDENTICAL "%12.6" "{u}"
    /end COMPU_METHOD""" for u in units)
    blobs = "\n".join(f"""    /begin CHARACTERISTIC {name} "{what}"
      {kind} 0x{address:08X} RL_UBYTE 0 NO_COMPU_METHOD 0 255
      NUMBER {size}
    /end CHARACTERISTIC""" for name, what, kind, address, size in (
        ("coefficient_bank", "segment 0: u32 length + coefficient bank image; page 0 and 1 = bank 0 and 1",
         "VAL_BLK", CAL_BASE, CAL_SIZE),
        ("push_record", "u32 length + JSON: crc32 the host expects, its push record", "ASCII", RECORD_BASE,
         RECORD_SIZE),
        ("bank_status", "u32 length + JSON: banks, layout, push log, last refusal (read-only)", "ASCII",
         STATUS_BASE, STATUS_SIZE)))
    constants = "\n".join(f"""    /begin CHARACTERISTIC {name} "calibration constant"
      {"VALUE" if len(values) == 1 else "VAL_BLK"} 0x{address:08X} RL_FLOAT64 0 NO_COMPU_METHOD -1e300 1e300{
      "" if len(values) == 1 else f"{chr(10)}      NUMBER {len(values)}"}
      READ_ONLY
    /end CHARACTERISTIC""" for name, address, values in CalibrationConstants(rig.calibration()).entries)
    firmware = profile(rig.profile).firmware
    table = ControllerParameters(rig, firmware.parameters if firmware is not None else {})
    parameters = "\n".join(_parameter_block(name, address, param, _role(name, firmware.capabilities(rig)))
                            for name, address, param in table.entries)
    parameter_segment = f"""
      /begin MEMORY_SEGMENT PARAMETERS "the controller's parameters" DATA RAM INTERN 0x{PARAMETERS_BASE:08X} 0x{table.end - PARAMETERS_BASE:X} -1 -1 -1 -1 -1
      /end MEMORY_SEGMENT""" if table.entries else ""
    return f"""ASAP2_VERSION 1 71
/begin PROJECT {asap2_name(rig.profile)} "ambdaq simulated {rig.profile} AMB controller"
  /begin MODULE CONTROLLER "the XCP slave's memory (ambdaq/sim/devices/xcp_memory.py)"
    /begin A2ML
      block "IF_DATA" taggedunion if_data {{
        "AMBDAQ" struct {{ uint; }};  /* none used: an A2L without A2ML is reported as such by parsers */
      }};
    /end A2ML
    /begin MOD_PAR ""
      /begin MEMORY_SEGMENT MEASUREMENT_RAM "" DATA RAM INTERN 0x{MEASUREMENT_BASE:08X} 0x{len(measurements) * 4:X} -1 -1 -1 -1 -1
      /end MEMORY_SEGMENT
      /begin MEMORY_SEGMENT COEFFICIENTS "two pages: the coefficient banks" DATA FLASH INTERN 0x{CAL_BASE:08X} 0x{CAL_SIZE:X} -1 -1 -1 -1 -1
      /end MEMORY_SEGMENT{parameter_segment}
    /end MOD_PAR
    /begin MOD_COMMON ""
      BYTE_ORDER MSB_LAST
      ALIGNMENT_FLOAT32_IEEE 4
    /end MOD_COMMON
    /begin RECORD_LAYOUT RL_UBYTE
      FNC_VALUES 1 UBYTE ROW_DIR DIRECT
    /end RECORD_LAYOUT
    /begin RECORD_LAYOUT RL_FLOAT64
      FNC_VALUES 1 FLOAT64_IEEE ROW_DIR DIRECT
    /end RECORD_LAYOUT
{methods}
{chr(10).join(blocks)}
{blobs}
{constants}
{parameters}
  /end MODULE
/end PROJECT
"""


def _role(name: str, caps) -> str:
    """What ambdaq's drivers take a parameter for (docs/hardware.md, "XCP"): the text of its
    ``ambdaq`` ANNOTATION, or ''."""
    spec = caps.excitation
    if spec is not None and name == spec.parameter:
        return (f"role=test-signal axes={','.join(spec.axes)} unit={spec.unit} min_amplitude={spec.min_amplitude!r} "
                f"max_amplitude={spec.max_amplitude!r}")
    return "role=speed unit=rpm" if name == caps.speed_parameter else ""


def _parameter_block(name: str, address: int, param: Param, role: str) -> str:
    lo, hi = (f"{max(v, -1e300) if v < 0 else min(v, 1e300):g}" for v in (param.lo, param.hi))
    note = f"""
      /begin ANNOTATION
        ANNOTATION_LABEL "ambdaq"
        /begin ANNOTATION_TEXT
          "{role}"
        /end ANNOTATION_TEXT
      /end ANNOTATION""" if role else ""
    return f"""    /begin CHARACTERISTIC {name} "{param.doc.replace('"', "'")}"
      {"VALUE" if param.size == 1 else "VAL_BLK"} 0x{address:08X} RL_FLOAT64 0 NO_COMPU_METHOD {lo} {hi}{
      "" if param.size == 1 else f"{chr(10)}      NUMBER {param.size}"}{note}
    /end CHARACTERISTIC"""


def _unit_id(unit: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in unit) or "none"
