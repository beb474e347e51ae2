"""The APHT figure (``ambdaq apht``): per order, amplitude and phase against time."""

from __future__ import annotations

import numpy as np

from . import pyplot


def draw_apht(res):
    """Per order: amplitude and phase against time of each axis's gap (solid), command error
    (dashed) and, on a second scale, the feedforward output (dotted)."""
    plt = pyplot()
    fig, axs = plt.subplots(2, len(res.orders), figsize=(7 * len(res.orders), 7), sharex=True, squeeze=False,
                            constrained_layout=True)
    ff_scale, ff_unit = (1e6, "µm") if res.ff_unit == "m" else (1.0, res.ff_unit)
    for i, k in enumerate(res.orders):
        amp, ph = axs[0, i], axs[1, i]
        ff_ax = amp.twinx() if res.feedforward is not None else None
        for j, a in enumerate(res.axes):
            c = f"C{j}"
            amp.plot(res.time_s, np.abs(res.gap[:, i, j]) * 1e6, color=c, lw=1.2, label=f"{a} gap")
            ph.plot(res.time_s, np.degrees(np.unwrap(np.angle(res.gap[:, i, j]))), color=c, lw=1.2)
            if res.error is not None:
                amp.plot(res.time_s, np.abs(res.error[:, i, j]) * 1e6, color=c, lw=0.9, ls="--", label=f"{a} error")
            if ff_ax is not None:
                ff_ax.plot(res.time_s, np.abs(res.feedforward[:, i, j]) * ff_scale, color=c, lw=0.8, ls=":",
                           label=f"{a} feedforward")
        amp.set(ylabel="amplitude [µm]", title=f"{k}X at {res.rpm:,.0f} rpm")
        ph.set(xlabel="time [s]", ylabel="phase [deg], unwrapped")
        if ff_ax is not None:
            ff_ax.set_ylabel(f"feedforward {k}X [{ff_unit}] (dotted)")
        handles, labels = amp.get_legend_handles_labels()
        if ff_ax is not None:
            more = ff_ax.get_legend_handles_labels()
            handles, labels = handles + more[0], labels + more[1]
        amp.legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.12 if ff_ax else 1.01, 1.0))
        for ax in (amp, ph):
            ax.grid(alpha=0.3)
    fig.suptitle(f"APHT, {res.compensation}")
    return fig
