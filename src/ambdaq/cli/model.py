"""``ambdaq model``: a cone-shaped AMB axis from its description (Jeong et al.): gains, stability, stiffness."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import click
import numpy as np

from ..analysis.cone import PdLoop, force_factor, linear_gains, shape_factor, stable_region
from ..errors import BadInputError
from .options import plot_option

EXAMPLE = """\
# one axis of Jeong et al.'s cone-shaped AMB (Table 1; gains of the Routh-Hurwitz example)
[magnet]
area_mm2 = 155
turns = 400
gap_mm = 0.5
bias_a = 1.03
pole_angles_deg = [20, 50]     # optional: force and shape factors (eq. 3); default 1, 1

[axis]
mass_kg = 1.68
# Ky and Ki of the paper's Routh-Hurwitz example: Ky/G = 1.9 and m/G = 5.69e-6 s^2, G = Ks Kc Ki.
# Delete these two lines to take the differential pair's 2 Kq and 2 Ki from [magnet] instead.
ky_n_per_m = 5.609e5
ki_n_per_a = 29.52

[controller]
sensor_v_per_m = 10000
amplifier_a_per_v = 1.0        # Kc
kp = 3.0
kd = 0.005                      # s
tau_s = 8e-5                    # derivative filter
tau_c_s = 6e-5                  # current loop
tau_e_s = 0.0                   # eddy-current lag (eq. 16)
"""


def _get(table: dict, key: str, path: str, default=None) -> float:
    if key not in table:
        if default is None:
            raise BadInputError(f"{path}: missing {key}")
        return default
    value = table[key]
    if not isinstance(value, (int, float)) or not np.isfinite(value):
        raise BadInputError(f"{path}: {key} must be a finite number, not {value!r}")
    return float(value)


def load_axis(path: str) -> tuple[PdLoop, dict]:
    """A bearing description (TOML, see ``ambdaq model --example``) -> the PD loop and the magnet's gains."""
    try:
        doc = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise BadInputError(f"{path}: not TOML ({err})") from None
    mag, axis, ctl = doc.get("magnet", {}), doc.get("axis", {}), doc.get("controller", {})
    angles = mag.get("pole_angles_deg")
    if angles is not None and (not isinstance(angles, list) or len(angles) != 2):
        raise BadInputError(f"{path}: pole_angles_deg must be [theta1, theta2]")
    ag, c = (1.0, 1.0) if angles is None else (force_factor(*np.radians(angles)), shape_factor(*np.radians(angles)))
    turns = _get(mag, "turns", path)
    gains = linear_gains(area=_get(mag, "area_mm2", path) * 1e-6, turns=int(turns), gap=_get(mag, "gap_mm", path) * 1e-3,
                         bias=_get(mag, "bias_a", path), alpha_g=ag, c=c)
    loop = PdLoop(m=_get(axis, "mass_kg", path), ky=_get(axis, "ky_n_per_m", path, 2 * gains.kq),
                  ki=_get(axis, "ki_n_per_a", path, 2 * gains.ki), ks=_get(ctl, "sensor_v_per_m", path),
                  kc=_get(ctl, "amplifier_a_per_v", path), kp=_get(ctl, "kp", path), kd=_get(ctl, "kd", path),
                  tau=_get(ctl, "tau_s", path), tau_c=_get(ctl, "tau_c_s", path), tau_e=_get(ctl, "tau_e_s", path, 0.0))
    if min(loop.m, loop.ky, loop.ki, loop.ks, loop.kc, loop.tau, loop.tau_c) <= 0 or loop.tau_e < 0:
        raise BadInputError(f"{path}: masses, gains and time constants must be > 0")
    return loop, {"alpha_g": ag, "c": c, "ki_n_per_a": gains.ki, "kq_n_per_m": gains.kq, "f0_n": gains.f0}


@click.command("model")
@click.argument("file", type=click.Path(dir_okay=False), required=False)
@click.option("--example", is_flag=True, help="Print an example description and exit.")
@click.option("--json", "as_json", is_flag=True)
@plot_option("The stable (Kp, Kd) region (.png, .pdf, .svg).")
def command(file, example, as_json, plot_path):
    """Linearised gains, stable (Kp, Kd) region, eigenvalues and equivalent stiffness/damping of
    one cone-shaped AMB axis with its PD loop (Jeong et al.; docs/cone.md).

    \b
    Example:
      ambdaq model --example > axis.toml
      ambdaq model axis.toml --plot region.png
    """
    if example:
        click.echo(EXAMPLE, nl=False)
        return
    if not file:
        raise BadInputError("give a bearing description FILE (ambdaq model --example shows one)")
    loop, magnet = load_axis(file)
    region = stable_region(loop)
    kp_max = region.kp_max(loop)
    poles = loop.poles()
    f = np.array([10.0, 50.0, 100.0, 200.0, 500.0])
    k, c = loop.stiffness_damping(f)
    report = {
        "magnet": {k2: round(v, 6) for k2, v in magnet.items()},
        "axis": {"ky_n_per_m": loop.ky, "ki_n_per_a": loop.ki, "loop_gain_n_per_m": loop.ki * loop.ks * loop.kc},
        "stable": loop.stable(),
        "region": {k: (None if not np.isfinite(v) else v) for k, v in  # JSON has no NaN: none stable is null
                   {"kp_min": region.kp_min, "kd_min_s": region.kd_min, "kd_max_s": region.kd_max,
                    "kp_max_at_kd": kp_max}.items()},
        "poles_rad_s": [[float(p.real), float(p.imag)] for p in sorted(poles, key=lambda p: (abs(p), p.imag))],
        "stiffness_damping": [{"hz": float(fi), "keq_n_per_m": float(ki), "ceq_n_s_per_m": float(ci)}
                              for fi, ki, ci in zip(f, k, c)],
    }
    if plot_path:
        if not np.isfinite(region.kp_min):
            raise BadInputError(f"{file}: no stable (Kp, Kd) region to plot")
        from ..figures import save
        from ..figures.model import draw_region

        save(draw_region(loop, region, kp_max), plot_path)
        click.echo(f"-> {plot_path}", err=True)
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    click.echo(f"magnet: Ki {magnet['ki_n_per_a']:.2f} N/A, Kq {magnet['kq_n_per_m']:.4g} N/m, F0 {magnet['f0_n']:.2f} N "
               f"(alpha_g {magnet['alpha_g']:.3f}, c {magnet['c']:.3f})")
    click.echo(f"axis: Ky {loop.ky:.4g} N/m, Ki {loop.ki:.4g} N/A, Kp {loop.kp:g}, Kd {loop.kd:g} s -> "
               f"{'stable' if report['stable'] else 'UNSTABLE'}")
    if not np.isfinite(region.kp_min):
        click.echo(f"stable region: none: tau tau_c = {loop.tau * loop.tau_c:.3g} s^2 is not below m/Ky = "
                   f"{loop.m / loop.ky:.3g} s^2 (Jeong et al. eq. 23), no PD gains stabilise this axis")
    else:
        at_kd = (f"Kp < {kp_max:.4g}" if np.isfinite(kp_max) else "no upper bound on Kp" if kp_max > 0
                 else "no Kp is stable (Kd is outside the range)")
        click.echo(f"stable region: Kp > {region.kp_min:.3g}; {region.kd_min:.3g} s < Kd < {region.kd_max:.3g} s "
                   f"(at Kp_min); at Kd = {loop.kd:g} s, {at_kd}")
    click.echo("poles (rad/s): " + ", ".join(f"{p.real:.1f}{p.imag:+.1f}j" for p in sorted(poles, key=abs)))
    for row in report["stiffness_damping"]:
        click.echo(f"  {row['hz']:>5g} Hz  Keq {row['keq_n_per_m']:>11.4g} N/m  Ceq {row['ceq_n_s_per_m']:>9.4g} N s/m")


