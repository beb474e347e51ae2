"""Kang & Jung on the base-motion rig: physics against its exact linear model, MFXLMS against W*,
and the whole chain through the CLI (secondary path, campaign, estimate, fit, compensated run)."""

import json

import numpy as np
import pytest

from ambdaq.analysis.mfxlms import fit_fir, knee, mfxlms, run_beta, separate
from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load
from ambdaq.sim.rigs.base_motion import BaseExcitation, BaseMotionRig
from ambdaq.units import GRAVITY

FS = 10_000.0


def harmonic(values: np.ndarray, f_hz: float, skip: int = 5000) -> np.ndarray:
    """|amplitude| at f_hz of each column of ``values`` after ``skip`` samples."""
    n = values.shape[0]
    th = 2 * np.pi * f_hz * np.arange(n) / FS
    return np.abs(harmonic_fit(values[skip:], th[skip:], (1,))[0])


def test_closed_loop_is_stable_and_carries_gravity():
    rig = BaseMotionRig()
    Acl, *_ = rig.closed_loop()
    assert np.abs(np.linalg.eigvals(Acl)).max() < 1.0
    block = rig.run(20_000)
    gap, cur = block.values["/amb/gap"], block.values["/amb/current"]
    assert np.abs(gap.mean(axis=0)).max() < 0.02e-6  # centred, gravity or not
    # vertical coils carry the shaft's weight (sum of bearing forces = m g), horizontal ones nothing
    p = rig.params
    assert p.ki[0] * cur[:, 0].mean() + p.ki[1] * cur[:, 1].mean() == pytest.approx(p.mass * GRAVITY, rel=1e-3)
    assert np.abs(cur[:, 2:].mean(axis=0)).max() < 1e-4


@pytest.mark.parametrize("f_hz", [5.0, 40.0, 100.0])
def test_base_motion_response_equals_the_exact_model(f_hz):
    """The kernel's gap response to harmonic base motion is C(e^{jwT}) d within 1%."""
    alpha = 0.5 - 0.8j
    rig = BaseMotionRig(noise=False)
    rig.set_base_motion(BaseExcitation("sine", 1.0, f_hz, alpha))
    gap = rig.run(40_000).values["/amb/gap"]
    _, C, _ = rig.responses([f_hz])
    expected = np.abs(C[0] @ np.array([alpha, 1.0]))
    measured = harmonic(gap, f_hz, skip=20_000)
    np.testing.assert_allclose(measured[:2], expected, rtol=0.01)
    np.testing.assert_allclose(measured[2:], expected, rtol=0.01)  # the horizontal plane alike, no gravity


@pytest.mark.parametrize("f_hz", [5.0, 40.0, 100.0])
def test_mfxlms_with_two_alphas_recovers_the_perfect_compensator(f_hz):
    """Eq. A-4 to A-17 on recorded responses with the exact secondary path: W within 1 % of
    W* = -B^-1 C relative to the matrix, each element within 5 % of its own (noise on the gap
    sensors and accelerometers included; the cross terms, 30 times smaller, carry the noise: up to
    3.9 % at 100 Hz over 12 seeds in the validation campaign, docs/validation.md)."""
    rig0 = BaseMotionRig()
    B, _, Wstar = rig0.responses([f_hz])
    betas = []
    for alpha in (1.0, -1.0 + 0.5j):
        rig = BaseMotionRig(seed=7)
        rig.set_base_motion(BaseExcitation("sine", 1.0, f_hz, alpha))
        rig.run(5000)
        v = rig.run(30_000).values
        res = mfxlms(v["/amb/gap"][:, :2], v["/base/accel"][:, :2], B[0], f_hz, FS)
        # the compensated error ends at the sensor noise
        assert np.sqrt(np.mean(res.error[-5000:] ** 2)) < 1.5 * rig.params.gap_noise
        betas.append((run_beta(res, alpha), alpha))
    W = separate(betas[0][0], betas[0][1], betas[1][0], betas[1][1])
    assert np.abs(W - Wstar[0]).max() < 0.01 * np.linalg.norm(Wstar[0]) and np.abs(W / Wstar[0] - 1).max() < 0.05
    with pytest.raises(ValueError, match="different disturbance ratios"):
        separate(betas[0][0], 1.0, betas[1][0], 1.0)


def test_fir_fit_and_knee():
    """A FIR fitted to exact W* points: the knee is where a tap stops paying, and the error there
    is under 1% from 5 to 100 Hz."""
    f = np.arange(5.0, 101.0, 5.0)
    _, _, Wstar = BaseMotionRig().responses(f)
    orders = np.arange(0, 16)
    for j in range(2):
        for m in range(2):
            costs = np.array([fit_fir(f, Wstar[:, j, m], o, FS)[1] for o in orders])
            assert np.all(np.diff(costs) <= 1e-15)  # more taps never fit worse
            k = knee(orders, costs, len(f))
            taps, _ = fit_fir(f, Wstar[:, j, m], k, FS)
            E = np.exp(-2j * np.pi * np.outer(f / FS, np.arange(k + 1)))
            assert np.abs(E @ taps / Wstar[:, j, m] - 1).max() < 0.01, (j, m, k)


CHAIN_WORKER = pytest.mark.xdist_group("base-motion-chain")
"""The tests of the chain run on one worker: the other does not wait idle while it is built."""


@pytest.fixture(scope="module")
def chain(build_once):
    """The engineer's chain, every step a CLI command: secondary path (broadband test signal per
    axis), stepped-sine campaign, MFXLMS estimate, FIR fit.  Built once per run (the compute tests
    and the real-time push share it)."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    runner = CliRunner()

    def run(*args):
        r = runner.invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
        return r

    def build(d):
        for a in ("amb1_y", "amb2_y", "amb1_z", "amb2_z"):
            run("sim", "generate", "--profile", "base-motion", "--duration", "6", "--excite", f"{a}:0.3", "-q",
                "-o", d / f"sp_{a}.mcap")
        summary = run("frf", "estimate", *[d / f"sp_{a}.mcap" for a in ("amb1_y", "amb2_y", "amb1_z", "amb2_z")],
                      "--output-topic", "/amb/gap", "--resolution", "5", "-o", d / "path.json", "--json").stdout
        (d / "path_summary.json").write_text(summary)
        run("fx", "campaign", "--freqs", "5,20,40,70,100", "--seconds", "0.6", "--settle", "0.15", "-o", d / "camp")
        run("fx", "estimate", d / "camp", "--path", d / "path.json", "-o", d / "points.json")
        (d / "fit.json").write_text(run("fx", "fit", d / "points.json", "-o", d / "fir.json", "--exact", "--json",
                                        "--plot", d / "fir.png").stdout)

    d = build_once("base-motion-chain", build)
    return d, json.loads((d / "fit.json").read_text()), run


@CHAIN_WORKER
def test_secondary_path_coherence_is_reported_over_the_band_it_holds(chain):
    """White noise to 5 kHz on each amplifier input: the gap answers above the sensor noise up to
    several hundred Hz.  The summary names that band and its coherence, not a median over the
    whole axis dominated by the noise above it (issue 12: "median coherence 0.05")."""
    d, _, _ = chain
    for axis, s in json.loads((d / "path_summary.json").read_text()).items():
        lo, hi = s["coherent_band_hz"]
        assert lo == 5.0 and hi >= 500.0, axis
        assert s["median_coherence_in_band"] > 0.95 and s["median_coherence"] < s["median_coherence_in_band"], axis


@CHAIN_WORKER
def test_fitted_compensator_against_the_exact_one(chain):
    d, report, _ = chain
    assert 1 <= report["taps"] <= 25
    assert max(report["error_vs_exact_pct"]) < 5.0  # per frequency, worst of both planes and four W
    assert (d / "fir.png").stat().st_size > 30_000


@CHAIN_WORKER
@pytest.mark.parametrize("f_hz", [5.0, 20.0, 40.0, 70.0, 100.0])
def test_campaign_frequencies_fall_by_20_db(chain, f_hz):
    d, _, run = chain
    amp = {}
    for name, extra in (("fb", ()), ("ff", ("--fir", d / "fir.json"))):
        out = d / f"sine_{f_hz:g}_{name}.mcap"
        run("sim", "generate", "--profile", "base-motion", "--duration", "3", "--base", f"sine:{f_hz:g}:1:0.7:40",
            *extra, "-q", "-o", out)
        g = load(out, topics=["/amb/gap"])["/amb/gap"]
        amp[name] = harmonic(np.stack([g[a] for a in g.fields], axis=1), f_hz)
    drop = 20 * np.log10(amp["fb"] / amp["ff"])
    assert drop.min() >= 20.0, drop


@CHAIN_WORKER
def test_broadband_base_motion_falls_by_10_db_rms(chain):
    d, _, run = chain
    rms = {}
    for name, extra in (("fb", ()), ("ff", ("--fir", d / "fir.json"))):
        out = d / f"broadband_{name}.mcap"
        run("sim", "generate", "--profile", "base-motion", "--duration", "10", "--base", "noise:5-100:1",
            "--seed", "4", *extra, "-q", "-o", out)
        g = load(out, topics=["/amb/gap"])["/amb/gap"]
        v = np.stack([g[a] for a in g.fields], axis=1)[10_000:]
        rms[name] = np.sqrt(np.mean(v**2, axis=0))
    drop = 20 * np.log10(rms["fb"] / rms["ff"])
    assert drop.min() >= 10.0, drop


def test_bad_input_is_one_line_and_exit_2(run_cli, tmp_path, spindle_file):
    cases = [
        (("sim", "generate", "--profile", "base-motion", "--duration", "1", "--base", "sine:0:1", "-o", tmp_path / "a.mcap"),
         "base motion 'sine:0:1': frequency must be > 0"),
        (("sim", "generate", "--duration", "1", "--base", "noise:5-100:1", "-o", tmp_path / "b.mcap"),
         "the spindle rig has no moving base"),
        (("sim", "generate", "--profile", "base-motion", "--duration", "1", "--excite", "front_x:0.1",
          "-o", tmp_path / "c.mcap"), "the controller's axes are amb1_y"),
        (("fx", "estimate", tmp_path, "--path", tmp_path / "p.json", "-o", tmp_path / "w.json"),
         "no readable campaign.json"),
        (("record", "--device", "sim://cone", "--duration", "1", "-o", tmp_path / "d.mcap"),
         "the cone rig serves no devices on a transport: use `ambdaq sim generate --profile cone`"),
        (("fx", "campaign", "--alphas", "1,1", "-o", tmp_path / "camp"), "give two different ratios"),
    ]
    for args, needle in cases:
        r = run_cli(*args)
        assert r.exit_code == 2, (args, r.output)
        assert needle in r.output and r.output.count("\n") == 1, r.output
    # sim:// serves a rig's devices one way for every profile: the base-motion controller records
    r = run_cli("record", "--device", "sim://base-motion", "--duration", "0.5", "-q", "-o", tmp_path / "bm.mcap")
    assert r.exit_code == 0, r.output
    coef = tmp_path / "coef.json"
    assert run_cli("runout", "identify", spindle_file, "-o", coef).exit_code == 0
    r = run_cli("sim", "generate", "--profile", "base-motion", "--duration", "1", "--fir", coef, "-o", tmp_path / "e.mcap")
    assert r.exit_code == 2 and "no base-motion FIR for plane" in r.output


@CHAIN_WORKER
@pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)
def test_push_the_fir_to_the_served_controller(chain, tmp_path):
    """``ambdaq sim serve --profile base-motion --base sine:40:1`` in its own process; from another,
    record, push the fitted FIR (verified, logged), record again: the controller applies u = W d
    and the 40 Hz response falls by 20 dB or more. A wrong key writes nothing."""
    import os
    import subprocess
    import sys

    d, _, _ = chain
    env = {**os.environ, "AMBDAQ_STATE_DIR": str(tmp_path / "state")}
    cmd = [sys.executable, "-m", "ambdaq"]

    def ambdaq(*args, key=None):
        e = dict(env, AMBDAQ_UNLOCK_KEY=key) if key else env
        return subprocess.run(cmd + [str(a) for a in args], capture_output=True, text=True, env=e, timeout=60)

    proc = subprocess.Popen(cmd + ["sim", "serve", "--profile", "base-motion", "--base", "sine:40:1", "--duration", "60"],
                            stdout=subprocess.PIPE, text=True)
    try:
        _, pty = proc.stdout.readline().split()
        url = f"serial://{pty}"
        amps = []
        for name in ("before", "after"):
            if name == "after":
                r = ambdaq("push", d / "fir.json", "--device", url, "--yes", key="wrong")
                assert r.returncode == 1 and "wrong unlock key" in r.stderr
                assert json.loads(ambdaq("controller", "status", "--device", url, "--json").stdout)["inactive_length"] == 0
                r = ambdaq("push", d / "fir.json", "--device", url, "--yes", key="ambdaq-sim")
                assert r.returncode == 0 and "device-verified" in r.stdout, r.stderr
            out = tmp_path / f"{name}.mcap"
            assert ambdaq("record", "--device", url, "--duration", "1", "-o", out, "-q").returncode == 0
            g = load(out, topics=["/amb/gap"])["/amb/gap"]
            amps.append(harmonic(np.stack([g[a] for a in g.fields], axis=1), 40.0, skip=2000))
        drop = 20 * np.log10(amps[0] / amps[1])
        assert drop.min() >= 20.0, drop
        status = json.loads(ambdaq("controller", "status", "--device", url, "--json").stdout)
        assert status["active_fir_taps"] >= 1 and status["log"][-1]["file"] == "fir.json"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_a_fit_that_misses_a_point_far_is_refused_naming_it(run_cli, tmp_path):
    """Points at the simulated rig's exact W* (5 to 100 Hz) fit within the limit; the same points with
    the 100 Hz one ten times too large (a step that lost most of its samples gave 1,105 %) are
    refused in one line naming the point, and no coefficient file is written."""
    from ambdaq.documents.compensator_points import save_points
    from ambdaq.sim.rigs.base_motion import BaseMotionRig

    freqs = np.array([5.0, 10, 20, 40, 70, 100])
    _, _, wstar = BaseMotionRig().responses(freqs)  # (freq, j, m)
    W = np.repeat(wstar[:, None], 2, axis=1)  # both planes
    good = save_points(tmp_path / "good.json", freqs.tolist(), W, [[0.06, 0.06]] * len(freqs), {"test": "W*"})
    r = run_cli("fx", "fit", good, "-o", tmp_path / "fir.json", "--json")
    assert r.exit_code == 0, r.output
    assert max(json.loads(r.stdout)["fit_error_pct"]) < 5
    W[-1, 0, 0, 1] *= 10
    bad = save_points(tmp_path / "bad.json", freqs.tolist(), W, [[0.06, 0.06]] * len(freqs), {"test": "W* spoilt"})
    r = run_cli("fx", "fit", bad, "-o", tmp_path / "fir_bad.json")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert "at 100 Hz by" in r.output and "(limit 25 %, --max-fit-error)" in r.output
    assert not (tmp_path / "fir_bad.json").exists()


@pytest.mark.realtime
def test_a_campaign_step_that_loses_samples_is_recorded_again_then_refused(run_cli, tmp_path):
    """The controller's serial line damages 10 % of its frames (``line_errors``: the host's CRC
    rejects them, the recorder counts the samples lost): every attempt at the first step loses far
    more than 0.1 % (0.5 s is about 100 frames; all 100 intact has a chance of 3e-5), so after three
    the campaign stops naming the step; accepting 50 % it runs."""
    device = "sim://base-motion?line_errors=0.1"
    r = run_cli("fx", "campaign", "--device", device, "--freqs", "20", "--seconds", "0.5", "--settle", "0",
                "-o", tmp_path / "camp")
    assert r.exit_code == 1, r.output
    line = r.output.strip().splitlines()[-1]
    assert line.startswith("ambdaq: error: step_000_20Hz.mcap: lost more than 0.1% of its samples in each of 3 attempts")
    assert not (tmp_path / "camp" / "campaign.json").exists()  # no campaign that holds the bad step
    r = run_cli("fx", "campaign", "--device", device, "--freqs", "20", "--seconds", "0.5", "--settle", "0",
                "--max-lost", "0.5", "-o", tmp_path / "camp2")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "camp2" / "campaign.json").exists() and "shakers stopped, the base at rest" in r.stderr
