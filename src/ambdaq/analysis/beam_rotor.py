"""A flexible rotor as beam finite elements: shaft elements with consistent mass, rotary inertia
and gyroscopic matrices, rigid disks at nodes (Nelson & McVaugh, "The Dynamics of Rotor-Bearing
Systems Using Finite Elements", ASME J. Eng. Ind. 98, 1976: the Euler-Bernoulli element of their
eq. 7-13 without axial load or shear).

Coordinates: each node has a displacement and a slope in each of two planes, the x-z plane
(``x``, ``a = dx/dz``) and the y-z plane (``y``, ``b = dy/dz``); the rotor spins about z, from x
towards y.  The generalised coordinates are ordered plane by plane,

    q = [x_1, a_1, x_2, a_2, ..., x_n, a_n, y_1, b_1, ..., y_n, b_n],

so that the equations of motion at spin speed Omega are

    M q'' + Omega G q' + K q = f,

with M and K block-diagonal (the same block in each plane) and G skew-symmetric, coupling the
planes.  With the slopes as coordinates, a disk of polar and transverse inertia Ip, It adds
It a'' + Ip Omega b' to the ``a`` equation and It b'' - Ip Omega a' to the ``b`` one: a forward
whirl (x then y) is stiffened by the spin, a backward one softened.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eig, eigh

STEEL = (2.1e11, 7850.0)  # Young's modulus (Pa) and density (kg/m^3)


@dataclass(frozen=True)
class ShaftElement:
    """One shaft element: a hollow circular beam.

    Parameters
    ----------
    length : float
        m.
    outer_d, inner_d : float
        Outer and inner diameter, m (0: solid).
    """

    length: float
    outer_d: float
    inner_d: float = 0.0

    @property
    def area(self) -> float:
        """Cross-section, m^2."""
        return np.pi / 4.0 * (self.outer_d**2 - self.inner_d**2)

    @property
    def inertia(self) -> float:
        """Area moment of inertia about a diameter, m^4 (the polar one is twice it)."""
        return np.pi / 64.0 * (self.outer_d**4 - self.inner_d**4)


@dataclass(frozen=True)
class Disk:
    """A rigid disk at a node: mass (kg), polar and transverse moments of inertia (kg m^2)."""

    node: int
    mass: float
    ip: float
    it: float


def _pattern_m(length: float) -> np.ndarray:
    """The consistent translational mass pattern of a cubic beam element, times rho A L / 420."""
    L = length
    return np.array([[156, 22 * L, 54, -13 * L], [22 * L, 4 * L * L, 13 * L, -3 * L * L],
                     [54, 13 * L, 156, -22 * L], [-13 * L, -3 * L * L, -22 * L, 4 * L * L]])


def _pattern_r(length: float) -> np.ndarray:
    """The rotary-inertia pattern of a cubic beam element, times rho I / (30 L) (Nelson &
    McVaugh's M_R; the gyroscopic matrix is the same pattern with the polar inertia 2 I)."""
    L = length
    return np.array([[36, 3 * L, -36, 3 * L], [3 * L, 4 * L * L, -3 * L, -L * L],
                     [-36, -3 * L, 36, -3 * L], [3 * L, -L * L, -3 * L, 4 * L * L]])


def _pattern_k(length: float) -> np.ndarray:
    """The bending stiffness pattern of a cubic beam element, times E I / L^3."""
    L = length
    return np.array([[12, 6 * L, -12, 6 * L], [6 * L, 4 * L * L, -6 * L, 2 * L * L],
                     [-12, -6 * L, 12, -6 * L], [6 * L, 2 * L * L, -6 * L, 4 * L * L]])


@dataclass(frozen=True)
class BeamRotor:
    """A rotor of shaft elements in a row (node k joins element k-1 and element k) and disks.

    Parameters
    ----------
    elements : tuple of ShaftElement
        From the left end.
    disks : tuple of Disk
        At nodes (0 .. len(elements)).
    youngs_modulus : float
        Pa.
    density : float
        kg/m^3.
    rotary_inertia : bool
        Include the shaft's rotary inertia and gyroscopic moments (off: the Euler-Bernoulli beam of
        the textbooks' closed forms).
    """

    elements: tuple[ShaftElement, ...]
    disks: tuple[Disk, ...] = ()
    youngs_modulus: float = STEEL[0]
    density: float = STEEL[1]
    rotary_inertia: bool = True

    @property
    def nodes(self) -> int:
        return len(self.elements) + 1

    @property
    def node_z(self) -> np.ndarray:
        """Axial position of each node from the left end, m."""
        return np.concatenate([[0.0], np.cumsum([e.length for e in self.elements])])

    @property
    def mass(self) -> float:
        """Total mass, kg."""
        return sum(self.density * e.area * e.length for e in self.elements) + sum(d.mass for d in self.disks)

    def dof(self, node: int, plane: str, slope: bool = False) -> int:
        """The index in q of a node's displacement (or slope) in plane ``"x"`` or ``"y"``."""
        return (0 if plane == "x" else 2 * self.nodes) + 2 * node + (1 if slope else 0)

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M, G (per rad/s of spin) and K of the free rotor, each (4 n, 4 n) for n nodes."""
        n = 2 * self.nodes  # coordinates per plane
        Mp, Kp, Gp = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
        for k, e in enumerate(self.elements):
            s = slice(2 * k, 2 * k + 4)
            Mp[s, s] += self.density * e.area * e.length / 420.0 * _pattern_m(e.length)
            Kp[s, s] += self.youngs_modulus * e.inertia / e.length**3 * _pattern_k(e.length)
            if self.rotary_inertia:
                rot = self.density * e.inertia / (30.0 * e.length) * _pattern_r(e.length)
                Mp[s, s] += rot
                Gp[s, s] += 2.0 * rot  # the polar inertia is twice the diametral one
        for d in self.disks:
            Mp[2 * d.node, 2 * d.node] += d.mass
            Mp[2 * d.node + 1, 2 * d.node + 1] += d.it
            Gp[2 * d.node + 1, 2 * d.node + 1] += d.ip
        Z = np.zeros((n, n))
        M = np.block([[Mp, Z], [Z, Mp]])
        K = np.block([[Kp, Z], [Z, Kp]])
        # It a'' + Ip Omega b' (x-z plane), It b'' - Ip Omega a' (y-z plane): G skew-symmetric
        G = np.block([[Z, Gp], [-Gp, Z]])
        return M, G, K

    def free_modes(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The free-free rotor's lowest ``count`` modes of one plane at standstill, rigid-body
        modes first: natural frequencies (Hz, 0 for the rigid ones) and mode shapes (one column
        per mode over the plane's coordinates, mass-normalised)."""
        M, _G, K = self.matrices()
        n = 2 * self.nodes
        w2, shapes = eigh(K[:n, :n], M[:n, :n], subset_by_index=(0, count - 1))
        return np.sqrt(np.clip(w2, 0.0, None)) / (2 * np.pi), shapes

    def whirl_frequencies(self, omega: float, stiffness: dict[int, float]) -> tuple[np.ndarray, np.ndarray]:
        """Natural frequencies at spin ``omega`` (rad/s) on isotropic springs (N/m by node), split
        into forward and backward whirl: each mode's frequency (Hz, ascending) and its whirl
        (+1 forward, -1 backward) from the direction its largest node turns (x then y)."""
        M, G, K = self.matrices()
        K = K.copy()
        for node, k in stiffness.items():
            for plane in "xy":
                i = self.dof(node, plane)
                K[i, i] += k
        n = M.shape[0]
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -omega * np.linalg.solve(M, G)]])
        lam, vec = eig(A)
        keep = lam.imag > 1e-6
        lam, vec = lam[keep], vec[:n, keep]
        order = np.argsort(lam.imag)
        freqs, whirl = [], []
        for j in order:
            xs = vec[0 : 2 * self.nodes : 2, j]
            ys = vec[2 * self.nodes :: 2, j]
            big = int(np.argmax(np.abs(xs) + np.abs(ys)))
            # x = Re(X e^{i w t}), y = Re(Y e^{i w t}): forward (x towards y) where y lags x by 90 deg
            turn = np.imag(np.conj(xs[big]) * ys[big])
            freqs.append(lam[j].imag / (2 * np.pi))
            whirl.append(-1 if turn > 0 else 1)
        return np.array(freqs), np.array(whirl)
