"""The controller design's figure (``ambdaq controller design --plot``): each axis's predicted peak
|Gs| over speed, the design's and the stock controller's, against the ISO 14839-3 zone limits."""

from __future__ import annotations

import numpy as np

from ..analysis.iso14839 import STABILITY_LIMITS, db
from . import pyplot


def draw_design(speeds_rpm: np.ndarray, peak_db: np.ndarray, stock_db: np.ndarray, axes: list[str],
                sections: dict[str, list[str]]):
    """Predicted peak |Gs| against speed per axis (one line each; x and y of a bearing alike), the
    stock controller's dashed, where it is unstable shaded.

    Parameters
    ----------
    speeds_rpm : ndarray, shape (n,)
        The speed grid, rpm.
    peak_db, stock_db : ndarray, shape (n, axes)
        Predicted peak |Gs| with the design and with the stock controller, dB (NaN: unstable).
    axes : list of str
        The axes, in the columns' order.
    sections : dict of str to list of str
        Each bearing's sections, in words (the title says them).
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.6), constrained_layout=True)
    for i, name in enumerate(axes):
        line = ax.plot(speeds_rpm, peak_db[:, i], lw=1.2, label=f"{name}: design")[0]
        ax.plot(speeds_rpm, stock_db[:, i], lw=0.9, ls="--", color=line.get_color(), alpha=0.6,
                label=f"{name}: stock")
    unstable = np.isnan(stock_db).any(axis=1)
    if unstable.any():
        ax.fill_between(speeds_rpm, 0, 1, where=unstable, transform=ax.get_xaxis_transform(), color="red", alpha=0.08,
                        label="stock unstable")
    for z, v in zip(("A/B", "B/C", "C/D"), STABILITY_LIMITS.as_list()):
        ax.axhline(db(v), color="grey", lw=0.7, ls=":")
        ax.annotate(z, (1.0, db(v)), xycoords=("axes fraction", "data"), ha="right", va="bottom", fontsize=7)
    title = "; ".join(f"{b}: {', '.join(s) or 'no sections'}" for b, s in sections.items())
    ax.set(xlabel="speed [rpm]", ylabel="predicted peak |Gs| [dB]", title=title)
    ax.title.set_fontsize(8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="upper left")
    return fig
