"""Per-frequency MFXLMS throughput (Kang & Jung eq. A-4 to A-9): instants (2 gaps, 2 accelerometers)
per second.

Baseline, measured in the same run on the same data: the same update (in-phase and quadrature
references, one normaliser) as a plain Python loop. Target: 10,000,000 samples/s for the whole
``mfxlms`` call (the quadrature references included).

    python benchmarks/bench_mfxlms.py [--samples 10000000]
"""

from __future__ import annotations

import argparse

import numpy as np

from ambdaq.analysis.mfxlms import mfxlms, quadrature

from _common import best_of, row

FS, F_HZ = 10_000.0, 40.0
PATH = np.array([[1.0, 0.1], [0.12, 0.9]]) * 1e-6 * np.exp(-0.3j)  # m/V, a secondary path at F_HZ


def mfxlms_python(y, d, dq, path, mu, period):
    w = [[[0.0, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]]
    power, lam = 0.0, 1.0 / period
    for k in range(len(y)):
        r = [[[(path[i][j].real * d[k][m] - path[i][j].imag * dq[k][m],
                -(path[i][j].imag * d[k][m] + path[i][j].real * dq[k][m])) for m in range(2)]
              for j in range(2)] for i in range(2)]
        power += lam * (sum(a * a + b * b for ri in r for rj in ri for a, b in rj) - power)
        e = [y[k][i] + sum(w[j][m][q] * r[i][j][m][q] for j in range(2) for m in range(2) for q in range(2))
             for i in range(2)]
        if k >= 2 * period:
            for j in range(2):
                for m in range(2):
                    for q in range(2):
                        w[j][m][q] -= mu * (e[0] * r[0][j][m][q] + e[1] * r[1][j][m][q]) / power
    return w


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10_000_000)
    args = ap.parse_args()
    n = args.samples
    rng = np.random.default_rng(0)
    t = np.arange(n) / FS
    d = np.stack([0.7 * np.sin(2 * np.pi * F_HZ * t + 0.4), np.sin(2 * np.pi * F_HZ * t)], axis=1)
    d += 0.005 * rng.standard_normal(d.shape)
    y = 1e-6 * np.stack([1.3 * np.sin(2 * np.pi * F_HZ * t + 0.1), 1.2 * np.sin(2 * np.pi * F_HZ * t - 0.2)], axis=1)
    mfxlms(y[:1000], d[:1000], PATH, F_HZ, FS)  # compile
    fast = n / best_of(lambda: mfxlms(y, d, PATH, F_HZ, FS))
    p = 50_000
    dq = quadrature(d[:p], F_HZ, FS)
    args_py = (y[:p].tolist(), d[:p].tolist(), dq.tolist(), PATH.tolist(), 0.01, FS / F_HZ)
    base = p / best_of(lambda: mfxlms_python(*args_py), repeat=2)
    print(row("MFXLMS per frequency (numba, quadrature included)", fast, "samples/s"))
    print(row("same update, plain Python loop (baseline)", base, "samples/s"))
    print(f"ratio: {fast / base:.0f}x (target >= 10,000,000 samples/s)")


if __name__ == "__main__":
    main()
