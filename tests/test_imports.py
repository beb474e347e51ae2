"""What a process imports: python-can without asammdf (ambdaq.python_can_import), measured in a
fresh interpreter, since the suite's own workers have imported everything already."""

import subprocess
import sys


def test_python_can_comes_without_asammdf_and_asammdf_still_imports():
    code = ("import sys, ambdaq, can, canopen; import can.io.mf4 as mf4; "
            "print('asammdf' in sys.modules, mf4.asammdf is None); "
            "import asammdf; from ambdaq.daq import mdf; print(asammdf.MDF is not None)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True", "True"], out
