"""The adaptive LMS through a whole run-up, as an engineer runs it: the simulated spindle served in
its own process, every step a separate ``ambdaq`` process. The headline workflow (record, identify,
push, record again, and the rest of the day) is tests/test_commissioning_day.py."""

import os
import subprocess
import sys

import numpy as np
import pytest

from ambdaq.daq import load

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

RADIAL = ("front_x", "front_y", "rear_x", "rear_y")


def ambdaq(*args, env=None, check=True):
    r = subprocess.run([sys.executable, "-m", "ambdaq", *map(str, args)], capture_output=True, text=True, env=env,
                       timeout=120)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def windows(path, seconds=0.2):
    """Per window: speed (rpm), worst radial |1X| and |2X| of the command error, its RMS (um)."""
    rec = load(path, topics=["/amb/error", "/amb/rotor"])
    th, speed = rec["/amb/rotor"]["angle"], rec["/amb/rotor"]["speed"] * 60 / (2 * np.pi)
    e = np.stack([rec["/amb/error"][a] for a in RADIAL], axis=1)
    n = int(seconds * 10000)
    rows = []
    for i in range(0, len(th) - n + 1, n):
        s = slice(i, i + n)
        c = [max(2 * abs(np.mean(e[s, a] * np.exp(-1j * k * th[s]))) for a in range(4)) * 1e6 for k in (1, 2)]
        rows.append((speed[s].mean(), *c, np.sqrt(np.mean(e[s] ** 2)) * 1e6))
    return np.array(rows)


@pytest.mark.long  # 11 s of run-up recorded in real time; the LMS's convergence by the model: test_lms_design.py
@pytest.mark.parametrize("served", [0], indirect=True)
def test_adaptive_lms_through_a_run_up_to_50000_rpm(served, tmp_path):
    """Design the phase-compensated LMS on the rig's map, push it to the served controller at
    standstill, record the run-up to 50,000 rpm (5,000 rpm/s), and compare with the same run-up
    without feedforward (`sim generate`, same physics and seed)."""
    env = {**os.environ, "AMBDAQ_UNLOCK_KEY": "ambdaq-sim", "AMBDAQ_STATE_DIR": str(tmp_path / "state")}
    coef, run, base = tmp_path / "lms.json", tmp_path / "lms_runup.mcap", tmp_path / "base.mcap"
    ambdaq("lms", "schedule", "--plant", "rig", "--compensated", "--mu", "0.002", "-o", coef)
    r = ambdaq("push", coef, "--device", served, "--yes", env=env)
    assert "committed" in r.stdout
    ambdaq("record", "--device", served, "--rpm", 50000, "--duration", 11, "-o", run, "-q")
    ambdaq("sim", "generate", "--rpm", "0:50000:10", "--duration", 11, "-o", base, "-q")
    lms, off = windows(run), windows(base)
    assert lms[:, 0].max() > 49000  # the run-up reached 50,000 rpm
    report = []
    for lo in range(5000, 50000, 5000):
        a = lms[(lms[:, 0] >= lo) & (lms[:, 0] < lo + 5000)]
        b = off[(off[:, 0] >= lo) & (off[:, 0] < lo + 5000)]
        d1 = 20 * np.log10(b[:, 1].mean() / a[:, 1].max())
        d2 = 20 * np.log10(b[:, 2].mean() / a[:, 2].max())
        report.append((lo, round(d1, 1), round(d2, 1), round(a[:, 3].max(), 2)))
        assert d1 >= 20 and d2 >= 20 and a[:, 3].max() < 5.0, report
    at_top = lms[lms[:, 0] > 49900]
    assert at_top[:, 3].max() < 5.0
    print(report)
