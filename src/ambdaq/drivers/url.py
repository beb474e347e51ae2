"""Device URLs: one string names a device (docs/device-urls.md).

``scheme://target?option=value&...``, or ``serial:`` followed by anything pyserial opens.  The
back-end that owns a scheme (:mod:`.registry`) declares its form and options (:class:`Scheme`);
a URL is parsed once, into a :class:`DeviceURL`, and an unknown scheme or option is a
:class:`~ambdaq.errors.BadInputError` that spells out the expected form.
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from ..errors import BadInputError

TRUE, FALSE = ("1", "true"), ("0", "false")


@dataclass(frozen=True)
class Scheme:
    """A URL scheme: its form for messages and the options it accepts.

    Parameters
    ----------
    name : str
        ``sim``, ``can``, ``serial`` ...
    form : str
        What a URL of it looks like, for error messages.
    options : tuple of str
        Query options it takes.
    opaque : bool
        The target is everything after ``name:`` up to ``?``, slashes and all (``serial:`` takes any
        pyserial URL), instead of the netloc and path of ``name://``.
    """

    name: str
    form: str
    options: tuple[str, ...]
    opaque: bool = False

    def parse(self, text: str) -> "DeviceURL":
        """Parse ``text`` (a URL of this scheme) and check its option names."""
        if self.opaque:
            rest, _, query = text[len(self.name) + 1 :].partition("?")
            target = rest[2:] if rest.startswith("///") else rest
            if not target or target == "//":
                raise BadInputError(f"device URL {text!r} names no {self.name} port: expected {self.form}")
        else:
            try:
                parts = urlsplit(text)
                target = (parts.netloc + parts.path).strip("/")
            except ValueError as err:  # a malformed host, e.g. "[::1" without its bracket
                raise BadInputError(f"device URL {text!r} is malformed ({err}): expected {self.form}") from None
            query = parts.query
            if not target:
                raise BadInputError(f"device URL {text!r} names no device: expected {self.form}")
        try:
            options = dict(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
        except ValueError:
            raise BadInputError(f"malformed options in {text!r}: expected {self.form}") from None
        unknown = sorted(set(options) - set(self.options))
        if unknown:
            raise BadInputError(f"unknown option {unknown[0]!r} in {text!r}: expected {self.form}")
        return DeviceURL(self.name, target, options, text)


@dataclass(frozen=True)
class DeviceURL:
    """A parsed device URL.

    Parameters
    ----------
    scheme : str
        ``sim``, ``can``, ``serial`` ...
    target : str
        What the scheme addresses: the rig profile for ``sim``, ``INTERFACE/CHANNEL`` for ``can``,
        the port or pyserial URL for ``serial``.
    options : dict of str to str
        Query options, their names checked against the scheme's.
    text : str
        The URL as given.
    """

    scheme: str
    target: str
    options: dict[str, str]
    text: str

    def integer(self, key: str, default: int) -> int:
        """Option ``key`` as an integer (decimal or 0x hexadecimal)."""
        value = self.options.get(key)
        if value is None:
            return default
        try:
            return int(value, 0)
        except ValueError:
            raise BadInputError(f"option {key}={value!r} in {self.text!r}: expected an integer") from None

    def number(self, key: str, default: float) -> float:
        """Option ``key`` as a finite number."""
        value = self.options.get(key)
        if value is None:
            return default
        try:
            out = float(value)
        except ValueError:
            out = float("nan")
        if out != out or out in (float("inf"), float("-inf")):
            raise BadInputError(f"option {key}={value!r} in {self.text!r}: expected a number")
        return out

    def flag(self, key: str, default: bool) -> bool:
        """Option ``key`` as 0/1 (or false/true)."""
        value = self.options.get(key)
        if value is None:
            return default
        if value not in TRUE + FALSE:
            raise BadInputError(f"option {key}={value!r} in {self.text!r}: expected 0 or 1")
        return value in TRUE

    def choice(self, key: str, default: str, choices: tuple[str, ...]) -> str:
        """Option ``key``, one of ``choices``."""
        value = self.options.get(key, default)
        if value not in choices:
            raise BadInputError(f"option {key}={value!r} in {self.text!r}: expected one of {', '.join(choices)}")
        return value
