"""Whether a recording is fit to compute from: the samples each topic lost, and the speed it ran
at, checked before a workflow fits anything to it (the data-quality gate, docs/cli.md).

A harmonic fit against the rotor angle takes the samples that are there at their own angles, so a
few lost samples do not bias it; a recording that lost a large share, or compares a speed or a
machine other than the one it is compared with, gives a number that looks right and is not. Such
an input is refused with one line (exit 2) naming the file, the topic and the count; the limit is
an option where a user may knowingly accept more.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BadInputError
from .recording import Recording
from ..acquisition.sequence import HALF, WRAP

MAX_LOST = 0.001
"""The share of a topic's samples that may be lost (0.1 %): a few isolated holes, as a CAN bus or
a noisy serial line leaves, and never a block large enough to take a revolution's worth out of a
harmonic fit at the lowest speed a workflow takes (a 10 kHz loop at 800 rpm has 750 samples per
revolution; 0.1 % of 10 s is 100 samples)."""
MAX_SPEED_CHANGE = 0.01
"""Recordings compared at one speed may differ by 1 %: their harmonics then lie within a bin of a
10 s recording's spectrum."""


@dataclass(frozen=True)
class TopicCounts:
    """A topic's samples as the recording holds them.

    Attributes
    ----------
    topic : str
        The topic.
    samples : int
        Samples written.
    drops : int
        Sample periods lost: gaps in ``seq``, and those the device never sent before the end.
    restarts : int
        Times the device restarted its count.
    """

    topic: str
    samples: int
    drops: int
    restarts: int

    @property
    def lost_fraction(self) -> float:
        """Lost periods over all periods (0 for an empty topic)."""
        total = self.samples + self.drops
        return self.drops / total if total else 0.0


def topic_counts(rec: Recording, topic: str) -> TopicCounts:
    """The counts the recorder wrote for ``topic`` (``ambdaq.statistics``), or, in a file without
    them (another writer's, a recovered one), the gaps in its ``seq``."""
    s = rec.statistics(topic)
    if s:
        return TopicCounts(topic, int(s.get("samples", 0)), int(s.get("drops", 0)), int(s.get("restarts", 0)))
    seq = rec[topic].seq.astype(np.int64)
    step = np.diff(seq) % WRAP
    return TopicCounts(topic, len(seq), int(np.sum(np.where((step > 1) & (step < HALF), step - 1, 0))),
                       int(np.sum(step >= HALF)))


def require_complete(rec: Recording, topics: list[str], purpose: str, max_lost: float = MAX_LOST) -> list[str]:
    """Refuse a recording whose topics lost more than ``max_lost`` of their samples.

    Parameters
    ----------
    rec : Recording
        With ``topics`` loaded.
    topics : list of str
        The topics the computation reads.
    purpose : str
        What would compute from them, for the message.
    max_lost : float
        The share of lost sample periods accepted (0..1).

    Returns
    -------
    list of str
        A note for each topic that lost fewer, but some: what the result is computed over; and
        one for each device whose clock drift was suspect (:attr:`.clock.ClockMap.suspect`).

    Raises
    ------
    BadInputError
        A topic lost more (one line: file, topic, count, the limit and the option that moves it).
    """
    lossy: dict[tuple[int, int], list[str]] = {}  # the topics of one device lose the same samples
    restarted: dict[int, list[str]] = {}
    for name, device in rec.devices.items():  # time stamps that were no clock: nothing computes over them
        refused = device.clock.get("refused")
        if refused and set(device.topics) & set(topics):
            raise BadInputError(f"{rec.path}: {name}'s time stamps could not be its clock ({refused}): {purpose} "
                                "would compute over times that are not; record it again")
    suspect = [f"{rec.path.name}: {name}'s {device.clock['suspect']}; its times were mapped by the offset alone"
               for name, device in rec.devices.items() if device.clock.get("suspect") and set(device.topics) & set(topics)]
    for topic in topics:
        c = topic_counts(rec, topic)
        if c.lost_fraction > max_lost:
            raise BadInputError(
                f"{rec.path}: {topic} lost {c.drops:,} of {c.samples + c.drops:,} samples ({_share(c.lost_fraction)}); "
                f"{purpose} would compute over the holes (limit {_share(max_lost)}, --max-lost): record it again")
        if c.drops:
            lossy.setdefault((c.drops, c.samples + c.drops), []).append(topic)
        if c.restarts:
            restarted.setdefault(c.restarts, []).append(topic)
    notes = suspect + [f"{rec.path.name}: {', '.join(names)} lost {drops:,} of {total:,} samples ({_share(drops / total)}), "
             f"within the {_share(max_lost)} limit" for (drops, total), names in lossy.items()]
    # a restart is a device that began counting again (a reconnect, a reboot): no loss is counted
    # across it, so the computation spans a gap of unknown length
    notes += [f"{rec.path.name}: {', '.join(names)}: the device restarted its sample count {n} time{'s' if n > 1 else ''}"
              " (a reconnect or reboot): the time across each restart is not known to be whole"
              for n, names in restarted.items()]
    return notes


def _share(fraction: float) -> str:
    """A share as a percentage to three significant digits (0.00945 -> "0.945%")."""
    return f"{fraction * 100:.3g}%"


def require_same_speed(recs: list[Recording], rpm: list[float], purpose: str,
                       tolerance: float = MAX_SPEED_CHANGE) -> None:
    """Refuse recordings compared as one speed that ran at speeds more than ``tolerance`` apart.

    Parameters
    ----------
    recs : list of Recording
        The recordings compared.
    rpm : list of float
        Their speeds, rpm.
    purpose : str
        The comparison, for the message.
    tolerance : float
        Relative difference accepted.
    """
    lo, hi = min(rpm), max(rpm)
    if hi - lo > tolerance * max(hi, 1.0):
        named = ", ".join(f"{r.path.name} at {w:,.0f} rpm" for r, w in zip(recs, rpm))
        raise BadInputError(f"{purpose} compares recordings at one speed, and these differ by more than "
                            f"{tolerance:.0%} ({named}): their harmonics are at different frequencies")


def controller_serial(rec: Recording) -> tuple[str, str] | None:
    """(device name, serial) of the recording's controller, or None if it names no serial."""
    return next(((d.name, d.serial) for d in rec.devices.values() if d.kind == "controller" and d.serial), None)


def require_same_machine(recs: list[Recording], purpose: str) -> None:
    """Refuse recordings whose controllers name different serial numbers (recordings without one
    are not judged)."""
    serials = {m[1]: r for r in recs if (m := controller_serial(r)) is not None}
    if len(serials) > 1:
        named = ", ".join(f"{r.path.name} from controller {s}" for s, r in serials.items())
        raise BadInputError(f"{purpose} compares one machine, and these recordings come from different ones ({named})")

