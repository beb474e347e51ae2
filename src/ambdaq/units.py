"""Units ambdaq converts between, defined once (everything else is SI)."""

import math

RPM_TO_RAD_S = 2.0 * math.pi / 60.0  # rotor speed: rpm -> rad/s
RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)
GRAVITY = 9.81  # m/s^2, for every rig's rotor weight
