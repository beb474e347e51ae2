"""The plant of a levitated rotor, measured in closed loop (issue 42, item 2).

A magnetic bearing cannot be opened: its plant P (controller output u, V, to the gap y, m) is
unstable on its own.  The test signal r is added at the sensor summing point (ISO 14839-3), so the
controller sees e = y - r and drives u = -C e; the gap carries the sensor noise and the unbalance
n, which the loop feeds back into u.  The *direct* estimate G_uy / G_uu is therefore biased: where
n dominates r it tends to -1/C, the inverse of the controller, not the plant (Pintelon & Schoukens,
System Identification, 2nd ed., section 13.2).  The estimator here is the *joint input-output*
one: both the gap and the controller's output are referred to the test signal, which nothing in
the loop is correlated with,

    H_ry = G_ry / G_rr,   H_ru = G_ru / G_rr,   P = H_RY H_RU^-1          (Pintelon & Schoukens eq. 13-23)

column j of H_RY and H_RU being the run that excited axis j.  It needs every axis of a coupled set
excited (one run each), and it is asymptotically unbiased whatever the noise, the feedback and
the controller, which it never needs to know (the *indirect* estimate from the sensitivity,
P = C^-1 (S^-1 - 1), needs C exactly and inherits every error in it).

The sensitivity S = -H_re (e = -S r) and the complementary sensitivity T = 1 - S are measured
alongside, per axis, as ISO 14839-3 asks.

Random errors: column j of both H_RY and H_RU comes from one run, and their errors share its
noise: the gap and the controller's output are one loop, so the noise that moves one moves the
other (through -C), and the two errors are strongly correlated.  To first order
dP = (dH_RY - P dH_RU) H_RU^-1, and row i of run j's part, dHy_ij - sum_l P_il dHu_lj = a_i^T d_j,
has the variance a_i^T Cov(d_j) a_i^*, with d_j the run's response errors over the gaps and the
outputs together and Cov(d_j) the H1 error covariance of that run
(:func:`~ambdaq.analysis.frf.h1_estimate`: the residuals' cross-spectral matrix over the input's
power).  Treating the two errors as independent instead misstates P's error by up to a factor
sqrt(2) either way (measured on the flexible rotor: its scatter 1.13-1.21 times the independent
statement).  Different runs' errors are independent, so their parts add in power through
|H_RU^-1|^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClosedLoopPlant:
    """The plant measured in closed loop, per frequency.

    Attributes
    ----------
    freq_hz : ndarray, shape (n,)
    response : ndarray of complex, shape (n, outputs, inputs)
        P[output, input], m per V.
    sigma : ndarray, shape (n, outputs, inputs)
        The standard deviation of each element's complex error, sqrt(E|dP|^2), m per V (its real
        and imaginary parts each sigma / sqrt(2)).
    coherence : ndarray, shape (n, outputs, inputs)
        P[i, k]: the smaller of the coherences of gap i's H1 and of output k's H1 in the run that
        excited axis k (what the element can be trusted by).
    """

    freq_hz: np.ndarray
    response: np.ndarray
    sigma: np.ndarray
    coherence: np.ndarray


def joint_input_output(h_ry: np.ndarray, h_ru: np.ndarray, coh_ry: np.ndarray, coh_ru: np.ndarray,
                       error: np.ndarray, freq_hz: np.ndarray) -> ClosedLoopPlant:
    """P = H_RY H_RU^-1 at each frequency, with its first-order random error.

    Parameters
    ----------
    h_ry, h_ru : ndarray of complex, shape (n, axes, axes)
        Gap (m) and controller output (V) per test signal (m), column j from the run that excited
        axis j.
    coh_ry, coh_ru : ndarray, shape (n, axes, axes)
        Their coherences.
    error : ndarray of complex, shape (axes, n, 2 axes, 2 axes)
        Per run j, the covariance of the errors of its column of H_RY and H_RU stacked (the gaps
        first, m^2/m^2 and V m/m^2 and V^2/m^2 in its blocks).
    freq_hz : ndarray, shape (n,)

    Raises
    ------
    ValueError
        Where H_RU is singular: a run that moved no controller output.
    """
    cond = np.linalg.cond(h_ru)
    if not np.all(np.isfinite(cond)) or np.any(cond > 1e12):
        raise ValueError("the controller's outputs do not respond to every test signal (singular at "
                         f"{freq_hz[np.argmax(np.where(np.isfinite(cond), cond, np.inf))]:g} Hz)")
    inv = np.linalg.inv(h_ru)
    p = h_ry @ inv
    k = p.shape[1]
    # a[n, i] = [e_i, -P_i,:]: row i of run j's error is a_i^T d_j
    a = np.concatenate([np.broadcast_to(np.eye(k), p.shape), -p], axis=2)
    spread = np.einsum("nia,jnab,nib->nij", a, error, a.conj()).real  # (n, outputs, runs)
    var = np.einsum("nij,njk->nik", np.maximum(spread, 0.0), np.abs(inv) ** 2)
    coh = np.minimum(coh_ry, np.diagonal(coh_ru, axis1=1, axis2=2)[:, None, :])
    return ClosedLoopPlant(freq_hz, p, np.sqrt(var), coh)
