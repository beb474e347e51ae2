"""A real XCP slave's side of a recorded conversation, played back to a master on 127.0.0.1.

``../shared/corpus/xcp/*.jsonl`` holds every packet between a master and Vector's XCPlite, both
directions (its README).  :class:`Replay` answers the master's commands with what XCPlite
answered: the k-th command the master sends must be, byte for byte, the k-th command of the
session, and is answered with the k-th response and then the DTOs, events and service requests the
slave sent before its next response, paced as they were recorded.  A command the session does not
hold next is never answered with a guess: the replay stops, keeps what was asked and what the
session held (:attr:`Replay.mismatch`), and the master meets a slave that does not answer.

Commands and responses are paired by their order, not by the proxy's time stamps: the proxy
wrote each direction from its own thread, so a response may carry an earlier time than its
command.  The slave's packets go out with the CTR it sent them with, so a master's loss count sees
what it saw then.  A command that arrives while the slave's packets of the step before are still
being paced (a master that stops a DAQ list a little earlier than the recorded one did) has them
sent at once before its own response: they were on their way before the slave read the command.
"""

from __future__ import annotations

import json
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path

HEADER = struct.Struct("<HH")  # XCP on Ethernet: LEN, CTR (ASAM MCD-1 XCP Part 3), written here on its own
CORPUS = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "xcp"


@dataclass(frozen=True)
class Step:
    """One command of a session and what the slave sent for it: (recorded ns, CTR, packet) from its
    response up to the next response."""

    command: bytes
    sent: tuple[tuple[int, int, bytes], ...]


class Session:
    """A recorded conversation: its description and its steps, in order."""

    def __init__(self, path: Path) -> None:
        lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        self.path, self.head = path, lines[0]
        packets = lines[1:]
        commands = [bytes.fromhex(p["hex"]) for p in packets if p["dir"] == "m2s"]
        s2m = [(p["t_ns"], p["ctr"], bytes.fromhex(p["hex"])) for p in packets if p["dir"] == "s2m"]
        responses = [k for k, (_t, _c, pkt) in enumerate(s2m) if pkt[0] in (0xFF, 0xFE)]
        if len(responses) != len(commands) or (responses and responses[0] != 0):
            raise ValueError(f"{path.name}: {len(commands)} commands and {len(responses)} responses")
        ends = responses[1:] + [len(s2m)]
        self.steps = [Step(cmd, tuple(s2m[a:b])) for cmd, a, b in zip(commands, responses, ends)]
        self.transport = self.head["transport"]

    def dtos(self) -> list[tuple[int, int, bytes]]:
        """Every DTO the slave sent (PID below 0xFC), in order."""
        return [s for step in self.steps for s in step.sent if s[2][0] < 0xFC]


class Replay:
    """The slave's side of ``session`` on 127.0.0.1 (``url``), served on a thread until :meth:`close`.

    Attributes
    ----------
    url : str
        ``xcp+tcp://127.0.0.1:PORT`` or ``xcp+udp://...``.
    answered : int
        Commands answered as recorded.
    mismatch : tuple of (int, bytes, bytes or None) or None
        The first command that was not the session's next: its number, what the master sent, what
        the session held there (None: the session had ended).
    """

    def __init__(self, session: Session) -> None:
        self.session = session
        self.answered = 0
        self.mismatch: tuple[int, bytes, bytes | None] | None = None
        self._stop = threading.Event()
        kind = socket.SOCK_STREAM if session.transport == "tcp" else socket.SOCK_DGRAM
        self._sock = socket.socket(socket.AF_INET, kind)
        self._sock.bind(("127.0.0.1", 0))
        if kind == socket.SOCK_STREAM:
            self._sock.listen(1)
        self.url = f"xcp+{session.transport}://127.0.0.1:{self._sock.getsockname()[1]}"
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def __enter__(self) -> Replay:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._sock.close()

    @property
    def finished(self) -> bool:
        """Every command of the session was asked and answered."""
        return self.answered == len(self.session.steps)

    def explain(self) -> str:
        if self.mismatch is None:
            return f"{self.answered} of {len(self.session.steps)} commands answered as recorded"
        k, got, held = self.mismatch
        return (f"{self.session.path.name}: command {k} was {got.hex()}, the recorded session "
                f"{'had ended' if held is None else f'held {held.hex()}'}: no response is known for it")

    # --- serving -------------------------------------------------------------------------------

    def _serve(self) -> None:
        tcp = self.session.transport == "tcp"
        conn, peer, buf = None, None, bytearray()
        queue: list[tuple[float, int, bytes]] = []  # (due, ctr, packet)
        while not self._stop.is_set():
            if tcp and conn is None:
                ready, _, _ = select.select([self._sock], [], [], 0.05)
                if ready:
                    conn, _ = self._sock.accept()
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    buf.clear()
                continue
            wait = max(0.0, min(0.05, queue[0][0] - time.monotonic())) if queue else 0.05
            ready, _, _ = select.select([conn if tcp else self._sock], [], [], wait)
            now = time.monotonic()
            send = (lambda data: conn.sendall(data)) if tcp else (lambda data: self._sock.sendto(data, peer))
            try:
                while queue and queue[0][0] <= now:
                    _due, ctr, packet = queue.pop(0)
                    send(HEADER.pack(len(packet), ctr) + packet)
                if not ready:
                    continue
                if tcp:
                    data = conn.recv(1 << 16)
                    if not data:  # the master closed: the next may connect (a session of several)
                        conn.close()
                        conn = None
                        queue.clear()
                        continue
                    buf += data
                else:
                    data, peer = self._sock.recvfrom(1 << 16)
                    send = lambda data: self._sock.sendto(data, peer)  # noqa: E731 (the peer just learned)
                    buf = bytearray(data)
                while len(buf) >= HEADER.size:
                    length, _ctr = HEADER.unpack_from(buf)
                    if len(buf) < HEADER.size + length:
                        break
                    command = bytes(buf[HEADER.size : HEADER.size + length])
                    del buf[: HEADER.size + length]
                    for _due, ctr, packet in queue:  # already on their way when the command came
                        send(HEADER.pack(len(packet), ctr) + packet)
                    queue.clear()
                    if self.mismatch is None:
                        self._answer(command, queue)
            except OSError:
                if tcp and conn is not None:
                    conn.close()
                    conn = None
                queue.clear()
        if conn is not None:
            conn.close()

    def _answer(self, command: bytes, queue: list) -> None:
        """Queue the recorded answer to ``command``; if it is not the session's next command, note
        :attr:`mismatch` and answer nothing from then on (the master meets a silent slave)."""
        k = self.answered
        steps = self.session.steps
        if k >= len(steps) or steps[k].command != command:
            self.mismatch = (k, command, steps[k].command if k < len(steps) else None)
            return
        self.answered += 1
        start = time.monotonic()
        t0 = steps[k].sent[0][0]
        for t, ctr, packet in steps[k].sent:
            queue.append((start + (t - t0) * 1e-9, ctr, packet))


# --- what the slave sent, decoded by the configuration the session's own commands wrote ------------

GET_DAQ_PROCESSOR_INFO, GET_DAQ_RESOLUTION_INFO, CONNECT = 0xDA, 0xD9, 0xFF
SET_DAQ_PTR, WRITE_DAQ, SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST = 0xE2, 0xE1, 0xE0, 0xDE
ID_FIELD = {0: 1, 1: 2, 2: 3, 3: 4}  # DAQ_KEY_BYTE identification: absolute PID; ODT + DAQ byte; + DAQ word; + fill + DAQ word


@dataclass
class DaqSamples:
    """One DAQ list's samples as the slave sent them: the event it was set to, each sample's raw
    timestamp (0 where none) and the bytes of each ODT entry by (address extension, address)."""

    event: int
    entries: list[list[tuple[int, int, int]]]  # per ODT: (extension, address, size)
    timestamps: list[int]
    values: list[dict[tuple[int, int], bytes]]


def daq_samples(session: Session) -> dict[int, DaqSamples]:
    """Every whole sample of every DAQ list in ``session``, decoded with the ODT layout its
    WRITE_DAQ commands configured (ASAM MCD-1 XCP Part 2: SET_DAQ_PTR, WRITE_DAQ,
    SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST; the identification field from GET_DAQ_PROCESSOR_INFO's
    DAQ_KEY_BYTE, the timestamp size from GET_DAQ_RESOLUTION_INFO), by this module alone."""
    order, ident, ts_size = "<", 0, 0
    lists: dict[int, DaqSamples] = {}
    first_pid: dict[int, int] = {}
    timestamped: set[int] = set()
    ptr = (0, 0)
    for step in session.steps:
        cmd, response = step.command, step.sent[0][2]
        if cmd[0] == CONNECT:
            order = ">" if response[2] & 0x01 else "<"
        elif cmd[0] == GET_DAQ_PROCESSOR_INFO:
            ident = response[7] >> 6
        elif cmd[0] == GET_DAQ_RESOLUTION_INFO:
            ts_size = response[5] & 0x07
        elif cmd[0] == SET_DAQ_PTR:
            daq, odt = struct.unpack_from(order + "H", cmd, 2)[0], cmd[4]
            ptr = (daq, odt)
        elif cmd[0] == WRITE_DAQ:
            size, ext, address = cmd[2], cmd[3], struct.unpack_from(order + "I", cmd, 4)[0]
            entries = lists.setdefault(ptr[0], DaqSamples(-1, [], [], [])).entries
            while len(entries) <= ptr[1]:
                entries.append([])
            entries[ptr[1]].append((ext, address, size))
        elif cmd[0] == SET_DAQ_LIST_MODE:
            daq, event = struct.unpack_from(order + "HH", cmd, 2)
            lists.setdefault(daq, DaqSamples(-1, [], [], [])).event = event
            if cmd[1] & 0x10:
                timestamped.add(daq)
        elif cmd[0] == START_STOP_DAQ_LIST and cmd[1] == 0x02:  # select: its first PID comes back
            first_pid[struct.unpack_from(order + "H", cmd, 2)[0]] = response[1]
    by_pid = {first_pid[d] + j: (d, j) for d in first_pid for j in range(len(lists[d].entries))}
    head = ID_FIELD[ident]
    partial: dict[int, tuple[int, dict]] = {}
    stamp = {1: "B", 2: "H", 4: "I"}.get(ts_size, "")
    for _t, _ctr, dto in session.dtos():
        if ident == 0:
            daq, odt = by_pid[dto[0]]
        else:
            odt = dto[0]
            daq = dto[1] if ident == 1 else struct.unpack_from(order + "H", dto, 1 if ident == 2 else 2)[0]
        at, ts = head, 0
        if odt == 0:
            if daq in timestamped:
                ts = struct.unpack_from(order + stamp, dto, at)[0]
                at += ts_size
            partial[daq] = (ts, {})
        elif daq not in partial:
            continue  # the rest of a sample whose first ODT was not seen
        for ext, address, size in lists[daq].entries[odt]:
            partial[daq][1][(ext, address)] = bytes(dto[at : at + size])
            at += size
        if odt == len(lists[daq].entries) - 1:
            ts, values = partial.pop(daq)
            lists[daq].timestamps.append(ts)
            lists[daq].values.append(values)
    return lists
