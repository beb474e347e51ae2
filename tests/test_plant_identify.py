"""``ambdaq plant identify`` (issue 42, item 2): the plant of the flexible rotor measured in closed
loop against the simulator's truth, the discrete plant Cs (zI - Phi)^-1 Gam its kernel steps
(machines/flexible_spindle.py), at standstill and at speed (where the gyroscopic coupling joins
the x and y planes and the unbalance puts its 1X on the gaps)."""

import json

import numpy as np
import pytest

from ambdaq.machines.flexible_spindle import FlexibleLoop
from ambdaq.workflows.plant_identification import load_measurement

AXES = ("front_x", "front_y", "rear_x", "rear_y")


def true_plant(rpm: float, freq_hz: np.ndarray) -> np.ndarray:
    """P(e^{jwh}) from the controller's output (V) to the gaps (m), shape (n, 4, 4)."""
    return FlexibleLoop().plant_response(rpm, freq_hz)


def true_modes() -> dict:
    """The plant's poles at standstill below 4 kHz: the rigid-body modes' unstable real pairs and
    the bending modes, in Hz (the fourth, 2,433 Hz, has a node at the front bearing and at the rear
    sensor: only the elements across the bearings hold it)."""
    poles = FlexibleLoop().plant_poles(0.0)
    rigid = sorted({round(p.real / (2 * np.pi), 3) for p in poles if abs(p.imag) < 1e-6 and p.real > 0})
    bending = sorted({round(abs(p) / (2 * np.pi), 3) for p in poles if p.imag > 0 and -p.real / abs(p) < 0.1})
    return {"rigid_hz": rigid, "bending_hz": [hz for hz in bending if hz < 4000]}


def true_residues() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The levitated rotor's modes at standstill (their frequencies, Hz) and each element's residue
    of each (m/V/s^2): the mode's shape at the output's sensor and at the input's bearing, the
    current gain and the amplifier's gain; the modes of the free rotor with the magnets' negative
    stiffness at the bearings (one plane: x and y are alike at standstill)."""
    loop = FlexibleLoop()
    axes = loop.params.axes
    stiffness = loop._stiff.copy()
    for i in (0, 2):  # front_x and rear_x: the x plane's bearings
        stiffness -= axes[i].kx * np.outer(loop._at_bearing[i], loop._at_bearing[i])
    w2, shapes = np.linalg.eigh(stiffness)
    gain = axes[0].ki * axes[0].amp_gain
    out = {}
    for out_name, oi in (("front", 0), ("rear", 2)):
        for in_name, ii in (("front", 0), ("rear", 2)):
            for plane in "xy":
                label = f"{out_name}_{plane}" if out_name == in_name else f"{out_name}_{plane}<-{in_name}_{plane}"
                out[label] = (loop._at_sensor[oi] @ shapes) * (loop._at_bearing[ii] @ shapes) * gain
    return np.sqrt(np.abs(w2)) / (2 * np.pi), out


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
@pytest.mark.parametrize("rpm", [0, 20000])
def test_the_plant_measured_in_closed_loop_is_the_simulators_within_its_stated_error(rpm, run_cli, tmp_path):
    """Four runs of 4 s, 2 um RMS of white noise at one axis's summing point each (sim generate,
    seed 5), 5 Hz: on the diagonal, where the coherence is 0.9 or more, the measured plant is the
    true one within 4 % (median; 1.5-2.5 % measured over seeds 5 and 6 at both speeds), within
    twice its stated random error at 90 % of the points or more (92-97 % measured at seed 5; 98 %
    for an exactly stated circular error), and its error's RMS at most 1.4 times the stated one, the
    per-axis bound issue 39 sets for a stated uncertainty (1.05-1.25 measured per axis at seed 5;
    1.13-1.23 when the errors of the gap's and the controller output's responses were taken as
    independent, which they are not: one loop's noise moves both)."""
    runs = []
    for axis in AXES:
        path = tmp_path / f"run_{axis}.mcap"
        r = run_cli("sim", "generate", "--profile", "flexible", "--rpm", str(rpm), "--excite", f"{axis}:2",
                    "--duration", "4", "--seed", "5", "-q", "-o", path)
        assert r.exit_code == 0, r.output
        runs.append(path)
    out = tmp_path / "plant.json"
    figure = () if rpm else ("--plot", tmp_path / "plant.png")  # drawn once, at standstill
    r = run_cli("plant", "identify", *runs, "--resolution", "5", "-o", out, "--json", *figure)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["axes"] == list(AXES) and abs(summary["speed_rpm"] - rpm) < 1
    assert summary["estimator"].startswith("joint input-output") and len(summary["sources"]) == 4
    measured = load_measurement(out)
    truth = true_plant(float(rpm), measured.freq_hz)
    for i, axis in enumerate(AXES):
        good = measured.plant.coherence[:, i, i] >= 0.9
        assert good.sum() > 50, (axis, good.sum())
        p, t, s = measured.plant.response[good, i, i], truth[good, i, i], measured.plant.sigma[good, i, i]
        normalised = np.abs(p - t) / s
        assert np.median(np.abs(p / t - 1)) < 0.04, axis
        assert np.mean(normalised < 2) >= 0.9 and np.sqrt(np.mean(normalised**2)) < 1.4, (axis, np.mean(normalised < 2))
    assert rpm or (tmp_path / "plant.png").stat().st_size > 10_000

    # item 3: the parametric model of every element, its poles shared
    r = run_cli("plant", "fit", out, "-o", tmp_path / "model.json", "--json", "--plot", tmp_path / "fit.png")
    if rpm:  # at speed the gyroscopic modes need complex modal gains: refused, not a wrong model
        assert r.exit_code == 2 and "the x and y planes reach each other" in r.output, r.output
        assert "fit a standstill measurement" in r.output and not (tmp_path / "model.json").exists()
        return
    assert r.exit_code == 0, r.output
    fitted = json.loads(r.stdout)
    # the deviations say what they hold
    assert "window's bias taken out" in fitted["std_holds"] and "RESOLUTION_FLOOR" in fitted["std_holds"]
    got = {k: (v["value"], v["std"]) for k, v in fitted["parameters"].items()}
    truth = true_modes()
    # each bending mode's damping is stated no better than the frequency step leaves it (5 Hz: the
    # first mode, 3.9 Hz wide, 8 % of its damping; the validation campaign measured the need)
    for k, hz in enumerate(truth["bending_hz"], 1):
        floor = 0.05 * (5.0 / (2 * 0.005 * hz)) ** 2 * 0.005
        # 0.9: the floor here is the true damping's, the
        # fit's (within 4 % of it above) sets the file's, and the JSON keeps 3 digits
        assert got[f"mode{k}_zeta"][1] >= 0.9 * floor, (k, got[f"mode{k}_zeta"], floor)
    # the diagonal and the elements across each plane's bearings; the x-y elements hold only noise
    assert sorted(fitted["responses"]) == sorted([*AXES, "front_x<-rear_x", "rear_x<-front_x", "front_y<-rear_y",
                                                  "rear_y<-front_y"])
    assert sum(k.endswith("_hz") and k.startswith("mode") for k in got) == len(truth["bending_hz"]) == 5
    # at 5 Hz resolution, seed 5, the window's bias taken out: bending modes within 0.01 % and their
    # damping within 4 %, the rigid-body poles within 0.6 %, the amplifier within 1 % (before the
    # bias was taken out, over seeds 1-3 and 5: 0.07 %, 1 % low to 11 % high, 5 %, 1 %): the bounds
    # are those measured before, which issue 42 asks (1 % and 20 %) and the measurement now holds
    # with a margin
    for k, hz in enumerate(truth["bending_hz"], 1):
        assert abs(got[f"mode{k}_hz"][0] / hz - 1) < 0.001, (k, got[f"mode{k}_hz"], hz)
        assert abs(got[f"mode{k}_zeta"][0] / 0.005 - 1) < 0.15, (k, got[f"mode{k}_zeta"])
    for k, hz in enumerate(truth["rigid_hz"], 1):
        assert abs(got[f"rigid{k}_hz"][0] / hz - 1) < 0.06, (k, got[f"rigid{k}_hz"], hz)
    assert abs(got["amplifier_hz"][0] / 2500 - 1) < 0.03 and abs(got["amplifier_zeta"][0] / 0.8 - 1) < 0.03
    assert all(std > 0 for _, std in got.values())
    # and each pole is the machine's within three of its stated deviations: the fit takes the
    # window's bias out (by the first model seen through the measured loop) and states the
    # covariance the elements share (one run's noise reaches every element of its plane). Without
    # the two, the second mode was 5.8 deviations low here (this test failed), and the validation
    # campaign's 95 % intervals held the frequencies in 75 % of runs; seed 5 now: modes 1-4 within 0.9
    poles = {f"mode{k}_hz": hz for k, hz in enumerate(truth["bending_hz"], 1)}
    poles.update({f"rigid{k}_hz": hz for k, hz in enumerate(truth["rigid_hz"], 1)})
    z = {name: (got[name][0] - hz) / got[name][1] for name, hz in poles.items()}
    assert max(abs(v) for v in z.values()) < 3, z
    # every stated residue is the rotor's own within its deviation (seed 5: RMS 0.67 deviations, the
    # largest 2.1; 1.3 and 4.0 before the window's bias was taken out); a residue of a mode above an element's band
    # is not stated (the rear sensor's elements are trusted to about 900 Hz: modes 3-5 are in their
    # residual; fitted, they were +6,459 and -10,098 for -0.3 and +0.7, with deviations of 0.5)
    hz, truth = true_residues()
    z = []
    for name, (value, std) in got.items():
        if name.endswith("_residue"):
            label, mode = name.rsplit(".", 1)
            nearest = int(np.argmin(np.abs(hz - got[mode.removesuffix("_residue") + "_hz"][0])))
            z.append((value - truth[label][nearest]) / std)
    z = np.array(z)
    assert len(z) >= 40 and np.abs(z).max() < 5 and np.sqrt(np.mean(z**2)) < 1.6, z
    for element in ("rear_x", "rear_y", "rear_x<-front_x", "rear_y<-front_y"):
        assert f"{element}.mode2_residue" in got and f"{element}.mode3_residue" not in got, element
        assert f"{element}.residual" in got
    # one shape per mode: each mode's residues over a plane's two bearings are c_i b_j (rank one),
    # imposed on the fit where the plane's four elements hold the mode (two rigid-body modes and the
    # first two bending modes, per plane: eight constraints). The rear sensor sits near the first
    # bending mode's node: its residue alone was 4.4 and 18.9 % off (x, y; stated 7.8 and 18 %),
    # with the three other elements' 3.4 and 2.4 % (stated 2.7 %); 5 %: the stated deviation's twice
    shapes = fitted["mode_shapes"]
    assert shapes["imposed"] and shapes["constraints"] == 8 and shapes["wald_chi2"] <= shapes["limit"], shapes
    first = int(np.argmin(np.abs(hz - got["mode1_hz"][0])))
    for element in ("rear_x", "rear_y"):
        value, std = got[f"{element}.mode1_residue"]
        assert abs(value / truth[element][first] - 1) < 0.05 and std < 0.04 * abs(value), (element, value, std)
    # a plant whose elements are not one shape per mode (the rear's response to the front scaled by
    # 1.3, as an unmodelled path between the bearings would make it): the test rejects the
    # constraints, the fit states each element on its own and says so
    from dataclasses import replace

    measured = load_measurement(out)
    skewed = measured.plant.response.copy()
    skewed[:, measured.axes.index("rear_x"), measured.axes.index("front_x")] *= 1.3
    replace(measured, plant=replace(measured.plant, response=skewed)).save(tmp_path / "skewed.json")
    r = run_cli("plant", "fit", tmp_path / "skewed.json", "-o", tmp_path / "skewed_model.json", "--json")
    assert r.exit_code == 0, r.output
    shapes = json.loads(r.stdout)["mode_shapes"]
    assert not shapes["imposed"] and shapes["wald_chi2"] > shapes["limit"], shapes
    assert "not one shape per mode" in r.stderr, r.stderr

    # the bearings' actuator gain ki ka and negative stiffness kx, fitted with the rotor's model
    # (plant gains), and ka and ki apart from the coil currents the runs recorded: the machine's
    # own (the simulator's truth) within 5 %, the bound issue 42 sets, and within 3 of their stated
    # deviations (seed 5: within 0.5 %, 0.5 deviations; ka within 5e-5 and 0.5 of its deviation)
    r = run_cli("plant", "gains", out, "--machine", "flexible", "--json")
    assert r.exit_code == 0, r.output
    gains = json.loads(r.stdout)["parameters"]
    assert sorted(gains) == ["front_ka", "front_ki", "front_ki_ka", "front_kx", "rear_ka", "rear_ki", "rear_ki_ka",
                             "rear_kx"]
    for name, row in gains.items():
        assert abs(row["value"] / row["machine"] - 1) < 0.05, (name, row)
        assert abs(row["value"] - row["machine"]) < 3 * row["std"], (name, row)
    # from a machine's data 20-30 % off (a datasheet's ki, a larger gap's kx) the same gains: the
    # measurement decides them, not the start (to 1e-4, the least-squares' tolerance)
    from ambdaq.machines.flexible_spindle import FLEXIBLE
    from ambdaq.workflows.bearing_gains import NAMES, fit_bearing_gains, nominal

    measured = load_measurement(out)
    off = fit_bearing_gains(measured, FLEXIBLE, "flexible", start=nominal(FLEXIBLE) * [0.75, 1.3, 1.25, 0.8])
    np.testing.assert_allclose(off.values, [gains[name]["value"] for name in NAMES], rtol=1e-4)
    # the other rotor's model does not reach this measurement: refused, not wrong gains
    r = run_cli("plant", "gains", out, "--machine", "flexible-long")
    assert r.exit_code == 2 and "does not reach the measurement" in r.output, r.output


@pytest.mark.offline  # no device, no wall clock (tests/scheduling.py)
def test_the_model_fitted_to_the_machines_own_plant_returns_its_poles():
    """The model against the plant it models, without noise: the flexible machine's P(e^{jwh}) at
    standstill on a 5 Hz grid, each element trusted where a measurement trusts it (the front
    sensor's to 4 kHz, the rear's to 875 Hz), each point weighted as if it had 1 % of random error.
    The fit reaches it (reduced chi-square 0.03, measured: residuals a fifth of the 1 %) and returns
    the machine's poles: the bending modes within 0.001 % (bound 0.01 %), their damping within
    0.7 % (bound 1 %), the rigid-body poles within 0.33 % (0.5 %), the amplifier within 0.1 %
    (0.5 %). Before the linear solve put its columns to unit norm (a residual compliance's and a
    residue's eight orders apart), this fit stopped unsettled at a reduced chi-square of 6 with the
    2.4 kHz mode's damping 483 % off. So the model holds the machine exactly: the biases of a
    measurement's fit (docs/validation.md) are the measurement's."""
    from ambdaq.analysis.plant_model import fit
    from ambdaq.machines.flexible_spindle import FLEXIBLE

    f = np.arange(5.0, 5000.0, 5.0)
    loop = FlexibleLoop()
    truth = loop.plant_response(0.0, f)
    poles = loop.plant_poles(0.0)
    bending = sorted({(round(abs(p) / (2 * np.pi), 6), round(-p.real / abs(p), 9)) for p in poles
                      if p.imag > 0 and -p.real / abs(p) < 0.1 and abs(p) / (2 * np.pi) < 4000})
    rigid = true_modes()["rigid_hz"]
    top = {"front": 4000.0, "rear": 875.0}
    data = {}
    for i, out in enumerate(AXES):
        for j, inp in enumerate(AXES):
            if out[-1] == inp[-1]:  # at standstill the x and y planes do not reach each other
                p = truth[:, i, j]
                trusted = f <= min(top[out.split("_")[0]], top[inp.split("_")[0]])
                data[out if i == j else f"{out}<-{inp}"] = (p, 0.01 * np.abs(p), trusted)
    result = fit(f, data, 1.0 / FLEXIBLE.sample_rate, rigid_hz=[50.0, 90.0],
                 bending_hz=[hz * 1.002 for hz, _ in bending])  # started 0.2 % off, as resonances are found
    got = dict(zip(result.names, result.values))
    assert result.converged and result.chi2_reduced < 0.1, result.chi2_reduced
    for k, (hz, zeta) in enumerate(bending, 1):
        assert abs(got[f"mode{k}_hz"] / hz - 1) < 1e-4 and abs(got[f"mode{k}_zeta"] / zeta - 1) < 0.01, (k, got)
    for k, hz in enumerate(rigid, 1):
        assert abs(got[f"rigid{k}_hz"] / hz - 1) < 0.005, (k, got[f"rigid{k}_hz"], hz)
    assert abs(got["amplifier_hz"] / 2500 - 1) < 0.005 and abs(got["amplifier_zeta"] / 0.8 - 1) < 0.005


def test_a_recording_without_the_controllers_output_is_one_line(run_cli, tmp_path):
    path = tmp_path / "spindle.mcap"
    assert run_cli("sim", "generate", "--excite", "front_x:2", "--duration", "0.5", "-q", "-o", path).exit_code == 0
    r = run_cli("plant", "identify", path, "-o", tmp_path / "p.json")
    assert r.exit_code == 2 and "no controller output (/amb/control)" in r.output
    assert len(r.output.strip().splitlines()) == 1 and not (tmp_path / "p.json").exists()
    r = run_cli("plant", "identify", "-o", tmp_path / "p.json")
    assert r.exit_code == 2 and "either --device URL (measure) or recordings" in r.output


@pytest.mark.realtime
def test_measured_by_url_on_the_served_flexible_rotor(run_cli, tmp_path):
    """The x plane at standstill (front and rear coupled through the rotor), over the real
    driver: the controller's own runs, the test signal switched off after each; the diagonal
    within 6 % of the truth (median; 2 s runs at 10 Hz: fewer averages than above)."""
    r = run_cli("plant", "identify", "--device", "sim://flexible", "--axes", "front_x,rear_x", "--duration", "2",
                "-o", tmp_path / "plant.json", "--json")
    assert r.exit_code == 0, r.output
    assert "test signal switched off after each run" in r.stderr
    measured = load_measurement(tmp_path / "plant.json")
    assert measured.axes == ["front_x", "rear_x"] and sorted(p.name for p in (tmp_path / "plant_runs").iterdir()) == [
        "gs_front_x.mcap", "gs_rear_x.mcap"]
    truth = true_plant(0.0, measured.freq_hz)[:, [0, 2]][:, :, [0, 2]]
    for i in range(2):
        good = measured.plant.coherence[:, i, i] >= 0.9
        assert np.median(np.abs(measured.plant.response[good, i, i] / truth[good, i, i] - 1)) < 0.06
