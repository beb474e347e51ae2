"""The MCAP layout's signal roles and the topics ambdaq's own devices record them on (the layout
contract, docs/data-format.md): one home for ``/amb/gap`` and its kin.

A *role* is what a signal is to an AMB engineer: the gap at the sensors, the coil control
currents, the key-phasor's rotor angle and speed.  ambdaq's controllers and simulated devices
record each role on its topic here, with fields named after the machine's axes.  A device no one
here wrote records its own topics; a rig file maps its fields to roles (``[machine.gap]``,
:mod:`ambdaq.machines.machine`), so the host side finds every role the same way.
"""

ROLE_TOPICS = {
    "gap": "/amb/gap",  # measured displacement at the sensors, m
    "current": "/amb/current",  # coil control currents, A
    "accel": "/amb/accel",  # housing or base acceleration, m/s^2
    "rotor": "/amb/rotor",  # key-phasor angle (rad) and speed (rad/s): fields angle, speed
    "error": "/amb/error",  # the controller's command error, m
    "ff": "/amb/ff",  # feedforward output, m
    "voltage": "/amb/voltage",  # coil voltages, V
    "control": "/amb/control",  # the controller's output to the amplifiers, V
}
"""Role -> the topic ambdaq's own devices record it on."""

GAP, CURRENT, ACCEL, ROTOR, ERROR, FF, VOLTAGE, CONTROL = (
    ROLE_TOPICS[r] for r in ("gap", "current", "accel", "rotor", "error", "ff", "voltage", "control"))
ROTOR_FIELDS = ("angle", "speed")  # the rotor role's fields: rad, rad/s

__all__ = ["ACCEL", "CONTROL", "CURRENT", "ERROR", "FF", "GAP", "ROLE_TOPICS", "ROTOR", "ROTOR_FIELDS", "VOLTAGE"]
