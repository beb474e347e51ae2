"""``can://`` URLs: a CANopen device or the controller's configuration port on any python-can
interface and channel."""

from __future__ import annotations

from pathlib import Path

from ...errors import BadInputError
from ..interfaces import BankPort
from ..registry import Backend, Opened, OpenRequest
from ..url import DeviceURL, Scheme


SOCKETCAND_PORT = 29536  # socketcand's default TCP port
NETWORK_INTERFACES = ("udp_multicast",)
"""python-can interfaces that carry CAN over an IP network: refused, whatever the URL."""


def _a_rate(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value <= 100_000


class CanBackend(Backend):
    """Opens the shared bus of ``INTERFACE/CHANNEL`` and the device at ``node`` on it."""

    scheme = Scheme("can", "can://INTERFACE/CHANNEL?node=N[&kind=amplifier|gap_sensor|accelerometer|keyphasor|controller"
                           "&sync=HZ&bitrate=1000000&namespace=NAME&open_delay=S], can://INTERFACE/CHANNEL?node=N&eds=FILE"
                           "[&sync=HZ|external] or can://INTERFACE/CHANNEL?dbc=FILE[&raw=1] "
                           "(any python-can interface, e.g. can://virtual/amb0?node=16, can://slcan/dev/ttyACM0?node=16, "
                           "can://socketcand/can0?host=H&port=29536&dbc=FILE)",
                    ("node", "kind", "sync", "bitrate", "namespace", "open_delay", "dbc", "raw", "eds", "host", "port"))
    description_keys = ("dbc", "messages", "counters", "rates", "rate", "raw", "eds", "mapping", "signal")
    path_keys = ("dbc", "eds")

    def _on_hub(self, url: DeviceURL, make):
        """``make(hub)`` on the shared bus ``url`` names; the hub is released if that fails."""
        from .bus import CanHub

        interface, channel, options = self.bus_of(url)
        hub = CanHub.acquire(interface, channel, url.integer("bitrate", 1_000_000), **options)
        try:
            return make(hub)
        except BaseException:
            hub.release()
            raise

    @staticmethod
    def _node(url: DeviceURL, default: int) -> int:
        """The URL's CANopen node id (1..127), checked before the bus is opened."""
        node = url.integer("node", default)
        if not 1 <= node <= 127:
            raise BadInputError(f"CANopen node id must be 1..127, not {node}")
        return node

    @staticmethod
    def _sync_timeable(url: DeviceURL, external: bool) -> None:
        """Refuse a SYNC from ambdaq where it cannot be timed against the replies: a gateway that
        stamps frames on its own clock and returns none that ambdaq sends (bus.GATEWAY_CLOCK)."""
        from .bus import GATEWAY_CLOCK

        interface = url.target.partition("/")[0]
        if interface in GATEWAY_CLOCK and not external:
            raise BadInputError(f"{url.text}: a {interface} gateway stamps frames on its own clock and returns none that "
                                "ambdaq sends, so a SYNC from ambdaq cannot be timed against the replies; give "
                                "sync=external, with a SYNC master on the bus")

    def bus_of(self, url: DeviceURL) -> tuple[str, str, dict]:
        """python-can interface, channel and bus options of ``url``.

        A channel with a ``/`` in it is a device path (``can://slcan/dev/ttyACM0`` is slcan on
        ``/dev/ttyACM0``).  ``open_delay`` is the seconds slcan waits after opening its serial port
        (python-can's default, 2 s, is for adapters that reset when the port opens).
        """
        interface, _, channel = url.target.partition("/")
        if interface in NETWORK_INTERFACES:
            raise BadInputError(f"{url.text}: python-can's {interface} interface sends CAN frames onto an IP "
                                "network; ambdaq talks only to the buses and ports it is given")
        if not channel:
            raise BadInputError(f"device URL {url.text!r} names no channel: expected {self.scheme.form}")
        if "/" in channel:
            channel = "/" + channel
        options = {}
        if interface == "socketcand":  # a CAN-over-TCP gateway (socketcand's protocol, its raw mode)
            if "host" not in url.options:
                raise BadInputError(f"{url.text}: a socketcand gateway needs host=H (and port=P, default {SOCKETCAND_PORT})")
            options = {"host": url.options["host"], "port": url.integer("port", SOCKETCAND_PORT)}
        elif "host" in url.options or "port" in url.options:
            raise BadInputError(f"options host and port in {url.text!r} are for socketcand gateways only")
        if "open_delay" in url.options:
            if interface != "slcan":
                raise BadInputError(f"option open_delay in {url.text!r} is for slcan adapters only")
            options["sleep_after_open"] = url.number("open_delay", 2.0)
        return interface, channel, options

    def open(self, url: DeviceURL, request: OpenRequest) -> Opened:
        from .device import CanopenDevice
        from .device_profiles import DEVICE_PROFILES

        if "dbc" in url.options or "dbc" in request.description:
            return self._open_dbc(url, request)
        if "eds" in url.options or "eds" in request.description:
            return self._open_eds(url, request)

        kind = url.options.get("kind")
        if kind is not None and kind not in DEVICE_PROFILES:
            raise BadInputError(f"option kind={kind!r} in {url.text!r}: expected one of {', '.join(DEVICE_PROFILES)}")
        if "node" not in url.options and kind is None:
            raise BadInputError(f"device URL {url.text!r} needs node=N (or kind=...): expected {self.scheme.form}")
        node = self._node(url, DEVICE_PROFILES[kind].default_node if kind else 0)
        self._sync_timeable(url, external=False)  # ambdaq's own CANopen devices follow ambdaq's SYNC
        dev = self._on_hub(url, lambda hub: CanopenDevice(
            hub, node, kind=kind, sync_hz=url.number("sync", 800.0), name=request.name,
            namespace=url.options.get("namespace", ""), url=url.text))
        dev.add_calibration(request.calibration)
        return Opened([dev])

    def _open_eds(self, url: DeviceURL, request: OpenRequest) -> Opened:
        """A CANopen device from its vendor's EDS (:mod:`.eds`): the EDS and the mapping are
        checked before the bus is opened, so a refused mapping writes nothing to the device."""
        from .eds import EdsDevice, load_eds, parse_signals, check_mapping

        d = request.description
        if "kind" in url.options or "namespace" in url.options:
            raise BadInputError(f"{url.text}: kind and namespace are for ambdaq's own CANopen devices, not an EDS device")
        if "node" not in url.options:
            raise BadInputError(f"{url.text}: an EDS device needs node=N")
        node = self._node(url, 0)
        if url.target.partition("/")[0] == "slcan":
            raise BadInputError(f"{url.text}: python-can's slcan interface stamps a frame when it reads it, so the replies "
                                "of a device that does not echo the SYNC counter cannot be matched to their SYNC; "
                                "use an interface with bus time stamps (socketcan, pcan, kvaser, vector ...)")
        path = Path(d.get("eds") or url.options["eds"])
        name = request.name or path.stem
        odict = load_eds(path, node)
        mapping = d.get("mapping", "configure" if "signal" in d else "existing")
        if mapping not in ("configure", "existing"):
            raise BadInputError(f"{url.text}: mapping must be \"configure\" or \"existing\", not {mapping!r}")
        signals = parse_signals(odict, d.get("signal"), name, str(path)) if "signal" in d or mapping == "configure" else None
        tpdos = check_mapping(signals, odict, path) if mapping == "configure" else None
        sync = url.options.get("sync", "800")
        sync_hz = None if sync == "external" else url.number("sync", 800.0)
        self._sync_timeable(url, external=sync_hz is None)
        device = self._on_hub(url, lambda hub: EdsDevice(hub, node, path, odict, signals, tpdos, sync_hz=sync_hz,
                                                         name=name, url=url.text))
        device.add_calibration(request.calibration)
        return Opened([device])

    def _open_dbc(self, url: DeviceURL, request: OpenRequest) -> Opened:
        """A raw-CAN device described by a DBC file: one source per topic (:mod:`.dbc`)."""
        from .dbc import DbcMessageSource, DbcReceiver, DbcRequest, load_dbc

        d = request.description
        for key in ("node", "kind", "sync", "namespace"):
            if key in url.options:
                raise BadInputError(f"option {key} in {url.text!r} is for CANopen devices, not a DBC device")
        messages, counters = d.get("messages", []), d.get("counters", {})
        if not isinstance(messages, list) or not all(isinstance(m, str) for m in messages):
            raise BadInputError(f"{url.text}: messages must be a list of DBC message names")
        if not isinstance(counters, dict) or not all(isinstance(v, str) for v in counters.values()):
            raise BadInputError(f"{url.text}: counters must be a table of message = \"counter signal\"")
        raw = d.get("raw", url.flag("raw", False))
        if not isinstance(raw, bool):
            raise BadInputError(f"{url.text}: raw must be true or false")
        rates, rate = d.get("rates", {}), d.get("rate")
        if not isinstance(rates, dict) or not all(_a_rate(v) for v in rates.values()) or not (rate is None or _a_rate(rate)):
            raise BadInputError(f"{url.text}: rates must be a table of message = Hz and rate a number of Hz "
                                "(0 < Hz <= 100000)")
        path = d.get("dbc") or url.options["dbc"]
        db = load_dbc(path)  # before the bus is opened: a bad file touches nothing
        wanted = DbcRequest(Path(path), tuple(messages), dict(counters), raw, dict(rates), rate)
        name = request.name or Path(path).stem
        receiver = self._on_hub(url, lambda hub: DbcReceiver(hub, db, wanted, name))
        streams = list(receiver.streams.values()) + ([receiver.raw_stream] if receiver.raw_stream else [])
        sources = []
        for i, stream in enumerate(streams):
            if i:
                receiver.hub.retain()  # each source releases the hub once
            topic = stream.group.topic
            part = topic.removeprefix(f"/{name}/").replace("/", ".") if topic.startswith(f"/{name}/") else "raw"
            source = DbcMessageSource(receiver, stream, name=f"{name}.{part}", url=url.text)
            source.add_calibration(request.calibration)
            sources.append(source)
        return Opened(sources)

    def controller(self, url: DeviceURL, description: dict | None = None) -> BankPort:
        from .controller import CanopenController
        from .device_profiles import CONTROLLER

        if url.options.get("kind", "controller") != "controller":
            raise BadInputError(f"{url.text}: a push goes to the controller (kind=controller), not a {url.options['kind']}")
        node = self._node(url, CONTROLLER.default_node)
        return self._on_hub(url, lambda hub: CanopenController(hub, node, url=url.text))
