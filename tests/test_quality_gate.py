"""The data-quality gate: a workflow refuses, in one line with exit 2, a recording that lost more
than the stated share of its samples, and recordings compared at one speed that ran at others;
below the limit it computes and says what it computed over (ambdaq.daq.quality)."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Two simulated spindle recordings that lost a run of samples (the fleet simulator's line
    drop: seed 4 loses 189 of 20,000, seed 1 loses 7), a clean one at 30,000 rpm and a slow roll."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    d = tmp_path_factory.mktemp("gate")
    for args in (["sim", "fleet", "-o", d / "lossy", "--machines", "1", "--days", "1", "--duration", "2",
                  "--rpm", "30000", "--drop-chance", "1", "--seed", "4"],
                 ["sim", "fleet", "-o", d / "few", "--machines", "1", "--days", "1", "--duration", "2",
                  "--rpm", "30000", "--drop-chance", "1", "--seed", "1"],
                 ["sim", "generate", "--rpm", "30000", "--duration", "2", "-q", "-o", d / "fast.mcap"],
                 ["sim", "generate", "--rpm", "slowroll", "--duration", "2", "-q", "-o", d / "slow.mcap"]):
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    return {"lossy": next((d / "lossy").rglob("*.mcap")), "few": next((d / "few").rglob("*.mcap")),
            "fast": d / "fast.mcap", "slow": d / "slow.mcap", "dir": d}


def drops_of(run_cli, path) -> int:
    info = json.loads(run_cli("info", path, "--json").stdout)
    return next(t["drops"] for t in info["topics"] if t["topic"] == "/amb/gap")


@pytest.mark.parametrize("command", [
    ("runout", "identify", "{rec}", "-o", "{dir}/c.json"),
    ("runout", "check", "{fast}", "{rec}"),
    ("iso", "vibration", "{rec}", "--cmin", "150"),
    ("runup", "{rec}"),
])
def test_a_recording_that_lost_more_than_the_limit_is_refused_in_one_line(recordings, run_cli, command):
    lost = drops_of(run_cli, recordings["lossy"])
    assert lost == 189  # the simulator's seed 4: 0.945 % of 20,000
    args = [a.format(rec=recordings["lossy"], fast=recordings["fast"], dir=recordings["dir"]) for a in command]
    r = run_cli(*args)
    assert r.exit_code == 2, r.output
    line = r.output.strip()
    assert len(line.splitlines()) == 1, line
    # the number is the one the recording holds: what `info` counts
    assert f" lost {lost} of 20,000 samples (0.945%)" in line and "(limit 0.1%, --max-lost)" in line, line
    assert str(recordings["lossy"]) in line
    # a user who knowingly accepts more says so, and the computation runs
    r = run_cli(*args, "--max-lost", "0.01")
    assert r.exit_code in (0, 1), r.output  # runout check may fail its own criteria (exit 1); it ran


def test_below_the_limit_the_result_says_what_it_was_computed_over(recordings, run_cli):
    r = run_cli("runout", "check", recordings["fast"], recordings["few"])
    assert r.exit_code == 0, r.output
    assert "note: " in r.stderr and "/amb/error, /amb/gap, /amb/rotor lost 7 of 20,000 samples (0.035%), within the 0.1% limit" in r.stderr
    r = run_cli("runout", "check", recordings["fast"], recordings["fast"])
    assert r.exit_code == 0 and "lost" not in r.stderr  # nothing lost, nothing said


def test_recordings_at_different_speeds_are_not_compared(recordings, run_cli):
    r = run_cli("runout", "check", recordings["fast"], recordings["slow"])
    assert r.exit_code == 2, r.output
    assert "runout check compares recordings at one speed, and these differ by more than 1%" in r.output
    assert "fast.mcap at 30,000 rpm, slow.mcap at 800 rpm" in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_a_device_that_restarted_its_count_is_said(run_cli, tmp_path):
    """A controller that began counting its samples again half way (a reboot): nothing is lost by
    count, but the time across the restart is not known to be whole, and the result says so."""
    import numpy as np

    from ambdaq.acquisition.recorder import Recorder, RecordOptions
    from ambdaq.drivers.interfaces import PassThrough
    from ambdaq.sim.source import SimSource
    from ambdaq.speed import SpeedProfile

    class Rebooting(PassThrough):
        def read(self):
            block = self.inner.read()
            if block is not None and block.seq[0] >= 10_000:  # counts from 0 again after 1 s
                block = block.select(np.ones(len(block), bool))
                object.__setattr__(block, "seq", (block.seq - 10_000).astype(np.uint32))
            return block

    path = tmp_path / "reboot.mcap"
    Recorder([Rebooting(SimSource("spindle", speed=SpeedProfile(30000, 30000)))], path,
             RecordOptions(duration_s=2, fsync=False)).run()
    fast = tmp_path / "fast.mcap"
    assert run_cli("sim", "generate", "--rpm", "30000", "--duration", "2", "-q", "-o", fast).exit_code == 0
    r = run_cli("runout", "check", fast, path)
    assert r.exit_code == 0, r.output
    assert "the device restarted its sample count 1 time (a reconnect or reboot)" in r.stderr
