"""Jeong et al.: the rigid rotor on two cone-shaped AMBs, five degrees of freedom (eq. 2-10).

Eight magnets, four per bearing, pull the rotor along their pole axes n_j, tilted by beta from the
radial plane: the upper bearing (at +l1 along the axial x from the centre of mass) pulls up and
out, the lower (at -l2) down and out.  Magnet j sits at p_j = (a_j, R_m e_j) with e_j = +y, -y,
+z, -z.  With the rotor's centre-of-mass coordinates q_g = (x, y, z, theta_y, theta_z), the rotor
point at p_j moves by u_j = J_j q_g (rigid-body kinematics, small angles), its gap closes by
c n_j . u_j (eq. 2-3, c the shape factor) and the magnet's pull F_j (eq. 3) acts on q_g through
J_j^T n_j (virtual work; eq. 5's right-hand sides).

Eq. 2 as printed leaves out the gap change the tilt makes through R_m sin(beta), although eq. 5
keeps the moment arm R_m sin(beta): that makes the paper's stiffness matrix K_g unsymmetric, which
a force field from a magnetic energy cannot be.  Here both come from the same J_j, so the
linearised stiffness is symmetric (tested).

Bearing coordinates q_b = (x, y1, y2, z1, z2) = T q_g with y1 = y + l1 theta_z,
y2 = y - l2 theta_z, z1 = z - l1 theta_y, z2 = z + l2 theta_y (eq. 7; the printed T's last two
rows are garbled: they are rederived here from eq. 2's y + l1 theta_z and z - l1 theta_y).  The
current-distribution law (eq. 9) maps the bearing-coordinate control currents
I_b = (i_x, i_y1, i_y2, i_z1, i_z2) to the eight coils.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..units import GRAVITY
from .cone import MU0

AXES = ("x", "y1", "y2", "z1", "z2")  # bearing coordinates
COILS = tuple(f"m{j}" for j in range(1, 9))

# eq. 9: i = D I_b, coils 1-4 upper (+y, -y, +z, -z), 5-8 lower
DISTRIBUTION = np.array([
    [1, 1, 0, 0, 0], [1, -1, 0, 0, 0], [1, 0, 0, 1, 0], [1, 0, 0, -1, 0],
    [-1, 0, 1, 0, 0], [-1, 0, -1, 0, 0], [-1, 0, 0, 0, 1], [-1, 0, 0, 0, -1],
], dtype=float)


@dataclass(frozen=True)
class ConeRotor:
    """Rotor and magnets (SI: m, kg, kg m^2, A, rad).

    Table 1 gives A, beta, g0, m and N; Table 3 the bias currents.  The paper gives no bearing
    positions, core radius or inertias: ``l1``, ``l2``, ``core_radius``, ``inertia_d``,
    ``inertia_p`` are assumed for a rotor inside the 130 mm x 130 mm joint, and the pole faces
    span +-15 deg about their axes (alpha_g 0.989, c 1).
    """

    area: float = 155e-6
    turns: int = 400
    gap: float = 0.5e-3
    beta: float = np.deg2rad(15.0)
    mass: float = 1.68
    inertia_d: float = 1.8e-3  # transverse, about the centre of mass (assumed)
    inertia_p: float = 7.6e-4  # polar (assumed)
    l1: float = 0.040  # centre of mass to the upper bearing (assumed)
    l2: float = 0.045  # to the lower bearing (assumed)
    core_radius: float = 0.030  # R_m (assumed)
    bias: tuple[float, float] = (1.03, 1.0)  # I01, I02 (Table 3)
    pole_half_angle: float = np.deg2rad(15.0)
    gravity: float = GRAVITY  # along -x (the joint's axis is vertical, eq. 5)

    @property
    def alpha_g(self) -> float:
        """Force factor (eq. 3) of poles spanning +-pole_half_angle."""
        t = self.pole_half_angle
        return float(np.sin(t) / t)

    @property
    def shape_factor(self) -> float:
        """c = cos of the pole's mean angle (eq. 3): 1 for symmetric poles."""
        return 1.0

    @property
    def force_constant(self) -> float:
        """k in F = k I^2 / g^2: alpha_g mu0 A N^2 / 4 (eq. 3), in N m^2/A^2."""
        return self.alpha_g * MU0 * self.area * self.turns**2 / 4

    @property
    def inductance(self) -> float:
        """Coil inductance at the nominal gap, L0 = mu0 N^2 A / (2 g0) (eq. 12), in H."""
        return MU0 * self.turns**2 * self.area / (2 * self.gap)

    def frames(self) -> tuple[np.ndarray, np.ndarray]:
        """Pole axes n (8, 3) and kinematic maps J (8, 3, 5): u_j = J_j q_g."""
        sb, cb = np.sin(self.beta), np.cos(self.beta)
        radial = np.array([[0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
        n = np.zeros((8, 3))
        J = np.zeros((8, 3, 5))
        for j in range(8):
            upper = j < 4
            e = radial[j % 4]
            n[j] = (sb if upper else -sb, cb * e[1], cb * e[2])
            p = np.array([self.l1 if upper else -self.l2, self.core_radius * e[1], self.core_radius * e[2]])
            # u = (x, y, z) + (0, theta_y, theta_z) x p
            J[j, :, :3] = np.eye(3)
            J[j, :, 3] = (p[2], 0.0, -p[0])  # d u / d theta_y
            J[j, :, 4] = (-p[1], p[0], 0.0)  # d u / d theta_z
        return n, J

    def transform(self) -> np.ndarray:
        """T of eq. 7: q_b = T q_g."""
        l1, l2 = self.l1, self.l2
        return np.array([[1, 0, 0, 0, 0], [0, 1, 0, 0, l1], [0, 1, 0, 0, -l2],
                         [0, 0, 1, -l1, 0], [0, 0, 1, l2, 0]], dtype=float)

    def mass_matrix(self) -> np.ndarray:
        """M_g = diag(m, m, m, I_d, I_d) (eq. 6)."""
        return np.diag([self.mass, self.mass, self.mass, self.inertia_d, self.inertia_d])

    def gyroscopic(self, speed: float) -> np.ndarray:
        """C_g of eq. 6 at spin ``speed`` (rad/s): I_p Omega couples theta_y and theta_z."""
        G = np.zeros((5, 5))
        G[3, 4], G[4, 3] = self.inertia_p * speed, -self.inertia_p * speed
        return G

    def gaps(self, q_g: np.ndarray) -> np.ndarray:
        """Air gaps (8,) at centre-of-mass displacement ``q_g`` (m, rad), in m (eq. 2-3)."""
        n, J = self.frames()
        return self.gap - self.shape_factor * np.einsum("ji,jik,k->j", n, J, np.asarray(q_g, dtype=float))

    def coil_bias(self) -> np.ndarray:
        """Bias currents of the eight coils (A)."""
        return np.repeat(np.asarray(self.bias, dtype=float), 4)

    def generalised_force(self, q_g: np.ndarray, currents: np.ndarray) -> np.ndarray:
        """Magnet forces and gravity on q_g (N, N m) at coil ``currents`` (8, A) (eq. 3, 5)."""
        n, J = self.frames()
        f = self.force_constant * np.asarray(currents) ** 2 / self.gaps(q_g) ** 2
        Q = np.einsum("j,ji,jik->k", f, n, J)
        Q[0] -= self.mass * self.gravity
        return Q

    def levitation_offset(self) -> float:
        """Axial control current i_x (A) that holds the rotor's weight at q = 0: through eq. 9 it
        adds to the upper coils and subtracts from the lower."""
        k, g0, sb = self.force_constant, self.gap, np.sin(self.beta)
        i1, i2 = self.bias
        # 4 k sin(beta) ((I01 + ix)^2 - (I02 - ix)^2) / g0^2 = m g, linear in ix
        return (self.mass * self.gravity * g0**2 / (4 * k * sb) - (i1**2 - i2**2)) / (2 * (i1 + i2))

    def operating_currents(self) -> np.ndarray:
        """Coil currents (8, A) at the levitated equilibrium q = 0."""
        return self.coil_bias() + DISTRIBUTION @ np.array([self.levitation_offset(), 0, 0, 0, 0])

    def linearise(self) -> tuple[np.ndarray, np.ndarray]:
        """K_g and K_ig of eq. 6 at the levitated equilibrium: M q'' + C q' + K_g q = K_ig i,
        K_g negative (the magnets' negative stiffness), K_ig (5, 8) in N/A."""
        n, J = self.frames()
        i0 = self.operating_currents()
        f0 = self.force_constant * i0**2 / self.gap**2
        a = np.einsum("ji,jik->jk", n, J)  # (8, 5): J_j^T n_j
        # dF/dq = 2 c F0 / g0 (n^T J), dF/di = 2 F0 / I0 (eq. 4)
        K = -np.einsum("j,jk,jl->kl", 2 * self.shape_factor * f0 / self.gap, a, a)
        Kig = (a * (2 * f0 / i0)[:, None]).T
        return K, Kig

    def bearing_model(self, speed: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Eq. 10: M_b q_b'' + C_b q_b' + K_b q_b = K_ib I_b in bearing coordinates, with the
        current-distribution law (eq. 9).  Returns M_b, C_b, K_b, K_ib."""
        Ti = np.linalg.inv(self.transform())
        K, Kig = self.linearise()
        return (Ti.T @ self.mass_matrix() @ Ti, Ti.T @ self.gyroscopic(speed) @ Ti, Ti.T @ K @ Ti,
                Ti.T @ Kig @ DISTRIBUTION)


def uncontrolled_eigenvalues(rotor: ConeRotor, speed: float = 0.0) -> np.ndarray:
    """Eigenvalues (1/s) of the levitated rotor with the control currents held at zero, sorted.

    Parameters
    ----------
    rotor : ConeRotor
        The rotor and magnets.
    speed : float
        Spin, in rad/s.
    """
    M, C, K, _ = rotor.bearing_model(speed)
    return _eig(M, C, K)


@dataclass(frozen=True)
class ConeControl:
    """Decoupled PD per bearing coordinate through current-feedback amplifiers (Jeong et al. eq. 11,
    15, 16): i = -Kc Ks (Kp + Kd s / (tau s + 1)) / (tau_c s + 1) q_b, force lagging by tau_e.

    ``kp``, ``kd`` per axis (x, y1, y2, z1, z2) as Table 3; ``ks`` in V/m, ``kc`` in A/V, time
    constants in s.
    """

    kp: tuple[float, ...] = (3.0, 3.0, 3.0, 3.0, 3.0)
    kd: tuple[float, ...] = (0.006, 0.004, 0.004, 0.004, 0.004)
    ks: float = 2000.0
    kc: float = 0.5
    tau: float = 8e-5
    tau_c: float = 6e-5
    tau_e: float = 4e-4


def controlled_eigenvalues(rotor: ConeRotor, control: ConeControl, speed: float = 0.0) -> np.ndarray:
    """Eigenvalues (1/s) of the full coupled 5-DOF closed loop with the decoupled PD, the current
    loop and the eddy-current lag (eq. 10, 11, 15, 16), sorted by imaginary part then real.

    Parameters
    ----------
    rotor : ConeRotor
        The rotor and magnets.
    control : ConeControl
        Gains and time constants.
    speed : float
        Spin, in rad/s.
    """
    M, C, K, Kib = rotor.bearing_model(speed)
    A, _, _ = closed_loop_state_space(M, C, K, Kib, control)
    return np.sort_complex(np.linalg.eigvals(A))


def closed_loop_state_space(M: np.ndarray, C: np.ndarray, K: np.ndarray, Kib: np.ndarray,
                            c: ConeControl) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """State space of the closed loop: state (q, q', d, i, f) per axis, with d the derivative
    filter, i the bearing-coordinate current and f the eddy-lagged current.  Returns A, the force
    input matrix (external generalised force on q_b) and the output matrix for q_b."""
    n = M.shape[0]
    Mi = np.linalg.inv(M)
    Z, I = np.zeros((n, n)), np.eye(n)
    kp, kd = np.diag(c.kp), np.diag(c.kd)
    # derivative filter state d: tau d' = -d + q'  ->  PD output Ks (Kp q + Kd d)... with d' = (q' - d)/tau
    # written on q directly: d' = (q - d) / tau gives s/(tau s + 1) q = (q - d) / tau
    blocks = [
        [Z, I, Z, Z, Z],
        [-Mi @ K, -Mi @ C, Z, Z, Mi @ Kib],
        [I / c.tau, Z, -I / c.tau, Z, Z],
        # tau_c i' = -i - Kc Ks (Kp q + Kd (q - d) / tau)
        [-(c.kc * c.ks / c.tau_c) * (kp + kd / c.tau), Z, (c.kc * c.ks / c.tau_c) * kd / c.tau, -I / c.tau_c, Z],
        [Z, Z, Z, I / c.tau_e, -I / c.tau_e],
    ]
    A = np.block(blocks)
    B = np.vstack([Z, Mi, Z, Z, Z])
    Cq = np.hstack([I, Z, Z, Z, Z])
    return A, B, Cq


def _eig(M: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    n = M.shape[0]
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ C]])
    return np.sort_complex(np.linalg.eigvals(A))
