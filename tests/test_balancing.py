"""Balancing the rotor (issue 43). Item 1: simulated unbalance you can correct: masses put on the
spindle's balancing planes (``sim generate --trial/--correction``), the unbalance they leave recorded
as the simulator's truth, and the rotor's 1X moved by what the machine's model predicts."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load
from ambdaq.machines.spindle import SPINDLE
from ambdaq.machines.spindle_loop import SpindleLoop

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

RPM = 20000.0
RADIAL = ("front_x", "front_y", "rear_x", "rear_y")


def one_x(path) -> np.ndarray:
    """The rotor's true 1X at each radial bearing axis (m, phasors as the model states them)."""
    rec = load(path, topics=["/truth/position", "/amb/rotor"])
    theta = rec["/amb/rotor"]["angle"]
    x = np.column_stack([rec["/truth/position"][a] for a in RADIAL])
    return harmonic_fit(x, theta, (1, 2, 3, 4, 5, 6))[0]


def true_unbalance(calibration: dict, plane: str) -> complex:
    """The simulator's unbalance on ``plane`` as a recording's calibration states it (``--truth``),
    a phasor in kg m (as BalanceMass.unbalance)."""
    return float(calibration[f"truth.unbalance.{plane}_kg_m"]) * np.exp(
        1j * np.radians(float(calibration[f"truth.unbalance.{plane}_deg"])))


def model_one_x(front: complex, rear: complex) -> np.ndarray:
    """The machine model's 1X at RPM with these unbalances per plane (kg m phasors)."""
    params = dataclasses.replace(SPINDLE, unbalance=(abs(front), abs(rear)),
                                 unbalance_phase=(float(np.angle(front)), float(np.angle(rear))))
    return SpindleLoop(params).unbalance_response(RPM)[:4]


def hsbalance_agrees(saved: dict, out: dict, unit: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """An independent solver, hsbalance (cvxpy's least squares), given the saved influence
    coefficients and the reference vector ``--json`` printed (in ``unit``, ``scale`` per SI unit;
    4 decimals, 2 of a degree: 1e-4 of it), finds each correction ``out`` states within 1 %, the
    bound issue 43 sets (measured: 2e-9 on exact inputs). Returns the coefficients and the vector."""
    import warnings

    from hsbalance.IC_matrix import Alpha
    from hsbalance.model import LeastSquares

    A = np.array(saved["influence_re"]) + 1j * np.array(saved["influence_im"])
    v = np.array([[out["reference"][a][unit] / scale * np.exp(1j * np.radians(out["reference"][a]["deg"]))]
                  for a in out["axes"]])
    alpha = Alpha()
    alpha.add(direct_matrix=A)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the solver's licence notice
        w = LeastSquares(v, alpha).solve().ravel()
    for m in out["correction"]:
        got = m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
        theirs = w[out["planes"].index(m["plane"])]
        assert abs(got - theirs) < 0.01 * abs(theirs), (m, theirs)
    return A, v


def test_a_trial_mass_moves_the_1x_as_the_machines_model_says(run_cli, tmp_path):
    """0.1 g at 90 degrees on the front plane's 30 mm radius (3e-6 kg m, as large as the rotor's own
    unbalance there): the recording states the masses and the unbalance per plane they leave, and the
    rotor's 1X changes by the model's influence of that mass (4.3 um at the front, 1.7 um at the
    rear) within 2 % of it plus 0.02 um (the 1X of a 1 s recording at 20,000 rpm scatters 0.015 um,
    docs/validation.md's apht row; measured here within 0.6 %)."""
    ref, trial = tmp_path / "ref.mcap", tmp_path / "trial.mcap"
    for path, extra in ((ref, ()), (trial, ("--trial", "front:0.1@90"))):
        r = run_cli("sim", "generate", "--rpm", RPM, "--duration", 1, "--truth", "-q", "-o", path, *extra)
        assert r.exit_code == 0, r.output
    cal = load(trial, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
    assert cal["sim.mass.0"] == "front:0.1@90:30"
    own = {p: u * np.exp(1j * ph) for p, u, ph in zip(("front", "rear"), SPINDLE.unbalance, SPINDLE.unbalance_phase)}
    front = own["front"] + 0.1e-3 * 0.03 * 1j
    assert float(cal["truth.unbalance.front_kg_m"]) == pytest.approx(abs(front), rel=1e-12)
    assert float(cal["truth.unbalance.front_deg"]) == pytest.approx(np.degrees(np.angle(front)), abs=1e-9)
    assert float(cal["truth.unbalance.rear_kg_m"]) == pytest.approx(abs(own["rear"]), rel=1e-12)
    measured = one_x(trial) - one_x(ref)
    predicted = model_one_x(front, own["rear"]) - model_one_x(own["front"], own["rear"])
    assert np.all(np.abs(predicted) > 1e-6)  # the mass moves every axis by a micrometre or more
    assert np.all(np.abs(measured - predicted) < 0.02 * np.abs(predicted) + 0.02e-6), (measured, predicted)


@pytest.mark.parametrize("spec, message", [
    ("front:0.1", "PLANE:GRAMS@DEG[:RADIUS_MM]"),
    ("middle:0.1@90", "no plane 'middle' (there is: front, rear)"),
    ("front:-1@90", "the mass and the radius must be above 0"),
    ("front:nan@90", "the mass and the radius must be above 0"),
])
def test_a_bad_mass_is_one_line(run_cli, tmp_path, spec, message):
    r = run_cli("sim", "generate", "--rpm", RPM, "--duration", 0.1, "--trial", spec, "-q", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and message in r.output and not (tmp_path / "x.mcap").exists(), r.output


def test_the_base_motion_rig_has_no_balancing_planes(run_cli, tmp_path):
    r = run_cli("sim", "generate", "--profile", "base-motion", "--duration", 0.1, "--trial", "front:0.1@90", "-q",
                "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "has no balancing planes (the spindle and cone rigs have)" in r.output, r.output


def test_the_cone_rig_is_balanced_by_both_methods(run_cli, tmp_path):
    """Items 1-3 on the cone rig (Jeong et al.'s rotor on two cone-shaped AMBs, planes ``upper`` and
    ``lower`` at its bearings): 15 g mm at 0 degrees and 10 g mm at 120 degrees (``--unbalance``), a
    0.5 g trial mass per plane at 6,000 rpm. The rig's sensors have no runout (the paper models
    none), so the job runs with --no-runout, which warns. Both the influence coefficients and the
    bearing forces (the eight coils' currents through the eddy-current lag, eq. 16) find each
    plane's unbalance within 3 % and 2 degrees (seed 0: within 0.4 % and 0.2 degrees) and within
    3.5 of their stated deviations; the corrections leave at most 10 % of it. A spindle recording
    read with --machine cone is refused: the cone model would see no motion on the spindle's axes."""
    import json

    def generate(name, *extra):
        path = tmp_path / f"{name}.mcap"
        r = run_cli("sim", "generate", "--profile", "cone", "--rpm", 6000, "--duration", 1, "--truth",
                    "--unbalance", "1.5e-5:1e-5:120", "-q", "-o", path, *extra)
        assert r.exit_code == 0, r.output
        return path

    ref, upper, lower = generate("ref"), generate("t_up", "--trial", "upper:0.5@0"), generate("t_lo", "--trial", "lower:0.5@0")
    cal = load(ref, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
    truth = {p: true_unbalance(cal, p) for p in ("upper", "lower")}
    assert truth["upper"] == pytest.approx(1.5e-5) and truth["lower"] == pytest.approx(1e-5 * np.exp(2j * np.pi / 3))
    assert load(upper, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]["sim.mass.0"] == "upper:0.5@0:25"
    influence = run_cli("balance", "influence", ref, upper, lower, "--mass", "upper:0.5@0", "--mass", "lower:0.5@0",
                        "--machine", "cone", "--no-runout", "--max-rpm", 6000, "--json")
    forces = run_cli("balance", "forces", ref, "--machine", "cone", "--no-runout", "--max-rpm", 6000, "--json")
    for r in (influence, forces):
        assert r.exit_code == 0, r.output
        assert "warning: --no-runout" in r.stderr, r.stderr
        out = json.loads(r.stdout)
        for plane, u in truth.items():
            fix = sum(m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
                      for m in out["correction"] if m["plane"] == plane)
            assert abs(abs(fix / u) - 1) < 0.03 and abs(np.degrees(np.angle(-fix / u))) < 2, (plane, fix, u)
            assert abs(u + fix) <= 0.10 * abs(u)
            std = (out["correction_std_g_mm"][plane] if "correction_std_g_mm" in out
                   else out["unbalance_estimated"][plane]["std_g_mm"]) * 1e-6
            assert abs(u + fix) < 3.5 * std, (plane, abs(u + fix), std)
    r = run_cli("sim", "generate", "--rpm", 6000, "--duration", 0.3, "-q", "-o", tmp_path / "spindle.mcap")
    assert r.exit_code == 0, r.output
    r = run_cli("balance", "forces", tmp_path / "spindle.mcap", "--machine", "cone", "--no-runout")
    assert r.exit_code == 2 and "is --machine cone this recording's machine?" in r.output, r.output
    r = run_cli("balance", "forces", ref, "--machine", "cone")
    assert r.exit_code == 2 and "--coefficients FILE), or --no-runout" in r.output, r.output
    # the cone's recording with the spindle's model (the default) and a spindle's runout file: the
    # machine is what is wrong, and that is said (it said the file had no runout for y1 ... z2)
    slow = tmp_path / "slow.mcap"
    assert run_cli("sim", "generate", "--rpm", "slowroll", "--duration", 1, "-q", "-o", slow).exit_code == 0
    assert run_cli("runout", "identify", slow, "-o", tmp_path / "coef.json").exit_code == 0
    r = run_cli("balance", "forces", ref, "--coefficients", tmp_path / "coef.json")
    assert r.exit_code == 2 and "is --machine spindle this recording's machine?" in r.output, r.output


@pytest.fixture
def runout_coefficients(build_once) -> Path:
    """The runout of the simulated spindle from a 4 s slow roll (docs/balancing.md's first step),
    identified once per run and shared by every balancing job here: the coefficient file."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    def build(d: Path) -> None:
        for args in (("sim", "generate", "--rpm", "slowroll", "--duration", "4", "-q", "-o", str(d / "slow.mcap")),
                     ("runout", "identify", str(d / "slow.mcap"), "-o", str(d / "coef.json"))):
            r = CliRunner().invoke(cli, list(args))
            assert r.exit_code == 0, r.output

    return build_once("balancing-runout", build) / "coef.json"


def test_one_influence_coefficient_step_removes_the_unbalance(run_cli, tmp_path, runout_coefficients):
    """ISO 21940-13 on the simulated spindle at 20,000 rpm: the runout from a slow roll, a reference
    run, a 0.1 g trial mass on each plane in turn; balance influence gives a correction mass per
    plane within 10 % and 10 degrees of the one that cancels the rotor's own unbalance (the truth:
    its negative), and with it on the rotor's unbalance is at most 10 % of what it was."""
    import json

    def generate(name, *extra, rpm=RPM, seconds=1.0):
        path = tmp_path / f"{name}.mcap"
        r = run_cli("sim", "generate", "--rpm", rpm, "--duration", seconds, "--truth", "-q", "-o", path, *extra)
        assert r.exit_code == 0, r.output
        return path

    coef = runout_coefficients
    ref = generate("ref")
    front, rear = generate("t_front", "--trial", "front:0.1@0"), generate("t_rear", "--trial", "rear:0.1@0")
    r = run_cli("balance", "influence", ref, front, rear, "--mass", "front:0.1@0", "--mass", "rear:0.1@0",
                "--coefficients", coef, "--max-rpm", 60000, "-o", tmp_path / "infl.json", "--json",
                "--record", tmp_path / "job.json", "--plot", tmp_path / "job.png")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    # the sealed record: each run with its role and hash, the coefficient file, what --json printed
    from ambdaq.documents.coefficients import file_sha256
    from ambdaq.documents.sealed import read_sealed

    record = read_sealed(tmp_path / "job.json", "ambdaq.balancing_record", 1, "balancing record")
    assert [(run["role"], run["file"], run["sha256"]) for run in record["runs"]] == [
        ("reference", "ref.mcap", file_sha256(ref)), ("trial front:0.1@0:30", "t_front.mcap", file_sha256(front)),
        ("trial rear:0.1@0:30", "t_rear.mcap", file_sha256(rear))]
    assert record["runout_coefficients"]["sha256"] == file_sha256(coef)
    assert record["result"] == out and record["machine"] == "spindle" and record["influence_file"] is None
    assert (tmp_path / "job.png").stat().st_size > 30_000
    # an independent solver, hsbalance, on the saved coefficients: the same correction within 1 %
    A, v = hsbalance_agrees(json.loads((tmp_path / "infl.json").read_text()), out, "um", 1e6)
    own = {p: u * np.exp(1j * ph) for p, u, ph in zip(("front", "rear"), SPINDLE.unbalance, SPINDLE.unbalance_phase)}
    for m in out["correction"]:
        got = m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
        want = -own[m["plane"]]
        assert abs(abs(got) / abs(want) - 1) < 0.10, (m, abs(want))
        assert abs(np.degrees(np.angle(got / want))) < 10.0, (m, np.degrees(np.angle(want)))
    fixed = generate("fixed", *[x for m in out["correction"] for x in
                                ("--correction", f"{m['plane']}:{m['grams']}@{m['deg']}:{m['radius_mm']}")])
    # in 12 holes per plane: each correction split between the two holes either side of its angle,
    # the same vector per plane (to the JSON's 4 decimals of a gram)
    r = run_cli("balance", "influence", ref, front, rear, "--mass", "front:0.1@0", "--mass", "rear:0.1@0",
                "--coefficients", coef, "--holes", "12", "--json")
    assert r.exit_code == 0, r.output
    split = json.loads(r.stdout)["correction"]
    assert all(m["deg"] % 30 == 0 for m in split) and len(split) <= 4, split
    for plane in ("front", "rear"):
        whole = sum(m["grams"] * np.exp(1j * np.radians(m["deg"])) for m in out["correction"] if m["plane"] == plane)
        parts = sum(m["grams"] * np.exp(1j * np.radians(m["deg"])) for m in split if m["plane"] == plane)
        assert abs(parts - whole) < 3e-4, (plane, split, out["correction"])
    # no mass above 0.05 g (both planes need more): each plane's at most that, and the correction the
    # best within it: better than each plane's cut back to 0.05 g, and than 4,000 other corrections
    # within the limits around it (angles +-15 deg, magnitudes 80-100 %), to the JSON's 4 decimals
    r = run_cli("balance", "influence", ref, front, rear, "--mass", "front:0.1@0", "--mass", "rear:0.1@0",
                "--coefficients", coef, "--max-grams", "0.05", "--json")
    assert r.exit_code == 0, r.output
    held = json.loads(r.stdout)
    assert held["limited_by_max_grams"] == ["front", "rear"] and all(m["grams"] <= 0.05 for m in held["correction"])

    def left(masses) -> float:  # the 1X a correction leaves, um RMS over the axes, by the saved coefficients
        u = np.array([sum(g * 1e-6 * 30 * np.exp(1j * np.radians(d)) for p, g, d in masses if p == plane)
                      for plane in out["planes"]])
        return float(np.linalg.norm(v[:, 0] + A @ u)) * 1e6

    best = left([(m["plane"], m["grams"], m["deg"]) for m in held["correction"]])
    assert best == pytest.approx(np.linalg.norm([x["um"] for x in held["predicted_residual"].values()]), rel=1e-3)
    cut = left([(m["plane"], min(m["grams"], 0.05), m["deg"]) for m in out["correction"]])
    rng = np.random.default_rng(0)
    others = [left([(m["plane"], m["grams"] * rng.uniform(0.8, 1.0), m["deg"] + rng.uniform(-15, 15))
                    for m in held["correction"]]) for _ in range(4000)]
    assert best < cut and best <= min(others) * (1 + 1e-3), (best, cut, min(others))
    # the unbalance the correction leaves, as the simulator states it: at most 10 % of each plane's
    cal = load(fixed, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
    for plane in ("front", "rear"):
        assert float(cal[f"truth.unbalance.{plane}_kg_m"]) <= 0.10 * abs(own[plane]), (plane, cal)
    # the balance grade (ISO 21940-11 at 60,000 rpm) before and after, each against the simulator's
    # truth within 3 of its stated deviations (seed 0: 7.15 +- 0.12 for 7.17 mm/s, G16; after, 0.024
    # +- 0.12 for 0.047 mm/s, G0.4)
    def truth_grade(path):
        c = load(path, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
        u = float(c["truth.unbalance.front_kg_m"]) + float(c["truth.unbalance.rear_kg_m"])
        return u / float(c["rotor.mass_kg"]) * 60000 * 2 * np.pi / 60 * 1e3

    assert abs(out["grade_mm_s"] - truth_grade(ref)) < 3 * out["grade_std_mm_s"], out
    r = run_cli("balance", "correct", fixed, "--influence", tmp_path / "infl.json", "--coefficients",
                coef, "--max-rpm", 60000, "--json", "--record", tmp_path / "after.json")
    assert r.exit_code == 0, r.output
    after = json.loads(r.stdout)
    record = read_sealed(tmp_path / "after.json", "ambdaq.balancing_record", 1, "balancing record")
    assert [run["role"] for run in record["runs"]] == ["run"] and record["result"] == after
    assert record["influence_file"] == {"file": "infl.json", "sha256": file_sha256(tmp_path / "infl.json")}
    # a record is not replaced without --overwrite, and that is said before any work
    r = run_cli("balance", "correct", fixed, "--influence", tmp_path / "infl.json", "--coefficients",
                coef, "--record", tmp_path / "after.json")
    assert r.exit_code == 2 and "after.json exists" in r.output, r.output
    assert abs(after["grade_mm_s"] - truth_grade(fixed)) < 3 * after["grade_std_mm_s"], after
    assert after["grade_mm_s"] < 0.1 * out["grade_mm_s"] and after["grade"] == "G0.4", after
    # ISO 21940-14's acceptance against a grade asked for: the residual with its error (twice its
    # deviation) within G1 after balancing (the truth, 0.096 mm/s, is); against G0.1 the error alone
    # (0.27 mm/s) is beyond it, so not after balancing, while a user's check (within G0.1 and the
    # error) would take it; a grade without the speed it is judged at is refused
    def judged(grade):
        r = run_cli("balance", "correct", fixed, "--influence", tmp_path / "infl.json", "--coefficients", coef,
                    "--max-rpm", 60000, "--grade", grade, "--json")
        assert r.exit_code == 0, r.output
        return json.loads(r.stdout)["acceptance"]

    g1, g01 = judged("G1"), judged("0.1")
    # (the error from the unrounded deviation, the JSON's from the rounded one: 1e-3 apart at most)
    assert g1 == {"target": "G1", "permissible_mm_s": 1.0, "error_mm_s": pytest.approx(2 * after["grade_std_mm_s"], abs=2e-3),
                  "after_balancing": True, "check": True} and truth_grade(fixed) <= 1.0, g1
    assert (g01["after_balancing"], g01["check"]) == (False, True), g01
    r = run_cli("balance", "correct", fixed, "--influence", tmp_path / "infl.json", "--coefficients", coef,
                "--grade", "G1")
    assert r.exit_code == 2 and "--grade judges the grade at the machine's maximum service speed" in r.output
    # and what is left of the rotor's 1X is what the sensor runout drives through the loop (33 um
    # at 20,000 rpm, ten times the unbalance's): balancing cannot take that out, the feedforward does
    runout_only = np.abs(model_one_x(0j, 0j))
    assert np.all(np.abs(np.abs(one_x(fixed)) - runout_only) < 0.1 * np.abs(model_one_x(own["front"], own["rear"])
                                                                          - model_one_x(0j, 0j)) + 0.05e-6)


def test_saved_influence_coefficients_balance_the_next_job_from_one_run(run_cli, tmp_path, runout_coefficients):
    """The influence coefficients saved by one job (balance influence -o) and the next job on the
    same machine: the rotor has changed (0.05 g more at 45 degrees on the front plane), one run,
    balance correct: the correction cancels the rotor's whole unbalance within 10 % and 10 degrees.
    A changed file or a run at another speed is refused in one line."""
    import json

    def generate(name, *extra, rpm=RPM, seconds=1.0):
        path = tmp_path / f"{name}.mcap"
        assert run_cli("sim", "generate", "--rpm", rpm, "--duration", seconds, "-q", "-o", path, *extra).exit_code == 0
        return path

    coef = runout_coefficients
    runs = [generate("ref"), generate("tf", "--trial", "front:0.1@0"), generate("tr", "--trial", "rear:0.1@0")]
    infl = tmp_path / "influence.json"
    r = run_cli("balance", "influence", *runs, "--mass", "front:0.1@0", "--mass", "rear:0.1@0", "--coefficients", coef,
                "-o", infl)
    assert r.exit_code == 0 and infl.exists(), r.output
    today = generate("today", "--correction", "front:0.05@45")
    r = run_cli("balance", "correct", today, "--influence", infl, "--coefficients", coef, "--json")
    assert r.exit_code == 0, r.output
    own = {p: u * np.exp(1j * ph) for p, u, ph in zip(("front", "rear"), SPINDLE.unbalance, SPINDLE.unbalance_phase)}
    own["front"] += 0.05e-3 * 0.03 * np.exp(1j * np.radians(45))
    for m in json.loads(r.stdout)["correction"]:
        got = m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
        assert abs(abs(got) / abs(own[m["plane"]]) - 1) < 0.10, m
        assert abs(np.degrees(np.angle(-got / own[m["plane"]]))) < 10.0, m
    # the same job by the bearings' forces (issue 43, item 2: influence coefficients of the forces
    # where the currents are recorded): N per g mm, saved as such, the same correction within 10 %
    # and 10 degrees (the validation campaign measures how often: docs/validation.md)
    forces = tmp_path / "influence_forces.json"
    r = run_cli("balance", "influence", *runs, "--mass", "front:0.1@0", "--mass", "rear:0.1@0", "--coefficients", coef,
                "--signal", "forces", "-o", forces, "--json", "--plot", tmp_path / "forces.png")
    assert r.exit_code == 0, r.output
    job = json.loads(r.stdout)
    assert job["signal"] == "forces" and "influence_um_per_g_mm" not in job
    assert all(v["N"] > 1.0 for row in job["influence_N_per_g_mm"].values() for v in row.values())  # N, not um
    saved = json.loads(forces.read_text())
    assert saved["signal"] == "forces" and "noise_N" in saved
    # the independent solver on the forces' coefficients (N per kg m): the same correction within 1 %
    hsbalance_agrees(saved, job, "N", 1.0)
    # balance correct reads the runs as the file's coefficients were measured: the forces here
    r = run_cli("balance", "correct", today, "--influence", forces, "--coefficients", coef, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["signal"] == "forces"
    for m in json.loads(r.stdout)["correction"]:
        got = m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
        assert abs(abs(got) / abs(own[m["plane"]]) - 1) < 0.10, m
        assert abs(np.degrees(np.angle(-got / own[m["plane"]]))) < 10.0, m
    # and a file of one signal is never applied to vectors of the other (the workflow's own check)
    from ambdaq.errors import BadInputError
    from ambdaq.workflows.balancing import correct_with, run_vector

    with pytest.raises(BadInputError, match="influence coefficients of the forces; the runs' vectors are of the gaps"):
        correct_with(forces, [run_vector(today, coef)])
    # a file from before the signal was kept holds the gaps' coefficients
    from ambdaq.documents.sealed import read_sealed, write_sealed

    older = read_sealed(infl, "ambdaq.balance_influence", 1, "influence file")
    assert older.pop("signal") == "gaps"
    write_sealed(tmp_path / "older.json", older)
    r = run_cli("balance", "correct", today, "--influence", tmp_path / "older.json", "--coefficients", coef, "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["signal"] == "gaps", r.output
    other = generate("other", rpm=25000.0)
    r = run_cli("balance", "correct", other, "--influence", infl, "--coefficients", coef)
    assert r.exit_code == 2 and "the influence coefficients are of 20,000 rpm" in r.output, r.output
    infl.write_text(infl.read_text().replace('"rpm": 2', '"rpm": 3'))
    r = run_cli("balance", "correct", today, "--influence", infl, "--coefficients", coef)
    assert r.exit_code == 2 and "checksum mismatch" in r.output, r.output


def test_one_least_squares_over_two_speeds(run_cli, tmp_path, runout_coefficients):
    """ISO 21940-13 at several speeds: the reference and the trial runs at 20,000 and at 30,000 rpm,
    one least squares over both speeds' axes; the correction within 10 % and 10 degrees (seed 0:
    0.9 % small and 0.1 % large, within 0.1 degree), its stated deviation below one speed's (more
    equations, the same unknowns), and each row an axis at a speed. The runs' count and speeds are
    checked; the saved coefficients correct the next job from one run at each speed."""
    import json

    def generate(name, rpm, *extra):
        path = tmp_path / f"{name}.mcap"
        assert run_cli("sim", "generate", "--rpm", rpm, "--duration", 1, "-q", "-o", path, *extra).exit_code == 0
        return path

    coef = runout_coefficients
    runs = [generate(f"{kind}{rpm}", rpm, *extra) for rpm in (20000, 30000)
            for kind, extra in (("ref", ()), ("tf", ("--trial", "front:0.1@0")), ("tr", ("--trial", "rear:0.1@0")))]
    masses = ("--mass", "front:0.1@0", "--mass", "rear:0.1@0")
    r = run_cli("balance", "influence", *runs, *masses, "--coefficients", coef, "--max-rpm", 60000, "--json",
                "-o", tmp_path / "two.json", "--record", tmp_path / "job.json")
    assert r.exit_code == 0, r.output
    two = json.loads(r.stdout)
    assert [round(v) for v in two["speeds_rpm"]] == [20000, 30000]
    assert list(two["reference"]) == [f"{a}@{rpm}rpm" for rpm in (20000, 30000)
                                      for a in ("front_x", "front_y", "rear_x", "rear_y")]
    own = {p: u * np.exp(1j * ph) for p, u, ph in zip(("front", "rear"), SPINDLE.unbalance, SPINDLE.unbalance_phase)}
    for m in two["correction"]:
        got = m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
        assert abs(abs(got) / abs(own[m["plane"]]) - 1) < 0.10, m
        assert abs(np.degrees(np.angle(-got / own[m["plane"]]))) < 10.0, m
    one = json.loads(run_cli("balance", "influence", *runs[:3], *masses, "--coefficients", coef, "--max-rpm", 60000,
                             "--json").stdout)
    assert two["grade_std_mm_s"] < one["grade_std_mm_s"], (two["grade_std_mm_s"], one["grade_std_mm_s"])
    from ambdaq.documents.sealed import read_sealed

    record = read_sealed(tmp_path / "job.json", "ambdaq.balancing_record", 1, "balancing record")
    assert [run["file"] for run in record["runs"]] == [p.name for p in runs]
    # five runs for two trial masses; both speeds' runs at one speed
    r = run_cli("balance", "influence", *runs[:5], *masses, "--coefficients", coef)
    assert r.exit_code == 2 and "5 runs and 2 --mass: per speed, a reference and one trial run" in r.output, r.output
    r = run_cli("balance", "influence", *runs[:3], *runs[:3], *masses, "--coefficients", coef)
    assert r.exit_code == 2 and "two references ran at one speed" in r.output, r.output
    # the next job from the saved coefficients: one run at each speed, in any order (here the two
    # references again: the same correction as the job's); one run for two speeds is refused
    r = run_cli("balance", "correct", runs[3], runs[0], "--influence", tmp_path / "two.json", "--coefficients", coef,
                "--json")
    assert r.exit_code == 0, r.output
    again = json.loads(r.stdout)
    assert again["correction"] == two["correction"] and again["speeds_rpm"] == two["speeds_rpm"], (again, two)
    r = run_cli("balance", "correct", runs[0], "--influence", tmp_path / "two.json", "--coefficients", coef)
    assert r.exit_code == 2 and "1 run for influence coefficients of 20,000 and 30,000 rpm: one run at each speed" \
        in r.output, r.output


def test_influence_coefficients_with_the_feedforward_running(run_cli, tmp_path, runout_coefficients):
    """The job with the controller's feedforward on (Ro et al.'s LMS, adapting from each run's
    start for about 0.5 s): its loop follows neither the runout nor the rotor at 1X, the runout
    drives nothing, and the settled windows' 1X is the rotor's unbalance response. A correction
    within 10 % and 10 degrees, leaving at most 10 % of the unbalance (seed 0: 0.6 % small and 0.2 %
    large, within 0.1 degree). Runs of one job share one loop; an influence file is for its loop only; a
    run too short to settle is refused, not averaged over the transient."""
    import json

    def generate(name, *extra, ff="lms", seconds=3.0):
        path = tmp_path / f"{name}.mcap"
        r = run_cli("sim", "generate", "--rpm", RPM, "--duration", seconds, "--ff", ff, "--truth", "-q", "-o", path,
                    *extra)
        assert r.exit_code == 0, r.output
        return path

    coef = runout_coefficients
    ref, front, rear = generate("ref"), generate("tf", "--trial", "front:0.1@0"), generate("tr", "--trial", "rear:0.1@0")
    masses = ("--mass", "front:0.1@0", "--mass", "rear:0.1@0")
    r = run_cli("balance", "influence", ref, front, rear, *masses, "--coefficients", coef, "-o", tmp_path / "infl.json",
                "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["feedforward"] is True
    own = {p: u * np.exp(1j * ph) for p, u, ph in zip(("front", "rear"), SPINDLE.unbalance, SPINDLE.unbalance_phase)}
    for m in out["correction"]:
        got = m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
        assert abs(abs(got) / abs(own[m["plane"]]) - 1) < 0.10, m
        assert abs(np.degrees(np.angle(-got / own[m["plane"]]))) < 10.0, m
    fixed = generate("fixed", *[x for m in out["correction"] for x in
                                ("--correction", f"{m['plane']}:{m['grams']}@{m['deg']}:{m['radius_mm']}")])
    cal = load(fixed, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
    for plane in ("front", "rear"):
        assert float(cal[f"truth.unbalance.{plane}_kg_m"]) <= 0.10 * abs(own[plane]), (plane, cal)
    # one loop per job, and per influence file
    off = generate("off", ff="off", seconds=1.0)
    r = run_cli("balance", "influence", off, front, rear, *masses, "--coefficients", coef)
    assert r.exit_code == 2 and "tf.mcap ran with the feedforward on, the reference with it off" in r.output, r.output
    r = run_cli("balance", "correct", off, "--influence", tmp_path / "infl.json", "--coefficients", coef)
    assert r.exit_code == 2 and "of the loop with it on" in r.output, r.output
    # one second: the feedforward still adapting for half of it, the rest not twice the settling
    short = generate("short", seconds=1.0)
    r = run_cli("balance", "correct", short, "--influence", tmp_path / "infl.json", "--coefficients", coef)
    assert r.exit_code == 2 and "the feedforward was adapting; record longer" in r.output, r.output


@pytest.mark.parametrize("ff", ["off", "lms"])
def test_the_bearing_forces_give_the_unbalance_without_a_trial_run(run_cli, tmp_path, ff):
    """Issue 43, item 3: one run at 20,000 rpm, the feedforward off or on (its currents are what the
    bearings apply), 0.15 g added at 200 degrees on the front plane: balance forces finds each
    plane's unbalance within 10 % and 10 degrees of the simulator's and within 3.5 of its stated
    deviations (circular: beyond it 0.2 % of the time; seed 0, front and rear, off: 0.75 and 1.89, on:
    0.49 and 0.44; within 2.7 % and 2.5 degrees),
    and its correction, put on the rotor, leaves at most 10 % of the unbalance."""
    import json

    run, coef = tmp_path / "run.mcap", tmp_path / "coef.json"
    # the job's own slow roll first (docs/balancing.md, section 1): its runout holds the rotor's
    # response to the unbalance it has now, which balance forces gives back
    for args in (("sim", "generate", "--rpm", "slowroll", "--duration", 4, "--correction", "front:0.15@200", "-q", "-o",
                  tmp_path / "slow.mcap"), ("runout", "identify", tmp_path / "slow.mcap", "-o", coef),
                 ("sim", "generate", "--rpm", RPM, "--duration", 1, "--ff", ff, "--truth", "--correction", "front:0.15@200",
                  "-q", "-o", run)):
        r = run_cli(*args)
        assert r.exit_code == 0, r.output
    r = run_cli("balance", "forces", run, "--coefficients", coef, "--max-rpm", 60000, "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["feedforward"] is (ff == "lms") and out["windows"] >= 16
    cal = load(run, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
    left = {}
    for plane, got in out["unbalance_estimated"].items():
        truth = true_unbalance(cal, plane)
        est = got["g_mm"] * 1e-6 * np.exp(1j * np.radians(got["deg"]))
        assert abs(abs(est) / abs(truth) - 1) < 0.10 and abs(np.degrees(np.angle(est / truth))) < 10.0, (plane, got, truth)
        assert abs(est - truth) < 3.5 * got["std_g_mm"] * 1e-6, (plane, got, abs(est - truth), truth)
        fix = sum(m["grams"] * 1e-3 * m["radius_mm"] * 1e-3 * np.exp(1j * np.radians(m["deg"]))
                  for m in out["correction"] if m["plane"] == plane)
        left[plane] = abs(truth + fix) / abs(truth)
    assert max(left.values()) <= 0.10, left
    # another machine's model: one line
    r = run_cli("balance", "forces", run, "--coefficients", coef, "--machine", "cone")
    assert r.exit_code == 2 and "are not the cone model's" in r.output, r.output


def test_the_grade_after_a_force_correction_gives_back_the_slow_rolls_part(run_cli, tmp_path, runout_coefficients):
    """The check run after a correction from the bearing forces, feedforward on: the runout
    coefficients' slow roll was recorded with the rotor's unbalance before, and their 1X holds the
    rotor's response to it (about 1 % of it, read as unbalance now). With ``--before`` the record
    of the first run, that part is given back from the record's unbalance and the grade's 95 %
    interval holds the simulator's; without, it is given back as this run's own unbalance, which
    the correction has changed, and the interval misses it; a record made with other runout
    coefficients is refused."""
    import json

    from ambdaq.workflows.balancing import balance_grade

    coef, before, after = runout_coefficients, tmp_path / "before.mcap", tmp_path / "after.mcap"
    assert run_cli("sim", "generate", "--rpm", RPM, "--duration", 1, "--ff", "lms", "--truth", "-q", "-o",
                   before).exit_code == 0
    r = run_cli("balance", "forces", before, "--coefficients", coef, "--max-rpm", 60000, "--record",
                tmp_path / "before.json", "--json")
    assert r.exit_code == 0, r.output
    fix = [f"{m['plane']}:{m['grams']}@{m['deg']}:{m['radius_mm']}" for m in json.loads(r.stdout)["correction"]]
    r = run_cli("sim", "generate", "--rpm", RPM, "--duration", 1, "--ff", "lms", "--truth", "--seed", 2,
                *[a for f in fix for a in ("--correction", f)], "-q", "-o", after)
    assert r.exit_code == 0, r.output
    rec = load(after, topics=["/amb/rotor"])
    cal = rec.metadata["ambdaq.calibration.rig"]
    truth = balance_grade(sum(float(cal[f"truth.unbalance.{p}_kg_m"]) for p in ("front", "rear")),
                          rec.machine.rotor_mass_kg, 60000)
    r = run_cli("balance", "forces", after, "--coefficients", coef, "--max-rpm", 60000, "--before",
                tmp_path / "before.json", "--json")
    assert r.exit_code == 0 and "note:" not in r.stderr, r.output
    got = json.loads(r.stdout)
    assert got["slow_roll_held"]["of"] == "before" and set(got["slow_roll_held"]["planes"]) == {"front", "rear"}
    assert abs(got["grade_mm_s"] - truth) <= 1.96 * got["grade_std_mm_s"], (got["grade_mm_s"], got["grade_std_mm_s"], truth)
    for p, u in got["unbalance_estimated"].items():  # each plane's vector within its 95 % circle (2.45 deviations)
        true = true_unbalance(cal, p) * 1e6
        assert abs(u["g_mm"] * np.exp(1j * np.radians(u["deg"])) - true) <= 2.45 * u["std_g_mm"], (p, u, true)
    # without it the part is given back as this run's own unbalance, and the note says what to do
    r = run_cli("balance", "forces", after, "--coefficients", coef, "--max-rpm", 60000, "--json")
    assert r.exit_code == 0 and "pass --before" in r.stderr, r.output
    assert json.loads(r.stdout)["slow_roll_held"]["of"] == "this run"
    # a record of another runout: refused in one line
    other = tmp_path / "other.json"  # the same slow roll to 5X: another file
    assert run_cli("runout", "identify", coef.parent / "slow.mcap", "--harmonics", 5, "-o", other).exit_code == 0
    r = run_cli("balance", "forces", after, "--coefficients", other, "--before", tmp_path / "before.json")
    assert r.exit_code == 2 and "runout coefficients were not" in r.output, r.output
    # and with no runout taken out there is no slow roll's part to give back
    r = run_cli("balance", "forces", after, "--no-runout", "--before", tmp_path / "before.json")
    assert r.exit_code == 2 and "none to give back" in r.output, r.output


def test_the_grade_predicted_after_a_correction_holds_the_simulators(run_cli, tmp_path, runout_coefficients):
    """ISO 21940-11's grade before and after, predicted and then measured (issue 43, item 4), with
    the correction's own errors counted (ISO 21940-14): ``balance forces --mass-tolerance 0.002
    --angle-tolerance 1`` predicts the grade once its masses are on; the masses then go on within
    those tolerances (1 mg heavier, half a degree back), and the simulator's grade after is within
    the predicted bound; ``--before`` states the prediction beside the grade measured now.
    The bound counts what it is told: with no tolerance it is lower, and with a tenfold angle
    error the predicted bound rises with it (the validation campaign checks the 95 % over 100 jobs
    per row, docs/validation.md)."""
    import json

    from ambdaq.workflows.balancing import balance_grade

    coef, before, after = runout_coefficients, tmp_path / "before.mcap", tmp_path / "after.mcap"
    assert run_cli("sim", "generate", "--rpm", RPM, "--duration", 1, "--truth", "-q", "-o", before).exit_code == 0
    told = ("--mass-tolerance", 0.002, "--angle-tolerance", 1)
    r = run_cli("balance", "forces", before, "--coefficients", coef, "--max-rpm", 60000, *told, "--record",
                tmp_path / "before.json", "--json", "--grade", "G1")
    assert r.exit_code == 0, r.output
    got = json.loads(r.stdout)
    predicted = got["predicted_after"]
    assert predicted["mass_tolerance_g"] == 0.002 and predicted["angle_tolerance_deg"] == 1.0
    assert predicted["within_target"] is (predicted["at_most_mm_s"] <= 1.0)
    assert 0 < predicted["grade_mm_s"] < predicted["at_most_mm_s"] < got["grade_mm_s"] and predicted["improves"]
    fix = [f"{m['plane']}:{m['grams'] + 0.001}@{m['deg'] - 0.5}:{m['radius_mm']}" for m in got["correction"]]
    r = run_cli("sim", "generate", "--rpm", RPM, "--duration", 1, "--truth", "--seed", 2,
                *[a for f in fix for a in ("--correction", f)], "-q", "-o", after)
    assert r.exit_code == 0, r.output
    rec = load(after, topics=["/amb/rotor"])
    cal = rec.metadata["ambdaq.calibration.rig"]
    truth = balance_grade(sum(float(cal[f"truth.unbalance.{p}_kg_m"]) for p in ("front", "rear")),
                          rec.machine.rotor_mass_kg, 60000)
    assert truth <= predicted["at_most_mm_s"], (truth, predicted)
    r = run_cli("balance", "forces", after, "--coefficients", coef, "--max-rpm", 60000, "--before",
                tmp_path / "before.json")
    assert r.exit_code == 0 and "before.json predicted" in r.output and "within the prediction" in r.output, r.output
    # the balanced rotor's own correction is within the noise: predicted not to improve it, said
    assert "not predicted to lower the grade" in r.stderr, r.output
    r = run_cli("balance", "forces", after, "--coefficients", coef, "--max-rpm", 60000, "--before",
                tmp_path / "before.json", "--json")
    b = json.loads(r.stdout)["before"]
    assert b["predicted_after"]["at_most_mm_s"] == predicted["at_most_mm_s"] and b["within_prediction"] is True
    # at another maximum speed the grades are not comparable: said, not compared
    r = run_cli("balance", "forces", after, "--coefficients", coef, "--max-rpm", 30000, "--before",
                tmp_path / "before.json")
    assert r.exit_code == 0 and "give --max-rpm 60000 to compare" in r.output, r.output

    def bound(*tolerance) -> float:
        r = run_cli("balance", "forces", before, "--coefficients", coef, "--max-rpm", 60000, *tolerance, "--json")
        assert r.exit_code == 0, r.output
        return json.loads(r.stdout)["predicted_after"]["at_most_mm_s"]

    assert bound() < predicted["at_most_mm_s"] < bound("--mass-tolerance", 0.002, "--angle-tolerance", 10)


def test_a_slow_rolls_runout_holds_the_unbalance_response_the_rigid_rotor_predicts(run_cli, tmp_path):
    """What balancing gives back (workflows.runout.unbalance_held): a slow roll's 1X runout, as
    runout identify finds it, is the sensors' runout plus the rotor's response to its unbalance at
    800 rpm, which the coil currents do not explain, H(Omega) B U Omega^2 through the recording's
    rigid rotor. With 0.3 g added at 60 degrees on the front plane and 0.6 g at 200 degrees on the
    rear (9 and 18 g mm), the identified 1X is off the simulator's runout beyond the bound runout
    identify states for it, and less the predicted part, within that bound (the bound holds the
    model's own error on slow rolls, docs/coefficients.md; seed 0, 10 s: off by 41-112 nm, bounds
    9.2 and 16.2 nm; 1.4-5.7 nm left)."""
    from ambdaq.documents.coefficients import Coefficients
    from ambdaq.machines.spindle import SPINDLE
    from ambdaq.workflows.runout import runout_phasors, unbalance_held

    slow, coef = tmp_path / "slow.mcap", tmp_path / "coef.json"
    for args in (("sim", "generate", "--rpm", "slowroll", "--duration", 10, "--correction", "front:0.3@60",
                  "--correction", "rear:0.6@200", "--truth", "-q", "-o", slow), ("runout", "identify", slow, "-o", coef)):
        r = run_cli(*args)
        assert r.exit_code == 0, r.output
    rec, c = load(slow), Coefficients.load(coef)
    axes = list(RADIAL)
    found = runout_phasors(c, axes)[c.harmonics.index(1)]
    s, k = SPINDLE.runout_sin_cos()
    runout = (s[:, 0] + 1j * k[:, 0])[:4]  # the simulator's, as harmonic_fit's a sin + b cos -> a + j b
    cal = rec.metadata["ambdaq.calibration.rig"]
    unbalance = np.array([true_unbalance(cal, p) for p in ("front", "rear")])
    bound = np.array([c.source["model_bound_m"][a][0] for a in axes])
    u = np.array([c.source["uncertainty_m"][a][0] for a in axes])
    assert np.all(np.abs(found - runout) > bound), (np.abs(found - runout), bound)
    left = np.abs(found - runout - unbalance_held(c, rec, axes) @ unbalance)
    assert np.all(left <= bound + 3 * u), (left, bound, u)


def test_balance_correct_gives_back_the_slow_roll_of_the_coefficients_it_is_given(run_cli, tmp_path, runout_coefficients):
    """The next job's run, read with the influence job's runout coefficients, gets back the part of
    the job's unbalance their slow roll held (the influence file keeps their SHA-256 and that
    unbalance); read with a new slow roll's, recorded on the rotor as it is now (0.3 g more at 45
    degrees on the front plane), the part of the rotor's own. Either way each plane's unbalance is
    the simulator's within its 95 % circle (2.45 of its deviations), and the front plane's within
    0.6 %: the slow roll holds about 1 % of an unbalance, and giving back the wrong one (the job's
    for the new slow roll) leaves the front 0.96 % off, where the right one leaves 0.2-0.4 % (seed 0)."""
    import json

    from ambdaq.documents.coefficients import file_sha256

    def generate(name, *extra, rpm=RPM, seconds=1.0):
        path = tmp_path / f"{name}.mcap"
        assert run_cli("sim", "generate", "--rpm", rpm, "--duration", seconds, "--truth", "-q", "-o", path,
                       *extra).exit_code == 0
        return path

    coef, infl = runout_coefficients, tmp_path / "influence.json"
    runs = [generate("ref"), generate("tf", "--trial", "front:0.1@0"), generate("tr", "--trial", "rear:0.1@0")]
    r = run_cli("balance", "influence", *runs, "--mass", "front:0.1@0", "--mass", "rear:0.1@0", "--coefficients", coef,
                "-o", infl)
    assert r.exit_code == 0, r.output
    assert json.loads(infl.read_text())["runout_sha256"] == file_sha256(coef)
    changed = ("--correction", "front:0.3@45")
    today = generate("today", *changed)
    slow, new = generate("slow", *changed, rpm="slowroll", seconds=4), tmp_path / "new.json"
    assert run_cli("runout", "identify", slow, "-o", new).exit_code == 0
    cal = load(today, topics=["/amb/rotor"]).metadata["ambdaq.calibration.rig"]
    for runout in (coef, new):
        r = run_cli("balance", "correct", today, "--influence", infl, "--coefficients", runout, "--json")
        assert r.exit_code == 0, r.output
        out = json.loads(r.stdout)
        for p, u in out["unbalance_estimated"].items():
            true = true_unbalance(cal, p) * 1e6
            got = u["g_mm"] * np.exp(1j * np.radians(u["deg"]))
            assert abs(got - true) <= 2.45 * out["correction_std_g_mm"][p], (runout.name, p, got, true, out)
        front = out["unbalance_estimated"]["front"]
        true = true_unbalance(cal, "front") * 1e6
        assert abs(front["g_mm"] * np.exp(1j * np.radians(front["deg"])) - true) < 0.006 * abs(true), (runout.name, front)
