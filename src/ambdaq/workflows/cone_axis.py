"""One cone-shaped AMB axis from its description (Jeong et al.): the workflow of ``ambdaq model``.

A bearing description (TOML: ``ambdaq model --example``) is read into the PD loop and the magnet's
linearised gains (:func:`load_axis`), and :func:`analyse_axis` gives everything the command reports
as one :class:`AxisModel`: its ``as_dict()`` is what ``--json`` prints, and the terminal lines are
printed from the same object.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..analysis.cone import PdLoop, StableRegion, force_factor, linear_gains, shape_factor, stable_region
from ..errors import BadInputError

STIFFNESS_HZ = (10.0, 50.0, 100.0, 200.0, 500.0)  # where the equivalent stiffness and damping are reported

EXAMPLE = """\
# one axis of Jeong et al.'s cone-shaped AMB (Table 1; gains of the Routh-Hurwitz example)
[magnet]
area_mm2 = 155
turns = 400
gap_mm = 0.5
bias_a = 1.03
pole_angles_deg = [20, 50]     # optional: force and shape factors (eq. 3); default 1, 1

[axis]
mass_kg = 1.68
# Ky and Ki of the paper's Routh-Hurwitz example: Ky/G = 1.9 and m/G = 5.69e-6 s^2, G = Ks Kc Ki.
# Delete these two lines to take the differential pair's 2 Kq and 2 Ki from [magnet] instead.
ky_n_per_m = 5.609e5
ki_n_per_a = 29.52

[controller]
sensor_v_per_m = 10000
amplifier_a_per_v = 1.0        # Kc
kp = 3.0
kd = 0.005                      # s
tau_s = 8e-5                    # derivative filter
tau_c_s = 6e-5                  # current loop
tau_e_s = 0.0                   # eddy-current lag (eq. 16)
"""


def _get(table: dict, key: str, path: str, default=None) -> float:
    if key not in table:
        if default is None:
            raise BadInputError(f"{path}: missing {key}")
        return default
    value = table[key]
    if not isinstance(value, (int, float)) or not np.isfinite(value):
        raise BadInputError(f"{path}: {key} must be a finite number, not {value!r}")
    return float(value)


def load_axis(path: str) -> tuple[PdLoop, dict]:
    """A bearing description (TOML, see ``ambdaq model --example``) -> the PD loop and the magnet's gains."""
    try:
        doc = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise BadInputError(f"{path}: not TOML ({err})") from None
    mag, axis, ctl = doc.get("magnet", {}), doc.get("axis", {}), doc.get("controller", {})
    angles = mag.get("pole_angles_deg")
    if angles is not None and (not isinstance(angles, list) or len(angles) != 2):
        raise BadInputError(f"{path}: pole_angles_deg must be [theta1, theta2]")
    ag, c = (1.0, 1.0) if angles is None else (force_factor(*np.radians(angles)), shape_factor(*np.radians(angles)))
    turns = _get(mag, "turns", path)
    gains = linear_gains(area=_get(mag, "area_mm2", path) * 1e-6, turns=int(turns), gap=_get(mag, "gap_mm", path) * 1e-3,
                         bias=_get(mag, "bias_a", path), alpha_g=ag, c=c)
    loop = PdLoop(m=_get(axis, "mass_kg", path), ky=_get(axis, "ky_n_per_m", path, 2 * gains.kq),
                  ki=_get(axis, "ki_n_per_a", path, 2 * gains.ki), ks=_get(ctl, "sensor_v_per_m", path),
                  kc=_get(ctl, "amplifier_a_per_v", path), kp=_get(ctl, "kp", path), kd=_get(ctl, "kd", path),
                  tau=_get(ctl, "tau_s", path), tau_c=_get(ctl, "tau_c_s", path), tau_e=_get(ctl, "tau_e_s", path, 0.0))
    if min(loop.m, loop.ky, loop.ki, loop.ks, loop.kc, loop.tau, loop.tau_c) <= 0 or loop.tau_e < 0:
        raise BadInputError(f"{path}: masses, gains and time constants must be > 0")
    return loop, {"alpha_g": ag, "c": c, "ki_n_per_a": gains.ki, "kq_n_per_m": gains.kq, "f0_n": gains.f0}



@dataclass(frozen=True)
class AxisModel:
    """What ``ambdaq model`` reports of one axis: the magnet's gains, the loop, its stability, the
    stable (Kp, Kd) region, the poles (rad/s) and the equivalent stiffness (N/m) and damping
    (N s/m) at :data:`STIFFNESS_HZ`."""

    loop: PdLoop
    magnet: dict
    region: StableRegion
    kp_max: float
    poles: np.ndarray
    stiffness_n_per_m: np.ndarray
    damping_n_s_per_m: np.ndarray

    def as_dict(self) -> dict:
        """The report as ``--json`` prints it (JSON has no NaN: a bound that does not exist is null)."""
        loop, region = self.loop, self.region
        return {
            "magnet": {k: round(v, 6) for k, v in self.magnet.items()},
            "axis": {"ky_n_per_m": loop.ky, "ki_n_per_a": loop.ki, "loop_gain_n_per_m": loop.ki * loop.ks * loop.kc},
            "stable": loop.stable(),
            "region": {k: (None if not np.isfinite(v) else v) for k, v in
                       {"kp_min": region.kp_min, "kd_min_s": region.kd_min, "kd_max_s": region.kd_max,
                        "kp_max_at_kd": self.kp_max}.items()},
            "poles_rad_s": [[float(p.real), float(p.imag)] for p in sorted(self.poles, key=lambda p: (abs(p), p.imag))],
            "stiffness_damping": [{"hz": float(f), "keq_n_per_m": float(k), "ceq_n_s_per_m": float(c)}
                                  for f, k, c in zip(STIFFNESS_HZ, self.stiffness_n_per_m, self.damping_n_s_per_m)],
        }


def analyse_axis(loop: PdLoop, magnet: dict) -> AxisModel:
    """The report of one axis (see :class:`AxisModel`) from its loop and the magnet's gains
    (:func:`load_axis`)."""
    region = stable_region(loop)
    k, c = loop.stiffness_damping(np.array(STIFFNESS_HZ))
    return AxisModel(loop, magnet, region, region.kp_max(loop), loop.poles(), k, c)
