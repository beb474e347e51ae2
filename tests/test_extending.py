"""A back-end from another package, registered through the ``ambdaq.backends`` entry-point group
(docs/architecture.md, "Adding a device type"): installed beside ambdaq, its scheme is found by
``ambdaq record`` without a line of ambdaq changed, and what it streams is recorded exactly."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from ambdaq.daq import load

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

PLUGIN = '''
"""tone://NAME?hz=F: a 1 kHz source of a 1 um sine on one gap channel (a test back-end)."""
import numpy as np

from ambdaq.drivers.interfaces import Source
from ambdaq.drivers.registry import Backend, Opened
from ambdaq.drivers.signals import SampleBlock, SignalGroup
from ambdaq.drivers.url import Scheme

RATE = 1000.0


class Tone(Source):
    sample_rate = RATE

    def __init__(self, name, hz):
        self.name, self.hz, self.next, self.end = name, hz, 0, 0

    def signal_groups(self):
        return [SignalGroup("/tone/gap", "Gap", ("x",), ("m",)),
                SignalGroup("/tone/count", "Count", ("up", "down", "half"), ("", "", ""), ("uint64", "int64", "float64"))]

    def identity(self):
        return {"url": f"tone://{self.name}?hz={self.hz:g}", "kind": "tone generator"}

    def device_calibration(self):
        return {}

    def start(self, n_samples):
        self.end = n_samples

    def read(self):
        n = min(100, self.end - self.next)
        if n <= 0:
            return None
        k = np.arange(self.next, self.next + n, dtype=np.int64)
        self.next += n
        x = 1e-6 * np.sin(2 * np.pi * self.hz * k / RATE)
        count = self.signal_groups()[1].values_array(
            [(2**64 - 1 - i, -(2**63) + i, i / 2) for i in k.tolist()])  # 64-bit integers at their ends
        return SampleBlock(k * 1_000_000, k.astype(np.uint32), {"/tone/gap": x[:, None], "/tone/count": count})

    def _close(self):
        self.end = self.next


class ToneBackend(Backend):
    scheme = Scheme("tone", "tone://NAME[?hz=F]", ("hz",))
    description_keys = ("pitch_file",)  # a rig file may name a file holding the tone's frequency
    path_keys = ("pitch_file",)

    def discover(self):
        return [{"url": "tone://gen?hz=50", "description": "the test tone generator"}]

    def open(self, url, request):
        pitch = request.description.get("pitch_file")
        hz = float(open(pitch).read()) if pitch else url.number("hz", 50.0)
        return Opened([Tone(request.name or url.target, hz)])
'''


def _installed(tmp_path):
    """The plugin as an installed distribution would leave it: a module and a dist-info folder
    whose entry_points.txt names the back-end."""
    (tmp_path / "tone_plugin.py").write_text(PLUGIN)
    info = tmp_path / "tone_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: tone-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[ambdaq.backends]\ntone = tone_plugin:ToneBackend\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}


def _ambdaq(env, *args):
    return subprocess.run([sys.executable, "-m", "ambdaq", *args], env=env, capture_output=True, text=True,
                          timeout=120)


def test_an_entry_point_back_end_is_recorded_like_ambdaq_s_own(tmp_path):
    env = _installed(tmp_path)
    out = tmp_path / "tone.mcap"
    run = _ambdaq(env, "record", "--device", "tone://gen?hz=50", "--duration", "0.5", "-q", "-o", str(out))
    assert run.returncode == 0, run.stderr
    gap = load(out)["/tone/gap"]
    k = np.arange(500)
    assert np.array_equal(gap.seq, k)
    # float64 values are stored byte for byte and computed by the same expression: equal exactly
    assert np.array_equal(gap["x"], 1e-6 * np.sin(2 * np.pi * 50.0 * k / 1000.0))


def test_64_bit_integer_fields_are_exact_in_every_reader_and_export(tmp_path):
    """A back-end that declares uint64 and int64 fields: the values at the ends of their range
    (2**64 - 1 and -2**63, far past float64's 2**53) come back exactly from ``load``, from the
    official ROS 2 decoder, as CSV text, as Parquet and MDF 4 integer columns, and from ``recover``."""
    import pyarrow.parquet as pq
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    env = _installed(tmp_path)
    out = tmp_path / "tone.mcap"
    run = _ambdaq(env, "record", "--device", "tone://gen", "--duration", "0.3", "-q", "-o", str(out))
    assert run.returncode == 0, run.stderr
    k = list(range(300))
    up, down = [2**64 - 1 - i for i in k], [-(2**63) + i for i in k]
    count = load(out)["/tone/count"]
    assert count["up"].dtype == np.uint64 and count["down"].dtype == np.int64 and count["half"].dtype == np.float64
    assert count["up"].tolist() == up and count["down"].tolist() == down and count["half"].tolist() == [i / 2 for i in k]
    with open(out, "rb") as fh:
        official = [(m.up, m.down) for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                    .iter_decoded_messages(topics=["/tone/count"])]
    assert official == list(zip(up, down))
    run = _ambdaq(env, "export", str(out), "--format", "csv", "--topic", "/tone/count", "-o", str(tmp_path / "c.csv"))
    assert run.returncode == 0, run.stderr
    rows = [line.split(",") for line in (tmp_path / "c.csv").read_text().splitlines()]
    head = rows[0]
    assert [int(r[head.index("up")]) for r in rows[1:]] == up and [int(r[head.index("down")]) for r in rows[1:]] == down
    run = _ambdaq(env, "export", str(out), "--format", "parquet", "-o", str(tmp_path / "pq"))
    assert run.returncode == 0, run.stderr
    table = pq.read_table(tmp_path / "pq" / "tone_count.parquet")
    assert table.column("up").to_pylist() == up and table.column("down").to_pylist() == down
    run = _ambdaq(env, "export", str(out), "--format", "mf4", "--topic", "/tone/count", "-o", str(tmp_path / "c.mf4"))
    assert run.returncode == 0, run.stderr
    from asammdf import MDF

    mdf = MDF(tmp_path / "c.mf4")  # asammdf, as CANape and INCA users open it: integer channels
    assert mdf.get("tone.count.up").samples.tolist() == up and mdf.get("tone.count.down").samples.tolist() == down
    mdf.close()
    cut = tmp_path / "cut.mcap"  # the file as a crash would leave it: no summary, no footer
    cut.write_bytes(out.read_bytes()[: int(out.stat().st_size * 0.8)])
    run = _ambdaq(env, "recover", str(cut), "-o", str(tmp_path / "r.mcap"))
    assert run.returncode == 0, run.stderr
    kept = load(tmp_path / "r.mcap")["/tone/count"]
    assert len(kept) > 0 and kept["up"].tolist() == up[: len(kept)] and kept["down"].tolist() == down[: len(kept)]


def test_an_unknown_scheme_names_the_installed_ones(tmp_path):
    env = _installed(tmp_path)
    run = _ambdaq(env, "record", "--device", "bogus://x", "--duration", "0.1", "-o", str(tmp_path / "x.mcap"))
    assert run.returncode == 2
    assert "tone://NAME[?hz=F]" in run.stderr and "serial:" in run.stderr and len(run.stderr.splitlines()) == 1
    # without the plugin on the path its scheme is as unknown as any other
    run = _ambdaq({**os.environ}, "record", "--device", "tone://gen", "--duration", "0.1", "-o", str(tmp_path / "y.mcap"))
    assert run.returncode == 2 and "unknown device URL 'tone://gen'" in run.stderr


def test_a_back_end_declares_the_rig_file_keys_it_reads(tmp_path):
    """The plug-in's own rig-file key (a file name, taken relative to the rig file) reaches it;
    a key no back-end of that device declares is one line naming the keys it has."""
    env = _installed(tmp_path)
    rigs = tmp_path / "rigs"
    rigs.mkdir()
    (rigs / "pitch.txt").write_text("25")
    (rigs / "rig.toml").write_text('name = "t"\n[[device]]\nname = "gen"\nurl = "tone://gen"\npitch_file = "pitch.txt"\n')
    out = tmp_path / "rig.mcap"
    run = _ambdaq(env, "record", "--rig", str(rigs / "rig.toml"), "--duration", "0.5", "-q", "-o", str(out))
    assert run.returncode == 0, run.stderr
    k = np.arange(500)
    assert np.array_equal(load(out)["/tone/gap"]["x"], 1e-6 * np.sin(2 * np.pi * 25.0 * k / 1000.0))
    (rigs / "bad.toml").write_text('[[device]]\nurl = "tone://gen"\ndbc = "x.dbc"\n')
    run = _ambdaq(env, "record", "--rig", str(rigs / "bad.toml"), "--duration", "0.5", "-o", str(tmp_path / "b.mcap"))
    assert run.returncode == 2 and "unknown key 'dbc'" in run.stderr and "pitch_file" in run.stderr, run.stderr


def test_ambdaq_devices_lists_what_a_plug_in_finds(tmp_path):
    env = _installed(tmp_path)
    run = _ambdaq(env, "devices")
    assert run.returncode == 0, run.stderr
    assert "tone:// (plug-in):" in run.stdout and "the test tone generator  tone://gen?hz=50" in run.stdout
    run = _ambdaq(env, "devices", "--json")
    assert json.loads(run.stdout)["plugins"] == {"tone": [{"url": "tone://gen?hz=50", "description": "the test tone generator"}]}
