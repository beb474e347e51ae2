"""ambdaq's own serial protocol: COBS framing with CRC-32, the message types, the host end of a
line and the AMB controller driver on it (docs/protocol.md)."""
