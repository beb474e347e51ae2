"""Jeon et al.: the `lorentz` simulator profile and `ambdaq selfsense` against the paper's claims."""

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from ambdaq.analysis.selfsense import angle_error, error_gain, estimate_angle, lyapunov_bound
from ambdaq.cli.main import cli
from ambdaq.sim.rigs.lorentz import LORENTZ, POLE_PAIRS, LorentzRig, machine
from ambdaq.speed import SpeedProfile

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def generate(path, rpm, duration):
    r = CliRunner().invoke(cli, ["sim", "generate", "--profile", "lorentz", "--rpm", rpm, "--duration", str(duration),
                                 "-o", str(path), "-q"])
    assert r.exit_code == 0, r.output
    return str(path)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("lorentz")
    return {"start": generate(d / "start.mcap", "0:100:2", 6),
            **{rpm: generate(d / f"r{rpm}.mcap", str(rpm), 3) for rpm in (100, 300, 500, 1000)}}


def selfsense(*args):
    r = CliRunner().invoke(cli, ["selfsense", *args, "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def test_coil_voltages_are_eq_7_with_the_true_coils():
    """Noise off: eq. 10 with each coil's true R and L gives exactly the flux change the true
    angle implies (the voltage averaged over the period ending at each sample)."""
    rig = LorentzRig(speed=SpeedProfile(300, 300), truth=True, noise=False)
    b = rig.run(2000)
    v, i, th = b.values["/coil/voltage"], b.values["/coil/current"], b.values["/truth/rotor"][:, 0]
    res, ind, ripple = machine(LORENTZ)
    lam0 = LORENTZ.emf_constant / POLE_PAIRS
    for j in range(6):
        a = th - j * np.pi / 3
        rho = ripple[0, 0] * np.cos(a) + ripple[0, 1] * np.sin(a) + ripple[1, 0] * np.cos(2 * a) + ripple[1, 1] * np.sin(2 * a)
        lam = lam0 * np.cos(4 * a) * (1 + rho)
        dl = (v[1:, j] - res[j] * 0.5 * (i[1:, j] + i[:-1, j])) / LORENTZ.sample_rate - ind[j] * np.diff(i[:, j])
        np.testing.assert_allclose(dl, np.diff(lam), atol=2e-3 * np.abs(np.diff(lam)).max())
    assert np.ptp(res) > 0 and np.ptp(ind) > 0  # the coils differ from the datasheet, and from each other


def test_estimator_is_exact_on_an_ideal_machine():
    """No mismatch, ideal magnets, no noise: what is left is discretisation, far below the paper's 1 deg."""
    ideal = replace(LORENTZ, r_mismatch=0.0, l_mismatch=0.0, pole_variation=0.0)
    rig = LorentzRig(ideal, speed=SpeedProfile(500, 500), truth=True, noise=False)
    b = rig.run(20000)
    th = b.values["/truth/rotor"][:, 0]
    est = estimate_angle(b.values["/coil/voltage"], b.values["/coil/current"], ideal.sample_rate,
                         resistance=ideal.resistance, inductance=ideal.inductance, emf_constant=ideal.emf_constant,
                         theta0=th[0] + np.deg2rad(8))
    err = np.rad2deg(angle_error(est, th))
    assert np.abs(err[5000:]).max() < 0.02


def test_start_up_from_8_degrees_converges_within_5_s(recordings, tmp_path):
    """Jeon et al. Fig. 5: 0 to 100 rpm with an 8 deg initial error; below 1 deg within 5 s."""
    r = selfsense(recordings["start"], "--initial-error", "8", "--plot", str(tmp_path / "fig5.png"))
    assert r["speed_rpm"]["start"] < 5 and 90 < r["speed_rpm"]["end"] < 110
    assert r["converged_s"] is not None and r["converged_s"] < 5.0
    assert r["steady"]["mean_abs_deg"] <= 1.0 and r["steady"]["max_abs_deg"] < 1.0
    assert (tmp_path / "fig5.png").stat().st_size > 10_000


def test_steady_error_from_100_to_1000_rpm(recordings, tmp_path):
    """Jeon et al. Fig. 7: mean absolute error 1 deg or less from 100 to 1,000 rpm; the spread falls with speed."""
    files = [recordings[rpm] for rpm in (100, 300, 500, 1000)]
    out = CliRunner().invoke(cli, ["selfsense", *files, "--json", "--plot", str(tmp_path / "fig7.png")])
    assert out.exit_code == 0, out.output
    rows = json.loads(out.output)
    for rpm, r in zip((100, 300, 500, 1000), rows):
        assert r["steady"]["speed_rpm"] == pytest.approx(rpm, rel=0.02)
        assert r["steady"]["mean_abs_deg"] <= 1.0 and r["steady"]["max_abs_deg"] <= 1.0
    stds = [r["steady"]["std_deg"] for r in rows]
    assert stds[-1] < stds[0]  # more back-EMF against the same R and L errors
    # a wrong resistance (the estimator's R 10 % high) shows as a larger error at low speed
    wrong = selfsense(recordings[100], "--resistance", str(LORENTZ.resistance * 1.1))
    assert abs(wrong["steady"]["mean_deg"]) > 5 * abs(rows[0]["steady"]["mean_deg"]) + 0.05


def test_convergence_region_matches_the_lyapunov_bound(recordings):
    """Eq. 17-18: a sweep of initial errors converges exactly on (-30, 60) deg; outside it the
    estimate locks 90 deg away (the same electrical angle)."""
    r = selfsense(recordings["start"], "--sweep")
    sw = r["sweep"]
    conv = [e for e, c in zip(sw["initial_deg"], sw["converges"]) if c]
    assert sw["agrees"] and sw["lyapunov_deg"] == [-30.0, 60.0]
    assert min(conv) >= -30 and max(conv) == 55 and conv == list(range(min(conv), 60, 5))
    for e0, f in zip(sw["initial_deg"], sw["final_deg"]):
        if e0 >= 60:
            assert f == pytest.approx(90, abs=1)
        elif e0 < -30:
            assert f == pytest.approx(-90, abs=1)


def test_lyapunov_bound_against_the_error_recursion():
    """The bound from eq. 17 against eq. 17's recursion iterated directly, and the paper's 12,500 rpm."""
    b = lyapunov_bound(10_000.0)
    assert (round(b.eps_low_deg), round(b.eps_high_deg)) == (-30, 60)
    for e0 in np.arange(-85, 150, 5.0):
        eps = np.deg2rad(e0)
        for _ in range(20000):
            eps -= error_gain(eps) * 1e-3  # 1 mrad of rotation per step, forward
        inside = -30 < e0 < 60
        assert (abs(np.rad2deg(eps)) < 0.1) == inside, e0
    # the speed bound scales with the sample rate; the paper's 12,500 rpm is a ~200 us period
    assert lyapunov_bound(5000.0).max_rpm == pytest.approx(12_500, rel=0.02)
    assert lyapunov_bound(10_000.0).max_rpm == pytest.approx(2 * lyapunov_bound(5000.0).max_rpm)


def test_selfsense_bad_input(recordings, tmp_path):
    runner = CliRunner()
    cone = tmp_path / "cone.mcap"
    assert runner.invoke(cli, ["sim", "generate", "--profile", "cone", "--duration", "0.1", "-o", str(cone), "-q"]).exit_code == 0
    r = runner.invoke(cli, ["selfsense", str(cone)])
    assert r.exit_code == 2 and "no ambdaq topic /coil/voltage" in r.output and len(r.output.strip().splitlines()) == 1
    r = runner.invoke(cli, ["selfsense", recordings[100], "--resistance", "nan"])
    assert r.exit_code == 2 and "resistance must be a positive number" in r.output
    r = runner.invoke(cli, ["selfsense", str(tmp_path / "missing.mcap")])
    assert r.exit_code == 2
