"""XCP seed & key algorithms (ASAM XCP Part 2, GET_SEED / UNLOCK), as plug-ins.

A slave protects a resource (calibration, DAQ, programming) until the master answers a random
seed with the key the vendor's algorithm derives from it.  The algorithms are the vendor's
(often a DLL next to the A2L); ambdaq names one by ``key=NAME`` in the device URL and finds it
among :data:`ALGORITHMS` or in the ``ambdaq.xcp_keys`` entry-point group of an installed
package::

    [project.entry-points."ambdaq.xcp_keys"]
    acme = "acme_keys:key"      # key(resource: int, seed: bytes, secret: str) -> bytes

``secret`` is what the user gives ambdaq as the unlock key (``--key`` or ``$AMBDAQ_UNLOCK_KEY``);
an algorithm that needs none ignores it.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Callable
from importlib.metadata import entry_points

from ...errors import BadInputError

KeyAlgorithm = Callable[[int, bytes, str], bytes]
ENTRY_POINTS = "ambdaq.xcp_keys"
SIM_KEY_BYTES = 8


def sim_key(resource: int, seed: bytes, secret: str) -> bytes:
    """The simulated controller's algorithm: the first 8 bytes of HMAC-SHA256 over the resource
    byte and the seed, keyed with the unlock secret."""
    return hmac.new(secret.encode(), bytes([resource]) + seed, hashlib.sha256).digest()[:SIM_KEY_BYTES]


ALGORITHMS: dict[str, KeyAlgorithm] = {"ambdaq-sim": sim_key}
"""ambdaq's own algorithms by name."""


def algorithm(name: str) -> KeyAlgorithm:
    """The key algorithm called ``name`` (ambdaq's own, then installed plug-ins)."""
    if name in ALGORITHMS:
        return ALGORITHMS[name]
    for ep in entry_points(group=ENTRY_POINTS):
        if ep.name == name:
            return ep.load()
    known = sorted(set(ALGORITHMS) | {ep.name for ep in entry_points(group=ENTRY_POINTS)})
    raise BadInputError(f"unknown XCP key algorithm {name!r}: installed are {', '.join(known)}")
