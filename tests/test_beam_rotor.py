"""The flexible rotor's beam finite elements (analysis/beam_rotor.py) against closed forms: a free
uniform beam's bending modes, a rigid rotor's whirl on springs as it spins."""

import numpy as np
import pytest

from ambdaq.analysis.beam_rotor import STEEL, BeamRotor, Disk, ShaftElement

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def uniform(length: float, d: float, n: int, **kw) -> BeamRotor:
    return BeamRotor(tuple(ShaftElement(length / n, d) for _ in range(n)), **kw)


def test_a_free_uniform_beam_bends_at_the_euler_bernoulli_frequencies():
    """Free-free Euler-Bernoulli beam: f_k = (beta_k L)^2 / (2 pi L^2) sqrt(E I / (rho A)) with
    beta L = 4.7300, 7.8532, 10.9956; two rigid-body modes at 0.  Cubic elements converge from
    above as h^4: 20 elements are within 1e-4 of the closed form (measured 2e-6 .. 5e-5)."""
    L, d = 0.5, 0.04
    rotor = uniform(L, d, 20, rotary_inertia=False)
    f, shapes = rotor.free_modes(5)
    e = rotor.elements[0]
    scale = np.sqrt(STEEL[0] * e.inertia / (STEEL[1] * e.area)) / (2 * np.pi * L**2)
    expect = np.array([4.730041, 7.853205, 10.995608]) ** 2 * scale
    assert f[:2] == pytest.approx([0.0, 0.0], abs=1e-3 * expect[0])
    np.testing.assert_allclose(f[2:], expect, rtol=1e-4)
    assert shapes.shape == (2 * rotor.nodes, 5)


@pytest.mark.parametrize("omega", [0.0, 1500.0, 6000.0])
def test_a_stiff_rotor_on_springs_whirls_as_a_rigid_body(omega):
    """A shaft a thousand times stiffer than steel on two springs at its ends moves as a rigid
    body: bounce at sqrt(2 k / m), whatever the speed, and tilt at
    w = (+-Ip Omega + sqrt(Ip^2 Omega^2 + 4 It k L^2 / 2)) / (2 It), forward stiffened, backward
    softened (It = m L^2/12 + m d^2/16, Ip = m d^2/8, the shaft's own rotary inertia).  The
    bending modes sit 30 times higher; their residual flexibility lowers these by 1.7e-5
    (measured), so 1e-4."""
    L, d, k = 0.4, 0.05, 2e6
    rotor = uniform(L, d, 8, youngs_modulus=STEEL[0] * 1e3)
    m = rotor.mass
    it, ip = m * L**2 / 12 + m * d**2 / 16, m * d**2 / 8
    f, whirl = rotor.whirl_frequencies(omega, {0: k, rotor.nodes - 1: k})
    root = np.sqrt((ip * omega) ** 2 + 4 * it * k * L**2 / 2)
    tilt_fwd, tilt_bwd = (root + ip * omega) / (2 * it) / (2 * np.pi), (root - ip * omega) / (2 * it) / (2 * np.pi)
    bounce = np.sqrt(2 * k / m) / (2 * np.pi)
    low = f[:4]  # two bounce (one per plane) and two tilt modes
    np.testing.assert_allclose(sorted(low), sorted([bounce, bounce, tilt_fwd, tilt_bwd]), rtol=1e-4)
    if omega > 0:
        assert whirl[np.argmin(np.abs(f - tilt_fwd))] == 1 and whirl[np.argmin(np.abs(f - tilt_bwd))] == -1


def test_a_disk_adds_its_mass_and_its_gyroscopic_moment():
    """A heavy disk in the middle of a shaft on end springs: at speed its tilt mode splits as its
    polar inertia says (forward up, backward down), and the bounce mode does not move."""
    L, d, k = 0.4, 0.03, 5e6
    disk = Disk(node=4, mass=10.0, ip=0.05, it=0.03)
    rotor = uniform(L, d, 8, disks=(disk,))
    f0, _ = rotor.whirl_frequencies(0.0, {0: k, 8: k})
    f1, whirl = rotor.whirl_frequencies(3000.0, {0: k, 8: k})
    assert rotor.mass == pytest.approx(10.0 + STEEL[1] * np.pi / 4 * d**2 * L)
    fwd = f1[whirl == 1]
    bwd = f1[whirl == -1]
    assert fwd[:2].max() > f0[:4].max() and bwd[:2].min() < f0[:4].min()
