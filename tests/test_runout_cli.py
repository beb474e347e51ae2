"""``ambdaq runout identify`` and the coefficient file, against the simulator's ground truth."""

import json

import numpy as np
import pytest

from ambdaq.daq.coefficients import Coefficients
from ambdaq.drivers.rig.spindle import SPINDLE
from ambdaq.errors import BadInputError

TRUE = SPINDLE.runout_amp[:, :6] * np.exp(1j * SPINDLE.runout_phase[:, :6])
AXES = ("front_x", "front_y", "rear_x", "rear_y", "axial")


def phasors(coef_path):
    w = Coefficients.load(coef_path).weights
    return np.array([[a + 1j * b for a, b in w[axis]] for axis in AXES])


def assert_matches_truth(est, harmonics=slice(0, 6)):
    truth = TRUE[:, harmonics]
    big = np.abs(truth) >= 1e-6
    ratio = est[:, harmonics][big] / truth[big]
    assert np.abs(np.abs(ratio) - 1).max() < 0.02
    assert np.degrees(np.abs(np.angle(ratio))).max() < 2.0


def test_slow_roll_recording(tmp_path, run_cli):
    rec = tmp_path / "slow.mcap"
    assert run_cli("sim", "generate", "--rpm", "slowroll", "--duration", "8", "-q", "-o", rec).exit_code == 0
    r = run_cli("runout", "identify", rec, "-o", tmp_path / "coef.json", "--json")
    assert r.exit_code == 0, r.output
    assert_matches_truth(phasors(tmp_path / "coef.json"))
    table = json.loads(r.stdout)
    assert table["rear_x"][0]["harmonic"] == 1 and abs(table["rear_x"][0]["amplitude_um"] - 16.0) < 0.3
    doc = json.loads((tmp_path / "coef.json").read_text())
    assert doc["source"]["recordings"][0]["speed_rpm"] == 800.0 and len(doc["source"]["recordings"][0]["sha256"]) == 64


def test_over_the_real_drivers(tmp_path, run_cli):
    """sim:// records through the serial controller driver (float32 on the wire): same accuracy."""
    rec = tmp_path / "live.mcap"
    assert run_cli("record", "--device", "sim://spindle", "--rpm", "slowroll", "--duration", "5", "-q", "-o", rec).exit_code == 0
    r = run_cli("runout", "identify", rec, "-o", tmp_path / "coef.json")
    assert r.exit_code == 0, r.output
    assert_matches_truth(phasors(tmp_path / "coef.json"))


def test_several_speeds_separate_1x_and_one_fast_recording_warns(tmp_path, run_cli):
    files = []
    for rpm in (3000, 9000, 15000, 21000):
        f = tmp_path / f"r{rpm}.mcap"
        assert run_cli("sim", "generate", "--rpm", str(rpm), "--duration", "2", "-q", "-o", f).exit_code == 0
        files.append(f)
    r = run_cli("runout", "identify", *files, "-o", tmp_path / "multi.json")
    assert r.exit_code == 0 and "warning" not in r.output
    assert_matches_truth(phasors(tmp_path / "multi.json"))
    r = run_cli("runout", "identify", files[-1], "-o", tmp_path / "one.json")
    assert r.exit_code == 0 and "1X at 21000 rpm also holds the rotor's unbalance response" in r.stderr
    assert_matches_truth(phasors(tmp_path / "one.json"), slice(1, 6))  # above 1X it is right anyway


def test_a_ramp_is_refused(tmp_path, run_cli):
    f = tmp_path / "ramp.mcap"
    assert run_cli("sim", "generate", "--rpm", "0:20000", "--duration", "1", "-q", "-o", f).exit_code == 0
    r = run_cli("runout", "identify", f, "-o", tmp_path / "c.json")
    assert r.exit_code == 2 and "needs a constant speed" in r.output and "Traceback" not in r.output


def test_coefficient_file_is_checked(tmp_path, run_cli):
    f = tmp_path / "slow.mcap"
    run_cli("sim", "generate", "--rpm", "slowroll", "--duration", "4", "-q", "-o", f)
    run_cli("runout", "identify", f, "-o", tmp_path / "c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    doc["runout"]["weights"]["front_x"][0][0] *= 2  # a hand edit
    (tmp_path / "edited.json").write_text(json.dumps(doc))
    with pytest.raises(BadInputError, match="checksum mismatch"):
        Coefficients.load(tmp_path / "edited.json")
    c = Coefficients.load(tmp_path / "c.json")
    c.weights["rear_y"][2][1] = float("nan")
    c.save(tmp_path / "nan.json")
    with pytest.raises(BadInputError, match="not a finite number"):
        Coefficients.load(tmp_path / "nan.json")
    with pytest.raises(BadInputError, match="not an ambdaq coefficient file"):
        (tmp_path / "x.json").write_text('{"format": "other"}')
        Coefficients.load(tmp_path / "x.json")
