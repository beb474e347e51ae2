"""A flexible rotor on two radial AMBs that needs tuning (the ``flexible`` profile, issue 42).

The machine is :mod:`ambdaq.machines.flexible_spindle`: a 23.2 kg rotor of beam elements with its
two rigid-body modes and six bending modes per plane, gyroscopic coupling with speed, sensors
40 mm outboard of the bearings.  Its controller's firmware runs, per radial axis and in this
order every 100 us: the gap sensor's sample (with noise) minus the test signal r_c (ISO 14839-3's
injection at the sensor summing point), the PID of :mod:`ambdaq.machines.spindle_loop` (Tustin
integrator, filtered derivative), a chain of up to ``MAX_SECTIONS`` second-order sections in
transposed direct form II (:mod:`ambdaq.analysis.sections`: notch, lead-lag, low-pass), the D/A's
saturation, held over the period.  The rotor and amplifiers are stepped exactly over the period
(zero-order hold, per 100 rpm of speed) with the unbalance forces held with them; without noise
and below saturation, the kernel is :class:`~ambdaq.machines.flexible_spindle.FlexibleLoop`'s
linear loop to rounding (tests/test_flexible_rig.py), the truth ``plant identify`` and
``controller design`` are checked against.

Its stock controller (PID, no sections) leaves the third bending mode barely damped at
standstill and the second unstable at speed: the rotor then grows until a sensor reads more than
the clearance, and the protection trips the amplifiers (the rotor rests on its touchdown
bearings; every later sample repeats the last, and :attr:`FlexibleRig.tripped_at` says when).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...drivers.coefbank import BankImage, controller_problem
from ...drivers.signals import SampleBlock, SignalGroup
from ...machines.flexible_spindle import AXES, FLEXIBLE, FlexibleLoop, FlexibleSpindleParams
from ...machines.spindle_loop import GAIN_KEYS, GAIN_LEAST, derivative_filter
from ...speed import RPM_TO_RAD_S, SpeedProfile
from ..devices.firmware import EXCITATION, SPEED, Feedforward, Firmware, Param
from ..profiles import Profile
from .base import CommandedSpeed, Rig
from .excitation import ExcitationInput

MAX_SECTIONS = 4  # second-order sections per axis the firmware runs
IDENTITY_SECTION = (1.0, 0.0, 0.0, 0.0, 0.0)
SPEED_BUCKET_RPM = 100.0  # the gyroscopic coupling is recomputed per bucket
N_AXES = len(AXES)


@njit(cache=True, fastmath=False, nogil=True)
def _simulate(x, ctl, sec_state, st, theta, omega, noise, exc, Phi, Gam, Gamf, Cs, ks, P, ci, ad, bd, sections,
              ur, ui, c, out_gap, out_cur, out_err, out_ff, out_ctl, out_pos):
    """Advance the loop over len(theta) periods.  x: rotor and amplifier state; ctl (axes, 3):
    integral, derivative, previous error voltage; sec_state (axes, sections, 2); st[0]: 1 while
    levitated, 0 once tripped.  c = [gap noise m, D/A range V, clearance m]."""
    n_state = x.shape[0]
    m = ur.shape[0]
    nr = 4 * m
    u = np.zeros(Cs.shape[0])
    f = np.zeros(2 * m)
    xn = np.empty(n_state)
    for k in range(theta.shape[0]):
        for a in range(Cs.shape[0]):
            pos = 0.0
            for j in range(n_state):
                pos += Cs[a, j] * x[j]
            gap = pos + c[0] * noise[k, a]
            out_pos[k, a] = pos
            out_gap[k, a] = gap
            out_ff[k, a] = exc[k, a]
            out_cur[k, a] = x[nr + 2 * a]
            e = gap - exc[k, a]
            out_err[k, a] = e
            if st[0] == 0.0 or abs(gap) > c[2]:
                st[0] = 0.0
                u[a] = 0.0
                out_ctl[k, a] = 0.0
                continue
            ev = ks * e
            integ = ctl[a, 0] + ci[a] * (ev + ctl[a, 2])
            deriv = ad[a] * ctl[a, 1] + bd[a] * (ev - ctl[a, 2])
            ctl[a, 0] = integ
            ctl[a, 1] = deriv
            ctl[a, 2] = ev
            v = -(P[a] * ev + integ + deriv)
            for s in range(sections.shape[1]):  # transposed direct form II, one section after another
                y = sections[a, s, 0] * v + sec_state[a, s, 0]
                sec_state[a, s, 0] = sections[a, s, 1] * v - sections[a, s, 3] * y + sec_state[a, s, 1]
                sec_state[a, s, 1] = sections[a, s, 2] * v - sections[a, s, 4] * y
                v = y
            u[a] = min(max(v, -c[1]), c[1])
            out_ctl[k, a] = u[a]
        if st[0] == 0.0:  # on the touchdown bearings: the rotor stays where the trip left it
            continue
        w2 = omega[k] * omega[k]
        cth, sth = np.cos(theta[k]), np.sin(theta[k])
        for j in range(m):
            f[j] = w2 * (ur[j] * cth - ui[j] * sth)
            f[m + j] = w2 * (ur[j] * sth + ui[j] * cth)
        for i in range(n_state):
            acc = 0.0
            for j in range(n_state):
                acc += Phi[i, j] * x[j]
            for j in range(u.shape[0]):
                acc += Gam[i, j] * u[j]
            for j in range(2 * m):
                acc += Gamf[i, j] * f[j]
            xn[i] = acc
        for i in range(n_state):
            x[i] = xn[i]


def _groups(truth: bool) -> list[SignalGroup]:
    m4 = ("m",) * N_AXES
    groups = [
        SignalGroup("/amb/gap", "Gap", AXES, m4),
        SignalGroup("/amb/current", "Current", AXES, ("A",) * N_AXES),
        SignalGroup("/amb/error", "Error", AXES, m4),
        SignalGroup("/amb/ff", "Feedforward", AXES, m4),
        SignalGroup("/amb/control", "Control", AXES, ("V",) * N_AXES),
        SignalGroup("/amb/rotor", "Rotor", ("angle", "speed", "keyphasor"), ("rad", "rad/s", "1")),
    ]
    if truth:
        groups.append(SignalGroup("/truth/position", "Position", AXES, m4))
    return groups


def chain(sections) -> np.ndarray:
    """Per-axis sections, shape (axes, MAX_SECTIONS, 5), padded with identity sections.

    Parameters
    ----------
    sections : sequence of sequences of Section
        One chain per axis in ``AXES`` order, each at most MAX_SECTIONS (b0, b1, b2, a1, a2).

    Raises
    ------
    ValueError
        A chain too long, or what :func:`~ambdaq.drivers.coefbank.controller_problem` refuses.
    """
    if len(sections) != N_AXES:
        raise ValueError(f"one chain of sections per axis ({N_AXES}), not {len(sections)}")
    out = np.tile(np.array(IDENTITY_SECTION), (N_AXES, MAX_SECTIONS, 1))
    for a, axis_sections in enumerate(sections):
        if len(axis_sections) > MAX_SECTIONS:
            raise ValueError(f"{AXES[a]}: {len(axis_sections)} sections, the firmware runs at most {MAX_SECTIONS}")
        if len(axis_sections):
            out[a, : len(axis_sections)] = np.asarray(axis_sections, dtype=float).reshape(-1, 5)
    problem = controller_problem(np.zeros((N_AXES, 3)), out)
    if problem:
        raise ValueError(problem)
    return out


class FlexibleRig(CommandedSpeed, Rig, ExcitationInput):
    """The flexible rotor's closed loop, stepped in blocks of control periods.

    Parameters
    ----------
    params : FlexibleSpindleParams
    seed : int
        Seed of the noise generator.
    speed : SpeedProfile
        Rotor speed, rpm over time.
    truth : bool
        Also produce ``/truth/position`` (each sensor node's displacement, no noise).
    noise : bool
        Sensor noise on.
    """

    profile = "flexible"
    inputs = frozenset({"excitation"})
    excitation_axes = AXES  # test signal added at the sensor summing point, in m
    excitation_unit = "m"
    excitation_min = 0.01e-6
    excitation_max = 20e-6

    def __init__(self, params: FlexibleSpindleParams = FLEXIBLE, *, seed: int = 0,
                 speed: SpeedProfile = SpeedProfile(0.0, 0.0), truth: bool = False, noise: bool = True) -> None:
        super().__init__(params, seed=seed, speed=speed, truth=truth, noise=noise)
        self._exc_rng = np.random.default_rng([seed, 1])
        self._loop = FlexibleLoop(params)
        axes = params.axes
        self._sections = chain([()] * N_AXES)
        self.set_pid(*(np.array([getattr(ax, f"pid_{k}") for ax in axes]) for k in "pid"))
        self._cs = np.ascontiguousarray(self._loop.sensor_rows())
        unb = self._loop.unbalance_modal()
        self._ur, self._ui = np.ascontiguousarray(unb.real), np.ascontiguousarray(unb.imag)
        self._plants: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._x = np.zeros(self._cs.shape[1])
        self._ctl = np.zeros((N_AXES, 3))
        self._sec_state = np.zeros((N_AXES, MAX_SECTIONS, 2))
        self._st = np.ones(1)
        self._c = np.array([params.gap_noise if noise else 0.0, params.dac_range, params.clearance])
        self._rev = float(np.floor(speed.angle_speed(np.zeros(1))[0][0] / (2 * np.pi)))
        self.tripped_at: float | None = None

    # --- the firmware's parameters --------------------------------------------------------------

    def set_pid(self, p: np.ndarray, i: np.ndarray, d: np.ndarray) -> None:
        """Replace the PID gains of the four axes (V/V, 1/s, s); the derivative filter follows."""
        p, i, d = (np.asarray(v, dtype=float).reshape(N_AXES).copy() for v in (p, i, d))
        self._p, self._i, self._d = p, i, d
        self._ci = i * self.h * 0.5
        self._ad, self._bd = derivative_filter(p, d, self.params.derivative_filter, self.h)

    @property
    def pid_gains(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present (P, I, D) per axis, in V/V, 1/s, s."""
        return self._p.copy(), self._i.copy(), self._d.copy()

    def set_sections(self, sections: np.ndarray) -> None:
        """Replace every axis's chain (shape (axes, MAX_SECTIONS, 5), :func:`chain`); the sections'
        states restart from zero, as a firmware loading new coefficients does."""
        self._sections = np.ascontiguousarray(sections, dtype=float)
        self._sec_state[:] = 0.0

    @property
    def sections(self) -> np.ndarray:
        """Present sections per axis, shape (axes, MAX_SECTIONS, 5)."""
        return self._sections.copy()

    def signal_groups(self) -> list[SignalGroup]:
        return _groups(self.truth)

    def calibration(self) -> dict[str, str]:
        p = self.params
        return {
            "gap_sensor_gain_v_per_m": f"{p.sensor_gain:g}",
            "units": "SI: m, A, rad, rad/s",
            "machine.min_clearance_m": repr(p.clearance),
            # the gains the loop runs at now, under the names the spindle states them (GAIN_KEYS)
            **{key: ",".join(repr(float(v)) for v in g) for key, g in zip(GAIN_KEYS, self.pid_gains)},
        }

    def loop(self) -> FlexibleLoop:
        """The linear loop at the present gains and sections (the truth a design is checked on)."""
        return FlexibleLoop(self.params, tuple(tuple(float(v) for v in g) for g in self.pid_gains),
                            [[tuple(sec) for sec in axis if tuple(sec) != IDENTITY_SECTION] for axis in self._sections])

    def loop_matrices(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M, B, C of the linear loop at ``rpm`` with the present gains and sections."""
        return self.loop().matrices(rpm)

    # --- stepping -------------------------------------------------------------------------------

    def _plant(self, rpm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        key = int(round(rpm / SPEED_BUCKET_RPM))
        if key not in self._plants:
            self._plants[key] = tuple(np.ascontiguousarray(a) for a in self._loop.plant(key * SPEED_BUCKET_RPM))
        return self._plants[key]

    def run(self, n: int) -> SampleBlock:
        """Advance the loop by ``n`` control periods and return their samples."""
        steps = self._steps(n)
        t = steps * self.h
        theta, omega = self._angle_speed(steps)
        noise = self._rng.standard_normal((n, N_AXES))
        exc = self.excitation_block(steps)
        outs = [np.empty((n, N_AXES)) for _ in range(6)]
        rpm = omega / RPM_TO_RAD_S
        bucket = np.round(rpm / SPEED_BUCKET_RPM)
        edges = np.concatenate(([0], np.flatnonzero(np.diff(bucket)) + 1, [n]))
        levitated = self._st[0]
        for lo, hi in zip(edges[:-1], edges[1:]):
            Phi, Gam, Gamf = self._plant(float(rpm[lo]))
            sl = slice(lo, hi)
            _simulate(self._x, self._ctl, self._sec_state, self._st, theta[sl], omega[sl], noise[sl], exc[sl],
                      Phi, Gam, Gamf, self._cs, self.params.sensor_gain, self._p, self._ci, self._ad, self._bd,
                      self._sections, self._ur, self._ui, self._c, *(o[sl] for o in outs))
        if levitated and not self._st[0]:
            self.tripped_at = float(t[np.flatnonzero(np.abs(outs[0]).max(axis=1) > self.params.clearance)[0]])
        self.step_index += n
        gap, cur, err, ff, ctl, pos = outs
        revs = np.floor(theta / (2 * np.pi))
        keyphasor = (revs > np.concatenate(([self._rev], revs[:-1]))).astype(float)  # once per turn, at its start
        self._rev = float(revs[-1])
        rotor = np.column_stack([np.mod(theta, 2 * np.pi), omega, keyphasor])
        arrays = [gap, cur, err, ff, ctl, rotor] + ([pos] if self.truth else [])
        return self._block(steps, arrays)


class ControllerBank(Feedforward):
    """The flexible rig's coefficient banks hold its feedback controller (a PID and a chain of
    sections per axis, :data:`~ambdaq.drivers.coefbank.SECTION_CONTROLLER`): ``ambdaq push`` of a
    controller design goes through them, checked by CRC, switched between two control periods and
    rolled back as a coefficient file is; it runs no runout feedforward."""

    def layout(self, rig) -> dict:
        return {"axes": list(AXES), "harmonics": 0,
                "controller": {"max_sections": MAX_SECTIONS, "sample_rate_hz": rig.params.sample_rate}}

    def present(self, rig) -> BankImage:
        return BankImage(np.zeros((N_AXES, 0, 2)), "off", pid=np.column_stack(rig.pid_gains),
                         biquads=rig.sections)

    def apply(self, rig, image: BankImage) -> None:
        if image.pid is not None:
            rig.set_pid(*image.pid.T)
            rig.set_sections(chain([list(axis) for axis in (image.biquads if image.biquads is not None
                                                             else np.zeros((N_AXES, 0, 5)))]))


def _set_pid(which: int):
    def write(rig, values):
        gains = list(rig.pid_gains)
        gains[which] = values
        rig.set_pid(*gains)

    return write


def _sections_problem(rig, values: np.ndarray) -> str:
    try:
        chain(list(values.reshape(N_AXES, MAX_SECTIONS, 5)))
    except ValueError as err:
        return str(err)
    return ""


FIRMWARE = Firmware(
    "AMB controller (simulated, flexible rotor)",
    ("/amb/gap", "/amb/current", "/amb/error", "/amb/ff", "/amb/control", "/amb/rotor"),
    {
        "pid.p": Param(N_AXES, lambda r: r.pid_gains[0], _set_pid(0), GAIN_LEAST[0], 100.0,
                       "proportional gain per axis, V/V"),
        "pid.i": Param(N_AXES, lambda r: r.pid_gains[1], _set_pid(1), GAIN_LEAST[1], 1e4,
                       "integral gain per axis, 1/s"),
        "pid.d": Param(N_AXES, lambda r: r.pid_gains[2], _set_pid(2), GAIN_LEAST[2], 1.0,
                       "derivative gain per axis, s"),
        # the sections after each axis's PID: written here one change at a time by hand, or as a
        # whole design with the PID through the coefficient banks (CRC-checked, undone by rollback)
        "filter.sections": Param(N_AXES * MAX_SECTIONS * 5, lambda r: r.sections.ravel(),
                                 lambda r, v: r.set_sections(v.reshape(N_AXES, MAX_SECTIONS, 5)), -1e3, 1e3,
                                 f"second-order sections per axis [axis][section 1..{MAX_SECTIONS}][b0, b1, b2, a1, a2], "
                                 "transposed direct form II, a0 = 1; (1, 0, 0, 0, 0) passes through",
                                 _sections_problem),
        "speed.rpm": SPEED,
        "exc.signal": EXCITATION,
    },
    ControllerBank(),
)

PROFILE = Profile("flexible", FlexibleRig, FIRMWARE, ("controller",))
