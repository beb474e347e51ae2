"""A raw-CAN device described by its vendor's DBC file (cantools), recorded from a rig file.

The simulated probe conditioner (src/ambdaq/sim/devices/probes.py) sends big- and little-endian
signals, a multiplexed message and a frame its DBC does not describe; it keeps what it meant to
send, which is what the recording must hold.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ambdaq.daq import load
from ambdaq.sim.devices.probes import DBC_PATH, VENDOR_ID

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)


@pytest.fixture
def probes(third_party_rig):
    return third_party_rig


def test_dbc_messages_from_a_rig_file_hold_what_the_device_sent(probes, tmp_path, run_cli):
    channel_url = probes.urls["probes"].split("?")[0]
    (tmp_path / "probes.dbc").write_bytes(DBC_PATH.read_bytes())
    rig = tmp_path / "rig.toml"
    rig.write_text(f'''name = "probe-bench"
[[device]]
name = "probes"
url = "{channel_url}"
dbc = "probes.dbc"
messages = ["FrontGap", "RearGap", "Diagnostics"]
counters = {{ FrontGap = "counter", RearGap = "counter" }}
raw = true
''')
    out = tmp_path / "probes.mcap"
    r = run_cli("record", "--rig", rig, "--duration", "1", "--json", "-o", out)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["drops"] == 0 and summary["duplicates"] == 0
    rec = load(out)
    sent = list(probes.devices["probes"].sent)
    for message in ("FrontGap", "RearGap"):
        got = rec[f"/probes/{message}"]
        assert got.units["gap_x"] == "um" and "counter" not in got.fields  # the counter is the seq
        mine = [(t, v) for t, name, v in sent if name == message]
        # 500 frames/s for the recording's second of host time: no fewer than 450, and no more than
        # the device sent over the span recorded (a sender starved by a loaded host sends its
        # backlog in a burst: 716 in one second once)
        during = [t for t, _v in mine if got.log_time[0] - 50_000_000 <= t <= got.log_time[-1]]  # 50 ms: its latency
        assert 450 <= len(got) <= len(during), (len(got), len(during))
        for i in range(0, len(got), 37):
            # the frame it is: the last one sent before it arrived with its counter (the counter
            # turns every 32 ms; no frame here is that late)
            t, values = [(t, v) for t, v in mine if t <= got.log_time[i] and v["counter"] == got.seq[i] % 16][-1]
            # the DBC's 0.02 um counts: decoded scaled values agree to far below one count
            assert got["gap_x"][i] == pytest.approx(values["gap_x"], abs=1e-9)
            assert got["gap_y"][i] == pytest.approx(values["gap_y"], abs=1e-9)
    page0, page1 = rec["/probes/Diagnostics/m0"], rec["/probes/Diagnostics/m1"]
    assert set(page0["temperature_front"]) == {41.0} and set(page0["temperature_rear"]) == {44.0}
    assert page1.units["supply"] == "V" and set(page1["supply"]) == {24.012}
    raw = rec["/can/raw"]
    # 10 frames/s of an id the DBC does not describe: every one that came while the bus was read is
    # recorded (its byte 0 is the sender's 2 ms tick, every 50th), and the bus is read for most of the second (how soon it
    # opens depends on the host's load: CI once recorded 7 over 0.6 s)
    assert set(raw["arbitration_id"]) == {VENDOR_ID} and set(raw["b1"]) == {0xA5}
    assert len(raw) >= 5 and np.all(np.diff(raw["b0"].astype(int)) % 256 == 50), raw["b0"]  # every 50th tick
    assert "unknown_frames = " in run_cli("info", out).output

    # the official reader and ros2 decoder read the same SI values
    with open(out, "rb") as fh:
        decoded = [m for _s, _c, _m, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(topics=["/probes/RearGap"])]
    np.testing.assert_array_equal([m.gap_x for m in decoded], rec["/probes/RearGap"]["gap_x"])


def test_a_lost_frame_is_counted_from_the_rolling_counter():
    from ambdaq.drivers.can.dbc import _Stream
    from ambdaq.drivers.signals import SignalGroup

    s = _Stream(SignalGroup("/p/m", "M", ("x",), ("um",)), "counter", 4, 500.0)
    for counter in (14, 15, 0, 2, 3, 3, 4):  # one lost after 0; 3 repeated
        s.add(0, [0.0], counter)
    assert [r[0] for r in s.queue.rows] == [14, 15, 16, 18, 19, 19, 20]  # a gap, and a duplicate for the recorder to drop


@pytest.mark.parametrize("damage, says", [
    (lambda t: t.replace("SG_ gap_y : 23|16@0-", "SG_ gap_y : 23|16@0"), "line 18"),
    # a message without a cycle time records (tests/test_dbc_corpus.py); a negative one cannot be
    (lambda t: t.replace('BA_ "GenMsgCycleTime" BO_ 770 2;', 'BA_ "GenMsgCycleTime" BO_ 770 -5;'),
     "RearGap: GenMsgCycleTime -5 is not a cycle time"),
    (lambda t: "\x00\xff" + t[: len(t) // 3], "not a valid DBC file"),
    # bounds: a string that would cost cantools some 20 GB is refused before cantools sees it
    (lambda t: t + 'CM_ "' + "x" * 100_000 + '";\n', "a string or word of 100,002 characters"),
    (lambda t: t + "\n" * (17 << 20), "more than the 16 MB"),
])
def test_a_broken_dbc_is_one_line_exit_2(tmp_path, run_cli, damage, says):
    bad = tmp_path / "bad.dbc"
    bad.write_text(damage(DBC_PATH.read_text()))
    r = run_cli("record", "--device", f"can://virtual/nobus?dbc={bad}", "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
    assert "bad.dbc" in r.output and says in r.output
    assert not (tmp_path / "x.mcap").exists()
