"""``ambdaq runout identify`` and the coefficient file, against the simulator's ground truth."""

import json

import numpy as np
import pytest

from ambdaq.daq import load
from ambdaq.documents.coefficients import Coefficients
from ambdaq.sim.rigs.spindle import SPINDLE
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


@pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)
def test_over_the_real_drivers(tmp_path, run_cli):
    """sim:// records through the serial controller driver (float32 on the wire): same accuracy.
    A host starved of CPU (a slow CI host beside another worker's processes) can cost the
    in-process rig samples; identify then refuses the recording ("record it again", exit 2), as it
    must, and the test records again as a user would, up to three times."""
    for attempt in range(3):
        rec = tmp_path / f"live{attempt}.mcap"
        assert run_cli("record", "--device", "sim://spindle?can=0", "--rpm", "slowroll", "--duration", "5", "-q",
                       "-o", rec).exit_code == 0
        r = run_cli("runout", "identify", rec, "-o", tmp_path / "coef.json", "--overwrite")
        if r.exit_code == 0 or "record it again" not in r.output:
            break
    assert r.exit_code == 0, r.output
    assert_matches_truth(phasors(tmp_path / "coef.json"))


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
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
    with pytest.raises(BadInputError, match=r"runout\.weights\.rear_y\.2\.1: Input should be a finite number"):
        Coefficients.load(tmp_path / "nan.json")
    with pytest.raises(BadInputError, match="not an ambdaq coefficient file"):
        (tmp_path / "x.json").write_text('{"format": "other"}')
        Coefficients.load(tmp_path / "x.json")


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
def test_report_orbit_after_is_the_true_rotor_motion(tmp_path, run_cli):
    """The report's "after" orbit (sensor minus the identified runout, synthesised at the recorded
    angle) is the rotor's true motion at the sensor, and the report is written."""
    from matplotlib.image import imread

    from ambdaq.analysis.runout import synthesise
    from ambdaq.daq import load

    fast, slow = tmp_path / "fast.mcap", tmp_path / "slow.mcap"
    assert run_cli("sim", "generate", "--rpm", "24000", "--duration", "3", "--truth", "-q", "-o", fast).exit_code == 0
    assert run_cli("sim", "generate", "--rpm", "slowroll", "--duration", "6", "-q", "-o", slow).exit_code == 0
    report = tmp_path / "report.png"
    r = run_cli("runout", "identify", fast, slow, "-o", tmp_path / "coef.json", "--plot", report)
    assert r.exit_code == 0, r.output
    assert imread(report).shape[:2] == (1250, 1560)
    est = phasors(tmp_path / "coef.json")  # (axis, harmonic)
    rec = load(fast, topics=["/amb/gap", "/amb/rotor", "/truth/position", "/truth/runout"])
    th = rec["/amb/rotor"]["angle"]
    for i, a in enumerate(AXES[:4]):
        gap, truth_runout = rec["/amb/gap"][a], rec["/truth/runout"][a]
        removed = gap - synthesise(est[i], list(range(1, 7)), th)
        rms = lambda x: np.sqrt(np.mean(x**2))  # noqa: E731
        # what is left of the runout after taking away the identified one: under 2% of it
        assert rms(removed - (gap - truth_runout)) < 0.02 * rms(truth_runout)


@pytest.fixture(scope="module")
def before_after(tmp_path_factory):
    """30,000 rpm without feedforward, and with Ro et al.'s LMS adapting from zero (4 s each)."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    d = tmp_path_factory.mktemp("check")
    for name, ff in (("before", "off"), ("after", "lms")):
        r = CliRunner().invoke(cli, ["sim", "generate", "--rpm", "30000", "--duration", "4", "--ff", ff, "-q",
                                     "-o", str(d / f"{name}.mcap")])
        assert r.exit_code == 0, r.output
    return d / "before.mcap", d / "after.mcap"


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
def test_check_reports_the_fall_of_the_command_error(before_after, tmp_path, run_cli):
    from ambdaq.daq import load

    before, after = before_after
    r = run_cli("runout", "check", before, after, "--json", "--min-db", "20", "--max-rms", "5",
                "--plot", tmp_path / "check.png")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["failures"] == [] and (tmp_path / "check.png").stat().st_size > 50_000
    # the same figures computed here by projection on exp(-j k theta)
    for path, when in ((before, "before"), (after, "after")):
        rec = load(path, topics=["/amb/error", "/amb/gap", "/amb/rotor"])
        th = rec["/amb/rotor"]["angle"]
        for a in AXES[:4]:
            e = rec["/amb/error"][a]
            row = doc["axes"][a]
            for k in (1, 2):
                amp = 2 * abs(np.mean(e * np.exp(-1j * k * th))) * 1e6
                assert row["harmonics"][k - 1][f"{when}_um"] == pytest.approx(amp, rel=0.02, abs=0.01)
            assert row[f"rms_{when}_um"] == pytest.approx(np.sqrt(np.mean(e**2)) * 1e6, rel=1e-3)
            if when == "after":  # the sensor still carries the runout (plus the rotor's 1X response)
                g1 = 2 * abs(np.mean(rec["/amb/gap"][a] * np.exp(-1j * th))) * 1e6
                assert row["sensor_1x_after_um"] == pytest.approx(g1, rel=0.02) and g1 > 5
    assert all(h["change_db"] < -20 for row in doc["axes"].values() for h in row["harmonics"])


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
def test_check_fails_with_exit_1_when_the_error_did_not_fall_enough(before_after, run_cli):
    before, after = before_after
    r = run_cli("runout", "check", before, after, "--min-db", "60")
    assert r.exit_code == 1
    assert "check failed: front_x 1X fell" in r.stderr and "(< 60 dB)" in r.stderr
    r = run_cli("runout", "check", after, before, "--max-rms", "5")  # swapped: the error grew
    rms = np.sqrt(np.mean(load(before)["/amb/error"]["front_x"] ** 2)) * 1e6  # the recording's own, > 5 um
    assert r.exit_code == 1 and f"front_x RMS {rms:.2f} um after (>= 5 um)" in r.stderr, (rms, r.stderr)


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
def test_runout_identified_at_speed_is_flagged_wherever_it_is_taken_out(run_cli, tmp_path):
    """Coefficients identified at 30,000 rpm hold the unbalance response in their 1X (identify
    says so); every command that takes them out as runout (here apht, iso vibration) says so too,
    in one line; coefficients from a slow roll are not flagged."""
    fast, slow = tmp_path / "fast.mcap", tmp_path / "slow.mcap"
    assert run_cli("sim", "generate", "--rpm", "30000", "--duration", "0.4", "-q", "-o", fast).exit_code == 0
    assert run_cli("sim", "generate", "--rpm", "slowroll", "--duration", "1", "-q", "-o", slow).exit_code == 0
    for rec, coef in ((fast, tmp_path / "at_speed.json"), (slow, tmp_path / "slow.json")):
        assert run_cli("runout", "identify", rec, "-o", coef).exit_code == 0
    said = "its 1X was identified at 30,000 rpm and holds the rotor's unbalance response there"
    r = run_cli("apht", fast, "--coefficients", tmp_path / "at_speed.json", "--window", "0.1")
    assert r.exit_code == 0 and said in r.stderr, r.stderr
    r = run_cli("iso", "vibration", fast, "--coefficients", tmp_path / "at_speed.json", "--cmin", "150")
    assert r.exit_code == 0 and said in r.stderr, r.stderr
    r = run_cli("apht", fast, "--coefficients", tmp_path / "slow.json", "--window", "0.1")
    assert r.exit_code == 0 and "unbalance response" not in r.stderr, r.stderr
    # and each says in one line what taking runout out does to its numbers; without coefficients, not
    means = "runout taken out: these are the rotor's own motion, not what the sensors read"
    assert r.stderr.count(means) == 1
    r = run_cli("runup", fast, "--coefficients", tmp_path / "at_speed.json", "--json")
    assert r.exit_code == 0 and said in r.stderr and r.stderr.count(means) == 1, r.stderr
    assert json.loads(r.stdout)["runout_removed"].startswith(means)
    r = run_cli("iso", "vibration", fast, "--coefficients", tmp_path / "slow.json", "--cmin", "150", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["runout_removed"]["means"].startswith(means), r.stderr
    assert r.stderr.count(means) == 1
    r = run_cli("iso", "vibration", fast, "--cmin", "150")
    assert r.exit_code == 0 and means not in r.stderr
    # the report lists the at-speed file among its open items, as identify warned
    r = run_cli("report", "--before", fast, "--after", fast, "--coefficients", tmp_path / "at_speed.json",
                "-o", tmp_path / "r.html", "--json")
    assert r.exit_code == 0, r.output
    (item,) = [i for i in json.loads(r.stdout)["verdict"]["open_items"] if "unbalance response" in i]
    assert item.startswith("at_speed.json: " + said)
    # the fleet's runout trend of recordings at speed is runout and unbalance together: fleet trend says so
    plant = tmp_path / "plant"
    plant.mkdir()
    (plant / "fast.mcap").write_bytes(fast.read_bytes())
    assert run_cli("fleet", "scan", plant, "-o", tmp_path / "fleet.parquet", "--workers", "1").exit_code == 0
    r = run_cli("fleet", "trend", tmp_path / "fleet.parquet")
    assert r.exit_code == 0 and "the 1X runout of 1 recording at speed (above 2,000 rpm) holds the rotor's " \
        "unbalance response there" in r.stderr, r.stderr
