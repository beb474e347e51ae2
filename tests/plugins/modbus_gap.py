"""``modbus+tcp://HOST:PORT?unit=U&rate=HZ``: a probe conditioner read over Modbus TCP, its registers
described by a register-map file: the worked example of docs/architecture.md ("Adding a device
type"), a plug-in back-end as another package would ship it (its own module, one entry point).

A register map (TOML) names what each holding register is::

    [[register]]
    address = 0            # holding register, 0-based (function 0x03)
    type = "int16"         # int16, uint16, int32, uint32, float32 (two registers, high word first)
    topic = "/probes/gap"  # the topic it is recorded on
    field = "de_x"         # its field there
    scale = 1e-8           # SI = raw * scale + offset
    unit = "m"

Modbus TCP (MODBUS Messaging on TCP/IP Implementation Guide V1.0b; MODBUS Application Protocol
V1.1b3, 6.3 Read Holding Registers) has no clock and no stream: the back-end reads every mapped
register in one request per period of ``rate``, stamps each reply on the host clock, and counts a
period it could not keep (a late reply) as lost.  Discovery asks the hosts named in
``AMBDAQ_MODBUS_HOSTS`` (``HOST:PORT,...``) whether they answer.
"""

from __future__ import annotations

import os
import socket
import struct
import time
import tomllib

import numpy as np

from ambdaq.drivers.interfaces import Source
from ambdaq.drivers.registry import Backend, Opened
from ambdaq.drivers.signals import SampleBlock, SignalGroup
from ambdaq.drivers.url import Scheme
from ambdaq.errors import BadInputError, DeviceError

TYPES = {"int16": (">h", 1), "uint16": (">H", 1), "int32": (">i", 2), "uint32": (">I", 2), "float32": (">f", 2)}
MAX_REGISTERS = 125  # one Read Holding Registers request (Application Protocol 6.3)
BLOCK = 10  # polls per block handed to the recorder


def read_map(path: str) -> list[dict]:
    """The registers of a register-map file, each checked; one line for a bad one."""
    try:
        doc = tomllib.loads(open(path).read())
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise BadInputError(f"{path}: not a register map ({err})") from None
    regs = doc.get("register")
    if not isinstance(regs, list) or not regs:
        raise BadInputError(f"{path}: no [[register]] tables")
    for i, r in enumerate(regs):
        if r.get("type") not in TYPES or not isinstance(r.get("address"), int) or not 0 <= r["address"] < 65536:
            raise BadInputError(f"{path}: register {i + 1} needs an address (0..65535) and a type "
                                f"({', '.join(TYPES)})")
        if not str(r.get("topic", "")).startswith("/") or not r.get("field"):
            raise BadInputError(f"{path}: register {i + 1} needs a topic (/...) and a field")
    span = max(r["address"] + TYPES[r["type"]][1] for r in regs) - min(r["address"] for r in regs)
    if span > MAX_REGISTERS:
        raise BadInputError(f"{path}: the map spans {span} registers; one request reads {MAX_REGISTERS}")
    return regs


class ModbusClient:
    """Read Holding Registers over one TCP connection (MBAP header, 7 bytes, then the PDU)."""

    def __init__(self, host: str, port: int, unit: int, timeout: float = 1.0) -> None:
        self.unit, self.transaction = unit, 0
        try:
            self.sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as err:
            raise DeviceError(f"modbus+tcp://{host}:{port}: cannot connect ({err})") from None

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            part = self.sock.recv(n - len(data))
            if not part:
                raise DeviceError("the Modbus server closed the connection")
            data += part
        return data

    def read_holding(self, start: int, count: int) -> bytes:
        """``count`` registers from ``start``, their bytes as the server sent them (big-endian)."""
        self.transaction = (self.transaction + 1) & 0xFFFF
        self.sock.sendall(struct.pack(">HHHBBHH", self.transaction, 0, 6, self.unit, 0x03, start, count))
        tid, proto, length, unit = struct.unpack(">HHHB", self._exactly(7))
        if proto != 0 or not 2 <= length <= 253:
            raise DeviceError(f"not a Modbus TCP reply (protocol {proto}, length {length})")
        pdu = self._exactly(length - 1)
        if tid != self.transaction or unit != self.unit:
            raise DeviceError(f"a reply to another request (transaction {tid}, unit {unit})")
        if pdu[0] == 0x83:
            raise DeviceError(f"the Modbus server refused the read: exception code {pdu[1]}")
        if pdu[0] != 0x03 or pdu[1] != 2 * count or len(pdu) != 2 + 2 * count:
            raise DeviceError(f"a malformed Read Holding Registers reply ({len(pdu)} bytes)")
        return pdu[2:]

    def close(self) -> None:
        self.sock.close()


class ModbusProbes(Source):
    """The conditioner's mapped registers, one sample of every topic per poll."""

    duration_in_samples = True

    def __init__(self, name: str, host: str, port: int, unit: int, rate: float, registers: list[dict]) -> None:
        self.name, self.host, self.port, self.unit, self.sample_rate = name, host, port, unit, rate
        self.registers = registers
        self.start_reg = min(r["address"] for r in registers)
        self.count = max(r["address"] + TYPES[r["type"]][1] for r in registers) - self.start_reg
        self.topics: dict[str, list[dict]] = {}
        for r in registers:
            self.topics.setdefault(r["topic"], []).append(r)
        self.client: ModbusClient | None = None

    def signal_groups(self) -> list[SignalGroup]:
        return [SignalGroup(t, "Registers", tuple(r["field"] for r in rs), tuple(r.get("unit", "") for r in rs))
                for t, rs in self.topics.items()]

    def identity(self) -> dict[str, str]:
        return {"url": f"modbus+tcp://{self.host}:{self.port}?unit={self.unit}&rate={self.sample_rate:g}",
                "kind": "probe conditioner", "sample_rate_hz": f"{self.sample_rate:g}"}

    def device_calibration(self) -> dict[str, str]:
        return {}

    def start(self, n_samples: int | None) -> None:
        self.client = ModbusClient(self.host, self.port, self.unit)
        self.end, self.period, self.next = n_samples, 0, time.monotonic()

    def _decode(self, data: bytes) -> dict[str, list[float]]:
        out: dict[str, list[float]] = {}
        for topic, regs in self.topics.items():
            row = []
            for r in regs:
                fmt, _words = TYPES[r["type"]]
                at = 2 * (r["address"] - self.start_reg)
                raw = struct.unpack_from(fmt, data, at)[0]
                row.append(raw * r.get("scale", 1.0) + r.get("offset", 0.0))
            out[topic] = row
        return out

    def read(self) -> SampleBlock | None:
        seqs, times, rows = [], [], []
        while len(seqs) < BLOCK and (self.end is None or self.period < self.end):
            late = time.monotonic() - self.next
            if late > 1.0 / self.sample_rate:  # periods that went by without a poll: lost, counted
                skipped = int(late * self.sample_rate)
                self.period += skipped
                self.next += skipped / self.sample_rate
                continue
            time.sleep(max(0.0, self.next - time.monotonic()))
            data = self.client.read_holding(self.start_reg, self.count)
            seqs.append(self.period)
            times.append(time.time_ns())
            rows.append(self._decode(data))
            self.period += 1
            self.next += 1.0 / self.sample_rate
        if not seqs:
            return None
        t = np.array(times, dtype=np.int64)
        values = {topic: np.array([row[topic] for row in rows]) for topic in self.topics}
        return SampleBlock(t, np.array(seqs, dtype=np.uint32), values, host_time_ns=t)

    def _close(self) -> None:
        if self.client is not None:
            self.client.close()
        self.end = self.period


class ModbusBackend(Backend):
    """``modbus+tcp://``: the rig-file key ``register_map`` (a file, relative to the rig file)."""

    scheme = Scheme("modbus+tcp", "modbus+tcp://HOST:PORT[?unit=U&rate=HZ]", ("unit", "rate"))
    description_keys = ("register_map",)
    path_keys = ("register_map",)

    def discover(self) -> list[dict]:
        found = []
        for item in filter(None, os.environ.get("AMBDAQ_MODBUS_HOSTS", "").split(",")):
            host, _, port = item.strip().rpartition(":")
            try:
                socket.create_connection((host, int(port)), timeout=0.2).close()
            except (OSError, ValueError):
                continue
            found.append({"url": f"modbus+tcp://{host}:{port}", "description": "a Modbus TCP server that answers"})
        return found

    def open(self, url, request) -> Opened:
        path = request.description.get("register_map")
        if not path:
            raise BadInputError(f"{url.text}: a Modbus device needs its register map (rig file: register_map = FILE)")
        host, _, port = url.target.rpartition(":")
        if not host or not port.isdigit():
            raise BadInputError(f"{url.text}: expected modbus+tcp://HOST:PORT")
        return Opened([ModbusProbes(request.name or "modbus", host, int(port), int(url.number("unit", 1)),
                                    url.number("rate", 100.0), read_map(path))])
