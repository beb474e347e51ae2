"""Natural frequencies and damping ratios from impact tests.

Each hammer strike is found on the force channel; the response that follows, once the strike is
over, is a free decay: a sum of damped modes y[k] = sum_i c_i z_i^k, y one or several sensors.
The eigensystem realisation algorithm (ERA; Juang and Pappa, J. Guidance 1985) finds the z_i from
the block Hankel matrices of those decays: H0 = U S V^T truncated to the model order,
A = S^-1/2 U^T H1 V S^-1/2, z = eig(A), s = ln(z) fs.  The decays of every strike sit side by side
in the Hankel matrices, so strikes of different strength need no scaling; several sensors (block
rows) separate modes that one sensor sees mixed.  Each mode's share of the response comes from a
least-squares fit of the c_i per sensor; the mode with the largest share is the dominant one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mode:
    """One identified mode: natural frequency (Hz), damping ratio, RMS share of the decay (signal
    units), and the pole (1/s)."""

    freq_hz: float
    zeta: float
    amplitude: float
    pole: complex


def strikes(force: np.ndarray, rate: float, *, threshold: float | None = None) -> list[tuple[int, int]]:
    """Hammer strikes as (first, last) sample index of each pulse.

    Parameters
    ----------
    force : ndarray
        Hammer force, in N.
    rate : float
        Sample rate, in Hz.
    threshold : float, optional
        Force that marks a strike, in N; default a fifth of the largest force, and at least eight
        times the load cell's noise (its median absolute deviation as a standard deviation).
    """
    f = np.asarray(force, dtype=float)
    if threshold is None and f.size:
        noise = 1.4826 * float(np.median(np.abs(f - np.median(f))))
        threshold = max(0.2 * float(np.max(np.abs(f))), 8.0 * noise)
    on = np.abs(f) > threshold
    if not f.size or threshold <= 0 or not on.any():
        return []
    edges = np.diff(on.astype(np.int8), prepend=0, append=0)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    # pulses closer than 5 ms are one strike (a bounce)
    out: list[tuple[int, int]] = []
    for a, b in zip(starts, ends):
        if out and a - out[-1][1] < 0.005 * rate:
            out[-1] = (out[-1][0], int(b))
        else:
            out.append((int(a), int(b)))
    return out


def free_decays(response: np.ndarray, force: np.ndarray, rate: float, *, window_s: float = 0.05,
                skip_s: float = 0.002) -> list[np.ndarray]:
    """The free decay after each strike, less the level just before it.

    Parameters
    ----------
    response : ndarray, shape (n,) or (n, p)
        Response of one or ``p`` sensors (any unit).
    force : ndarray
        Hammer force at the same instants, in N.
    rate : float
        Sample rate, in Hz.
    window_s : float
        Decay length kept, in s.
    skip_s : float
        Time skipped after the strike ends, in s: the fast poles (amplifier, eddy currents) die
        out in it.
    """
    y = np.asarray(response, dtype=float)
    y = y[:, None] if y.ndim == 1 else y
    n, skip, pre = int(round(window_s * rate)), int(round(skip_s * rate)), int(round(0.01 * rate))
    out = []
    hits = strikes(force, rate)
    for k, (a, b) in enumerate(hits):
        start = b + 1 + skip
        stop = min(start + n, hits[k + 1][0] if k + 1 < len(hits) else y.shape[0])
        if a - pre < 0 or stop - start < n // 2:
            continue
        out.append(y[start:stop] - np.mean(y[a - pre:a], axis=0))
    return out


def era(decays: list[np.ndarray], order: int, rate: float) -> np.ndarray:
    """Continuous-time poles (1/s) of the decays by the eigensystem realisation algorithm.

    Parameters
    ----------
    decays : list of ndarray, shape (n_k, p)
        Free decays of ``p`` sensors, sampled at ``rate``.
    order : int
        Model order (number of poles).
    rate : float
        Sample rate, in Hz.
    """
    rows = max(order * 4, min(len(d) for d in decays) // 3)
    H0, H1 = [], []
    for d in decays:
        cols, p = d.shape[0] - rows - 1, d.shape[1]
        idx = np.arange(rows)[:, None] + np.arange(cols)[None, :]
        H0.append(d[idx].transpose(0, 2, 1).reshape(rows * p, cols))  # block row i: the p sensors at lag i
        H1.append(d[idx + 1].transpose(0, 2, 1).reshape(rows * p, cols))
    U, S, Vt = np.linalg.svd(np.hstack(H0), full_matrices=False)
    U, S, Vt = U[:, :order], S[:order], Vt[:order]
    Sr = 1.0 / np.sqrt(S)
    A = (Sr[:, None] * U.T) @ np.hstack(H1) @ (Vt.T * Sr[None, :])
    return np.log(np.linalg.eigvals(A).astype(complex)) * rate


def modes(decays: list[np.ndarray], rate: float, *, order: int = 6) -> list[Mode]:
    """Damped modes of the decays, largest share first (real poles are left out).

    Parameters
    ----------
    decays : list of ndarray
        Free decays (:func:`free_decays`).
    rate : float
        Sample rate, in Hz.
    order : int
        ERA model order.
    """
    if not decays:
        return []
    poles = era(decays, order, rate)
    k = np.arange(max(d.shape[0] for d in decays))
    basis = np.exp(np.outer(k / rate, poles))
    share = np.zeros(poles.shape[0])
    for d in decays:
        c, *_ = np.linalg.lstsq(basis[: d.shape[0]], d.astype(complex), rcond=None)  # (poles, p)
        share += np.sum(np.abs(c) ** 2, axis=1) * np.mean(np.abs(basis[: d.shape[0]]) ** 2, axis=0)
    share = np.sqrt(share / len(decays))
    out = [Mode(float(abs(p) / (2 * np.pi)), float(-p.real / abs(p)), float(2 * a), complex(p))
           for p, a in zip(poles, share) if p.imag > 0 and p.real < 0]
    return sorted(out, key=lambda m: -m.amplitude)


def stable_modes(decays: list[np.ndarray], rate: float, *, max_order: int = 12) -> tuple[list[Mode], int]:
    """:func:`modes` at the lowest order whose dominant mode the next order confirms (a
    stabilisation check: frequency within 0.2 %, damping within 1 %).

    Parameters
    ----------
    decays, rate
        As for :func:`modes`.
    max_order : int
        Highest ERA order tried.

    Returns
    -------
    modes : list of Mode
        Largest share first; empty when no order is confirmed.
    order : int
        The order used (0 when none).
    """
    previous: list[Mode] = []
    for order in range(2, max_order + 3, 2):
        found = modes(decays, rate, order=order)
        if previous and found:
            a, b = previous[0], found[0]
            if abs(a.freq_hz - b.freq_hz) <= 0.002 * b.freq_hz and abs(a.zeta - b.zeta) <= 0.01 * b.zeta:
                return previous, order - 2
        previous = found
    return [], 0
