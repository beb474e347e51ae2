"""Bad input: one clear line, exit 2, no traceback, nothing written over."""

import hashlib
import subprocess
import sys

import pytest
from damage import without_data_crc
from mcap.writer import Writer

from ambdaq.daq import load
from ambdaq.errors import BadInputError

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)


def one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output, result.output
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def truncated(spindle_file, tmp_path):
    data = spindle_file.read_bytes()
    p = tmp_path / "truncated.mcap"
    p.write_bytes(data[: len(data) // 2])
    return p


def test_truncated_file(truncated, run_cli):
    for cmd in (["info"], ["export", "--format", "npz", "-o", str(truncated.with_suffix(".npz"))],
                ["plot", "--field", "front_x", "-o", str(truncated.with_suffix(".png"))]):
        r = run_cli(cmd[0], truncated, *cmd[1:])
        one_line_error(r, "truncated or unfinished", "ambdaq recover")
    assert not truncated.with_suffix(".npz").exists() and not truncated.with_suffix(".png").exists()


def _second_chunk(path):
    from ambdaq.mcap.mcapfile import McapFile

    f = McapFile(path)
    return sorted(f.summary.chunk_indexes, key=lambda ci: ci.chunk_start_offset)[1], f


def test_corrupted_chunk(spindle_file, tmp_path, run_cli):
    ci, _ = _second_chunk(spindle_file)
    data = bytearray(spindle_file.read_bytes())
    mid = ci.chunk_start_offset + ci.chunk_length // 2
    data[mid : mid + 64] = bytes(64)  # zero a run of bytes inside a compressed chunk
    p = tmp_path / "corrupt.mcap"
    p.write_bytes(bytes(data))
    r = run_cli("export", p, "--format", "npz", "-o", tmp_path / "c.npz")
    one_line_error(r, "corrupt")
    # recover keeps the good chunks and drops the damaged one
    r = run_cli("recover", p, "-o", tmp_path / "fixed.mcap", "--json")
    assert r.exit_code == 0, r.output
    gap = load(tmp_path / "fixed.mcap")["/amb/gap"]
    assert 0 < len(gap) < 20000


@pytest.mark.parametrize("where", ["first entry", "middle entry"])
def test_a_damaged_message_index_is_an_error_not_wrong_samples(spindle_file, tmp_path, run_cli, where):
    """A Message Index has no checksum: zeroed entries (log time and offset 0) at its start (the
    offsets keep a constant stride from the second on) or in its middle must not load another
    record's bytes as samples.  The records are intact, so recover keeps every sample."""
    ci, f = _second_chunk(spindle_file)
    gap_channel = next(cid for cid, ch in f.summary.channels.items() if ch.topic == "/amb/gap")
    entries = ci.message_index_offsets[gap_channel] + 15  # opcode, length, channel id, byte count
    at = entries + (0 if where == "first entry" else 16 * (f.message_index(ci, gap_channel).shape[0] // 2))
    data = bytearray(spindle_file.read_bytes())
    data[at : at + 64] = bytes(64)  # four entries
    p = tmp_path / "bad_index.mcap"
    p.write_bytes(bytes(data))
    one_line_error(run_cli("export", p, "--format", "npz", "-o", tmp_path / "c.npz"),
                   "fails its CRC-32", "ambdaq recover")  # the data section's CRC sees it first
    p.write_bytes(without_data_crc(data))  # as a writer without that CRC leaves it: the index is checked
    one_line_error(run_cli("export", p, "--format", "npz", "-o", tmp_path / "c.npz"),
                   "does not point at channel", "/amb/gap", "ambdaq recover")
    assert not (tmp_path / "c.npz").exists()
    r = run_cli("recover", p, "-o", tmp_path / "fixed.mcap", "--json")
    assert r.exit_code == 0, r.output
    fixed, original = load(tmp_path / "fixed.mcap")["/amb/gap"], load(spindle_file)["/amb/gap"]
    assert len(fixed) == 20000 and (fixed["front_x"] == original["front_x"]).all()


def test_foreign_files(tmp_path, run_cli):
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    one_line_error(run_cli("info", text), "not an MCAP file")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    one_line_error(run_cli("info", empty), "empty file")
    one_line_error(run_cli("info", tmp_path / "missing.mcap"), "no such file")
    # a valid MCAP from another tool: info describes it; its JSON topic loads and exports (issue 28:
    # any MCAP in, numbers out; tests/test_foreign_mcap.py), a topic no decoder here reads does not
    other = tmp_path / "other.mcap"
    with open(other, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("Pose", "jsonschema", b"{}")
        cid = w.register_channel("/pose", "json", sid)
        w.add_message(cid, log_time=1, publish_time=1, data=b"{}")
        fid = w.register_channel("/scan", "flatbuffer", w.register_schema("Scan", "flatbuffer", b"\x00"))
        w.add_message(fid, log_time=2, publish_time=2, data=b"\x00")
        w.finish()
    r = run_cli("info", other)
    assert r.exit_code == 0 and "/pose" in r.output
    r = run_cli("export", other, "--format", "npz", "-o", tmp_path / "o.npz")
    assert r.exit_code == 0 and (tmp_path / "o.npz").exists(), r.output
    assert len(load(other)["/pose"]) == 1 and not load(other)["/pose"].fields
    one_line_error(run_cli("export", other, "--format", "npz", "--topic", "/scan", "-o", tmp_path / "s.npz"),
                   "no ambdaq topic /scan", "/pose")
    with pytest.raises(BadInputError):
        load(other, topics=["/scan"])


@pytest.mark.parametrize(
    "url, needle",
    [
        ("foo://bar", "unknown device URL 'foo://bar': expected sim://PROFILE"),
        ("spindle", "unknown device URL"),
        ("sim://nope", "unknown simulated rig 'nope': profiles are base-motion, cone, flexible, flexible-long, lorentz, spindle"),
        ("sim://spindle?bogus=1", "unknown option 'bogus'"),
        ("sim://spindle?seed=x", "expected an integer"),
        ("sim://spindle?ff=maybe", "expected one of off, table, lms"),
        ("sim://spindle?truth=2", "expected 0 or 1"),
    ],
)
def test_bad_device_urls(url, needle, tmp_path, run_cli):
    r = run_cli("record", "--device", url, "--duration", "0.1", "-o", tmp_path / "x.mcap")
    one_line_error(r, needle)
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("args, needle", [
    (["--rpm", "fast"], "bad speed 'fast'"),
    (["--rpm", "90000"], "rpm must be within 0..60000"),
    (["--rpm", "0:1000:-1"], "ramp time must be > 0 s"),
    (["--duration", "-1"], "Invalid value for '--duration'"),
    (["--split-size", "lots"], "is not a size"),
])
def test_bad_options(args, needle, tmp_path, run_cli):
    r = run_cli("record", "--device", "sim://spindle", "--duration", "0.1", "-o", tmp_path / "x.mcap", *args)
    assert r.exit_code == 2 and needle in r.output and "Traceback" not in r.output


@pytest.mark.parametrize("url", ["can://udp_multicast/239.74.163.2?node=16",
                                 "xcp+can://udp_multicast/239.74.163.2?id_master=1&id_slave=2&a2l=x.a2l"])
def test_can_over_an_ip_network_is_refused(url, tmp_path, run_cli, monkeypatch):
    """The house never sends traffic onto a network: python-can's network interface is refused by
    the URL parser itself, before any bus is opened. Should that refusal ever break, no bus can
    open here either: python-can's constructor fails the test instead of joining the group."""
    import can

    def no_bus(*args, **kwargs):
        raise AssertionError(f"a CAN bus was opened: {args} {kwargs}")

    monkeypatch.setattr(can, "Bus", no_bus)
    monkeypatch.setattr(can.interface, "Bus", no_bus)
    one_line_error(run_cli("record", "--device", url, "--duration", "0.1", "-o", tmp_path / "x.mcap"),
                   "sends CAN frames onto an IP network")
    assert not (tmp_path / "x.mcap").exists()


def test_no_device(tmp_path, run_cli):
    one_line_error(run_cli("record", "-o", tmp_path / "x.mcap"), "give --device URL or --rig FILE")


def test_bad_rig_files(tmp_path, run_cli):
    cases = {
        "broken.toml": ("[[device]\nurl=", "not a valid TOML rig file"),
        "nodev.toml": ('name = "x"\n', "no [[device]] tables"),
        "badkey.toml": ('[[device]]\nurl = "sim://spindle"\nport = 3\n', "unknown key 'port'"),
        "badurl.toml": ('[[device]]\nurl = "tcp://x"\n', "unknown device URL"),
    }
    for name, (text, needle) in cases.items():
        (tmp_path / name).write_text(text)
        one_line_error(run_cli("record", "--rig", tmp_path / name, "-o", tmp_path / "x.mcap"), needle)


def test_nothing_is_written_over(spindle_file, tmp_path, run_cli):
    before = digest(spindle_file)
    r = run_cli("record", "--device", "sim://spindle", "--duration", "0.1", "-o", spindle_file)
    one_line_error(r, "exists", "--overwrite")
    r = run_cli("sim", "generate", "--duration", "0.1", "-o", spindle_file)
    one_line_error(r, "exists")
    r = run_cli("recover", spindle_file, "-o", spindle_file)
    one_line_error(r, "exists")
    assert digest(spindle_file) == before


def test_subprocess_exit_codes_and_no_traceback(tmp_path):
    r = subprocess.run([sys.executable, "-m", "ambdaq", "info", str(tmp_path / "nope.mcap")], capture_output=True,
                       text=True)
    assert r.returncode == 2 and r.stderr.strip().startswith("ambdaq: error:") and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "ambdaq", "--debug", "info", str(tmp_path / "nope.mcap")],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "Traceback" in r.stderr  # --debug shows it


def test_small_input_gaps_are_one_line(spindle_file, tmp_path, run_cli):
    """Issue 12, item 8: an image suffix matplotlib cannot write, an excitation in metres instead
    of micrometres (and below what the controller resolves in volts), a usage error: one line,
    exit 2, nothing written."""
    one_line_error(run_cli("plot", spindle_file, "--field", "front_x", "-o", tmp_path / "p.jpg2"),
                   "p.jpg2'", ".png", "ambdaq plot --help")
    assert not (tmp_path / "p.jpg2").exists()
    one_line_error(run_cli("runout", "identify", spindle_file, "-o", tmp_path / "c.json", "--plot", tmp_path / "r.bmpx"),
                   ".bmpx")
    assert not (tmp_path / "c.json").exists()  # refused before anything ran
    one_line_error(run_cli("sim", "generate", "--duration", "0.1", "--excite", "front_x:2e-6", "-o", tmp_path / "e.mcap"),
                   "2e-06 um is below 0.01 um", "in um", "give 2")
    one_line_error(run_cli("sim", "generate", "--profile", "base-motion", "--duration", "0.1", "--excite",
                           "amb1_y:1e-5", "-o", tmp_path / "e.mcap"), "below 0.001 V")
    assert not (tmp_path / "e.mcap").exists()
    one_line_error(run_cli("record", "--duration", "-1", "--device", "sim://spindle", "-o", tmp_path / "x.mcap"),
                   "--duration", "ambdaq record --help")


def test_a_closed_pipe_is_not_an_error(spindle_file):
    """``ambdaq info FILE | head``: the reader closes the pipe; nothing is said about it."""
    p = subprocess.Popen([sys.executable, "-m", "ambdaq", "info", "--json", str(spindle_file)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # before a byte is read: every write meets a closed pipe
    _, err = p.communicate(timeout=60)
    assert b"Broken pipe" not in err and b"Exception ignored" not in err and b"Traceback" not in err, err


@pytest.mark.parametrize("missing, args, extra", [
    ("matplotlib", ["plot", "{file}", "--topic", "/amb/gap", "--field", "front_x", "-o", "{tmp}/p.png"], "ambdaq[plot]"),
    ("pyarrow", ["export", "{file}", "--format", "parquet", "--topic", "/amb/gap", "-o", "{tmp}/g.parquet"],
     "ambdaq[parquet]"),
])
def test_a_missing_extra_is_one_line_naming_it(spindle_file, tmp_path, run_cli, missing, args, extra):
    """A recording-only install has no matplotlib or pyarrow: the command that needs one says which
    extra to install, in one line, exit 2.  The package is hidden from the import system here
    (``sys.modules[name] = None`` makes ``import name`` fail as if it were not installed)."""
    argv = [a.format(file=spindle_file, tmp=tmp_path) for a in args]
    code = (f"import sys; sys.modules[{missing!r}] = None; sys.argv = ['ambdaq', *{argv!r}]; "
            "from ambdaq.cli.main import main; main()")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and extra in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert run_cli(*argv).exit_code == 0  # the same command with the package there (in this process)


@pytest.mark.parametrize("kind", ["fifo", "directory", "symlink-to-device", "dangling-symlink"])
@pytest.mark.parametrize("overwrite", [False, True])
def test_output_is_only_ever_a_regular_file(kind, overwrite, tmp_path, run_cli):
    """`-o` names a FIFO, a directory or a symlink to a device node or to nothing: one line, exit 2,
    with or without --overwrite, and the thing is left as it was (it had been replaced by a file)."""
    import os
    import stat

    target = tmp_path / "out.mcap"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "directory":
        target.mkdir()
    elif kind == "symlink-to-device":
        target.symlink_to("/dev/null")
    else:
        target.symlink_to(tmp_path / "nowhere" / "x.mcap")
    before = os.lstat(target)
    args = ["sim", "generate", "--duration", "0.1", "-q", "-o", target] + (["--overwrite"] if overwrite else [])
    r = run_cli(*args)
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert "regular file" in r.output or "is a directory" in r.output  # click refuses a directory itself
    after = os.lstat(target)
    assert stat.S_IFMT(after.st_mode) == stat.S_IFMT(before.st_mode) and after.st_ino == before.st_ino


@pytest.mark.parametrize("profile", ["cone", "lorentz", "base-motion"])
def test_a_feedforward_mode_for_a_rig_without_one_is_one_line(profile, run_cli, tmp_path):
    """Only the spindle runs Ro et al.'s runout feedforward; asking another rig for it had been an
    internal ValueError."""
    r = run_cli("sim", "generate", "--profile", profile, "--ff", "lms", "--duration", "0.1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and f"the {profile} rig has no runout feedforward" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("codec", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("data_crc", [True, False], ids=["data CRC", "no data CRC"])
def test_a_flipped_byte_anywhere_is_refused_or_changes_nothing(codec, data_crc, tmp_path, run_cli):
    """One bit flipped at 80 places drawn over the whole file (chunk headers and data, indexes,
    metadata, summary, footer): ``load`` refuses the file in one BadInputError or returns every
    value bit for bit as written, never another value; with the data section's CRC, every flip is
    refused.  Without it (a writer that stores none), a flip that changes a chunk's records is
    still refused: by the zstd or lz4 frame checksum, or the chunk's CRC-32 of an uncompressed one."""
    import random

    import numpy as np

    from ambdaq.mcap.mcapfile import McapFile, chunk_header

    path = tmp_path / "f.mcap"
    assert run_cli("sim", "generate", "--duration", "0.03", "--compression", codec, "-q", "-o", path).exit_code == 0
    data = bytes(path.read_bytes() if data_crc else without_data_crc(path.read_bytes()))
    path.write_bytes(data)
    # an uncompressed chunk's records: a flip there is a changed record, which its CRC-32 must
    # catch (in compressed data a flip can leave what it inflates to as it was: a match offset into
    # a run of equal bytes; the frame's checksum catches every one that does not)
    payloads = [(h.data_start, h.data_end) for h in (chunk_header(data, ci.chunk_start_offset)
                                                     for ci in McapFile(path).chunks)] if codec == "none" else []
    ref = load(path)
    want = {(t, n): np.array(ref[t][n]).view(np.uint64) for t in ref for n in ref[t].fields}
    rnd = random.Random(f"{codec}{data_crc}")
    flipped = tmp_path / "flipped.mcap"
    outcomes = {"refused": 0, "unchanged": 0}
    for _ in range(80):
        at = rnd.randrange(len(data))
        b = bytearray(data)
        b[at] ^= 1 << rnd.randrange(8)
        flipped.write_bytes(b)
        try:
            got = load(flipped)
        except BadInputError as err:
            assert "\n" not in str(err) and str(flipped) in str(err)
            outcomes["refused"] += 1
            continue
        # without the data CRC a flip elsewhere may leave every value as it was (a flag bit of a frame
        # header, a byte of a schema's comment): what matters is that no value changed
        assert not data_crc and not any(a <= at < e for a, e in payloads), f"a flip at byte {at} was not seen"
        for (t, n), v in want.items():
            assert np.array_equal(np.array(got[t][n]).view(np.uint64), v), f"byte {at} changed {t}.{n}"
        outcomes["unchanged"] += 1
    assert outcomes["refused"] > 40, outcomes


@pytest.mark.parametrize("byte", [0, 3, 7], ids=["low byte", "middle byte", "high byte"])
def test_a_chunk_size_that_cannot_be_is_refused_before_memory_is_sized_from_it(byte, tmp_path, run_cli):
    """A chunk's uncompressed size changed in a file without indexes and without the data CRC (so
    nothing but the chunk itself can tell): refused in one line, exit 2, before any memory is sized
    from it (the high byte once asked numpy for 7.75 PiB); export writes nothing."""
    from ambdaq.mcap.mcapfile import McapFile

    path = tmp_path / "n.mcap"
    assert run_cli("sim", "generate", "--duration", "0.05", "--no-index", "-q", "-o", path).exit_code == 0
    first = McapFile(path).chunks[0].chunk_start_offset
    data = without_data_crc(path.read_bytes())
    data[first + 9 + 16 + byte] ^= 0x40  # opcode, length; message start and end times; then the size
    path.write_bytes(bytes(data))
    r = run_cli("export", path, "--format", "csv", "-o", tmp_path / "out")
    one_line_error(r, "the chunk at byte", "declares", "ambdaq recover")
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
