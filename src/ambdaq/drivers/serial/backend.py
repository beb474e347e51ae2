"""``serial:`` URLs: ambdaq's own serial protocol on any port pyserial opens."""

from __future__ import annotations


from ...loading import load_object
from ...errors import DeviceError
from ..interfaces import BankPort, Controller
from ..registry import Backend, Opened, OpenRequest, opened_controller
from ..url import DeviceURL, Scheme
from ...errors import BadInputError


DEVICE_TYPES = {
    # the device_type a device names in its IDENTITY -> "module:class" of its driver (a Controller);
    # a new device type on ambdaq's serial protocol is one driver module and one line here
    "controller": "ambdaq.drivers.serial.controller:ControllerDriver",
}


class SerialBackend(Backend):
    """Opens the line, asks the device who it is, and hands it to the driver for its type."""

    scheme = Scheme("serial", "serial:///dev/ttyUSB0[?baud=3000000&alive=1] or serial:socket://HOST:PORT "
                              "(any pyserial URL)", ("baud", "alive"), opaque=True)

    def _driver(self, url: DeviceURL, name: str | None) -> Controller:
        from .link import SerialLink

        alive = url.number("alive", 1.0)  # s of silence after which the line counts as lost
        if alive <= 0:
            raise BadInputError(f"option alive={alive:g} in {url.text!r}: seconds, above 0")
        link = SerialLink(url.target, baudrate=url.integer("baud", 3_000_000), alive_s=alive)
        try:
            kind = link.identify().get("device_type")
            target = DEVICE_TYPES.get(kind)
            if target is None:
                raise DeviceError(f"{url.text}: no driver for a device of type {kind!r}")
            return load_object(target)(link, name=name or kind, url=url.text)
        except BaseException:
            link.close()
            raise

    def open(self, url: DeviceURL, request: OpenRequest) -> Opened:
        return opened_controller(self._driver(url, request.name), url, request)

    def controller(self, url: DeviceURL, description: dict | None = None) -> BankPort:
        dev = self._driver(url, None)
        if not dev.capabilities.banks:
            dev.close()
            raise DeviceError(f"{url.text}: the controller reports no coefficient banks")
        return dev
