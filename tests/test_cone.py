"""Jeong et al.'s cone-shaped AMB analysis against the paper's numbers, where they are self-consistent."""

import numpy as np
import pytest

from ambdaq.analysis.cone import (MU0, PdLoop, force_factor, linear_gains, magnet_force, routh_stable,
                                  shape_factor, stable_region)

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

TAU, TAU_C = 8e-5, 6e-5  # the paper's Routh-Hurwitz example


def example_loop(kp=3.0, kd=0.005) -> PdLoop:
    """A loop with the two ratios the example fixes: Ky / G = 1.9 (its Kp > 1.9) and m / G from its
    Kd < 0.166 s (G = Ks Kc Ki); m = 1.68 kg (Table 1)."""
    m = 1.68
    g = m / (0.166 * TAU * TAU_C / (TAU + TAU_C))
    return PdLoop(m=m, ky=1.9 * g, ki=g, ks=1.0, kc=1.0, kp=kp, kd=kd, tau=TAU, tau_c=TAU_C)


def test_linearisation_is_the_derivative_of_the_force():
    a, n, g0, i0 = 155e-6, 400, 0.5e-3, 1.03
    ag, c = force_factor(0.3, 0.9), shape_factor(0.3, 0.9)
    lin = linear_gains(area=a, turns=n, gap=g0, bias=i0, alpha_g=ag, c=1.0)  # c = 1: Kq is then |dF/dg|
    h = 1e-7
    dfdi = (magnet_force(i0 + h, g0, area=a, turns=n, alpha_g=ag) - magnet_force(i0 - h, g0, area=a, turns=n, alpha_g=ag)) / (2 * h)
    dfdg = -(magnet_force(i0, g0 + h, area=a, turns=n, alpha_g=ag) - magnet_force(i0, g0 - h, area=a, turns=n, alpha_g=ag)) / (2 * h)
    assert float(dfdi) == pytest.approx(lin.ki, rel=1e-6)
    assert float(dfdg) == pytest.approx(lin.kq, rel=1e-6)
    assert lin.f0 == pytest.approx(float(magnet_force(i0, g0, area=a, turns=n, alpha_g=ag)))
    assert ag <= c  # alpha_g = c sinc(half the pole angle): never above the shape factor


def test_routh_hurwitz_example_kd_range_and_kp_min():
    """tau = 8e-5 s, tau_c = 6e-5 s: the paper's 2.6e-4 s < Kd < 0.166 s and Kp > 1.9 (eq. 23)."""
    loop = example_loop()
    region = stable_region(loop)
    assert region.kp_min == pytest.approx(1.9)
    assert region.kd_min == pytest.approx(2.66e-4 - 1.9 * TAU, rel=1e-9)  # Kp tau + Kd > 2.66e-4 s
    assert 1.9 * TAU + region.kd_min == pytest.approx(2.6e-4, abs=0.1e-4)
    assert region.kd_max + 1.9 * TAU == pytest.approx(0.166)
    # the bounds are necessary: over a grid, every stable point lies inside them, points outside are
    # unstable, and the Routh array agrees with the eigenvalues everywhere
    inside = 0
    for kp in np.geomspace(1.0, 300.0, 40):
        for kd in np.geomspace(1e-5, 1.0, 40):
            lp = PdLoop(**{**loop.__dict__, "kp": kp, "kd": kd})
            stable = lp.stable()
            assert stable == bool(np.real(lp.poles()).max() < 0)
            bounded = kp > region.kp_min and region.kd_min < kp * TAU + kd - region.kp_min * TAU < region.kd_max
            assert not stable or bounded
            inside += stable
    assert inside > 100


def test_kp_max_at_kd_0005_and_the_papers_34_7():
    """Exactly, Kp may go to 71.8 at Kd = 0.005 s; the paper's 34.7 is its eq. 23 with K_a taken as
    Kd alone (Kp tau dropped), which this reproduces."""
    loop = example_loop(kd=0.005)
    kp_max = stable_region(loop).kp_max(loop)
    assert kp_max == pytest.approx(72.0, abs=0.05)
    assert np.real(PdLoop(**{**loop.__dict__, "kp": kp_max * 0.99}).poles()).max() < 0
    assert np.real(PdLoop(**{**loop.__dict__, "kp": kp_max * 1.01}).poles()).max() > 0
    m, ky, g = loop.m, loop.ky, loop.ki
    ka = 0.005  # K_a = Kd, as the paper's number implies
    paper = (m + TAU * TAU_C * ky) / ((TAU + TAU_C) * m) * ka - TAU * TAU_C * g / ((TAU + TAU_C) ** 2 * m) * ka**2
    assert paper == pytest.approx(34.7, abs=0.05)


def test_equivalent_stiffness_and_damping_at_low_frequency():
    """Eq. 19 at low frequency: Keq -> -Ky + Ki Ks Kc Kp (eq. 21), Ceq -> Ki Ks Kc (Kd - Kp tau_c); eq. 21's
    Ki Ks Kc Kd drops the current loop's lag (here 4.5% of the damping)."""
    loop = example_loop(kp=3.0, kd=0.004)
    k, c = loop.stiffness_damping(np.array([0.5]))
    g = loop.ks * loop.kc
    assert k[0] == pytest.approx(-loop.ky + loop.ki * g * loop.kp, rel=1e-3)
    assert c[0] == pytest.approx(loop.ki * g * (loop.kd - loop.kp * loop.tau_c), rel=1e-3)


def test_table_3_is_not_reproducible_from_table_1():
    """Eq. 4 with Table 1 (A 155 mm^2, N 400, g0 0.5 mm, I0 1.03 A) gives Ki = 64.2 alpha_g N/A per
    magnet; Table 3's 101.8 needs alpha_g = 1.59 (> 1, impossible) per magnet, or 0.79 per pair, and
    then Table 3's Kq needs c = 0.76 < alpha_g, which eq. 3 forbids (alpha_g = c sinc <= c). Also
    Kq(Y2)/Kq(Y1) should be (1.0/1.03)^2 = 0.943; Table 3 has 0.994. docs/cone.md says so."""
    one = linear_gains(area=155e-6, turns=400, gap=0.5e-3, bias=1.03)
    assert one.ki == pytest.approx(64.2, abs=0.05)
    ag_pair = 101.8 / (2 * one.ki)
    c_pair = 1.60e5 / (2 * one.kq) / ag_pair
    assert ag_pair > c_pair  # contradicts alpha_g <= c
    assert 101.8 / one.ki > 1.0
    assert (1.59e5 / 1.60e5) - (1.0 / 1.03) ** 2 > 0.04
    assert 98.38 / 101.8 == pytest.approx(1.0 / 1.03, abs=0.006)  # Ki does scale with I0


def test_routh_array_against_roots():
    rng = np.random.default_rng(1)
    for _ in range(300):
        p = np.concatenate([[1.0], rng.normal(size=rng.integers(2, 6))])
        assert routh_stable(p) == bool(np.all(np.real(np.roots(p)) < 0))
    assert MU0 == pytest.approx(1.25663706e-6)


def test_model_command(run_cli, tmp_path):
    import json

    r = run_cli("model", "--example")
    axis = tmp_path / "axis.toml"
    axis.write_text(r.output)
    r = run_cli("model", axis, "--json", "--plot", tmp_path / "region.png")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["stable"] and all(re < 0 for re, _ in rep["poles_rad_s"])
    reg = rep["region"]
    assert reg["kp_min"] == pytest.approx(rep["axis"]["ky_n_per_m"] / rep["axis"]["loop_gain_n_per_m"])
    assert (tmp_path / "region.png").stat().st_size > 10_000
    # the example is the paper's Routh-Hurwitz example, as docs/cone.md says: Ky / G = 1.9, Kd < 0.166 s
    # (G = 1.68 / (0.166 tau tau_c / (tau + tau_c)), rounded in the example to 4 digits: 0.1%)
    g = 1.68 / (0.166 * TAU * TAU_C / (TAU + TAU_C))
    assert rep["axis"]["loop_gain_n_per_m"] == pytest.approx(g, rel=1e-3)
    assert reg["kp_min"] == pytest.approx(1.9, rel=1e-3) and reg["kd_max_s"] == pytest.approx(0.166, rel=2e-3)
    assert reg["kp_max_at_kd"] == pytest.approx(72.0, rel=2e-3)
    # without the two lines the pair's own gains from Table 1's magnet (docs/cone.md: 0.169 and 53.1)
    text = "\n".join(line for line in axis.read_text().splitlines() if not line.startswith(("ky_n", "ki_n")))
    axis.write_text(text)
    reg = json.loads(run_cli("model", axis, "--json").stdout)["region"]
    assert reg["kp_min"] == pytest.approx(0.169, abs=5e-4) and reg["kp_max_at_kd"] == pytest.approx(53.1, abs=0.05)
    # a Kd outside the stable range: said in words, never "nan"; null in JSON
    axis.write_text(text.replace("kd = 0.005", "kd = 0.5"))
    r = run_cli("model", axis)
    assert "no Kp is stable (Kd is outside the range)" in r.output and "nan" not in r.output
    assert json.loads(run_cli("model", axis, "--json").stdout)["region"]["kp_max_at_kd"] is None
    bad = tmp_path / "bad.toml"
    bad.write_text("[magnet]\narea_mm2 = 155\n")
    r = run_cli("model", bad)
    assert r.exit_code == 2 and "missing turns" in r.output and r.output.count("\n") == 1
    bad.write_text("not = [toml")
    r = run_cli("model", bad)
    assert r.exit_code == 2 and "not TOML" in r.output
