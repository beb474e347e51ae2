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

    [machine]                     # optional: the machine the devices are on (docs/device-urls.md)
    id = "blower-7"
    min_clearance_m = 150e-6
    gap.de_x = "/probes/probes.probe_1"   # which recorded field is which bearing's gap

A device described by a file no one here wrote adds its description (docs/hardware.md), in the
keys its back-end declares (``Backend.description_keys``): a DBC device ``dbc``, ``messages``,
``counters``, ``rates``, ``raw``; a CANopen device from its vendor's EDS ``eds``, ``mapping`` and
``[[device.signal]]`` tables; an XCP controller ``a2l`` and ``measurements``; a plug-in back-end
its own.  Relative paths (``Backend.path_keys``) are taken from the rig file's folder; the
device's back-end checks the rest.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import BadInputError
from .registry import Backend, backend, parse_device_url

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
"""Keys every [[device]] table may have; the rest are its back-end's (``Backend.description_keys``)."""


@dataclass(frozen=True)
class RigFile:
    """A parsed rig file: its devices, and its ``[machine]`` table as written (checked against the
    devices' topics when they are recorded: :meth:`ambdaq.machines.machine.Machine.describe`)."""

    path: Path
    name: str
    devices: tuple[DeviceEntry, ...]
    machine: dict | None = None


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
    unknown = sorted(set(doc) - {"name", "device", "machine"})
    if unknown:
        raise BadInputError(f"{path}: unknown key {unknown[0]!r}; a rig file has 'name', [[device]] tables and "
                            "a [machine] table")
    machine = doc.get("machine")
    if machine is not None and not isinstance(machine, dict):
        raise BadInputError(f"{path}: machine must be a table ([machine])")
    entries = doc.get("device")
    if not isinstance(entries, list) or not entries:
        raise BadInputError(f"{path}: no [[device]] tables")
    devices = []
    for i, e in enumerate(entries):
        where = f"{path}: device {i + 1}"
        if not isinstance(e, dict) or "url" not in e:
            raise BadInputError(f"{where}: needs url = \"scheme://...\"")
        url = parse_device_url(str(e["url"]))
        known = backend(url.scheme)  # parse_device_url found it
        check_keys(e, BASE_KEYS + known.description_keys, where)
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
                description=_description(e, known, path.parent, where),
            )
        )
    names = [d.name for d in devices]
    if len(set(names)) != len(names):
        raise BadInputError(f"{path}: device names must be unique ({', '.join(names)})")
    return RigFile(path, str(doc.get("name", path.stem)), tuple(devices), machine)


def _description(entry: dict, known: Backend, folder: Path, where: str) -> dict:
    """The device's description keys (its back-end's), with its files' paths made absolute."""
    out = {k: entry[k] for k in known.description_keys if k in entry}
    for k in known.path_keys:
        if k in out:
            if not isinstance(out[k], str):
                raise BadInputError(f"{where}: {k} must be a file name")
            out[k] = str((folder / out[k]).resolve())
    return out
