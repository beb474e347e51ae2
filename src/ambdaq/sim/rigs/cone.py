"""Jeong et al.'s rig: a rotor on two cone-shaped AMBs (the ``cone`` profile).

The rotor is :class:`~ambdaq.analysis.cone_rotor.ConeRotor`: five rigid-body degrees of freedom
with gyroscopic coupling, eight magnets with the nonlinear force law F = k i_e^2 / g^2 (eq. 3) on
gaps that follow the rotor (eq. 2), gravity along the axis, and touchdown bearings with a
clearance of half the air gap: round at each radial bearing (the orbit's radius stops at the
clearance: a contact force along the normal, with damping; no friction, as if the bearing's inner
race turned with the journal at once, so this rig's drops do not whip), an axial stop on x.
The controller is the paper's analogue one, integrated with the rotor: per bearing coordinate
(x, y1, y2, z1, z2) a PD with filtered derivative on the gap-sensor signal (eq. 11), distributed to the coils by eq. 9, each coil driven by a current-feedback
amplifier with a 25 V supply (eq. 13-15: below the limit a first-order current loop of gain
Kc and time constant tau_c; at the limit the coil's own L/R), the force lagging the current by the
eddy-current time constant tau_e (eq. 16).  The rotor's weight is carried by a constant axial
control current (:meth:`ConeRotor.levitation_offset`).

Everything runs in continuous time with ``SUBSTEPS`` steps per 10 kHz sample: first-order lags
are advanced exactly over a step, the rotor by semi-implicit Euler.  An instrumented hammer
(``/amb/hammer``) strikes the rotor at one bearing coordinate: a half-sine pulse.  The run starts
levitated, or with ``start="touchdown"`` at rest on the touchdown bearings with the amplifiers
just enabled (Jeong et al. Fig. 7a and 8).  A mass unbalance per balancing plane (one at each
bearing, :data:`~ambdaq.machines.cone.BALANCE_PLANES`) and trial or correction masses on them
(issue 43) push with U Omega^2 along the rotor angle.  :meth:`ConeRig.modes` gives the simulator's own
linearisation, the ground truth for ``ambdaq identify modal``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ...analysis.cone_rotor import AXES, COILS, DISTRIBUTION
from ...errors import BadInputError
from ...machines.balance_masses import BalanceMass, plane_unbalance
from ...machines.cone import BALANCE_PLANES, CONE, ConeParams
from ...drivers.signals import SampleBlock, SignalGroup
from ..profiles import Profile
from .base import Rig, balancing_truth
from .drop import Drop
from ...speed import RPM_TO_RAD_S, SpeedProfile

SUBSTEPS = 50  # 2 us steps: the kernel's modes within 0.2% (frequency) and 2.5% (damping) of the continuous model
N_STATE = 31  # q_g (5), v_g (5), derivative filters (5), coil currents (8), eddy-lagged currents (8)
IMPACT_S = 0.5e-3  # hammer pulse length
TOUCHDOWN_START_UM = (-250.0, -200.0, -120.0, 110.0, -80.0)  # q_b at rest (Jeong et al. Fig. 8's shape, in the clearance)
SETTLE_S = 0.1
"""After its unbalance changes, the loop runs this long unrecorded (:meth:`ConeRig.settle`): its
slowest radial mode decays in a few ms, the axial one (57 Hz, zeta 0.3) in about 30 ms."""




@dataclass(frozen=True)
class Impact:
    """Hammer strikes: a half-sine of ``peak`` N on bearing coordinate ``axis`` (0..4), lasting
    IMPACT_S, first at ``first_s`` and then every ``every_s`` s."""

    axis: int
    peak: float
    every_s: float = 0.5
    first_s: float = 0.2

    @classmethod
    def parse(cls, spec: str) -> "Impact":
        """``AXIS:PEAK_N[:EVERY_S]``, AXIS one of x, y1, y2, z1, z2."""
        parts = spec.split(":")
        try:
            if len(parts) not in (2, 3) or parts[0] not in AXES:
                raise ValueError
            peak = float(parts[1])
            every = float(parts[2]) if len(parts) == 3 else 0.5
        except ValueError:
            raise BadInputError(f"bad impact {spec!r}: expected AXIS:PEAK_N[:EVERY_S], AXIS one of "
                                f"{', '.join(AXES)}") from None
        if not (np.isfinite(peak) and 0 < peak <= 500):
            raise BadInputError(f"bad impact {spec!r}: peak must be > 0 and <= 500 N")
        if not (np.isfinite(every) and every >= 0.05):
            raise BadInputError(f"bad impact {spec!r}: strikes must be at least 0.05 s apart")
        return cls(AXES.index(parts[0]), peak, every)

    def force(self, t: np.ndarray) -> np.ndarray:
        """Hammer force (N) at times ``t`` (s)."""
        since = t - self.first_s
        phase = np.where(since >= 0, np.mod(since, self.every_s), -1.0)
        on = (phase >= 0) & (phase < IMPACT_S)
        return np.where(on, self.peak * np.sin(np.pi * np.clip(phase, 0, IMPACT_S) / IMPACT_S), 0.0)


@dataclass(frozen=True)
class Unbalance:
    """A mass unbalance at the two bearing planes: ``upper`` and ``lower`` kg m (mass times its
    eccentricity) at bearings 1 and 2, the lower one ``lower_phase_deg`` ahead in the spin.  It
    pushes with ``U Omega^2`` along the rotor angle: ``y = cos``, ``z = sin`` (the spin turns y
    towards z, the forward whirl of the bearings' y/z pairs)."""

    upper: float
    lower: float
    lower_phase_deg: float = 0.0

    @classmethod
    def parse(cls, spec: str) -> "Unbalance":
        """``UPPER_KGM:LOWER_KGM[:LOWER_PHASE_DEG]``."""
        parts = spec.split(":")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            u = cls(*(float(v) for v in parts))
        except ValueError:
            raise BadInputError(f"bad unbalance {spec!r}: expected UPPER_KGM:LOWER_KGM[:LOWER_PHASE_DEG]") from None
        if not all(np.isfinite(v) for v in (u.upper, u.lower, u.lower_phase_deg)) or not (
                0 <= u.upper <= MAX_UNBALANCE and 0 <= u.lower <= MAX_UNBALANCE):
            raise BadInputError(f"bad unbalance {spec!r}: each between 0 and {MAX_UNBALANCE:g} kg m")
        return u

    @staticmethod
    def planes(unbalance: "Unbalance | None") -> dict[str, complex]:
        """``unbalance`` per balancing plane, kg m as a phasor (its angle from the key-phasor's
        mark); None: a balanced rotor, zero on every plane."""
        if unbalance is None:
            return {plane: 0j for plane in BALANCE_PLANES}
        return {"upper": complex(unbalance.upper),
                "lower": unbalance.lower * np.exp(1j * np.deg2rad(unbalance.lower_phase_deg))}


MAX_UNBALANCE = 1e-3
"""kg m: 1 g at 1 m, or 100 g at the core's 10 mm: far beyond any balance grade of a 1.7 kg rotor."""


@njit(cache=True, fastmath=True, nogil=True)
def _simulate(s, hammer_t, unb, enabled, noise, speed, c, Minv, A, Tm, D, V0, out_gap, out_cur, out_volt, out_ctl,
              out_pos):
    """Advance state ``s`` (N_STATE) over len(hammer_t) samples.  ``hammer_t`` (n, SUBSTEPS) is
    the hammer force on bearing coordinate int(c[12]) at each substep; ``unb`` (n, 5) the
    unbalance force on each bearing coordinate, held over each sample; ``enabled`` (n,) 1 where
    the amplifiers run, 0 where they are off (a drop: no output, the coil currents decay through
    R/L); ``noise`` (n, 5) the gap sensors' noise (m); ``c`` the constants in the order
    ConeRig._constants lists them."""
    hs = c[0] / SUBSTEPS
    ks, tau, kc, ka, kf, res, ind, vs = c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]
    kforce, g0, shape = c[9], c[10], c[11]
    axis_hit = int(c[12])
    clr, kcon, ccon, ip, vx0 = c[13], c[14], c[15], c[16], c[17]
    kp = c[18:23]
    kd = c[23:28]
    mg = c[28]
    e_tau = np.exp(-hs / tau)
    e_c = np.exp(-hs * (ka * kf + res) / ind)
    e_lr = np.exp(-hs * res / ind)
    e_e = np.exp(-hs / c[29])
    qb = np.empty(5)
    vb = np.empty(5)
    vc = np.empty(5)
    Q = np.empty(5)
    fb = np.empty(5)
    for k in range(hammer_t.shape[0]):
        for sub in range(SUBSTEPS):
            for a in range(5):
                x = 0.0
                y = 0.0
                for b in range(5):
                    x += Tm[a, b] * s[b]
                    y += Tm[a, b] * s[5 + b]
                qb[a] = x
                vb[a] = y
            # eq. 11: vc = -Ks (Kp y + Kd s/(tau s + 1) y), the sensor signal held over the sample
            for a in range(5):
                y = qb[a] + noise[k, a]
                vc[a] = -ks * (kp[a] * y + kd[a] * (y - s[10 + a]) / tau)
                s[10 + a] = y + (s[10 + a] - y) * e_tau
            vc[0] += vx0
            # eq. 9 and 13-15: coil references, current-feedback amplifiers with the supply limit
            for j in range(8):
                vref = V0[j]
                for a in range(5):
                    vref += D[j, a] * vc[a]
                i = s[15 + j]
                v = ka * (vref - kf * i)
                if sub == 0:
                    out_cur[k, j] = i
                if enabled[k] < 0.5:  # the amplifier off: no output, the current decays through R/L
                    v = 0.0
                    i = i * e_lr
                elif v > vs or v < -vs:
                    v = vs if v > 0 else -vs
                    iss = v / res
                    i = iss + (i - iss) * e_lr
                else:
                    iss = kc * vref
                    i = iss + (i - iss) * e_c
                if i < 0.0:
                    i = 0.0
                if sub == 0:
                    out_volt[k, j] = v
                s[15 + j] = i
                s[23 + j] = i + (s[23 + j] - i) * e_e  # eq. 16: the force lags the current
            # eq. 3 forces on q_g through J^T n (matrix A: (8, 5)), gravity, touchdown, hammer
            for a in range(5):
                Q[a] = 0.0
            Q[0] = -mg
            for j in range(8):
                dq = 0.0
                for a in range(5):
                    dq += A[j, a] * s[a]
                g = g0 - shape * dq
                if g < 1e-5:
                    g = 1e-5
                f = kforce * s[23 + j] * s[23 + j] / (g * g)
                for a in range(5):
                    Q[a] += f * A[j, a]
            fb[:] = 0.0
            over = abs(qb[0]) - clr  # the axial stop
            if over > 0:
                fb[0] = -kcon * over * (1.0 if qb[0] > 0 else -1.0) - ccon * vb[0]
            for a, b in ((1, 3), (2, 4)):  # each round radial touchdown bearing, (y, z) of its plane
                r = np.sqrt(qb[a] * qb[a] + qb[b] * qb[b])
                over = r - clr
                if over > 0:
                    ny = qb[a] / r
                    nz = qb[b] / r
                    normal = kcon * over + ccon * (vb[a] * ny + vb[b] * nz)
                    if normal < 0.0:
                        normal = 0.0
                    fb[a] -= normal * ny
                    fb[b] -= normal * nz
            fb[axis_hit] += hammer_t[k, sub]
            for a in range(5):
                fb[a] += unb[k, a]
            for a in range(5):  # bearing-coordinate forces act on q_g through T^T
                for b in range(5):
                    Q[b] += Tm[a, b] * fb[a]
            Q[3] -= ip * speed * s[9]  # eq. 5: I_d th_y'' + Omega I_p th_z' = ...
            Q[4] += ip * speed * s[8]
            for a in range(5):
                acc = 0.0
                for b in range(5):
                    acc += Minv[a, b] * Q[b]
                s[5 + a] += hs * acc
            for a in range(5):
                s[a] += hs * s[5 + a]
            if sub == 0:  # the sample instant: the state before this period's first step
                for a in range(5):
                    out_pos[k, a] = qb[a]
                    out_gap[k, a] = qb[a] + noise[k, a]
                    out_ctl[k, a] = vc[a]


class ConeRig(Rig):
    """Jeong et al.'s cone-AMB rotor, closed loop (see the module docstring).

    Parameters
    ----------
    params : ConeParams
        Rig parameters.
    seed : int
        Noise seed; the run is deterministic for a given seed.
    speed : SpeedProfile
        Spin (the gyroscopic term); a robot joint turns slowly.
    truth : bool
        Also produce ``/truth/position`` (the true bearing coordinates).
    noise : bool
        Gap-sensor and hammer load-cell noise.
    start : {"levitated", "touchdown"}
        Initial state: at the levitated equilibrium, or at rest on the touchdown bearings with
        the coil currents zero.
    impact : Impact, optional
        Hammer strikes.
    unbalance : Unbalance, optional
        A mass unbalance (Jeong et al. give none: the rig has none unless asked).

    Attributes
    ----------
    masses : list of BalanceMass
        The trial and correction masses put on its balancing planes (:meth:`add_masses`).
    """

    profile = "cone"
    inputs = frozenset({"impact", "drop", "unbalance", "balancing"})
    balance_planes = BALANCE_PLANES

    def __init__(self, params: ConeParams = CONE, *, seed: int = 0, speed: SpeedProfile = SpeedProfile(0.0, 0.0),
                 truth: bool = False, noise: bool = True, start: str = "levitated",
                 impact: Impact | None = None, unbalance: "Unbalance | None" = None) -> None:
        super().__init__(params, seed=seed, speed=speed, truth=truth, noise=noise)
        self.impact = impact
        self._unbalance = Unbalance.planes(unbalance)
        self.masses: list[BalanceMass] = []
        self.drop: Drop | None = None
        self._last_rev = 0.0  # revolutions begun before this block (the key-phasor's count)
        self._theta0 = 0.0  # the rotor angle at step 0 (rad): where a settle left it
        r = params.rotor
        self._Minv = np.linalg.inv(r.mass_matrix())
        n, J = r.frames()
        self._A = np.einsum("ji,jik->jk", n, J)
        self._T = r.transform()
        self._V0 = r.coil_bias() / params.control.kc
        self.restart(start)

    def initial_state(self, start: str) -> np.ndarray:
        """The state a run starts from: "levitated" or "touchdown" (see the class)."""
        s = np.zeros(N_STATE)
        if start == "touchdown":
            s[0:5] = np.linalg.solve(self._T, np.array(TOUCHDOWN_START_UM) * 1e-6)
            return s
        i0 = self.params.rotor.operating_currents()
        s[15:23] = i0
        s[23:31] = i0
        return s

    def restart(self, start: str) -> None:
        """Start again from ``start`` ("levitated" or "touchdown") at the present time."""
        if start not in ("levitated", "touchdown"):
            raise ValueError(f"start must be levitated or touchdown, not {start!r}")
        self.start = start
        self.state = self.initial_state(start)

    def set_impact(self, impact: Impact | None) -> None:
        """Strike with the hammer from now on (None: stop)."""
        self.impact = impact

    def set_drop(self, drop: Drop | None) -> None:
        """Drop the rotor as ``drop`` says (None: the amplifiers always on)."""
        self.drop = drop

    def set_unbalance(self, unbalance: "Unbalance | None") -> None:
        """Spin with this mass unbalance (None: a balanced rotor), the masses put on before kept,
        and let the loop settle (:meth:`settle`)."""
        self._unbalance = plane_unbalance(Unbalance.planes(unbalance), self.masses)
        self.settle(SETTLE_S)

    def plane_unbalance(self) -> dict[str, complex]:
        """The rotor's unbalance per balancing plane now, kg m as a phasor (its angle from the
        key-phasor's mark in the direction of rotation)."""
        return dict(self._unbalance)

    def add_masses(self, masses: list[BalanceMass]) -> None:
        """Put ``masses`` (trial or correction) on the balancing planes before a recording: the
        unbalance changes, and the loop settles again (:meth:`settle`)."""
        self._unbalance = plane_unbalance(self._unbalance, masses)
        self.masses = [*self.masses, *masses]
        self.settle(SETTLE_S)

    def settle(self, seconds: float) -> None:
        """Run the closed loop for ``seconds`` at the start speed, unrecorded, with no hammer and the
        amplifiers on, and start the clock at 0 from there: the rotor's 1X is its steady response
        when the first sample is taken, as on a machine running before a recording starts.  The
        angle runs on continuously.  A run that starts on the touchdown bearings starts there: it
        does not settle."""
        n = int(round(seconds / self.h))
        if self.start != "levitated" or n <= 0:
            return
        speed, impact, drop = self.speed, self.impact, self.drop
        self.speed, self.impact, self.drop = SpeedProfile(speed.rpm_start, speed.rpm_start), None, None
        try:
            self.run(n)
        finally:
            self.speed, self.impact, self.drop = speed, impact, drop
        self._theta0 = float((self._theta0 + speed.rpm_start * RPM_TO_RAD_S * n * self.h) % (2 * np.pi))
        self.step_index, self._last_rev = 0, 0.0

    def _constants(self) -> np.ndarray:
        p, r, c = self.params, self.params.rotor, self.params.control
        return np.array([self.h, c.ks, c.tau, c.kc, p.amp_gain, p.current_feedback, p.resistance, r.inductance,
                         p.supply, r.force_constant, r.gap, r.shape_factor,
                         float(self.impact.axis if self.impact else 0), p.clearance, p.contact_stiffness,
                         p.contact_damping, r.inertia_p, r.levitation_offset() / c.kc,
                         *c.kp, *c.kd, r.mass * r.gravity, c.tau_e])

    def signal_groups(self) -> list[SignalGroup]:
        groups = [
            SignalGroup("/amb/gap", "Gap", AXES, ("m",) * 5),
            SignalGroup("/amb/current", "Current", COILS, ("A",) * 8),
            SignalGroup("/amb/voltage", "Voltage", COILS, ("V",) * 8),
            SignalGroup("/amb/control", "Control", AXES, ("V",) * 5),
            SignalGroup("/amb/hammer", "Force", ("hammer",), ("N",)),
            SignalGroup("/amb/rotor", "Rotor", ("angle", "speed", "keyphasor"), ("rad", "rad/s", "1")),
        ]
        if self.truth:
            groups.append(SignalGroup("/truth/position", "Position", AXES, ("m",) * 5))
        return groups

    def calibration(self) -> dict[str, str]:
        p, r = self.params, self.params.rotor
        modes = "; ".join(f"{AXES[a]}: {f:.3f} Hz zeta {z:.4f}" for f, z, a in self.modes())
        return {"mass_kg": f"{r.mass:g}", "l1_m": f"{r.l1:g}", "l2_m": f"{r.l2:g}",
                "sensor_gain_v_per_m": f"{p.control.ks:g}", "supply_v": f"{p.supply:g}",
                "start": self.start, "modes": modes, "units": "SI: m, A, V, N",
                "machine.min_clearance_m": repr(p.clearance), "machine.voltage_limit_v": repr(p.supply),
                "machine.axial_axes": "x",  # the spin axis (AXIAL_KEY): its gap has no orbit
                "machine.bearings": "1=y1/z1, 2=y2/z2",  # each cone bearing's two radial axes (BEARINGS_KEY)
                "machine.rotor_mass_kg": repr(r.mass),
                **balancing_truth(self.masses, self.plane_unbalance() if self.truth else None)}

    def run(self, n: int) -> SampleBlock:
        """Advance by ``n`` samples and return them."""
        steps = self._steps(n)
        t_sub = (steps[:, None] + np.arange(SUBSTEPS)[None, :] / SUBSTEPS) * self.h
        hammer = self.impact.force(t_sub) if self.impact else np.zeros_like(t_sub)
        noise = self._rng.standard_normal((n, 6))
        if not self.noise:
            noise[:] = 0.0
        outs = [np.empty((n, 5)), np.empty((n, 8)), np.empty((n, 8)), np.empty((n, 5)), np.empty((n, 5))]
        enabled = self.drop.enabled(steps * self.h) if self.drop else np.ones(n)
        theta, spin = self.speed.angle_speed(steps * self.h, self._theta0)
        # each plane's U Omega^2 along theta + its angle, y = cos, z = sin, at mid-sample
        turn = np.exp(1j * (theta + spin * self.h / 2))[:, None] * (spin**2)[:, None]
        push = turn * np.array([self._unbalance[p] for p in BALANCE_PLANES])[None, :]  # (n, planes)
        unb = np.column_stack([np.zeros(n), push.real, push.imag])  # x, y1, y2, z1, z2
        # the gyroscopic term at the block's first spin
        _simulate(self.state, hammer, unb, enabled, noise[:, :5] * self.params.gap_noise, float(spin[0]),
                  self._constants(), self._Minv, self._A, self._T, DISTRIBUTION, self._V0, *outs)
        self.step_index += n
        force = hammer[:, :1] + noise[:, 5:6] * self.params.hammer_noise
        # the spin as the spindle's controller reports it: angle in [0, 2 pi), speed, a key-phasor
        # pulse at the sample where a revolution begins
        rev = np.floor(theta / (2 * np.pi))
        pulse = np.diff(np.concatenate(([self._last_rev], rev))) > 0
        self._last_rev = float(rev[-1])
        rotor = np.column_stack([theta - rev * 2 * np.pi, spin, pulse.astype(float)])
        arrays = [outs[0], outs[1], outs[2], outs[3], force, rotor] + ([outs[4]] if self.truth else [])
        return self._block(steps, arrays)

    def step_jacobian(self, speed_rpm: float = 0.0) -> np.ndarray:
        """Jacobian of one sample of the noise-free kernel at the levitated equilibrium, by
        central differences: the simulator's own linearisation (N_STATE x N_STATE)."""
        s0 = self.initial_state("levitated")
        c = self._constants()
        c[12] = 0.0
        omega = speed_rpm * RPM_TO_RAD_S
        z = np.zeros((1, SUBSTEPS))
        nz = np.zeros((1, 5))
        outs = [np.empty((1, 5)), np.empty((1, 8)), np.empty((1, 8)), np.empty((1, 5)), np.empty((1, 5))]
        scale = np.r_[np.full(5, 1e-8), np.full(5, 1e-6), np.full(5, 1e-8), np.full(16, 1e-5)]
        Jac = np.empty((N_STATE, N_STATE))
        for i in range(N_STATE):
            cols = []
            for sign in (1.0, -1.0):
                s = s0.copy()
                s[i] += sign * scale[i]
                _simulate(s, z, nz, np.ones(1), nz, omega, c, self._Minv, self._A, self._T, DISTRIBUTION, self._V0,
                          *outs)
                cols.append(s)
            Jac[:, i] = (cols[0] - cols[1]) / (2 * scale[i])
        return Jac

    def modes(self, speed_rpm: float = 0.0) -> list[tuple[float, float, int]]:
        """The simulator's lightly-to-heavily damped modes below 1 kHz: (natural frequency in Hz,
        damping ratio, the bearing coordinate it moves most), from :meth:`step_jacobian`."""
        w, v = np.linalg.eig(self.step_jacobian(speed_rpm))
        s = np.log(w.astype(complex)) / self.h
        out = []
        for k in np.flatnonzero((s.imag > 1e-6) & (np.abs(s) < 2 * np.pi * 1000)):
            shape = np.abs(self._T @ v[:5, k])
            out.append((float(np.abs(s[k]) / (2 * np.pi)), float(-s[k].real / np.abs(s[k])), int(np.argmax(shape))))
        return sorted(out)


PROFILE = Profile("cone", ConeRig)  # served on no transport: ambdaq sim generate only
