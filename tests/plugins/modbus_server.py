"""A Modbus TCP server no one here wrote (pymodbus's simulator) holding a probe conditioner's
registers, for the plug-in test (tests/test_modbus_plugin.py): a frame counter at 0 that counts
every read, then a gap in int16 (1), uint32 (2-3) and float32 (4-5).

    python modbus_server.py PORT
"""

import asyncio
import sys

from pymodbus.server import StartAsyncTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

HELD = {"frames": None, "int16": -1234, "uint32": 100_000, "float32": 1.5}


async def count(function_code, start_address, address, count, current_registers, set_values):
    """Every read advances the frame counter (register 0) by one, as a conditioner's frame count does."""
    current_registers[0 - start_address] = (current_registers[0 - start_address] + 1) & 0xFFFF
    return None


def run(port: int) -> None:
    registers = [SimData(0, values=[0, HELD["int16"] & 0xFFFF, HELD["uint32"] >> 16, HELD["uint32"] & 0xFFFF],
                         datatype=DataType.REGISTERS),
                 SimData(4, values=[HELD["float32"]], datatype=DataType.FLOAT32)]
    asyncio.run(StartAsyncTcpServer(context=SimDevice(1, simdata=registers, action=count), address=("127.0.0.1", port)))


if __name__ == "__main__":
    run(int(sys.argv[1]))
