"""Hostile input (issue 18): documents and options built to break the parsers get one line and
exit 2, before any device is opened, and bounded work."""

from __future__ import annotations

import copy
import json
import os

import pytest

from ambdaq.documents.coefficients import Coefficients
from ambdaq.documents.sealed import seal

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

NOWHERE = "serial:///dev/null"  # a broken file fails before any device is opened


def one_line_exit_2(result, *needles):
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and "Traceback" not in result.output, result.output
    for n in needles:
        assert n in lines[0], lines[0]


@pytest.fixture
def good():
    """A coefficient document as `runout identify` writes it (two harmonics, two axes)."""
    return Coefficients(target={"axes": ["front_x", "front_y"]}, source={"method": "test"}, harmonics=[1, 2],
                        weights={"front_x": [[1e-6, 2e-6], [3e-7, 0.0]], "front_y": [[0.0, 1e-6], [0.0, 0.0]]},
                        lms_schedule=[[1, 0.0, 60000.0, 0.001]]).to_dict()


def sealed(doc: dict) -> str:
    return json.dumps(seal({k: v for k, v in doc.items() if k != "checksum"}))


def edit(doc: dict, change) -> str:
    d = copy.deepcopy(doc)
    change(d)
    return sealed(d)


CASES = {
    # name: (file text from the good document, what the line must name)
    "nested 100,000 deep": (lambda d: '{"a":' * 100_000 + "1" + "}" * 100_000, "JSON nested too deep"),
    "an integer of 5,000 digits": (lambda d: sealed(d).replace('"version": 1', '"version": ' + "9" * 5000),
                                   "not a JSON coefficient file"),
    "an integer of 400 digits": (lambda d: edit(d, lambda x: x["runout"]["weights"]["front_x"][0].__setitem__(0, 10**400)),
                                 "runout.weights.front_x.0.0"),
    "weights a list": (lambda d: edit(d, lambda x: x["runout"].__setitem__("weights", [1, 2])), "runout.weights"),
    "a NaN weight": (lambda d: edit(d, lambda x: x["runout"]["weights"]["front_y"][1].__setitem__(1, float("nan"))),
                     "runout.weights.front_y.1.1"),
    "a schedule not a list": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", 5)), "lms_schedule"),
    "integer schedule rows": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", [1, 2])), "lms_schedule.0"),
    "strings in a row": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", [["a", "b", "c"]])),
                         "lms_schedule.0.0"),
    "a range of 1e300 rpm": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", [[0, 1e300, 0.001]])),
                             "lms_schedule.0.1"),
    "a range of 1e9 rpm": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", [[0, 1e9, 0.001]])),
                           "lms_schedule.0.1"),
    "a range run backwards": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", [[9000, 100, 0.001]])),
                              "rpm_from 9000 is not below rpm_to 100"),
    "a step size above 1": (lambda d: edit(d, lambda x: x.__setitem__("lms_schedule", [[0, 100, 5.0]])),
                            "lms_schedule.0.2"),
    "weights missing a harmonic": (lambda d: edit(d, lambda x: x["runout"]["weights"]["front_x"].pop()),
                                   "front_x has 1 weight pairs for 2 harmonics"),
}


@pytest.mark.parametrize("case", CASES)
def test_a_malformed_coefficient_file_is_one_line_naming_the_key(good, tmp_path, run_cli, case):
    make, needle = CASES[case]
    path = tmp_path / "coef.json"
    path.write_text(make(good))
    one_line_exit_2(run_cli("push", path, "--device", NOWHERE, "--dry-run"), str(path), needle)


def test_the_good_document_loads(good, tmp_path):
    """The cases above differ from a file that loads only in what they break."""
    path = tmp_path / "coef.json"
    path.write_text(sealed(good))
    coef = Coefficients.load(path)
    assert coef.harmonics == [1, 2] and coef.lms_schedule == [[1, 0.0, 60000.0, 0.001]]


def test_a_fifo_is_refused_not_read(tmp_path, run_cli):
    """A FIFO would block the read forever: it is refused for not being a regular file."""
    fifo = tmp_path / "coef.json"
    os.mkfifo(fifo)
    one_line_exit_2(run_cli("push", fifo, "--device", NOWHERE, "--dry-run"), "not a regular file")


def test_an_improper_plant_is_one_line(tmp_path, run_cli):
    one_line_exit_2(run_cli("lms", "schedule", "--plant", "tf:1,0/1", "--mu", "0.001", "-o", tmp_path / "s.json"),
                    "improper")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_a_duration_that_is_not_a_finite_number(tmp_path, run_cli, value):
    r = run_cli("record", "--device", "sim://spindle", "--duration", value, "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "Invalid value for '--duration'" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("url", ["serial:socket://[::1:7001", "serial:rfc2217://[::1:7001", "serial:socket://host:port"])
def test_a_pyserial_url_with_a_malformed_host_or_port_is_bad_input(tmp_path, run_cli, url):
    """pyserial reports these as a port it could not open (exit 1); they are the URL's fault."""
    one_line_exit_2(run_cli("record", "--device", url, "--duration", "0.1", "-o", tmp_path / "x.mcap"),
                    "serial port", url.removeprefix("serial:"))
    assert not (tmp_path / "x.mcap").exists()


def test_a_rig_file_nested_too_deep(tmp_path, run_cli):
    rig = tmp_path / "deep.toml"
    rig.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    one_line_exit_2(run_cli("record", "--rig", rig, "-o", tmp_path / "x.mcap"), "nested too deep")


def test_a_split_recording_whose_first_part_exists_writes_nothing(tmp_path, run_cli):
    first = tmp_path / "run_000.mcap"
    first.write_bytes(b"keep me")
    one_line_exit_2(run_cli("record", "--device", "sim://spindle", "--duration", "2", "--split-duration", "1",
                            "-o", tmp_path / "run.mcap"), "run_000.mcap exists")
    assert first.read_bytes() == b"keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["run_000.mcap"]


@pytest.mark.parametrize("command", [("lms", "map"), ("lms", "schedule", "--mu", "0.001")])
def test_a_plant_whose_numbers_overflow_is_one_line(tmp_path, run_cli, command):
    """Finite coefficients whose loop overflows (1e-300 s^0 over s + 1e300): the convergence map
    cannot be computed, which is the plant's fault, not ambdaq's."""
    out = ("-o", tmp_path / "s.json") if command[1] == "schedule" else ()
    one_line_exit_2(run_cli(*command, "--plant", "tf:1e-300/1,1e300", *out), "cannot be analysed")


def test_frequency_response_and_points_files_name_the_offending_key(tmp_path, run_cli):
    import numpy as np

    from ambdaq.documents.compensator_points import save_points
    from ambdaq.documents.frequency_response import FrequencyResponse

    frf = FrequencyResponse(np.array([10.0, 20.0]), {"front_x": {"source": {}, "outputs": {
        "front_x": (np.array([1 + 1j, 2 - 1j]), np.array([0.9, 0.95]))}}}).to_dict()
    frf["columns"]["front_x"]["outputs"]["front_x"]["coherence"][1] = 2.0  # a coherence above 1
    (tmp_path / "loop.frf.json").write_text(sealed(frf))
    one_line_exit_2(run_cli("lms", "schedule", "--plant", "rig", "--frf", tmp_path / "loop.frf.json",
                            "-o", tmp_path / "s.json"), "columns.front_x.outputs.front_x.coherence.1")
    save_points(tmp_path / "p.json", [10.0, 20.0], np.ones((2, 2, 2, 2), dtype=complex), [[0.1, 0.2]] * 2, {})
    points = json.loads((tmp_path / "p.json").read_text())
    points["planes"]["vertical"]["W12"]["im"] = [0.0]  # one value for two frequencies
    (tmp_path / "p.json").write_text(sealed(points))
    one_line_exit_2(run_cli("fx", "fit", tmp_path / "p.json", "-o", tmp_path / "fir.json"),
                    "planes.vertical.W12 has 2 re and 1 im values for 2 frequencies")


def _plant_files(folder):
    """Plant files (``--plant ss:FILE``) built to hang or exhaust the analysis, with what the
    line must say."""
    import numpy as np

    big = folder / "zeros_3000.npz"  # 72 MB of zeros in 70 KB: eigenproblems of order 3,000 at 600 speeds
    np.savez_compressed(big, M=np.zeros((1, 3000, 3000)), B=np.zeros((1, 3000, 1)), C=np.zeros((1, 1, 3000)),
                        h=np.array(1e-4))
    order = folder / "order_65.npz"
    np.savez(order, A=np.zeros((65, 65)), B=np.zeros((65, 1)), C=np.zeros((1, 65)))
    broken = folder / "broken.npz"
    broken.write_bytes(order.read_bytes()[:300])
    no_b = folder / "no_b.npz"
    np.savez(no_b, M=np.eye(3), C=np.ones((1, 3)), h=np.array(1e-4))
    fifo = folder / "fifo.npz"
    os.mkfifo(fifo)
    return {big: "9,006,001 values; a plant file holds at most", order: "a plant of order 65; at most 64",
            broken: "File is not a zip file", no_b: "B is missing", fifo: "not a regular file"}


def test_plant_files_that_would_hang_or_exhaust_memory_are_one_line(tmp_path):
    """In a process of its own with a time limit: before the bounds, the first file read 72 MB
    and began 600 eigenproblems of order 3,000 (hours), the FIFO blocked forever."""
    import subprocess
    import sys

    files = _plant_files(tmp_path)
    script = ("import json, sys\nfrom click.testing import CliRunner\nfrom ambdaq.cli.main import cli\n"
              "for path in sys.argv[1:]:\n"
              "    r = CliRunner().invoke(cli, ['lms', 'map', '--plant', 'ss:' + path])\n"
              "    print(json.dumps([path, r.exit_code, r.output]), flush=True)\n")
    r = subprocess.run([sys.executable, "-c", script, *map(str, files)], capture_output=True, text=True, timeout=120)
    results = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(results) == len(files), r.stderr
    for (path, needle), (_, code, output) in zip(files.items(), results):
        lines = output.strip().splitlines()
        assert code == 2 and len(lines) == 1 and needle in lines[0], (path.name, output)
