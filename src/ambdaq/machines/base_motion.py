"""Kang & Jung's shaft on two AMBs on a moving base (a vehicle gimbal's elevation axis), as ambdaq
knows it: its axes, its base accelerometers, its two planes and its controller's FIR
feedforward.  The rig's physics and numbers are in :mod:`ambdaq.sim.rigs.base_motion`."""

AXES = ("amb1_y", "amb2_y", "amb1_z", "amb2_z")  # plane-major: (plane, bearing)
BASE_AXES = ("base1_y", "base2_y", "base1_z", "base2_z")  # the accelerometers under the bearings
PLANES = ("vertical", "horizontal")
SAMPLE_RATE = 10_000.0  # Hz, the controller's rate
MAX_FIR_TAPS = 64  # the controller's FIR feedforward, per (plane, output, input)
