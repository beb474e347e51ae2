"""The live status of a recording on a terminal: per device its rate and losses, per bearing the
gap's DC and 1X from the key-phasor, the speed, the file size."""

import os
import pty
import re
import subprocess
import sys

import numpy as np
import pytest

from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load
from ambdaq.live.view import LiveView
from ambdaq.drivers.signals import SampleBlock
from ambdaq.machines.machine import Machine

GROUPS = {"ctl": {"/amb/gap": ["front_x", "front_y", "axial"], "/amb/rotor": ["angle", "speed", "keyphasor"]}}
MACHINE = Machine.describe(GROUPS["ctl"])


def test_bearing_figures_are_the_last_windows_dc_and_1x():
    """Blocks of a gap with a known DC and 1X at a known speed: the view reports exactly those over
    its window, whatever came before it (an older block with other values is out of the window)."""
    view = LiveView({"ctl": 10_000.0}, GROUPS, MACHINE, window_s=0.2)
    omega = 30000 * 2 * np.pi / 60
    for k, (dc, amp) in enumerate(((50e-6, 1e-6), (12e-6, 17e-6), (12e-6, 17e-6), (12e-6, 17e-6))):
        n = np.arange(k * 1000, (k + 1) * 1000)
        theta = omega * n / 10_000.0
        gap = np.column_stack([dc + amp * np.sin(theta + 0.3), -dc + 0.5 * amp * np.cos(theta), np.zeros(1000)])
        rotor = np.column_stack([np.mod(theta, 2 * np.pi), np.full(1000, omega), np.zeros(1000)])
        view.received("ctl", SampleBlock(n * 100_000, n.astype(np.uint32), {"/amb/gap": gap, "/amb/rotor": rotor}))
    (front,) = view.bearings()
    assert front.bearing == "front" and front.speed_rpm == pytest.approx(30000, rel=1e-9)
    # 0.2 s at 30,000 rpm is 100 whole revolutions: the mean and the 1X fit are exact to rounding
    assert front.dc_um == pytest.approx((12.0, -12.0), abs=1e-9)
    assert front.one_x_um == pytest.approx((17.0, 8.5), rel=1e-9)
    assert len(front.orbit_um[0]) == len(front.orbit_um[1]) == 400  # 2,000 samples, every 5th
    short = LiveView({"ctl": 10_000.0}, GROUPS, MACHINE, window_s=0.2)
    n = np.arange(540)
    short.received("ctl", SampleBlock(n * 100_000, n.astype(np.uint32),
                                     {"/amb/gap": np.zeros((540, 3)), "/amb/rotor": np.zeros((540, 3))}))
    assert len(short.bearings()[0].orbit_um[0]) <= 400  # a window not yet full is capped too


def strip(text: str) -> str:
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)


@pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)
def test_a_terminal_shows_the_live_status(tmp_path):
    """The live status on a terminal, stopped with Ctrl-C once it shows 2 s recorded: the promised
    "stopping, finishing FILE" line is said (through the status's own console, above it: written
    under it, the next redraw had erased it from the screen, which this byte stream cannot show),
    and the file is finished."""
    import signal

    out = tmp_path / "live.mcap"
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "record", "--device", "sim://spindle", "--rpm", "30000",
                             "--duration", "60", "-o", str(out)], stderr=slave, stdout=subprocess.PIPE)
    os.close(slave)
    chunks, interrupted = [], False
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
        if not interrupted and re.search(r"recording\s+[2-9][\d.]* s", strip(b"".join(chunks[-8:]).decode(errors="replace"))):
            proc.send_signal(signal.SIGINT)
            interrupted = True
    assert proc.wait(timeout=60) == 0 and interrupted
    os.close(master)
    text = strip(b"".join(chunks).decode(errors="replace"))
    assert f"ambdaq: stopping, finishing {out}" in text.replace("\n", ""), text[-1500:]
    assert "samples/s" in text and "gap DC x / y [µm]" in text and "1X x / y [µm]" in text
    rows = re.findall(r"rig front\s+│\s+([\d,]+)\s+│\s+(-?[\d.]+) / (-?[\d.]+)\s+│\s+([\d.]+) / ([\d.]+)", text)
    assert rows, text[-2000:]
    rpm, dcx, dcy, x1, y1 = rows[-1]
    # against the recording: the front gap's DC and 1X over the whole file (the rig runs steadily,
    # so the last 0.2 s window shows the same within the sensor noise: 0.2 um RMS, 0.3 um)
    rec = load(out, topics=["/amb/gap", "/amb/rotor"])
    gap, rot = rec["/amb/gap"], rec["/amb/rotor"]
    assert float(rpm.replace(",", "")) == pytest.approx(30000, rel=1e-3)
    assert abs(float(dcx) - gap["front_x"].mean() * 1e6) < 0.3 and abs(float(dcy) - gap["front_y"].mean() * 1e6) < 0.3
    whole = np.abs(harmonic_fit(np.column_stack([gap["front_x"], gap["front_y"]]), np.unwrap(rot["angle"]), (1,))[0]) * 1e6
    assert abs(float(x1) - whole[0]) < 0.3 and abs(float(y1) - whole[1]) < 0.3
    assert re.search(r"recording [\d.]+ s\s+[\d.]+ MB", text)
