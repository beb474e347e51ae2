"""CAN: the shared bus (SYNC, load, health), the CANopen device types with their EDS files, the
CANopen device driver and the controller's CANopen configuration port (docs/protocol.md)."""
