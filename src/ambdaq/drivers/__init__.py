"""Hardware-facing drivers: transports, wire protocols, device drivers, the device interfaces and
the registry of back-ends by URL scheme.  Nothing here imports the simulator (:mod:`ambdaq.sim`),
which is one back-end among them."""
