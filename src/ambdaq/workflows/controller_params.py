"""Controller parameters changed from the host, each change logged and undoable (every change
ambdaq makes to a controller can be undone; a coefficient push has its bank rollback, a parameter
its logged old value).

``ambdaq controller param NAME VALUES`` writes, reads back and logs what the parameter held before
and holds now; ``ambdaq controller param --undo`` writes the last change's old values back, if the
controller still holds what that change left (else someone changed it since, and the undo is
refused rather than overwrite their change).  The log is JSON lines beside the push log.
"""

from __future__ import annotations

import json
import socket
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..drivers.interfaces import Controller
from ..errors import BadInputError, DeviceError
from .push import local_log_path

LOG_NAME = "parameters.log"


def change_log_path() -> Path:
    """Where parameter changes are logged on this machine: beside the push log."""
    return local_log_path().with_name(LOG_NAME)


@dataclass(frozen=True)
class ParamChange:
    """One logged change: the controller's URL, the parameter (and calibration page), its values
    before and after (read back), when, and which change it undid (its line in the log)."""

    target: str
    name: str
    page: int | None
    old: list[float]
    new: list[float]
    host_time: str
    undo_of: int | None = None


def _entries() -> list[dict]:
    path = change_log_path()
    if not path.exists():
        return []
    out = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            raise BadInputError(f"{path}: line {n} is not JSON: not ambdaq's parameter log") from None
    return out


def _log(change: ParamChange) -> None:
    path = change_log_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    entry = {**change.__dict__, "host": socket.gethostname()}
    with open(path, "a") as fh:
        fh.write(json.dumps(entry, sort_keys=True) + "\n")


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def write_param(dev: Controller, target: str, name: str, values: list[float], page: int | None = None,
                old: list[float] | None = None) -> ParamChange:
    """Write ``values`` to parameter ``name`` of ``dev`` (on calibration ``page`` where given:
    the caller has presented it), read it back, and log the change with what it replaced
    (``old``, where the caller has just read it: one read, one write, one read on the wire, as a
    recorded XCP session expects); returns it."""
    old = [float(v) for v in (dev.read_param(name) if old is None else old)]
    dev.write_param(name, list(values))
    change = ParamChange(target, name, page, old, [float(v) for v in dev.read_param(name)], _now())
    _log(change)
    return change


def last_change(target: str) -> tuple[int, dict]:
    """The last logged change to ``target`` not undone yet: (its line in the log, the entry);
    BadInputError if there is none."""
    entries = _entries()
    undone = {e.get("undo_of") for e in entries}
    for line in range(len(entries), 0, -1):
        e = entries[line - 1]
        if e.get("target") == target and e.get("undo_of") is None and line not in undone:
            return line, e
    raise BadInputError(f"{target}: no parameter change of ambdaq's to undo ({change_log_path()})")


def undo(dev: Controller, target: str, last: tuple[int, dict], page_of=None) -> ParamChange:
    """Write the old values of change ``last`` (:func:`last_change`) back to ``dev``
    (``page_of(page)``: a context manager that presents a calibration page, for a change made on
    one), if the parameter still holds what that change left; log the undo and return it."""
    from contextlib import nullcontext

    line, e = last
    with page_of(e["page"]) if e.get("page") is not None and page_of is not None else nullcontext():
        now = [float(v) for v in dev.read_param(e["name"])]
        if now != e["new"]:
            raise BadInputError(f"{target}: {e['name']} is {values_text(now)} now, not {values_text(e['new'])} as ambdaq left it "
                                f"at {e['host_time']}: changed since; not undone")
        dev.write_param(e["name"], e["old"])
        back = [float(v) for v in dev.read_param(e["name"])]
    if back != [float(v) for v in e["old"]]:
        raise DeviceError(f"{target}: {e['name']} reads back {values_text(back)} after writing {values_text(e['old'])}")
    change = ParamChange(target, e["name"], e.get("page"), now, back, _now(), undo_of=line)
    _log(change)
    return change


def values_text(values) -> str:
    """A parameter's values as the command line writes them: ``0.0015 0.0015 0.002``."""
    return " ".join(f"{float(v):g}" for v in values)
