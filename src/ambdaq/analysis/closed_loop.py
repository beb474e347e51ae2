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
|H_RU^-1|^2.  Each run's noise reaches a whole row of P through H_RU^-1, so the elements' errors
are correlated (on the flexible rotor at standstill, 0.1-0.8 between the elements of one plane):
the full covariance is kept, and a model fitted to several elements at once states its
parameters' covariance with it (:func:`ambdaq.analysis.plant_model.fit`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .frf import interpolate_response, window_kernel


@dataclass(frozen=True)
class ClosedLoopPlant:
    """The plant measured in closed loop, per frequency.

    Attributes
    ----------
    freq_hz : ndarray, shape (n,)
    response : ndarray of complex, shape (n, outputs, inputs)
        P[output, input], m per V.
    covariance : ndarray of complex, shape (n, outputs, inputs, outputs, inputs)
        The covariance of the elements' complex errors, E[dP[i, k] dP[c, l]^*], m^2 per V^2: one
        run's noise reaches every element of P through H_RU^-1, so the elements' errors are
        correlated (the module docstring); each error is circular (its real and imaginary parts
        each carry half its variance, uncorrelated).
    coherence : ndarray, shape (n, outputs, inputs)
        P[i, k]: the smaller of the coherences of gap i's H1 and of output k's H1 in the run that
        excited axis k (what the element can be trusted by).
    controller_response : ndarray of complex, shape (n, inputs, inputs)
        H_RU, the controller's outputs (V) per test signal (m), column j from the run that excited
        axis j: with P it gives the loop's other responses (T = P H_RU, S = 1 - T, the controller
        C = H_RU S^-1), which the window's leakage acts on.
    """

    freq_hz: np.ndarray
    response: np.ndarray
    covariance: np.ndarray
    coherence: np.ndarray
    controller_response: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        """The standard deviation of each element's complex error, sqrt(E|dP|^2), m per V, shape
        (n, outputs, inputs) (its real and imaginary parts each sigma / sqrt(2))."""
        n, k, m = self.response.shape
        var = self.covariance.reshape(n, k * m, k * m).diagonal(axis1=1, axis2=2).real
        return np.sqrt(np.maximum(var, 0.0)).reshape(n, k, m)

    def subset(self, idx: list[int]) -> "ClosedLoopPlant":
        """The elements among the axes ``idx`` (outputs and inputs alike) with their covariance."""
        i = np.asarray(idx)
        cov = self.covariance[:, i][:, :, i][:, :, :, i][:, :, :, :, i]
        return ClosedLoopPlant(self.freq_hz, self.response[:, i][:, :, i], cov, self.coherence[:, i][:, :, i],
                               self.controller_response[:, i][:, :, i])


def joint_input_output(h_ry: np.ndarray, h_ru: np.ndarray, coh_ry: np.ndarray, coh_ru: np.ndarray,
                       error: np.ndarray, freq_hz: np.ndarray) -> ClosedLoopPlant:
    """P = H_RY H_RU^-1 at each frequency, with the first-order covariance of its random error.

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
    # run j's row errors' covariance, Cov(e_ij, e_cj) = a_i^T Cov(d_j) a_c^*, then through H_RU^-1:
    # Cov(dP_ik, dP_cl) = sum_j Cov(e_ij, e_cj) inv_jk inv_jl^* (the runs' noises independent)
    rows = np.einsum("nia,jnab,ncb->njic", a, error, a.conj())
    cov = np.einsum("njic,njk,njl->nikcl", rows, inv, inv.conj())
    coh = np.minimum(coh_ry, np.diagonal(coh_ru, axis1=1, axis2=2)[:, None, :])
    return ClosedLoopPlant(freq_hz, p, cov, coh, h_ru)


def window_bias(plant: ClosedLoopPlant, model: Callable[[np.ndarray], np.ndarray], fs: float) -> np.ndarray:
    """What the estimate's window does to a plant ``model`` seen through this loop: the measured P
    minus the model's, to add to the model before comparing it with the measurement (or to take
    from the measurement).

    The window averages the responses the estimator divides, H_RY = T = PC (1 + PC)^-1 and
    H_RU = C (1 + PC)^-1, over its kernel (:func:`~ambdaq.analysis.frf.window_kernel`), not P:
    at a lightly damped bending mode, H_RU has a notch as narrow as the mode, and the averaged
    ratio is a broader, shifted resonance (its damping high, its frequency low by tens of ppm at
    2.5 Hz steps on the flexible rotor: several of the noise's deviations over 10 s).  The
    controller C = H_RU (1 - P H_RU)^-1 is taken from the measurement at each frequency and
    interpolated between them (a controller varies slowly against the frequency step).

    Parameters
    ----------
    plant : ClosedLoopPlant
        The measurement (its frequencies and H_RU).
    model : callable
        Frequencies (Hz, shape (m,)) -> the model's P, shape (m, outputs, inputs), m/V.
    fs : float
        The recordings' sample rate, Hz.

    Returns
    -------
    ndarray of complex, shape (n, outputs, inputs)
        E[P measured] - P model at ``plant.freq_hz``, m/V.
    """
    f = plant.freq_hz
    offsets, weights = window_kernel(float(f[1] - f[0]), fs)
    k = plant.response.shape[1]
    eye = np.eye(k)
    h_ru = plant.controller_response
    c = h_ru @ np.linalg.inv(eye - plant.response @ h_ru)
    fine = (f[:, None] + offsets[None, :]).ravel()
    c_fine = interpolate_response(f, c, fine)
    pc = model(fine) @ c_fine
    closed = np.linalg.inv(eye + pc)
    shape = (f.size, offsets.size, k, k)
    t = np.einsum("m,nmij->nij", weights, (closed @ pc).reshape(shape))  # (1 + PC)^-1 PC = PC (1 + PC)^-1
    u = np.einsum("m,nmij->nij", weights, (c_fine @ closed).reshape(shape))
    return t @ np.linalg.inv(u) - model(f)

