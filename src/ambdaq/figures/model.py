"""The stable (Kp, Kd) region of a cone AMB axis (``ambdaq model --plot``, Jeong et al. eq. 22-23)."""

from __future__ import annotations

import numpy as np

from ..analysis.cone import PdLoop, stable_map
from . import pyplot


def draw_region(loop: PdLoop, region, kp_max: float):
    """The stable (Kp, Kd) map, wide enough to show Kp_max at the design Kd and the design point;
    the legend beside the map, so it hides none of the stable region."""
    plt = pyplot()

    kd = np.geomspace(max(region.kd_min, 1e-7) * 0.5, region.kd_max * 2, 160)
    top = max(region.kp_min * 20, loop.kp, kp_max if np.isfinite(kp_max) else 0.0) * 3
    kp = np.geomspace(region.kp_min * 0.5, top, 160)
    ok = stable_map(loop, kp, kd)
    fig, ax = plt.subplots(figsize=(8.5, 5), constrained_layout=True)
    ax.contourf(kd, kp, ok.astype(float), levels=[-0.5, 0.5, 1.5], colors=["#f4c7c3", "#b7e1cd"])
    ax.plot(loop.kd, loop.kp, "k*", ms=10, label="design point")
    ax.axhline(region.kp_min, color="k", lw=0.6, ls=":", label=f"Kp_min {region.kp_min:.3g}")
    if np.isfinite(kp_max) and kp_max > 0:
        ax.plot(loop.kd, kp_max, "kv", ms=7, label=f"Kp_max {kp_max:.3g}\nat the design Kd")
    ax.set(xscale="log", yscale="log", xlabel="Kd [s]", ylabel="Kp [V/V]",
           title="stable PD gains (green), Jeong et al. eq. 22-23")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
    return fig
