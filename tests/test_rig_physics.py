"""The simulated spindle against Ro et al.: stability over speed, stiffness and damping, runout."""

from dataclasses import replace

import numpy as np
import pytest

from ambdaq.analysis.amb import equivalent_stiffness_damping
from ambdaq.machines.spindle_loop import SpindleLoop
from ambdaq.speed import SpeedProfile
from ambdaq.sim.rigs.spindle import AXES, SPINDLE, SpindleRig

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def quiet_params(**kw):
    return replace(SPINDLE, runout_amp=np.zeros_like(SPINDLE.runout_amp), **kw)


@pytest.mark.parametrize("rpm", [0, 6000, 10000, 20000, 30000, 40000, 50000])
def test_linearised_closed_loop_is_stable(rpm):
    # the Jacobian of the simulation step itself; stable iff every eigenvalue is inside the unit circle
    M = SpindleRig().loop_matrices(rpm)[0]
    radius = np.abs(np.linalg.eigvals(M)).max()
    assert radius < 1.0
    # the slowest pole is the integrator; everything else is well inside
    assert radius > 0.999


@pytest.mark.parametrize("rpm", [0, 1250, 7000, 30000, 55000])  # the kernel's rotor steps: every 50 rpm
@pytest.mark.parametrize("gains", ["Ro et al.", "detuned"])
def test_the_kernel_steps_the_machines_loop_model_at_every_speed(rpm, gains):
    """The machine's loop model (machines/spindle_loop.py, written from Ro et al. eq. 1-3: what
    ``runup --model``, ``lms --plant rig`` and the ISO 14839-3 predictions read) is what the
    simulator's kernel steps, probed one unit perturbation at a time with noise, runout, unbalance,
    gravity and quantisation off: equal to rounding (1e-12 of the largest entry; the probe's
    perturbation of 1e-9 and the kernel's sums in another order leave differences of order 1e-15),
    at Ro et al.'s gains and at a retuned controller's."""
    rig = SpindleRig()
    if gains == "detuned":
        rig.set_pid([1.2, 1.2, 1.8, 1.8, 1.6], [0.5, 0.5, 2.0, 2.0, 1.0], [0.001, 0.001, 0.0025, 0.0025, 0.002])
    model = SpindleLoop(SPINDLE, tuple(tuple(map(float, g)) for g in rig.pid_gains)).matrices(rpm)
    for name, ours, probed in zip("MBC", model, rig.probe_loop(rpm)):
        np.testing.assert_allclose(ours, probed, rtol=0, atol=1e-12 * np.abs(probed).max(), err_msg=name)


def test_least_damped_mode_is_reasonably_damped_over_speed():
    for rpm in (0, 25000, 50000):
        s = np.log(np.linalg.eigvals(SpindleRig().loop_matrices(rpm)[0]).astype(complex)) / 1e-4
        osc = s[np.abs(s.imag) > 2 * np.pi * 5]
        zeta = -osc.real / np.abs(osc)
        assert zeta.min() > 0.2, (rpm, zeta.min())


def test_run_up_0_to_50000_rpm_stays_levitated():
    rig = SpindleRig(speed=SpeedProfile(0, 50000, 5.0), truth=True)
    peak = np.zeros(5)
    i_peak = 0.0
    for _ in range(50):
        b = rig.run(1000)
        peak = np.maximum(peak, np.abs(b.values["/truth/position"]).max(axis=0))
        i_peak = max(i_peak, np.abs(b.values["/amb/current"]).max())
    assert b.values["/amb/rotor"][-1, 1] == pytest.approx(50000 * 2 * np.pi / 60, rel=1e-4)
    # crossing the ~320 Hz rigid-body mode amplifies the runout fed back through the sensors,
    # but the rotor stays within a fifth of the 0.3 mm air gap and no coil exceeds the 8 A limit
    assert peak.max() < 60e-6, dict(zip(AXES, peak))
    assert SPINDLE.front.bias + i_peak < SPINDLE.coil_max_current


@pytest.mark.parametrize("rpm", [3000, 12000, 30000, 50000])
def test_equivalent_stiffness_and_damping_match_the_model(rpm):
    """Unbalance excites each bearing at 1X; F = Kx x + Ki i gives -(Keq + j w Ceq) x."""
    p = quiet_params()
    rig = SpindleRig(p, speed=SpeedProfile(rpm, rpm), noise=False, truth=True)
    rig.run(20000)  # settle
    b = rig.run(20000)
    th = b.values["/amb/rotor"][:, 0]
    basis = np.column_stack([np.cos(th), np.sin(th), np.ones_like(th)])
    f = rpm / 60.0
    for axis, ax in ((0, p.front), (2, p.rear)):
        cx = np.linalg.lstsq(basis, b.values["/truth/position"][:, axis], rcond=None)[0]
        ci = np.linalg.lstsq(basis, b.values["/amb/current"][:, axis], rcond=None)[0]
        X, I = cx[0] - 1j * cx[1], ci[0] - 1j * ci[1]
        measured = -(ax.kx + ax.ki * I / X)
        pred = equivalent_stiffness_damping(
            np.array([f]), ki=ax.ki, kx=ax.kx, sensor_gain=p.sensor_gain, p=ax.pid_p, i=ax.pid_i, d=ax.pid_d,
            nd=p.derivative_filter, h=1 / p.sample_rate, amp_gain=ax.amp_gain, amp_wn_hz=ax.amp_wn_hz,
            amp_zeta=ax.amp_zeta,
        )
        expected = pred.stiffness[0] + 1j * 2 * np.pi * f * pred.damping[0]
        assert abs(measured - expected) / abs(expected) < 0.02, (axis, measured, expected)


def test_low_frequency_stiffness_is_table_1_and_pid():
    # Keq -> P Kamp Ki Ks - Kx at low frequency: 1.724e6 N/m front, 1.149e6 N/m rear
    for ax, expected in ((SPINDLE.front, 1.724e6), (SPINDLE.rear, 1.149e6)):
        k = ax.pid_p * ax.amp_gain * ax.ki * SPINDLE.sensor_gain - ax.kx
        assert k == pytest.approx(expected, rel=1e-3)
        pred = equivalent_stiffness_damping(
            np.array([2.0, 20.0]), ki=ax.ki, kx=ax.kx, sensor_gain=SPINDLE.sensor_gain, p=ax.pid_p, i=ax.pid_i,
            d=ax.pid_d, nd=15, h=1e-4, amp_gain=ax.amp_gain, amp_wn_hz=ax.amp_wn_hz, amp_zeta=ax.amp_zeta,
        )
        assert pred.stiffness[0] == pytest.approx(k, rel=0.01)
        # damping: Ki Ks Kamp (D - I/w^2 - P tau), the derivative less the integrator and the
        # proportional action delayed by the amplifier (2 zeta / wn) and the D/A hold (h/2)
        w = 2 * np.pi * 20.0
        tau = 2 * ax.amp_zeta / (2 * np.pi * ax.amp_wn_hz) + 0.5e-4
        c = ax.ki * SPINDLE.sensor_gain * ax.amp_gain * (ax.pid_d - ax.pid_i / w**2 - ax.pid_p * tau)
        assert pred.damping[1] == pytest.approx(c, rel=0.02)


def test_runout_is_fixed_to_the_rotor_angle_at_every_speed():
    """Electrical runout is a function of angle only: same pattern at 800 and 30,000 rpm."""
    patterns = []
    for rpm in (800, 30000):
        rig = SpindleRig(speed=SpeedProfile(rpm, rpm), truth=True, noise=False)
        b = rig.run(20000)
        th = b.values["/amb/rotor"][:, 0]
        k = np.arange(1, 7)
        basis = np.column_stack([np.sin(np.outer(th, k)), np.cos(np.outer(th, k))])
        patterns.append(np.linalg.lstsq(basis, b.values["/truth/runout"][:, 0], rcond=None)[0])
    np.testing.assert_allclose(patterns[0], patterns[1], atol=1e-9)
    amp = np.hypot(patterns[0][:6], patterns[0][6:])
    np.testing.assert_allclose(amp, SPINDLE.runout_amp[0, :6], atol=1e-9)


def test_defaults_are_in_the_papers_runout_range():
    # Ro et al.: 15 um front, 30 um rear on the spindle; 1X and 2X dominant
    total = SPINDLE.runout_amp.sum(axis=1) * 1e6
    assert 15 <= total[0] <= 20 and 28 <= total[2] <= 32
    assert np.all(np.argsort(SPINDLE.runout_amp[:4], axis=1)[:, -2:].min(axis=1) <= 1)


def test_deterministic_for_a_seed_and_different_across_seeds():
    a = SpindleRig(seed=3, speed=SpeedProfile(20000, 20000)).run(2000).values["/amb/gap"]
    b = SpindleRig(seed=3, speed=SpeedProfile(20000, 20000)).run(2000).values["/amb/gap"]
    c = SpindleRig(seed=4, speed=SpeedProfile(20000, 20000)).run(2000).values["/amb/gap"]
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_block_size_does_not_change_the_result():
    """Stepping in blocks of any size gives the same trajectory (noise off, so draws do not matter)."""
    rig_a = SpindleRig(speed=SpeedProfile(0, 20000, 0.3), noise=False)
    rig_b = SpindleRig(speed=SpeedProfile(0, 20000, 0.3), noise=False)
    whole = rig_a.run(3000).values["/amb/error"]
    parts = np.concatenate([rig_b.run(n).values["/amb/error"] for n in (1, 999, 1000, 1000)])
    np.testing.assert_allclose(whole, parts, rtol=0, atol=1e-15)


def test_keyphasor_pulses_once_per_revolution():
    rig = SpindleRig(speed=SpeedProfile(6000, 6000))  # 100 rev/s: a pulse every 100 samples
    pulses = np.flatnonzero(rig.run(10000).values["/amb/rotor"][:, 2])
    assert pulses.shape[0] == 99  # t = 0.01 ... 0.99 s within 0 ... 0.9999 s
    assert np.all(np.diff(pulses) == 100)


def test_lms_feedforward_cancels_runout_in_the_command_error():
    """Ro et al. eq. 9-10 at 30,000 rpm with mu = +0.001: the 1X and 2X error falls, the sensor keeps the runout."""
    rig = SpindleRig(speed=SpeedProfile(30000, 30000), truth=True, ff_mode="lms",
                     mu_schedule=((0, 60000, 0.001),))
    first = rig.run(2000)
    rig.run(30000)
    last = rig.run(5000)

    def harmonic(x, th, k):
        return 2 * abs(np.mean(x * np.exp(-1j * k * th)))

    th0, th1 = first.values["/amb/rotor"][:, 0], last.values["/amb/rotor"][:, 0]
    for k in (1, 2):
        before = harmonic(first.values["/amb/error"][:, 0], th0, k)
        after = harmonic(last.values["/amb/error"][:, 0], th1, k)
        assert after < before / 10, (k, before, after)
    # the gap sensor still shows the runout, the rotor itself is nearly still at 1X
    runout_1x = harmonic(last.values["/truth/runout"][:, 0], th1, 1)
    assert harmonic(last.values["/amb/gap"][:, 0], th1, 1) == pytest.approx(runout_1x, rel=0.1)
    assert harmonic(last.values["/truth/position"][:, 0], th1, 1) < 0.2 * runout_1x


def test_fixed_feedforward_table_of_the_true_runout_removes_it_from_the_error():
    """ff=table with the runout's own sin/cos coefficients: r_c = r, so e = x + noise.

    What is left in e at 1X is the rotor's real unbalance response, not runout."""
    rig = SpindleRig(speed=SpeedProfile(30000, 30000), truth=True)
    a_sin, b_cos = SPINDLE.runout_sin_cos()
    rig.set_feedforward("table", np.stack([a_sin, b_cos], axis=-1))
    rig.run(5000)
    b = rig.run(10000)
    th = b.values["/amb/rotor"][:, 0]
    residual = b.values["/amb/error"] - b.values["/truth/position"]
    for axis in range(5):
        for k in (1, 2):
            left = 2 * abs(np.mean(residual[:, axis] * np.exp(-1j * k * th)))
            assert left < 0.02e-6, (axis, k, left)
    assert residual.std() < 0.3e-6  # sensor noise (0.2 um) and A/D steps (30 nm)
    # the feedforward output is the runout itself, and the table does not adapt
    np.testing.assert_allclose(b.values["/amb/ff"], b.values["/truth/runout"], atol=1e-12)
    np.testing.assert_array_equal(rig.feedforward_weights[:, :, 0], a_sin)
