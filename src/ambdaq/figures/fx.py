"""The base-motion compensators (``ambdaq fx fit --plot``): Kang & Jung's MFXLMS points beside the
fitted FIR filters' responses (eq. 19), per plane."""

from __future__ import annotations

import numpy as np

from ..machines.base_motion import PLANES
from ..documents.compensator_points import PAIRS
from . import pyplot


def draw_compensators(freqs: np.ndarray, W: np.ndarray, fs: float, taps: np.ndarray):
    """Magnitude and phase of each compensator W_jm per plane: the MFXLMS points (``freqs``, Hz;
    ``W`` (frequency, plane, output, input), V/(m/s^2)) and the FIR ``taps`` at ``fs`` (Hz)."""
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
    return fig
