"""Device URLs: one string names a device (see docs/device-urls.md).

``scheme://target?option=value&...``.  Each scheme registers the options it accepts; an unknown
scheme or option is a :class:`~ambdaq.errors.BadInputError` that spells out the expected form.
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from ..errors import BadInputError


@dataclass(frozen=True)
class Scheme:
    """A URL scheme: its form for error messages and the options it accepts."""

    name: str
    form: str
    options: tuple[str, ...]


SCHEMES: dict[str, Scheme] = {
    "sim": Scheme(
        "sim",
        "sim://PROFILE[?seed=N&rpm=SPEED&truth=0|1&ff=off|table|lms&noise=0|1]",
        ("seed", "rpm", "truth", "ff", "noise"),
    ),
    "can": Scheme(
        "can",
        "can://INTERFACE/CHANNEL?node=N[&kind=amplifier|gap_sensor|accelerometer|keyphasor|controller&sync=HZ"
        "&bitrate=1000000&namespace=NAME] (any python-can interface, e.g. can://virtual/amb0?node=16)",
        ("node", "kind", "sync", "bitrate", "namespace"),
    ),
    "serial": Scheme(
        "serial",
        "serial:///dev/ttyUSB0[?baud=3000000] or serial:socket://HOST:PORT (any pyserial URL)",
        ("baud",),
    ),
}


@dataclass(frozen=True)
class DeviceURL:
    """A parsed device URL.

    Parameters
    ----------
    scheme : str
        ``sim`` ...
    target : str
        What the scheme addresses: the rig profile for ``sim``.
    options : dict of str to str
        Query options.
    text : str
        The URL as given.
    """

    scheme: str
    target: str
    options: dict[str, str]
    text: str


def expected_forms() -> str:
    return "; ".join(s.form for s in SCHEMES.values())


def _parse_serial(text: str, scheme: Scheme) -> DeviceURL:
    """``serial:`` + a port path or a pyserial URL, then options: the target keeps its slashes."""
    rest, _, query = text[len("serial:") :].partition("?")
    port = rest[2:] if rest.startswith("///") else rest
    if not port or port == "//":
        raise BadInputError(f"device URL {text!r} names no port: expected {scheme.form}")
    try:
        options = dict(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
    except ValueError:
        raise BadInputError(f"malformed options in {text!r}: expected {scheme.form}") from None
    unknown = sorted(set(options) - set(scheme.options))
    if unknown:
        raise BadInputError(f"unknown option {unknown[0]!r} in {text!r}: expected {scheme.form}")
    return DeviceURL("serial", port, options, text)


def parse_device_url(text: str) -> DeviceURL:
    """Parse ``text`` into a :class:`DeviceURL`, checking scheme and option names."""
    if text.startswith("serial:"):
        return _parse_serial(text, SCHEMES["serial"])
    parts = urlsplit(text)
    scheme = SCHEMES.get(parts.scheme)
    if scheme is None or "://" not in text:
        raise BadInputError(f"unknown device URL {text!r}: expected {expected_forms()}")
    target = (parts.netloc + parts.path).strip("/")
    if not target:
        raise BadInputError(f"device URL {text!r} names no device: expected {scheme.form}")
    try:
        pairs = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise BadInputError(f"malformed options in {text!r}: expected {scheme.form}") from None
    options = dict(pairs)
    unknown = sorted(set(options) - set(scheme.options))
    if unknown:
        raise BadInputError(f"unknown option {unknown[0]!r} in {text!r}: expected {scheme.form}")
    return DeviceURL(parts.scheme, target, options, text)
