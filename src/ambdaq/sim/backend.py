"""``sim://PROFILE``: a simulated rig served in this process, its devices opened by their real
drivers over real transports (a pseudo-terminal, a CAN bus), as hardware would be."""

from __future__ import annotations

from ..drivers.registry import Backend, Endpoints, Opened, OpenRequest, open_url
from ..drivers.url import DeviceURL, Scheme
from ..errors import BadInputError
from ..speed import SpeedProfile
from .source import FF_CHOICES


IN_PROCESS_ALIVE_S = 5.0
"""Seconds of silence after which the in-process simulated controller's line counts as lost (1 s for
a controller of its own): it runs in the recorder's process, so a host starved of CPU (a process
burning a core beside two busy ones) stops it and the reader together, for longer than a second
at times, which says nothing about a line; a controller that stops is still caught
(tests/test_serial_controller.py stalls one served in another process)."""


class SimBackend(Backend):
    """Serves the rig (:func:`ambdaq.sim.serve.serve`) and opens each of its devices' URLs."""

    scheme = Scheme("sim", "sim://PROFILE[?seed=N&rpm=SPEED&truth=0|1&ff=off|table|lms&noise=0|1&can=0|1"
                           "&third_party=0|1&fault=SECONDS&line_errors=SHARE]",
                    ("seed", "rpm", "truth", "ff", "noise", "can", "third_party", "fault", "line_errors"))

    def _serve(self, url: DeviceURL, request: OpenRequest):
        from .serve import serve

        seed = url.integer("seed", 0)
        if seed < 0:
            raise BadInputError(f"option seed={seed} in {url.text!r}: expected an integer >= 0")
        speed = request.speed if request.speed is not None else SpeedProfile.parse(url.options.get("rpm", "0"))
        fault = url.number("fault", -1.0) if "fault" in url.options else None
        if fault is not None and fault < 0:
            raise BadInputError(f"option fault={url.options['fault']} in {url.text!r}: expected the seconds (>= 0) "
                                "after the start at which the controller reports a fault")
        line_errors = url.number("line_errors", 0.0)
        if not 0.0 <= line_errors < 1.0:
            raise BadInputError(f"option line_errors={url.options['line_errors']} in {url.text!r}: expected the share "
                                "(0 to below 1) of the controller's frames its line damages")
        return serve(url.target, seed=seed, speed=speed,
                     truth=url.flag("truth", False) if request.truth is None else request.truth,
                     ff_mode=url.choice("ff", "off", FF_CHOICES), noise=url.flag("noise", True),
                     can="virtual" if url.flag("can", True) else None, third_party=url.flag("third_party", False), fault_after_s=fault, line_errors=line_errors)

    def endpoints(self, url: DeviceURL, request: OpenRequest) -> Endpoints:
        served = self._serve(url, request)
        shaker = served.devices.get("shaker")
        return Endpoints(dict(served.urls), served, {} if shaker is None else {"shaker_gain_m_s2_per_v": shaker.gain})

    def open(self, url: DeviceURL, request: OpenRequest) -> Opened:
        """The rig's streaming devices: the controller (named after the rig) and its CANopen
        devices (``NAME-KIND``); a shaker generator is not a source and is left out."""
        served = self._serve(url, request)
        opened = Opened(keep=[served])
        base = request.name or "rig"
        try:
            for name, device_url in served.urls.items():
                if name == "shaker":
                    continue
                if name == "controller":  # it shares this process, and the CPU the host gives it
                    device_url += f"?alive={IN_PROCESS_ALIVE_S:g}"
                opened.add(open_url(device_url, name=base if name == "controller" else f"{base}-{name}",
                                    calibration=request.calibration))
        except BaseException:
            opened.close()
            raise
        return opened

    def parameters(self, url: DeviceURL, description: dict | None = None):
        raise BadInputError(f"{url.text}: a parameter written to a rig served in this process is gone when the "
                            "command ends: start `ambdaq sim serve` and use the serial:// port it prints")

    def controller(self, url: DeviceURL, description: dict | None = None):
        raise BadInputError(f"{url.text}: a push needs a controller that keeps running: start `ambdaq sim serve` "
                            "and push to the serial:// port it prints")
