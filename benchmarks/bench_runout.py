"""Runout identification and offline LMS throughput (samples of one signal per second), and what
one command's harmonic fit costs in a fresh process.

Baselines, measured in the same run on the same data: for the harmonic fit, the direct numpy
least squares on an explicit sin/cos basis (``np.linalg.lstsq``) and the one-pass numba kernel
ambdaq used before (here, not in the package: warm, and in a fresh process where numba loads it
from its cache); for the LMS, the same update (Ro et al. eq. 9-10) as a plain Python loop.
Targets: the fit >= 4x ``lstsq`` and a fresh process's fit of a 10 s recording (5 axes) faster than
numba's; the LMS 20,000,000 samples/s and >= 50x the plain loop.

    python benchmarks/bench_runout.py [--samples 20000000]
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
from numba import njit

from ambdaq.analysis.runout import harmonic_fit, lms_offline

from _common import best_of, row

HARMONICS = (1, 2, 3, 4, 5, 6)


def lstsq_fit(x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    k = np.asarray(HARMONICS)
    kt = np.outer(theta, k)
    A = np.concatenate([np.sin(kt), np.cos(kt), np.ones((theta.shape[0], 1))], axis=1)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    return coef[:6] + 1j * coef[6:12]


@njit(cache=True, nogil=True, fastmath=True)
def numba_sums(s1, c1, x, kmax, k):
    """The one-pass kernel ambdaq's fit was before (baseline): the sums of sin/cos m theta, m up to
    2 kmax, and A^T x, by angle addition, sample by sample."""
    mmax = 2 * kmax
    ssum, csum = np.zeros(mmax + 1), np.zeros(mmax + 1)
    nh = k.shape[0]
    atx = np.zeros((2 * nh + 1, x.shape[1]))
    sk, ck = np.empty(mmax + 1), np.empty(mmax + 1)
    for t in range(s1.shape[0]):
        sk[0], ck[0] = 0.0, 1.0
        for j in range(1, mmax + 1):
            sk[j] = sk[j - 1] * c1[t] + ck[j - 1] * s1[t]
            ck[j] = ck[j - 1] * c1[t] - sk[j - 1] * s1[t]
        for j in range(mmax + 1):
            ssum[j] += sk[j]
            csum[j] += ck[j]
        for c in range(x.shape[1]):
            for j in range(nh):
                atx[j, c] += sk[k[j]] * x[t, c]
                atx[nh + j, c] += ck[k[j]] * x[t, c]
            atx[2 * nh, c] += x[t, c]
    return ssum, csum, atx


def numba_fit(x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    k = np.arange(1, 9)  # the orders harmonic_fit fits (GUARD_ORDERS)
    x2 = np.ascontiguousarray(x.reshape(x.shape[0], -1))
    return numba_sums(np.sin(theta), np.cos(theta), x2, 8, k)


COLD = """import sys, time
import numpy as np
t0 = time.perf_counter()
th = np.arange(100_000) * (2 * np.pi * 500 / 10_000)
x = np.sin(np.outer(th, np.ones(5)))
if sys.argv[1] == "ambdaq":
    from ambdaq.analysis.runout import harmonic_fit
    harmonic_fit(x, th)
else:
    sys.path.insert(0, sys.argv[2])
    from bench_runout import numba_fit
    numba_fit(x, th)
print(time.perf_counter() - t0)
"""


def cold(which: str) -> float:
    """Seconds a fresh process takes to import the fit and fit 100,000 samples x 5 axes."""
    here = str(Path(__file__).parent)
    return min(float(subprocess.run([sys.executable, "-c", COLD, which, here], capture_output=True, text=True,
                                    check=True).stdout) for _ in range(3))


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
    numba_fit(x[:1000], theta[:1000])  # compiled (or loaded from its cache) before it is timed
    kernel_fit = n / best_of(lambda: numba_fit(x, theta))
    cold_fit, cold_numba = cold("ambdaq"), cold("numba")
    m = 2_000_000
    base_fit = m / best_of(lambda: lstsq_fit(x[:m], theta[:m]), repeat=2)
    fast_lms = n / best_of(lambda: lms_offline(x, theta, mu=0.002))
    p = 100_000
    xs, ts = x[:p].tolist(), theta[:p].tolist()
    base_lms = p / best_of(lambda: lms_python(xs, ts, 0.002), repeat=2)
    print(row("harmonic fit (numpy, blocks of samples)", fast_fit, "samples/s"))
    print(row("one-pass numba kernel, warm (baseline)", kernel_fit, "samples/s"))
    print(row("np.linalg.lstsq on a sin/cos basis (baseline)", base_fit, "samples/s"))
    print(f"ratio fit / lstsq: {fast_fit / base_fit:.1f}x (target >= 4x)")
    print(f"fresh process, 100,000 samples x 5 axes: {cold_fit:.3f} s, numba's kernel {cold_numba:.3f} s "
          f"(ratio {cold_numba / cold_fit:.1f}x; target > 1)")
    print(row("offline LMS (numba)", fast_lms, "samples/s"))
    print(row("same LMS, plain Python loop (baseline)", base_lms, "samples/s"))
    print(f"ratio LMS / plain Python: {fast_lms / base_lms:.0f}x (targets >= 20,000,000 samples/s, >= 50x)")


if __name__ == "__main__":
    main()
