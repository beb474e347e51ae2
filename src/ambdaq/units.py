"""Units ambdaq converts between, defined once (everything else is SI)."""

import math

RPM_TO_RAD_S = 2.0 * math.pi / 60.0  # rotor speed: rpm -> rad/s
RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)
GRAVITY = 9.81  # m/s^2, for every rig's rotor weight


def phasor_um_deg(v) -> tuple[float, float]:
    """A harmonic's phasor in m as its amplitude in µm and its phase in degrees, as every table and
    document of ambdaq gives a 1X or a runout harmonic.

    Parameters
    ----------
    v : complex or pair of float
        ``a + j b`` for ``a sin k theta + b cos k theta``, in m, or the weight pair ``(a, b)`` of a
        coefficient file.

    Returns
    -------
    tuple of float
        Amplitude in µm, phase in degrees (-180 to 180).
    """
    z = complex(v) if isinstance(v, complex) or not hasattr(v, "__len__") else complex(v[0], v[1])
    return abs(z) * 1e6, math.degrees(math.atan2(z.imag, z.real))
