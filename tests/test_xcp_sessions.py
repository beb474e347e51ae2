"""ambdaq as the XCP master of a slave no one here wrote, proven on that slave's recorded
conversations (``../shared/corpus/xcp/``: Vector's XCPlite, every packet both ways, as data).

Each session of ambdaq 0.2.0 is played back (``tests/xcp_replay.py``): the slave's side answers
ambdaq's k-th command with the k-th response XCPlite gave, and only if that command is, byte for
byte, the one the session holds; then streams XCPlite's DTOs as they came.  What ambdaq records is
checked against two things it did not compute:

- the DTOs of the session decoded by the test's own reading of the session's WRITE_DAQ layout
  (:func:`xcp_replay.daq_samples`), every field of every sample, by the measurement's address
  and type as the A2L's text gives them (read here with a regular expression, not ambdaq's parser);
- what the corpus README says the slave's memory held: the temperatures, ``diff_temp``,
  ``heat_power``, ``global_counter`` counting loops, ``params.flow_rate`` 0.301.

A value under the wrong name, from another sample or another event breaks the first; a wrong
conversion breaks the second.  A session played to a master that asks something else says which
command (the replay never guesses an answer).  pyxcp's own session is decoded the same way and
agrees with what pyxcp printed.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from xcp_replay import CORPUS, Replay, Session, daq_samples

from ambdaq.daq import load

# the slave's packets are paced as they were recorded; one worker runs the module
pytestmark = [pytest.mark.realtime, pytest.mark.xdist_group("xcp-sessions")]

TYPES = {"UBYTE": "u1", "SBYTE": "i1", "UWORD": "<u2", "SWORD": "<i2", "ULONG": "<u4", "SLONG": "<i4",
         "A_UINT64": "<u8", "A_INT64": "<i8", "FLOAT32_IEEE": "<f4", "FLOAT64_IEEE": "<f8"}
MEASUREMENT = re.compile(r"/begin MEASUREMENT (\S+) \"[^\"]*\" (\S+) (\S+) .*?ECU_ADDRESS (0x[0-9A-Fa-f]+)"
                         r"(?: ECU_ADDRESS_EXTENSION (\d+))?")


def measurements(a2l: Path) -> dict[str, tuple[int, int, str, str]]:
    """Each MEASUREMENT's (extension, address, numpy type, conversion), from the file's text."""
    text = a2l.read_text(encoding="latin-1")
    return {m.group(1): (int(m.group(5) or 0), int(m.group(4), 16), TYPES[m.group(2)], m.group(3))
            for m in MEASUREMENT.finditer(text)}


def replayed(name: str) -> tuple[Session, Replay]:
    session = Session(CORPUS / f"{name}.jsonl")
    return session, Replay(session)


def check_against_the_dtos(session: Session, out: Path, a2l: Path) -> dict[str, np.ndarray]:
    """Every field of every topic ambdaq recorded equals the session's DTOs decoded here, sample for
    sample (matched by the DTO timestamp); returns each recorded field by its A2L name."""
    rec = load(out)
    known = measurements(a2l)
    lists = {s.event: s for s in daq_samples(session).values()}
    by_name: dict[str, np.ndarray] = {}
    for topic in rec:
        data = rec[topic]
        device = next(d for d in rec.devices.values() if topic in d.topics)
        sent = lists[int(device.identity["event_number"])]
        stamps = np.array(sent.timestamps, dtype=np.int64)
        # the recorded samples are a run of the slave's: its first sample's timestamp says where
        raw = data.device_time % (1 << 32)  # 32-bit DTO timestamps in 1 ns (GET_DAQ_RESOLUTION_INFO)
        start = int(np.flatnonzero(stamps == raw[0])[0])
        np.testing.assert_array_equal(raw, stamps[start : start + len(data)], err_msg=f"{topic}: time stamps")
        for field, a2l_name in json.loads(device.identity["measurements"]).items():
            by_name[a2l_name] = data[field]
            if a2l_name not in known:
                continue  # an instance's component: checked against the README below
            ext, address, dtype, conversion = known[a2l_name]
            values = np.array([np.frombuffer(v[(ext, address)], dtype=dtype)[0]
                               for v in sent.values[start : start + len(data)]])
            if conversion == "conv.temperature":  # COEFFS_LINEAR 1 -55 (the A2L's own method)
                values = values.astype(np.float64) - 55.0
            np.testing.assert_array_equal(data[field], values, err_msg=f"{topic} {field} ({a2l_name})")
    return by_name


@pytest.mark.parametrize("name", ["hello_tcp_record_all", "hello_udp_record_all"])
def test_record_every_measurement_of_hello_xcp(name, tmp_path, run_cli):
    session, replay = replayed(name)
    a2l = CORPUS / ("hello_xcp_udp.a2l" if "udp" in name else "hello_xcp_hello.a2l")
    out = tmp_path / "hello.mcap"
    with replay:
        r = run_cli("record", "--device", replay.url, "--a2l", a2l, "--measure", "*", "--duration", "2", "-o", out)
    assert replay.mismatch is None and replay.finished, replay.explain()
    assert r.exit_code == 0, r.output
    got = check_against_the_dtos(session, out, a2l)
    assert set(got) == {"t1", "t2", "diff_temp", "heat_power", "outside_temperature", "inside_temperature",
                        "heat_energy", "global_counter", "counter"}
    # what the README says the slave held
    assert set(got["outside_temperature"]) == {-5.0} and set(got["inside_temperature"]) == {20.0}
    assert set(got["t1"]) == {50.0} and set(got["t2"]) == {75.0} and set(got["diff_temp"]) == {25.0}
    flow_rate = float(np.float32(0.301))  # params.flow_rate, a float in this build
    assert set(got["heat_power"]) == {25.0 * flow_rate * 1000.0 * 1.16}  # computed in double, exactly
    loops = got["global_counter"].astype(np.int64)
    assert len(loops) > 1000 and np.all(np.diff(loops) == 1)  # a sporadic event on every loop
    # heat_energy sums heat_power / 3.6e9 over the loops (1e-9: the running sum's rounding over
    # some 10^4..10^5 additions is ~1e-11 relative; one loop more or less is 5e-5 off)
    np.testing.assert_allclose(got["heat_energy"], loops * (float(np.float32(25.0 * flow_rate * 1160.0)) / 3.6e9),
                               rtol=1e-9)


@pytest.mark.parametrize(("name", "chosen"), [
    ("abs_reversed_u8", ["outside_temperature", "inside_temperature"]),  # in reverse address order
    ("abs_mixed_f64_u8", ["heat_energy", "outside_temperature", "inside_temperature"])])
def test_a_rig_files_measurements_on_absolute_addresses(name, chosen, tmp_path, run_cli):
    """Absolute addressing (extension 0), a counter that numbers the samples (``counter=``) and is
    not a field, FLOAT64 beside UBYTEs in one ODT: 1 s is 1,000 periods of the 1 ms event."""
    session, replay = replayed(name)
    a2l = CORPUS / "hello_xcp_abs.a2l"
    out, rig = tmp_path / "abs.mcap", tmp_path / "rig.toml"
    with replay:
        rig.write_text(f'[[device]]\nname = "controller"\nurl = "{replay.url}?counter=global_counter"\n'
                       f'a2l = "{a2l}"\nmeasurements = {json.dumps(chosen)}\n')
        r = run_cli("record", "--rig", rig, "--duration", "1", "-o", out)
    assert replay.mismatch is None and replay.finished, replay.explain()
    assert r.exit_code == 0, r.output
    got = check_against_the_dtos(session, out, a2l)
    assert list(got) == chosen
    assert set(got["outside_temperature"]) == {-5.0} and set(got["inside_temperature"]) == {20.0}
    data = load(out)["/xcp/mainloop"]
    assert len(data) == 1000 and np.all(np.diff(data.seq.astype(np.int64)) == 1)  # numbered by global_counter
    if "heat_energy" in got:
        assert np.all(np.diff(got["heat_energy"]) > 0)


def test_every_integer_width_and_a_typedef_instance_of_c_demo(tmp_path, run_cli):
    """c_demo keeps one loop counter in 8- to 64-bit variables, signed and unsigned, global and on
    its stack, each truncated to its type as C truncates; 64-bit ones are recorded as integers,
    exact; the instance ``params_copy`` of a TYPEDEF_STRUCTURE holds the struct's defaults."""
    session, replay = replayed("c_demo_tcp_record_all")
    a2l = CORPUS / "c_demo.a2l"
    out = tmp_path / "c.mcap"
    with replay:
        r = run_cli("record", "--device", replay.url, "--a2l", a2l, "--measure", "*", "--duration", "2", "-o", out)
    assert replay.mismatch is None and replay.finished, replay.explain()
    assert r.exit_code == 0, r.output
    got = check_against_the_dtos(session, out, a2l)
    c = got["counter"].astype(np.int64)
    assert len(c) > 1000 and c.max() > 128
    # the event comes after `counter` counts and before the others copy it: they hold the loop
    # before's count (counter_max 1024 where counter wrapped to 0)
    before = np.where(c > 0, c - 1, 1024)
    for width in (8, 16, 32, 64):
        for prefix in ("counter", "g_counter"):
            unsigned, signed = got[f"{prefix}{width}"], got[f"{prefix}{width}s"]
            if width == 8:
                np.testing.assert_array_equal(unsigned, before & 0xFF)
                np.testing.assert_array_equal(signed, (before & 0xFF).astype(np.uint8).astype(np.int8))
            else:
                np.testing.assert_array_equal(unsigned, before)
                np.testing.assert_array_equal(signed, before)
    assert {n: got[n].dtype.str for n in ("counter64", "counter64s", "g_param_sum")} == {
        "counter64": "<u8", "counter64s": "<i8", "g_param_sum": "<u8"}
    assert set(got["g_param_sum"]) == {8 + 16 + 32 + 64}
    copy = {n: set(v) for n, v in got.items() if n.startswith("params_copy")}
    assert copy == {"params_copy.test_byte1": {1.0}, "params_copy.test_byte2": {-1.0},
                    "params_copy.counter_max": {1024.0}, "params_copy.delay_us": {1000.0}}


def test_a_float64_parameter_read_written_and_read_back(run_cli):
    """``controller param`` over three connections, as recorded: reads 0.301, writes 0.5 (the
    DOWNLOAD bytes are the session's, which XCPlite took), reads back 0.5."""
    _session, replay = replayed("f64_param_read_write")
    a2l = CORPUS / "hello_xcp_f64.a2l"
    outputs = []
    with replay:
        for extra in ([], ["0.5", "--yes"], []):
            r = run_cli("controller", "param", "--device", replay.url, "--a2l", a2l, "params.flow_rate", *extra)
            assert r.exit_code == 0, (r.output, replay.explain())
            outputs.append(r.output.strip())
    assert replay.mismatch is None and replay.finished, replay.explain()
    # the write says what it replaced, as the slave held it (and logs it for --undo)
    assert outputs == ["params.flow_rate = 0.301", "params.flow_rate = 0.5 (was 0.301; logged, --undo puts it back)",
                       "params.flow_rate = 0.5"]


def test_a_master_that_asks_otherwise_meets_a_silent_slave(tmp_path, run_cli):
    """The replay answers only what the session holds: a prescaler the slave lacks is refused after
    GET_DAQ_RESOLUTION_INFO, in one line, before anything is configured, and nothing is guessed;
    the session then ends with DISCONNECT, which the recorded one never sent there."""
    _session, replay = replayed("hello_tcp_record_all")
    with replay:
        r = run_cli("record", "--device", f"{replay.url}?prescaler=2", "--a2l", CORPUS / "hello_xcp_hello.a2l",
                    "--measure", "*", "--duration", "1", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "no DAQ prescaler" in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert replay.answered == 5 and not (tmp_path / "p.mcap").exists()
    # and it ends its session: DISCONNECT where the recorded master went on to GET_DAQ_EVENT_INFO
    assert replay.mismatch == (5, bytes([0xFE]), bytes.fromhex("d7000000")), replay.explain()


def test_ambdaqs_decoder_on_pyxcps_own_packing():
    """The session pyxcp ran (no ambdaq code on the master side) packed its ODT its own way; ambdaq's
    DTO assembler, given that layout, decodes its DTOs to what pyxcp printed
    (``pyxcp_daq_cyclic.out``: 1,672 samples, first and last values, the timestamps' span) and to
    what the test's own decoding of the same DTOs says, sample for sample."""
    from collections import deque

    from ambdaq.drivers.xcp.a2l import read_a2l
    from ambdaq.drivers.xcp.daq import DaqListPlan, DtoAssembler, Element
    from ambdaq.drivers.xcp.master import DaqProcessor, EventChannel

    session = Session(CORPUS / "pyxcp_daq_cyclic.jsonl")
    a2l = CORPUS / "hello_xcp_cyc.a2l"
    known = measurements(a2l)
    (daq, sent), = daq_samples(session).items()
    by_address = {(m.extension, m.address): m for m in read_a2l(a2l).measurements.values()}
    odts = [[Element(by_address[(ext, address)], 0, by_address[(ext, address)].name) for ext, address, _n in odt]
            for odt in sent.entries]
    processor = DaqProcessor(dynamic=True, prescaler=False, timestamps=True, overload="none", max_daq=0,
                             max_event=2, min_daq=0, address_extension="free", identification=3, granularity=1,
                             max_entry_size=248, timestamp_size=4, timestamp_fixed=True, timestamp_ns=1)
    plan = DaqListPlan(daq, EventChannel(sent.event, "mainloop", 1_000_000, 255, True), odts, header=4, timestamp=4)
    rows: deque = deque()
    assembler = DtoAssembler([plan], [rows], processor, "<", loss=lambda: 0, padded_to=0)
    assembler.selected()
    for t, _ctr, dto in session.dtos():
        assembler.on_dto(t, dto)
    decoded = np.frombuffer(b"".join(r[3] for r in rows), dtype=plan.dtype())
    assert len(decoded) == len(sent.values) == 1672 and assembler.unknown == 0
    assert [r[2] for r in rows] == sent.timestamps
    printed = (CORPUS / "pyxcp_daq_cyclic.out").read_text()
    span = re.search(r"device timestamp \(ts1, ns\) first (\d+) last (\d+)", printed)
    assert (sent.timestamps[-1] - sent.timestamps[0]) % (1 << 32) == int(span.group(2)) - int(span.group(1))  # 32-bit, wraps
    for k, element in enumerate(plan.elements):
        name = element.measurement.name
        ext, address, dtype, _conv = known[name]
        mine = decoded[f"e{k}"]
        np.testing.assert_array_equal(mine, [np.frombuffer(v[(ext, address)], dtype=dtype)[0] for v in sent.values])
        line = re.search(rf"^  {name}\s+first (\S+) last (\S+)", printed, re.M)
        assert (float(mine[0]), float(mine[-1])) == (float(line.group(1)), float(line.group(2))), name
