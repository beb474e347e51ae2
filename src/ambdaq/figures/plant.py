"""The plant measured in closed loop (``ambdaq plant identify --plot``): per axis its magnitude
with the 95 % band of its random error and its phase, where the coherence trusts it, and the
loop's sensitivity and complementary sensitivity; a fitted model's response beside it when given."""

from __future__ import annotations

import numpy as np

from ..analysis.frf import COHERENT
from ..analysis.iso14839 import db
from . import pyplot


def draw_plant(measured, fitted: np.ndarray | None = None):
    """Three panels: |P_ii| (um/V) with +-2 sigma, its phase (deg), |S| and |T| (dB).

    Parameters
    ----------
    measured : PlantMeasurement
        What ``plant identify`` measured.
    fitted : ndarray of complex, shape (n, axes), optional
        A model's P_ii at the same frequencies, m/V (``plant fit``).
    """
    plt = pyplot()
    f = measured.freq_hz
    fig, (mag, phase, loop) = plt.subplots(3, 1, figsize=(9, 9), sharex=True, constrained_layout=True)
    for i, axis in enumerate(measured.axes):
        p = measured.plant.response[:, i, i] * 1e6
        sigma = measured.plant.sigma[:, i, i] * 1e6
        good = measured.plant.coherence[:, i, i] >= COHERENT
        shown = np.where(good, np.abs(p), np.nan)
        line = mag.loglog(f, shown, lw=0.9, label=f"{axis} measured")[0]
        colour = line.get_color()
        mag.fill_between(f, np.where(good, np.maximum(np.abs(p) - 2 * sigma, 1e-6), np.nan),
                         np.where(good, np.abs(p) + 2 * sigma, np.nan), color=colour, alpha=0.2, lw=0)
        phase.semilogx(f, np.where(good, np.degrees(np.angle(p)), np.nan), lw=0.9, color=colour)
        if fitted is not None:
            model = fitted[:, i] * 1e6
            mag.loglog(f, np.abs(model), lw=0.9, ls="--", color=colour, label=f"{axis} model")
            phase.semilogx(f, np.degrees(np.angle(model)), lw=0.9, ls="--", color=colour)
        s = measured.sensitivity[:, i]
        trusted = measured.sensitivity_coherence[:, i] >= COHERENT
        loop.semilogx(f, np.where(trusted, db(np.abs(s)), np.nan), lw=0.9, color=colour, label=f"{axis} |S|")
        loop.semilogx(f, np.where(trusted, db(np.abs(1 - s)), np.nan), lw=0.7, ls=":", color=colour, label=f"{axis} |T|")
    mag.set(ylabel="|P| [um/V]", title=f"plant measured in closed loop at {measured.speed_rpm:,.0f} rpm "
                                        f"(band: 95 % of its random error; coherence >= {COHERENT:g})")
    phase.set(ylabel="phase [deg]", ylim=(-185, 185), yticks=range(-180, 181, 90))
    loop.set(ylabel="[dB]", xlabel="frequency [Hz]", title="sensitivity S = -e/r and T = 1 - S")
    for ax in (mag, phase, loop):
        ax.grid(alpha=0.3, which="both")
    mag.legend(fontsize=7, loc="lower left", ncol=2)
    loop.legend(fontsize=7, loc="lower right", ncol=2)
    return fig
