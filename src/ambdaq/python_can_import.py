"""python-can without asammdf at its import.

``import can`` imports python-can's MF4 logger, which imports asammdf (and through it canmatrix,
pandas and openpyxl) when it is installed: 1.5 s of the 2.3 s a simulated rig's recording spends on
imports on a slow host, in every process that touches a CAN bus.  ambdaq never uses python-can's
MF4 reader or writer (MDF export goes through asammdf itself, :mod:`ambdaq.daq.mdf`), so while
``can.io.mf4`` is being imported, asammdf is reported missing to it: python-can then leaves its MF4
classes unavailable (they raise if used) and every other import of asammdf is untouched.

Only the command line installs it (:mod:`ambdaq.cli.main`): its processes never use python-can's
MF4 logger, while a notebook or a program that imports ambdaq as a library may, and keeps
python-can as it is.
"""

from __future__ import annotations

import importlib.abc
import sys


class _AsammdfHiddenFromPythonCanMf4(importlib.abc.MetaPathFinder):
    """Answers ``import asammdf`` with ImportError while, and only while, can.io.mf4 initialises."""

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "asammdf":
            mf4 = sys.modules.get("can.io.mf4")
            if mf4 is not None and getattr(mf4.__spec__, "_initializing", False):
                raise ImportError("asammdf is not imported for python-can's MF4 logger (ambdaq never uses it)",
                                  name=name)
        return None


def install() -> None:
    """Put the finder first on the import path, once per process (before anything imports can)."""
    if not any(isinstance(f, _AsammdfHiddenFromPythonCanMf4) for f in sys.meta_path):
        sys.meta_path.insert(0, _AsammdfHiddenFromPythonCanMf4())
