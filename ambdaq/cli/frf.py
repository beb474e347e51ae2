"""``ambdaq frf``: measure the loop's frequency response with the controller's excitation input."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from ..analysis.frf import COHERENT, coherent_band, h1_estimate
from ..daq.coefficients import file_sha256
from ..daq.frequency_response import FrequencyResponse
from ..daq.mcapfile import McapFile
from ..daq.reader import ambdaq_channels, load
from ..drivers.devices import open_devices
from ..drivers.rig.spindle import AXES, SPINDLE
from ..errors import BadInputError, DeviceError
from .options import excitation_option, output_options, report_options, speed_option
from .record import run_recording
from .figures import plot_option, pyplot

RPM_PER_RAD_S = 60.0 / (2 * np.pi)
EXCITATION_PARAM = "exc.signal"  # [axis (-1 off), amplitude m, frequency Hz]; docs/protocol.md


@click.group("frf")
def command() -> None:
    """Frequency responses: excite the loop, record, estimate H1 with coherence."""


@command.command("measure")
@click.option("--device", required=True, metavar="URL", help="The AMB controller (or sim://spindle).")
@excitation_option
@click.option("--duration", type=click.FloatRange(min=1), default=20.0, show_default=True, metavar="SECONDS")
@speed_option
@output_options
@report_options
def measure(device, excitation, duration, speed, out, quiet, as_json):
    """Record with the controller's test signal on (one axis), then switch it off.

    \b
    Example:
      ambdaq frf measure --device serial:///dev/pts/5 --excite front_x:2 --duration 20 -o frf_fx.mcap
      ambdaq frf estimate frf_fx.mcap -o loop.frf.json
    """
    if excitation is None:
        raise BadInputError("frf measure needs --excite AXIS:UM[:HZ] (e.g. front_x:2 for 2 um RMS white noise)")
    sources = open_devices(device, speed=speed)
    try:
        i = next((i for i, s in enumerate(sources) if hasattr(s, "write_param")), None)
        if i is None:
            raise BadInputError(f"{device}: no AMB controller there to excite (frf measure needs its {EXCITATION_PARAM})")
        try:
            exc = excitation.resolve(AXES, True, SPINDLE.sample_rate)
        except ValueError as err:
            raise BadInputError(str(err)) from None
        sources[i].write_param(EXCITATION_PARAM, [exc.axis, exc.amplitude, exc.freq_hz])
        sources[i] = _Excited(sources[i])
    except BaseException:
        for s in sources:
            s.close()
        raise
    run_recording(sources, out, duration=duration, quiet=quiet, as_json=as_json)


class _Excited:
    """A controller whose test signal is switched off when the recorder closes it, however the
    recording ends (duration, Ctrl-C, a failure)."""

    def __init__(self, controller) -> None:
        self._controller = controller

    def __getattr__(self, name):
        return getattr(self._controller, name)

    def close(self) -> None:
        try:
            self._controller.write_param(EXCITATION_PARAM, [-1.0, 0.0, 0.0])
        except DeviceError as err:  # the recording is kept; say the signal may still be on
            click.echo(f"ambdaq: warning: could not switch the excitation off: {err}", err=True)
        finally:
            self._controller.close()


def _excited_axis(ff, path: Path, given: str | None) -> str:
    """The input axis: ``given``, or the one axis whose feedforward input is not zero."""
    if given:
        if given not in ff.fields:
            raise BadInputError(f"--input {given!r}: {path} has {', '.join(ff.fields)}")
        return given
    live = [a for a in ff.fields if np.any(ff[a] != 0.0)]
    if len(live) != 1:
        raise BadInputError(f"{path}: {len(live)} axes carry a feedforward input ({', '.join(live) or 'none'}); "
                            "name the excited one with --input AXIS")
    return live[0]


def estimate_responses(paths: list[Path], resolution_hz: float, input_axis: str | None,
                       input_topic: str = "/amb/ff", output_topic: str = "/amb/error") -> FrequencyResponse:
    """H1 and coherence from each recording's excited axis to every output axis (one column per file)."""
    freq, columns = None, {}
    for path in paths:
        spinning = "/amb/rotor" in ambdaq_channels(McapFile(path))  # base-motion rigs have no rotor topic
        rec = load(path, topics=[input_topic, output_topic] + (["/amb/rotor"] if spinning else []))
        x_data, y_data = rec[input_topic], rec[output_topic]
        n = min(len(x_data), len(y_data))
        axis = _excited_axis(x_data, path, input_axis)
        x_unit, y_unit = x_data.units[axis], next(iter(y_data.units.values()))
        if axis in columns:
            raise BadInputError(f"{path}: {axis} was already measured in {columns[axis]['source']['path']}")
        outputs = list(y_data.fields)
        try:
            est = h1_estimate(x_data[axis][:n], np.stack([y_data[a][:n] for a in outputs], axis=1),
                              fs=rec[input_topic].nominal_rate, resolution_hz=resolution_hz)
        except ValueError as err:
            raise BadInputError(f"{path}: {err}") from None
        if not np.all(np.isfinite(est.response)):
            raise BadInputError(f"{path}: the input {axis} carries nothing at some frequencies (a sine, not noise?)")
        if freq is not None and not np.array_equal(freq, est.freq_hz):
            raise BadInputError(f"{path}: sample rate differs from the other recordings'")
        freq = est.freq_hz
        rpm = float(np.median(rec["/amb/rotor"]["speed"])) * RPM_PER_RAD_S if spinning else 0.0
        columns[axis] = {
            "source": {"path": str(path), "sha256": file_sha256(path), "speed_rpm": round(rpm, 1),
                       "segments": est.segments},
            "outputs": {a: (est.response[:, i], est.coherence[:, i]) for i, a in enumerate(outputs)},
        }
    return FrequencyResponse(freq, columns, input_topic, output_topic, f"{y_unit}/{x_unit}")


@command.command("estimate")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Frequency-response file (JSON).")
@click.option("--resolution", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Frequency step, Hz (10 matches the LMS phase table).")
@click.option("--input", "input_axis", help="The excited axis; default: the one axis whose input is not zero.")
@click.option("--input-topic", default="/amb/ff", show_default=True, help="Where the test signal is recorded.")
@click.option("--output-topic", default="/amb/error", show_default=True,
              help="The response: /amb/error (the LMS loop), /amb/gap (base-motion secondary path).")
@click.option("--overwrite", is_flag=True)
@plot_option("Bode plot and coherence (.png, .pdf, .svg).")
@click.option("--json", "as_json", is_flag=True, help="Print a summary as JSON.")
def estimate(files, output, resolution, input_axis, input_topic, output_topic, overwrite, plot_path, as_json):
    """H1 frequency response with coherence, from each recording's excited axis to every axis.

    The input is the feedforward input /amb/ff (where the controller adds its test signal), the
    output the command error /amb/error: T_aa on the diagonal is what the phase-compensated LMS
    needs (ambdaq lms schedule --frf).

    \b
    Example:
      ambdaq frf estimate frf_fx.mcap frf_fy.mcap frf_rx.mcap frf_ry.mcap frf_ax.mcap -o loop.frf.json
    """
    frf = estimate_responses([Path(f) for f in files], resolution, input_axis, input_topic, output_topic)
    frf.save(output, overwrite=overwrite)
    summary = {}
    for axis, col in frf.columns.items():
        h, c = col["outputs"][axis]
        band = coherent_band(frf.freq_hz, c)
        inside = np.zeros(c.shape, dtype=bool) if band is None else (frf.freq_hz >= band[0]) & (frf.freq_hz <= band[1])
        peak = int(np.argmax(np.where(inside, np.abs(h), -np.inf))) if band is not None else int(np.argmax(np.abs(h)))
        summary[axis] = {"points": int(h.shape[0]), "coherent_band_hz": list(band) if band else None,
                         "median_coherence_in_band": round(float(np.median(c[inside])), 4) if band else None,
                         "median_coherence": round(float(np.median(c)), 4),
                         "peak_gain": float(f"{np.abs(h[peak]):.4g}"), "peak_hz": float(frf.freq_hz[peak]),
                         "source": col["source"]["path"]}
    if plot_path:
        _bode(frf, plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        span = f"{frf.freq_hz[0]:g}-{frf.freq_hz[-1]:,.0f} Hz"
        for axis, s in summary.items():
            if s["coherent_band_hz"] is None:
                click.echo(f"{axis}: {s['points']} points, coherence never reaches {COHERENT:g} (median "
                           f"{s['median_coherence']:.3f} over {span}): the input explains too little of the output "
                           f"({s['source']})")
                continue
            lo, hi = s["coherent_band_hz"]
            click.echo(f"{axis}: {s['points']} points, coherence >= {COHERENT:g} from {lo:g} to {hi:,.0f} Hz (median "
                       f"{s['median_coherence_in_band']:.3f} there, {s['median_coherence']:.3f} over {span}); peak |H| "
                       f"there {s['peak_gain']:.3g} {frf.unit} at {s['peak_hz']:g} Hz  ({s['source']})")
        click.echo(f"-> {output}", err=True)


def _bode(frf: FrequencyResponse, path: str) -> None:
    plt = pyplot()

    fig, (mag, ph, coh) = plt.subplots(3, 1, figsize=(9, 9), sharex=True, constrained_layout=True)
    for axis, col in frf.columns.items():
        h, c = col["outputs"][axis]
        trusted = c >= COHERENT
        db = 20 * np.log10(np.abs(h))
        line = mag.semilogx(frf.freq_hz, np.where(trusted, db, np.nan), lw=0.8, label=f"{axis} -> {axis}")[0]
        mag.semilogx(frf.freq_hz, np.where(trusted, np.nan, db), lw=0.5, alpha=0.3, color=line.get_color())
        # phase only where the input explains the output, unwrapped there (noise wraps at random)
        ph.semilogx(frf.freq_hz[trusted], np.degrees(np.unwrap(np.angle(h[trusted]))), ".", ms=1.5,
                    color=line.get_color())
        coh.semilogx(frf.freq_hz, c, lw=0.8, color=line.get_color())
    coh.axhline(COHERENT, color="grey", lw=0.6, ls="--")
    mag.set(ylabel="|T| [dB]", title=f"{frf.output_topic} per {frf.input_topic} (H1; faint: coherence < {COHERENT:g})")
    ph.set(ylabel="phase [deg], unwrapped")
    coh.set(ylabel="coherence", xlabel="frequency [Hz]", ylim=(0, 1.05))
    for ax in (mag, ph, coh):
        ax.grid(alpha=0.3, which="both")
    mag.legend(fontsize=7)
    fig.savefig(path, dpi=100)
    plt.close(fig)
