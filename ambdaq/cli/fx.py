"""``ambdaq fx``: base-motion compensators (seed 002): stepped-sine campaign, MFXLMS, FIR fit."""

from __future__ import annotations

import json
import time
from contextlib import ExitStack
from pathlib import Path

import click
import numpy as np

from ..analysis.mfxlms import fit_fir, knee, mfxlms, run_beta, separate
from ..analysis.runout import harmonic_fit
from ..daq.coefficients import Coefficients, file_sha256, now_iso
from ..daq.frequency_response import FrequencyResponse
from ..daq.reader import load
from ..daq.sealed import read_sealed, write_sealed
from ..drivers.devices import open_device
from ..drivers.rig.base_motion import AXES, BASE_AXES, BASE_MOTION, PLANES, BaseExcitation, BaseMotionRig
from ..drivers.shaker import Shaker, drive_problem
from ..drivers.sim import sim_options
from ..drivers.simdev.serve import serve_serial
from ..drivers.simdev.shaker import SHAKER_GAIN
from ..drivers.url import parse_device_url
from ..errors import BadInputError, DeviceError
from .options import Output
from .record import run_recording
from .figures import plot_option, pyplot

CAMPAIGN = "campaign.json"
POINTS_FORMAT, POINTS_VERSION = "ambdaq-fx-points", 1
PAIRS = [(j, m) for j in range(2) for m in range(2)]  # (actuator, accelerometer)


def _freqs(spec: str) -> list[float]:
    """``5:100:5`` (from:to:step) or ``5,10,40``, in Hz."""
    try:
        if ":" in spec:
            lo, hi, step = (float(v) for v in spec.split(":"))
            return [float(f) for f in np.arange(lo, hi + step / 2, step)]
        return [float(v) for v in spec.split(",")]
    except ValueError:
        raise BadInputError(f"--freqs {spec!r}: expected FROM:TO:STEP or F1,F2,... in Hz") from None


def _alpha(text: str) -> complex:
    try:
        return complex(text.replace(" ", ""))
    except ValueError:
        raise BadInputError(f"--alphas: {text!r} is not a number (e.g. 1, -1, 0.5+0.5j)") from None


@click.group("fx")
def command() -> None:
    """Base-motion feedforward (seed 002): campaign, MFXLMS estimate, FIR fit."""


@command.command("campaign")
@click.option("--device", default="sim://base-motion", show_default=True, metavar="URL",
              help="The AMB controller (streams /amb/gap and /base/accel): serial://PORT, or sim://base-motion "
                   "served in this process with its simulated shaker generator.")
@click.option("--shaker", metavar="URL",
              help="The two-channel SCPI generator driving the base shakers (serial:///dev/ttyUSB1, "
                   "serial:socket://HOST:5025); default for sim://base-motion: its simulated one.")
@click.option("--shaker-gain", type=click.FloatRange(min=0, min_open=True), default=SHAKER_GAIN, show_default=True,
              help="Base acceleration per generator volt, m/s^2/V (the simulated shakers' by default).")
@click.option("--freqs", default="5:100:5", show_default=True, help="FROM:TO:STEP or F1,F2,... Hz.")
@click.option("--amplitude", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Peak base acceleration d2, m/s^2.")
@click.option("--alphas", default="1,-1+0.5j", show_default=True,
              help="Two disturbance ratios d1/d2 (seed 002 eq. A-10); each frequency is run with both.")
@click.option("--seconds", type=click.FloatRange(min=0.5), default=3.0, show_default=True, help="Recorded per step.")
@click.option("--settle", type=click.FloatRange(min=0), default=0.5, show_default=True,
              help="Wait after moving the shaker before recording each step, s.")
@click.option("-o", "--output", type=click.Path(file_okay=False), required=True, help="Campaign folder.")
def campaign(device, shaker, shaker_gain, freqs, amplitude, alphas, seconds, settle, output):
    """Stepped sine over the base: the shakers are set through their generator, then every
    (frequency, alpha) step is recorded from the controller to its own MCAP file, listed in
    campaign.json.  The same commands run on hardware and on the simulator.

    \b
    Examples:
      ambdaq fx campaign --freqs 5:100:5 -o campaign/
      ambdaq fx campaign --device serial:///dev/ttyUSB0 --shaker serial:socket://10.0.0.7:5025 \\
          --shaker-gain 4.2 --freqs 5:100:5 -o campaign/
    """
    freq_list = _freqs(freqs)
    ratios = [_alpha(a) for a in alphas.split(",")]
    if len(ratios) != 2 or abs(ratios[0] - ratios[1]) < 1e-9:
        raise BadInputError("--alphas: give two different ratios (seed 002 eq. A-17 needs both)")
    for f in freq_list:
        problem = (BaseExcitation("sine", amplitude, f, max(ratios, key=abs)).problem(BASE_MOTION.sample_rate)
                   or drive_problem(amplitude, max(ratios, key=abs), shaker_gain))
        if problem:
            raise BadInputError(f"step {f:g} Hz: {problem}")
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    with ExitStack() as stack:
        controller, shaker = _campaign_devices(device, shaker, stack)
        shakers = Shaker(shaker, gain=shaker_gain)
        stack.callback(shakers.close)
        stack.callback(_at_rest, shakers)
        steps = []
        for f in freq_list:
            for a in ratios:
                shakers.sine(f, amplitude, a)
                time.sleep(settle)
                name = f"step_{len(steps):03d}_{f:g}Hz.mcap"
                run_recording([open_device(controller, name="controller")], Output(out / name, overwrite=True),
                              duration=seconds, quiet=True, as_json=False)
                steps.append({"file": name, "freq_hz": f, "alpha_commanded": [a.real, a.imag]})
                click.echo(f"{f:>7g} Hz  alpha {a:g}  -> {out / name}", err=True)
        shakers.stop()
        (out / CAMPAIGN).write_text(json.dumps({"device": device, "shaker": shakers.identity,
                                                "shaker_gain_m_s2_per_v": shaker_gain,
                                                "amplitude_m_s2": amplitude, "steps": steps}, indent=2))
    click.echo(f"{len(steps)} steps -> {out / CAMPAIGN}")


def _at_rest(shakers: Shaker) -> None:
    """Stop the shakers however the campaign ended; a failure here must not hide the one that ended it."""
    try:
        shakers.stop()
    except DeviceError:
        pass


def _campaign_devices(device: str, shaker: str | None, stack: ExitStack) -> tuple[str, str]:
    """The controller's and the shaker generator's URLs; ``sim://base-motion`` is served in this
    process (stopped when ``stack`` closes) and reached over its pseudo-terminals, as hardware is."""
    url = parse_device_url(device)
    if url.scheme != "sim":
        if shaker is None:
            raise BadInputError("--shaker URL: give the generator that drives the base shakers "
                                "(serial:///dev/ttyUSB1, serial:socket://HOST:5025)")
        return device, shaker
    options = sim_options(url)
    if url.target != "base-motion":
        raise BadInputError(f"{device}: the {url.target} rig has no moving base (use sim://base-motion)")
    served = serve_serial("base-motion", seed=options["seed"])
    stack.callback(served.stop)
    return f"serial://{served.ptys['controller'].path}", shaker or f"serial://{served.ptys['shaker'].path}"


def _path_at(frf: FrequencyResponse, plane: int, f_hz: float) -> np.ndarray:
    """The secondary path B (2 x 2, m/V) of ``plane`` at ``f_hz``, interpolated on the measured points."""
    out = np.empty((2, 2), dtype=complex)
    for i in range(2):
        for j in range(2):
            h, _ = frf.response(AXES[2 * plane + i], AXES[2 * plane + j])
            out[i, j] = np.interp(f_hz, frf.freq_hz, h.real) + 1j * np.interp(f_hz, frf.freq_hz, h.imag)
    return out


@command.command("estimate")
@click.argument("folder", type=click.Path(file_okay=False, exists=True))
@click.option("--path", "path_file", type=click.Path(dir_okay=False), required=True,
              help="Secondary path: frequency-response file from /amb/ff to /amb/gap (ambdaq frf estimate).")
@click.option("--mu", type=click.FloatRange(min=0, min_open=True, max=0.5), default=0.01, show_default=True,
              help="Normalised step on gap 1's error (eta, on gap 2's, is the same).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Compensator points (JSON).")
@click.option("--overwrite", is_flag=True)
def estimate(folder, path_file, mu, output, overwrite):
    """MFXLMS per frequency and plane over a campaign; two alphas per frequency give W11, W21,
    W12, W22 (seed 002 eq. A-4 to A-17).

    \b
    Example:
      ambdaq fx estimate campaign/ --path secondary.frf.json -o points.json
    """
    folder = Path(folder)
    try:
        plan = json.loads((folder / CAMPAIGN).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise BadInputError(f"{folder}: no readable {CAMPAIGN} ({err})") from None
    frf = FrequencyResponse.load(path_file)
    by_freq: dict[float, list] = {}
    try:
        for step in plan["steps"]:
            by_freq.setdefault(float(step["freq_hz"]), []).append(step)
    except (KeyError, TypeError, ValueError) as err:
        raise BadInputError(f"{folder / CAMPAIGN}: malformed campaign ({err})") from None
    freqs, W, residual = [], [], []
    for f, steps in sorted(by_freq.items()):
        if len(steps) != 2:
            raise BadInputError(f"{folder}: {f:g} Hz has {len(steps)} steps; eq. A-17 needs two alphas")
        runs = []
        for step in steps:
            rec = load(folder / step["file"], topics=["/amb/gap", "/base/accel"])
            gap, acc = rec["/amb/gap"], rec["/base/accel"]
            n = min(len(gap), len(acc))
            fs = rec["/amb/gap"].nominal_rate
            theta = 2 * np.pi * f * np.arange(n) / fs
            per_plane = []
            for p in range(2):
                y = np.stack([gap[AXES[2 * p + i]][:n] for i in range(2)], axis=1)
                d = np.stack([acc[BASE_AXES[2 * p + m]][:n] for m in range(2)], axis=1)
                ph = harmonic_fit(d, theta, (1,))[0]  # the ratio the base really had (eq. A-10)
                alpha = complex(ph[0] / ph[1])
                res = mfxlms(y, d, _path_at(frf, p, f), f, fs, mu=mu, eta=mu)
                tail = res.error[-n // 4:]
                per_plane.append((run_beta(res, alpha), alpha, float(np.sqrt(np.mean(tail**2)) / np.sqrt(np.mean(y**2)))))
            runs.append(per_plane)
        freqs.append(f)
        W.append([separate(runs[0][p][0], runs[0][p][1], runs[1][p][0], runs[1][p][1]) for p in range(2)])
        residual.append([max(runs[0][p][2], runs[1][p][2]) for p in range(2)])
        click.echo(f"{f:>7g} Hz  " + "  ".join(f"{PLANES[p]}: residual {20 * np.log10(residual[-1][p]):6.1f} dB"
                                              for p in range(2)), err=True)
    W = np.array(W)  # (freq, plane, j, m)
    doc = {"format": POINTS_FORMAT, "version": POINTS_VERSION, "unit": "V/(m/s^2)", "freq_hz": freqs,
           "planes": {PLANES[p]: {f"W{j + 1}{m + 1}": {"re": W[:, p, j, m].real.tolist(),
                                                       "im": W[:, p, j, m].imag.tolist()} for j, m in PAIRS}
                      for p in range(2)},
           "residual": [[float(r) for r in row] for row in residual],
           "source": {"campaign": str(folder), "path": str(path_file), "path_sha256": file_sha256(path_file),
                      "mu": mu, "created": now_iso()}}
    out = write_sealed(output, doc, overwrite=overwrite, indent=1)
    click.echo(f"{len(freqs)} frequencies x 2 planes -> {out}")


def load_points(path: str) -> tuple[np.ndarray, np.ndarray]:
    """A points file -> (freq_hz (n,), W (n, plane, j, m) complex); checked like every ambdaq file."""
    doc = read_sealed(path, POINTS_FORMAT, POINTS_VERSION, "compensator points file")
    try:
        f = np.array(doc["freq_hz"], dtype=float)
        W = np.empty((f.shape[0], 2, 2, 2), dtype=complex)
        for p, plane in enumerate(PLANES):
            for j, m in PAIRS:
                v = doc["planes"][plane][f"W{j + 1}{m + 1}"]
                W[:, p, j, m] = np.array(v["re"], dtype=float) + 1j * np.array(v["im"], dtype=float)
    except (KeyError, TypeError, ValueError) as err:
        raise BadInputError(f"{path}: malformed points file ({err})") from None
    if not np.all(np.isfinite(W)):
        raise BadInputError(f"{path}: a compensator point is not a finite number")
    return f, W


@command.command("fit")
@click.argument("points", type=click.Path(dir_okay=False))
@click.option("--max-order", type=click.IntRange(0, 63), default=24, show_default=True)
@click.option("--order", type=click.IntRange(0, 63), help="Use this order instead of the knee.")
@click.option("--exact", is_flag=True, help="Also report the error against the simulated rig's exact W* = -B^-1 C.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Coefficient file with the FIR.")
@click.option("--overwrite", is_flag=True)
@plot_option("Bode plot: points and fits.")
@click.option("--json", "as_json", is_flag=True)
def fit(points, max_order, order, exact, output, overwrite, plot_path, as_json):
    """Weighted least-squares FIR fit of each compensator W_jm (seed 002 eq. 19); the order at the
    knee of cost against order unless --order; a FIR is stable by construction.

    \b
    Example:
      ambdaq fx fit points.json -o fir.json --plot fir.png --exact
    """
    freqs, W = load_points(points)
    fs = BASE_MOTION.sample_rate
    orders = np.arange(0, max_order + 1)
    costs = np.array([[[sum(fit_fir(freqs, W[:, p, j, m], o, fs)[1] for p in range(2)) for o in orders]
                       for m in range(2)] for j in range(2)])  # (j, m, order), both planes together
    chosen = order if order is not None else max(knee(orders, costs[j, m], 2 * len(freqs)) for j, m in PAIRS)
    taps = np.zeros((2, 2, 2, chosen + 1))
    for p in range(2):
        for j, m in PAIRS:
            taps[p, j, m] = fit_fir(freqs, W[:, p, j, m], chosen, fs)[0]
    E = np.exp(-2j * np.pi * np.outer(freqs / fs, np.arange(chosen + 1)))
    fitted = np.einsum("ft,pjmt->fpjm", E, taps)
    report = {"order": chosen, "taps": chosen + 1,
              "cost_per_order": {f"W{j + 1}{m + 1}": [float(c) for c in costs[j, m]] for j, m in PAIRS},
              "fit_error_pct": (100 * np.abs(fitted / W - 1)).max(axis=(1, 2, 3)).round(3).tolist()}
    if exact:
        _, _, Wstar = BaseMotionRig().responses(freqs)
        report["error_vs_exact_pct"] = (100 * np.abs(fitted / Wstar[:, None] - 1)).max(axis=(1, 2, 3)).round(3).tolist()
        report["points_vs_exact_pct"] = (100 * np.abs(W / Wstar[:, None] - 1)).max(axis=(1, 2, 3)).round(3).tolist()
    coef = Coefficients(
        target={"rig": "base-motion", "axes": list(AXES)},
        source={"points": str(points), "points_sha256": file_sha256(points), "created": now_iso(), "fit": "eq. 19"},
        harmonics=[], weights={},
        fir={"sample_rate_hz": fs, "unit": "V/(m/s^2)", "outputs": list(AXES), "inputs": list(BASE_AXES),
             "planes": {PLANES[p]: taps[p].tolist() for p in range(2)}},
    )
    coef.save(output, overwrite=overwrite)
    if plot_path:
        _bode(freqs, W, fitted, fs, taps, plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    click.echo("fit error per FIR order: RMS relative error over the points of both planes, % (eq. 19's J)")
    click.echo(f"{'order':>5}" + "".join(f"{f'W{j + 1}{m + 1}':>11}" for j, m in PAIRS))
    for i, o in enumerate(orders):
        mark = "  <- knee" if o == chosen else ""
        click.echo(f"{o:>5}" + "".join(f"{100 * np.sqrt(costs[j, m, i] / (2 * len(freqs))):>11.3f}"
                                        for j, m in PAIRS) + mark)
    click.echo(f"FIR order {chosen} ({chosen + 1} taps) -> {output}")
    click.echo(f"{'Hz':>7}{'fit err %':>11}" + (f"{'vs W* %':>10}{'points vs W* %':>16}" if exact else ""))
    for i, f in enumerate(freqs):
        row = f"{f:>7g}{report['fit_error_pct'][i]:>11.3f}"
        if exact:
            row += f"{report['error_vs_exact_pct'][i]:>10.3f}{report['points_vs_exact_pct'][i]:>16.3f}"
        click.echo(row)


def _bode(freqs, W, fitted, fs, taps, path) -> None:
    plt = pyplot()

    fine = np.linspace(freqs.min(), freqs.max(), 400)
    E = np.exp(-2j * np.pi * np.outer(fine / fs, np.arange(taps.shape[-1])))
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True, constrained_layout=True)
    for p, ls in ((0, "-"), (1, "--")):
        for k, (j, m) in enumerate(PAIRS):
            curve = E @ taps[p, j, m]
            c = f"C{k}"
            axes[0, p].plot(freqs, np.abs(W[:, p, j, m]), "o", color=c, ms=4, label=f"W{j + 1}{m + 1} MFXLMS")
            axes[0, p].plot(fine, np.abs(curve), ls, color=c, lw=1, label=f"W{j + 1}{m + 1} FIR")
            points = np.degrees(np.unwrap(np.angle(W[:, p, j, m])))
            line = np.degrees(np.unwrap(np.angle(curve)))
            line += 360 * np.round((points[0] - np.interp(freqs[0], fine, line)) / 360)  # the points' branch
            axes[1, p].plot(freqs, points, "o", color=c, ms=4)
            axes[1, p].plot(fine, line, ls, color=c, lw=1)
        axes[0, p].set(title=f"{PLANES[p]} plane", ylabel="|W| [V/(m/s²)]", yscale="log")
        axes[1, p].set(xlabel="frequency [Hz]", ylabel="phase [deg], unwrapped")
        axes[0, p].legend(fontsize=7, ncol=2)
        for ax in axes[:, p]:
            ax.grid(alpha=0.3, which="both")
    fig.suptitle(f"base-motion compensators: MFXLMS points and FIR fit ({taps.shape[-1]} taps)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
