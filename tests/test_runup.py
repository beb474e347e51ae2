"""Run-up diagnostics: order tracking against the simulator's true rotor motion, 1X peaks against a
resonance of known speed and damping, and what cannot be tracked."""

import json
import re

import numpy as np
import pytest

from ambdaq.analysis.orders import CRITICAL_AMPLIFICATION, one_x_peaks, order_track
from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load, open_recording

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


@pytest.mark.parametrize("zeta, critical", [(0.1, True), (0.15, True), (0.3, False)])
def test_one_x_peak_of_a_resonance_of_known_speed_and_damping(zeta, critical):
    """The unbalance response of one mode at 18,000 rpm: its peak is at 18,000 / sqrt(1 - 2 zeta^2),
    the phase turns through it, and the half-power amplification is about 1 / (2 zeta)."""
    rpm = np.linspace(1000, 60000, 600)  # 98.5 rpm per window, as 8 revolutions at 5,000 rpm/s give
    r = rpm / 18000.0
    v = 10e-6 * r**2 / ((1 - r**2) + 2j * zeta * r)
    (peak,) = one_x_peaks(rpm, v)
    assert abs(peak.rpm - 18000 / np.sqrt(1 - 2 * zeta**2)) < 100  # one window
    assert peak.phase_change_deg > 60
    if zeta <= 0.15:  # the half-power width of an r^2-forced mode is 2 zeta to first order: 15 % at 0.15
        assert peak.amplification == pytest.approx(1 / (2 * zeta), rel=0.15)
        # and the curve's own half-power factor, its edges found on a 100x finer grid: the edges
        # interpolated between windows 98.5 rpm apart are within 1 % of it
        fine = np.linspace(1000, 60000, 60000)
        a = np.abs(10e-6 * (fine / 18000) ** 2 / ((1 - (fine / 18000) ** 2) + 2j * zeta * fine / 18000))
        band = fine[a >= a.max() / np.sqrt(2)]
        assert peak.amplification == pytest.approx(fine[np.argmax(a)] / (band[-1] - band[0]), rel=0.01)
    assert peak.is_critical() is critical and (peak.amplification >= CRITICAL_AMPLIFICATION) is critical


@pytest.fixture(scope="module")
def runup(tmp_path_factory):
    """A run-up to 30,000 rpm with the truth, a slow roll, and the runout identified from it."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    d = tmp_path_factory.mktemp("runup")
    for args in (["sim", "generate", "--rpm", "0:30000:3", "--duration", "3", "--truth", "-q", "-o", d / "runup.mcap"],
                 ["sim", "generate", "--rpm", "slowroll", "--duration", "2", "-q", "-o", d / "slow.mcap"],
                 ["runout", "identify", d / "slow.mcap", "-o", d / "runout.json"]):
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    return d


def test_order_tracking_with_the_runout_out_is_the_true_rotor(runup, run_cli):
    r = run_cli("runup", runup / "runup.mcap", "--coefficients", runup / "runout.json", "--orders", "1,2", "--json",
                "--model", "spindle", "--plot", runup / "runup.png")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    rec = load(runup / "runup.mcap")
    truth, rot = rec["/truth/position"], rec["/amb/rotor"]
    axes = list(out["axes"])
    assert axes == ["front_x", "front_y", "rear_x", "rear_y"]
    true = order_track(np.column_stack([truth[a] for a in axes]), rot["angle"], rot["speed"] * 60 / (2 * np.pi))
    np.testing.assert_allclose(out["rpm"], true.rpm, atol=0.05)
    for i, a in enumerate(axes):
        for k in (1, 2):
            got = np.array(out["axes"][a][f"{k}X"]["amplitude_um"]) * np.exp(-1j * np.radians(out["axes"][a][f"{k}X"]["phase_lag_deg"]))
            # the identified runout is within 0.07 um of the true one; the sensor noise (0.2 um RMS)
            # over 8 revolutions adds about 0.05 um: 0.3 um
            assert np.abs(got - true.order(k)[:, i] * 1e6).max() < 0.3, (a, k)
    # the rotor follows 16 um of rear runout at low speed and lets go of it above the ~300 Hz modes
    rear = np.array(out["axes"]["rear_x"]["1X"]["amplitude_um"])
    assert rear[np.array(out["rpm"]) < 5000].mean() > 25 and rear[-5:].mean() < 25
    modes = out["model_modes"]
    assert modes["rpm"][0] == pytest.approx(out["rpm"][0], abs=0.1)
    assert any(280 < f < 330 for f in modes["freq_hz"][0] if f is not None)  # the radial rigid-body modes
    # whirl, from each mode's shape at the bearings: the gyroscopic moment splits the radial pair, and
    # the mode marked forward is the one that stiffens with speed, the backward one the one that
    # softens (the physics, not a label); the split grows with speed, from under 2 Hz at the run's start
    split = [{w: f for f, w in zip(fs, ws) if w} for fs, ws in zip(modes["freq_hz"], modes["whirl"])]
    assert all(set(s) == {"forward", "backward"} and s["forward"] > s["backward"] for s in split)
    assert np.all(np.diff([s["forward"] for s in split]) >= 0) and np.all(np.diff([s["backward"] for s in split]) <= 0)
    assert split[0]["forward"] - split[0]["backward"] < 2 and split[-1]["forward"] - split[-1]["backward"] > 10
    # the critical speed the model predicts: where its forward mode meets 1X, found here from the
    # model itself by bisection (to 1 rpm); the run's 26-speed grid interpolates it within 0.5 %.
    # Amplified 1/(2 zeta) ~ 1.5 < 2.5, it is critically damped (API 684), and the run measured no
    # critical speed there: it passes
    from ambdaq.analysis.orders import loop_modes
    from ambdaq.sim.rigs.spindle import SpindleRig

    rig = SpindleRig()

    def forward(rpm: float) -> tuple[float, float]:
        M, _B, C = rig.loop_matrices(rpm)
        f, zeta, whirl = loop_modes(M, rig.h, fmax_hz=2000.0, outputs=C, pairs=((0, 1), (2, 3)))
        return float(f[whirl == 1][0]), float(zeta[whirl == 1][0])

    lo, hi = 10000.0, 30000.0
    while hi - lo > 1.0:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if forward(mid)[0] > mid / 60.0 else (lo, mid)
    (crit,) = out["critical_speeds"]
    assert crit["predicted_rpm"] == pytest.approx(lo, rel=0.005) and crit["whirl"] == "forward"
    assert crit["predicted_amplification"] == pytest.approx(1 / (2 * forward(lo)[1]), rel=0.02)
    assert crit["passed"] and crit["measured_rpm"] is None and "critically damped" in crit["rule"]
    assert (runup / "runup.png").stat().st_size > 60_000


def test_slow_roll_compensation_takes_out_what_the_rotor_did_at_slow_roll(runup, run_cli):
    """Bently's slow-roll vector is runout plus the rotor's slow-roll motion: on an AMB, whose loop
    makes the rotor follow the runout at low speed, the compensated 1X starts near zero and the
    rotor's real motion there is lost; the coefficient file keeps it."""
    slow = json.loads(run_cli("runup", runup / "runup.mcap", "--slow-roll", runup / "slow.mcap", "--json").stdout)
    coef = json.loads(run_cli("runup", runup / "runup.mcap", "--coefficients", runup / "runout.json", "--json").stdout)
    assert slow["rpm"] == coef["rpm"] and slow["rpm"][0] < 2000
    first_slow, first_rotor = (d["axes"]["rear_x"]["1X"]["amplitude_um"][0] for d in (slow, coef))
    assert first_slow < 5.0 and first_rotor > 25.0  # 3.6 against 31.7 um at 1,549 rpm here
    text = run_cli("runup", runup / "runup.mcap", "--slow-roll", runup / "slow.mcap").output
    # up to 30,000 rpm the slow-roll-compensated 1X only rises: no peak with a half-power band
    assert "compensation: slow-roll vector" in text and "rear_x: no 1X peak that stands out" in text
    # and the user is told why that number is off on an AMB, and what to use instead
    assert "warning: a slow-roll vector on an active magnetic bearing holds the rotor's own motion" in text
    assert "--coefficients from `runout identify`" in text


def test_what_cannot_be_tracked_is_one_line_exit_2(runup, run_cli, tmp_path):
    r = run_cli("runup", runup / "runup.mcap", "--speeds", "0:50000")
    assert r.exit_code == 2 and "rpm, not 0-50,000: record a run-up (or coast-down) over the whole range" in r.output
    r = run_cli("runup", runup / "runup.mcap", "--coefficients", runup / "runout.json", "--slow-roll", runup / "slow.mcap")
    assert r.exit_code == 2 and "not both" in r.output
    r = run_cli("runup", runup / "runup.mcap", "--slow-roll", runup / "runup.mcap")
    assert r.exit_code == 2 and "a slow roll is below a tenth" in r.output
    base = tmp_path / "base.mcap"
    assert run_cli("sim", "generate", "--profile", "base-motion", "--duration", "0.3", "-q", "-o", base).exit_code == 0
    r = run_cli("runup", base)
    assert r.exit_code == 2 and "no rotor angle and speed (/amb/rotor): order tracking needs the key-phasor" in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_plot_marks_the_orders_of_a_steady_run_and_the_clearance(runup, run_cli, tmp_path):
    steady = tmp_path / "steady.mcap"
    assert run_cli("sim", "generate", "--rpm", "20000", "--duration", "0.5", "-q", "-o", steady).exit_code == 0
    for rec, extra in ((steady, ()), (runup / "runup.mcap", ("--cmin", "200"))):
        out = tmp_path / f"{rec.stem}.png"
        r = run_cli("plot", rec, "--field", "rear_x", "-o", out, *extra)
        assert r.exit_code == 0, r.output
        assert out.stat().st_size > 50_000


def test_a_1x_of_sensor_noise_has_no_critical_speed_and_the_cone_model_overlays_its_modes(run_cli, tmp_path):
    """The cone rotor has no unbalance: its 1X is sensor noise, whose peaks are everywhere and none
    significant.  --model cone overlays Jeong et al.'s coupled model: the 57 Hz mode at low speed, and
    the tilting modes the gyroscopic coupling splits as it spins up."""
    rec = tmp_path / "cone.mcap"
    assert run_cli("sim", "generate", "--profile", "cone", "--rpm", "0:6000:3", "--duration", "3", "-q", "-o", rec).exit_code == 0
    r = run_cli("runup", rec, "--model", "cone", "--json", "--plot", tmp_path / "cone.png")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert list(out["axes"]) == ["y1", "y2", "z1", "z2"]  # x, the spin axis, has no orbit
    assert max(max(v["1X"]["amplitude_um"]) for v in out["axes"].values()) < 0.1  # noise: 0.1 um RMS sensors
    assert all(peaks == [] for peaks in out["peaks_1x"].values())
    modes = out["model_modes"]
    slow, fast = [f for f in modes["freq_hz"][0] if f], [f for f in modes["freq_hz"][-1] if f]
    assert any(abs(f - 57.0) < 1.0 for f in slow) and len(fast) > len(slow)
    # the synthetic resonance of the test above, buried in the same kind of scatter, is still found
    rpm = np.linspace(1000, 60000, 600)
    v = 10e-6 * (rpm / 18000) ** 2 / ((1 - (rpm / 18000) ** 2) + 0.2j * rpm / 18000)
    noise = 0.3e-6 * np.array([1, 1j]) @ np.random.default_rng(0).standard_normal((2, 600))
    assert len(one_x_peaks(rpm, v + noise)) == 1 and one_x_peaks(rpm, noise) == []


def test_the_runup_figure_shows_the_phase_lag_unwrapped_and_both_axes_of_a_bearing(runup):
    """What the figure shows, read back from it: the 1X phase is a lag that grows through the run
    without +-180 jumps (as engineers read it), and x and y of a bearing are told apart (y dashed on
    top of solid x), so equal curves of an isotropic bearing are both visible."""
    from ambdaq.figures import pyplot
    from ambdaq.figures.runup import draw_runup
    from ambdaq.workflows.runup_diagnostics import analyse

    res = analyse(open_recording(runup / "runup.mcap"), coefficients=runup / "runout.json", orders=(1, 2))
    fig = draw_runup(res, "runup.mcap")
    try:
        amp_ax, ph_ax = fig.axes[0], fig.axes[1]
        phase = {ln.get_label(): ln for ln in ph_ax.get_lines()}
        assert set(phase) == {f"{a} 1X" for a in res.axes}
        for label, line in phase.items():
            y = np.asarray(line.get_ydata())
            # neighbouring windows are 8 revolutions apart: the phase moves by far less than 180 deg
            # between them, so a step that large could only be a wrap
            assert np.max(np.abs(np.diff(y))) < 180, label
            assert 0 <= y[0] < 360
        # the rear bearing's 1X lags by more at the top of the run than at the bottom (it passes
        # its rigid-body modes near 300 Hz = 18,000 rpm on the way)
        rear = np.asarray(phase["rear_x 1X"].get_ydata())
        assert rear[-5:].mean() - rear[:5].mean() > 90
        # every title inside the figure (a compensation naming a long path is wrapped)
        fig.canvas.draw()
        page = fig.get_window_extent()
        for ax in fig.axes:
            box = ax.title.get_window_extent()
            assert box.x0 >= page.x0 and box.x1 <= page.x1, ax.title.get_text()
        styles = {ln.get_label(): (ln.get_color(), ln.get_linestyle(), ln.get_zorder()) for ln in amp_ax.get_lines()}
        for bearing in ("front", "rear"):
            x, y = styles[f"{bearing}_x 1X"], styles[f"{bearing}_y 1X"]
            assert x[1] == "-" and y[1] == "--" and y[2] > x[2]  # y dashed, drawn over x
    finally:
        pyplot().close(fig)


def test_the_runup_table_json_and_figure_give_one_phase(runup, run_cli):
    """One phase convention in every output of ``runup``: the lag behind the key-phasor, unwrapped
    along the run.  The JSON's numbers are the figure's lines to their 2-decimal rounding, and the
    table's cells (to the degree) are the JSON's at the speeds it prints (they had the opposite
    sign)."""
    from ambdaq.figures import pyplot
    from ambdaq.figures.runup import draw_runup
    from ambdaq.workflows.runup_diagnostics import analyse

    out = json.loads(run_cli("runup", runup / "runup.mcap", "--coefficients", runup / "runout.json", "--json").stdout)
    res = analyse(open_recording(runup / "runup.mcap"), coefficients=runup / "runout.json", orders=(1, 2))
    fig = draw_runup(res, "runup.mcap")
    try:
        for line in fig.axes[1].get_lines():
            axis = line.get_label().split()[0]
            np.testing.assert_allclose(out["axes"][axis]["1X"]["phase_lag_deg"], line.get_ydata(), atol=0.006)
    finally:
        pyplot().close(fig)
    table = run_cli("runup", runup / "runup.mcap", "--coefficients", runup / "runout.json").stdout.splitlines()
    speeds = np.linspace(min(out["rpm"]), max(out["rpm"]), 5)
    at = [int(np.argmin(np.abs(np.array(out["rpm"]) - r))) for r in speeds]
    row = next(ln for ln in table if ln.startswith("rear_x") and " 1X " in ln)
    printed = [float(c) for c in re.findall(r"(-?\d+)°", row)]
    lag = np.array(out["axes"]["rear_x"]["1X"]["phase_lag_deg"])[at]
    np.testing.assert_allclose(printed, lag, atol=0.51)
    assert lag[-1] - lag[0] > 90  # a lag that grows through the modes: the sign is the figure's


def test_the_shaft_centreline_is_the_rotors_mean_position(runup, run_cli):
    """The centreline (each bearing's position per 0.1 s, runout taken out: the DC of a fit of the
    DC and four orders, so the 1X does not leak into it over a window that is not whole
    revolutions) against the simulator's true rotor position reduced the same way by the test's
    own least squares: the sensor noise (0.2 um RMS over 1,000 samples: 0.006 um) and the rest of
    the runout keep them within 0.05 um (a plain mean had been 0.65 um off on a run-up above 3,000
    rpm); the rotor sits inside its clearance circle."""
    out = json.loads(run_cli("runup", runup / "runup.mcap", "--coefficients", runup / "runout.json", "--json").stdout)
    line = out["centreline"]
    assert set(line["bearings"]) == {"front", "rear"} and line["cmin_um"] == 150.0
    rec = load(runup / "runup.mcap")
    truth, theta = rec["/truth/position"], np.unwrap(rec["/amb/rotor"]["angle"])
    n = 1000  # 0.1 s at 10 kHz

    def dc(v, th):  # the constant of the least-squares fit of a constant and orders 1-4
        if th[-1] - th[0] < 8 * np.pi:
            return v.mean()
        cols = [np.ones_like(th)] + [f(k * th) for k in range(1, 5) for f in (np.sin, np.cos)]
        return np.linalg.lstsq(np.column_stack(cols), v, rcond=None)[0][0]

    for bearing, xy in line["bearings"].items():
        for axis, got in (("x", xy["x_um"]), ("y", xy["y_um"])):
            true = truth[f"{bearing}_{axis}"]
            want = [dc(true[i * n:(i + 1) * n], theta[i * n:(i + 1) * n]) * 1e6 for i in range(len(got))]
            assert np.max(np.abs(np.array(got) - want)) < 0.05, (bearing, axis)
        radius = np.hypot(xy["x_um"], xy["y_um"])
        assert radius.max() < line["cmin_um"]
    assert np.all(np.diff(line["time_s"]) > 0) and line["rpm"][-1] > line["rpm"][0]  # a run-up, in time order


def test_apht_shows_the_lms_converging_and_the_rotors_own_1x(runup, run_cli, tmp_path):
    """30,000 rpm with the controller's LMS adapting from zero (Ro et al.): APHT per 0.25 s window.
    The command error's 1X falls by 30 dB or more while the feedforward's rises to the runout it
    cancels; the gap's 1X with the identified runout taken out is the simulator's true rotor 1X
    per window within 0.3 um (the same bound as the run-up's order tracking)."""
    rec = tmp_path / "lms.mcap"
    assert run_cli("sim", "generate", "--rpm", "30000", "--ff", "lms", "--duration", "2", "--truth", "-q",
                   "-o", rec).exit_code == 0
    r = run_cli("apht", rec, "--coefficients", runup / "runout.json", "--window", "0.25", "--json",
                "--plot", tmp_path / "apht.png")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["axes"] == ["front_x", "front_y", "rear_x", "rear_y"] and len(out["time_s"]) == 8
    err = np.array(out["error_um"]["amplitude"])[:, 0, :]  # (window, axis) of 1X
    ff = np.array(out["feedforward"]["amplitude"])[:, 0, :]
    assert np.all(20 * np.log10(err[0] / err[-1]) > 30) and np.all(ff[-1] > ff[0])
    data = load(rec)
    truth, theta = data["/truth/position"], data["/amb/rotor"]["angle"]
    got = np.array(out["gap_um"]["amplitude"])[:, 0, :] * np.exp(1j * np.radians(np.array(out["gap_um"]["phase_deg"])[:, 0, :]))
    for w, start in enumerate(out["time_s"]):
        s = int(round(start * 10000))
        want = harmonic_fit(np.column_stack([truth[a][s:s + 2500] for a in out["axes"]]), theta[s:s + 2500], (1,))[0]
        assert np.max(np.abs(got[w] - want * 1e6)) < 0.3, w
    assert (tmp_path / "apht.png").stat().st_size > 30_000


def test_the_waterfall_is_the_bearings_full_spectrum_and_the_unbalance_whirls_forward(runup):
    """The run-up's waterfall is the front bearing's full spectrum (x + j y): over the upper half of
    the run the unbalance response is on the +1X line, the forward side, and the -1X side holds
    far less of it (the runout is taken out with the coefficient file)."""
    from ambdaq.workflows.runup_diagnostics import analyse

    res = analyse(open_recording(runup / "runup.mcap"), coefficients=runup / "runout.json")
    rpm, f, a = res.waterfall
    assert res.waterfall_axis == "front" and f[0] < 0 < f[-1]
    fast = rpm > 15000
    forward = [a[i, np.argmin(np.abs(f - r / 60.0))] for i, r in zip(np.flatnonzero(fast), rpm[fast])]
    backward = [a[i, np.argmin(np.abs(f + r / 60.0))] for i, r in zip(np.flatnonzero(fast), rpm[fast])]
    assert np.median(forward) > 10 * np.median(backward)


def test_critical_speeds_are_verified_as_api_684_has_it():
    """A measured resonance (a single mode of amplification 5 at 18,000 rpm, in scatter) against
    predictions: one within 5 % and amplified at least as much passes; one amplified less than
    measured, one 8 % off, and a lightly damped prediction with no peak measured each fail, as does
    the measured peak when no prediction explains it; a critically damped prediction passes with
    no peak."""
    from ambdaq.analysis.orders import PredictedCritical, verify_criticals

    rpm = np.linspace(1000, 40000, 800)
    r = rpm / 18000
    v = 10e-6 * r**2 / ((1 - r**2) + 0.2j * r)  # zeta 0.1: amplification 5
    noise = 0.3e-6 * np.array([1, 1j]) @ np.random.default_rng(0).standard_normal((2, 800))
    (peak,) = one_x_peaks(rpm, v + noise)
    assert peak.is_critical() and abs(peak.rpm - 18000) < 400

    def check(*predicted):
        return verify_criticals([PredictedCritical(p, p / 60, 1 / (2 * af), af, 1) for p, af in predicted],
                                {"front_x": [peak]}, (1000.0, 40000.0))

    (ok,) = check((18300.0, 6.0))
    assert ok.passed and ok.measured is peak and ok.axis == "front_x"
    (less,) = check((18300.0, 3.0))
    assert not less.passed  # measured more amplified than predicted
    # up to 5 % more amplified than predicted passes (AMPLIFICATION_TOLERANCE), 6 % more fails
    assert check((18300.0, peak.amplification / 1.04))[0].passed
    assert not check((18300.0, peak.amplification / 1.06))[0].passed
    off, unexplained = check((18000 * 1.08, 6.0))
    assert not off.passed and off.measured is None and not unexplained.passed and unexplained.predicted is None
    damped, missing, unexplained = check((30000.0, 1.5), (35000.0, 4.0))
    assert damped.passed and not missing.passed and not unexplained.passed
    (outside, ) = [c for c in check((50000.0, 6.0), (18100.0, 6.0))]  # 50,000 rpm is beyond the run
    assert outside.passed and outside.predicted.rpm == 18100.0


def test_a_critical_speed_keeps_api_617s_separation_margin():
    """API 617's separation margins (as API 684 explains them): none for a critically damped mode,
    5 % below / 15 % above the operating range up to an amplification of 3.55, then 16 - 6/(AF - 3)
    and 26 - 6/(AF - 3) %; the measured critical speed of amplification 5 at 18,000 rpm against four
    operating ranges, and a critically damped mode inside the range, which needs none."""
    from ambdaq.analysis.orders import PredictedCritical, separation_margin, verify_criticals

    assert separation_margin(2.0) == (0.0, 0.0)
    assert separation_margin(3.0) == separation_margin(3.55) == (0.05, 0.15)
    assert separation_margin(3.56) == pytest.approx((0.16 - 0.06 / 0.56, 0.26 - 0.06 / 0.56))  # ~5.3 %, ~15.3 %
    assert separation_margin(5.0) == pytest.approx((0.13, 0.23))
    assert separation_margin(9.0) == pytest.approx((0.15, 0.25))

    rpm = np.linspace(1000, 40000, 800)
    r = rpm / 18000
    v = 10e-6 * r**2 / ((1 - r**2) + 0.2j * r)  # zeta 0.1: amplification 5
    (peak,) = one_x_peaks(rpm, v)
    below, above = separation_margin(peak.amplification)

    def check(operating, predicted=(18300.0, 6.0)):
        p, af = predicted
        return verify_criticals([PredictedCritical(p, p / 60, 1 / (2 * af), af, 1)], {"front_x": [peak]},
                                (1000.0, 40000.0), operating_rpm=operating)[0]  # the prediction's check

    far_above = check((2000.0, 14000.0))  # the critical speed 28 % above the maximum continuous speed
    assert far_above.margin.actual == pytest.approx((peak.rpm - 14000) / 14000, rel=1e-12)
    assert far_above.margin.required == above and far_above.passed
    assert not check((2000.0, 15500.0)).passed  # 16 % above: less than the ~23 % asked
    near_below = check((20000.0, 30000.0))  # 10 % below the minimum operating speed, ~13 % asked
    assert near_below.margin.actual == pytest.approx((20000 - peak.rpm) / 20000, rel=1e-12)
    assert near_below.margin.required == below and not near_below.passed
    assert check((22000.0, 30000.0)).passed
    inside = check((10000.0, 25000.0))
    assert inside.margin.actual < 0 and not inside.passed
    damped = check((10000.0, 40000.0), predicted=(30000.0, 1.5))  # amplification 1.5 inside the range
    assert damped.margin.required == 0.0 and damped.passed


DETUNED_D = (0.00075, 0.00075, 0.001, 0.001, 0.002)  # s: Ro et al.'s radial D halved, the axial kept


def test_a_detuned_loops_amplified_critical_speed_is_where_the_model_at_its_recorded_gains_puts_it(runup, run_cli,
                                                                                                   tmp_path):
    """API 684's check on a mode amplified past 2.5: the spindle's radial D halved (`sim generate
    --param pid.d=...`, what `controller param pid.d` writes on the served controller) leaves its
    forward tilt mode near 180 Hz with zeta 0.13. The recording states the gains its controller ran,
    `runup --model spindle` builds the loop at them, and the run-up 3,000-15,000 rpm measures that
    critical speed within 5 % of the prediction and amplified as the model's own 1X response is.
    Ground truth: the crossing found from the model by bisection, and the true rotor's 1X."""
    from ambdaq.analysis.orders import loop_modes, verify_criticals
    from ambdaq.sim.rigs.spindle import SpindleRig
    from ambdaq.workflows.runup_diagnostics import model_modes

    rec = tmp_path / "detuned.mcap"
    r = run_cli("sim", "generate", "--rpm", "3000:15000:6", "--duration", "6", "--truth", "-q", "-o", rec,
                "--param", "pid.d=" + ",".join(map(str, DETUNED_D)))
    assert r.exit_code == 0, r.output
    stated = load(rec).metadata["ambdaq.calibration.rig"]["controller.pid.d"]
    assert [float(v) for v in stated.split(",")] == pytest.approx(DETUNED_D, rel=1e-12)
    r = run_cli("runup", rec, "--coefficients", runup / "runout.json", "--model", "spindle", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert not out["model_modes"]["assumed"] and "pid.d 0.00075, 0.00075, 0.001" in out["model_modes"]["basis"]
    (crit,) = [c for c in out["critical_speeds"] if c["predicted_amplification"] >= CRITICAL_AMPLIFICATION]
    assert crit["passed"] and crit["whirl"] == "forward" and crit["predicted_amplification_from"] == "response"
    assert abs(crit["deviation"]) < 0.05 and crit["measured_amplification"] > 3.5
    # the prediction: where the loop's forward mode at these gains meets 1X, by bisection (to 1 rpm)
    model = SpindleRig()
    p, i, _ = model.pid_gains
    model.set_pid(p, i, np.array(DETUNED_D))

    def forward(rpm: float) -> float:
        M, _B, C = model.loop_matrices(rpm)
        f, _z, whirl = loop_modes(M, model.h, fmax_hz=2000.0, outputs=C, pairs=((0, 1), (2, 3)))
        return float(f[whirl == 1][np.argmin(np.abs(f[whirl == 1] - rpm / 60))])

    lo, hi = 9000.0, 13000.0
    while hi - lo > 1.0:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if forward(mid) > mid / 60.0 else (lo, mid)
    assert crit["predicted_rpm"] == pytest.approx(lo, rel=0.005)  # the Campbell grid interpolates it
    # the measurement: the true rotor's 1X peak, tracked alike, is where and as amplified as the gap's
    # (the identified runout is 0.07 um off the true one against a 72 um peak)
    data = load(rec)
    truth, rot = data["/truth/position"], data["/amb/rotor"]
    true = order_track(np.column_stack([truth[a] for a in out["axes"]]), rot["angle"], rot["speed"] * 60 / (2 * np.pi))
    k = list(out["axes"]).index(crit["axis"])
    (peak,) = [q for q in one_x_peaks(true.rpm, true.order(1)[:, k]) if q.is_critical()]
    assert crit["measured_rpm"] == pytest.approx(peak.rpm, abs=0.1)
    assert crit["measured_amplification"] == pytest.approx(peak.amplification, rel=0.01)
    # the model's own 1X response (its unbalance and runout through the loop) is the rotor's: the
    # peak amplitude within 1 % (the run-up sweeps through the mode; the model is steady)
    resp = out["model_modes"]["response_1x"]
    assert max(resp[crit["axis"]]["amplitude_um"]) == pytest.approx(peak.amplitude * 1e6, rel=0.01)
    # the limits are options (API 684's by default): a speed tolerance of 0.1 % is tighter than the
    # 0.3 % this run is off, so the prediction is not met and the measured one is unexplained; a
    # machine whose specification calls modes critically damped below 5 has none here
    tight = json.loads(run_cli("runup", rec, "--coefficients", runup / "runout.json", "--model", "spindle", "--json",
                               "--critical-tolerance", "0.1").stdout)["critical_speeds"]
    missed = [c for c in tight if c["predicted_rpm"] == crit["predicted_rpm"]]
    assert [c["passed"] for c in missed] == [False] and missed[0]["measured_rpm"] is None
    assert any(c["predicted_rpm"] is None and not c["passed"] for c in tight)
    damped = json.loads(run_cli("runup", rec, "--coefficients", runup / "runout.json", "--model", "spindle", "--json",
                                "--critically-damped", "5").stdout)
    assert all(c["passed"] and "critically damped" in c["rule"] for c in damped["critical_speeds"])
    assert not any(p["critical"] for peaks in damped["peaks_1x"].values() for p in peaks)
    # at Ro et al.'s gains the model puts its forward mode near 19,000 rpm, critically damped: this
    # run's critical speed is one it does not explain
    default = model_modes("spindle", 3000.0, 15000.0, {}, ("front_x", "front_y", "rear_x", "rear_y"))
    assert default.assumed
    peaks = {a: one_x_peaks(true.rpm, true.order(1)[:, j]) for j, a in enumerate(out["axes"])}
    checks = verify_criticals(default.criticals(), peaks, (3000.0, 15000.0))
    assert any(c.predicted is None and not c.passed for c in checks)


def test_what_sim_generate_param_refuses_is_one_line_exit_2(run_cli, tmp_path):
    for spec, said in (("pid.d=0.001,0.001", "expected 5 values"), ("pid.q=1", "NAME=VALUES with a writable"),
                       ("pid.d", "NAME=VALUES"), ("pid.p=0,1,1,1,1", "within"), ("ff.table=1", "read-only"), ("ff.mode=1.5", "0 off, 1 table, 2 LMS"),
                       ("pid.d=a,b,c,d,e", "comma-separated numbers")):
        r = run_cli("sim", "generate", "--duration", "0.1", "--param", spec, "-q", "-o", tmp_path / "x.mcap")
        assert r.exit_code == 2 and said in r.output and len(r.output.strip().splitlines()) == 1, (spec, r.output)
    assert not (tmp_path / "x.mcap").exists()


def test_a_recordings_malformed_gains_are_refused_in_one_line_when_the_model_needs_them(run_cli, tmp_path):
    """A controller's calibration that states its gains wrongly (one D for five axes, a P of zero:
    a rig file's [device.calibration] can say anything) is one line, exit 2, under --model spindle;
    without --model nothing needs them and the run-up is tracked."""
    from ambdaq.acquisition.recorder import Recorder, RecordOptions
    from ambdaq.sim.source import SimSource
    from ambdaq.speed import SpeedProfile

    for key, text, said in (("controller.pid.d", "0.001", "5 gains, one per axis"),
                            ("controller.pid.p", "0,1.6,1.6,1.6,1.6", "at least 1e-06"),
                            ("controller.pid.i", "1,1,1,1,nan", "each finite")):
        source = SimSource("spindle", speed=SpeedProfile(3000, 12000, 1.0))
        source.add_calibration({key: text})
        path = tmp_path / f"{key}.mcap"
        Recorder([source], path, RecordOptions(duration_s=1.0, fsync=False)).run()
        r = run_cli("runup", path, "--model", "spindle")
        assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
        assert f"the recording's {key} is {text!r}" in r.output and said in r.output, r.output
        assert run_cli("runup", path, "--json").exit_code == 0


def test_the_cone_with_an_unbalance_whirls_forward_through_critically_damped_modes(run_cli, tmp_path):
    """The cone rig with a mass unbalance (`sim generate --unbalance`; Jeong et al. give none) run
    up to 6,000 rpm: its 1X is the true rotor's, it whirls forward at both bearings (z 90 degrees
    behind y, as the spin turns y towards z), and `--model cone` verifies it as API 684 asks of a
    loop whose radial modes are all critically damped: no critical speed predicted or measured, on
    the gap as on the true rotor. The model's 57 Hz mode is axial (no whirl at the bearings), so it
    is no 1X critical speed; its radial modes split forward and backward as the rotor spins up."""
    rec = tmp_path / "unbalanced.mcap"
    r = run_cli("sim", "generate", "--profile", "cone", "--rpm", "0:6000:3", "--duration", "3", "--truth",
                "--unbalance", "2e-5:2e-5", "-q", "-o", rec)
    assert r.exit_code == 0, r.output
    r = run_cli("runup", rec, "--model", "cone", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    axes = list(out["axes"])
    data = load(rec)
    truth, rot = data["/truth/position"], data["/amb/rotor"]
    true = order_track(np.column_stack([truth[a] for a in axes]), rot["angle"], rot["speed"] * 60 / (2 * np.pi))
    rpm = np.array(out["rpm"])
    for i, a in enumerate(axes):
        got = np.array(out["axes"][a]["1X"]["amplitude_um"]) * np.exp(-1j * np.radians(out["axes"][a]["1X"]["phase_lag_deg"]))
        # the sensors' 0.1 um RMS noise over 8 revolutions, and the 4-decimal rounding: 0.1 um
        assert np.abs(got - true.order(1)[:, i] * 1e6).max() < 0.1, a
        assert np.abs(got[-1]) > 10  # tens of um at 6,000 rpm: an unbalance response, not noise
        assert one_x_peaks(true.rpm, true.order(1)[:, i]) == [] or not any(
            p.is_critical() for p in one_x_peaks(true.rpm, true.order(1)[:, i]))
    for y, z in (("y1", "z1"), ("y2", "z2")):
        lag = (np.array(out["axes"][y]["1X"]["phase_lag_deg"]) - np.array(out["axes"][z]["1X"]["phase_lag_deg"]) + 180) % 360 - 180
        assert np.all(np.abs(lag[rpm > 1000] + 90) < 2), (y, z)
    assert not any(p["critical"] for peaks in out["peaks_1x"].values() for p in peaks)
    assert all(c["passed"] for c in out["critical_speeds"])
    modes = out["model_modes"]
    axial = [w for f, w in zip(modes["freq_hz"][0], modes["whirl"][0]) if f and abs(f - 57.1) < 0.5]
    assert axial == [None]  # 57 Hz, no whirl: not on the 1X line's list
    assert {w for w in modes["whirl"][-1] if w} == {"forward", "backward"}
    assert all(abs(c["predicted_hz"] - 57.1) > 0.5 for c in out["critical_speeds"])
