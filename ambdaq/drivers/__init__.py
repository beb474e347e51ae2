"""Transports, protocols, device drivers, simulated devices and the rig physics they serve."""
