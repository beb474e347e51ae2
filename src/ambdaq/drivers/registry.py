"""Device back-ends by URL scheme, as python-can finds its interfaces and pyserial its URL handlers.

A back-end owns a scheme: it declares the URL's form and options (:class:`~.url.Scheme`) and
opens what a URL names.  :data:`BACKENDS` lists ambdaq's own, loaded only when a URL asks for
them; another package adds one through the ``ambdaq.backends`` entry-point group::

    [project.entry-points."ambdaq.backends"]
    mybus = "mypackage.backend:MyBusBackend"     # a subclass of Backend, scheme "mybus"

The simulator is one such back-end (``sim://``): nothing here, nor anywhere under ``drivers``,
imports it.
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from importlib.metadata import entry_points

from ..loading import load_object
from ..errors import BadInputError, DeviceError
from ..speed import SpeedProfile
from .interfaces import BankPort, Controller, Source
from .url import DeviceURL, Scheme

BACKENDS = {
    "sim": "ambdaq.sim.backend:SimBackend",
    "can": "ambdaq.drivers.can.backend:CanBackend",
    "serial": "ambdaq.drivers.serial.backend:SerialBackend",
    "xcp+tcp": "ambdaq.drivers.xcp.backend:XcpTcpBackend",
    "xcp+udp": "ambdaq.drivers.xcp.backend:XcpUdpBackend",
    "xcp+sxi": "ambdaq.drivers.xcp.backend:XcpSxiBackend",
    "xcp+can": "ambdaq.drivers.xcp.backend:XcpCanBackend",
}
"""Scheme -> ``module:class`` of ambdaq's own back-ends."""
ENTRY_POINTS = "ambdaq.backends"
SCHEME_NAME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*")  # RFC 3986, section 3.1


@dataclass(frozen=True)
class OpenRequest:
    """What the caller asks of the devices a URL opens.

    Parameters
    ----------
    name : str, optional
        Device name in the recording (a whole rig names its devices after it).
    speed : SpeedProfile, optional
        Speed to command before recording (a device that takes a speed set-point).
    truth : bool, optional
        Also record ground truth (simulated rigs).
    calibration : dict of str to str
        Notes stored with every device's calibration (a rig file's ``[device.calibration]``).
    description : dict
        What a rig file says of the device beyond its URL, for its back-end to read: a DBC or
        EDS file and what to record of it (docs/hardware.md); paths are absolute.
    """

    name: str | None = None
    speed: SpeedProfile | None = None
    truth: bool | None = None
    calibration: dict[str, str] = field(default_factory=dict)
    description: dict = field(default_factory=dict)


class Opened:
    """Devices opened from URLs, with what must live as long as they do (a simulated rig
    serving them); a context manager: closing closes the devices, then what they needed.

    Parameters
    ----------
    sources : list of Source
        The devices, as recorder sources.
    keep : list
        Objects with a ``close()`` (or ``stop()``) to call after the devices are closed.
    """

    def __init__(self, sources: list[Source] | None = None, keep: list | None = None) -> None:
        self.sources: list[Source] = list(sources or [])
        self.keep: list = list(keep or [])

    def add(self, other: "Opened") -> None:
        """Take over ``other``'s devices and what they need."""
        self.sources += other.sources
        self.keep += other.keep

    def close(self) -> None:
        """Close every device (each is safe to close twice), then what they needed, newest first."""
        for s in self.sources:
            try:
                s.close()
            except Exception:  # one device failing to close must not keep the others open
                pass
        while self.keep:
            k = self.keep.pop()
            (k.close if hasattr(k, "close") else k.stop)()

    def __enter__(self) -> "Opened":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class Endpoints:
    """Where the devices behind a URL are reached: name -> device URL.  For hardware that is the
    URL itself; a simulated rig serves its devices on transports and names each one's URL, and
    stops when this is closed.  ``facts``: what the back-end knows of the setup that no device
    reports (a simulated rig's shaker gain, ``shaker_gain_m_s2_per_v``)."""

    urls: dict[str, str]
    keep: object | None = None
    facts: dict = field(default_factory=dict)

    def close(self) -> None:
        if self.keep is not None:
            self.keep.stop()
            self.keep = None

    def __enter__(self) -> "Endpoints":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def opened_controller(dev: Controller, url: DeviceURL, request: OpenRequest) -> Opened:
    """``dev``, a controller a back-end just opened, with ``request`` carried out: its speed
    set-point written (``--rpm``) and the calibration notes added; closed if either fails."""
    try:
        if request.speed is not None:
            param = dev.capabilities.speed_parameter
            if param is None:
                raise DeviceError(f"{url.text}: the device takes no speed command (--rpm)")
            dev.write_param(param, [request.speed.rpm_end])
        dev.add_calibration(request.calibration)
    except BaseException:
        dev.close()
        raise
    return Opened([dev])


class Backend(ABC):
    """What a URL scheme opens.  Subclasses set :attr:`scheme` and implement :meth:`open`.

    A back-end whose devices a rig file describes beyond their URL names the keys of a
    ``[[device]]`` table it reads (:attr:`description_keys`, handed to it as
    ``OpenRequest.description``) and which of them name files (:attr:`path_keys`: made absolute,
    relative to the rig file); the rig-file reader takes only those for its devices."""

    scheme: Scheme
    description_keys: tuple[str, ...] = ()
    path_keys: tuple[str, ...] = ()

    @abstractmethod
    def open(self, url: DeviceURL, request: OpenRequest) -> Opened:
        """The devices at ``url``, opened, as recorder sources."""

    def discover(self) -> list[dict[str, str]]:
        """What of this back-end's this host can reach, without writing to anything: one dict per
        device with its ``url`` and what else is known (``ambdaq devices`` lists a plug-in's)."""
        return []

    def endpoints(self, url: DeviceURL, request: OpenRequest) -> Endpoints:
        """Where the devices behind ``url`` are reached (hardware: the URL itself)."""
        return Endpoints({"device": url.text})

    def parameters(self, url: DeviceURL, description: dict | None = None) -> Source:
        """The device at ``url`` for reading and writing its parameters (``controller param``):
        by default the one device :meth:`open` opens; a back-end whose streaming needs more than its
        parameters do (an XCP controller's DAQ lists) opens it without."""
        opened = self.open(url, _request(None, description=description))
        if len(opened.sources) != 1 or opened.keep:
            opened.close()
            raise BadInputError(f"{url.text}: opens {len(opened.sources)} devices; open it with open_url")
        return opened.sources[0]

    def controller(self, url: DeviceURL, description: dict | None = None) -> BankPort:
        """The controller's coefficient banks at ``url`` (``ambdaq push``); ``description``: what a
        rig file or an option says of it beyond its URL (an XCP controller's A2L)."""
        raise BadInputError(f"{url.text}: a {url.scheme}:// device has no coefficient banks to push to")


_loaded: dict[str, Backend] = {}


def _targets() -> dict[str, str]:
    """Every known scheme -> ``module:class``: ambdaq's own, then those of installed packages."""
    out = dict(BACKENDS)
    for ep in entry_points(group=ENTRY_POINTS):
        out.setdefault(ep.name, ep.value)
    return out


def plugin_schemes() -> list[str]:
    """The schemes installed packages add (the ``ambdaq.backends`` entry points), sorted."""
    return sorted(s for s in _targets() if s not in BACKENDS)


def backend(scheme: str) -> Backend | None:
    """The back-end of ``scheme`` (imported on first use), or None."""
    if scheme not in _loaded:
        target = BACKENDS.get(scheme) or _targets().get(scheme)
        if target is None:
            return None
        _loaded[scheme] = load_object(target)()
    return _loaded[scheme]


def expected_forms() -> str:
    """The form of every known scheme, for messages."""
    return "; ".join(backend(s).scheme.form for s in _targets())


def parse_device_url(text: str | DeviceURL) -> DeviceURL:
    """Parse ``text`` into a :class:`DeviceURL` by its scheme's back-end (a DeviceURL is returned
    as it is: a URL is parsed once)."""
    if isinstance(text, DeviceURL):
        return text
    name, sep, _rest = str(text).partition(":")
    found = backend(name) if sep and SCHEME_NAME.fullmatch(name) else None
    if found is None or (not found.scheme.opaque and "://" not in text):
        if re.fullmatch(r"/dev/\S+|COM\d+", str(text)):  # a serial port given without its scheme
            raise BadInputError(f"unknown device URL {text!r}: did you mean serial://{text}?")
        raise BadInputError(f"unknown device URL {text!r}: expected {expected_forms()}")
    return found.scheme.parse(str(text))


def _request(speed: str | SpeedProfile | None, **kw) -> OpenRequest:
    return OpenRequest(speed=SpeedProfile.parse(speed) if isinstance(speed, str) else speed,
                       **{k: v for k, v in kw.items() if v is not None})


def open_url(url: str | DeviceURL, *, name: str | None = None, speed: str | SpeedProfile | None = None,
             truth: bool | None = None, calibration: dict[str, str] | None = None,
             description: dict | None = None) -> Opened:
    """Open what ``url`` names: one device, or a whole simulated rig (see :class:`OpenRequest`)."""
    parsed = parse_device_url(url)
    return backend(parsed.scheme).open(parsed, _request(speed, name=name, truth=truth, calibration=calibration,
                                                        description=description))


def open_device(url: str | DeviceURL, *, name: str | None = None, speed: str | SpeedProfile | None = None,
                calibration: dict[str, str] | None = None, description: dict | None = None) -> Source:
    """The one device at ``url`` (a URL that opens several, such as a simulated rig, is refused:
    :func:`open_url` takes those)."""
    opened = open_url(url, name=name, speed=speed, calibration=calibration, description=description)
    if len(opened.sources) != 1 or opened.keep:
        opened.close()
        raise BadInputError(f"{url}: opens {len(opened.sources)} devices; open it with open_url")
    return opened.sources[0]


def open_parameters(url: str | DeviceURL, description: dict | None = None) -> Source:
    """The device at ``url`` for its parameters (``controller param``; see :meth:`Backend.parameters`)."""
    parsed = parse_device_url(url)
    return backend(parsed.scheme).parameters(parsed, description)


def endpoints(url: str | DeviceURL, *, speed: str | SpeedProfile | None = None) -> Endpoints:
    """Where the devices behind ``url`` are reached (see :class:`Endpoints`)."""
    parsed = parse_device_url(url)
    return backend(parsed.scheme).endpoints(parsed, _request(speed))


def open_controller(url: str | DeviceURL, description: dict | None = None) -> BankPort:
    """The coefficient banks of the controller at ``url`` (``ambdaq push``, ``controller status``);
    ``description`` as in :class:`OpenRequest`."""
    parsed = parse_device_url(url)
    return backend(parsed.scheme).controller(parsed, description)
