"""Rig physics: closed-loop simulations of AMB machines that feed the simulated devices."""
