"""A machine that needs tuning (issue 42): a flexible rotor on two radial AMBs whose gap sensors
sit outboard of the bearings, with its stock controller, a PID per axis and no filters.

The rotor is beam finite elements (:mod:`ambdaq.analysis.beam_rotor`): a stepped steel shaft with
the motor's rotor in the middle, the bearings' laminated journals and an overhung impeller,
0.65 m long, 23.2 kg.  Its free-free modes are reduced to the two rigid-body modes and the first
``bending_modes`` bending modes per plane (394, 768, 1505, 2434 Hz ...), each bending mode with a
structural damping ratio; the gyroscopic matrix couples the planes in those coordinates and
splits each mode into a forward and a backward whirl as the rotor spins.  A bearing's force acts
at its journal's node (Kx x + Ki i, linearised about the bias); a sensor reads its own node, 40
mm outboard, where the bending modes move two to eight times more than at the bearing
(non-collocation).  The stock PID, tuned for the rigid rotor, still has gain above 1 kHz, and the
amplifier, the hold and the computation delay turn its phase there: at standstill the third
bending mode is barely damped (ISO 14839-3 zone D), and as the impeller's spin lifts the second
one's forward whirl from 793 Hz towards 1.2 kHz the loop goes unstable below the maximum speed
(tests/test_flexible_spindle.py).

The loop is discrete at the controller's rate, in the order its firmware runs (as
:mod:`ambdaq.machines.spindle_loop`): sample the gaps, run the PID, hold the output over the
period through the amplifier, the rotor and amplifiers stepped exactly (zero-order hold).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..analysis.beam_rotor import BeamRotor, Disk, ShaftElement
from ..analysis.sections import state_space
from ..units import RPM_TO_RAD_S
from .spindle import BearingAxis
from ..analysis.amb import zoh
from .spindle_loop import amplifier_continuous, derivative_filter

AXES = ("front_x", "front_y", "rear_x", "rear_y")
SAMPLE_RATE = 10_000.0  # Hz
MAX_RPM = 36_000.0

# (length m, outer diameter m) from the non-drive end: front sensor, front journal, shaft, motor,
# shaft, rear journal, rear sensor, the impeller's stub
ELEMENTS = ((0.04, 0.045), (0.04, 0.045), (0.06, 0.055), (0.08, 0.060), (0.08, 0.060), (0.08, 0.060),
            (0.08, 0.060), (0.06, 0.055), (0.04, 0.045), (0.04, 0.045), (0.05, 0.040))
FRONT_SENSOR, FRONT_BEARING, MOTOR, REAR_BEARING, REAR_SENSOR, IMPELLER = 0, 2, 5, 9, 10, 11
DISKS = (Disk(FRONT_BEARING, 1.2, 0.0009, 0.0007),  # the journal's laminations
         Disk(MOTOR, 6.0, 0.012, 0.020),  # the motor's rotor
         Disk(REAR_BEARING, 1.2, 0.0009, 0.0007),
         Disk(IMPELLER, 3.0, 0.03, 0.016))  # overhung: 280 mm across, its spin splits the bending modes


@dataclass(frozen=True)
class FlexibleSpindleParams:
    """The machine (SI).  The bearing axes use the spindle's front-bearing magnet and amplifier
    (Ro et al. Table 1) with a PID tuned for this rotor's rigid-body modes."""

    elements: tuple = ELEMENTS
    disks: tuple = DISKS
    front: BearingAxis = BearingAxis(273.0, 1.77e6, 2.1, 0.8, 2500.0, 0.8, 1.4, 2.0, 0.0012, 20.0)
    rear: BearingAxis = BearingAxis(273.0, 1.77e6, 2.1, 0.8, 2500.0, 0.8, 1.4, 2.0, 0.0012, 20.0)
    bearing_nodes: tuple[int, int] = (FRONT_BEARING, REAR_BEARING)
    sensor_nodes: tuple[int, int] = (FRONT_SENSOR, REAR_SENSOR)
    bending_modes: int = 6
    structural_damping: float = 0.005  # zeta of each bending mode (a built-up steel rotor)
    # mass unbalance per disk: (node, m e in kg m, angle rad): the motor's rotor 1 um of eccentricity,
    # the impeller 2 um at 120 deg (about ISO 21940-11 G2.5 at 36,000 rpm for the whole rotor)
    unbalance: tuple = ((MOTOR, 6.0e-6, 0.0), (IMPELLER, 6.0e-6, 2 * np.pi / 3))
    gap_noise: float = 0.1e-6  # m RMS at each sensor
    dac_range: float = 10.0  # V: the controller's output saturates here
    clearance: float = 150e-6  # m at the sensors: beyond it the protection trips the amplifiers
    sensor_gain: float = 1.0e4  # V/m
    derivative_filter: float = 15.0  # Nd
    sample_rate: float = SAMPLE_RATE

    @property
    def axes(self) -> tuple[BearingAxis, ...]:
        return (self.front, self.front, self.rear, self.rear)

    def rotor(self) -> BeamRotor:
        return BeamRotor(tuple(ShaftElement(length, d) for length, d in self.elements), self.disks)


FLEXIBLE = FlexibleSpindleParams()

LONG_ELEMENTS = tuple((length * 1.15, d) if FRONT_BEARING <= i < REAR_BEARING else (length, d)
                      for i, (length, d) in enumerate(ELEMENTS[:-1])) + ((0.07, 0.040),)
LONG_ROTOR = FlexibleSpindleParams(
    elements=LONG_ELEMENTS,
    disks=(Disk(FRONT_BEARING, 1.2, 0.0009, 0.0007), Disk(MOTOR, 7.0, 0.014, 0.024),
           Disk(REAR_BEARING, 1.2, 0.0009, 0.0007), Disk(IMPELLER, 3.8, 0.04, 0.021)))
"""Another machine of the kind (``--profile flexible-long``, ``--machine flexible-long``): the shaft
between the journals 15 % longer, a larger motor and a heavier impeller 70 mm out, on the same
bearings and stock PID. Its bending modes sit lower (301, 600, 1193, 1890 Hz free-free), the
stock controller is zone D at standstill (17.4 dB at 1.2 kHz) and stays stable to 36,000 rpm: a
second rotor the controller design must handle without anything tuned for it."""

FLEXIBLE_MACHINES: dict[str, tuple[FlexibleSpindleParams, float]] = {"flexible": (FLEXIBLE, MAX_RPM),
                                                                     "flexible-long": (LONG_ROTOR, MAX_RPM)}
"""The flexible rotors whose models the host side reads (``--machine NAME``): parameters and maximum
speed (rpm)."""


def flexible_machine(name: str) -> tuple[FlexibleSpindleParams, float]:
    """``FLEXIBLE_MACHINES[name]``, or BadInputError naming the ones there are."""
    from ..errors import BadInputError

    if name not in FLEXIBLE_MACHINES:
        raise BadInputError(f"no rotor model for machine {name!r} (there is: {', '.join(FLEXIBLE_MACHINES)})")
    return FLEXIBLE_MACHINES[name]


class FlexibleLoop:
    """The machine's loop at given PID gains: x[n+1] = M x + B r_c, e = C x - r_c, per radial axis
    (``AXES``), r_c the test-signal input at the sensor summing point (ISO 14839-3), m.

    Parameters
    ----------
    params : FlexibleSpindleParams
    gains : tuple of three tuples, optional
        P (V/V), I (1/s), D (s) per axis; default the machine's stock PID.
    sections : list of Section, or one such list per axis, optional
        The filter chain after each axis's PID, before its D/A (:mod:`ambdaq.analysis.sections`):
        one chain for every axis, or one per axis in ``AXES`` order; default none, the stock
        controller.
    """

    def __init__(self, params: FlexibleSpindleParams = FLEXIBLE, gains=None, sections=()) -> None:
        self.params = params
        sections = list(sections)
        per_axis = len(sections) == len(AXES) and all(isinstance(c, list) for c in sections)
        self.sections = [list(c) for c in sections] if per_axis else [sections] * len(AXES)
        self.h = 1.0 / params.sample_rate
        axes = params.axes
        self.gains = gains or (tuple(a.pid_p for a in axes), tuple(a.pid_i for a in axes), tuple(a.pid_d for a in axes))
        rotor = params.rotor()
        self.rotor = rotor
        freqs, shapes = rotor.free_modes(2 + params.bending_modes)
        self.free_hz = freqs
        M, G, _K = rotor.matrices()
        n = 2 * rotor.nodes
        self._phi = shapes  # (plane coordinates, modes), mass-normalised
        self._gyro = shapes.T @ G[:n, n:] @ shapes  # the x plane's modal rows driven by the y plane's
        w = 2 * np.pi * freqs
        zeta = np.where(freqs > 0, params.structural_damping, 0.0)
        self._stiff = np.diag(w**2)
        self._damp = np.diag(2 * zeta * w)
        # where each axis's force acts and its sensor reads, on the plane's modal coordinates
        self._at_bearing = np.array([shapes[2 * params.bearing_nodes[i // 2]] for i in range(len(AXES))])
        self._at_sensor = np.array([shapes[2 * params.sensor_nodes[i // 2]] for i in range(len(AXES))])
        self._steps: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def modes(self) -> int:
        """Modal coordinates per plane."""
        return self._phi.shape[1]

    def _continuous(self, rpm: float) -> tuple[np.ndarray, np.ndarray]:
        """Rotor (modal displacements and velocities of both planes) and amplifiers in continuous
        time at ``rpm``, with the controller's output (V per axis) as input."""
        m, p = self.modes, self.params
        omega = rpm * RPM_TO_RAD_S
        nr = 4 * m  # [eta_x, eta_y, eta_x', eta_y']
        na = 2 * len(AXES)
        A = np.zeros((nr + na, nr + na))
        Bu = np.zeros((nr + na, len(AXES)))
        K = np.kron(np.eye(2), self._stiff)
        D = np.kron(np.eye(2), self._damp) + omega * np.block([[np.zeros((m, m)), self._gyro], [-self._gyro, np.zeros((m, m))]])
        for i, ax in enumerate(p.axes):  # the magnets' negative stiffness at each bearing's node, in its plane
            plane = slice(0, m) if i % 2 == 0 else slice(m, 2 * m)
            K[plane, plane] -= ax.kx * np.outer(self._at_bearing[i], self._at_bearing[i])
        A[: 2 * m, 2 * m : nr] = np.eye(2 * m)
        A[2 * m : nr, : 2 * m] = -K
        A[2 * m : nr, 2 * m : nr] = -D
        for i, ax in enumerate(p.axes):
            Aa, Ba = amplifier_continuous(ax)
            s = slice(nr + 2 * i, nr + 2 * i + 2)
            A[s, s] = Aa
            Bu[s, i] = Ba[:, 0]
            rows = slice(2 * m, 3 * m) if i % 2 == 0 else slice(3 * m, 4 * m)
            A[rows, nr + 2 * i] = ax.ki * self._at_bearing[i]  # the coil current's force, ki i
        return A, Bu

    def plant(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rotor and amplifiers over one control period at ``rpm`` (rpm), zero-order hold:
        x[n+1] = Phi x[n] + Gam_u u[n] + Gam_f f[n], with u the controller's output per axis (V)
        and f the generalised (modal) forces of both planes, [x plane, y plane] (N per unit of
        mass-normalised mode shape), each held over the period."""
        A, Bu = self._continuous(rpm)
        m = self.modes
        Bf = np.zeros((A.shape[0], 2 * m))
        Bf[2 * m : 4 * m] = np.eye(2 * m)
        Phi, Gam = zoh(A, np.hstack([Bu, Bf]), self.h)
        return Phi, Gam[:, : len(AXES)].copy(), Gam[:, len(AXES) :].copy()

    def plant_poles(self, rpm: float) -> np.ndarray:
        """The open-loop poles of the rotor on its magnets with the amplifiers at ``rpm`` (rpm), in
        rad/s: what a model fitted to the plant should find (the rigid-body modes' unstable pairs,
        the bending modes, the amplifiers')."""
        return np.linalg.eigvals(self._continuous(rpm)[0])

    def plant_response(self, rpm: float, freq_hz: np.ndarray) -> np.ndarray:
        """The plant the controller sees at ``rpm`` (rpm), P(e^{j w h}) from its output (V) to the
        gaps (m) at ``freq_hz`` (Hz), shape (n, axes, axes): what ``plant identify`` measures."""
        phi, gam, _ = self.plant(rpm)
        cs = self.sensor_rows()
        eye = np.eye(phi.shape[0])
        return np.array([cs @ np.linalg.solve(np.exp(2j * np.pi * f * self.h) * eye - phi, gam) for f in freq_hz])

    def unbalance_modal(self) -> np.ndarray:
        """The rotor's unbalance on its modal coordinates: complex, one value per mode, so that the
        x plane's modal force is Re(U e^{j theta}) Omega^2 and the y plane's Im(U e^{j theta}) Omega^2
        (theta the rotor angle, Omega its speed in rad/s)."""
        return sum(self._phi[2 * node] * me * np.exp(1j * angle) for node, me, angle in self.params.unbalance)

    def sensor_rows(self) -> np.ndarray:
        """The gap each axis's sensor reads, as rows over the rotor-and-amplifier state, m."""
        m = self.modes
        C = np.zeros((len(AXES), 4 * m + 2 * len(AXES)))
        for i in range(len(AXES)):
            plane = slice(0, m) if i % 2 == 0 else slice(m, 2 * m)
            C[i, plane] = self._at_sensor[i]
        return C

    def matrices(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M, B and C at ``rpm`` (rpm)."""
        return self.closed(rpm, self.gains, self.sections)

    def closed(self, rpm: float, gains, sections) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M, B and C at ``rpm`` (rpm) with another controller: ``gains`` (P, I, D per axis) and
        ``sections`` (one chain per axis); the rotor's step over a period is computed once per speed."""
        if rpm not in self._steps:
            self._steps[rpm] = zoh(*self._continuous(rpm), self.h)
        Phi, Gam = self._steps[rpm]
        p = self.params
        return close_loop(Phi, Gam, self.sensor_rows(), gains, sections, sensor_gain=p.sensor_gain,
                          nd=p.derivative_filter, h=self.h)

def close_loop(Phi: np.ndarray, Gam: np.ndarray, Cs: np.ndarray, gains, sections, *, sensor_gain: float, nd: float,
               h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A discrete plant closed by the firmware's controller, per axis in the order it runs (sample
    the gap, PID, the chain of sections, hold): x[n+1] = M x + B r_c, e = C x - r_c.

    Parameters
    ----------
    Phi, Gam : ndarray
        The plant over one period, x[n+1] = Phi x + Gam u, u the controller's output per axis (V).
    Cs : ndarray, shape (axes, states)
        The gap each axis's sensor reads, m.
    gains : tuple of three sequences
        P (V/V), I (1/s), D (s) per axis.
    sections : list of lists of Section
        Each axis's chain (:mod:`ambdaq.analysis.sections`).
    sensor_gain : float
        V/m.
    nd : float
        The derivative filter's Nd.
    h : float
        Control period, s.
    """
    ks = sensor_gain
    P, I, D = (np.asarray(g, dtype=float) for g in gains)
    ad, bd = derivative_filter(P, D, nd, h)
    ci = I * h * 0.5
    nra, na = Phi.shape[0], Cs.shape[0]
    chains = [state_space(c) for c in sections]  # (Af, Bf, Cf, Df) per axis
    offsets = np.concatenate(([0], np.cumsum([c[0].shape[0] for c in chains])))
    n = nra + 3 * na + int(offsets[-1])
    M, B = np.zeros((n, n)), np.zeros((n, na))
    U, Ur = np.zeros((na, n)), np.zeros(na)
    for a in range(na):
        integ, deriv, prev = nra + 3 * a, nra + 3 * a + 1, nra + 3 * a + 2
        ev = np.zeros(n)
        ev[:nra] = ks * Cs[a]  # the error voltage Ks (gap - r_c)
        M[integ] = ci[a] * ev
        M[integ, integ] += 1.0
        M[integ, prev] += ci[a]
        B[integ, a] = -ci[a] * ks
        M[deriv] = bd[a] * ev
        M[deriv, deriv] += ad[a]
        M[deriv, prev] -= bd[a]
        B[deriv, a] = -bd[a] * ks
        M[prev] = ev
        B[prev, a] = -ks
        U[a] = -(P[a] * ev + M[integ] + M[deriv])  # u = -(P ev + integral + derivative), eq. 3
        Ur[a] = P[a] * ks - B[integ, a] - B[deriv, a]
    # each axis's filter chain: s' = Af s + Bf u, and its D/A gets y = Cf s + Df u
    Y, Yr = np.zeros((na, n)), np.zeros(na)
    for a, (Af, Bf, Cf, Df) in enumerate(chains):
        f = slice(nra + 3 * na + offsets[a], nra + 3 * na + offsets[a + 1])
        M[f, f] = Af
        M[f] += np.outer(Bf, U[a])
        B[f, a] = Bf * Ur[a]
        Y[a] = Df * U[a]
        Y[a, f] += Cf
        Yr[a] = Df * Ur[a]
    M[:nra, :nra] = Phi
    M[:nra] += Gam @ Y
    B[:nra] = Gam * Yr[None, :]
    C = np.zeros((na, n))
    C[:, :nra] = Cs
    return M, B, C
