"""A recording survives Ctrl-C, SIGTERM and kill -9 (then ``ambdaq recover``)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ambdaq.daq import load

AMBDAQ = [sys.executable, "-m", "ambdaq"]


def start_recording(out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [*AMBDAQ, "record", "--device", "sim://spindle", "--rpm", "30000", "--duration", "60", "-o", str(out), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def wait_for_data(out: Path, proc: subprocess.Popen, seconds: float) -> None:
    deadline = time.monotonic() + 60
    while not (out.exists() and out.stat().st_size > 100_000):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "recording never started"
        time.sleep(0.05)
    time.sleep(seconds)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_finishes_the_file_cleanly(tmp_path, sig):
    out = tmp_path / "stop.mcap"
    proc = start_recording(out)
    wait_for_data(out, proc, 1.5)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    assert summary["stopped_by_user"] is True
    rec = load(out)  # finished and indexed: the fast reader opens it
    gap = rec["/amb/gap"]
    assert len(gap) == summary["samples"] > 10000
    np.testing.assert_array_equal(np.diff(gap.seq.astype(np.int64)), 1)  # nothing lost at the end


def test_kill_9_loses_at_most_the_last_second(tmp_path, run_cli):
    out = tmp_path / "crash.mcap"
    proc = start_recording(out)
    wait_for_data(out, proc, 3.0)
    os.kill(proc.pid, signal.SIGKILL)
    killed_ns = time.time_ns()
    proc.communicate(timeout=30)
    before = out.read_bytes()
    r = run_cli("info", out)
    assert r.exit_code == 2 and "ambdaq recover" in r.output and "Traceback" not in r.output
    fixed = tmp_path / "fixed.mcap"
    r = run_cli("recover", out, "-o", fixed, "--json")
    assert r.exit_code == 0, r.output
    assert out.read_bytes() == before  # the broken file is never touched
    report = json.loads(r.stdout)
    assert report["chunks_kept"] >= 4
    gap = load(fixed)["/amb/gap"]
    np.testing.assert_array_equal(np.diff(gap.seq.astype(np.int64)), 1)  # contiguous from the first sample
    lost_s = (killed_ns - int(gap.log_time[-1])) * 1e-9
    assert 0 <= lost_s <= 1.0, lost_s
    assert report["topics"]["/amb/gap"] == {"samples": len(gap), "drops": 0, "duplicates": 0, "wraps": 0, "restarts": 0}
