"""Bode plot and coherence of a measured frequency response (``ambdaq frf estimate --plot``)."""

from __future__ import annotations

import numpy as np

from ..analysis.frf import COHERENT
from ..documents.frequency_response import FrequencyResponse
from . import pyplot


def draw_bode(frf: FrequencyResponse):
    """Each excited axis's response on itself: magnitude (faint where the coherence is below
    COHERENT), phase where it is trusted, and the coherence."""
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
    return fig
