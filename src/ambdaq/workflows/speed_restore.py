"""A workflow that sets a controller's speed sets it back: the speed read before, written again at
the end, also when the workflow fails or is stopped (Ctrl-C), and the caller told which."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

from ..drivers.interfaces import Controller
from ..drivers.registry import Opened, open_url
from ..errors import BadInputError


def _controller(sources) -> Controller:
    found = next((s for s in sources if isinstance(s, Controller) and s.capabilities.speed_parameter), None)
    if found is None:
        raise BadInputError("no device here takes a speed command (--rpm)")
    return found


def speed_now(device: str, description: dict | None = None) -> float:
    """The speed the controller at ``device`` runs at now, rpm."""
    with Opened() as opened:
        opened.add(open_url(device, description=description))
        controller = _controller(opened.sources)
        return float(controller.read_param(controller.capabilities.speed_parameter)[0])


def set_speed(device: str, rpm: float, description: dict | None = None) -> None:
    """Command the controller at ``device`` to ``rpm``."""
    with Opened() as opened:
        opened.add(open_url(device, description=description))
        controller = _controller(opened.sources)
        controller.write_param(controller.capabilities.speed_parameter, [rpm])


@contextmanager
def speed_restored(device: str, description: dict | None, on_restore: Callable[[float | Exception], None] | None
                   ) -> Iterator[float]:
    """Inside: the workflow may change the speed; after (however it ended): the speed it had.

    Parameters
    ----------
    device : str
        The controller's URL.
    description : dict, optional
        What its back-end reads beyond the URL (an A2L).
    on_restore : callable, optional
        Told the speed set back (rpm), or the exception if that failed (never raised over what
        ended the workflow).

    Yields
    ------
    float
        The speed before, rpm.
    """
    before = speed_now(device, description)
    try:
        yield before
    finally:
        try:
            set_speed(device, before, description)
        except Exception as err:
            if on_restore is not None:
                on_restore(err)
        else:
            if on_restore is not None:
                on_restore(before)


__all__ = ["set_speed", "speed_now", "speed_restored"]
