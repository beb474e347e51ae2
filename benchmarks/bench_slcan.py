"""CAN across processes through the simulated SLCAN adapter: lost frames and CPU, against
python-can's logger on the same traffic.

``ambdaq sim serve --can slcan`` runs the rig and its four CANopen devices in another process,
behind a simulated SLCAN adapter on a pseudo-terminal.  Two phases, each with its own served rig
and the same traffic (SYNC at RATE Hz, the devices' 6 TPDOs per SYNC):

* ambdaq: ``Recorder`` over the four ``can://slcan/...`` devices (python-can's slcan interface
  under ambdaq's CAN hub);
* baseline: python-can's own path, a ``can.Notifier`` on the same slcan interface with a
  ``can.Logger`` writing .blf (canopen configures the devices and produces SYNC, as a user with
  python-can alone would).

CPU is per thread from /proc (``bench_can_load.ThreadCpu``): the recorder's receive, reader and
writer threads against the notifier's thread.  Lost frames: what the adapter could not hand over
(its backlog full), the cycles the recorder counted lost, and the frames the logger lacks.

    python benchmarks/bench_slcan.py [--seconds 20] [--rate 400 --rate 1070]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import can
import canopen

from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.drivers.can.bus import bus_load
from ambdaq.drivers.can.device_profiles import DEVICE_PROFILES
from ambdaq.drivers.registry import open_device

from bench_can_load import Count, ThreadCpu, notifier_ids

KINDS = ("amplifier", "gap_sensor", "accelerometer", "keyphasor")
TPDO_BYTES = [8, 5, 8, 3, 7, 8]  # the six TPDOs of the four devices per SYNC


def served() -> tuple[subprocess.Popen, dict[str, str]]:
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--rpm", "30000", "--can", "slcan"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = dict(proc.stdout.readline().split() for _ in range(6))
    return proc, lines


def adapter_lost(proc: subprocess.Popen) -> int:
    proc.terminate()
    _out, err = proc.communicate(timeout=10)
    return int(re.search(r"(\d+) lost", err).group(1))


def phase_ambdaq(seconds: float, rate: float, tmp: Path) -> dict:
    proc, urls = served()
    try:
        devices = [open_device(re.sub(r"sync=[\d.]+", f"sync={rate:g}", urls[k])) for k in KINDS]
        hub = devices[0].hub
        hub.load_limit = 1.0  # saturate the bus on purpose
        monitor = ThreadCpu()
        monitor.sample()
        start = dict(monitor.cpu)
        monitor.start()
        t0 = time.monotonic()
        res = Recorder(devices, tmp / f"slcan-{rate:g}.mcap", RecordOptions(duration_s=seconds)).run()
        wall = time.monotonic() - t0
        monitor.sample()
        monitor.stop.set()
        ids = {hub.receive_thread_id, threading.main_thread().native_id} | {
            t for t, n in monitor.names.items() if n.startswith("read-")}
        cpu = sum(monitor.cpu.get(t, 0.0) - start.get(t, 0.0) for t in ids)
        skipped = hub.skipped_syncs
    finally:
        lost = adapter_lost(proc)
    return {"wall": wall, "cpu": cpu, "cycles": res.samples, "drops": res.drops, "skipped": skipped,
            "adapter_lost": lost}


def phase_logger(seconds: float, rate: float, tmp: Path) -> dict:
    proc, urls = served()
    try:
        network = canopen.Network()
        network.connect(interface="slcan", channel=urls["can"], bitrate=1_000_000, sleep_after_open=0)
        for kind in KINDS:
            p = DEVICE_PROFILES[kind]
            node = network.add_node(p.default_node, str(p.eds_path))
            node.sdo.RESPONSE_TIMEOUT = 2.0
            for i in range(len(p.tpdos)):
                node.sdo[0x1800 + i][1].raw = 0x180 + 0x100 * i + p.default_node
                node.sdo[0x1800 + i][2].raw = 1
            node.nmt.send_command(0x01)
        count = Count()
        logger = can.Logger(str(tmp / f"baseline-{rate:g}.blf"))
        network.notifier.add_listener(logger)
        network.notifier.add_listener(count)
        monitor = ThreadCpu()
        monitor.sample()
        start = dict(monitor.cpu)
        network.sync.start(1.0 / rate)
        t0 = time.monotonic()
        time.sleep(seconds)
        network.sync.stop()
        wall = time.monotonic() - t0
        monitor.sample()
        ids = notifier_ids(network.notifier)
        cpu = sum(monitor.cpu.get(t, 0.0) - start.get(t, 0.0) for t in ids)
        frames = count.n
        network.disconnect()  # stops the notifier and its listeners (the logger closes its file)
    finally:
        lost = adapter_lost(proc)
    return {"wall": wall, "cpu": cpu, "frames": frames, "expected": round(wall * rate * len(TPDO_BYTES)),
            "adapter_lost": lost}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=float, action="append", help="SYNC rate in Hz (repeatable; default 400 and 1070)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rate or [400.0, 1070.0]:
            load = bus_load([1, *TPDO_BYTES], rate, 1_000_000)
            a = phase_ambdaq(args.seconds, rate, Path(tmp))
            b = phase_logger(args.seconds, rate, Path(tmp))
            print(f"SYNC {rate:g} Hz, {rate * len(TPDO_BYTES):,.0f} TPDO frames/s, worst-case bus load {load:.0%}:")
            print(f"  ambdaq recorder: {a['cycles']:,} cycles recorded per device, {a['drops']:,} lost cycles "
                  f"(all devices; {a['skipped']:,} SYNCs held back), adapter lost {a['adapter_lost']:,} frames; "
                  f"CPU {a['cpu']:.2f} s over {a['wall']:.1f} s ({100 * a['cpu'] / a['wall']:.0f} % of a core)")
            print(f"  python-can Notifier + BLF Logger: {b['frames']:,} frames of ~{b['expected']:,} due, "
                  f"adapter lost {b['adapter_lost']:,} frames; CPU {b['cpu']:.2f} s over {b['wall']:.1f} s "
                  f"({100 * b['cpu'] / b['wall']:.0f} % of a core)")
            print(f"  ratio recorder / logger CPU = {a['cpu'] / max(b['cpu'], 1e-9):.2f}")


if __name__ == "__main__":
    main()
