"""Every parameter change ambdaq makes to a controller is logged and can be undone (the house
rule; a push has its bank rollback): ``controller param`` and ``controller ff`` against the
spindle served in its own process, read back over its serial line."""

import json

import pytest

from ambdaq.drivers.serial.controller import ControllerDriver
from ambdaq.drivers.serial.link import SerialLink

pytestmark = pytest.mark.realtime  # a served controller, streaming in real time


def held(url: str, name: str) -> list[float]:
    drv = ControllerDriver(SerialLink(url.removeprefix("serial://")))
    try:
        return [float(v) for v in drv.read_param(name)]
    finally:
        drv.close()


def test_a_parameter_change_is_logged_and_undone(served, run_cli, tmp_path, monkeypatch):
    """Write pid.d and switch the feedforward off; --undo puts the mode back, then the gain, each
    read back over the line; a third undo has nothing to undo; a change made since (here another
    master's write) is not overwritten."""
    monkeypatch.setenv("AMBDAQ_STATE_DIR", str(tmp_path / "state"))
    before = held(served, "pid.d")
    r = run_cli("controller", "param", "--device", served, "pid.d", "0.001", "0.001", "0.0025", "0.0025", "0.002",
                "--yes")
    assert r.exit_code == 0 and "(was 0.0015 0.0015 0.002 0.002 0.002; logged" in r.output, r.output
    mode = held(served, "ff.mode")
    assert run_cli("controller", "ff", "off", "--device", served).exit_code == 0
    assert held(served, "ff.mode") == [0.0]
    log = [json.loads(line) for line in (tmp_path / "state" / "parameters.log").read_text().splitlines()]
    assert [(e["name"], e["old"], e["target"]) for e in log] == [("pid.d", before, served), ("ff.mode", mode, served)]

    r = run_cli("controller", "param", "--device", served, "--undo", "--yes")  # the last change first
    assert r.exit_code == 0 and r.output.startswith("ff.mode = "), r.output
    assert held(served, "ff.mode") == mode
    r = run_cli("controller", "param", "--device", served, "--undo", "--yes")
    assert r.exit_code == 0 and "pid.d = 0.0015 0.0015 0.002 0.002 0.002" in r.output, r.output
    assert held(served, "pid.d") == before
    r = run_cli("controller", "param", "--device", served, "--undo", "--yes")
    assert r.exit_code == 2 and "no parameter change of ambdaq's to undo" in r.output

    assert run_cli("controller", "param", "--device", served, "pid.i", "2", "2", "2", "2", "2", "--yes").exit_code == 0
    drv = ControllerDriver(SerialLink(served.removeprefix("serial://")))  # someone else's write, unlogged
    try:
        drv.write_param("pid.i", [3.0] * 5)
    finally:
        drv.close()
    r = run_cli("controller", "param", "--device", served, "--undo", "--yes")
    assert r.exit_code == 2 and "changed since; not undone" in r.output, r.output
    assert held(served, "pid.i") == [3.0] * 5
