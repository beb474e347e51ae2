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


@pytest.mark.long  # four 10 s measurements, fit, designs (the refused one searches nine times), push, measure: about 11 minutes
def test_a_design_from_the_measured_plant_is_zone_a_over_speed_and_robust(run_cli, tmp_path, monkeypatch, chromium):
    """docs/tuning.md's steps: four runs of 10 s at 2.5 Hz, the model fitted, a design for 4,000 N s/m
    of damping. On the machine's model it is stable at every speed of the 1 % grid where the stock PID
    is unstable above 32,400 rpm, every axis in ISO 14839-3 zone A; the identified loop at
    standstill below 9.5 dB too; all 200 plants drawn within the identified uncertainty stable, and
    all 200 perturbed by +-10 % frequency, +-20 % damping and +-5 % gain (exit 0).
    A third of the machine's bearing stiffness (400 kN/m) sinks the rigid-body modes to 14 Hz, below
    any section's reach: zone B (12.0 dB at the rear), exit 1, saying so. (The stock damping reaches
    zone A, 9.1 dB: zone B, 10.1 dB, before each mode's residues were one shape, when the identified
    loop at standstill read 0.1-0.3 dB above the machine's; a quarter of it, 1,000 N s/m, reached
    zone B or A by the greedy path the last digits of the fit set, so it is not the test's case.)"""
    measure_plant(run_cli, tmp_path, "flexible", 5)
    r = run_cli("plant", "fit", tmp_path / "plant.json", "-o", tmp_path / "model.json", "--json")
    assert r.exit_code == 0, r.output
    identified_as_issue_42_asks(json.loads(r.stdout), tmp_path, FlexibleLoop(), "flexible")
    r = run_cli("plant", "gains", tmp_path / "plant.json", "--machine", "flexible", "--json")
    assert r.exit_code == 0, r.output
    for name, row in json.loads(r.stdout)["parameters"].items():  # each bearing's actuator gain: within 5 %
        assert abs(row["value"] / row["machine"] - 1) < 0.05, (name, row)
    r = run_cli("controller", "design", tmp_path / "model.json", "--damping", "4000", "-o", tmp_path / "ctl.json",
                "--json", "--plot", tmp_path / "design.png")
    assert r.exit_code == 0, r.output
    design = json.loads(r.stdout)
    assert design["stable_on_the_grid"] and design["speed_grid_rpm"] == [0.0, 36000.0, 101]
    assert design["robust"] and design["meets_target"] and design["robustness"]["stable"] == 200
    assert design["perturbed"]["plants"] == design["perturbed"]["stable"] == 200
    assert (tmp_path / "design.png").stat().st_size > 30_000
    for row in design["axes"]:
        assert row["zone"] == "A" and row["stock_unstable_from_rpm"] == 32400.0, row
        assert row["identified_standstill_db"] < 9.5, row
    r = run_cli("controller", "design", tmp_path / "model.json", "--stiffness", "400000", "-o", tmp_path / "soft.json",
                "--json")
    assert r.exit_code == 1 and ("not A" in r.stderr or "do not push it" in r.stderr), r.output
    soft = json.loads(r.stdout)
    assert soft["zone"] == "B" and not soft["meets_target"], soft["axes"]
    r = run_cli("push", tmp_path / "soft.json", "--device", "sim://flexible", "--dry-run")
    assert r.exit_code == 2 and "did not meet its target" in r.output, r.output
    monkeypatch.setenv("AMBDAQ_UNLOCK_KEY", "ambdaq-sim")
    push_measure_undo(run_cli, tmp_path, tmp_path / "ctl.json", design)
    report_renders_the_controller(run_cli, tmp_path, chromium)


@pytest.mark.long  # four 10 s measurements, their fit and a design that starts again: about 2 minutes
def test_a_search_that_ends_unstable_starts_again_from_another_first_section(run_cli, tmp_path):
    """The flexible rotor measured as docs/tuning.md says, seed 1, --damping 4000: the greedy
    search's first section (a full notch on the front's first bending mode) left a loop no single
    section could bring back (unstable on the machine's model from 11,160 rpm, 38 of 200 drawn plants
    stable: exit 1); started again from the next-best first section it reaches zone A, every drawn
    and perturbed plant stable (7.7 dB at the front, 7.4 dB at the rear, measured)."""
    measure_plant(run_cli, tmp_path, "flexible", 1)
    assert run_cli("plant", "fit", tmp_path / "plant.json", "-o", tmp_path / "model.json").exit_code == 0
    r = run_cli("controller", "design", tmp_path / "model.json", "--damping", "4000", "-o", tmp_path / "ctl.json",
                "--json")
    assert r.exit_code == 0, r.output
    design = json.loads(r.stdout)
    assert design["meets_target"] and design["zone"] == "A" and design["stable_on_the_grid"]
    assert design["robustness"]["stable"] == design["perturbed"]["stable"] == 200


def report_renders_the_controller(run_cli, tmp_path, chromium):
    """The commissioning report with the design and the stability measured after its push: its
    controller section, rendered by Chromium, holds the numbers ``--json`` printed."""
    import subprocess

    from ambdaq.report.pdf import HEADLESS
    from report_page import Tables

    page = tmp_path / "report.html"
    r = run_cli("report", "--stability", tmp_path / "st_20000.json", "--design", tmp_path / "ctl.json", "-o", page,
                "--json")
    assert r.exit_code == 0, r.output
    c = json.loads(r.stdout)["controller"]
    assert [x["axis"] for x in c["compared"]] == ["front_x", "rear_x"] and all(x["within"] for x in c["compared"])
    browse = [chromium, *HEADLESS, f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run([*browse, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0
    tables = Tables()
    tables.feed(dom.stdout)
    shown = tables.tables["controller-compared"]
    assert [cells[:5] for cells in shown] == [[f"{x['speed_rpm']:,.0f}", x["axis"], f"{x['measured_db']:.1f}",
                                              f"{x['predicted_db']:.1f}", f"{x['difference_db']:+.1f}"]
                                             for x in c["compared"]]
    assert [cells[4] for cells in tables.tables["controller-prediction"]] == [row["zone"] for row in c["axes"]]


def served_flexible(*extra: str, profile: str = "flexible"):
    """``ambdaq sim serve --profile PROFILE`` in its own process; yields its URLs by kind."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--profile", profile, "--duration",
                             "300", *extra], stdout=subprocess.PIPE, text=True)
    urls = {}
    while len(urls) < 1 + len(extra) // 2:
        line = proc.stdout.readline()
        assert line, "sim serve printed no URL"
        kind, where = line.split()
        urls[kind] = f"serial://{where}" if kind == "controller" else where
    return proc, urls


def measure_plant(run_cli, tmp_path, profile: str, seed: int) -> None:
    """docs/tuning.md's measurement on the simulated ``profile`` rotor: four runs of 10 s, 2 um of
    white noise at one axis's summing point each (``seed``), identified at 2.5 Hz into
    tmp_path/plant.json."""
    runs = [tmp_path / f"run_{axis}.mcap" for axis in AXES]
    for axis, path in zip(AXES, runs):
        assert run_cli("sim", "generate", "--profile", profile, "--excite", f"{axis}:2", "--duration", "10",
                       "--seed", str(seed), "-q", "-o", path).exit_code == 0
    assert run_cli("plant", "identify", *runs, "--resolution", "2.5", "-o", tmp_path / "plant.json").exit_code == 0


def identified_as_issue_42_asks(fitted: dict, tmp_path, machine: FlexibleLoop, profile: str) -> None:
    """Issue 42's figures for one identification (``plant fit --json`` of ``tmp_path``'s plant file,
    measured on ``machine``): every bending mode below 4 kHz found, its frequency within 1 % and its
    damping within 20 % of the machine's; the fitted plant within 5 % and 5 degrees of the machine's
    wherever the measurement's coherence is 0.9 or more, on every axis."""
    from ambdaq.workflows.plant_fit import load_model
    from ambdaq.workflows.plant_identification import load_measurement

    got = {k: v["value"] for k, v in fitted["parameters"].items()}
    poles = [p for p in machine.plant_poles(0.0) if p.imag > 0 and -p.real / abs(p) < 0.1 and abs(p) / (2 * np.pi) < 4000]
    bending = sorted((abs(p) / (2 * np.pi), -p.real / abs(p)) for p in poles)[::2]  # each mode once per plane
    assert sum(k.startswith("mode") and k.endswith("_hz") for k in got) == len(bending), (profile, got, bending)
    for k, (hz, zeta) in enumerate(bending, 1):
        assert abs(got[f"mode{k}_hz"] / hz - 1) < 0.01 and abs(got[f"mode{k}_zeta"] / zeta - 1) < 0.20, (k, got, hz, zeta)
    measured, model = load_measurement(tmp_path / "plant.json"), load_model(tmp_path / "model.json")
    truth = machine.plant_response(0.0, measured.freq_hz)
    for k, axis in enumerate(AXES):
        i = measured.axes.index(axis)
        good = measured.plant.coherence[:, i, i] >= 0.9
        ratio = model.response(axis, measured.freq_hz[good]) / truth[good, k, k]
        assert np.abs(ratio - 1).max() < 0.05 and np.degrees(np.abs(np.angle(ratio))).max() < 5, (profile, axis)


def push_measure_undo(run_cli, tmp_path, ctl, design):
    """docs/tuning.md's steps 4-5 on the served machine: over the serial line, the design pushed
    (PID and sections in one bank, device-verified), ISO 14839-3 measured at standstill and at
    20,000 and 36,000 rpm and compared with the prediction (within 0.5 dB), the push rolled back (the stock
    controller's bank again); over XCP the same push and rollback."""
    proc, urls = served_flexible("--xcp", "tcp:0")
    try:
        url = urls["controller"]
        stock = json.loads(run_cli("controller", "status", "--device", url, "--json").stdout)
        r = run_cli("push", ctl, "--device", url, "--yes")
        assert r.exit_code == 0 and "device-verified" in r.output, r.output
        assert run_cli("controller", "param", "--device", url, "pid.d").stdout.split()[2] == f"{design['pid']['d'][0]:g}"
        # at 20,000 rpm the front's peak is the first bending mode's whirl at 323 Hz, a few hertz
        # wide: measured at 1.25 Hz steps over 16 s with 4 um (coherence at the peak 0.96; at 5 Hz
        # over 10 s 0.83, at 2.5 Hz a neighbouring point's 0.86: not graded)
        for rpm, duration, step, amplitude in ((0, 4, 5, 2), (20000, 16, 1.25, 4), (36000, 16, 1.25, 4)):
            r = run_cli("iso", "stability", "--device", url, "--rpm", rpm, "--duration", duration, "--resolution", step,
                        "--amplitude", amplitude,
                        "--axes", "front_x,rear_x", "-o", tmp_path / f"st_{rpm}.json", "--compare", ctl, "--json", "-q")
            assert r.exit_code == 0, r.output
            rows = json.loads(r.stdout)["compared"]["rows"]
            assert [c["axis"] for c in rows] == ["front_x", "rear_x"] and all(c["within"] for c in rows), rows
        r = run_cli("push", "--rollback", "--device", url, "--yes")
        assert r.exit_code == 0 and "rolled back" in r.output, r.output
        back = json.loads(run_cli("controller", "status", "--device", url, "--json").stdout)
        assert back["active_crc32"] == stock["active_crc32"]
        # over XCP, the same file by the A2L's names
        a2l = tmp_path / "flexible.a2l"
        assert run_cli("sim", "a2l", "--profile", "flexible", "-o", a2l).exit_code == 0
        xcp = f"{urls['xcp']}?a2l={a2l}"
        port = int(urls["xcp"].rsplit(":", 1)[1])
        before = held_by_the_slave(port, a2l)
        r = run_cli("push", ctl, "--device", xcp, "--yes")
        assert r.exit_code == 0 and "device-verified" in r.output, r.output
        # what the slave runs, read by a master that is not ours (pyxcp) at the addresses pya2ldb
        # reads from the A2L: the design's PID and sections, FLOAT64 both ways, so bit for bit; the
        # sections the design leaves free pass the signal (b0 = 1, the rest 0)
        from ambdaq.sim.rigs.flexible import IDENTITY_SECTION
        from ambdaq.workflows.controller_design import load_design

        pushed, design_file = held_by_the_slave(port, a2l), load_design(ctl)
        order = [design_file.axes.index(axis) for axis in AXES]
        for k, name in enumerate(("pid.p", "pid.i", "pid.d")):
            np.testing.assert_array_equal(pushed[name], design_file.pid[order, k])
        used = design_file.biquads.shape[1]
        np.testing.assert_array_equal(pushed["filter.sections"][:, :used], design_file.biquads[order])
        assert np.all(pushed["filter.sections"][:, used:] == IDENTITY_SECTION)
        assert run_cli("push", "--rollback", "--device", xcp, "--yes").exit_code == 0
        assert json.loads(run_cli("controller", "status", "--device", xcp, "--json").stdout)["active_crc32"] == \
            stock["active_crc32"]
        after = held_by_the_slave(port, a2l)
        assert all(np.array_equal(after[name], before[name]) for name in before), (before, after)
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def held_by_the_slave(port: int, a2l) -> dict[str, np.ndarray]:
    """The controller's PID gains (per axis) and sections ((axes, sections, 5)) as pyxcp uploads
    them from the XCP slave on ``port``, at the addresses and sizes of the A2L's CHARACTERISTICs
    as pya2ldb reads them (no ambdaq code between the slave and the numbers)."""
    import struct

    from pya2l import import_a2l, model

    from test_xcp import master

    session = import_a2l(str(a2l), in_memory=True, loglevel="ERROR", progress_bar=False)
    found = {c.name: (c.address, c.number.number if c.number else 1) for c in session.query(model.Characteristic)
             if c.name in ("pid.p", "pid.i", "pid.d", "filter.sections")}
    out = {}
    with master(port) as x:
        x.connect()
        for name, (address, count) in found.items():
            x.setMta(address)
            out[name] = np.array(struct.unpack(f"<{count}d", x.fetch(8 * count)))
        x.disconnect()
    out["filter.sections"] = out["filter.sections"].reshape(len(AXES), -1, 5)
    return out


def test_the_second_rotor_needs_tuning_and_is_not_the_first():
    """The longer rotor (``--profile flexible-long``): bending modes at least 20 % below the first
    rotor's, its stock PID zone D at standstill and still stable at the top speed (a machine the
    design has nothing tuned for; the long test below takes it from measurement to undo)."""
    from ambdaq.machines.flexible_spindle import LONG_ROTOR, MAX_RPM

    first, second = FlexibleLoop(FLEXIBLE), FlexibleLoop(LONG_ROTOR)
    assert np.all(second.free_hz[2:6] < 0.8 * first.free_hz[2:6]), (first.free_hz, second.free_hz)
    radius, peak, _ = model_sensitivity_peaks(*second.matrices(0.0), second.h, BAND)
    assert radius < 1 and db(peak.max()) > 14.0, db(peak)  # ISO 14839-3 zone D beyond 14 dB
    assert model_sensitivity_peaks(*second.matrices(MAX_RPM), second.h, BAND)[0] < 1


@pytest.mark.long  # four 10 s measurements, fit, design, push, three measurements: about 3 minutes
def test_the_whole_job_on_a_rotor_the_design_was_not_written_for(run_cli, tmp_path, monkeypatch):
    """Identify -> fit -> design -> push -> measure -> undo on the longer rotor (seed 9): its
    poles within 3 of their stated deviations; a design for 4,000 N s/m of damping to zone A (9.2
    dB at the rear at 36,000 rpm; 200 drawn and 200 perturbed plants stable; the stock PID was zone
    D; zone B, 10.4 dB, before each mode's residues were one shape); after the push every
    measured peak within 0.5 dB of the prediction, at standstill and at 36,000 rpm; the rollback
    restores the stock bank.
    Measured here: fitted bending modes 295.26, 596.53, 1192.4, 1888.7, 2828.4, 3675.6 Hz for
    295.26 ... 3675.1; peaks +0.04 and -0.09 dB at standstill, -0.03 and -0.02 dB at 36,000 rpm."""
    from ambdaq.machines.flexible_spindle import LONG_ROTOR

    measure_plant(run_cli, tmp_path, "flexible-long", 9)
    r = run_cli("plant", "fit", tmp_path / "plant.json", "-o", tmp_path / "model.json", "--json")
    assert r.exit_code == 0, r.output
    fitted = json.loads(r.stdout)
    got = {k: (v["value"], v["std"]) for k, v in fitted["parameters"].items()}
    poles = FlexibleLoop(LONG_ROTOR).plant_poles(0.0)
    bending = sorted(abs(p) / (2 * np.pi) for p in poles if p.imag > 0 and -p.real / abs(p) < 0.1
                     and abs(p) / (2 * np.pi) < 4000)[::2]  # each mode once per plane
    assert len(bending) == sum(k.startswith("mode") and k.endswith("_hz") for k in got) == 6
    for k, hz in enumerate(bending, 1):
        value, std = got[f"mode{k}_hz"]
        assert abs(value - hz) < 3 * std, (k, value, std, hz)
    # the identified plant (the fitted model) is the machine's within 5 % and 5 degrees wherever the
    # measurement's coherence is 0.9 or more (seed 9: within 3.9 % and 2.1 degrees, on the diagonal;
    # 4.7 % before each mode's residues were one shape), its modes within 1 % and 20 %
    identified_as_issue_42_asks(fitted, tmp_path, FlexibleLoop(LONG_ROTOR), "flexible-long")
    # each bearing's actuator gain and negative stiffness, with this rotor's model: within 5 %
    r = run_cli("plant", "gains", tmp_path / "plant.json", "--machine", "flexible-long", "--json")
    assert r.exit_code == 0, r.output
    for name, row in json.loads(r.stdout)["parameters"].items():
        assert abs(row["value"] / row["machine"] - 1) < 0.05 and abs(row["value"] - row["machine"]) < 3 * row["std"]
    ctl = tmp_path / "ctl.json"
    r = run_cli("controller", "design", tmp_path / "model.json", "--machine", "flexible-long", "--damping", "4000",
                "-o", ctl, "--json")
    assert r.exit_code == 0, r.output
    design = json.loads(r.stdout)
    assert design["meets_target"] and design["zone"] == "A"
    assert design["robustness"]["stable"] == design["perturbed"]["stable"] == 200
    assert all(row["stock_peak_db"] > 14.0 for row in design["axes"]), design["axes"]
    monkeypatch.setenv("AMBDAQ_UNLOCK_KEY", "ambdaq-sim")
    proc, urls = served_flexible(profile="flexible-long")
    try:
        url = urls["controller"]
        stock = json.loads(run_cli("controller", "status", "--device", url, "--json").stdout)
        r = run_cli("push", ctl, "--device", url, "--yes")
        assert r.exit_code == 0 and "device-verified" in r.output, r.output
        # the front's standstill peak is the third bending mode's, 1.2 kHz and narrow: 10 s at
        # 2.5 Hz with 4 um (4 s at 5 Hz with 2 um left its coherence at 0.87, not graded)
        for rpm, axes, duration, step, amplitude in ((0, "front_x,rear_x", 10, 2.5, 4),
                                                     (36000, "front_x,rear_x", 16, 1.25, 4)):
            r = run_cli("iso", "stability", "--device", url, "--rpm", rpm, "--duration", duration, "--resolution",
                        step, "--amplitude", amplitude, "--axes", axes, "-o", tmp_path / f"st_{rpm}.json",
                        "--compare", ctl, "--json", "-q")
            assert r.exit_code == 0, r.output
            rows = json.loads(r.stdout)["compared"]["rows"]
            assert [c["axis"] for c in rows] == ["front_x", "rear_x"] and all(c["within"] for c in rows), rows
        assert run_cli("push", "--rollback", "--device", url, "--yes").exit_code == 0
        back = json.loads(run_cli("controller", "status", "--device", url, "--json").stdout)
        assert back["active_crc32"] == stock["active_crc32"]
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_the_predicted_loop_is_python_controls_interconnection_of_plant_and_controller():
    """The prediction's loop (the firmware's order in ``close_loop``: sample, PID, sections, hold)
    against python-control's (an independent library: the plant discretised by its c2d, each
    axis's controller a transfer function in z, the sensitivity (I - P K)^-1 by its feedback):
    the same closed-loop poles' largest modulus within 1e-9, and Gs within 1e-6 of its magnitude
    at every frequency (the two differ only by rounding: both are exact discretisations of one
    loop)."""
    control = pytest.importorskip("control")
    from ambdaq.analysis import sections as sec
    from ambdaq.analysis.iso14839 import model_sensitivity
    from ambdaq.machines.spindle_loop import derivative_filter
    from ambdaq.workflows.controller_design import identified_continuous

    model, labels = true_model()
    h, fs, ks = model.h, FLEXIBLE.sample_rate, FLEXIBLE.sensor_gain
    front = [sec.notch(390.0, 1.0, fs, 0.3), sec.lead_lag(1200.0, 3000.0, fs)]
    rear = [sec.lead_lag(600.0, 1500.0, fs), sec.lowpass(2000.0, 0.707, fs)]
    chains = [front, front, rear, rear]
    P, I, D = (np.array([1.5, 1.5, 1.3, 1.3]), np.array([2.0] * 4), np.array([0.0013, 0.0013, 0.0011, 0.0011]))
    M, B, C = close_loop(*identified_plant(model, labels, h), (P, I, D), chains, sensor_gain=ks,
                         nd=FLEXIBLE.derivative_filter, h=h)

    A, Bc, Cc = identified_continuous(model, labels)
    plant = control.c2d(control.ss(A, Bc, Cc, np.zeros((4, 4))), h, method="zoh")
    ad, bd = derivative_filter(P, D, FLEXIBLE.derivative_filter, h)
    z = control.tf([1.0, 0.0], [1.0], h)
    axes = []
    for a in range(4):
        k = -ks * (P[a] + I[a] * h / 2 * (z + 1) / (z - 1) + bd[a] * (z - 1) / (z - ad[a]))
        for b0, b1, b2, a1, a2 in chains[a]:
            k = k * control.tf([b0, b1, b2], [1.0, a1, a2], h)
        axes.append(control.ss(k))
    K = control.append(*axes)
    identity = control.ss(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((4, 0)), np.eye(4), h)
    S = control.feedback(identity, plant * K, sign=+1)  # e = -(I - P K)^-1 r, Gs = -e/r

    assert abs(np.abs(control.poles(S)).max() - np.abs(np.linalg.eigvals(M)).max()) < 1e-9
    f = np.array([10.0, 61.0, 200.0, 390.0, 800.0, 1504.0, 2433.0, 4000.0])
    theirs = np.array([np.diag(S(np.exp(2j * np.pi * x * h))) for x in f]).T
    ours = model_sensitivity(M, B, C, h, f)
    assert np.allclose(ours, theirs, rtol=1e-6, atol=0), np.abs(ours / theirs - 1).max()
