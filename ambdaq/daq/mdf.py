"""Recordings as ASAM MDF 4 files (``ambdaq export --format mf4``), the format CANape, INCA and
the XCP world open, written by asammdf (the ``mdf`` extra).

Each topic is one channel group (its comment the topic), its fields channels with their units,
beside ``device_time_ns`` and ``seq``; the group's time channel is seconds since the recording's
first message, and the header's start time is that message's host time.  What the recording's
metadata says (session, devices, calibration, statistics) is embedded as one JSON attachment,
``ambdaq_metadata.json``; the calibration history (the push log's entries of the coefficient files
the recording's controllers name as running) as ``ambdaq_push_log.json``; the header's comment
names the source.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

from ..errors import BadInputError
from .recording import Recording

METADATA_NAME = "ambdaq_metadata.json"
PUSH_LOG_NAME = "ambdaq_push_log.json"


def write_mf4(rec: Recording, target: Path, push_log: list[dict] | None = None) -> Path:
    """Write ``rec`` to the MDF 4.10 file ``target`` (see the module docstring); ``push_log``: the
    calibration history of the coefficient files its controllers ran (push log entries), attached
    as ``ambdaq_push_log.json``."""
    try:
        from asammdf import MDF, Signal
    except ImportError:
        raise BadInputError("MDF4 export needs asammdf, the mdf extra: pip install 'ambdaq[mdf]'") from None
    mdf = MDF(version="4.10")
    first = min((int(t.log_time[0]) for t in rec.values() if len(t)), default=None)
    if first is not None:
        mdf.header.start_time = datetime.fromtimestamp(first / 1e9, timezone.utc)
    mdf.header.comment = f"ambdaq recording {Path(rec.path).name}"
    for topic, data in rec.items():
        if not len(data):
            continue
        t = (data.log_time - first) * 1e-9
        signals = [Signal(samples=col, timestamps=t, name=name, unit=data.units.get(name, ""),
                          comment=f"{topic} {name}") for name, col in data.fields.items()]
        signals += [Signal(samples=data.device_time, timestamps=t, name="device_time_ns", unit="ns",
                           comment=f"{topic}: device clock"),
                    Signal(samples=data.seq, timestamps=t, name="seq", unit="", comment=f"{topic}: device sequence")]
        mdf.append(signals, comment=topic)
    mdf.attach(json.dumps(rec.metadata, indent=1, sort_keys=True).encode(), file_name=METADATA_NAME,
               comment="the recording's metadata: session, devices, calibration, statistics", embedded=True)
    if push_log:
        mdf.attach(json.dumps(push_log, indent=1, sort_keys=True).encode(), file_name=PUSH_LOG_NAME,
                   comment="calibration history: the pushes of the coefficient files the recording's controllers ran",
                   embedded=True)
    mdf.save(target, overwrite=True)
    mdf.close()
    return target
