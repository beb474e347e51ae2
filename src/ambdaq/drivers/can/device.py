"""Driver for the CANopen devices (amplifier, gap sensor, accelerometer, key-phasor).

Configuration by SDO (identity 0x1018, heartbeat 0x1017, TPDO communication parameters), NMT to
OPERATIONAL, process data in TPDOs sent on every SYNC, EMCY for faults, heartbeat for liveness.
A sample is one SYNC cycle: its time is the SYNC's bus timestamp, its ``seq`` the cycle count,
found from the SYNC counter the device echoes in its last TPDO; a cycle is recorded only when
every TPDO of it arrived, otherwise it is a drop.
"""

from __future__ import annotations

import queue
import struct
import time

import canopen
import numpy as np
from numpy.typing import ArrayLike
from canopen import objectdictionary as od

from ...errors import BadInputError, DeviceError
from ..interfaces import Parameters, Source
from ..signals import Event, SampleBlock, SignalGroup
from .bus import CanHub
from .device_profiles import DEVICE_PROFILES, DeviceProfile
from ..rows import RowQueue

_FMT = {od.INTEGER16: "h", od.UNSIGNED16: "H", od.UNSIGNED8: "B", od.REAL32: "f", od.INTEGER32: "i"}
_INTEGER = (od.INTEGER16, od.UNSIGNED16, od.UNSIGNED8, od.INTEGER32)
HEARTBEAT_MS = 100
HEARTBEAT_TIMEOUT_S = 0.6
"""Silence after which a device is lost: six heartbeats, so a reader up to MAX_OUTSTANDING SYNC
cycles behind (0.3 s at 400 Hz, through an SLCAN adapter) never reports a device that is there."""


def _sdo_error(node: int, what: str, err: Exception) -> DeviceError:
    return DeviceError(f"CANopen node {node}: {what} failed: {err}")


class CanopenDevice(Source, Parameters):
    """One CANopen device on a shared bus.

    Parameters
    ----------
    hub : CanHub
        The bus.
    node_id : int
        CANopen node id (1..127, checked by the back-end).
    kind : str, optional
        Expected device type; found from the identity's product code when omitted.
    sync_hz : float
        SYNC rate = sample rate, in Hz.
    name : str
        Device name in recordings.
    namespace : str
        Topic prefix (``can`` makes ``/can/amb/gap``), for rigs where another device has the topic.
    url : str
        The device URL (identity, messages).
    """

    def __init__(self, hub: CanHub, node_id: int, *, kind: str | None = None, sync_hz: float = 800.0,
                 name: str | None = None, namespace: str = "", url: str = "") -> None:
        self.hub = hub
        self.node_id = node_id
        self.url = url or f"can://{hub.interface}/{hub.channel}?node={node_id}"
        self.sample_rate = sync_hz
        self.node = canopen.RemoteNode(node_id, str(DEVICE_PROFILES[kind or "amplifier"].eds_path))
        hub.network.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = 0.5
        try:
            product = self.node.sdo.upload(0x1018, 2)
            serial = self.node.sdo.upload(0x1018, 4)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            hub.network.nodes.pop(node_id, None)
            raise _sdo_error(node_id, "reading its identity (0x1018)", err) from None
        code = struct.unpack("<I", product)[0]
        found = next((p for p in DEVICE_PROFILES.values() if p.product_code == code), None)
        if found is None or (kind is not None and found.kind != kind):
            hub.network.nodes.pop(node_id, None)
            raise DeviceError(f"CANopen node {node_id}: product code 0x{code:04x} is not "
                              f"{'a ' + kind if kind else 'an ambdaq device type'}")
        if found.kind != (kind or "amplifier"):
            hub.network.nodes.pop(node_id, None)
            self.node = canopen.RemoteNode(node_id, str(found.eds_path))
            hub.network.add_node(self.node)
        self.profile: DeviceProfile = found
        self.name = name or found.kind
        self.serial = struct.unpack("<I", serial)[0]
        prefix = f"/{namespace.strip('/')}" if namespace else ""
        self.group = SignalGroup(prefix + found.topic, found.type_name, tuple(c.field for c in found.channels),
                                 tuple(c.unit for c in found.channels))
        self._tpdo_fmt = [struct.Struct("<" + "".join(_FMT[t] for _i, t in found.tpdo_layout(i)))
                          for i in range(len(found.tpdos))]
        self._scale = np.array([c.scale for c in found.channels])
        self._rows = RowQueue(max(1.0, 20 / sync_hz))  # (cycle, time ns, TPDO parts), from the bus thread
        self._emcy: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._parts: list = [None] * len(found.tpdos)
        self._early: list[tuple[int, tuple]] = []  # complete replies ahead of their SYNC's echo
        self._last_heartbeat = time.monotonic()
        self._subscribed = False

    # --- recorder source ----------------------------------------------------------------------------

    def signal_groups(self) -> list[SignalGroup]:
        return [self.group]

    def identity(self) -> dict[str, str]:
        return {"url": self.url, "kind": self.profile.kind, "model": self.profile.product,
                "serial": str(self.serial), "node_id": str(self.node_id), "sample_rate_hz": f"{self.sample_rate:g}",
                "eds": self.profile.eds_path.name}

    def device_calibration(self) -> dict[str, str]:
        return {c.field: f"{c.scale:g} {c.unit} per count" for c in self.profile.channels}

    def configure(self) -> None:
        """SDO: heartbeat and TPDO communication (every SYNC); EMCY and heartbeat consumers."""
        n = self.node
        try:
            n.sdo[0x1017].raw = HEARTBEAT_MS
            for i in range(len(self.profile.tpdos)):
                n.sdo[0x1800 + i][1].raw = 0x180 + 0x100 * i + self.node_id  # valid, on our COB-ID
                n.sdo[0x1800 + i][2].raw = 1  # synchronous, every SYNC
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise _sdo_error(self.node_id, "configuring heartbeat and TPDOs", err) from None
        if not self._subscribed:  # once: a reconnect configures the device again, not our callbacks
            self._subscribed = True
            for i in range(len(self.profile.tpdos)):
                self.hub.on_frame(0x180 + 0x100 * i + self.node_id, self._tpdo_callback(i))
            n.emcy.add_callback(self._on_emcy)
            self.hub.on_frame(0x700 + self.node_id, self._on_heartbeat)
            self.hub.add_sync_listener(self._on_sync_cycle)

    def start(self, n_samples: int | None) -> None:
        self._rows.start(n_samples)
        self.hub.register_stream(self.name, self.profile.tpdo_bytes(), self.sample_rate)
        self.hub.check_load()
        self.configure()
        self.node.nmt.send_command(0x01)  # start remote node: OPERATIONAL
        self._last_heartbeat = self._rows.last_row = time.monotonic()
        self.hub.start_sync()

    def _tpdo_callback(self, i: int):
        fmt = self._tpdo_fmt[i]

        last = len(self._parts) - 1

        def on_tpdo(data: bytearray, timestamp: float) -> None:  # on the bus thread only
            try:
                values = fmt.unpack(data)
            except struct.error:
                return  # wrong length: never recorded
            if i < last:  # a device sends its TPDOs of one cycle in order: keep until the last
                self._parts[i] = values
                return
            parts = self._parts
            self._parts = [None] * len(parts)
            if None in parts[:last]:
                return  # part of this cycle was lost: a drop, never a made-up row
            cycle = self.hub.cycle_of(values[-1])  # the SYNC this cycle answers
            if cycle is None:
                self._early.append((values[-1], (*parts[:last], values)))
            else:  # flattened by the reader, off the bus thread
                self._rows.rows.append((cycle.count, cycle.time_ns, *parts[:last], values))
                self.hub.answered = cycle.count

        return on_tpdo

    def _on_sync_cycle(self, cycle) -> None:
        """A SYNC arrived (bus thread): the replies that came ahead of it are its; any other kept
        reply never found its SYNC and is dropped (the host sees the gap)."""
        if self._early:
            early, self._early = self._early, []
            for counter, parts in early:
                if counter == cycle.counter:
                    self._rows.rows.append((cycle.count, cycle.time_ns, *parts))
                    self.hub.answered = cycle.count

    def _on_emcy(self, err) -> None:
        self._emcy.put(Event(0, "fault", err.code, f"EMCY 0x{err.code:04X} {err.get_desc()} (register 0x{err.register:02X})"))

    def _on_heartbeat(self, data: bytearray, timestamp: float) -> None:
        self._last_heartbeat = time.monotonic()

    def read(self) -> SampleBlock | None:
        """Rows of the SYNC cycles since the last call (at least one), as a block."""
        taken = self._rows.take(
            lambda: None if (f := self.hub.failure or self._liveness()) is None
            else f"{self.name} ({self.url}) lost at {time.strftime('%H:%M:%S')}: {f}",
            lambda silent: f"{self.name} ({self.url}): no process data from node {self.node_id} for {silent:.1f} s "
                           "(is it OPERATIONAL, are its TPDOs mapped?)")  # alive (heartbeat) but silent
        if taken is None:
            return None
        rows, cycles = taken
        rows = [(r[0], r[1], [v for part in r[2:-1] for v in part] + list(r[-1][:-1])) for r in rows]
        raw = np.array([r[2] for r in rows], dtype=np.float64)
        nch = len(self.profile.channels)
        t = np.array([r[1] for r in rows], dtype=np.int64)
        return SampleBlock(
            device_time_ns=t,
            seq=(cycles & 0xFFFFFFFF).astype(np.uint32),
            values={self.group.topic: raw[:, :nch] * self._scale},
            host_time_ns=t,  # bus timestamps are on the host clock
            status=raw[:, nch].astype(np.uint32) if raw.shape[1] > nch else None,
        )

    def _liveness(self) -> str | None:
        silent = time.monotonic() - self._last_heartbeat
        if silent > HEARTBEAT_TIMEOUT_S:
            return f"no heartbeat from node {self.node_id} for {silent:.1f} s"
        return None

    @property
    def can_reconnect(self) -> bool:
        return True

    def reconnect(self) -> None:
        """Configure the node again and start it (after a reset or power cycle)."""
        if self.hub.failure is not None:
            raise DeviceError(self.hub.failure)
        try:
            struct.unpack("<I", self.node.sdo.upload(0x1018, 4))
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise _sdo_error(self.node_id, "reading its identity (0x1018)", err) from None
        self.configure()
        self.node.nmt.send_command(0x01)
        self._last_heartbeat = self._rows.last_row = time.monotonic()

    def events(self) -> list[Event]:
        return self.hub.take_events(self._emcy)

    def link_statistics(self) -> dict[str, str]:
        return self.hub.statistics() | {"sync_hz": f"{self.sample_rate:g}"}

    def _close(self) -> None:
        self._rows.closed.set()
        self.hub.remove_sync_listener(self._on_sync_cycle)
        try:
            self.node.nmt.send_command(0x80)  # back to PRE-OPERATIONAL: TPDOs stop
        except Exception:  # the bus may be gone already
            pass
        self.hub.release()

    # --- parameters ------------------------------------------------------------------------------------

    def read_param(self, name: str) -> np.ndarray:
        """Read an SDO parameter by name (see the device's EDS): one value."""
        prm = self._param(name)
        try:
            return np.array([self.node.sdo[prm.index].raw], dtype=float)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise _sdo_error(self.node_id, f"reading {name}", err) from None

    def write_param(self, name: str, values: ArrayLike) -> None:
        """Write an SDO parameter by name (one value); an SDO abort is a DeviceError with its code."""
        prm = self._param(name)
        v = np.atleast_1d(np.asarray(values, dtype=float))
        if v.shape != (1,):
            raise BadInputError(f"{self.profile.kind} parameter {name} takes one value, not {v.shape[0]}")
        value = int(v[0]) if prm.data_type in _INTEGER else float(v[0])
        try:
            self.node.sdo[prm.index].raw = value
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            raise _sdo_error(self.node_id, f"writing {name}", err) from None

    def parameter_names(self) -> list[str]:
        return [p.name for p in self.profile.parameters]

    def _param(self, name: str):
        for prm in self.profile.parameters:
            if prm.name == name:
                return prm
        raise BadInputError(f"{self.profile.kind} has no parameter {name!r} "
                            f"({', '.join(p.name for p in self.profile.parameters)})")
