"""``xcp+tcp://``, ``xcp+udp://``, ``xcp+sxi:`` and ``xcp+can://`` URLs: a controller's XCP slave
on Ethernet (TCP or UDP), on a serial line or on a CAN bus, described by its A2L file."""

from __future__ import annotations

from functools import partial
from pathlib import Path

from ...errors import BadInputError
from ..interfaces import BankPort
from ..registry import Backend, Opened, OpenRequest, opened_controller
from ..url import DeviceURL, Scheme
from .keys import algorithm

DEFAULT_KEY_ALGORITHM = "ambdaq-sim"
OPTIONS = ("a2l", "key", "counter", "event", "store", "prescaler")
CONNECT_TIMEOUT_S = 2.0


class _XcpBackend(Backend):
    """Opens the XCP slave a URL names with the A2L the URL (``a2l=``), the rig file or
    ``--a2l`` names; subclasses say how the slave is reached."""

    description_keys = ("a2l", "measurements")
    path_keys = ("a2l",)

    def link(self, url: DeviceURL):
        """A callable that opens the transport (:mod:`.transport`)."""
        raise NotImplementedError

    def bus_bitrate(self, url: DeviceURL) -> int | None:
        """The CAN bus's bit rate, on CAN (for the bus-load check); None elsewhere."""
        return None

    def _open(self, url: DeviceURL, name: str | None, description: dict, record: bool):
        from .a2l import read_a2l
        from .device import XcpController

        link = self.link(url)
        a2l = url.options.get("a2l") or description.get("a2l")
        if not a2l:
            raise BadInputError(f"{url.text}: an XCP device needs its A2L file (a2l=FILE in the URL, --a2l, or the rig file)")
        measurements = description.get("measurements")
        if measurements is not None and not (isinstance(measurements, list) and all(isinstance(m, str) for m in measurements)):
            raise BadInputError(f"{url.text}: measurements must be a list of A2L names or globs")
        event = url.integer("event", -1) if "event" in url.options else None
        if event is not None and not 0 <= event <= 0xFFFF:
            raise BadInputError(f"{url.text}: event must be 0..65535")
        return XcpController(url.text, link, read_a2l(Path(a2l)), name=name or "controller", record=record,
                             measure=measurements, counter=url.options.get("counter"), event=event,
                             store=url.flag("store", False),
                             key_algorithm=algorithm(url.options.get("key", DEFAULT_KEY_ALGORITHM)),
                             prescaler=url.integer("prescaler", 1), bus_bitrate=self.bus_bitrate(url))

    def open(self, url: DeviceURL, request: OpenRequest) -> Opened:
        controller = self._open(url, request.name, request.description, True)
        opened = opened_controller(controller, url, request)
        return Opened([*opened.sources, *controller.event_sources()])

    def controller(self, url: DeviceURL, description: dict | None = None) -> BankPort:
        return self._open(url, None, description or {}, False)

    def parameters(self, url: DeviceURL, description: dict | None = None):
        return self._open(url, None, description or {}, False)

    def upload_a2l(self, url: DeviceURL) -> bytes:
        """The A2L the slave at ``url`` holds (GET_ID, uploaded)."""
        from .device import upload_a2l

        return upload_a2l(url.text, self.link(url))

    def ask(self, url: DeviceURL) -> dict[str, str]:
        """Who answers XCP at ``url`` (``ambdaq devices --ask-xcp``); no A2L needed."""
        from .device import ask_slave

        return ask_slave(url.text, self.link(url))


def _host_port(url: DeviceURL, form: str) -> tuple[str, int]:
    host, sep, port = url.target.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536 or not host:
        raise BadInputError(f"device URL {url.text!r}: expected {form}")
    return host.strip("[]"), int(port)


class XcpTcpBackend(_XcpBackend):
    """XCP on TCP (ASAM XCP Part 3, Ethernet)."""

    scheme = Scheme("xcp+tcp", "xcp+tcp://HOST:PORT?a2l=FILE[&event=N&counter=NAME&key=ALGORITHM&store=1]", OPTIONS)

    def link(self, url: DeviceURL):
        from .transport import TcpLink

        return partial(TcpLink, url.text, *_host_port(url, self.scheme.form), CONNECT_TIMEOUT_S)


class XcpUdpBackend(_XcpBackend):
    """XCP on UDP (ASAM XCP Part 3, Ethernet): XCPlite's and CANape's usual transport."""

    scheme = Scheme("xcp+udp", "xcp+udp://HOST:PORT?a2l=FILE[&event=N&counter=NAME&key=ALGORITHM&store=1]", OPTIONS)

    def link(self, url: DeviceURL):
        from .transport import UdpLink

        return partial(UdpLink, url.text, *_host_port(url, self.scheme.form))


class XcpSxiBackend(_XcpBackend):
    """XCP on SxI (ASAM XCP Part 3, a serial line), framed LEN and CTR words without checksum."""

    scheme = Scheme("xcp+sxi", "xcp+sxi:///dev/ttyUSB0?a2l=FILE[&baud=3000000&event=N&counter=NAME&key=ALGORITHM&store=1]",
                    (*OPTIONS, "baud"), opaque=True)

    def link(self, url: DeviceURL):
        from .transport import SerialLink

        return partial(SerialLink, url.text, url.target, url.integer("baud", 3_000_000))


class XcpCanBackend(_XcpBackend):
    """XCP on CAN (ASAM XCP Part 3, CAN) on any python-can interface and channel."""

    scheme = Scheme("xcp+can", "xcp+can://INTERFACE/CHANNEL?a2l=FILE&id_master=0x7F1&id_slave=0x7F2"
                    "[&prescaler=N&bitrate=1000000&open_delay=S&event=N&counter=NAME&key=ALGORITHM&store=1]",
                    (*OPTIONS, "id_master", "id_slave", "bitrate", "open_delay"))

    def link(self, url: DeviceURL):
        from ..can.backend import CanBackend
        from .transport import CanLink

        interface, channel, options = CanBackend().bus_of(url)
        ids = [url.integer(k, -1) for k in ("id_master", "id_slave")]
        if not all(0 <= i <= 0x1FFFFFFF for i in ids):
            raise BadInputError(f"{url.text}: XCP on CAN needs id_master and id_slave (CAN identifiers): "
                                f"expected {self.scheme.form}")
        return partial(CanLink, url.text, interface, channel, self.bus_bitrate(url), *ids, options)

    def bus_bitrate(self, url: DeviceURL) -> int:
        return url.integer("bitrate", 1_000_000)
