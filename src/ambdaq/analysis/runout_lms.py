"""The offline LMS's sample-by-sample recursion (Ro et al. eq. 9-10), compiled by numba.

Its own module so that the harmonic fit every analysis command uses does not load numba: the
recursion is sequential (each weight update needs the error it left), the one part of runout
identification that numpy cannot do in whole arrays.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, fastmath=True)
def lms_recursion(e: np.ndarray, s1v: np.ndarray, c1v: np.ndarray, k: np.ndarray, mu: float, w: np.ndarray,
                  out: np.ndarray) -> None:
    """Run the LMS over ``e`` (any unit) with the rotor angle's sine and cosine per sample;
    ``w`` (harmonic, 2) holds the weights and is updated in place, ``out`` gets the error."""
    nh = k.shape[0]
    kmax = 0
    for kk in k:
        kmax = max(kmax, kk)
    sk = np.empty(kmax + 1)
    ck = np.empty(kmax + 1)
    for t in range(e.shape[0]):
        s1 = s1v[t]
        c1 = c1v[t]
        sk[0], ck[0] = 0.0, 1.0
        for j in range(1, kmax + 1):  # sin/cos of j theta by angle addition
            sk[j] = sk[j - 1] * c1 + ck[j - 1] * s1
            ck[j] = ck[j - 1] * c1 - sk[j - 1] * s1
        rc = 0.0
        for j in range(nh):  # r_c with the previous weights, eq. 10
            rc += w[j, 0] * sk[k[j]] + w[j, 1] * ck[k[j]]
        err = e[t] - rc
        out[t] = err
        for j in range(nh):  # eq. 9
            w[j, 0] += mu * err * sk[k[j]]
            w[j, 1] += mu * err * ck[k[j]]
