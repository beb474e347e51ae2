"""Sends CAN frames from its own process through the simulated SLCAN adapter (a pseudo-terminal
speaking Lawicel), so that a recorder in another process reads them with python-can's ``slcan``
interface: the way CAN crosses a process boundary on a machine without ``vcan``.

    python tests/slcan_sender.py FRAMES.json SECONDS

FRAMES.json holds ``[[frame id, data hex, is FD, is extended], ...]``; they are sent in order, round after round,
every 10 ms, for SECONDS. The first line printed is the pseudo-terminal's path.
"""

import json
import os
import pty
import sys
import time

import can

from ambdaq.sim.devices.slcan import SimSlcanAdapter


def main() -> None:
    frames = [can.Message(arbitration_id=i, data=bytes.fromhex(h), is_extended_id=ext, is_fd=fd)
              for i, h, fd, ext in json.loads(open(sys.argv[1]).read())]
    seconds = float(sys.argv[2])
    channel = f"slcan-sender-{os.getpid()}"
    master, slave = pty.openpty()
    adapter = SimSlcanAdapter(master, channel)
    adapter.start()
    bus = can.Bus(interface="virtual", channel=channel)
    print(os.ttyname(slave), flush=True)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            for msg in frames:
                bus.send(msg)
            time.sleep(0.01)
    finally:
        bus.shutdown()
        adapter.stop()


if __name__ == "__main__":
    main()
