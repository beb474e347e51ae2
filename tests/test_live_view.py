"""``record --live``: the topics served over the Foxglove WebSocket protocol (foxglove-sdk's server)
and read by an independent client from the npm registry (@foxglove/ws-protocol, run by Node); the
file keeps every sample; a slow viewer costs none; a taken port is one line."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import npm_installed

from ambdaq.analysis.runout import harmonic_fit
from ambdaq.daq import load

CLIENT = Path(__file__).parent / "live_client"


@pytest.fixture(scope="session")
def node_client(tmp_path_factory):
    """The client script with its pinned packages installed from the npm registry."""
    return npm_installed(tmp_path_factory, CLIENT, ("client.js",))


def start_recording(url: str, out: Path, *extra: str) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "record", "--device", url,
                             "--duration", "5", "-o", str(out), "--json", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if "live view on ws://127.0.0.1:" in line:
            return proc, int(line.split("ws://127.0.0.1:")[1].split()[0])
    raise AssertionError(proc.communicate())


@pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)
def test_a_foxglove_client_receives_the_topics_and_a_slow_one_costs_no_samples(node_client, served, tmp_path):
    """The spindle at 30,000 rpm served in its own process (as a controller would be), recorded over
    its serial line with --live, two Node clients connected."""
    out = tmp_path / "live.mcap"
    proc, port = start_recording(served, out, "--live", "0")
    url = f"ws://127.0.0.1:{port}"
    topics = ["/amb/gap", "/live/1x", "/live/speed", "/live/orbit/front"]
    slow = subprocess.Popen(["node", "client.js", url, "3", *topics], cwd=node_client, env={**os.environ, "SLOW": "1"},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    fast = subprocess.run(["node", "client.js", url, "2.5", *topics], cwd=node_client, capture_output=True, text=True,
                          timeout=60)
    assert fast.returncode == 0, fast.stderr
    slow.wait(timeout=60)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    # the file keeps every sample, with a slow viewer connected the whole time
    assert summary["samples"] == 50000 and summary["drops"] == 0 and summary["duplicates"] == 0

    got = [json.loads(line) for line in fast.stdout.splitlines()]
    gap = [m["data"] for m in got if m["topic"] == "/amb/gap"]
    rec = load(out, topics=["/amb/gap", "/amb/rotor"])
    g, rot = rec["/amb/gap"], rec["/amb/rotor"]
    # decimated to 100 Hz: every 100th sample of the 10 kHz stream, each equal to the file's
    seqs = np.array([m["seq"] for m in gap])
    assert len(gap) >= 150 and np.all(np.diff(seqs) == 100)
    at = np.searchsorted(g.seq, seqs)
    for field in g.fields:
        np.testing.assert_array_equal([m[field] for m in gap], g[field][at])
    # the 1X vector: the live one over 0.2 s against the whole recording's (the rig runs steadily;
    # 0.2 um RMS sensor noise over 100 revolutions moves it by well under 1 %: 2 % and 2 degrees)
    whole = harmonic_fit(np.column_stack([g["front_x"], g["front_y"]]), np.unwrap(rot["angle"]), (1,))[0] * 1e6
    one_x = [m["data"] for m in got if m["topic"] == "/live/1x" and m["data"]["axis"] in ("front_x", "front_y")]
    assert one_x
    for m in one_x:
        v = whole[0 if m["axis"] == "front_x" else 1]
        assert m["amplitude_um"] == pytest.approx(abs(v), rel=0.02)
        assert abs((m["phase_deg"] - np.degrees(np.angle(v)) + 180) % 360 - 180) < 2.0
    speed = [m["data"]["rpm"] for m in got if m["topic"] == "/live/speed"]
    assert speed and all(abs(s - 30000) < 30 for s in speed)
    # the last orbit: the first ones may come from a window not yet full (a client that connected
    # before the controller's first 0.2 s had arrived)
    orbit = [m["data"] for m in got if m["topic"] == "/live/orbit/front"][-1]
    assert 100 <= len(orbit["x_um"]) == len(orbit["y_um"]) <= 400
    assert max(np.hypot(orbit["x_um"], orbit["y_um"])) == pytest.approx(np.hypot(*np.abs(whole)), rel=0.3)


def test_a_port_in_use_is_one_line_before_recording(run_cli, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = run_cli("record", "--device", "sim://spindle", "--duration", "1", "--live", str(port), "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and f"--live {port}: cannot serve on 127.0.0.1:{port}" in r.output
    assert "Address already in use" in r.output and not (tmp_path / "x.mcap").exists()


def _handshake(port: int, subprotocol: str) -> bytes:
    """A WebSocket upgrade request offering ``subprotocol`` (RFC 6455 section 4.1), and the answer's first line."""
    import base64

    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                   f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                   f"Sec-WebSocket-Protocol: {subprotocol}\r\n\r\n").encode())
        return s.recv(4096).split(b"\r\n")[0]


@pytest.mark.realtime
def test_an_older_foxglove_client_is_said_once_not_per_connection(tmp_path):
    """Three clients offering only foxglove.websocket.v1 (Foxglove's older apps) and one offering
    foxglove.sdk.v1: the older ones are refused by foxglove-sdk, and the terminal says why once."""
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "record", "--device", "sim://spindle", "--duration", "3",
                             "-o", str(tmp_path / "r.mcap"), "--live", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if "live view on ws://127.0.0.1:" in line:
            port = int(line.split("ws://127.0.0.1:")[1].split()[0])
            break
    else:
        raise AssertionError(proc.communicate())
    answers = [_handshake(port, "foxglove.websocket.v1") for _ in range(3)]
    assert answers == [b"HTTP/1.1 400 Bad Request"] * 3
    assert _handshake(port, "foxglove.sdk.v1") == b"HTTP/1.1 101 Switching Protocols"
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    said = [ln for ln in err.splitlines() if "foxglove.websocket.v1" in ln]
    assert len(said) == 1 and said[0].startswith("ambdaq: live: a viewer's WebSocket handshake was refused")
    assert "Dropping client" not in err
