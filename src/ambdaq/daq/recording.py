"""A recording, opened once: its devices, its machine and its topics.

>>> rec = open_recording("run.mcap")                          # doctest: +SKIP
>>> rec.devices["rig"].sample_rate_hz, rec.machine.bearings   # doctest: +SKIP  (typed, read once)
>>> gap = rec.role("gap")                                     # doctest: +SKIP  (the gap, by axis, wherever recorded)
>>> rec = load("run.mcap", topics=["/amb/gap"])               # doctest: +SKIP  (those topics, read at once)
>>> rec["/amb/gap"].time, rec["/amb/gap"]["front_x"]          # doctest: +SKIP  (s, m)

A :class:`Recording` reads the file's summary and metadata when it is opened and never again; a
topic is decoded when first asked for and kept (:mod:`.reader` for ambdaq's fixed layouts,
:mod:`.foreign` through the official decoders for other writers').  It is a read-only mapping of
topic to :class:`~ambdaq.mcap.reader.TopicData`.  What the file says about its devices is typed
(:class:`DeviceInfo`), and its machine (:class:`~ambdaq.machines.machine.Machine`) says where each
signal role is recorded: workflows ask for ``rec.role("gap")``, not for a topic name.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from ..errors import BadInputError
from ..roles import ROLE_TOPICS
from ..machines.machine import RECORD, Machine
from ..mcap.foreign import NotFixed, fixed_topics, foreign_topics, load_fixed, load_foreign
from ..mcap.mcapfile import McapFile
from ..mcap.reader import READ_THREADS, NotInRecording, TopicData, ambdaq_channels, read_fixed

DEVICE, CALIBRATION, CLOCK, LINK = "ambdaq.device.", "ambdaq.calibration.", "ambdaq.clock.", "ambdaq.link."


@dataclass(frozen=True)
class DeviceInfo:
    """One recorded device as the recording describes it.

    Attributes
    ----------
    name : str
        Its name in the recording.
    identity : dict of str to str
        What it said of itself (kind, model, serial, firmware, declared sample rate ...).
    calibration : dict of str to str
        Its calibration (``machine.*``, ``rotor.*``, a rig file's ``[device.calibration]``).
    topics : tuple of str
        The topics it recorded.
    clock : dict of str to str
        Its clock map's fit (drift, offset, uncertainty), where it has one.
    link : dict of str to str
        Its link's statistics (frames, CRC errors, lost packets ...), where it has them.
    """

    name: str
    identity: Mapping[str, str]
    calibration: Mapping[str, str]
    topics: tuple[str, ...] = ()
    clock: Mapping[str, str] = field(default_factory=dict)
    link: Mapping[str, str] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return self.identity.get("kind", "")

    @property
    def serial(self) -> str:
        return self.identity.get("serial", "")

    @property
    def sample_rate_hz(self) -> float | None:
        """The rate it declared, Hz, or None (frames as they come)."""
        try:
            return float(self.identity["sample_rate_hz"])
        except (KeyError, ValueError):
            return None


class Recording(Mapping):
    """One MCAP recording, its summary and metadata read once, its topics loaded when asked for.

    Parameters
    ----------
    source : str, Path or McapFile
        The file (any MCAP: ambdaq's, or another writer's).
    topics : list of str, optional
        The topics it shows; default every ambdaq topic and every other topic an official decoder
        reads.  A topic the file lacks is one line (exit 2).
    start, end : float, optional
        Time window, in s since the first message of the file.
    threads : int
        Chunks decompressed at once (1 where the caller is already parallel over files).
    """

    def __init__(self, source: str | Path | McapFile, topics: list[str] | tuple[str, ...] | None = None, *,
                 start: float | None = None, end: float | None = None, threads: int = READ_THREADS) -> None:
        f = source if isinstance(source, McapFile) else McapFile(source)
        self.file, self.path, self.threads = f, f.path, threads
        self.metadata: dict[str, dict[str, str]] = f.metadata()  # the file's metadata records, once
        self._fixed = ambdaq_channels(f)
        self._foreign = foreign_topics(f, set(self._fixed))
        self._foreign_fixed = fixed_topics(f, set(self._fixed))  # other writers' topics of a fixed layout
        if topics is None:  # ambdaq's topics and every other topic a decoder reads
            shown = list(self._fixed) + list(self._foreign)
            if not shown:
                raise NotInRecording(f"{f.path}: no topic ambdaq or an official decoder reads (topics: "
                                     f"{', '.join(sorted(c.topic for c in f.summary.channels.values())) or 'none'})")
        else:
            shown = []
            for t in topics:
                if t not in self._fixed and t not in self._foreign:
                    known = ", ".join(sorted({*self._fixed, *self._foreign})) or "none"
                    raise NotInRecording(f"{f.path}: no ambdaq topic {t}; topics: {known}")
                shown.append(t)
        self._shown = list(dict.fromkeys(shown))
        stats = f.statistics
        self.start_ns = stats.message_start_time if stats is not None and stats.message_count else min(
            (ci.message_start_time for ci in f.chunks), default=0)
        self._lo = None if start is None else self.start_ns + int(start * 1e9)
        self._hi = None if end is None else self.start_ns + int(end * 1e9)
        self._cache: dict[str, TopicData] = {}

    # --- the mapping ------------------------------------------------------------------------------

    def __getitem__(self, topic: str) -> TopicData:
        if topic not in self._cache:
            if topic not in self._shown:
                raise NotInRecording(f"{self.path}: no topic {topic}; topics: {', '.join(self._shown)}")
            self.load([topic])
        return self._cache[topic]

    def __iter__(self) -> Iterator[str]:
        return iter(self._shown)

    def __len__(self) -> int:
        return len(self._shown)

    def __contains__(self, topic: object) -> bool:
        return topic in self._shown

    def __repr__(self) -> str:
        loaded = [self._cache[t] for t in self._shown if t in self._cache]
        parts = "; ".join(f"{t.topic} {len(t)} samples at {t.nominal_rate:g} Hz" for t in loaded)
        return (f"<Recording {self.path.name}: {len(self)} topic{'s' if len(self) != 1 else ''}, "
                f"{self.duration_s:.3f} s; {parts}>")

    @property
    def duration_s(self) -> float:
        """From its first message to its last, any topic (as ``ambdaq info`` and the record summary
        say), within the ``start``/``end`` it was opened with, s.  A topic's own first-to-last
        sample is :attr:`TopicData.duration`."""
        first, last = self.file.span_ns
        lo = first if self._lo is None else max(first, self._lo)
        hi = last if self._hi is None else min(last, self._hi)
        return max(hi - lo, 0) * 1e-9

    @property
    def topics(self) -> dict[str, TopicData]:
        """Every topic it shows, loaded."""
        self.load(self._shown)
        return {t: self._cache[t] for t in self._shown}

    def load(self, topics: list[str] | tuple[str, ...]) -> Recording:
        """Decode ``topics`` now, in one pass over the chunks (those already loaded are kept).

        Raises
        ------
        NotInRecording
            A topic it does not show (one line, exit 2; a KeyError to Python).
        """
        missing = [t for t in topics if t not in self._shown]
        if missing:
            raise NotInRecording(f"{self.path}: no ambdaq topic {missing[0]}; topics: {', '.join(self._shown) or 'none'}")
        todo = [t for t in dict.fromkeys(topics) if t not in self._cache]
        fixed = {t: self._fixed[t] for t in todo if t in self._fixed}
        if fixed:
            self._cache.update(read_fixed(self.file, fixed, self._fixed, self.start_ns, self._lo, self._hi, self.metadata,
                                          self.threads))
        others, read = [t for t in todo if t not in self._fixed], {}
        for topic in [t for t in others if t in self._foreign_fixed]:  # in blocks, where their layout is fixed
            try:
                read[topic] = load_fixed(self.file, topic, *self._foreign_fixed[topic], self._lo, self._hi)
            except NotFixed:
                pass  # the official decoder reads it, message by message
        others = [t for t in others if t not in read]
        read.update(load_foreign(self.file, others, self._lo, self._hi) if others else {})
        for topic, cols in read.items():
            n = cols["log_time"].shape[0]
            data = TopicData(topic=topic, nominal_rate=0.0, log_time=cols["log_time"], start_ns=self.start_ns,
                             device_time=cols["device_time"], seq=cols["seq"], status=np.zeros(n, dtype=np.uint32),
                             fields=cols["fields"], units={k: "" for k in cols["fields"]}, skipped=cols["skipped"])
            data.nominal_rate = data.sample_rate
            self._cache[topic] = data
        return self

    # --- what the file says -----------------------------------------------------------------------

    @cached_property
    def devices(self) -> dict[str, DeviceInfo]:
        """The recorded devices by name, with what the file says of each."""
        owner = {ch.topic: (ch.metadata or {}).get("device", "") for ch in self.file.summary.channels.values()}
        out = {}
        for name, identity in self.metadata.items():
            if name.startswith(DEVICE):
                dev = name.removeprefix(DEVICE)
                out[dev] = DeviceInfo(dev, identity, self.metadata.get(CALIBRATION + dev, {}),
                                      tuple(t for t, d in owner.items() if d == dev), self.metadata.get(CLOCK + dev, {}),
                                      self.metadata.get(LINK + dev, {}))
        return dict(sorted(out.items()))

    @property
    def session(self) -> Mapping[str, str]:
        """The recording session: start time, command, host, part ..."""
        return self.metadata.get("ambdaq.session", {})

    def statistics(self, topic: str) -> dict | None:
        """The counts the recorder wrote for ``topic`` (samples, drops, duplicates ...), or None in a
        file without them (another writer's, a recovered one)."""
        text = self.metadata.get("ambdaq.statistics", {}).get(topic)
        return statistics_entry(self.path, topic, text) if text else None

    @cached_property
    def machine(self) -> Machine:
        """The machine it was recorded on: its ``ambdaq.machine`` description, or, in a file made
        before recordings held one, what its devices declare."""
        record = self.metadata.get(RECORD)
        if record is not None:
            return Machine.from_record(record)
        topics = {t: g.fields for t, (_cid, g) in self._fixed.items()}
        return Machine.describe(topics, [d.calibration for d in self.devices.values()])

    @property
    def machine_id(self) -> str:
        """Which machine of a fleet: its description's id, else a device's serial, else the host."""
        if self.machine.id:
            return self.machine.id
        for d in self.devices.values():
            if d.serial:
                return f"serial-{d.serial}"
        return self.session.get("host") or "unknown"

    def role(self, name: str) -> TopicData:
        """The signals of role ``name`` (:data:`ambdaq.roles.ROLE_TOPICS`: gap, current, rotor ...),
        fields named after the machine's axes, wherever the machine records them.

        Raises
        ------
        NotInRecording
            The recording has no such signals (one line naming the topic that would hold them).
        """
        if name not in ROLE_TOPICS:
            raise NotInRecording(f"{name!r} is not a role ({', '.join(ROLE_TOPICS)}); a topic is rec[{name!r}] "
                                 f"and several are rec.to_pandas([...])")
        r = self.machine.role(name)
        if r is None or r.topic not in self._shown:
            raise NotInRecording(f"{self.path}: no {name} signals ({ROLE_TOPICS[name]}, or a rig file's "
                                 f"[machine] {name} mapping); topics: {', '.join(self._shown) or 'none'}")
        data = self[r.topic]
        return data if not r.renamed and tuple(data.fields) == r.axes else data.as_role(r.fields)

    def together(self, *names: str) -> list[TopicData]:
        """The signals of roles ``names`` (``gap``, ``rotor`` ...) at the same sample instants, the
        first role's (:func:`same_instants`)."""
        return same_instants([self.role(n) for n in names], list(names), self.path)

    def signals(self, spec: str) -> TopicData:
        """A role by name (``gap``), by the topic ambdaq's own devices record it on (``/amb/gap``: the
        machine's gap wherever it is recorded), or any other topic as it is."""
        role = spec if spec in ROLE_TOPICS else next((r for r, t in ROLE_TOPICS.items() if t == spec), None)
        if role is not None and (self.has_role(role) or spec not in self._shown):
            return self.role(role)
        return self[spec]

    def to_pandas(self, topics: list[str], index: str = "seconds", tolerance_s: float | None = None):
        """Several topics in one DataFrame on the first topic's samples: each other topic's latest
        sample at or before each of them (``pandas.merge_asof``), NaN where it has none within
        ``tolerance_s`` (default: 1.5 of its own sample periods: a hole, or before it began).
        Columns are ``TOPIC.FIELD``; ``df.attrs["units"]`` has each column's unit.

        Parameters
        ----------
        topics : list of str
            Topics (or roles: ``gap``, ``rotor`` ...), the first one's samples the rows.
        index : {"seconds", "timedelta", "datetime"}
            As :meth:`TopicData.to_pandas`.
        tolerance_s : float, optional
            The oldest a joined sample may be, s.
        """
        from ..mcap.reader import _pandas, _time_index

        pd = _pandas()
        if not topics:
            raise BadInputError("to_pandas: name at least one topic")
        datas = [self.signals(t) for t in topics]
        base = datas[0]
        frame = pd.DataFrame({f"{base.topic}.{k}": v for k, v in base.fields.items()})
        frame["_t"] = base.log_time
        units = {f"{base.topic}.{k}": u for k, u in base.units.items()}
        for d in datas[1:]:
            other = pd.DataFrame({f"{d.topic}.{k}": v for k, v in d.fields.items()})
            other["_t"] = d.log_time
            period = 1.0 / d.nominal_rate if d.nominal_rate else 0.0
            tol = tolerance_s if tolerance_s is not None else 1.5 * period
            frame = pd.merge_asof(frame, other, on="_t", direction="backward", tolerance=int(round(tol * 1e9)))
            units.update({f"{d.topic}.{k}": u for k, u in d.units.items()})
        frame.index = _time_index(pd, base, index)
        frame = frame.drop(columns="_t")
        frame.attrs = {"topics": [d.topic for d in datas], "units": units, "time_unit": "s"}
        return frame

    def has_role(self, name: str) -> bool:
        """Whether the recording holds the signals of role ``name``."""
        r = self.machine.role(name)
        return r is not None and r.topic in self._shown

    def load_roles(self, names: list[str] | tuple[str, ...]) -> Recording:
        """Decode the topics of roles ``names`` in one pass (a role it lacks is left for :meth:`role` to name)."""
        topics = [r.topic for n in names if (r := self.machine.role(n)) is not None and r.topic in self._shown]
        return self.load(topics)


def statistics_entry(path: Path, topic: str, text: str) -> dict:
    """One topic's ``ambdaq.statistics`` entry (JSON), or one line saying it is damaged (a file
    whose data section has no CRC to catch a changed byte: another writer's, or ambdaq's before 0.3)."""
    try:
        entry = json.loads(text)
        if isinstance(entry, dict):
            return entry
    except ValueError:
        pass
    raise BadInputError(f"{path}: the ambdaq.statistics metadata of {topic} is damaged (not a JSON object); "
                        "try: ambdaq recover")


def same_instants(data: list[TopicData], labels: list[str], where: Path) -> list[TopicData]:
    """``data`` on the sample instants of its first member: as recorded where they share them (the
    topics of one device); the rotor angle and speed (label ``rotor``) of a key-phasor on another
    device mapped onto them through the unwrapped angle, where it is sampled fast enough for that to
    be exact (less than half a revolution between two of its samples) and covers them.  Anything
    else measured by another device is refused in one line: ambdaq never pairs samples by index
    when they were not taken together."""
    base = data[0]
    out = [base]
    for label, d in zip(labels[1:], data[1:]):
        if d.log_time is base.log_time or (len(d) == len(base) and np.array_equal(d.log_time, base.log_time)):
            out.append(d)
        elif label == "rotor":
            out.append(_rotor_at(d, base, where))
        else:
            raise BadInputError(f"{where}: {label} ({d.topic}) is not sampled at the instants of {labels[0]} "
                                f"({base.topic}): ambdaq pairs no samples of different devices by index; record "
                                "both on one device")
    return out


def _rotor_at(rot: TopicData, base: TopicData, where: Path) -> TopicData:
    """The key-phasor's angle (rad, wrapped) and speed (rad/s) at ``base``'s instants."""
    t, tb = rot.log_time, base.log_time
    if len(rot) < 2 or len(base) == 0 or tb[0] < t[0] or tb[-1] > t[-1]:
        raise BadInputError(f"{where}: the rotor angle ({rot.topic}) does not cover the {base.topic} samples: they "
                            "cannot be placed on the key-phasor")
    dt = np.diff(t) * 1e-9
    if float(np.max(np.abs(rot["speed"][1:]) * dt)) >= np.pi:
        raise BadInputError(f"{where}: the rotor angle ({rot.topic}) is sampled too slowly for its speed (half a "
                            f"revolution or more between two samples) to be placed at the {base.topic} samples")
    angle = np.interp(tb, t, np.unwrap(rot["angle"]))
    speed = np.interp(tb, t, rot["speed"])
    return TopicData(rot.topic, base.nominal_rate, tb, base.start_ns, base.device_time, base.seq, base.status,
                     {"angle": np.mod(angle, 2 * np.pi), "speed": speed}, {"angle": "rad", "speed": "rad/s"})


def open_recording(source: str | Path | McapFile, **options) -> Recording:
    """A recording opened, its topics loaded when asked for (options as :class:`Recording`)."""
    return Recording(source, **options)


def load(path: str | Path | McapFile, topics: list[str] | tuple[str, ...] | None = None, *, start: float | None = None,
         end: float | None = None, threads: int = READ_THREADS) -> Recording:
    """Load topics of a recording as numpy arrays, all at once.

    Parameters
    ----------
    path : str, Path or McapFile
        An MCAP file: ambdaq's (fixed layouts, read block by block) or another writer's (its topics
        through the official decoders, numeric fields as columns by path).
    topics : list of str, optional
        Topics to load; default all ambdaq topics in the file and every other topic an official
        decoder reads.
    start, end : float, optional
        Time window, in s since the first message of the file.
    threads : int
        Chunks decompressed at once (zstd lets go of the GIL).

    Returns
    -------
    Recording
        ``rec[topic]`` is a :class:`~ambdaq.mcap.reader.TopicData`; ``rec.metadata`` holds the
        file's metadata.

    Raises
    ------
    BadInputError
        Not an MCAP file, truncated (``ambdaq recover`` rebuilds it), corrupted, or a topic
        that is missing.
    """
    rec = Recording(path, topics, start=start, end=end, threads=threads)
    rec.load(list(rec))
    return rec


__all__ = ["DeviceInfo", "Recording", "load", "open_recording", "same_instants", "statistics_entry"]
