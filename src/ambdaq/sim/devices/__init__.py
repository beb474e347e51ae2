"""Simulated devices: the far side of a real transport, fed by the rig physics.

Each one speaks the documented wire protocol (serial frames, CANopen) over a real transport (a
pseudo-terminal, python-can's virtual bus), with its own clock, so a driver cannot tell it from
hardware.
"""
