"""``ambdaq runout``: identify sensor runout from recordings and write a coefficient file."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import numpy as np

from ..analysis.rotor import AXES, RigidRotor
from ..analysis.runout import harmonic_fit, lms_offline, runout_from_sensor, separate_unbalance, synchronous_average
from ..daq.coefficients import Coefficients, file_sha256, now_iso
from ..daq.reader import load
from ..errors import BadInputError

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


def identify_recordings(paths: list[Path], harmonics: list[int], method: str) -> tuple[Coefficients, list[str]]:
    """Runout per axis and harmonic from recordings at constant speed (one speed per file).

    Returns the coefficients and warnings.  Harmonics above 1X come from every file (averaged);
    1X comes from a slow roll if there is one, else from separating runout and unbalance over
    the speeds, else (one fast recording) with a warning that it holds the unbalance response.
    """
    per_file, warnings, sources = [], [], []
    rotor = device = identity = None
    for path in paths:
        rec = load(path, topics=["/amb/gap", "/amb/current", "/amb/rotor"])
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
    return coef, warnings


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
def identify(files, output, harmonics, method, overwrite, as_json):
    """Identify runout per axis and harmonic from FILES (each at one constant speed).

    \b
    Examples:
      ambdaq runout identify slowroll.mcap -o coef.json
      ambdaq runout identify run_12k.mcap run_24k.mcap run_36k.mcap -o coef.json
    """
    coef, warnings = identify_recordings([Path(f) for f in files], list(range(1, harmonics + 1)), method)
    coef.save(output, overwrite=overwrite)
    for w in warnings:
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
