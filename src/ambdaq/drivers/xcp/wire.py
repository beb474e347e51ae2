"""XCP on the wire: the codes and the header both ends use (ASAM MCD-1 XCP Part 2, the protocol
layer; Part 3, the transport layers' LEN/CTR header).

One home for them, as the serial protocol has :mod:`ambdaq.drivers.serial.protocol`: the master
(:mod:`.master`, :mod:`.transport`) and the simulated controller's slave
(:mod:`ambdaq.sim.devices.xcp`) import the same numbers, so neither can drift from the other
unseen. What each side does with them stays with it.
"""

from __future__ import annotations

import struct

HEADER = struct.Struct("<HH")  # LEN, CTR (Part 3: Ethernet, SxI with LEN_CTR_WORD framing)

# packet identifiers of what the slave sends (Part 2: CTO packets)
PID_RES, PID_ERR, PID_EV, PID_SERV = 0xFF, 0xFE, 0xFD, 0xFC
EV_CMD_PENDING, EV_DAQ_OVERLOAD, EV_SESSION_TERMINATED = 0x05, 0x06, 0x07
SERV_TEXT = 0x01

# resources (CONNECT, GET_STATUS, GET_SEED)
RES_CALPAG, RES_DAQ, RES_STIM, RES_PGM = 0x01, 0x04, 0x08, 0x10

# command codes (Part 2, table of commands)
CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID = 0xFF, 0xFE, 0xFD, 0xFC, 0xFB, 0xFA
SET_REQUEST, GET_SEED, UNLOCK, SET_MTA, UPLOAD, SHORT_UPLOAD, BUILD_CHECKSUM = 0xF9, 0xF8, 0xF7, 0xF6, 0xF5, 0xF4, 0xF3
DOWNLOAD, SHORT_DOWNLOAD, SET_CAL_PAGE, GET_CAL_PAGE, GET_PAG_PROCESSOR_INFO = 0xF0, 0xED, 0xEB, 0xEA, 0xE9
COPY_CAL_PAGE = 0xE4
SET_DAQ_PTR, WRITE_DAQ, SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST, START_STOP_SYNCH = 0xE2, 0xE1, 0xE0, 0xDE, 0xDD
GET_DAQ_CLOCK, GET_DAQ_PROCESSOR_INFO, GET_DAQ_RESOLUTION_INFO, GET_DAQ_EVENT_INFO = 0xDC, 0xDA, 0xD9, 0xD7
GET_DAQ_LIST_INFO, CLEAR_DAQ_LIST = 0xD8, 0xE3
FREE_DAQ, ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY = 0xD6, 0xD5, 0xD4, 0xD3

XCP_ERRORS = {
    # Part 2, the error codes of a negative response, and what each means
    0x00: ("ERR_CMD_SYNCH", "command processor synchronisation"),
    0x10: ("ERR_CMD_BUSY", "command not executed: the slave is busy"),
    0x11: ("ERR_DAQ_ACTIVE", "command rejected while DAQ is running"),
    0x12: ("ERR_PGM_ACTIVE", "command rejected while programming is running"),
    0x20: ("ERR_CMD_UNKNOWN", "unknown command, or an optional one the slave lacks"),
    0x21: ("ERR_CMD_SYNTAX", "command syntax invalid"),
    0x22: ("ERR_OUT_OF_RANGE", "a command parameter is out of range"),
    0x23: ("ERR_WRITE_PROTECTED", "the memory location is write protected"),
    0x24: ("ERR_ACCESS_DENIED", "the memory location is not accessible"),
    0x25: ("ERR_ACCESS_LOCKED", "access denied: seed & key is required"),
    0x26: ("ERR_PAGE_NOT_VALID", "the page is not available"),
    0x27: ("ERR_MODE_NOT_VALID", "the page mode is not available"),
    0x28: ("ERR_SEGMENT_NOT_VALID", "the segment is not valid"),
    0x29: ("ERR_SEQUENCE", "commands out of sequence"),
    0x2A: ("ERR_DAQ_CONFIG", "the DAQ configuration is not valid"),
    0x30: ("ERR_MEMORY_OVERFLOW", "memory overflow"),
    0x31: ("ERR_GENERIC", "generic error"),
    0x32: ("ERR_VERIFY", "the slave's verification found an error"),
}
ERR_CMD_SYNCH, ERR_CMD_BUSY, ERR_DAQ_ACTIVE, ERR_CMD_UNKNOWN, ERR_CMD_SYNTAX = 0x00, 0x10, 0x11, 0x20, 0x21
ERR_OUT_OF_RANGE, ERR_WRITE_PROTECTED, ERR_ACCESS_LOCKED, ERR_PAGE_NOT_VALID = 0x22, 0x23, 0x25, 0x26
ERR_MODE_NOT_VALID, ERR_SEGMENT_NOT_VALID, ERR_SEQUENCE, ERR_DAQ_CONFIG, ERR_VERIFY = 0x27, 0x28, 0x29, 0x2A, 0x32

CHECKSUM_TYPES = {0x01: "XCP_ADD_11", 0x02: "XCP_ADD_12", 0x03: "XCP_ADD_14", 0x04: "XCP_ADD_22",
                  0x05: "XCP_ADD_24", 0x06: "XCP_ADD_44", 0x07: "XCP_CRC_16", 0x08: "XCP_CRC_16_CITT",
                  0x09: "XCP_CRC_32", 0xFF: "XCP_USER_DEFINED"}
"""BUILD_CHECKSUM's checksum type codes (Part 2)."""
CHECKSUM_CRC_32 = 0x09

TIME_UNITS_NS = {0: 1, 1: 10, 2: 100, 3: 1_000, 4: 10_000, 5: 100_000, 6: 1_000_000, 7: 10_000_000,
                 8: 100_000_000, 9: 1_000_000_000}
"""DAQ timestamp and event cycle units (Part 2: DAQ_TIMESTAMP_UNIT_1NS ... _1S) in ns."""
