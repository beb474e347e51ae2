"""The details users touch on the command line and in Python (issue 29): each one line or the
behaviour Python users expect of a mapping."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from ambdaq.daq import load


def test_a_mistyped_command_is_named_with_the_one_meant(run_cli):
    r = run_cli("recrod")
    assert r.exit_code == 2 and "no command 'recrod': did you mean 'record'?" in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_a_serial_port_without_its_scheme_is_answered_with_the_url(run_cli, tmp_path):
    r = run_cli("record", "--device", "/dev/ttyUSB0", "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "did you mean serial:///dev/ttyUSB0?" in r.output
    assert len(r.output) < 200  # not every URL grammar there is


@pytest.mark.parametrize("text, seconds", [("0.25", 0.25), ("250ms", 0.25), ("0.25s", 0.25)])
def test_durations_take_units_like_snapshot_does(text, seconds, run_cli, tmp_path):
    r = run_cli("sim", "generate", "--duration", text, "--json", "-o", tmp_path / "g.mcap")
    assert r.exit_code == 0, r.output
    assert len(load(tmp_path / "g.mcap")["/amb/gap"]) == round(seconds * 10_000)


@pytest.mark.parametrize("text", ["1e308", "0", "-5s", "ten"])
def test_an_impossible_duration_is_one_line(text, run_cli, tmp_path):
    r = run_cli("record", "--device", "sim://spindle", "--duration", text, "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "--duration" in r.output and len(r.output.strip().splitlines()) == 1, r.output


def test_recording_and_topic_behave_as_mappings(spindle_file):
    rec = load(spindle_file, topics=["/amb/gap"])
    assert rec.get("/amb/current") is None and "/amb/current" not in rec
    with pytest.raises(KeyError):
        rec["/amb/current"]
    gap = rec["/amb/gap"]
    assert list(gap) == list(gap.fields) == ["front_x", "front_y", "rear_x", "rear_y", "axial"]
    assert dict(gap)["front_x"] is gap["front_x"]
    with pytest.raises(KeyError):
        gap["nope"]


def test_push_without_yes_and_without_a_terminal_says_so(tmp_path):
    """No terminal to ask on (CI, a pipe): one line, exit 2, not click's "Aborted!"."""
    r = subprocess.run([sys.executable, "-m", "ambdaq", "push", str(tmp_path / "coef.json"), "--device",
                        "serial:///dev/null"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert r.returncode in (1, 2) and "Aborted" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_sim_serve_on_a_port_in_use_is_one_line(tmp_path):
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "ambdaq", "sim", "serve", "--xcp", f"tcp:{port}", "--duration", "1"],
                           capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and f"cannot listen on 127.0.0.1:{port}" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "internal error" not in r.stderr


def test_the_closing_line_names_each_devices_samples_and_drops(run_cli, tmp_path):
    """sim://spindle opens the controller (`rig`) and four CANopen devices at other rates: the line
    says what the devices wrote and lost, not the controller's samples beside everyone's drops."""
    import json

    r = run_cli("record", "--device", "sim://spindle", "--duration", "0.5", "-o", tmp_path / "r.mcap")
    assert r.exit_code == 0, r.output
    line = r.stderr.strip().splitlines()[-1]
    r = run_cli("record", "--device", "sim://spindle", "--duration", "0.5", "--json", "-o", tmp_path / "j.mcap")
    devices = json.loads(r.stdout)["devices"]
    assert len(devices) > 1 and "rig" in devices
    if len(devices) <= 4:
        assert all(f"{name} " in line for name in devices), line
    else:
        assert f"{len(devices)} devices, " in line and " samples each, " in line, line


def test_a_serial_peer_whose_identity_is_crc_valid_junk_is_one_line(tmp_path, run_cli):
    """A device on a serial line (a pseudo-terminal) that answers IDENTIFY with a well-framed,
    CRC-valid IDENTITY whose body is not UTF-8 JSON: one line naming what it sent, exit 1 (it had
    been "internal error: UnicodeDecodeError")."""
    import os
    import pty
    import select
    import threading

    from ambdaq.drivers.serial.framing import encode_frame
    from ambdaq.drivers.serial.protocol import HEADER, MsgType

    master, slave = pty.openpty()
    stop = threading.Event()

    def answer() -> None:
        seq = 0
        while not stop.is_set():
            if select.select([master], [], [], 0.05)[0]:
                try:
                    os.read(master, 4096)
                    os.write(master, encode_frame(HEADER.pack(MsgType.IDENTITY, 0, seq) + b"\xff\xfe{junk"))
                except OSError:
                    return
                seq += 1

    device = threading.Thread(target=answer, daemon=True)
    device.start()
    try:
        r = run_cli("record", "--device", f"serial://{os.ttyname(slave)}", "--duration", "1", "-o", tmp_path / "x.mcap")
    finally:
        stop.set()
        device.join(timeout=2)  # before its terminal is closed under it
        os.close(slave)
        os.close(master)
    assert r.exit_code == 1 and "IDENTITY is not JSON text" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and "internal error" not in r.output


def test_an_output_name_that_is_no_utf8_records(tmp_path):
    """A file name with a byte that is no UTF-8 (from another system): recorded, its command line
    kept in the metadata with the byte escaped (it had been an internal UnicodeEncodeError)."""
    import os

    name = os.fsdecode(bytes(tmp_path) + b"/run\xff.mcap")
    r = subprocess.run([sys.executable, "-m", "ambdaq", "sim", "generate", "--duration", "0.1", "-q", "-o", name],
                       capture_output=True, timeout=120)
    assert r.returncode == 0, r.stderr
    meta = load(name).metadata["ambdaq.session"]
    assert "run\\udcff.mcap" in meta["command"]


def test_a_disk_that_fills_up_is_one_line_naming_the_file_and_what_was_flushed_is_kept(tmp_path):
    """The process may write 2 MB (RLIMIT_FSIZE, with SIGXFSZ ignored: writes then fail with EFBIG, as
    they fail with ENOSPC on a full disk): the error names the file, and recover reads what was flushed."""
    import resource
    import signal

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2_000_000, 2_000_000))

    out = tmp_path / "big.mcap"
    r = subprocess.run([sys.executable, "-m", "ambdaq", "sim", "generate", "--duration", "10", "-q", "-o", str(out)],
                       preexec_fn=small_disk, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr
    assert r.stderr.strip() == (f"ambdaq: error: {out}: cannot write the recording: File too large; what was flushed "
                                "before is in the file (ambdaq recover reads it)")
    fixed = tmp_path / "fixed.mcap"
    r = subprocess.run([sys.executable, "-m", "ambdaq", "recover", str(out), "-o", str(fixed)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    gap = load(fixed)["/amb/gap"]
    assert len(gap) > 1000 and (gap.seq == gap.seq[0] + range(len(gap))).all()  # the first samples, none missing


def test_a_python_started_in_the_clones_parent_folder_imports_the_installed_package(tmp_path):
    """A clone named ``ambdaq`` and Python (or Jupyter) started in the folder that holds it: the
    import is the installed package, not the clone's folder as an empty namespace package (the
    src/ layout; the flat one failed here with "cannot import name '__version__'")."""
    import ambdaq

    root = Path(ambdaq.__file__).resolve().parents[2]  # the clone: src/ambdaq/__init__.py
    (tmp_path / "ambdaq").symlink_to(root, target_is_directory=True)
    r = subprocess.run([sys.executable, "-c", "from ambdaq import __version__; import ambdaq; print(ambdaq.__file__)"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert Path(r.stdout.strip()) == Path(ambdaq.__file__)
