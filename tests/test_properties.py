"""Property-based tests (hypothesis) of every parser and decoder of outside input (issue 18 item 4):
whatever the input, it ends in a value or one of ambdaq's documented errors (exit 2 for bad
input), within a time bound, and leaves no file half-written.

Each property runs a few dozen examples in the default suite (seconds) and, marked ``soak``
(``pytest -m soak tests/test_properties.py``), thousands.  The deadline is a hang detector, not
a speed target: a parse of these small inputs takes milliseconds, a hang takes forever.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ambdaq.documents.coefficients import Coefficients
from ambdaq.documents.compensator_points import load_points, save_points
from ambdaq.documents.frequency_response import FrequencyResponse
from ambdaq.acquisition.recover import recover
from ambdaq.documents.sealed import seal
from ambdaq.drivers.rigfile import load_rig
from ambdaq.drivers.serial.framing import FrameDecoder, encode_frame
from ambdaq.errors import BadInputError

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

QUICK = settings(max_examples=40, deadline=5000, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                     HealthCheck.too_slow])
SOAK = settings(max_examples=3000, deadline=5000, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])
PROFILES = [pytest.param(QUICK, id="quick"), pytest.param(SOAK, id="soak", marks=pytest.mark.soak)]

# any JSON value, with the numbers that break parsers: huge integers, NaN, infinities
JSON = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(10**400), max_value=10**400)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
    max_leaves=30)


def _paths(doc, prefix=()):
    """Every path into a JSON document (lists and dicts)."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


def mutated(draw, doc: dict) -> dict:
    """``doc`` with one subtree (not format or version) replaced by any JSON value."""
    paths = [p for p in _paths(doc) if p and p[0] not in ("format", "version", "checksum")]
    path = draw(st.sampled_from(paths))
    out = json.loads(json.dumps(doc))
    node = out
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = draw(JSON)
    return out


def documents():
    """A valid coefficient, frequency-response and points document, as ambdaq writes them."""
    coef = Coefficients(target={"axes": ["front_x", "front_y"]}, source={"method": "test"}, harmonics=[1, 2],
                        weights={"front_x": [[1e-6, 2e-6], [3e-7, 0.0]], "front_y": [[0.0, 1e-6], [0.0, 0.0]]},
                        lms_schedule=[[1, 100.0, 60000.0, 0.001]],
                        lms_phase={"bin_hz": 10.0, "phase_rad": {"front_x": [0.1, 0.2]}}).to_dict()
    f = np.array([10.0, 20.0])
    frf = FrequencyResponse(f, {"front_x": {"source": {"file": "a.mcap"},
                                           "outputs": {"front_x": (np.array([1 + 1j, 2 - 1j]), np.array([0.9, 0.95]))}}})
    from ambdaq.analysis.closed_loop import ClosedLoopPlant
    from ambdaq.analysis.plant_model import ModalPlant, PlantFit
    from ambdaq.workflows.plant_fit import FittedPlant, load_model
    from ambdaq.workflows.plant_identification import PlantMeasurement, load_measurement

    one = np.ones((2, 1, 1))
    plant = PlantMeasurement(["front_x"], ClosedLoopPlant(f, one * (1e-4 + 1e-5j), np.ones((2, 1, 1, 1, 1)) * 1e-12,
                                                          one * 0.95, one * (3e4 - 1e3j)),
                             np.ones((2, 1), complex), np.ones((2, 1)) * 0.9, 0.0, [{"path": "a.mcap"}], {})
    model = ModalPlant(np.array([300.0]), np.array([[2500.0, 0.005]]), np.array([[30.0, 10.0]]), (15000.0, 0.8), 0.0, 1e-4)
    values = np.array([47.7, 397.9, 0.005, 2387.3, 0.8, 0.0, 30.0, 10.0])
    names = ["rigid1_hz", "mode1_hz", "mode1_zeta", "amplifier_hz", "amplifier_zeta", "delay_s", "front_x.rigid1_residue",
             "front_x.mode1_residue"]
    fitted = FittedPlant(PlantFit(model, ["front_x"], names, values, np.eye(8) * 1e-6, 0.7, 40), 0.0, 1e-4)

    def model_doc():
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            fitted.save(Path(tmp) / "m.json")
            return json.loads((Path(tmp) / "m.json").read_text())

    return {"coefficient": (coef, Coefficients.load), "frequency-response": (frf.to_dict(), FrequencyResponse.load),
            "plant": (plant.to_document(), load_measurement), "plant-model": (model_doc(), load_model)}


def _influence(tmp: Path):
    """A saved influence file (balance influence -o) and what reads it: the next job's correction,
    as balance correct prints it."""
    from ambdaq.machines.balance_masses import BalanceMass
    from ambdaq.workflows.balancing import RunVector, correct_with, influence_balancing, save_influence

    axes, c = ["front_x", "front_y"], np.array([1e-6 + 2e-6j, -2e-6 + 1e-6j])
    noise = np.array([1e-8, 1e-8])

    def run(name, shift):
        return RunVector(name, 20000.0, axes, c + shift, noise, 4.4, noise)

    masses = [BalanceMass("front", 0.1, 0.0, 0.03), BalanceMass("rear", 0.1, 90.0, 0.03)]
    result = influence_balancing([(run("r", 0), [(masses[0], run("a", np.array([3e-6, 3e-6j]))),
                                                 (masses[1], run("b", np.array([1e-6j, 2e-6])))])], max_rpm=60000.0)
    for name in ("r", "a", "b"):
        (tmp / name).write_bytes(name.encode())
    save_influence(result, tmp / "i.json", [tmp / "r", tmp / "a", tmp / "b"])
    return json.loads((tmp / "i.json").read_text()), lambda path: correct_with(path, [run("r", 0)]).as_dict()


def _points_doc(tmp: Path) -> dict:
    W = np.ones((2, 2, 2, 2), dtype=complex)
    save_points(tmp / "p.json", [10.0, 20.0], W, [[0.1, 0.2], [0.1, 0.2]], {"campaign": "x"})
    return json.loads((tmp / "p.json").read_text())


@pytest.mark.parametrize("profile", PROFILES)
@pytest.mark.parametrize("kind", ["coefficient", "frequency-response", "points", "plant", "plant-model", "influence"])
def test_a_sealed_document_with_any_value_anywhere_loads_or_is_bad_input(tmp_path, kind, profile):
    if kind == "points":
        doc, load = _points_doc(tmp_path), load_points
    elif kind == "influence":
        doc, load = _influence(tmp_path)
    else:
        doc, load = documents()[kind]

    @profile
    @given(st.data())
    def check(data):
        broken = mutated(data.draw, doc)
        path = tmp_path / "doc.json"
        path.write_text(json.dumps(seal({k: v for k, v in broken.items() if k != "checksum"})))
        try:
            load(path)
        except BadInputError:
            pass

    check()


@pytest.mark.parametrize("profile", PROFILES)
def test_a_bank_image_with_any_bytes_changed_decodes_or_is_refused(profile):
    """A coefficient bank image (with the flexible controller's section: PID and biquads) with
    bytes changed, cut or appended decodes to an image that encodes back to the same bytes, or is
    refused with ValueError: the controller's decode never takes half an image."""
    from ambdaq.drivers.coefbank import BankImage

    good = BankImage(np.zeros((4, 0, 2)), "off", pid=np.tile([1.4, 2.0, 0.0012], (4, 1)),
                     biquads=np.tile([1.0, 0.0, 0.0, 0.0, 0.0], (4, 2, 1))).encode()

    @profile
    @given(st.lists(st.tuples(st.integers(0, len(good) - 1), st.integers(0, 255)), max_size=4),
           st.integers(0, len(good)), st.binary(max_size=16))
    def check(changes, cut, tail):
        data = bytearray(good)
        for at, value in changes:
            data[at] = value
        data = bytes(data[:cut]) + tail
        try:
            image = BankImage.decode(data)
        except ValueError:
            return
        assert image.encode() == data

    check()


RIG = '''name = "bench"

[[device]]
name = "controller"
url = "serial:///dev/ttyUSB0"
unlock_key = "k"

[device.calibration]
gap_sensor_gain_v_per_m = "10000"
'''


@pytest.mark.parametrize("profile", PROFILES)
def test_a_rig_file_with_any_edit_loads_or_is_bad_input(tmp_path, profile):
    @profile
    @given(st.integers(0, len(RIG)), st.integers(0, 20), st.text(max_size=30))
    def check(at, cut, insert):
        path = tmp_path / "rig.toml"
        path.write_text(RIG[:at] + insert + RIG[at + cut:])
        try:
            load_rig(path)
        except BadInputError:
            pass

    check()


@pytest.mark.parametrize("profile", PROFILES)
def test_the_serial_decoder_takes_any_bytes_and_keeps_the_good_frames(profile):
    @profile
    @given(st.binary(max_size=500), st.lists(st.binary(min_size=1, max_size=60), max_size=5), st.binary(max_size=200))
    def check(noise, bodies, tail):
        dec = FrameDecoder()
        out = dec.feed(noise)  # garbage: counted, never an exception
        # a zero byte ends whatever the noise left open; every frame after it comes back whole
        out = dec.feed(b"\x00" + b"".join(encode_frame(b) for b in bodies))
        assert out == bodies
        dec.feed(tail)

    check()


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory):
    from ambdaq.acquisition.recorder import Recorder, RecordOptions
    from ambdaq.sim.source import SimSource
    from ambdaq.speed import SpeedProfile

    path = tmp_path_factory.mktemp("prop") / "run.mcap"
    Recorder([SimSource("spindle", seed=5, speed=SpeedProfile(30000, 30000), block_s=0.01)], path,
             RecordOptions(duration_s=0.05, chunk_size=8 * 1024, fsync=False)).run()
    return path.read_bytes()


@pytest.mark.parametrize("profile", PROFILES)
def test_reading_and_recovering_a_damaged_file_ends_in_data_or_bad_input(small_recording, tmp_path, profile):
    from ambdaq.daq import load
    from ambdaq.mcap.mcapfile import McapFile

    data = small_recording

    @profile
    @given(st.lists(st.tuples(st.integers(0, len(data) - 1), st.integers(1, 255)), max_size=4),
           st.integers(0, len(data)))
    def check(flips, keep):
        damaged = bytearray(data[:keep])
        for at, x in flips:
            if at < len(damaged):
                damaged[at] ^= x
        bad, fixed = tmp_path / "bad.mcap", tmp_path / "fixed.mcap"
        bad.write_bytes(damaged)
        try:
            load(bad)
        except BadInputError:
            pass
        try:
            report = recover(bad, fixed, overwrite=True)
        except BadInputError:
            assert not fixed.with_name(fixed.name + ".part").exists()
            return
        assert not fixed.with_name(fixed.name + ".part").exists()  # finished, or nothing
        McapFile(fixed)  # a complete, indexed file
        assert report.messages >= 0

    check()
