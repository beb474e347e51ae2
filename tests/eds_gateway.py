"""A CANopen device from any EDS, with its own SYNC master, behind a socketcand gateway, in a
process of its own: a recorder in another process reaches it over TCP with python-can's
``socketcand`` interface, as a lab PC reaches a machine's CAN bus through a gateway.

    python tests/eds_gateway.py EDS NODE RATE CLOCK_OFFSET_S

The device is a canopen LocalNode built from EDS as shipped. A SYNC master on the bus sends SYNC
with its counter (1..240) at RATE Hz. On each SYNC the device writes into every object mapped to
its synchronous TPDOs the value :func:`value_of` gives for that SYNC's counter, and sends the TPDOs
0.1-0.4 ms later. The gateway's clock runs CLOCK_OFFSET_S apart from the host's. The first line
printed is the gateway's TCP port; the process runs until its stdin closes.
"""

from __future__ import annotations

import random
import struct
import sys
import threading
import time

import canopen
from canopen import objectdictionary as od

from socketcand_gateway import SimSocketcand

FORMATS = {od.INTEGER8: "b", od.UNSIGNED8: "B", od.INTEGER16: "h", od.UNSIGNED16: "H", od.INTEGER32: "i",
           od.UNSIGNED32: "I", od.INTEGER64: "q", od.UNSIGNED64: "Q", od.REAL32: "f", od.REAL64: "d"}


def value_of(counter: int, index: int, subindex: int, data_type: int) -> float | int:
    """The value an object holds in the SYNC with ``counter``: distinct per object, within its type."""
    k = (index * 7 + subindex * 3) % 64
    fmt = FORMATS[data_type]
    if fmt in "fd":
        return counter + k / 4  # exact in float32
    bits = 8 * struct.calcsize(fmt)
    raw = (counter + 16 * k) % (1 << bits)
    return raw - (1 << bits) if fmt.islower() and raw >= 1 << (bits - 1) else raw


def recordable(path: str, count: int) -> list[tuple[int, int, int]]:
    """(index, sub-index, data type) of the first ``count`` TPDO-mappable, readable numeric objects
    of an EDS's manufacturer and profile areas (0x2000 on), four bytes or less each, so two share
    a TPDO."""
    found = []
    for obj in canopen.import_od(str(path)).values():
        for var in [obj] if isinstance(obj, od.ODVariable) else [v for v in obj.values() if v.subindex > 0]:
            if var.index >= 0x2000 and var.pdo_mappable and "r" in var.access_type and var.data_type in FORMATS \
                    and struct.calcsize(FORMATS[var.data_type]) <= 4:
                found.append((var.index, var.subindex, var.data_type))
    return found[:count]


def synchronous_tpdos(node: canopen.LocalNode, counter: int) -> list[tuple[int, bytes]]:
    """(COB-ID, payload) of every mapped synchronous TPDO of ``node`` for the SYNC with ``counter``,
    each mapped object first set to its :func:`value_of` (as the device's application would)."""
    frames = []
    for n in range(512):
        if 0x1800 + n not in node.object_dictionary or 0x1A00 + n not in node.object_dictionary:
            continue
        cob_id = struct.unpack("<I", node.get_data(0x1800 + n, 1))[0]
        if cob_id & 0x80000000 or not 1 <= node.get_data(0x1800 + n, 2)[0] <= 240:
            continue
        payload = b""
        for i in range(1, node.get_data(0x1A00 + n, 0)[0] + 1):
            entry = struct.unpack("<I", node.get_data(0x1A00 + n, i))[0]
            index, sub = entry >> 16, (entry >> 8) & 0xFF
            var = node.object_dictionary[index]
            var = var if isinstance(var, od.ODVariable) else var[sub]
            raw = struct.pack("<" + FORMATS[var.data_type], value_of(counter, index, sub, var.data_type))
            node.set_data(index, sub, raw, check_writable=False)
            payload += raw[: (entry & 0xFF) // 8]
        frames.append((cob_id & 0x7FF, payload))
    return frames


def main() -> None:
    eds, node_id, rate, offset = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
    channel = f"eds-gateway-{random.getrandbits(32):08x}"
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(node_id, eds)
    network.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    rng = random.Random(1)

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        if node.nmt.state != "OPERATIONAL" or not data:
            return
        frames = synchronous_tpdos(node, data[0])
        time.sleep(rng.uniform(1e-4, 4e-4))  # the device's reaction time, well inside the window
        for cob, payload in frames:
            network.send_message(cob, payload)

    network.subscribe(0x80, on_sync)
    stop = threading.Event()

    def sync_master() -> None:
        bus = canopen.Network()
        bus.connect(interface="virtual", channel=channel)
        counter, period, at = 0, 1.0 / rate, time.monotonic()
        while not stop.is_set():
            counter = counter % 240 + 1
            bus.send_message(0x80, bytes([counter]))
            at += period
            time.sleep(max(0.0, at - time.monotonic()))
        bus.disconnect()

    gateway = SimSocketcand(channel, clock_offset_s=offset)
    gateway.start()
    master = threading.Thread(target=sync_master, daemon=True)
    master.start()
    print(gateway.port, flush=True)
    try:
        sys.stdin.read()  # until the test closes it
    finally:
        stop.set()
        master.join(1.0)
        gateway.stop()
        network.disconnect()


if __name__ == "__main__":
    main()
