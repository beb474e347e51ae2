"""Runout identification and offline LMS throughput (samples of one signal per second).

Baselines, measured in the same run on the same data: for the harmonic fit, the direct numpy
least squares on an explicit sin/cos basis (``np.linalg.lstsq``); for the LMS, the same update
(Ro et al. eq. 9-10) as a plain Python loop.  Targets: 20,000,000 samples/s each, LMS >= 50x the
plain loop.

    python benchmarks/bench_runout.py [--samples 20000000]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from ambdaq.analysis.runout import harmonic_fit, lms_offline

from _common import best_of, row

HARMONICS = (1, 2, 3, 4, 5, 6)


def lstsq_fit(x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    k = np.asarray(HARMONICS)
    kt = np.outer(theta, k)
    A = np.concatenate([np.sin(kt), np.cos(kt), np.ones((theta.shape[0], 1))], axis=1)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    return coef[:6] + 1j * coef[6:12]


def lms_python(x: list[float], theta: list[float], mu: float) -> list[list[float]]:
    w = [[0.0, 0.0] for _ in HARMONICS]
    for e, th in zip(x, theta):
        rc = sum(wk[0] * math.sin(k * th) + wk[1] * math.cos(k * th) for wk, k in zip(w, HARMONICS))
        err = e - rc
        for wk, k in zip(w, HARMONICS):
            wk[0] += mu * err * math.sin(k * th)
            wk[1] += mu * err * math.cos(k * th)
    return w


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=20_000_000)
    args = ap.parse_args()
    n = args.samples
    theta = np.arange(n) * (2 * np.pi * 500 / 10_000)  # 30,000 rpm at 10 kHz
    rng = np.random.default_rng(0)
    x = sum(1e-6 * (7 - k) * np.sin(k * theta + k) for k in HARMONICS) + 2e-7 * rng.standard_normal(n)
    harmonic_fit(x[:1000], theta[:1000])
    lms_offline(x[:1000], theta[:1000])
    fast_fit = n / best_of(lambda: harmonic_fit(x, theta))
    m = 2_000_000
    base_fit = m / best_of(lambda: lstsq_fit(x[:m], theta[:m]), repeat=2)
    fast_lms = n / best_of(lambda: lms_offline(x, theta, mu=0.002))
    p = 100_000
    xs, ts = x[:p].tolist(), theta[:p].tolist()
    base_lms = p / best_of(lambda: lms_python(xs, ts, 0.002), repeat=2)
    print(row("harmonic fit (one pass, numba)", fast_fit, "samples/s"))
    print(row("np.linalg.lstsq on a sin/cos basis (baseline)", base_fit, "samples/s"))
    print(f"ratio fit / lstsq: {fast_fit / base_fit:.1f}x (target >= 20,000,000 samples/s)")
    print(row("offline LMS (numba)", fast_lms, "samples/s"))
    print(row("same LMS, plain Python loop (baseline)", base_lms, "samples/s"))
    print(f"ratio LMS / plain Python: {fast_lms / base_lms:.0f}x (targets >= 20,000,000 samples/s, >= 50x)")


if __name__ == "__main__":
    main()
