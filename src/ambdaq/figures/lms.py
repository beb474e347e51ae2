"""The LMS convergence map (``ambdaq lms map --plot``, Ro et al. Fig. 5)."""

from __future__ import annotations

import numpy as np

from ..analysis.lms import converges
from . import pyplot


def draw_map(maps: dict, rpm: np.ndarray, mu: np.ndarray, harmonic: int, plant: str, compensated: bool):
    """Where the LMS converges (green), diverges (red) and holds (white) per loop, over speed
    (``rpm``) and step size (``mu``); ``maps``: loop name -> spectral radius (speed, mu)."""
    plt = pyplot()

    from matplotlib.colors import ListedColormap

    fig, axes = plt.subplots(1, len(maps), figsize=(6 * len(maps), 4.5), squeeze=False)
    for ax, (name, r) in zip(axes[0], maps.items()):
        ax.pcolormesh(rpm, mu, converges(r.T), shading="auto", vmin=-1, vmax=1,
                      cmap=ListedColormap(["#f4c7c3", "#ffffff", "#b7e1cd"]))
        ax.contour(rpm, mu, r.T, levels=[1.0], colors="k", linewidths=1.0)
        ax.axhline(0, color="grey", lw=0.5)
        ax.set(xlabel="speed (rpm)", ylabel="step size mu",
               title=f"{name}: {harmonic}X, {'compensated' if compensated else 'Ro et al.'} update "
                     "(green converges, red diverges, white holds)")
    fig.suptitle(f"LMS convergence map, plant {plant} (Ro et al. Fig. 5)")
    fig.tight_layout()
    return fig
