"""Frequency responses with the controller's test-signal input (the sensitivity measurement of
ISO 14839-3): switch the signal on for a recording, and estimate H1 with coherence from
recordings.  Works with any controller that reports the input (its ExcitationSpec): its axes,
unit, limits and rate are the device's own."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass

import numpy as np

from ..analysis.frf import COHERENT, H1Estimate, coherent_band, h1_estimate
from ..documents.coefficients import file_sha256
from ..documents.frequency_response import FrequencyResponse
from ..daq.quality import MAX_LOST, require_complete
from ..daq.recording import Recording, same_instants
from ..drivers.excitation import OFF, TEST_SIGNAL_RECORD, Excitation, ExcitationRequest
from ..drivers.interfaces import Controller, Source
from ..drivers.registry import Opened, open_url
from ..errors import BadInputError, DeviceError
from ..roles import ERROR, FF
from ..units import RAD_S_TO_RPM
from .speed_restore import speed_restored


@dataclass
class Excited:
    """A controller whose test signal is on until it is closed.

    Attributes
    ----------
    controller : Controller
        The device.
    excitation : Excitation
        What runs, in the device's units.
    switch_off_problem : str or None
        Set if the signal could not be switched off at the end (the recording is kept).
    """

    controller: Controller
    excitation: Excitation
    switch_off_problem: str | None = None

    def records(self) -> dict[str, dict[str, str]]:
        """The metadata the recording made while it runs carries (:data:`TEST_SIGNAL_RECORD`)."""
        spec = self.controller.capabilities.excitation
        return {TEST_SIGNAL_RECORD: self.excitation.record(self.controller.name, spec)}


def excite(sources: list[Source], request: ExcitationRequest) -> Excited:
    """Switch the test signal on at the first of ``sources`` that reports a test-signal input,
    checked against what it reports; it is switched off when that device is closed, before it
    is released, however the recording ends (its duration, Ctrl-C, a failure).

    Parameters
    ----------
    sources : list of Source
        Opened devices (a whole simulated rig, or hardware).
    request : ExcitationRequest
        Axis, amplitude (um for a displacement input, else the input's unit), frequency (Hz).
    """
    controller = next((s for s in sources if isinstance(s, Controller) and s.capabilities.excitation), None)
    if controller is None:
        raise BadInputError("no device here reports a test-signal input (frf measure needs an AMB controller with one)")
    spec = controller.capabilities.excitation
    try:
        excitation = request.resolve(spec)
    except ValueError as err:
        raise BadInputError(str(err)) from None
    controller.write_param(spec.parameter, excitation.values())
    state = Excited(controller, excitation)

    def switch_off(device: Controller) -> None:
        try:
            device.write_param(spec.parameter, list(OFF))
        except DeviceError as err:  # the recording is kept; the caller says the signal may still be on
            state.switch_off_problem = str(err)

    controller.before_close(switch_off)
    return state


@contextmanager
def excited_device(device: str, request: ExcitationRequest, *, speed: str | None = None,
                   description: dict | None = None, on_restore=None) -> Iterator[tuple[list[Source], Excited]]:
    """``device`` opened with its test signal on, for the caller to record (``frf measure`` with its
    terminal status; from Python a :class:`~ambdaq.acquisition.recorder.Recorder`): the signal switched off and the device closed when the block ends, however
    it ends; with ``speed``, the speed it had set again after (``on_restore`` is told).

    Parameters
    ----------
    device : str
        The controller's URL (``sim://spindle``, ``serial:///dev/ttyACM0`` ...).
    request : ExcitationRequest
        Axis, amplitude and frequency of the test signal, checked against what the device reports.
    speed : str, optional
        A speed to set first (``--rpm``).
    description : dict, optional
        What the device's back-end reads beyond its URL (an XCP controller's A2L).

    Yields
    ------
    sources : list of Source
        The opened devices, to record; a recording of them carries ``excited.records()``.
    excited : Excited
        What runs; its ``switch_off_problem`` says, after the block, if the signal could not be
        switched off.
    """
    with speed_restored(device, description, on_restore) if speed else nullcontext():
        with Opened() as opened:
            opened.add(open_url(device, speed=speed, description=description))
            yield opened.sources, excite(opened.sources, request)


def excited_axis(rec: Recording, ff, given: str | None) -> str:
    """The input axis: what the recording's :data:`TEST_SIGNAL_RECORD` says the workflow excited
    (``given`` must agree), else ``given``, else, in a recording without it (another tool's, an
    older ambdaq's), the one axis whose feedforward input is not zero for at least a tenth of it."""
    path = rec.path
    said = rec.metadata.get(TEST_SIGNAL_RECORD, {}).get("axis")
    if said is not None:
        if said not in ff.fields:
            raise BadInputError(f"{path}: its test signal ran on {said}, an axis {ff.topic} does not have "
                                f"({', '.join(ff.fields)})")
        if given and given != said:
            raise BadInputError(f"--input {given}: {path} was recorded with the test signal on {said}")
        return said
    if given:
        if given not in ff.fields:
            raise BadInputError(f"--input {given!r}: {path} has {', '.join(ff.fields)}")
        return given
    # an axis whose input runs for a moment only (a test signal still on for the first block of a
    # new stream, before the controller switched it off) is not the excited one
    live = [a for a in ff.fields if np.count_nonzero(ff[a]) >= 0.1 * len(ff)]
    if len(live) != 1:
        raise BadInputError(f"{path}: {len(live)} axes carry a feedforward input ({', '.join(live) or 'none'}); "
                            "name the excited one with --input AXIS")
    return live[0]


@dataclass(frozen=True)
class ExcitedRun:
    """One excited recording's H1 from its test signal to the fields of some topics.

    Attributes
    ----------
    axis : str
        The excited axis.
    outputs : list of (str, str)
        (the role or topic as asked, field) of each output, in the estimate's order.
    estimate : H1Estimate
        Responses (output unit per input unit), coherences and the covariance of their errors.
    unit : str
        The first output's unit per the input's.
    source : dict
        path, sha256, speed_rpm (the key-phasor's median; 0 without a rotor) and segments.
    """

    axis: str
    outputs: list[tuple[str, str]]
    estimate: H1Estimate
    unit: str
    source: dict


def estimate_run(rec: Recording, resolution_hz: float, input_axis: str | None, input_topic: str,
                 output_topics: list[str], max_lost: float = MAX_LOST) -> ExcitedRun:
    """H1 from ``rec``'s excited axis to every field of ``output_topics`` (roles or topics,
    :meth:`~ambdaq.daq.recording.Recording.signals`), all on the instants of the test signal, in
    one estimate so that the covariance of their errors holds across topics.  A recording that lost
    more than ``max_lost`` of its samples (a share, 0..1) is refused: a hole is a jump inside a
    Welch segment; ``resolution_hz`` in Hz."""
    path = rec.path
    spinning = rec.has_role("rotor")  # base-motion rigs have no rotor topic
    x_data, *y_topics = same_instants(
        [rec.signals(input_topic), *(rec.signals(t) for t in output_topics),
         *([rec.role("rotor")] if spinning else [])],
        ["input", *output_topics, *(["rotor"] if spinning else [])], path)
    rot = y_topics.pop() if spinning else None
    require_complete(rec, [d.topic for d in (x_data, *y_topics)] + ([rot.topic] if spinning else []),
                     "the frequency response", max_lost)
    n = len(x_data)
    axis = excited_axis(rec, x_data, input_axis)
    outputs = [(name, a) for name, d in zip(output_topics, y_topics) for a in d.fields]
    try:
        est = h1_estimate(x_data[axis][:n], np.stack([d[a][:n] for d in y_topics for a in d.fields], axis=1),
                          fs=x_data.nominal_rate, resolution_hz=resolution_hz)
    except ValueError as err:
        raise BadInputError(f"{path}: {err}") from None
    if not np.all(np.isfinite(est.response)):
        raise BadInputError(f"{path}: the input {axis} carries nothing at some frequencies (a sine, not noise?)")
    rpm = float(np.median(rot["speed"])) * RAD_S_TO_RPM if spinning else 0.0
    source = {"path": str(path), "sha256": file_sha256(path), "speed_rpm": round(rpm, 1), "segments": est.segments}
    return ExcitedRun(axis, outputs, est, f"{next(iter(y_topics[0].units.values()))}/{x_data.units[axis]}", source)


def check_runs(runs: list[ExcitedRun]) -> None:
    """BadInputError unless the runs excited different axes on one frequency grid (one column each
    of one response matrix)."""
    for j, run in enumerate(runs):
        earlier = next((r for r in runs[:j] if r.axis == run.axis), None)
        if earlier is not None:
            raise BadInputError(f"{run.source['path']}: {run.axis} was already measured in {earlier.source['path']}")
        if not np.array_equal(run.estimate.freq_hz, runs[0].estimate.freq_hz):
            raise BadInputError(f"{run.source['path']}: sample rate differs from the other recordings'")


def estimate_responses(recs: list[Recording], resolution_hz: float, input_axis: str | None,
                       input_topic: str = FF, output_topic: str = ERROR,
                       max_lost: float = MAX_LOST) -> FrequencyResponse:
    """H1 and coherence from each recording's excited axis to every output axis (one column per
    file, :func:`estimate_run`)."""
    runs: list[ExcitedRun] = []
    for rec in recs:  # each checked against those before it as it comes: refused before the next is read
        runs.append(estimate_run(rec, resolution_hz, input_axis, input_topic, [output_topic], max_lost))
        check_runs(runs)
    columns = {run.axis: {"source": run.source,
                          "outputs": {a: (run.estimate.response[:, i], run.estimate.coherence[:, i])
                                      for i, (_, a) in enumerate(run.outputs)}} for run in runs}
    freq, unit = (runs[-1].estimate.freq_hz, runs[-1].unit) if runs else (None, "")
    return FrequencyResponse(freq, columns, input_topic, output_topic, unit)


def summarize(frf: FrequencyResponse) -> dict:
    """Per excited axis: the coherent band (coherence >= COHERENT), the median coherence there and
    over the whole axis, the peak |H| inside the band (docs/frf.md)."""
    out = {}
    for axis, col in frf.columns.items():
        h, c = col["outputs"][axis]
        band = coherent_band(frf.freq_hz, c)
        inside = np.zeros(c.shape, dtype=bool) if band is None else (frf.freq_hz >= band[0]) & (frf.freq_hz <= band[1])
        peak = int(np.argmax(np.where(inside, np.abs(h), -np.inf))) if band is not None else int(np.argmax(np.abs(h)))
        out[axis] = {"points": int(h.shape[0]), "coherent_band_hz": list(band) if band else None,
                     "median_coherence_in_band": round(float(np.median(c[inside])), 4) if band else None,
                     "median_coherence": round(float(np.median(c)), 4),
                     "peak_gain": float(f"{np.abs(h[peak]):.4g}"), "peak_hz": float(frf.freq_hz[peak]),
                     "source": col["source"]["path"]}
    return out


__all__ = ["COHERENT", "Excited", "ExcitedRun", "check_runs", "estimate_responses", "estimate_run", "excite",
           "excited_axis", "excited_device", "summarize"]
