"""``ambdaq controller design`` (issue 42, item 4): the identified plant as one state space, closed
by the firmware's controller, against the machine it was measured on; the design's prediction on
the speed grid and on plants drawn within the identified uncertainty."""

import json

import numpy as np
import pytest

from ambdaq.analysis.iso14839 import db, model_sensitivity_peaks
from ambdaq.analysis.plant_model import ModalPlant
from ambdaq.machines.flexible_spindle import FLEXIBLE, FlexibleLoop, close_loop
from ambdaq.workflows.controller_design import identified_plant
from test_plant_identify import AXES, true_residues

BAND = (5.0, 4999.0)


def true_model() -> tuple[ModalPlant, list[str]]:
    """The levitated rotor's modes below 4 kHz with each element's true residue, as ``plant fit``
    states them (bending modes at the machine's structural damping, the amplifier's own poles)."""
    hz, residues = true_residues()
    keep = hz < 4000.0
    labels = sorted(residues)
    rigid = np.sort(2 * np.pi * hz[keep][:2])
    order = np.argsort(hz[keep])
    r = np.array([residues[lb][keep][order] for lb in labels])
    bending = np.column_stack([2 * np.pi * np.sort(hz[keep])[2:], np.full(int(keep.sum()) - 2, 0.005)])
    a = FLEXIBLE.front
    model = ModalPlant(rigid, bending, r, (2 * np.pi * a.amp_wn_hz, a.amp_zeta), 0.0, 1.0 / FLEXIBLE.sample_rate)
    return model, labels


def test_the_identified_plant_closed_by_the_controller_is_the_machines_loop():
    """The model of every element, realised as one state space and closed by the stock PID, has the
    machine's standstill sensitivity: each axis's peak |Gs| within 0.5 dB (the modes above 4 kHz and
    the bending modes' damping by the magnets, left out of the model, measured 0.1-0.3 dB). Realised
    with each mode copied per input instead, the rigid-body modes' copies the controller cannot
    tell apart stayed unstable: a closed loop with a pole outside the unit circle."""
    model, labels = true_model()
    h = model.h
    Phi, Gam, Cs = identified_plant(model, labels, h)
    f = np.array([20.0, 100.0, 300.0])
    P = np.array([Cs @ np.linalg.solve(np.exp(2j * np.pi * x * h) * np.eye(Phi.shape[0]) - Phi, Gam) for x in f])
    truth = FlexibleLoop().plant_response(0.0, f)
    assert np.allclose(P[:, [0, 2], [0, 2]], truth[:, [0, 2], [0, 2]], rtol=0.05)
    gains = tuple(tuple(getattr(a, k) for a in FLEXIBLE.axes) for k in ("pid_p", "pid_i", "pid_d"))
    chains = [[] for _ in AXES]
    radius, peak, _ = model_sensitivity_peaks(*close_loop(Phi, Gam, Cs, gains, chains, sensor_gain=FLEXIBLE.sensor_gain,
                                                          nd=FLEXIBLE.derivative_filter, h=h), h, BAND)
    machine = model_sensitivity_peaks(*FlexibleLoop().matrices(0.0), h, BAND)
    assert radius < 1.0 and machine[0] < 1.0
    assert np.all(np.abs(db(peak) - db(machine[1])) < 0.5), (db(peak), db(machine[1]))


@pytest.mark.long  # a measurement, its fit and a design: about 40 s (docs/tuning.md)
def test_a_design_from_the_measured_plant_is_zone_a_over_speed_and_says_how_robust(run_cli, tmp_path):
    """Four runs of 4 s at 5 Hz, the model fitted, a design: on the machine's model it is stable
    at every speed of the 1 % grid where the stock PID is unstable above 32,400 rpm, every axis in
    ISO 14839-3 zone A; the identified loop at standstill agrees with the machine's model within
    1 dB; and the plants drawn within the identified uncertainty are counted, the exit code
    saying whether all of them stay stable."""
    runs = []
    for axis in AXES:
        path = tmp_path / f"run_{axis}.mcap"
        assert run_cli("sim", "generate", "--profile", "flexible", "--excite", f"{axis}:2", "--duration", "4",
                       "--seed", "5", "-q", "-o", path).exit_code == 0
        runs.append(path)
    assert run_cli("plant", "identify", *runs, "--resolution", "5", "-o", tmp_path / "plant.json").exit_code == 0
    assert run_cli("plant", "fit", tmp_path / "plant.json", "-o", tmp_path / "model.json").exit_code == 0
    r = run_cli("controller", "design", tmp_path / "model.json", "--draws", "100", "-o", tmp_path / "ctl.json", "--json")
    design = json.loads(r.stdout)
    assert design["stable_on_the_grid"] and design["speed_grid_rpm"] == [0.0, 36000.0, 101]
    for row in design["axes"]:
        assert row["zone"] == "A" and row["stock_unstable_from_rpm"] == 32400.0, row
        assert abs(row["identified_standstill_db"] - row["peak_db"]) < 1.0 or row["at_rpm"] > 0, row
    rb = design["robustness"]
    assert rb["draws"] == 100 and (r.exit_code == 0) == (rb["stable"] == 100 and design["robust"])
    assert (tmp_path / "ctl.json").exists()
