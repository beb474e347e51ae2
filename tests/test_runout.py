"""Runout identification against the simulator's ground truth and Ro et al.'s equations."""

import numpy as np
import pytest
from scipy.signal import lfilter

from ambdaq.analysis.rotor import RigidRotor
from ambdaq.analysis.runout import (harmonic_fit, lms_offline, notch_filter, runout_from_sensor,
                                    separate_unbalance, synchronous_average)
from ambdaq.speed import RPM_TO_RAD_S, SpeedProfile
from ambdaq.sim.rigs.spindle import SPINDLE, SpindleRig

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

P = SPINDLE
ROTOR = RigidRotor(P.mass, P.jt, P.jp, P.a, P.b, tuple(ax.kx for ax in P.axes), tuple(ax.ki for ax in P.axes))
TRUE = P.runout_amp[:, :6] * np.exp(1j * P.runout_phase[:, :6])  # (axis, harmonic)
BIG = np.abs(TRUE) >= 1e-6  # the "every harmonic of 1 um or more"


def record(rpm, seconds, seed=0):
    rig = SpindleRig(seed=seed, speed=SpeedProfile(rpm, rpm), truth=True)
    rig.run(5000)  # settle
    b = rig.run(int(seconds * P.sample_rate))
    return b.values["/amb/rotor"][:, 0], b.values["/amb/gap"], b.values["/amb/current"]


def identify(theta, gap, current, rpm, estimate=harmonic_fit):
    w = rpm * RPM_TO_RAD_S
    G = np.stack([estimate(gap[:, a], theta) for a in range(5)], axis=1)  # (harmonic, axis)
    I = np.stack([estimate(current[:, a], theta) for a in range(5)], axis=1)
    return np.array([runout_from_sensor(G[k], I[k], (k + 1) * w, w, ROTOR) for k in range(6)]).T


def assert_within(est, mask, truth=TRUE, amp=0.02, deg=2.0):
    ratio = est[mask] / truth[mask]
    assert np.abs(np.abs(ratio) - 1).max() < amp, np.abs(np.abs(ratio) - 1).max()
    assert np.degrees(np.abs(np.angle(ratio))).max() < deg, np.degrees(np.abs(np.angle(ratio))).max()


@pytest.fixture(scope="module")
def slow_roll():
    return record(800, 10.0)


@pytest.mark.parametrize("method", ["fit", "average", "lms"])
def test_slow_roll_identifies_every_harmonic_within_2_percent_and_2_degrees(slow_roll, method):
    est_fn = {"fit": harmonic_fit,
              "average": lambda x, th: synchronous_average(x, th),
              "lms": lambda x, th: lms_offline(x, th, mu=0.002).phasors}[method]
    assert_within(identify(*slow_roll, 800, est_fn), BIG)


def test_levitated_sensor_signal_is_not_the_runout(slow_roll):
    """The runout is fed back: at slow roll the rotor moves about -2 r, the sensor reads about -1.03 r."""
    theta, gap, _ = slow_roll
    ratio = harmonic_fit(gap[:, 0], theta)[0] / TRUE[0, 0]
    assert abs(abs(ratio) - 1.03) < 0.02 and abs(abs(np.degrees(np.angle(ratio))) - 180) < 10


def test_at_speed_harmonics_above_1x_are_runout():
    est = identify(*record(30000, 2.0), 30000)
    mask = BIG.copy()
    mask[:, 0] = False  # 1X also holds the unbalance response: see the separation test
    assert_within(est, mask)
    assert np.abs(np.abs(est[:4, 0] / TRUE[:4, 0]) - 1).max() > 0.02  # and 1X alone is not


def test_several_speeds_separate_runout_from_unbalance():
    """1X runout from run-up speeds well below the Nyquist frequency (the continuous rotor model
    ignores the controller's sampling, which shows above ~30,000 rpm: 1X at 500 Hz, 20 samples
    per revolution)."""
    speeds = (3000, 9000, 15000, 21000)
    est = [identify(*record(rpm, 2.0), rpm)[:, 0] for rpm in speeds]
    sep = separate_unbalance(np.array(est), np.array(speeds) * RPM_TO_RAD_S, ROTOR)
    assert_within(sep.runout[:, None], BIG[:, :1], TRUE[:, :1])
    # the unbalance is a by-product, small at these speeds and so less well determined
    true_u = np.array(P.unbalance) * np.exp(1j * np.array(P.unbalance_phase))
    np.testing.assert_allclose(sep.unbalance, true_u, rtol=0.2)
    with pytest.raises(ValueError, match="two or more different speeds"):
        separate_unbalance(np.array(est[:1]), np.array([1000.0]), ROTOR)


def test_offline_lms_is_the_notch_filter_of_eq_16():
    """Ro et al. eq. 15-16: the LMS feedforward's error is the IIR notch applied to the signal."""
    rng = np.random.default_rng(1)
    n, w0, mu = 20000, 2 * np.pi * 0.0371, 0.004  # k Omega h = w0 per sample
    theta = w0 * np.arange(n)
    x = 2e-6 * np.sin(theta + 0.7) + 0.3e-6 * rng.standard_normal(n)
    x -= x.mean()
    lms = lms_offline(x, theta, mu=mu, harmonics=(1,))
    b, a = notch_filter(mu, w0)
    np.testing.assert_allclose(lms.error, lfilter(b, a, x), rtol=0, atol=1e-18)
    # and the weights converge to the harmonic
    assert abs(lms.phasors[0] / (2e-6 * np.exp(0.7j)) - 1) < 0.02


def test_notch_has_zero_gain_at_its_harmonic():
    from scipy.signal import freqz

    b, a = notch_filter(0.01, 0.3)
    _, h = freqz(b, a, worN=[0.3, 0.6])
    assert abs(h[0]) < 1e-12 and 0.9 < abs(h[1]) < 1.1


def test_synchronous_average_refuses_too_few_angles():
    theta = np.arange(1000) * (2 * np.pi / 20)  # 20 samples per revolution, always the same angles
    with pytest.raises(ValueError, match="angle bins"):
        synchronous_average(np.sin(theta), theta)


@pytest.mark.parametrize("n, harmonics", [(37, (1, 2, 3)), (5000, (1, 2, 3, 4, 5, 6)), (800, (2, 5, 7))])
def test_one_pass_fit_equals_least_squares_on_an_explicit_basis(n, harmonics):
    """A^T A built from sums of sin/cos m theta (sum and difference identities) is the exact LS
    over the orders it fits (those asked and the guard orders below them: fitted_orders), of which
    it reports those asked."""
    from ambdaq.analysis.runout import fitted_orders

    rng = np.random.default_rng(n)
    theta = np.cumsum(rng.uniform(0.01, 0.3, n))  # irregular angles, not whole revolutions
    x = rng.standard_normal((n, 3))
    basis = fitted_orders(harmonics, theta)
    assert set(harmonics) <= set(basis) and set(range(1, 9)) <= set(basis)  # 0.3 rad a step at most: 8X is resolved
    k = np.asarray(basis)
    A = np.concatenate([np.sin(np.outer(theta, k)), np.cos(np.outer(theta, k)), np.ones((n, 1))], axis=1)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    want = (coef[: len(k)] + 1j * coef[len(k) : 2 * len(k)])[[basis.index(h) for h in harmonics]]
    np.testing.assert_allclose(harmonic_fit(x, theta, harmonics), want, rtol=1e-7, atol=1e-9)


def test_an_order_the_fit_is_not_asked_for_does_not_leak_into_those_it_is():
    """A 10 um 2X beside a 3 um 1X over 12.4 revolutions: the 1X asked alone is the 1X (the 2X
    fitted too and not reported); a fit of the 1X alone had been 0.2 um off."""
    th = np.linspace(0.0, 12.4 * 2 * np.pi, 5000)
    x = 3e-6 * np.sin(th + 0.4) + 10e-6 * np.sin(2 * th + 1.0)
    (p,) = harmonic_fit(x, th, (1,))
    assert abs(p - 3e-6 * np.exp(0.4j)) < 1e-12
    A = np.column_stack([np.sin(th), np.cos(th), np.ones_like(th)])  # what a 1X-only fit gives
    c = np.linalg.lstsq(A, x, rcond=None)[0]
    assert abs(c[0] + 1j * c[1] - 3e-6 * np.exp(0.4j)) > 0.1e-6


def test_runout_uncertainty_is_the_scatter_of_its_estimate(tmp_path):
    """Each harmonic's standard uncertainty (the Cramer-Rao bound from the noise the recording holds)
    against the scatter of the estimate itself over 50 simulated recordings that differ only in
    their noise (seeds 1-50, 0.35 s at 30,000 rpm less its first 50 ms, 2X-4X; 1X holds the unbalance
    response and is the same test). The simulated rig starts levitating at rest: its first 30 ms are
    a start-up transient, the same for every seed (residuals of two seeds correlate 0.99 there, 0.01
    after), which a recording of a running machine does not have. The pooled scatter, normalised by each estimate's own stated uncertainty, is within
    1.2x of 1 (the pooled figure over 50 x 5 axes x 3 orders x 2 parts = 1,500 values is good to
    about 2 %; a single axis and order's, from 50, only to 10 %, hence pooled, and each within 1.4x)."""
    from ambdaq.daq import load
    from ambdaq.acquisition.recorder import Recorder, RecordOptions
    from ambdaq.sim.source import SimSource
    from ambdaq.workflows.runout import identify_recordings

    est, unc = [], []
    for seed in range(1, 51):
        path = tmp_path / f"r{seed}.mcap"
        Recorder([SimSource("spindle", seed=seed, speed=SpeedProfile(30000, 30000))], path,
                 RecordOptions(duration_s=0.35, fsync=False)).run()
        ident = identify_recordings([load(path, topics=["/amb/gap", "/amb/current", "/amb/rotor"], start=0.05)],
                                    [2, 3, 4], "fit")
        est.append(ident.per_file[0])
        unc.append(ident.uncertainty)
        path.unlink()
    est, unc = np.array(est), np.array(unc)  # (run, harmonic, axis)
    assert np.all(np.isfinite(unc)) and np.all(unc > 0)
    centred = est - est.mean(axis=0)
    z = np.concatenate([(centred.real / unc).ravel(), (centred.imag / unc).ravel()])
    pooled = float(np.sqrt(np.mean(z**2) * 50 / 49))  # the mean was estimated from the same 50
    assert 1 / 1.2 < pooled < 1.2, pooled
    each = np.sqrt(np.mean((centred.real / unc) ** 2 + (centred.imag / unc) ** 2, axis=0) / 2 * 50 / 49)
    assert np.all((each > 1 / 1.4) & (each < 1.4)), each
