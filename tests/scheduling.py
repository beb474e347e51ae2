"""A third pytest-xdist worker that fills the CPU the real-time tests leave idle, and takes nothing
that runs against the wall clock.

The real-time tests (served devices, recorders, protocols with heartbeats and time-outs) wait on
the wall clock for about 40 % of their time. A third worker of equal priority filled those waits
(the suite 15 % faster) but starved the served devices of the CPU for longer than their protocols
allow (3 failures in 8 fresh clones). This one runs under the kernel's SCHED_IDLE policy, it and
every process it starts: it gets a core only when no other process of the machine wants one, so a
device process never waits for it. And it takes only tests marked ``offline`` (no device, no
served process, no bound on wall time): a test that did hold the clock would run at whatever speed
the idle CPU allows.

The workers write the ids of the ``offline`` tests they collected to a file the controlling
process names (``AMBDAQ_TEST_OFFLINE``); the scheduler reads it once every worker has collected.
Each ``xdist_group`` stays whole on one worker, as pytest-xdist's ``loadgroup`` keeps it.
"""

from __future__ import annotations

import os
from pathlib import Path

from xdist.scheduler import LoadGroupScheduling

OFFLINE_LIST = "AMBDAQ_TEST_OFFLINE"
"""The environment variable naming the file of the ``offline`` tests' ids (one per line)."""


def background_worker(count: int) -> str | None:
    """The id of the low-priority worker among ``count`` (the last one), or None with fewer than 3:
    two workers are the suite's two cores, and neither is given away."""
    return f"gw{count - 1}" if count >= 3 else None


def bare(nodeid: str) -> str:
    """A test's id without the ``@group`` pytest-xdist appends to a grouped test (the rule of its
    ``loadgroup``: an ``@`` after the last ``]``)."""
    return nodeid.rsplit("@", 1)[0] if nodeid.rfind("@") > nodeid.rfind("]") else nodeid


def run_in_background() -> None:
    """This process, its threads and every process it starts, on the CPU only when it is idle."""
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


def write_offline(items) -> None:
    """The ids of the collected tests marked ``offline``, for the scheduler (written whole, then
    renamed: every worker writes the same list)."""
    path = Path(os.environ[OFFLINE_LIST])
    part = path.with_suffix(f".{os.getpid()}")
    part.write_text("".join(bare(i.nodeid) + "\n" for i in items if i.get_closest_marker("offline")))
    part.replace(path)


class BackgroundScheduling(LoadGroupScheduling):
    """pytest-xdist's ``loadgroup``, with the last worker given only work units whose every test
    is ``offline``, and the other workers taking the units that are not first: the offline work is
    left for the idle CPU while there is wall-clock work to do, and done by whoever is free at the
    end."""

    def __init__(self, config, log=None) -> None:
        super().__init__(config, log)
        self.background = background_worker(config.option.numprocesses)
        self._offline: set[str] | None = None

    def _is_offline(self, unit: dict[str, bool]) -> bool:
        if self._offline is None:
            self._offline = set(Path(os.environ[OFFLINE_LIST]).read_text().split("\n")) - {""}
        return all(bare(nodeid) in self._offline for nodeid in unit)

    def _assign_work_unit(self, node) -> None:
        background = node.gateway.id == self.background
        chosen = next((scope for scope, unit in self.workqueue.items() if self._is_offline(unit) == background), None)
        if chosen is None and background:
            self.assigned_work.setdefault(node, {})
            if not self._pending_of(self.assigned_work[node]):
                node.shutdown()  # nothing left it may run; the others finish the real-time tests
            return
        if chosen is not None:
            self.workqueue.move_to_end(chosen, last=False)
        super()._assign_work_unit(node)
