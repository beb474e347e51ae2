"""What every file of a recording holds beside its samples: opened with the session, the devices,
the machine and the rig file; finished with the clock fits, the alignment and the link statistics
(docs/data-format.md).  One home for both, so a part of a split recording and a snapshot file say
the same things of themselves.
"""

from __future__ import annotations

import platform
from datetime import datetime, timezone
from pathlib import Path

from .. import __version__
from ..machines.machine import RECORD as MACHINE_RECORD, Machine
from .acquisition import Acquisition
from ..output import check_output
from .writer import RecordingWriter


class RecordingFiles:
    """Opens and finishes the files of one recording.

    Parameters
    ----------
    acquisition : Acquisition
        The devices and their clocks.
    machine : Machine
        Their machine (metadata ``ambdaq.machine``).
    command : str
        The command line, stored in the session metadata.
    rig_file : Path, optional
        The rig file, attached to every file.
    requested_duration_s : float or None
        What was asked for, in s (session metadata).
    compression, chunk_size, fsync, index
        The writer's (:class:`~.writer.RecordingWriter`).
    overwrite : bool
        Replace an existing regular file (:func:`~.output.check_output`).
    """

    def __init__(self, acquisition: Acquisition, machine: Machine, *, command: str = "", rig_file: Path | None = None,
                 requested_duration_s: float | None = None, compression: str = "zstd", chunk_size: int,
                 fsync: bool = True, overwrite: bool = False, index: bool = True,
                 records: dict[str, dict[str, str]] | None = None) -> None:
        self.acquisition, self.machine = acquisition, machine
        self.records = dict(records or {})
        self.command, self.rig_file, self.requested_duration_s = command, rig_file, requested_duration_s
        self.compression, self.chunk_size, self.fsync, self.overwrite = compression, chunk_size, fsync, overwrite
        self.index = index

    def open(self, path: Path, start_ns: int, part: str) -> RecordingWriter:
        """A new file at ``path`` with the session (its part label), every device, the machine and
        the rig file, on disk at once: a crash keeps who recorded what."""
        if check_output(path, self.overwrite).exists():
            path.unlink()
        w = RecordingWriter(path, compression=self.compression, chunk_size=self.chunk_size, fsync=self.fsync,
                            index=self.index)
        sources = self.acquisition.sources
        try:
            w.add_metadata("ambdaq.session", {
                "start_time": datetime.fromtimestamp(start_ns / 1e9, timezone.utc).isoformat(),
                "ambdaq_version": __version__,
                "command": self.command,
                "host": platform.node(),
                "devices": ",".join(s.name for s in sources),
                "part": part,
                "requested_duration_s": "" if self.requested_duration_s is None else f"{self.requested_duration_s:g}",
            })
            for s in sources:
                w.add_device(s.name, s.signal_groups(), s.identity(), s.calibration())
            w.add_metadata(MACHINE_RECORD, self.machine.record())
            for name, record in self.records.items():
                w.add_metadata(name, record)
            if self.rig_file is not None:
                w.add_attachment(self.rig_file.name, "application/toml", self.rig_file.read_bytes(), start_ns)
            w.flush()
        except BaseException:
            w.close()
            raise
        return w

    def finish(self, w: RecordingWriter, kind: str, span: dict[str, str]) -> None:
        """``span`` under ``kind`` (``ambdaq.part``, ``ambdaq.snapshot``), the clock fits, the
        alignment and the link statistics as they are now go into the file's metadata; then it is
        closed (its own counts with it)."""
        acq = self.acquisition
        w.add_metadata(kind, span)
        for name, rep in acq.clock_report().items():
            w.add_metadata(f"ambdaq.clock.{name}", {k: str(v) for k, v in rep.items()})
        alignment = acq.alignment_us()
        if alignment is not None:
            w.add_metadata("ambdaq.alignment", {"estimated_worst_us": f"{alignment:.1f}"})
        for s in acq.sources:
            stats = s.link_statistics()
            if stats:
                w.add_metadata(f"ambdaq.link.{s.name}", stats)
        w.close()


__all__ = ["RecordingFiles"]
