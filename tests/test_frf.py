"""Frequency-response measurement (``ambdaq frf``) and the LMS phase taken from it, against the
simulated loop's own linearisation."""

import json
import time
import subprocess
import sys

import numpy as np
import pytest

from ambdaq.analysis.lms import error_response
from ambdaq.machines.spindle_loop import rig_loop
from ambdaq.daq import load
from ambdaq.documents.frequency_response import FrequencyResponse
from ambdaq.drivers.serial.controller import ControllerDriver
from ambdaq.drivers.serial.link import SerialLink
from ambdaq.errors import DeviceError

AXES = ("front_x", "front_y", "rear_x", "rear_y", "axial")


@pytest.fixture(scope="module")
def excited(build_once):
    """10 s at standstill with 2 um RMS white noise on each axis in turn (unpaced), and their FRF
    (built once for both workers)."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    def build(d):
        runner = CliRunner()
        for a in AXES:
            r = runner.invoke(cli, ["sim", "generate", "--duration", "10", "--excite", f"{a}:2", "-q", "-o",
                                    str(d / f"{a}.mcap")])
            assert r.exit_code == 0, r.output
        r = runner.invoke(cli, ["frf", "estimate", *[str(d / f"{a}.mcap") for a in AXES], "-o",
                                str(d / "loop.json"), "--json", "--plot", str(d / "loop.png")])
        assert r.exit_code == 0, r.output

    return build_once("frf-excited", build)


def test_h1_of_the_simulated_loop_is_its_linearisation(excited):
    """T_aa measured with the excitation input equals the kernel's own linearised loop within 3% and
    3 degrees from 20 Hz to 4 kHz; the other axes barely answer."""
    frf = FrequencyResponse.load(excited / "loop.json")
    f = frf.freq_hz
    band = (f >= 20) & (f <= 4000)
    model = error_response(rig_loop(), f[band])
    for i, a in enumerate(AXES):
        h, coh = frf.response(a, a)
        assert np.median(coh[band]) > 0.98
        ratio = h[band] / model[i]
        assert np.abs(np.abs(ratio) - 1).max() < 0.03, a
        assert np.degrees(np.abs(np.angle(ratio))).max() < 3.0, a
    cross, _ = frf.response("front_y", "front_x")
    assert np.median(np.abs(cross[band])) < 0.05
    assert (excited / "loop.png").stat().st_size > 30_000


def test_measured_phase_schedule_converges_like_the_model(excited, run_cli, tmp_path):
    meas, model = tmp_path / "meas.json", tmp_path / "model.json"
    r = run_cli("lms", "schedule", "--plant", "rig", "--frf", excited / "loop.json", "--mu", "0.002", "-o", meas)
    assert r.exit_code == 0 and "phase-compensated" in r.output, r.output
    assert run_cli("lms", "schedule", "--plant", "rig", "--compensated", "--mu", "0.002", "-o", model).exit_code == 0
    pm = json.loads(meas.read_text())
    a, b = pm["lms_phase"]["phase_rad"], json.loads(model.read_text())["lms_phase"]["phase_rad"]
    for axis in AXES:  # 10 Hz .. 2 kHz: harmonics up to 6X at 20,000 rpm
        d = np.degrees(np.angle(np.exp(1j * (np.array(a[axis]) - np.array(b[axis])))))[1:201]
        assert np.abs(d).max() < 8.0, axis
    assert pm["source"]["lms_design"]["phase_from"]["path"].endswith("loop.json")
    r = run_cli("lms", "runup", meas, "--speeds", "3000,12000,50000", "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert all(t is not None and t < 2.0 for t in rep["time_to_converge_s"]["meas.json"].values())
    for band, row in zip(rep["bands_rpm"], rep["runs"]["meas.json"]):
        if band[0] >= 5000:
            assert row[0] < 0.5, (band, row)  # worst radial 1X, um


def test_tampered_or_incomplete_frf_is_refused(excited, run_cli, tmp_path):
    doc = json.loads((excited / "loop.json").read_text())
    doc["columns"]["front_x"]["outputs"]["front_x"]["re"][10] += 0.1
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    r = run_cli("lms", "schedule", "--plant", "rig", "--frf", bad, "-o", tmp_path / "c.json")
    assert r.exit_code == 2 and "checksum mismatch" in r.output
    r = run_cli("frf", "estimate", excited / "front_x.mcap", "-o", tmp_path / "one.json")
    assert r.exit_code == 0
    r = run_cli("lms", "schedule", "--plant", "rig", "--frf", tmp_path / "one.json", "-o", tmp_path / "c.json")
    assert r.exit_code == 2 and "no front_y -> front_y" in r.output


def test_a_recording_without_excitation_is_refused(spindle_file, run_cli, tmp_path):
    r = run_cli("frf", "estimate", spindle_file, "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "0 axes carry a feedforward input" in r.output


@pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)
@pytest.mark.long  # the same excitation over the real drivers runs by default in iso stability (test_iso.py)
def test_measure_through_the_served_controller(tmp_path):
    """``frf measure`` sets the controller's test signal over the serial line, records, and switches
    it off; the controller refuses an out-of-range signal."""
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--duration", "60"],
                            stdout=subprocess.PIPE, text=True)
    try:
        _, pty = proc.stdout.readline().split()
        url = f"serial://{pty}"
        run = tmp_path / "m.mcap"
        cmd = [sys.executable, "-m", "ambdaq"]
        r = subprocess.run(cmd + ["frf", "measure", "--device", url, "--excite", "rear_y:2", "--duration", "2",
                                  "-o", run, "-q"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        r = subprocess.run(cmd + ["frf", "estimate", run, "-o", tmp_path / "m.json", "--json"],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        summary = json.loads(r.stdout)["rear_y"]
        # the loop's rear peak is flat (|T| within 3 % from 330 to 420 Hz in the linearised loop):
        # a 2 s measurement's argmax lands anywhere on it (410 Hz once); its height: coherence 0.99
        # over about 20 averages is 1.6 % of random error, and the largest of the flat top's noisy
        # bins sits about one of those above it (+2.2 % measured): 6 %
        f = np.arange(10.0, 2000.0, 1.0)
        model = np.abs(error_response(rig_loop(), f)[AXES.index("rear_y")])
        assert summary["median_coherence"] > 0.97 and 300 <= summary["peak_hz"] <= 450, summary
        assert abs(summary["peak_gain"] / model.max() - 1) < 0.06, (summary, model.max())
        after = tmp_path / "after.mcap"
        r = subprocess.run(cmd + ["record", "--device", url, "--duration", "1", "-o", after, "-q"],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        assert not np.any(load(after, topics=["/amb/ff"])["/amb/ff"]["rear_y"])  # switched off
        # with --rpm the measurement sets the speed it changed back, and says so
        r = subprocess.run(cmd + ["frf", "measure", "--device", url, "--excite", "rear_y:2", "--duration", "1",
                                  "--rpm", "12000", "-o", tmp_path / "at12k.mcap"], capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 0, r.stderr
        assert "speed set back to 0 rpm, as before the measurement" in r.stderr  # `sim serve` stands still
        assert "test signal switched off" in r.stderr
        drv = ControllerDriver(SerialLink(pty))
        try:
            rpm = float(drv.read_param("speed.rpm")[0])
            for _ in range(40):  # the rig ramps back at 5,000 rpm/s: what the controller itself reports
                if rpm < 20:
                    break
                time.sleep(0.2)
                rpm = float(drv.read_param("speed.rpm")[0])
            assert rpm < 20, rpm
            at12k = load(tmp_path / "at12k.mcap", topics=["/amb/rotor"])["/amb/rotor"]["speed"] * 60 / (2 * np.pi)
            assert at12k.max() > 1000  # it had really been sent towards 12,000 rpm
            with pytest.raises(DeviceError, match="axis must be 0 .. 4"):
                drv.write_param("exc.signal", [7, 1e-6, 0])
            with pytest.raises(DeviceError, match="amplitude must be"):
                drv.write_param("exc.signal", [0, 1e-3, 0])
            np.testing.assert_array_equal(drv.read_param("exc.signal"), [-1, 0, 0])
        finally:
            drv.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_an_output_that_stays_at_zero_is_explained_by_nothing():
    """A channel that stays at zero (an axis without power, a disconnected output) has coherence 0,
    never trusted, and no warning of a division by zero; the other outputs of the estimate are
    those of their own estimate, its error covariance zero on the silent channel."""
    import warnings

    from ambdaq.analysis.frf import h1_estimate

    rng = np.random.default_rng(1)
    x = rng.standard_normal(20_000)
    y = np.stack([0.5 * np.roll(x, 1) + 0.1 * rng.standard_normal(x.size), np.zeros(x.size)], axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        both = h1_estimate(x, y, fs=10_000.0, resolution_hz=10.0)
    alone = h1_estimate(x, y[:, 0], fs=10_000.0, resolution_hz=10.0)
    assert np.all(both.coherence[:, 1] == 0) and np.all(both.response[:, 1] == 0)
    assert np.all(both.error[:, 1, :] == 0) and np.all(both.error[:, :, 1] == 0)
    # the same sums in another order (the transforms and products over two channels, not one):
    # equal within 1e-12, rounding's scale
    assert np.allclose(both.response[:, 0], alone.response[:, 0], rtol=1e-12, atol=0)
    assert np.allclose(both.coherence[:, 0], alone.coherence[:, 0], rtol=1e-12, atol=0)
    assert np.median(both.coherence[:, 0]) > 0.9
