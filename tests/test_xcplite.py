"""ambdaq as the XCP master of a slave no one here wrote: Vector's XCPlite (``hello_xcp``), built by
the test from ``../shared/thirdparty/`` as shipped but for its ``#define``s (bound to 127.0.0.1,
a free port, TCP or UDP, quiet), with the A2L it writes itself.  Every recorded value is checked
against what pyxcp reads from the same slave or against the relations the slave's code keeps
between its variables in one loop (hello_xcp's ``main.c``):

- ``global_counter`` counts loops; ``counter`` counts them modulo ``params.counter_max + 1``;
- ``heat_energy`` (FLOAT64) is the sum of ``heat_power / 3.6e9`` over the loops, and ``heat_power``
  = (inside - outside temperature) * ``params.flow_rate`` * 1000 * 1.16;
- the temperatures (UBYTE, offset -55 degC) stay at -5 and 20 degC.

A value under the wrong name, or from another sample, breaks one of these.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
import socket
import struct
import subprocess
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest

from ambdaq.daq import load
from ambdaq.daq.mcapfile import McapFile

# the slave runs against the wall clock; one worker runs the module: one slave per build and port
pytestmark = [pytest.mark.realtime, pytest.mark.xdist_group("xcplite")]

ARCHIVE = Path(__file__).resolve().parents[2] / "shared" / "thirdparty" / "xcplite-917877cf.tar.gz"
MIXED = ["counter", "heat_energy", "inside_temperature", "global_counter", "outside_temperature"]  # any order
CALC = ["*heat_power", "*t2", "*diff_temp", "*t1"]  # calc_power.t1 where registered as instances


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _build(out: Path, *, tcp: bool, variadic: bool = True, example: str = "hello_xcp", cyclic_us: int = 0) -> None:
    """An example from the archive (hello_xcp, c_demo), its #defines set: 127.0.0.1, a free port, TCP
    or UDP, log errors only; without OPTION_USE_VARIADIC_MACROS hello_xcp registers its globals with
    A2lSetAbsoluteAddrMode. With ``cyclic_us`` (and without the variadic macros) its mainloop event
    is declared cyclic with that cycle (XCPlite's own DaqCreateCyclicEvent in place of
    DaqCreateEvent: the one source line besides the #defines)."""
    src = out / "xcplite"
    with tarfile.open(ARCHIVE) as tar:
        tar.extractall(src, filter="data")
    main = src / "examples" / example / "src" / "main.c"
    port = _free_port(socket.SOCK_STREAM if tcp else socket.SOCK_DGRAM)
    text = main.read_text(encoding="utf-8-sig")
    for pattern, value in ((r"#define OPTION_SERVER_ADDR \{0, 0, 0, 0\}", "#define OPTION_SERVER_ADDR {127, 0, 0, 1}"),
                           (r"#define OPTION_USE_TCP false", f"#define OPTION_USE_TCP {'true' if tcp else 'false'}"),
                           (r"#define OPTION_SERVER_PORT 5555", f"#define OPTION_SERVER_PORT {port}"),
                           (r"#define OPTION_LOG_LEVEL 4", "#define OPTION_LOG_LEVEL 1")):
        text, n = re.subn(pattern, value, text)
        assert n == 1, pattern  # the archive is as shipped: each #define is where its README says
    if not variadic:
        text = text.replace("#define OPTION_USE_VARIADIC_MACROS", "// #define OPTION_USE_VARIADIC_MACROS")
    if cyclic_us:
        text, n = re.subn(r"DaqCreateEvent\(mainloop\);", f"DaqCreateCyclicEvent(mainloop, {cyclic_us});", text)
        assert n == 1 and not variadic
    main.write_text(text)
    build = out / "build"
    for cmd in (["cmake", "-S", str(src), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release"],
                ["cmake", "--build", str(build), "--target", example, "-j2"]):
        subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    (out / "url").write_text(f"xcp+{'tcp' if tcp else 'udp'}://127.0.0.1:{port}")


def _started(binary: Path, url: str, run: Path):
    """``binary`` running in ``run`` and the A2L it writes when the first master connects
    (A2L_MODE_FINALIZE_ON_CONNECT); checked to listen on loopback only."""
    for attempt in range(100):
        here = run / f"start{attempt}"  # a folder of its own: nothing an earlier start wrote
        here.mkdir()
        proc = subprocess.Popen([str(binary)], cwd=here, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(0.2)
        # c_demo's main loop asks XcpEthServerStatus() before its transmit thread says it runs, and then
        # stops ("XCP Server failed", exit 0): an XCPlite start-up race (12, 17 and 10 of 20 starts in three
        # counts here), started again; 100 tries leave a 0.85^100 = 9e-8 chance that none starts
        if proc.poll() is None:
            break
    assert proc.poll() is None, f"{binary.name} stopped at each of 100 starts"
    deadline = time.monotonic() + 20
    while True:  # the A2L is named after the project GET_ID answers (it writes parts of it before)
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, f"{binary.name} answered no CONNECT"
        asked = subprocess.run(["ambdaq", "devices", "--ask-xcp", url, "--json"], capture_output=True, text=True,
                               timeout=30)
        if asked.returncode == 0:
            a2l = here / f"{json.loads(asked.stdout)['xcp'][0]['asap2_name']}.a2l"
            if a2l.exists():
                break
        time.sleep(0.2)
    listening = subprocess.run(["ss", "-Htlnup"], capture_output=True, text=True).stdout
    for line in listening.splitlines():  # bound to loopback only (the house rule)
        if f"pid={proc.pid}," in line:
            assert "127.0.0.1:" in line.split()[4], line
    return proc, a2l


def _needs_a_compiler() -> None:
    if shutil.which("cmake") is None or shutil.which("cc") is None:
        pytest.skip("building XCPlite needs cmake and a C compiler")


@pytest.fixture(scope="module", params=[pytest.param((False, True), id="udp"),
                                        pytest.param((True, False), id="tcp-absolute")])
def xcplite(request, build_once, tmp_path_factory):
    """A running hello_xcp (UDP as shipped, or TCP with absolute addressing) and its A2L file."""
    _needs_a_compiler()
    tcp, variadic = request.param
    built = build_once(f"xcplite-{request.param_index}", lambda out: _build(out, tcp=tcp, variadic=variadic))
    url = (built / "url").read_text()
    proc, a2l = _started(built / "build" / "hello_xcp", url, tmp_path_factory.mktemp("xcplite"))
    try:
        yield url, a2l
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _running(build_once, tmp_path_factory, example: str, key: str | None = None, **options):
    """XCPlite's ``example`` built (UDP unless ``options`` say otherwise, see _build) and running,
    with its A2L; stopped afterwards."""
    _needs_a_compiler()
    options.setdefault("tcp", False)
    built = build_once(key or f"xcplite-{example}", lambda out: _build(out, example=example, **options))
    url = (built / "url").read_text()
    proc, a2l = _started(built / "build" / example, url, tmp_path_factory.mktemp(key or example))
    try:
        yield url, a2l
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.fixture(scope="module")
def c_demo(build_once, tmp_path_factory):
    """XCPlite's c_demo on UDP: 8- to 64-bit counters, signed and unsigned, globals and on the stack,
    a typedef instance, a map and a curve in a calibration segment."""
    yield from _running(build_once, tmp_path_factory, "c_demo")


def pyxcp_master(url: str):
    """pyxcp's own master on the same slave: the independent reader of what the slave holds."""
    from pyxcp.config import create_application_from_config, set_application
    from pyxcp.master import Master

    protocol, host_port = url.split("://")
    host, port = host_port.rsplit(":", 1)
    app = create_application_from_config({"Transport": {"Eth": {
        "host": host, "port": int(port), "protocol": protocol.split("+")[1].upper()}}}, log_level=logging.ERROR)
    app.transport.layer = "ETH"
    set_application(app)
    return Master("eth", config=app)


def addresses(a2l: Path) -> dict[str, tuple[int, int]]:
    """ECU_ADDRESS and ECU_ADDRESS_EXTENSION of each MEASUREMENT and CHARACTERISTIC, read off the
    file's text (not through ambdaq's reader)."""
    text = a2l.read_text(encoding="latin-1")
    found = {}
    for m in re.finditer(r"/begin MEASUREMENT (\S+) .*?ECU_ADDRESS (0x[0-9A-Fa-f]+) ECU_ADDRESS_EXTENSION (\d+)", text):
        found[m.group(1)] = (int(m.group(2), 16), int(m.group(3)))
    for m in re.finditer(r"/begin CHARACTERISTIC (\S+) \"[^\"]*\" VALUE (0x[0-9A-Fa-f]+)", text):
        found[m.group(1)] = (int(m.group(2), 16), 0)
    return found


def test_mixed_types_in_any_order_hold_what_the_slave_holds(xcplite, tmp_path, run_cli):
    url, a2l = xcplite
    where = addresses(a2l)
    with pyxcp_master(url) as x:
        x.connect()
        raw = {n: x.shortUpload(size, where[n][0], where[n][1])
               for n, size in (("outside_temperature", 1), ("inside_temperature", 1), ("params.counter_max", 2),
                               ("params.flow_rate", 4), ("global_counter", 4))}
        x.disconnect()
    counter_max = struct.unpack("<H", raw["params.counter_max"])[0]
    flow_rate = struct.unpack("<f", raw["params.flow_rate"])[0]
    before = struct.unpack("<I", raw["global_counter"])[0]
    out = tmp_path / "hello.mcap"
    args = [a for n in MIXED + CALC for a in ("--measure", n)]
    r = run_cli("record", "--device", url, "--a2l", a2l, *args, "--duration", "1.5", "--json", "-o", out)
    assert r.exit_code == 0, r.output
    rec = load(out)
    assert set(rec) == {"/xcp/mainloop", "/xcp/calc_power"}  # one topic per event, named after it
    main, calc = rec["/xcp/mainloop"], rec["/xcp/calc_power"]
    assert list(main.fields) == MIXED and len(main) > 100
    named = {f.removeprefix("calc_power_"): f for f in calc.fields}  # A2L calc_power.t1: field calc_power_t1
    assert list(named) == [n.lstrip("*") for n in CALC]
    # UBYTE with the conversion C = raw - 55: what pyxcp reads, converted
    assert set(main["outside_temperature"]) == {raw["outside_temperature"][0] - 55.0} == {-5.0}
    assert set(main["inside_temperature"]) == {raw["inside_temperature"][0] - 55.0} == {20.0}
    loops = main["global_counter"].astype(np.int64)
    assert loops[0] > before  # a ULONG counted on from what pyxcp read before
    np.testing.assert_array_equal(main["counter"], loops % (counter_max + 1))  # UWORD, same sample
    heat_power = 25.0 * np.float64(flow_rate) * 1000.0 * 1.16  # in double, as calc_power computes it
    # FLOAT64: the running sum of heat_power / 3.6e9 (main sums the float calc_power returns), each
    # sample's own (1e-9: the sum's rounding over some 10^5 loops is ~1e-11 relative; the
    # neighbouring sample is 1e-5 off)
    np.testing.assert_allclose(main["heat_energy"], loops * (float(np.float32(heat_power)) / 3.6e9), rtol=1e-9)
    np.testing.assert_allclose(calc[named["heat_power"]], heat_power, rtol=1e-12)
    assert set(calc[named["diff_temp"]]) == {25.0}
    assert {float(v) for v in calc[named["t2"]]} - {float(v) for v in calc[named["t1"]]}  # two bytes, not one twice
    # time: the DTO timestamps (1 ns), increasing; loss counted from the transport counter
    meta = McapFile(out).metadata()
    stats = meta["ambdaq.link.controller"]
    device = meta["ambdaq.device.controller"]
    assert device["time"] == "DTO timestamp" and device["event_cycle"] == "sporadic"
    assert np.all(np.diff(main.time) > 0)
    missing = int(np.sum(np.diff(loops) - 1))
    lost = int(stats.get("transport_lost_packets", "0"))
    assert missing == 0 or lost > 0, (missing, stats)  # a gap in the loops is a loss the transport saw


def test_controller_param_writes_what_pyxcp_reads_back(xcplite, run_cli):
    url, a2l = xcplite
    where = addresses(a2l)
    for name, value, fmt in (("params.flow_rate", 0.25, "<f"), ("params.counter_max", 512, "<H")):
        r = run_cli("controller", "param", "--device", url, "--a2l", a2l, name, str(value), "--yes")
        assert r.exit_code == 0, r.output
        with pyxcp_master(url) as x:
            x.connect()
            got = struct.unpack(fmt, x.shortUpload(struct.calcsize(fmt), *where[name]))[0]
            x.disconnect()
        assert got == pytest.approx(value, rel=1e-7)  # FLOAT32 holds 0.25 exactly; UWORD 512
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "params.counter_max", "70000", "--yes")
    assert r.exit_code != 0 and "0 .. 65535" in r.output and len(r.output.strip().splitlines()) == 1
    for name, value in (("params.flow_rate", 0.301), ("params.counter_max", 1024)):  # as it was
        assert run_cli("controller", "param", "--device", url, "--a2l", a2l, name, str(value), "--yes").exit_code == 0


def test_a_prescaler_the_slave_lacks_is_refused(xcplite, tmp_path, run_cli):
    url, a2l = xcplite  # XCPlite is built without XCP_ENABLE_DAQ_PRESCALER: GET_DAQ_PROCESSOR_INFO says so
    r = run_cli("record", "--device", f"{url}?prescaler=2", "--a2l", a2l, "--measure", "global_counter",
                "--duration", "1", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "no DAQ prescaler" in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert not (tmp_path / "p.mcap").exists()


def test_devices_lists_its_sporadic_events(xcplite, run_cli):
    url, _a2l = xcplite
    r = run_cli("devices", "--ask-xcp", url, "--json")
    assert r.exit_code == 0, r.output
    (slave,) = json.loads(r.stdout)["xcp"]
    assert slave["asap2_name"] == "hello_xcp_200"
    assert {slave["event_0"], slave["event_1"]} == {"calc_power (sporadic)", "mainloop (sporadic)"}


def test_without_measure_it_says_how_to_choose(xcplite, tmp_path, run_cli):
    url, a2l = xcplite
    r = run_cli("record", "--device", url, "--a2l", a2l, "--duration", "1", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "--measure NAME_OR_GLOB" in r.output and len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "x.mcap").exists()


def test_pages_of_a_calibration_segment(xcplite, run_cli):
    """XCPlite's `params` segment has a working page 0 and a reference page 1 that XCP may not write
    (its A2L): a write goes to the working page, read back and checked with the slave's
    BUILD_CHECKSUM in the segment's XCP_CRC_16_CITT (ambdaq's CRC against XCPlite's); the reference
    page keeps the default that main.c compiled in, as pyxcp reads it there too."""
    url, a2l = xcplite
    where = addresses(a2l)
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l)
    assert r.exit_code == 0 and r.output.split() == ["params.counter_max", "params.delay_us", "params.flow_rate"]
    assert run_cli("controller", "param", "--device", url, "--a2l", a2l, "params.flow_rate", "0.5", "--yes").exit_code == 0
    try:
        for page, value in ((0, "0.5"), (1, "0.301")):
            r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "--page", page, "params.flow_rate")
            assert r.exit_code == 0 and r.output.strip() == f"params.flow_rate = {value} (page {page})", r.output
        with pyxcp_master(url) as x:
            x.connect()
            x.setCalPage(0x02, 1, 1)  # XCP access to the reference page of segment 1
            reference = struct.unpack("<f", x.shortUpload(4, *where["params.flow_rate"]))[0]
            x.setCalPage(0x02, 1, 0)
            x.disconnect()
        assert reference == pytest.approx(0.301, rel=1e-7)
        r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "--page", "1", "params.flow_rate", "0.7",
                    "--yes")
        assert r.exit_code == 1 and "XCP_WRITE_ACCESS_NOT_ALLOWED" in r.output and len(r.output.strip().splitlines()) == 1
        r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "--page", "2", "params.flow_rate")
        assert r.exit_code == 1 and "has pages [0, 1], not 2" in r.output
        # COPY_CAL_PAGE: the reference page over the working page puts the compiled default back
        r = run_cli("controller", "copy-page", "--device", url, "--a2l", a2l, "params.flow_rate", "--from", "1",
                    "--to", "0", "--yes")
        assert r.exit_code == 0 and r.output.strip().endswith("params.flow_rate = 0.301"), r.output
        r = run_cli("controller", "copy-page", "--device", url, "--a2l", a2l, "params.flow_rate", "--from", "0",
                    "--to", "1", "--yes")
        assert r.exit_code == 1 and "XCP_WRITE_ACCESS_NOT_ALLOWED" in r.output
    finally:
        run_cli("controller", "param", "--device", url, "--a2l", a2l, "params.flow_rate", "0.301", "--yes")


@pytest.fixture(scope="module")
def multi_thread(build_once, tmp_path_factory):
    """XCPlite's multi_thread_demo on UDP: eight threads, each with its own sporadic event and
    counter, and FLOAT64 parameters in a calibration segment."""
    yield from _running(build_once, tmp_path_factory, "multi_thread_demo")


def test_eight_events_eight_daq_lists_and_a_double_parameter(multi_thread, tmp_path, run_cli):
    """One DAQ list and topic per thread's event, each counting its own loops without a gap (a
    sample filed under another event would break its run); a FLOAT64 parameter written is what
    pyxcp reads back."""
    url, a2l = multi_thread
    out = tmp_path / "mt.mcap"
    r = run_cli("record", "--device", url, "--a2l", a2l, "--measure", "task_*.counter", "--duration", "1", "-o", out)
    assert r.exit_code == 0, r.output
    rec = load(out)
    assert set(rec) == {f"/xcp/task_{n}" for n in range(1, 9)}
    link = McapFile(out).metadata()["ambdaq.link.controller"]
    for n in range(1, 9):
        counts = rec[f"/xcp/task_{n}"][f"task_{n}_counter"].astype(np.int64)
        assert len(counts) > 100
        steps = np.diff(counts) % 1025  # counter_max 1024, then 0
        assert np.all(steps == 1) or int(link["transport_lost_packets"]) > 0, (n, steps[steps != 1][:5])
    where = addresses(a2l)
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "params.ampl", "12.625", "--yes")
    assert r.exit_code == 0 and r.output.strip() == "params.ampl = 12.625", r.output
    with pyxcp_master(url) as x:
        x.connect()
        held = struct.unpack("<d", x.shortUpload(8, *where["params.ampl"]))[0]
        x.disconnect()
    assert held == 12.625  # FLOAT64, exactly


COUNTERS = ["counter64s", "g_counter8", "counter", "g_counter64", "counter8s", "g_counter16s", "counter32",
            "g_counter32s", "counter16", "g_counter8s", "counter64", "g_counter16", "counter16s", "g_counter32",
            "counter8", "g_counter64s", "counter32s", "g_param_sum", "params_copy.*"]


def test_every_integer_type_and_a_typedef_instance(c_demo, tmp_path, run_cli):
    """c_demo keeps one loop counter c (0 .. counter_max) in 17 variables of 8 to 64 bits, signed and
    unsigned, at extensions 1 (globals) and 2 (its stack), and a copy of its calibration struct (an
    INSTANCE of a TYPEDEF_STRUCTURE): each sample holds c in every one, truncated to its type as C
    truncates (counter8s = (int8_t)(c & 0xFF): negative from 128), and the struct's defaults."""
    url, a2l = c_demo
    out = tmp_path / "c.mcap"
    r = run_cli("record", "--device", url, "--a2l", a2l, *[a for n in COUNTERS for a in ("--measure", n)],
                "--duration", "1.5", "-o", out)
    assert r.exit_code == 0, r.output
    got = load(out)["/xcp/mainloop"]
    c = got["counter"].astype(np.int64)
    assert len(c) > 100 and c.max() > 128  # the 8-bit ones wrap and the signed byte goes negative
    # main.c triggers the event after counting `counter` and before copying it into the others: they
    # hold the loop before's count in the same sample (counter_max 1024 where counter wrapped to 0)
    before = np.where(c > 0, c - 1, 1024)
    for name in ("counter8", "g_counter8"):
        np.testing.assert_array_equal(got[name], before & 0xFF, err_msg=name)
    for name in ("counter8s", "g_counter8s"):
        np.testing.assert_array_equal(got[name], (before & 0xFF).astype(np.uint8).astype(np.int8), err_msg=name)
    for name in ("counter16", "counter32", "counter64", "counter16s", "counter32s", "counter64s", "g_counter16",
                 "g_counter32", "g_counter64", "g_counter16s", "g_counter32s", "g_counter64s"):
        np.testing.assert_array_equal(got[name], before, err_msg=name)
    assert set(got["g_param_sum"]) == {8 + 16 + 32 + 64}  # A_UINT64 g_param8 + ... + g_param64
    # the 64-bit ones are recorded as integers, exact past 2**53 where float64 would round
    assert {n: got[n].dtype.str for n in ("counter64", "counter64s", "g_param_sum")} == {
        "counter64": "<u8", "counter64s": "<i8", "g_param_sum": "<u8"}
    copy = {f: set(got[f]) for f in got.fields if f.startswith("params_copy")}
    assert copy == {"params_copy_test_byte1": {1.0}, "params_copy_test_byte2": {-1.0},
                    "params_copy_counter_max": {1024.0}, "params_copy_delay_us": {1000.0}}


def test_a_map_and_a_curve_read_as_main_c_compiled_them(c_demo, run_cli):
    url, a2l = c_demo
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "params.curve")
    assert r.exit_code == 0 and r.output.strip() == "params.curve = 0 1 2 3 4 3 2 1", r.output
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "params.map")
    rows = np.array([float(v) for v in r.output.split("=")[1].split()]).reshape(8, 8)
    expected = np.zeros((8, 8))
    expected[1:6, 1:6] = 1
    expected[2:5, 2:5] = 3
    np.testing.assert_array_equal(rows, expected)  # int8 map[8][8], row by row as C lays it out
    r = run_cli("controller", "param", "--device", url, "--a2l", a2l, "g_param64")
    assert r.exit_code == 0 and r.output.strip() == "g_param64 = 64"


def test_xcp_list_uploads_the_a2l_the_slave_holds(xcplite, run_cli):
    """GET_ID type 4: XCPlite serves the A2L it wrote; `xcp list --device` reads it as it reads the file."""
    url, a2l = xcplite
    r = run_cli("xcp", "list", "--device", url, "--json")
    assert r.exit_code == 0, r.output
    uploaded = json.loads(r.stdout)
    local = json.loads(run_cli("xcp", "list", a2l, "--json").stdout)
    assert uploaded["file"] == f"{url} (GET_ID)" and uploaded["project"] == local["project"] == "hello_xcp"
    assert uploaded["measurements"] == local["measurements"] and uploaded["events"] == local["events"]
    assert {m["name"] for m in uploaded["measurements"]} >= {"global_counter", "heat_energy", "inside_temperature"}


@pytest.fixture(scope="module")
def cyclic(build_once, tmp_path_factory):
    """hello_xcp (TCP, absolute addressing) whose mainloop event is declared cyclic every 1,000 us:
    its loop sleeps 1,000 us and then works, so it really runs a little slower than it declares."""
    yield from _running(build_once, tmp_path_factory, "hello_xcp", key="xcplite-cyclic", tcp=True, variadic=False,
                        cyclic_us=1000)


def test_a_cyclic_event_records_for_the_wall_time_asked(cyclic, tmp_path, run_cli):
    """The event's declared cycle is listed and kept in the metadata, but --duration is wall time: a
    slave slower than it declares gives fewer samples, not a longer recording; every sample holds
    the loop it was taken in (the counter relation of main.c)."""
    url, a2l = cyclic
    r = run_cli("devices", "--ask-xcp", url, "--json")
    assert r.exit_code == 0, r.output
    (slave,) = json.loads(r.stdout)["xcp"]
    assert "mainloop (every 1000 us)" in {slave["event_0"], slave["event_1"]}
    out = tmp_path / "cyclic.mcap"
    started = time.monotonic()
    r = run_cli("record", "--device", url, "--a2l", a2l, "--measure", "global_counter", "--measure", "counter",
                "--duration", "1", "--json", "-o", out)
    took = time.monotonic() - started
    assert r.exit_code == 0, r.output
    main = load(out)["/xcp/mainloop"]
    device = McapFile(out).metadata()["ambdaq.device.controller"]
    assert device["event_cycle"] == "every 1000 us" and float(device["sample_rate_hz"]) == 1000
    # 1 s of wall time (the recording opens and closes around it: under 4 s in all): the loop's
    # 1,000 us sleep plus its work is slower than declared, so fewer than 1,000 samples; counted in
    # declared periods it would have run until 1,000 arrived
    assert 300 < len(main) < 1000 and took < 4, (len(main), took)
    loops = main["global_counter"].astype(np.int64)
    np.testing.assert_array_equal(main["counter"], loops % 1025)  # counter_max 1024 as shipped
