"""The exception tree every layer raises and the CLI maps to exit codes.

``AmbdaqError`` is the root.  ``BadInputError`` (exit 2) is for anything the user can fix by
changing what they typed or gave us: a malformed URL, an unknown option, a truncated or foreign
file.  ``DeviceError`` (exit 1) is for runtime failures of devices and I/O.
"""


class AmbdaqError(Exception):
    """Base of all ambdaq errors; the message is one actionable line."""

    exit_code = 1


class BadInputError(AmbdaqError):
    """Bad usage or bad input: a URL, an option, a file that is not what it should be."""

    exit_code = 2


class DeviceError(AmbdaqError):
    """A device or I/O failure at run time (device vanished, write failed)."""

    exit_code = 1


class DeviceTimeout(DeviceError):
    """A device did not answer a request in time (it may or may not have acted on it)."""


class AmbdaqWarning(UserWarning):
    """Something the user should know and that did not stop the command (a DBC file read with
    cantools' checks relaxed): the command line prints it as one ``ambdaq: warning:`` line."""
