"""``ambdaq runout``: identify sensor runout from recordings and write a coefficient file."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import click
import numpy as np

from ..analysis.rotor import AXES, RigidRotor
from ..analysis.runout import harmonic_fit, lms_offline, runout_from_sensor, separate_unbalance, synchronous_average
from ..daq.coefficients import Coefficients, file_sha256, now_iso
from ..daq.reader import Recording, load
from ..errors import AmbdaqError, BadInputError
from .runout_plots import check_report, identify_report
from .figures import plot_option

RPM_PER_RAD_S = 60.0 / (2 * np.pi)
SLOW_ROLL_RPM = 2000.0  # below this the unbalance response at 1X is negligible
METHODS = {
    "fit": lambda x, th, k: harmonic_fit(x, th, k),
    "average": lambda x, th, k: synchronous_average(x, th, harmonics=k),
    "lms": lambda x, th, k: lms_offline(x, th, harmonics=k).phasors,
}


def _rotor(rec, path: Path) -> tuple[RigidRotor, str, dict]:
    for name, meta in rec.metadata.items():
        if name.startswith("ambdaq.calibration.") and "rotor.mass_kg" in meta:
            device = name.removeprefix("ambdaq.calibration.")
            return RigidRotor.from_metadata(meta), device, rec.metadata.get(f"ambdaq.device.{device}", {})
    raise BadInputError(f"{path}: no rotor model (rotor.* calibration) in the recording; the rig file must give one")


@dataclass(frozen=True)
class Identification:
    """What ``runout identify`` found: the coefficients, and each recording's own estimate."""

    coef: Coefficients
    warnings: list[str]
    paths: list[Path]
    first: Recording  # the first recording's gap, current and rotor, for the report
    spins: np.ndarray  # rad/s, per recording
    per_file: np.ndarray  # complex m, (recording, harmonic, axis): runout seen at that speed alone


def identify_recordings(paths: list[Path], harmonics: list[int], method: str) -> Identification:
    """Runout per axis and harmonic from recordings at constant speed (one speed per file).

    Harmonics above 1X come from every file (averaged); 1X comes from a slow roll if there is
    one, else from separating runout and unbalance over the speeds, else (one fast recording)
    with a warning that it holds the unbalance response.
    """
    per_file, warnings, sources, recs = [], [], [], []
    rotor = device = identity = None
    for path in paths:
        rec = load(path, topics=["/amb/gap", "/amb/current", "/amb/rotor"])
        recs.append(rec)
        rotor, device, identity = _rotor(rec, path)
        gap, cur, rot = rec["/amb/gap"], rec["/amb/current"], rec["/amb/rotor"]
        n = min(len(gap), len(cur), len(rot))
        speed = rot["speed"][:n]
        w = float(np.median(speed))
        if w <= 0 or np.std(speed) > 0.01 * w:
            raise BadInputError(f"{path}: runout identification needs a constant speed; this recording runs from "
                                f"{speed.min() * RPM_PER_RAD_S:.0f} to {speed.max() * RPM_PER_RAD_S:.0f} rpm")
        theta = rot["angle"][:n]
        fit = METHODS[method]
        G = np.stack([fit(gap[a][:n], theta, harmonics) for a in AXES], axis=1)  # (harmonic, axis)
        I = np.stack([fit(cur[a][:n], theta, harmonics) for a in AXES], axis=1)
        r = np.array([runout_from_sensor(G[i], I[i], k * w, w, rotor) for i, k in enumerate(harmonics)])
        per_file.append((w, r))
        sources.append({"path": str(path), "sha256": file_sha256(path), "speed_rpm": round(w * RPM_PER_RAD_S, 1)})
    spins = np.array([w for w, _ in per_file])
    est = np.mean([r for _, r in per_file], axis=0)  # (harmonic, axis)
    if 1 in harmonics:
        i1 = harmonics.index(1)
        slow = [r for w, r in per_file if w * RPM_PER_RAD_S <= SLOW_ROLL_RPM]
        if slow:
            est[i1] = np.mean([r[i1] for r in slow], axis=0)
        elif len(set(np.round(spins))) >= 2:
            est[i1] = separate_unbalance(np.array([r[i1] for _, r in per_file]), spins, rotor).runout
        else:
            warnings.append(f"1X at {spins[0] * RPM_PER_RAD_S:.0f} rpm also holds the rotor's unbalance response "
                            "(right for feedforward at this speed); add a slow roll (--rpm slowroll) or recordings "
                            "at other speeds to separate the runout")
    weights = {axis: [[float(est[i, a].real), float(est[i, a].imag)] for i in range(len(harmonics))]
               for a, axis in enumerate(AXES)}
    coef = Coefficients(
        target={"rig": identity.get("profile", identity.get("model", "")), "device": device,
                "serial": identity.get("serial", ""), "axes": list(AXES)},
        source={"recordings": sources, "method": method, "created": now_iso()},
        harmonics=list(harmonics),
        weights=weights,
    )
    return Identification(coef, warnings, list(paths), recs[0], spins, np.array([r for _, r in per_file]))


@click.group("runout")
def command() -> None:
    """Sensor runout: identify it from recordings."""


@command.command("identify")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Coefficient file (JSON).")
@click.option("--harmonics", type=click.IntRange(1, 8), default=6, show_default=True, help="Identify 1X .. NX.")
@click.option("--method", type=click.Choice(sorted(METHODS)), default="fit", show_default=True,
              help="fit: batch least squares; average: angle-domain synchronous averaging (slow roll); "
                   "lms: seed 000's LMS run offline.")
@click.option("--overwrite", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the identified runout as JSON.")
@plot_option("Report image (.png, .pdf, .svg): spectrum, polar plot per harmonic, orbits before and after.")
def identify(files, output, harmonics, method, overwrite, as_json, plot_path):
    """Identify runout per axis and harmonic from FILES (each at one constant speed).

    \b
    Examples:
      ambdaq runout identify slowroll.mcap -o coef.json
      ambdaq runout identify run_12k.mcap run_24k.mcap run_36k.mcap -o coef.json --plot report.png
    """
    ident = identify_recordings([Path(f) for f in files], list(range(1, harmonics + 1)), method)
    coef = ident.coef
    coef.save(output, overwrite=overwrite)
    if plot_path:
        identify_report(ident, plot_path)
        click.echo(f"-> {plot_path}", err=True)
    for w in ident.warnings:
        click.echo(f"ambdaq: warning: {w}", err=True)
    table = {axis: [{"harmonic": k, "amplitude_um": round(float(np.hypot(*wk)) * 1e6, 4),
                     "phase_deg": round(float(np.degrees(np.arctan2(wk[1], wk[0]))), 2)}
                    for k, wk in zip(coef.harmonics, rows)] for axis, rows in coef.weights.items()}
    if as_json:
        click.echo(json.dumps(table, indent=2))
    else:
        click.echo(f"{'axis':<9}" + "".join(f"{f'{k}X um / deg':>18}" for k in coef.harmonics))
        for axis, rows in table.items():
            click.echo(f"{axis:<9}" + "".join(f"{r['amplitude_um']:>9.3f} {r['phase_deg']:>7.1f} " for r in rows))
        click.echo(f"-> {output}", err=True)
    sys.stdout.flush()


class CheckFailed(AmbdaqError):
    """``runout check``: the after-recording did not meet the asked reduction (exit 1)."""


def _synchronous(rec: Recording, harmonics: list[int]) -> dict:
    """Per radial axis: harmonic phasors of the command error and the gap sensor (m), the error's RMS (m)."""
    err, gap, rot = rec["/amb/error"], rec["/amb/gap"], rec["/amb/rotor"]
    n = min(len(err), len(gap), len(rot))
    if n < 2:
        raise BadInputError(f"{rec.path}: too short to check ({n} samples)")
    theta = rot["angle"][:n]
    out = {"rpm": float(np.median(rot["speed"][:n])) * RPM_PER_RAD_S, "axes": {}}
    for a in AXES:
        if a.endswith(("_x", "_y")) and a in err.fields:
            out["axes"][a] = {"error": harmonic_fit(err[a][:n], theta, harmonics),
                              "gap": harmonic_fit(gap[a][:n], theta, harmonics),
                              "rms": float(np.sqrt(np.mean(err[a][:n] ** 2)))}
    return out


def _db(after: float, before: float) -> float:
    return float(20 * np.log10(after / before))


@command.command("check")
@click.argument("before", type=click.Path(dir_okay=False))
@click.argument("after", type=click.Path(dir_okay=False))
@click.option("--harmonics", type=click.IntRange(1, 8), default=2, show_default=True, help="Compare 1X .. NX.")
@click.option("--min-db", type=click.FloatRange(min=0), help="Fail (exit 1) unless every harmonic falls this much.")
@click.option("--max-rms", type=click.FloatRange(min=0, min_open=True),
              help="Fail (exit 1) unless the command error's RMS after is below this, in um.")
@plot_option("Image (.png, .pdf, .svg): command-error orbits and spectra before and after.")
@click.option("--json", "as_json", is_flag=True)
def check(before, after, harmonics, min_db, max_rms, plot_path, as_json):
    """Prove on a new recording that the command error went down: 1X .. NX and RMS, per axis.

    The command error is what the controller acts on (gap minus feedforward); the gap sensor
    still carries the runout, and its 1X after is shown beside it.

    \b
    Examples:
      ambdaq runout check run.mcap after.mcap
      ambdaq runout check run.mcap after.mcap --min-db 20 --max-rms 5 --plot check.png
    """
    orders = list(range(1, harmonics + 1))
    recs = [load(f, topics=["/amb/error", "/amb/gap", "/amb/rotor"]) for f in (before, after)]
    b, a = (_synchronous(rec, orders) for rec in recs)
    rows, failures = {}, []
    for axis, rb in b["axes"].items():
        ra = a["axes"][axis]
        eb, ea = np.abs(rb["error"]) * 1e6, np.abs(ra["error"]) * 1e6
        rows[axis] = {
            "harmonics": [{"harmonic": k, "before_um": round(float(eb[i]), 4), "after_um": round(float(ea[i]), 4),
                           "change_db": round(_db(ea[i], eb[i]), 2)} for i, k in enumerate(orders)],
            "rms_before_um": round(rb["rms"] * 1e6, 4), "rms_after_um": round(ra["rms"] * 1e6, 4),
            "sensor_1x_after_um": round(float(abs(ra["gap"][0])) * 1e6, 4),
        }
        for h in rows[axis]["harmonics"]:
            if min_db is not None and not h["change_db"] <= -min_db:
                failures.append(f"{axis} {h['harmonic']}X fell {-h['change_db']:.1f} dB (< {min_db:g} dB)")
        if max_rms is not None and not rows[axis]["rms_after_um"] < max_rms:
            failures.append(f"{axis} RMS {rows[axis]['rms_after_um']:.2f} um after (>= {max_rms:g} um)")
    if plot_path:
        check_report(*recs, orders, plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps({"before": {"path": before, "rpm": round(b["rpm"], 1)},
                               "after": {"path": after, "rpm": round(a["rpm"], 1)},
                               "axes": rows, "failures": failures}, indent=2))
    else:
        click.echo(f"command error, before {before} at {b['rpm']:,.0f} rpm, after {after} at {a['rpm']:,.0f} rpm")
        click.echo(f"{'axis':<9}" + "".join(f"{f'{k}X um (dB)':>26}" for k in orders)
                   + f"{'RMS um':>18}{'sensor 1X after':>17}")
        for axis, r in rows.items():
            cells = "".join(f"{h['before_um']:>9.3f} ->{h['after_um']:>7.3f} ({h['change_db']:+6.1f})"
                            for h in r["harmonics"])
            click.echo(f"{axis:<9}{cells}{r['rms_before_um']:>8.2f} ->{r['rms_after_um']:>6.2f}"
                       f"{r['sensor_1x_after_um']:>14.2f} um")
    if abs(a["rpm"] - b["rpm"]) > 0.01 * max(b["rpm"], 1.0):
        click.echo(f"ambdaq: warning: the recordings run at different speeds ({b['rpm']:,.0f} and "
                   f"{a['rpm']:,.0f} rpm); the harmonics compare different frequencies", err=True)
    if failures:
        raise CheckFailed("check failed: " + "; ".join(failures))
