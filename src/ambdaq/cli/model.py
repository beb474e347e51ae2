"""``ambdaq model``: a cone-shaped AMB axis from its description (Jeong et al.): gains, stability, stiffness."""

from __future__ import annotations

import json

import click
import numpy as np

from ..errors import BadInputError
from ..workflows.cone_axis import EXAMPLE, analyse_axis, load_axis
from .options import plot_option

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
    model = analyse_axis(*load_axis(file))
    loop, magnet, region, kp_max = model.loop, model.magnet, model.region, model.kp_max
    report = model.as_dict()
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
    click.echo("poles (rad/s): " + ", ".join(f"{p.real:.1f}{p.imag:+.1f}j" for p in sorted(model.poles, key=abs)))
    for row in report["stiffness_damping"]:
        click.echo(f"  {row['hz']:>5g} Hz  Keq {row['keq_n_per_m']:>11.4g} N/m  Ceq {row['ceq_n_s_per_m']:>9.4g} N s/m")


