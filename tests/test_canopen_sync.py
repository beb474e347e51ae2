"""CANopen rows hold one SYNC's data or none: a device known by a real EDS, as shipped (the
corpus's vendor e35.eds, and python-canopen's sample.eds, which has no synchronous window 0x1007),
that answers some SYNCs a whole period late, as a device without a usable window can. The device
puts a value of the counter byte of the SYNC it answers into each mapped object, so every recorded
row says which SYNC its data came from."""

from __future__ import annotations

import json
import queue
import random
import sys
import threading
import time
from pathlib import Path

import canopen
import numpy as np
import pytest

from ambdaq.daq import load
from ambdaq.mcap.mcapfile import McapFile

sys.path.insert(0, str(Path(__file__).parent))
from eds_gateway import recordable, synchronous_tpdos, value_of  # noqa: E402

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

E35 = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "eds" / "e35.eds"
SAMPLE = Path(__file__).parent / "data" / "canopen_sample.eds"  # python-canopen's test/sample.eds, as shipped
NODE = 9
RATE = 200  # Hz: a 5 ms period, a 2.5 ms synchronous window
SYNC_COUNTER_MAX = 240  # CiA 301 0x1019: the SYNC counter runs 1..240


class LaggingEchoDrive:
    """A canopen LocalNode from ``eds`` that, on each SYNC, puts into every object mapped to its
    synchronous TPDOs the value ``value_of`` gives for the SYNC's counter byte (tests/eds_gateway.py),
    and sends those TPDOs as the host mapped them. Replies leave in SYNC order from one sender thread;
    most after 0.1-0.4 ms, but ``lag`` of the SYNCs start a run of one to five answered a whole
    period late (the device then catches up), and ``late`` go out after the window has closed.
    It never honours the window the host sets: that is the device the host must not trust."""

    def __init__(self, channel: str, eds: Path, *, lag: float, late: float, seed: int) -> None:
        self.network = canopen.Network()
        self.network.connect(interface="virtual", channel=channel)
        self.node = canopen.LocalNode(NODE, str(eds))
        self.network.add_node(self.node)
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.rng, self.lag, self.late = random.Random(seed), lag, late
        self.period = 1.0 / RATE
        self._lagging = 0
        self._last_out = 0.0
        self._out: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._sender = threading.Thread(target=self._send_loop, daemon=True)
        self._sender.start()
        self.network.subscribe(0x80, self._on_sync)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL" or not data:
            return
        frames = synchronous_tpdos(self.node, data[0])
        if self._lagging == 0 and self.rng.random() < self.lag:
            self._lagging = self.rng.randint(1, 5)
        delay = self.rng.uniform(1e-4, 4e-4)
        if self._lagging:
            self._lagging -= 1
            delay += self.period  # answered after the next SYNC went out
        elif self.rng.random() < self.late:
            delay = 0.7 * self.period  # after its window closed
        self._last_out = max(timestamp + delay, self._last_out + 5e-5)  # in order, as one CPU sends
        self._out.put((self._last_out, frames))

    def _send_loop(self) -> None:
        while not self._stop.is_set():
            try:
                at, frames = self._out.get(timeout=0.1)
            except queue.Empty:
                continue
            time.sleep(max(0.0, at - time.time()))
            for cob, payload in frames:
                self.network.send_message(cob, payload)

    def close(self) -> None:
        self._stop.set()
        self._sender.join(1.0)
        self.network.disconnect()


def rig_file(tmp_path: Path, channel: str, eds: Path, objects: list[tuple[int, int, int]]) -> Path:
    (tmp_path / eds.name).write_bytes(eds.read_bytes())
    path = tmp_path / "rig.toml"
    path.write_text(f'''name = "echo"
[[device]]
name = "drive"
url = "can://virtual/{channel}?node={NODE}&sync={RATE}"
eds = "{eds.name}"
mapping = "configure"
''' + "".join(f'''[[device.signal]]
object = "0x{index:04X}.{sub}"
topic = "/drive/sync"
field = "o{index:04x}_{sub}"
factor = 1
tpdo = {k + 1}
''' for k, (index, sub, _t) in enumerate(objects)))
    return path


@pytest.mark.parametrize("eds", [E35, SAMPLE], ids=["e35.eds", "canopen_sample.eds (no 0x1007)"])
def test_no_row_holds_another_syncs_data_when_the_device_answers_a_period_late(eds, tmp_path, run_cli):
    if not eds.is_file():
        pytest.skip(f"{eds} is not beside the clone")
    objects = recordable(eds, 2)  # one per TPDO: a lag shows as a second reply of each
    channel = f"sync-echo-{time.monotonic_ns()}"
    drive = LaggingEchoDrive(channel, eds, lag=0.03, late=0.02, seed=7)
    try:
        out = tmp_path / "echo.mcap"
        r = run_cli("record", "--rig", rig_file(tmp_path, channel, eds, objects), "--duration", "3", "--json", "-o", out)
        assert r.exit_code == 0, r.output
    finally:
        drive.close()
    summary = json.loads(r.stdout)
    cycles = 3 * RATE
    assert summary["samples"] + summary["drops"] == cycles  # every cycle recorded or counted lost
    sync = load(out)["/drive/sync"]
    # the SYNC each row's data answered (every object's value says it), against the SYNC the row is
    # filed under (its seq)
    expected = sync.seq.astype(np.int64) % SYNC_COUNTER_MAX + 1
    for index, sub, data_type in objects:
        want = np.array([value_of(int(c), index, sub, data_type) for c in expected])
        wrong = np.flatnonzero(sync[f"o{index:04x}_{sub}"] != want)
        assert wrong.size == 0, f"{wrong.size} of {len(sync)} rows hold another SYNC's data: seq {sync.seq[wrong[:5]]}"
    stats = McapFile(out).metadata()["ambdaq.link.drive"]
    # about 3 % of 600 SYNCs start a lag (18 runs, each ending with a catch-up the host sees), 2 %
    # are answered after their window: both kinds occurred, were dropped and counted
    assert int(stats["ambiguous_cycles"]) > 0 and int(stats["late_replies"]) > 0, stats
    assert int(stats["unverified_cycles"]) == 0  # no run was longer than the hold
    assert len(sync) >= cycles // 2  # the rest of the SYNCs are kept (a loaded host loses more to lateness)
    window = McapFile(out).metadata()["ambdaq.device.drive"]["synchronous_window_us"]
    assert window == ("2500 (host only: the device has no 0x1007)" if eds is SAMPLE else "2500")
