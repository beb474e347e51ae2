"""CAN at full 1 Mbit/s load on python-can's virtual bus: lost frames and recorder CPU.

Four simulated CANopen devices answer SYNC at 1,070 Hz: 7 frames per cycle, ~7,500 frames/s,
~84 % of 1 Mbit/s (the recorder refuses streams above 80 %; this benchmark lifts the limit on
purpose).  In the same run, on the same traffic, python-can's own logging path (a
``can.Notifier`` with ``can.Logger`` writing .blf) logs every frame.  CPU is read per thread
from /proc: the recorder's threads (its bus receive thread, which decodes the PDOs, the device reader
threads and the writer) against the logger's notifier thread.  The SYNC producer and the
simulated devices are traffic, not recorder, and are left out of both.
Target: zero lost frames, recorder CPU / logger CPU <= 1.0.

    python benchmarks/bench_can_load.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import can

from ambdaq.acquisition.recorder import Recorder, RecordOptions
from ambdaq.drivers.can.bus import bus_load
from ambdaq.drivers.registry import open_device
from ambdaq.speed import SpeedProfile
from ambdaq.sim.rigs.spindle import SpindleRig
from ambdaq.sim.devices.canopen import open_network, serve_can
from ambdaq.sim.devices.rig_server import RigServer

from _common import row

SYNC_HZ = 1070.0
KINDS = ("amplifier", "gap_sensor", "accelerometer", "keyphasor")


class ThreadCpu(threading.Thread):
    """Samples the CPU seconds of every thread of this process twice a second, by native id
    (a thread's /proc counters vanish when it ends, so the last sample is kept)."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.cpu: dict[int, float] = {}
        self.names: dict[int, str] = {}
        self.stop = threading.Event()
        self.tick = os.sysconf("SC_CLK_TCK")

    def sample(self) -> None:
        for t in threading.enumerate():
            try:
                with open(f"/proc/self/task/{t.native_id}/stat") as fh:
                    f = fh.read().rsplit(")", 1)[1].split()
            except (OSError, TypeError):
                continue
            self.cpu[t.native_id] = (int(f[11]) + int(f[12])) / self.tick
            self.names[t.native_id] = t.name

    def run(self) -> None:
        while not self.stop.wait(0.5):
            self.sample()


class Count(can.Listener):
    def __init__(self) -> None:
        self.n = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.n += 1


def notifier_ids(notifier: can.Notifier) -> set[int]:
    return {t.native_id for t in notifier._readers if isinstance(t, threading.Thread)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--threads", action="store_true", help="print the CPU of each measured thread")
    args = ap.parse_args()
    channel = "bench-can"
    server = RigServer(SpindleRig(speed=SpeedProfile(30000, 30000)))
    dev_net = open_network(channel)
    serve_can(dev_net, server)
    server.start()
    devices = [open_device(f"can://virtual/{channel}?kind={k}&sync={SYNC_HZ:g}") for k in KINDS]
    hub = devices[0].hub
    hub.load_limit = 1.0  # saturate the bus on purpose
    monitor = ThreadCpu()
    with tempfile.TemporaryDirectory() as tmp:
        log_bus = can.Bus(interface="virtual", channel=channel)
        count = Count()
        notifier = can.Notifier(log_bus, [can.Logger(str(Path(tmp) / "baseline.blf")), count])
        monitor.sample()
        start = dict(monitor.cpu)
        monitor.start()
        t0 = time.monotonic()
        res = Recorder(devices, Path(tmp) / "can.mcap", RecordOptions(duration_s=args.seconds)).run()
        wall = time.monotonic() - t0
        monitor.sample()
        monitor.stop.set()
        frames = count.n
        notifier.stop()
        log_bus.shutdown()
        hub_rx = {hub.receive_thread_id}
    server.stop()
    dev_net.disconnect()
    used = {tid: monitor.cpu[tid] - start.get(tid, 0.0) for tid in monitor.cpu}
    logger_cpu = sum(used.get(t, 0.0) for t in notifier_ids(notifier))
    recorder_ids = hub_rx | {threading.main_thread().native_id} | {
        t for t, n in monitor.names.items() if n.startswith("read-")}
    recorder_cpu = sum(used.get(t, 0.0) for t in recorder_ids)
    if args.threads:
        for tid in sorted(recorder_ids | notifier_ids(notifier), key=lambda t: -used.get(t, 0.0)):
            part = "logger" if tid in notifier_ids(notifier) else "recorder"
            print(f"  {part:<9} {monitor.names.get(tid, tid)!s:<50} {used.get(tid, 0.0):6.2f} s")
    load = bus_load([1, 8, 5, 8, 3, 7, 8], SYNC_HZ, 1_000_000)
    expected = round(args.seconds * SYNC_HZ)
    print(row("frames on the bus (counted by the logger)", frames / wall, "frames/s", f"worst-case load {load:.0%}"))
    print(row("recorded SYNC cycles (each device)", res.samples, "cycles", f"expected {expected}"))
    print(row("lost cycles (all devices)", res.drops, "cycles"))
    print(f"CPU over {wall:.1f} s: recorder {recorder_cpu:.2f} s ({100 * recorder_cpu / wall:.1f} % of a core), "
          f"python-can Notifier + BLF Logger {logger_cpu:.2f} s ({100 * logger_cpu / wall:.1f} %); "
          f"ratio recorder / logger = {recorder_cpu / max(logger_cpu, 1e-9):.2f} (target <= 1.0)")


if __name__ == "__main__":
    main()
