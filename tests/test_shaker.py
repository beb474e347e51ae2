"""The base shakers' generator (SCPI over a serial line) against the simulated one, and Kang & Jung's
stepped-sine campaign driving both devices over their transports, as it would on hardware."""

import cmath
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load
from ambdaq.sim.rigs.base_motion import BASE_AXES
from ambdaq.drivers.shaker import Shaker
from ambdaq.sim.serve import serve
from ambdaq.sim.devices.shaker import SHAKER_GAIN
from ambdaq.errors import BadInputError, DeviceError

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)


@pytest.fixture
def served():
    s = serve("base-motion", can=None)
    yield s
    s.stop()


def _until(predicate, timeout=1.0):
    end = time.monotonic() + timeout
    while not predicate() and time.monotonic() < end:
        time.sleep(0.01)
    return predicate()


def test_the_generator_moves_the_base_with_the_ratio_asked(served):
    rig = served.server.rig
    shaker = Shaker(f"scpi://{served.ptys['shaker'].path}", gain=SHAKER_GAIN)
    try:
        assert shaker.identity.startswith("ambdaq,SIM-SHAKER-2CH")
        alpha = 0.7 * cmath.exp(0.6j)
        shaker.sine(40.0, 1.5, alpha)
        assert _until(lambda: rig.base_motion is not None)
        m = rig.base_motion
        assert (m.kind, m.freq_hz) == ("sine", 40.0)
        assert m.amplitude == pytest.approx(1.5) and m.ratio == pytest.approx(alpha)
        assert float(shaker.query("SOUR2:VOLT?")) == pytest.approx(2 * 1.5 / SHAKER_GAIN)
        assert shaker.query("OUTP1?") == "1"

        # channels at two frequencies cannot move one base: refused, and the base is held still
        shaker.write("SOUR2:FREQ 41")
        with pytest.raises(DeviceError, match="-221 Settings conflict"):
            shaker.check("two frequencies")
        assert _until(lambda: rig.base_motion is None)
        shaker.check("nothing")  # the queue was read empty
        for bad, code in (("SOUR1:WOBBLE 3", "-113"), ("SOUR1:FREQ 1e9", "-222"), ("SOUR1:FUNC SQU", "-224")):
            shaker.write(bad)
            with pytest.raises(DeviceError, match=code):
                shaker.check(bad)
        with pytest.raises(BadInputError, match="the generator gives 10 Vpp"):
            shaker.sine(40.0, 40.0, 2.0)
        shaker.sine(20.0, 1.0, -1.0)
        assert _until(lambda: rig.base_motion is not None and rig.base_motion.freq_hz == 20.0)
        shaker.stop()
        assert _until(lambda: rig.base_motion is None)
    finally:
        shaker.close()


def test_a_generator_that_is_gone_is_one_line(served, tmp_path):
    with pytest.raises(DeviceError, match="cannot open the shaker generator"):
        Shaker(f"scpi://{tmp_path / 'no-such-port'}", gain=SHAKER_GAIN)
    with pytest.raises(BadInputError, match="scpi: URL"):
        Shaker("can://virtual/x?node=3", gain=SHAKER_GAIN)
    shaker = Shaker(f"scpi://{served.ptys['shaker'].path}", gain=SHAKER_GAIN)
    served.devices["shaker"].stop()  # the instrument stops answering
    with pytest.raises(DeviceError, match="did not answer"):
        shaker.sine(40.0, 1.0, 1.0)
    shaker.close()


def test_campaign_drives_the_served_controller_and_shaker_in_another_process(tmp_path):
    """``ambdaq sim serve --profile base-motion`` in its own process prints the controller's and
    the generator's pseudo-terminals; ``fx campaign`` reaches both by URL, as it would on hardware.
    The base moves with the ratio and amplitude commanded (measured at the base accelerometers)."""
    cmd = [sys.executable, "-m", "ambdaq"]
    proc = subprocess.Popen(cmd + ["sim", "serve", "--profile", "base-motion", "--duration", "60"],
                            stdout=subprocess.PIPE, text=True)
    try:
        ports = dict(proc.stdout.readline().split() for _ in range(2))
        out = tmp_path / "camp"
        args = ["fx", "campaign", "--device", f"serial://{ports['controller']}", "--shaker", f"scpi://{ports['shaker']}",
                "--freqs", "10,60", "--amplitude", "2", "--alphas", "1,0.5-0.5j", "--seconds", "0.5", "--settle", "0.2",
                "-o", str(out)]
        # by URL, as on hardware: the shakers' gain is the engineer's to give, no device reports it
        r = subprocess.run(cmd + args, capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "--shaker-gain: give your shakers'" in r.stderr, r.stderr
        r = subprocess.run(cmd + args + ["--shaker-gain", str(SHAKER_GAIN)], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    plan = json.loads((out / "campaign.json").read_text())
    assert plan["shaker"].startswith("ambdaq,SIM-SHAKER-2CH") and len(plan["steps"]) == 4
    for step in plan["steps"]:
        rec = load(out / step["file"], topics=["/base/accel"])
        acc = rec["/base/accel"]
        d = np.stack([acc[a] for a in BASE_AXES], axis=1)
        theta = 2 * np.pi * step["freq_hz"] * np.arange(len(d)) / rec["/base/accel"].nominal_rate
        ph = harmonic_fit(d, theta, (1,))[0]  # per accelerometer: base1_y, base2_y, base1_z, base2_z
        alpha = complex(*step["alpha_commanded"])
        for p in range(2):
            assert abs(ph[2 * p + 1]) == pytest.approx(2.0, rel=0.01)
            assert ph[2 * p] / ph[2 * p + 1] == pytest.approx(alpha, abs=0.01)


def test_campaign_bad_input_is_one_line(run_cli, tmp_path):
    cases = [
        (("fx", "campaign", "--device", f"serial://{tmp_path / 'ctl'}", "-o", tmp_path / "c"), 2, "--shaker URL"),
        (("fx", "campaign", "--device", "sim://spindle", "-o", tmp_path / "c"), 2, "has no moving base"),
        (("fx", "campaign", "--amplitude", "30", "--alphas", "1,2", "-o", tmp_path / "c"), 2, "the generator gives"),
        (("fx", "campaign", "--device", f"serial://{tmp_path / 'ctl'}", "--shaker", f"scpi://{tmp_path / 'gen'}",
          "-o", tmp_path / "c"), 2, "--shaker-gain: give your shakers'"),
        (("fx", "campaign", "--device", f"serial://{tmp_path / 'ctl'}", "--shaker", f"scpi://{tmp_path / 'gen'}",
          "--shaker-gain", "4.2", "-o", tmp_path / "c"), 1, "cannot open the shaker generator"),
    ]
    for args, code, needle in cases:
        r = run_cli(*args)
        assert r.exit_code == code and needle in r.output and r.output.count("\n") == 1, (args, r.output)
    assert not os.path.exists(tmp_path / "c" / "campaign.json")
