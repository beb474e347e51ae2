"""Recordings as ASAM MDF 4 files (``ambdaq export --format mf4``), the format CANape, INCA and
the XCP world open, written by asammdf (the ``mdf`` extra).

Each topic is one channel group named after it, its source the device that recorded it; its
fields are channels named ``<topic with dots>.<field>`` (``amb.gap.front_x``: unique in the file,
as CANape, INCA and asammdf's ``get`` need), with their units, beside ``device_time_ns`` and
``seq``; the group's time channel is seconds since the recording's
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


def channel_prefix(topic: str) -> str:
    """The name a topic's channels begin with: its path with dots (``/amb/gap`` -> ``amb.gap``), so
    that ``amb.gap.front_x`` and ``amb.current.front_x`` are two names, as MDF tools (CANape, INCA,
    asammdf's ``get``) need every channel's name to be."""
    return topic.strip("/").replace("/", ".")


BUS_TYPES = {"can": "BUS_TYPE_CAN", "xcp+can": "BUS_TYPE_CAN", "xcp+tcp": "BUS_TYPE_ETHERNET",
             "xcp+udp": "BUS_TYPE_ETHERNET", "socketcand": "BUS_TYPE_ETHERNET"}
"""MDF 4 source bus types by device URL scheme (other schemes: BUS_TYPE_OTHER, the simulator's NONE)."""


def _source(rec: Recording, topic: str):
    """The MDF 4 source of a topic: the device that recorded it (name, URL, model)."""
    from asammdf.blocks.source_utils import Source

    device = next((d for d in rec.devices.values() if topic in d.topics), None)
    if device is None:
        return Source("", "", "", Source.SOURCE_OTHER, Source.BUS_TYPE_NONE)
    url = device.identity.get("url", "")
    scheme = url.partition("://")[0]
    bus = "BUS_TYPE_NONE" if scheme == "sim" else BUS_TYPES.get(scheme, "BUS_TYPE_OTHER")
    kind = Source.SOURCE_ECU if "controller" in device.kind else Source.SOURCE_IO
    return Source(device.name, url, " ".join(v for v in (device.kind, device.identity.get("model", "")) if v),
                  kind, getattr(Source, bus))


def write_mf4(rec: Recording, target: Path, push_log: list[dict] | None = None) -> Path:
    """Write ``rec`` to the MDF 4.10 file ``target`` (see the module docstring); ``push_log``: the
    calibration history of the coefficient files its controllers ran (push log entries), attached
    as ``ambdaq_push_log.json``.

    Each topic is a channel group named after it (its acquisition name and comment), its source
    the device that recorded it; each channel is named ``<topic with dots>.<field>``
    (:func:`channel_prefix`), unique in the file, with its unit and, as its comment, the topic and
    the field's own name."""
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
        prefix, source = channel_prefix(topic), _source(rec, topic)
        columns = [(name, col, data.units.get(name, ""), f"{topic} {data.names.get(name, name)}")
                   for name, col in data.fields.items()]
        columns += [("device_time_ns", data.device_time, "ns", f"{topic}: device clock"),
                    ("seq", data.seq, "", f"{topic}: device sequence")]
        signals = [Signal(samples=col, timestamps=t, name=f"{prefix}.{name}", unit=unit, comment=comment, source=source)
                   for name, col, unit, comment in columns]
        mdf.append(signals, acq_name=topic, acq_source=source, comment=topic)
    mdf.attach(json.dumps(rec.metadata, indent=1, sort_keys=True).encode(), file_name=METADATA_NAME,
               comment="the recording's metadata: session, devices, calibration, statistics", embedded=True)
    if push_log:
        mdf.attach(json.dumps(push_log, indent=1, sort_keys=True).encode(), file_name=PUSH_LOG_NAME,
                   comment="calibration history: the pushes of the coefficient files the recording's controllers ran",
                   embedded=True)
    mdf.save(target, overwrite=True)
    mdf.close()
    return target
