"""Rig files (TOML): the devices of one machine with their URLs, names and calibrations.

.. code-block:: toml

    name = "spindle-lab"

    [[device]]
    name = "rig"
    url = "sim://spindle?seed=3"
    rpm = "30000"                 # optional speed command
    unlock_key = "..."            # optional: the controller's key for `ambdaq push`

    [device.calibration]          # optional, stored in the recording's metadata
    note = "sensor gains from 2026-11-01 slow roll"

A device described by a file no one here wrote adds its description (docs/hardware.md): a DBC
device ``dbc``, ``messages``, ``counters``, ``raw``; a CANopen device from its vendor's EDS
``eds``, ``mapping`` and ``[[device.signal]]`` tables.  Relative paths are taken from the rig
file's folder; the device's back-end checks the rest.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import BadInputError
from .registry import parse_device_url

MAX_BYTES = 2**20  # a rig file lists a machine's devices: a megabyte is far beyond any


@dataclass(frozen=True)
class DeviceEntry:
    """One device of a rig file."""

    name: str
    url: str
    rpm: str | None = None
    unlock_key: str | None = None
    calibration: dict[str, str] = field(default_factory=dict)
    description: dict = field(default_factory=dict)


BASE_KEYS = ("name", "url", "rpm", "unlock_key", "calibration")
DESCRIPTION_KEYS = ("dbc", "messages", "counters", "rates", "rate", "raw", "eds", "mapping", "signal", "a2l",
                    "measurements")
PATH_KEYS = ("dbc", "eds", "a2l")


@dataclass(frozen=True)
class RigFile:
    """A parsed rig file."""

    path: Path
    name: str
    devices: tuple[DeviceEntry, ...]


def check_keys(table: dict, allowed: tuple[str, ...], where: str) -> None:
    """A rig file's table may hold only ``allowed`` keys: the first other one is one
    :class:`BadInputError` line, so a typo never passes silently."""
    bad = sorted(set(table) - set(allowed))
    if bad:
        raise BadInputError(f"{where}: unknown key {bad[0]!r} (keys: {', '.join(allowed)})")


def load_rig(path: str | Path) -> RigFile:
    """Read and check a rig file; every problem is one :class:`BadInputError` line."""
    path = Path(path)
    try:
        if not path.is_file():
            raise BadInputError(f"{path}: {'not a regular file' if path.exists() else 'no such rig file'}")
        if path.stat().st_size > MAX_BYTES:
            raise BadInputError(f"{path}: a rig file is at most {MAX_BYTES:,} bytes")
        doc = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError) as err:
        raise BadInputError(f"{path}: not a valid TOML rig file ({err})") from None
    except RecursionError:
        raise BadInputError(f"{path}: not a rig file: tables or arrays nested too deep") from None
    unknown = sorted(set(doc) - {"name", "device"})
    if unknown:
        raise BadInputError(f"{path}: unknown key {unknown[0]!r}; a rig file has 'name' and [[device]] tables")
    entries = doc.get("device")
    if not isinstance(entries, list) or not entries:
        raise BadInputError(f"{path}: no [[device]] tables")
    devices = []
    for i, e in enumerate(entries):
        where = f"{path}: device {i + 1}"
        if not isinstance(e, dict) or "url" not in e:
            raise BadInputError(f"{where}: needs url = \"scheme://...\"")
        check_keys(e, BASE_KEYS + DESCRIPTION_KEYS, where)
        parse_device_url(str(e["url"]))
        cal = e.get("calibration", {})
        if not isinstance(cal, dict):
            raise BadInputError(f"{where}: calibration must be a table")
        devices.append(
            DeviceEntry(
                name=str(e.get("name", f"dev{i}")),
                url=str(e["url"]),
                rpm=None if "rpm" not in e else str(e["rpm"]),
                unlock_key=None if "unlock_key" not in e else str(e["unlock_key"]),
                calibration={str(k): str(v) for k, v in cal.items()},
                description=_description(e, path.parent, where),
            )
        )
    names = [d.name for d in devices]
    if len(set(names)) != len(names):
        raise BadInputError(f"{path}: device names must be unique ({', '.join(names)})")
    return RigFile(path, str(doc.get("name", path.stem)), tuple(devices))


def _description(entry: dict, folder: Path, where: str) -> dict:
    """The device's description keys, with its files' paths made absolute."""
    out = {k: entry[k] for k in DESCRIPTION_KEYS if k in entry}
    for k in PATH_KEYS:
        if k in out:
            if not isinstance(out[k], str):
                raise BadInputError(f"{where}: {k} must be a file name")
            out[k] = str((folder / out[k]).resolve())
    return out
