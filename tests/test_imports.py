"""What a process imports: the command line's python-can comes without asammdf
(ambdaq.python_can_import), a library user's python-can is whole; measured in fresh interpreters,
since the suite's own workers have imported everything already."""

import subprocess
import sys

import pytest

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def mf4_state(first_import: str) -> list[str]:
    code = (f"import sys; import {first_import}; import can, canopen; import can.io.mf4 as mf4; "
            "print('asammdf' in sys.modules, mf4.asammdf is None); "
            "import asammdf; from ambdaq.daq import mdf; print(asammdf.MDF is not None)")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()


def test_the_command_lines_python_can_comes_without_asammdf_and_asammdf_still_imports():
    assert mf4_state("ambdaq.cli.main") == ["False", "True", "True"]


def test_a_library_user_keeps_python_cans_mf4_logger():
    assert mf4_state("ambdaq") == ["True", "False", "True"]
