"""The simulator: rig physics and the simulated devices that serve it on real transports.

A back-end like any other (it registers ``sim://``): the drivers in :mod:`ambdaq.drivers` talk to
these devices over a pseudo-terminal or a CAN bus exactly as to hardware, and nothing under
``drivers`` imports this package.
"""
