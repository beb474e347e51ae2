"""The rigid rotor on its bearings in the frequency domain: how bearing forces move it.

For runout identification the rotor's own motion at the sensors is reconstructed from the coil
currents: at frequency w the linearised bearings push with F = Kx x + Ki i, so

    (-w^2 M + j w G - Kx) X = Ki I   ->   X = H(w) Ki I,

with M, G the mass and gyroscopic matrices in bearing coordinates (front_x, front_y, rear_x,
rear_y, axial; Ro et al. section 2.2 and Jeong et al. eq. 5-10), Kx the magnets' negative stiffness.
What the sensor shows beyond X is runout.

The one rigid-rotor model: the simulated spindle's state equations are built from
:meth:`RigidRotor.mass_gyro` too (:mod:`ambdaq.sim.rigs.spindle`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np



@dataclass(frozen=True)
class RigidRotor:
    """A rigid rotor on two radial bearings and a thrust bearing.

    Parameters
    ----------
    mass : float
        Rotor mass, in kg.
    jt, jp : float
        Transverse and polar moments of inertia, in kg m^2.
    a, b : float
        Centre of mass to the front and rear bearing, in m (sensors co-located).
    kx : tuple of 5 float
        Negative position stiffness per axis, in N/m.
    ki : tuple of 5 float
        Current gain per axis, in N/A.
    """

    mass: float
    jt: float
    jp: float
    a: float
    b: float
    kx: tuple[float, float, float, float, float]
    ki: tuple[float, float, float, float, float]

    @classmethod
    def from_metadata(cls, meta: dict[str, str]) -> "RigidRotor":
        """Build from ``rotor.*`` entries (as the simulated controller reports them)."""
        try:
            return cls(
                mass=float(meta["rotor.mass_kg"]),
                jt=float(meta["rotor.jt_kgm2"]),
                jp=float(meta["rotor.jp_kgm2"]),
                a=float(meta["rotor.a_m"]),
                b=float(meta["rotor.b_m"]),
                kx=tuple(float(v) for v in meta["rotor.kx_n_per_m"].split(",")),
                ki=tuple(float(v) for v in meta["rotor.ki_n_per_a"].split(",")),
            )
        except (KeyError, ValueError) as err:
            raise ValueError(f"rotor model incomplete or malformed ({err})") from None

    def metadata(self) -> dict[str, str]:
        """The ``rotor.*`` entries :meth:`from_metadata` reads (docs/coefficients.md)."""
        return {"rotor.mass_kg": repr(self.mass), "rotor.jt_kgm2": repr(self.jt), "rotor.jp_kgm2": repr(self.jp),
                "rotor.a_m": repr(self.a), "rotor.b_m": repr(self.b),
                "rotor.kx_n_per_m": ",".join(repr(k) for k in self.kx),
                "rotor.ki_n_per_a": ",".join(repr(k) for k in self.ki)}

    def mass_gyro(self, spin: float) -> tuple[np.ndarray, np.ndarray]:
        """Mass matrix (kg) and gyroscopic matrix (N s/m) in bearing coordinates at ``spin`` (rad/s)."""
        a, b = self.a, self.b
        # q_b = T q_c, q_c = [x, theta_y, y, theta_x]: x1 = x + a theta_y, x2 = x - b theta_y ...
        T = np.array([[1, a, 0, 0], [0, 0, 1, a], [1, -b, 0, 0], [0, 0, 1, -b]], dtype=float)
        Ti = np.linalg.inv(T)
        Mc = np.diag([self.mass, self.jt, self.mass, self.jt])
        Gc = np.zeros((4, 4))
        Gc[1, 3] = self.jp * spin
        Gc[3, 1] = -self.jp * spin
        M = np.zeros((5, 5))
        G = np.zeros((5, 5))
        M[:4, :4] = Ti.T @ Mc @ Ti
        G[:4, :4] = Ti.T @ Gc @ Ti
        M[4, 4] = self.mass
        return M, G

    def motion_from_currents(self, currents: np.ndarray, w: float, spin: float) -> np.ndarray:
        """Rotor displacement phasors (m) at the sensors from coil-current phasors (A), both (5,).

        Parameters
        ----------
        currents : ndarray of complex, shape (5,)
            Coil current phasors per axis at angular frequency ``w``, in A.
        w : float
            Angular frequency of the phasors, in rad/s.
        spin : float
            Rotor speed, in rad/s (gyroscopic coupling).
        """
        M, G = self.mass_gyro(spin)
        D = -(w**2) * M + 1j * w * G - np.diag(self.kx)
        return np.linalg.solve(D, np.asarray(self.ki) * np.asarray(currents))
