"""One CAN bus shared by the drivers of a rig: python-can bus, canopen network, SYNC, bus health.

Devices on the same interface and channel share a :class:`CanHub` (reference-counted).  The hub
produces SYNC (CiA 301, COB-ID 0x80) at the stream's rate (or follows another master's SYNC),
timestamps every SYNC cycle (from the bus, or its own as it is sent where the interface does not
echo it), checks the
bus load of the requested stream, and watches error frames and the bus state (error-active,
error-passive, bus-off).

One receive thread reads the bus: process data (TPDOs, SYNC, a DBC device's frames) goes straight
to the handler registered for its identifier, SDO, EMCY, NMT and heartbeat to the canopen
network's subscribers, and a frame nothing claims to the unknown-frame handlers (a DBC device
counts them, or records them raw).  At full bus load that keeps the per-frame cost below python-can's own logger.
"""

from __future__ import annotations

import itertools
import logging
import math
import queue
import socket
import threading
import time
from collections import deque
from typing import Callable, NamedTuple

import can
import canopen
import numpy as np

from ...errors import BadInputError, DeviceError
from .device_profiles import SYNC_COUNTER_MAX
from ..signals import Event, SampleBlock

SYNC_COB_ID = 0x80
MAX_LOAD = 0.80
BUS_TOPIC = "/can/bus"
RX_POLL_S = 0.001  # the wait when the bus is drained
BYTE_STREAM_INTERFACES = ("slcan", "serial", "seeedstudio", "robotell")  # python-can's serial-line ones
MAX_OUTSTANDING = SYNC_COUNTER_MAX // 2  # SYNCs sent and not yet answered (start_sync)
RECENT_CYCLES = 16  # kept for matching replies by time (cycle_at)
OWN_ECHO = ("virtual", "socketcan")
"""Interfaces that hand a frame we send back to us with its bus time (python-can's
``receive_own_messages``): our SYNC is timed by that echo.  Any other (an SLCAN adapter) is timed
as it is handed to the interface."""
GATEWAY_CLOCK = ("socketcand",)
"""Interfaces whose frames carry the time stamps of a gateway's own clock (socketcand: the kernel's
receive time on the gateway host), not the host's: a device's sample times on them are mapped to
the host clock by the recorder's clock map, from (bus time, arrival) pairs (:meth:`CanHub.take_clock_pairs`),
as a serial device's are.  Such a gateway returns no frame the host sends, so a SYNC from ambdaq
cannot be timed on its clock: there the SYNC must come from a master on the bus (``sync=external``)."""
GATEWAY_TIMEOUT_S = 3.0  # to reach a gateway's TCP port
GATEWAY_JUMP_NS = 1_000_000_000  # a time stamp whose lag behind arrival moves more than this is not the gateway's clock
GATEWAY_STEP_FRAMES = 10  # frames in a row agreeing on a new lag: the gateway's clock was stepped
PAIR_WINDOW_NS = 100_000_000  # one (bus time, arrival) pair per 100 ms: the frame that arrived soonest


def _one_line(err: Exception) -> str:
    """What an interface's exception says, on one line (python-can's socketcand client puts a
    traceback into its message)."""
    return " ".join(str(err).split("Traceback")[0].split()) or type(err).__name__


def _gateway_closed(bus: can.BusABC) -> bool:
    """Whether a gateway's TCP connection was closed by the gateway. python-can's socketcand client
    reads an empty string from a closed socket as "no frame" for ever, so its socket (a private
    attribute: None if a later python-can renames it, and then only silence tells) is peeked."""
    sock = getattr(bus, "_SocketCanDaemonBus__socket", None)
    if sock is None:
        return False
    try:
        return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


def frame_bits(data_bytes: int) -> int:
    """Worst-case length of a classic CAN data frame with an 11-bit identifier, in bits.

    47 bits of framing plus the data, plus the most stuff bits the stuffed part can carry
    (one per four bits after the first: Davis et al., "CAN schedulability analysis", 2007).
    """
    return 47 + 8 * data_bytes + (34 + 8 * data_bytes - 1) // 4


def bus_load(frames_per_cycle: list[int], rate_hz: float, bitrate: int) -> float:
    """Fraction of ``bitrate`` (bit/s) used by frames of ``frames_per_cycle`` data bytes each,
    sent ``rate_hz`` times a second."""
    return sum(frame_bits(n) for n in frames_per_cycle) * rate_hz / bitrate


class SyncCycle(NamedTuple):
    """A SYNC: its count since the stream started, its counter byte (1..240), its bus time (ns)."""

    count: int = -1
    counter: int = 0
    time_ns: int = 0


def _greets(interface: str, host: str, port: int) -> None:
    """That a gateway answers at ``host``:``port`` and greets a client within GATEWAY_TIMEOUT_S
    (socketcand: ``< hi >``); one line naming it otherwise."""
    where = f"the {interface} gateway at {host}:{port}"
    try:
        with socket.create_connection((host, port), timeout=GATEWAY_TIMEOUT_S) as conn:
            if interface == "socketcand":
                greeting = conn.recv(64)
                if not greeting.startswith(b"< hi >"):
                    raise DeviceError(f"{where} greeted with {greeting[:20]!r}, not socketcand's '< hi >'")
    except socket.timeout:
        raise DeviceError(f"{where} accepted the connection but said nothing in {GATEWAY_TIMEOUT_S:g} s "
                          "(socketcand greets with '< hi >')") from None
    except OSError as err:
        raise DeviceError(f"cannot reach {where}: {err.strerror or err}") from None


def _opened(interface: str, channel: str, bitrate: int, options: dict) -> can.BusABC:
    """python-can's bus, opened within GATEWAY_TIMEOUT_S where it talks to a gateway (its socketcand
    client waits for each handshake line without a timeout: a gateway that stops answering would
    hang the command); one DeviceError line otherwise."""
    result: list = []

    def open_bus() -> None:
        try:
            result.append(can.Bus(interface=interface, channel=channel, bitrate=bitrate, **options))
        except BaseException as err:  # handed to the caller as it is
            result.append(err)

    if "host" not in options:
        open_bus()
    else:
        opener = threading.Thread(target=open_bus, name=f"open-{interface}", daemon=True)
        opener.start()
        opener.join(GATEWAY_TIMEOUT_S)
        if not result:
            raise DeviceError(f"CAN {interface}/{channel}: the gateway at {options['host']}:{options['port']} did not "
                              f"finish its handshake in {GATEWAY_TIMEOUT_S:g} s")
    got = result[0]
    if isinstance(got, (can.CanError, ValueError, ImportError, OSError, NotImplementedError)):
        raise DeviceError(f"cannot open CAN {interface}/{channel}: {got}") from None
    if isinstance(got, BaseException):
        raise got
    return got


class CanHub:
    """A shared CAN bus (see the module docstring); get one with :meth:`acquire`."""

    _hubs: dict[tuple[str, str], "CanHub"] = {}
    _hubs_lock = threading.Lock()

    def __init__(self, interface: str, channel: str, bitrate: int, **bus_options) -> None:
        self.interface, self.channel, self.bitrate = interface, channel, bitrate
        self.own_echo = interface in OWN_ECHO
        self.host_clock = interface not in GATEWAY_CLOCK  # bus time stamps on the host clock
        self._pairs: list[tuple[int, int]] = []  # gateway clock: (bus ns, arrival ns), one per PAIR_WINDOW_NS
        self._pair_window = (0, 0, 0)  # (window start, bus ns, arrival ns) of the soonest frame in it
        self._pairs_taken: dict[int, int] = {}  # reader -> how many of _pairs it has taken
        self._lag: int | None = None  # gateway clock: the last kept frame's arrival minus its time stamp, ns
        self._stepped: list[int] = []  # lags of the frames in a row that jumped from it
        self.implausible_time = 0  # gateway frames whose time stamp cannot be the gateway's clock: dropped
        if self.own_echo:
            bus_options["receive_own_messages"] = True
        if interface in GATEWAY_CLOCK:  # ambdaq says what went wrong, once; python-can's client logs it too
            quiet = logging.getLogger(f"can.interfaces.{interface}")
            if quiet.propagate:
                quiet.addHandler(logging.NullHandler())
                quiet.propagate = False
        if "host" in bus_options:  # a gateway: python-can's client retries a refused connection for 10 s
            _greets(interface, bus_options["host"], bus_options["port"])
        bus = _opened(interface, channel, bitrate, bus_options)
        self.network = canopen.Network(bus)  # no notifier: our receive thread feeds it
        self._fast: dict[tuple[int, bool], Callable[[bytearray, float], None]] = {}  # (id, extended)
        self._last_frame = time.monotonic()
        self._unknown: list[Callable[[can.Message], None]] = []  # frames nothing on the bus claims
        self.error_frames = 0
        self.malformed_frames = 0  # lines or records the interface could not parse: counted, skipped
        self.events: "queue.SimpleQueue[Event]" = queue.SimpleQueue()  # drained by whichever device asks
        self._refs = 0
        self.by_counter: dict[int, SyncCycle] = {}  # the last SYNC_COUNTER_MAX cycles, by counter
        self.recent: deque[SyncCycle] = deque([SyncCycle()], maxlen=RECENT_CYCLES)  # newest last
        self._sync_listeners: list[Callable[[SyncCycle], None]] = []
        self._streams: dict[str, list[int]] = {}
        self.sync_hz: float | None = None
        self.load_limit = MAX_LOAD
        self._sync_thread: threading.Thread | None = None
        self._sync_stop = threading.Event()
        self._own_syncs: deque[tuple[int, float]] = deque()  # (counter, host time): SYNCs we sent
        self.external_sync = False
        self.answered = -1  # the newest SYNC cycle a device's reply was matched to (devices set it)
        self.skipped_syncs = 0
        self.failure: str | None = None
        self._state = getattr(bus, "state", can.BusState.ACTIVE)
        self._fast[(SYNC_COB_ID, False)] = self._on_sync
        self._rx = threading.Thread(target=self._receive, name=f"can-rx-{channel}", daemon=True)
        self._rx.start()
        self._watch = threading.Thread(target=self._watch_state, name=f"can-state-{channel}", daemon=True)
        self._watch.start()

    @classmethod
    def acquire(cls, interface: str, channel: str, bitrate: int, **bus_options) -> "CanHub":
        """The hub of ``interface``/``channel``, opened at ``bitrate`` (bit/s) with python-can's
        ``bus_options`` (e.g. slcan's ``sleep_after_open``) if it is not open yet."""
        with cls._hubs_lock:
            hub = cls._hubs.get((interface, channel))
            if hub is None:
                hub = cls._hubs[(interface, channel)] = cls(interface, channel, bitrate, **bus_options)
            elif hub.bitrate != bitrate:
                raise BadInputError(f"CAN {interface}/{channel} is open at {hub.bitrate} bit/s, not {bitrate}")
            hub._refs += 1
            return hub

    def retain(self) -> None:
        """One more holder of this hub (a device with several sources); each releases it once."""
        with self._hubs_lock:
            self._refs += 1

    def release(self) -> None:
        with self._hubs_lock:
            self._refs -= 1
            if self._refs > 0:
                return
            self._hubs.pop((self.interface, self.channel), None)
        self.stop_sync()
        self._sync_stop.set()
        self._rx.join(timeout=1.0)
        try:
            self.network.disconnect()
        except (can.CanError, OSError, ValueError):
            pass

    # --- streams and SYNC ---------------------------------------------------------------------------

    def register_stream(self, name: str, tpdo_bytes: list[int], sync_hz: float, *, external: bool = False) -> None:
        """Declare a device's TPDOs (data bytes each) sent on every SYNC at ``sync_hz`` (Hz); with
        ``external`` another master on the bus produces the SYNC and ambdaq only listens."""
        if self.sync_hz is not None and abs(self.sync_hz - sync_hz) > 1e-9:
            raise BadInputError(f"devices on CAN {self.channel} ask for SYNC at {self.sync_hz:g} and {sync_hz:g} Hz")
        if self._streams and external != self.external_sync:
            raise BadInputError(f"devices on CAN {self.channel} ask for SYNC from ambdaq and from another master")
        self.sync_hz, self.external_sync = sync_hz, external
        self._streams[name] = list(tpdo_bytes)

    def check_load(self) -> float:
        """The bus load of every registered stream plus SYNC; refuses (BadInputError) above
        ``load_limit`` (80 %: room for SDO, EMCY and heartbeats)."""
        limit = self.load_limit
        frames = [1] + [n for sizes in self._streams.values() for n in sizes]  # SYNC: its counter byte
        load = bus_load(frames, self.sync_hz or 0.0, self.bitrate)
        if load > limit:
            per_cycle = sum(frame_bits(n) for n in frames)
            fits = limit * self.bitrate / per_cycle
            raise BadInputError(
                f"CAN stream needs {load:.0%} of {self.bitrate:,} bit/s ({len(frames)} frames per SYNC at "
                f"{self.sync_hz:g} Hz, {load * self.bitrate / per_cycle * len(frames):,.0f} frames/s); the limit is "
                f"{limit:.0%}: use sync={int(fits)} or lower, or fewer devices/channels"
            )
        return load

    @property
    def receive_thread_id(self) -> int | None:
        """Native id of the bus receive thread (for CPU accounting)."""
        return self._rx.native_id

    def silent_s(self) -> float:
        """Seconds since the last frame of any identifier (or since the bus opened)."""
        return time.monotonic() - self._last_frame

    def on_frame(self, cob_id: int, handler: Callable[[bytearray, float], None], extended: bool | None = None) -> None:
        """Route frames of ``cob_id`` (process data) straight to ``handler(data, timestamp)``: only
        frames of that identifier **and format** (ISO 11898: an 11-bit and a 29-bit identifier of the
        same value are two identifiers); ``extended`` None: the format the value needs (29-bit
        above 0x7FF, else 11-bit, as CANopen's COB-IDs and XCP on CAN's are)."""
        self._fast[(cob_id, cob_id > 0x7FF if extended is None else extended)] = handler

    def _receive(self) -> None:
        """Drain the bus, then wait RX_POLL_S: one wake-up per burst (a SYNC and its PDOs) rather
        than one per frame.  On an interface that reads a byte stream (BYTE_STREAM_INTERFACES:
        an SLCAN adapter's serial line) the wait is the interface's own, so a line that is still
        arriving is read to its end at once; a sleep there held the reader to about a frame per
        millisecond.  Elsewhere it is a sleep: waking for every frame of a burst costs the other
        threads of the process (a serial controller's time sync among them) the GIL."""
        bus, fast, notify, own = self.network.bus, self._fast, self.network.notify, self._own_syncs
        subscribers, unknown = self.network.subscribers, self._unknown
        stream = self.interface in BYTE_STREAM_INTERFACES
        wait = 0.0
        while not self._sync_stop.is_set():
            while own:
                counter, sent = own.popleft()
                self._on_sync(bytes([counter]), sent)
            try:
                msg = bus.recv(wait)
            except ValueError as err:  # the interface could not parse what its adapter sent (slcan: a garbled line)
                self._malformed(err)
                continue
            except (can.CanError, OSError) as err:
                if not isinstance(err.__cause__, UnicodeDecodeError):
                    if not self._sync_stop.is_set():
                        self.failure = f"CAN {self.interface}/{self.channel} receive failed: {_one_line(err)}"
                    return
                # a byte over 0x7F from the adapter or gateway: python-can's slcan reader keeps the
                # line in its buffer and fails on it at every read after, so it is dropped; its
                # socketcand client has dropped what it read (the frames in it are lost). Counted,
                # as any malformed line, and the recording goes on
                if isinstance(getattr(bus, "_buffer", None), bytearray):
                    bus._buffer.clear()
                self._malformed(err.__cause__)
                continue
            if msg is None:
                if stream:
                    wait = RX_POLL_S
                else:
                    time.sleep(RX_POLL_S)
                continue
            wait = 0.0
            self._last_frame = time.monotonic()
            timed = self.host_clock or self._plausible(msg)
            while own:  # a SYNC we sent while waiting comes before any reply to it
                counter, sent = own.popleft()
                self._on_sync(bytes([counter]), sent)
            if msg.is_error_frame:
                self.error_frames += 1
                self.events.put(Event(int(msg.timestamp * 1e9), "error-frame", msg.arbitration_id,
                                      f"CAN {self.channel} error frame, data {bytes(msg.data).hex()}", BUS_TOPIC))
                continue
            handler = fast.get((msg.arbitration_id, msg.is_extended_id))
            if handler is not None:
                if timed:  # process data is timed by its stamp: one that cannot be the gateway's is not kept
                    handler(msg.data, msg.timestamp)
            elif msg.is_remote_frame:
                continue
            elif msg.arbitration_id in subscribers and msg.is_extended_id == (msg.arbitration_id > 0x7FF):
                notify(msg.arbitration_id, msg.data, msg.timestamp)  # SDO, EMCY, NMT: 11-bit COB-IDs
            elif timed:
                for cb in unknown:
                    cb(msg)

    def _plausible(self, msg: can.Message) -> bool:
        """Whether a gateway's time stamp can be its clock: its lag behind the host's arrival stays
        within GATEWAY_JUMP_NS of the last frame kept. The first frame only sets that lag. One that
        jumps is not timed, paired or recorded, and is counted (``implausible_time``);
        GATEWAY_STEP_FRAMES in a row that agree on a new lag are the gateway's clock stepped (NTP):
        taken from there on, with an event."""
        arrival = time.time_ns()
        stamp = msg.timestamp
        if not (isinstance(stamp, float) and math.isfinite(stamp)):
            self.implausible_time += 1
            return False
        bus = int(stamp * 1e9)
        lag = arrival - bus
        if self._lag is None:
            self._lag = lag
            return False
        if abs(lag - self._lag) > GATEWAY_JUMP_NS:
            self._stepped = [s for s in self._stepped if abs(lag - s) <= GATEWAY_JUMP_NS] + [lag]
            if len(self._stepped) < GATEWAY_STEP_FRAMES:
                self.implausible_time += 1
                return False
            self.events.put(Event(arrival, "clock-step", 0, f"CAN {self.channel}: the gateway's clock stepped by "
                                                            f"{(self._lag - lag) / 1e9:+.3f} s", BUS_TOPIC))
        self._lag, self._stepped = lag, []
        self._pair(bus, arrival)
        return True

    def _pair(self, bus_ns: int, arrival_ns: int) -> None:
        """Keep the frame that arrived soonest after its bus time in each PAIR_WINDOW_NS: the pair
        closest to the true offset between the gateway's clock and the host's."""
        start, bus, arrival = self._pair_window
        if arrival_ns - start >= PAIR_WINDOW_NS:
            if start:
                self._pairs.append((bus, arrival))
            self._pair_window = (arrival_ns, bus_ns, arrival_ns)
        elif arrival_ns - bus_ns < arrival - bus:
            self._pair_window = (start, bus_ns, arrival_ns)

    def take_clock_pairs(self, reader: object) -> list[tuple[int, int]] | None:
        """The (bus time, host arrival) pairs, in ns, that ``reader`` (a device's source) has not
        taken yet; None where bus times are host times (GATEWAY_CLOCK)."""
        if self.host_clock:
            return None
        done = self._pairs_taken.get(id(reader), 0)
        pairs = self._pairs[done:]
        self._pairs_taken[id(reader)] = done + len(pairs)
        return pairs

    def sample_block(self, time_ns: np.ndarray, seq: np.ndarray, values: dict[str, np.ndarray]) -> SampleBlock:
        """A block of samples at bus times ``time_ns`` (ns): host times as they are, or on a
        gateway's clock (GATEWAY_CLOCK) left for the recorder to map by its clock pairs."""
        seq32 = (seq & 0xFFFFFFFF).astype(np.uint32)
        if self.host_clock:
            return SampleBlock(device_time_ns=time_ns, seq=seq32, values=values, host_time_ns=time_ns)
        return SampleBlock(device_time_ns=time_ns, seq=seq32, values=values, received_ns=time.time_ns())

    def _malformed(self, err: Exception) -> None:
        """A line or frame the interface could not parse: counted, and an event."""
        self.malformed_frames += 1
        self.events.put(Event(time.time_ns(), "malformed-frame", 0,
                              f"CAN {self.channel}: malformed frame from the interface ({err})", BUS_TOPIC))

    def on_unknown(self, handler: Callable[[can.Message], None]) -> None:
        """Hand ``handler(message)`` every frame that no device registered or subscribed to."""
        self._unknown.append(handler)

    def add_sync_listener(self, cb: Callable[[SyncCycle], None]) -> None:
        self._sync_listeners.append(cb)

    def remove_sync_listener(self, cb: Callable[[SyncCycle], None]) -> None:
        if cb in self._sync_listeners:
            self._sync_listeners.remove(cb)

    def start_sync(self) -> None:
        """Start producing SYNC at the registered rate (once per bus; never with an external master).

        A reply is matched to its SYNC by the counter it echoes, which tells apart 240 SYNCs.  When
        the replies come back more than MAX_OUTSTANDING cycles behind the last SYNC sent (a reader
        that cannot keep up, e.g. an SLCAN adapter whose serial line backs up), a reply could match
        the SYNC a whole counter turn later; so cycles are then not sent until the replies catch
        up: each is counted, and lost, on every device, and no reply is ever attributed to the
        wrong cycle.

        A SYNC we send is timed by its echo from the bus where the interface gives one
        (OWN_ECHO: the time the devices see); otherwise it is timed by the host clock as it is
        handed to the interface and reaches the receive thread through a queue (SLCAN adapters do
        not echo).  A cycle held back is counted through the queue on every interface.
        """
        if self._sync_thread is not None or self.external_sync:
            return
        period = 1.0 / self.sync_hz
        self._sync_stop.clear()

        def run() -> None:
            nxt = time.monotonic()
            counter = last_sent = 0
            for count in itertools.count():
                if self._sync_stop.is_set():
                    return
                nxt += period
                counter = counter % SYNC_COUNTER_MAX + 1  # CiA 301: 1 .. 0x1019
                if 0 <= self.answered < last_sent - MAX_OUTSTANDING:
                    self.skipped_syncs += 1  # the cycle is counted, and lost, but never sent
                    self._own_syncs.append((counter, time.time()))
                    time.sleep(max(0.0, nxt - time.monotonic()))
                    continue
                if not self.own_echo:
                    self._own_syncs.append((counter, time.time()))  # before a reply to it can come back
                last_sent = count
                try:
                    self.network.bus.send(can.Message(arbitration_id=SYNC_COB_ID, is_extended_id=False,
                                                      data=bytes([counter])))
                except can.CanError as err:
                    self.failure = f"CAN {self.channel}: SYNC could not be sent: {err}"
                    return
                delay = nxt - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -0.1:  # far behind (machine stalled): skip rather than burst
                    nxt = time.monotonic()

        self._sync_thread = threading.Thread(target=run, name=f"can-sync-{self.channel}", daemon=True)
        self._sync_thread.start()

    def stop_sync(self) -> None:
        self._sync_stop.set()
        if self._sync_thread is not None:
            self._sync_thread.join(timeout=1.0)
            self._sync_thread = None

    def cycle_of(self, counter: int) -> SyncCycle | None:
        """The SYNC that a reply echoing ``counter`` answers: the newest SYNC with that counter, or
        ``None`` if the reply is ahead of the newest SYNC seen (its counter is the next one).

        That happens whenever a device answers before this thread has taken the SYNC in: ours
        comes through a queue from the SYNC thread, another master's can be read after the
        first replies on a busy bus.  The caller
        keeps such a reply until the SYNC arrives (:meth:`add_sync_listener`); without that it
        would be matched to the SYNC 240 cycles older, a duplicate row with an old time.
        """
        latest = self.cycle
        if latest.count < 0 or (counter - latest.counter) % SYNC_COUNTER_MAX == 1:
            return None
        return self.by_counter.get(counter)

    @property
    def cycle(self) -> SyncCycle:
        """The newest SYNC (count -1 before the first)."""
        return self.recent[-1]

    def cycle_at(self, time_ns: int) -> tuple[SyncCycle | None, SyncCycle | None]:
        """The newest SYNC sent at or before ``time_ns`` (a reply's bus time) and the one sent
        before it, among the recent ones (None where older than those)."""
        newest = None
        for c in reversed(self.recent):
            if c.count >= 0 and c.time_ns <= time_ns:
                if newest is not None:
                    return newest, c
                newest = c
        return newest, None

    def _on_sync(self, data: bytearray, timestamp: float) -> None:
        counter = data[0] if data else 0
        cycle = SyncCycle(self.cycle.count + 1, counter, int(round(timestamp * 1e9)))
        self.by_counter[counter] = cycle
        self.recent.append(cycle)
        for cb in list(self._sync_listeners):
            cb(cycle)

    # --- health ------------------------------------------------------------------------------------

    def statistics(self) -> dict[str, str]:
        """The bus's counts, for each device's link statistics."""
        return {"error_frames": str(self.error_frames), "malformed_frames": str(self.malformed_frames),
                "skipped_syncs": str(self.skipped_syncs), "bitrate": str(self.bitrate)} | (
                {} if self.host_clock else {"implausible_time": str(self.implausible_time)})

    def take_events(self, *device_queues: "queue.SimpleQueue[Event]") -> list[Event]:
        """Every event waiting in a device's ``device_queues`` and on the bus, in that order."""
        out = []
        for q in (*device_queues, self.events):
            while True:
                try:
                    out.append(q.get_nowait())
                except queue.Empty:
                    break
        return out

    def _watch_state(self) -> None:
        names = {can.BusState.ACTIVE: "error-active", can.BusState.PASSIVE: "error-passive",
                 can.BusState.ERROR: "bus-off"}
        while not self._sync_stop.wait(0.05):
            bus = self.network.bus
            if bus is None:
                return
            if not self.host_clock and _gateway_closed(bus):
                self.failure = f"CAN {self.interface}/{self.channel}: the gateway closed the connection"
                return
            try:
                state = bus.state
            except (NotImplementedError, AttributeError, can.CanError):
                return
            if state != self._state:
                self._state = state
                self.events.put(Event(time.time_ns(), "bus-state", 0, f"CAN {self.channel} {names.get(state, state)}",
                                         BUS_TOPIC))
                if state == can.BusState.ERROR:
                    self.failure = f"CAN {self.interface}/{self.channel} went bus-off"
