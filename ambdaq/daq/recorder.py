"""The recorder: reads sample blocks from one or more devices and writes them to MCAP.

Each device is read on its own thread into a queue; the calling thread maps device clocks to the
host clock, encodes and writes.  A chunk is closed and flushed at least every
``flush_interval`` seconds of wall time, so a killed recorder loses at most that much data.
Ctrl-C (or SIGTERM) stops the devices and finishes the file cleanly.
"""

from __future__ import annotations

import platform
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Protocol

from .. import __version__
from ..drivers.signals import SampleBlock, SignalGroup
from ..errors import BadInputError, DeviceError
from .writer import RecordingWriter, TopicStats


class Source(Protocol):
    """What the recorder needs of a device (see :class:`ambdaq.drivers.sim.SimSource`)."""

    name: str
    sample_rate: float

    def signal_groups(self) -> list[SignalGroup]: ...
    def identity(self) -> dict[str, str]: ...
    def calibration(self) -> dict[str, str]: ...
    def start(self, n_samples: int | None) -> None: ...
    def read(self) -> SampleBlock | None: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class RecordOptions:
    """How to record.

    Parameters
    ----------
    duration_s : float or None
        Recording length, in s of device time; ``None`` records until stopped.
    split_size : int or None
        Start a new file when the present one reaches this many bytes.
    split_duration_s : float or None
        Start a new file after this many seconds of data.
    compression : str
        Chunk compression: "zstd", "lz4" or "none".
    flush_interval_s : float
        Longest wall time between chunk flushes, in s (bounds the loss after a crash).
    """

    duration_s: float | None = None
    split_size: int | None = None
    split_duration_s: float | None = None
    compression: str = "zstd"
    flush_interval_s: float = 0.5
    chunk_size: int = 4 << 20


@dataclass
class Progress:
    """Figures shown while recording."""

    elapsed_s: float
    samples: int
    drops: int
    rate_hz: float


@dataclass
class RecordResult:
    """Summary of a finished recording."""

    files: list[Path]
    duration_s: float
    samples: int
    drops: int
    stopped_by_user: bool
    topics: dict[str, dict] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            "files": [str(f) for f in self.files],
            "duration_s": round(self.duration_s, 6),
            "samples": self.samples,
            "drops": self.drops,
            "stopped_by_user": self.stopped_by_user,
            "topics": self.topics,
        }


def split_names(output: Path, split: bool) -> Callable[[int], Path]:
    """File name for part ``i``: the output itself, or ``NAME_000.mcap`` ... when splitting."""
    if not split:
        return lambda i: output
    return lambda i: output.with_name(f"{output.stem}_{i:03d}{output.suffix or '.mcap'}")


class _Reader(threading.Thread):
    """Reads one device into the shared queue until it ends, fails or is stopped."""

    def __init__(self, source: Source, q: queue.Queue, stop: threading.Event) -> None:
        super().__init__(name=f"read-{source.name}", daemon=True)
        self.source, self.q, self.stop = source, q, stop

    def run(self) -> None:
        try:
            while not self.stop.is_set():
                block = self.source.read()
                if block is None:
                    break
                self.q.put((self.source, block))
        except Exception as err:  # report, the main thread decides
            self.q.put((self.source, err))
        self.q.put((self.source, None))


class _SigTerm(Exception):
    pass


class Recorder:
    """Record ``sources`` into ``output`` (see :class:`RecordOptions`).

    Parameters
    ----------
    sources : list of Source
        Devices, already opened.
    output : Path
        Output file (``NAME_000.mcap`` ... when splitting).
    options : RecordOptions
        Duration, splitting, compression.
    command : str
        The command line, stored in the session metadata.
    rig_file : Path, optional
        The rig file, attached to every part.
    overwrite : bool
        Replace existing output files.
    """

    def __init__(
        self,
        sources: list[Source],
        output: Path,
        options: RecordOptions,
        *,
        command: str = "",
        rig_file: Path | None = None,
        overwrite: bool = False,
    ) -> None:
        if not sources:
            raise BadInputError("nothing to record: give --device or --rig")
        names = [s.name for s in sources]
        if len(set(names)) != len(names):
            raise BadInputError(f"device names must be unique, got {', '.join(names)}")
        self.sources = sources
        self.options = options
        self.command = command
        self.rig_file = rig_file
        self._split = options.split_size is not None or options.split_duration_s is not None
        self._name = split_names(Path(output), self._split)
        self._overwrite = overwrite
        if not overwrite and self._name(0).exists():
            raise BadInputError(f"{self._name(0)} exists: choose another -o or pass --overwrite")

    def _open_part(self, index: int, start_ns: int) -> RecordingWriter:
        path = self._name(index)
        if path.exists():
            if not self._overwrite:
                raise BadInputError(f"{path} exists: choose another -o or pass --overwrite")
            path.unlink()
        w = RecordingWriter(path, compression=self.options.compression, chunk_size=self.options.chunk_size)
        w.add_metadata(
            "ambdaq.session",
            {
                "start_time": datetime.fromtimestamp(start_ns / 1e9, timezone.utc).isoformat(),
                "ambdaq_version": __version__,
                "command": self.command,
                "host": platform.node(),
                "devices": ",".join(s.name for s in self.sources),
                "part": str(index),
                "requested_duration_s": "" if self.options.duration_s is None else f"{self.options.duration_s:g}",
            },
        )
        for s in self.sources:
            w.add_device(s.name, s.signal_groups(), s.identity(), s.calibration())
        if self.rig_file is not None:
            w.add_attachment(self.rig_file.name, "application/toml", self.rig_file.read_bytes(), start_ns)
        return w

    def run(self, on_progress: Callable[[Progress], None] | None = None, progress_interval_s: float = 0.5) -> RecordResult:
        """Record until the duration is reached, every device ends, or the user stops."""
        opts = self.options
        q: queue.Queue = queue.Queue()
        stop = threading.Event()
        start_host_ns = self._start_host_ns = time.time_ns()
        for s in self.sources:
            n = None if opts.duration_s is None else int(round(opts.duration_s * s.sample_rate))
            s.start(n)
        readers = [_Reader(s, q, stop) for s in self.sources]
        part = 0
        writer = self._open_part(part, start_host_ns)
        files = [writer.path]
        totals: dict[str, TopicStats] = {}
        part_start_ns = start_host_ns
        t0 = time.monotonic()
        last_flush = last_progress = t0
        live = len(readers)
        user_stop = False
        failure: Exception | None = None
        old_term = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None

        def on_term(signum, frame):
            raise _SigTerm()

        if old_term is not None:
            signal.signal(signal.SIGTERM, on_term)
        for r in readers:
            r.start()
        try:
            while live:
                try:
                    source, item = q.get(timeout=0.1)
                except queue.Empty:
                    item = source = None
                if isinstance(item, Exception):
                    failure = item
                    stop.set()
                elif item is None and source is not None:
                    live -= 1
                elif item is not None:
                    block = self._on_host_clock(item)
                    if self._split and self._part_full(writer, part_start_ns, int(block.host_time_ns[0])):
                        self._merge(totals, writer)
                        writer.close()
                        part += 1
                        part_start_ns = int(block.host_time_ns[0])
                        writer = self._open_part(part, part_start_ns)
                        files.append(writer.path)
                    writer.write(source.name, block)
                now = time.monotonic()
                if now - last_flush >= opts.flush_interval_s:
                    writer.flush()
                    last_flush = now
                if on_progress is not None and now - last_progress >= progress_interval_s:
                    last_progress = now
                    on_progress(self._progress(totals, writer, now - t0))
        except (KeyboardInterrupt, _SigTerm):
            user_stop = True
        finally:
            stop.set()
            for s in self.sources:
                s.close()
            for r in readers:
                r.join(timeout=2.0)
            self._drain(q, writer)
            self._merge(totals, writer)
            writer.close()
            if old_term is not None:
                signal.signal(signal.SIGTERM, old_term)
        if failure is not None:
            raise DeviceError(f"device failed after {time.monotonic() - t0:.1f} s: {failure}") from failure
        samples = max((st.samples for st in totals.values()), default=0)
        drops = sum(st.drops for st in totals.values())
        rate = max((s.sample_rate for s in self.sources), default=1.0)
        return RecordResult(
            files=files,
            duration_s=samples / rate,
            samples=samples,
            drops=drops,
            stopped_by_user=user_stop,
            topics={t: {"samples": st.samples, "drops": st.drops} for t, st in totals.items()},
        )

    def _part_full(self, writer: RecordingWriter, part_start_ns: int, t_ns: int) -> bool:
        o = self.options
        if o.split_size is not None and writer.bytes_written >= o.split_size:
            return True
        return o.split_duration_s is not None and (t_ns - part_start_ns) >= o.split_duration_s * 1e9

    def _drain(self, q: queue.Queue, writer: RecordingWriter) -> None:
        """Blocks already read when the recording stopped are written, not lost."""
        while True:
            try:
                source, item = q.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, SampleBlock) and len(item):
                writer.write(source.name, self._on_host_clock(item))

    def _on_host_clock(self, block: SampleBlock) -> SampleBlock:
        """Map device time to host time.  In-process devices start their clock at 0 when the
        recording starts, so the mapping is the start offset."""
        return SampleBlock(block.device_time_ns, block.seq, block.values, block.device_time_ns + self._start_host_ns)

    @staticmethod
    def _merge(totals: dict[str, TopicStats], writer: RecordingWriter) -> None:
        for topic, st in writer.statistics().items():
            acc = totals.setdefault(topic, TopicStats(st.device))
            acc.samples += st.samples
            acc.drops += st.drops

    @staticmethod
    def _progress(totals: dict[str, TopicStats], writer: RecordingWriter, elapsed: float) -> Progress:
        stats = writer.statistics()
        samples = max((totals.get(t, TopicStats("")).samples + st.samples for t, st in stats.items()), default=0)
        drops = sum(totals.get(t, TopicStats("")).drops + st.drops for t, st in stats.items())
        return Progress(elapsed, samples, drops, samples / elapsed if elapsed > 0 else 0.0)


def print_progress(p: Progress, stream=sys.stderr) -> None:
    """One status line, redrawn in place on a terminal."""
    text = f"recording {p.elapsed_s:7.1f} s  {p.samples:>10d} samples  {p.drops:>6d} drops  {p.rate_hz:10.0f} samples/s"
    end = "\r" if stream.isatty() else "\n"
    stream.write(text + end)
    stream.flush()
