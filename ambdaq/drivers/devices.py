"""Open a device from its URL: the scheme picks the driver (one entry per scheme)."""

from __future__ import annotations

from ..errors import BadInputError, DeviceError
from .controller import ControllerDriver
from .serial_link import SerialLink
from .sim import SimSource, sim_options
from .can_bus import CanHub
from .canopen_controller import CanopenController
from .canopen_driver import CanopenDevice
from .canopen_profiles import CONTROLLER, PROFILES
from .url import SCHEMES, DeviceURL, parse_device_url

SERIAL_DRIVERS = {"controller": ControllerDriver}


def open_devices(url: str, *, name: str | None = None, speed: str | None = None, truth: bool | None = None,
                 calibration: dict[str, str] | None = None) -> list:
    """Open what ``url`` names: one device, or for ``sim://`` a whole simulated rig whose devices
    sit behind real transports (see :mod:`ambdaq.drivers.simdev.inproc`)."""
    parsed = parse_device_url(url)
    if parsed.scheme != "sim":
        dev = open_device(url, name=name, speed=speed)
        if calibration:
            dev.extra_calibration = dict(calibration)
        return [dev]
    from .simdev.inproc import open_simulated_rig

    return open_simulated_rig(parsed.target, name=name or "rig", calibration=calibration,
                              **sim_options(parsed, speed=speed, truth=truth))


def open_device(url: str, *, name: str | None = None, speed: str | None = None, truth: bool | None = None, paced: bool = True,
                calibration: dict[str, str] | None = None):
    """Open the device at ``url`` as a sample source for the recorder.

    Parameters
    ----------
    url : str
        Device URL (``sim://spindle?seed=3`` ...).
    name : str, optional
        Device name in the recording; default ``rig`` for a simulated rig, else the device's
        kind (``controller`` ...).
    speed : str, optional
        Rotor speed spec (rpm) to command before recording.
    truth : bool, optional
        Record ground truth topics (simulated rigs only).
    paced : bool
        Stream in real time (simulated rigs can also run unpaced).
    calibration : dict, optional
        Calibration entries from the rig file.
    """
    parsed = parse_device_url(url)
    if parsed.scheme == "sim":
        return SimSource(parsed, name=name or "rig", speed=speed, truth=truth, paced=paced, calibration=calibration)
    if parsed.scheme == "serial":
        return _open_serial(parsed, name, speed)
    if parsed.scheme == "can":
        return open_can_device(url, name=name)
    raise BadInputError(f"no driver for {parsed.scheme}:// devices")


def _number(url: DeviceURL, key: str, default: str, kind=int):
    try:
        return kind(url.options.get(key, default), 0) if kind is int else kind(url.options.get(key, default))
    except ValueError:
        raise BadInputError(f"option {key}={url.options[key]!r} in {url.text!r}: expected a number") from None


def _on_can_hub(url: DeviceURL, node: int, make):
    """``make(hub, node)`` on the shared bus ``url`` names; the hub is released if that fails."""
    interface, _, channel = url.target.partition("/")
    if not channel:
        raise BadInputError(f"device URL {url.text!r} names no channel: expected {SCHEMES['can'].form}")
    hub = CanHub.acquire(interface, channel, _number(url, "bitrate", "1000000"))
    try:
        return make(hub, node)
    except BaseException:
        hub.release()
        raise


def open_can_device(text: str, *, name: str | None = None, namespace: str | None = None, kind: str | None = None):
    """A CANopen device on a shared bus: ``can://INTERFACE/CHANNEL?node=N``."""
    url = parse_device_url(text)
    kind = kind or url.options.get("kind")
    if kind is not None and kind not in PROFILES:
        raise BadInputError(f"option kind={kind!r} in {url.text!r}: expected one of {', '.join(PROFILES)}")
    if "node" not in url.options and kind is None:
        raise BadInputError(f"device URL {url.text!r} needs node=N (or kind=...): expected {SCHEMES['can'].form}")
    node = _number(url, "node", str(PROFILES[kind].default_node) if kind else "0")
    return _on_can_hub(url, node, lambda hub, n: CanopenDevice(
        hub, n, kind=kind, sync_hz=_number(url, "sync", "800", float), name=name,
        namespace=url.options.get("namespace", "") if namespace is None else namespace, url=url.text))


def _open_serial(url: DeviceURL, name: str | None, speed: str | None):
    """Open the line, ask the device who it is, and hand it to the driver for its type."""
    try:
        baud = int(url.options.get("baud", "3000000"))
    except ValueError:
        raise BadInputError(f"option baud={url.options['baud']!r} in {url.text!r}: expected an integer") from None
    link = SerialLink(url.target, baudrate=baud)
    try:
        kind = link.identify().get("device_type")
        driver = SERIAL_DRIVERS.get(kind)
        if driver is None:
            raise DeviceError(f"{url.text}: no driver for a device of type {kind!r}")
        dev = driver(link, name=name or kind, url=url.text)
        if speed is not None:
            from .rig.speed import SpeedProfile

            dev.write_param("speed.rpm", [SpeedProfile.parse(speed).rpm_end])
        return dev
    except BaseException:
        link.close()
        raise


def open_controller(url: str):
    """The AMB controller at ``url`` as a coefficient-bank port (``ambdaq push``, ``controller
    status``): ``serial:PORT`` or ``can://INTERFACE/CHANNEL?node=N`` (its configuration port)."""
    parsed = parse_device_url(url)
    if parsed.scheme == "sim":
        raise BadInputError(f"{url}: a push needs a controller that keeps running: start `ambdaq sim serve "
                            "--serial pty` and push to the serial:// port it prints")
    if parsed.scheme == "serial":
        dev = _open_serial(parsed, None, None)
        if not isinstance(dev, ControllerDriver):
            dev.close()
            raise DeviceError(f"{url}: not an AMB controller")
        return dev
    if parsed.options.get("kind", "controller") != "controller":
        raise BadInputError(f"{url}: a push goes to the controller (kind=controller), not a {parsed.options['kind']}")
    node = _number(parsed, "node", str(CONTROLLER.default_node))
    return _on_can_hub(parsed, node, lambda hub, n: CanopenController(hub, n, url=url))
