"""Jeon et al.'s self-sensing figures (``ambdaq selfsense --plot``, Fig. 5-7)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..workflows.selfsense import CONVERGED_DEG
from . import pyplot


def draw_selfsense(results: list[dict]):
    """Jeon et al. Fig. 5-7 from :func:`~ambdaq.workflows.selfsense.analyse`'s results: (a) the encoder's and the estimate's
    angle (of the first file: with several, their sawtooths would lie on each other), (b) the
    angle error of every file, with several files the steady error against speed (Fig. 7), and
    with ``--sweep`` the convergence region: the final error against the initial one, beside the
    Lyapunov bound (eq. 18)."""
    plt = pyplot()
    several = len(results) > 1
    sweeps = [r for r in results if "sweep" in r]
    rows = 2 + several + bool(sweeps)
    fig, axes = plt.subplots(rows, 1, figsize=(9, 3.1 * rows), constrained_layout=True)
    first = results[0]
    t, true, est, _err, _ = first["_series"]
    axes[0].plot(t, np.rad2deg(true) % 360, lw=0.8, label="encoder")
    axes[0].plot(t, np.rad2deg(est) % 360, lw=0.8, ls="--", label="estimate")
    axes[0].set_ylabel("angle (deg)")
    axes[0].set_title("(a) measured and estimated rotor angle (Fig. 5a, 6a)"
                      + (f", {Path(first['file']).name}" if several else ""))
    axes[0].legend(fontsize=7, loc="upper right")
    for r in results:
        t, _true, _est, err, _ = r["_series"]
        axes[1].plot(t, err, lw=0.6, label=Path(r["file"]).name)
    axes[1].set_ylabel("error (deg)")
    axes[1].set_xlabel("time (s)")
    axes[1].axhline(CONVERGED_DEG, color="k", lw=0.5, ls=":")
    axes[1].axhline(-CONVERGED_DEG, color="k", lw=0.5, ls=":")
    axes[1].set_title("(b) angle error (Fig. 5b, 6b)")
    if several:
        axes[1].legend(fontsize=7, loc="upper right")
        steady = sorted((r["steady"]["speed_rpm"], r["steady"]["mean_deg"], r["steady"]["std_deg"])
                        for r in results if "steady" in r)
        ax = axes[2]
        if steady:
            sp, mean, std = map(np.array, zip(*steady))
            ax.plot(sp, mean, "o-", label="mean")
            ax.plot(sp, std, "s-", label="standard deviation")
            ax.legend(fontsize=7)
        ax.set(xlabel="speed (rpm)", ylabel="error (deg)", title="(c) steady-state angle error against speed (Fig. 7)")
    if sweeps:
        ax = axes[-1]
        sw = sweeps[0]["sweep"]
        lo, hi = sw["lyapunov_deg"]
        ax.axvspan(lo, hi, color="C2", alpha=0.15, label=f"Lyapunov bound (eq. 18): {lo:g} to {hi:g} deg")
        initial, final = np.array(sw["initial_deg"]), np.array(sw["final_deg"])
        ok = np.array(sw["converges"])
        ax.plot(initial[ok], final[ok], "o", color="C2", ms=4, label="converged (final |error| < 1 deg)")
        ax.plot(initial[~ok], final[~ok], "x", color="C3", ms=5, label="did not converge")
        ax.set(xlabel="initial error (deg)", ylabel="final error (deg)",
               title=f"({'d' if several else 'c'}) convergence region, {Path(sweeps[0]['file']).name}")
        ax.legend(fontsize=7, loc="best")
    for ax in axes:
        ax.grid(True, lw=0.3)
    return fig
