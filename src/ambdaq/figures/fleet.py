"""A machine's trend over a fleet dataset (``ambdaq fleet trend --plot``)."""

from __future__ import annotations

from . import pyplot


def draw_trend(df, machine: str):
    """One machine's trend over its recordings: 1X per axis, the mean runout per harmonic, each
    bearing's orbit against the ISO 14839-2 zone boundaries. Dates carry their year; the legends
    stand beside the panels and the zone names at their right edge, off the data.

    Parameters
    ----------
    df : pandas.DataFrame
        The machine's rows (:func:`~ambdaq.workflows.fleet.read`).
    machine : str
        Its name, for the title.
    """
    import matplotlib.dates as mdates

    from ..workflows.fleet import HARMONICS, axes_of, bearings_of

    plt = pyplot()
    axes = [a for a in axes_of(df) if df[f"onex_{a}_um"].notna().any()]  # one machine's own axes and bearings
    fig, axs = plt.subplots(3, 1, figsize=(10, 9), sharex=True, constrained_layout=True)
    t = df["start"]
    for a in axes:
        axs[0].plot(t, df[f"onex_{a}_um"], "o-", ms=3, label=a)
    axs[0].set_ylabel("1X gap [µm]")
    for k in HARMONICS:
        axs[1].plot(t, df[[f"runout_{a}_{k}x_um" for a in axes]].mean(axis=1), "o-", ms=3, label=f"{k}X")
    axs[1].set_ylabel("sensor runout,\nmean of axes [µm]")
    for b in (b for b in bearings_of(df) if df[f"vibration_{b}_um"].notna().any()):
        axs[2].plot(t, df[f"vibration_{b}_um"], "o-", ms=3, label=f"{b} orbit")
    cmin = df["cmin_um"].dropna()
    if not cmin.empty:
        for r, z in ((0.3, "A/B"), (0.4, "B/C"), (0.5, "C/D")):  # ISO 14839-2 boundaries per Cmin
            axs[2].axhline(r * cmin.iloc[0], color="grey", lw=0.8, ls="--")
            axs[2].annotate(z, (1.0, r * cmin.iloc[0]), xycoords=("axes fraction", "data"), xytext=(3, 0),
                            textcoords="offset points", fontsize=8, color="grey", va="center")
    axs[2].set_ylabel("orbit max [µm]\n(ISO 14839-2)")
    locator = mdates.AutoDateLocator(minticks=2, maxticks=8)
    axs[2].xaxis.set_major_locator(locator)
    axs[2].xaxis.set_major_formatter(mdates.DateFormatter("%Y-%m-%d"))
    for label in axs[2].get_xticklabels():
        label.set(rotation=30, ha="right")
    for ax in axs:
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.04, 0.5))
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{machine}: {len(df)} recordings")
    return fig
