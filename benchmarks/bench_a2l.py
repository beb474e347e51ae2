"""A2L files: ambdaq's reader against pya2ldb, the library a Python user would pick, each file in a
fresh process of each (time to a list of measurements, peak resident memory: VmHWM).

    python benchmarks/bench_a2l.py [FILE.a2l ...]

Without files it generates one of 20,000 measurements (5.5 MB).  Vendor files to try: the
``examples/`` of christoph2/pyA2L (docs/performance.md names the ones measured).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

AMBDAQ = """
import json, sys, time
t = time.monotonic()
from ambdaq.drivers.xcp.a2l import read_a2l
try:
    n = len(read_a2l(sys.argv[1]).measurements)
except Exception as err:
    n = f"refused: {str(err)[:90]}"
"""
PYA2LDB = """
import json, logging, sys, time
logging.disable(logging.WARNING)
t = time.monotonic()
from pya2l import import_a2l, model
try:
    n = import_a2l(sys.argv[1], in_memory=True, loglevel="ERROR", progress_bar=False).query(model.Measurement).count()
except Exception as err:
    n = f"refused: {str(err)[:90]}"
"""
REPORT = """
peak = [int(x.split()[1]) / 1024 for x in open("/proc/self/status") if x.startswith("VmHWM")][0]
print(json.dumps([n, time.monotonic() - t, peak]))
"""


def run(code: str, path: Path) -> tuple:
    r = subprocess.run([sys.executable, "-c", code + REPORT, str(path)], capture_output=True, text=True, timeout=600)
    return tuple(json.loads(r.stdout.strip().splitlines()[-1])) if r.returncode == 0 else ("crashed", 0.0, 0.0)


def generated(folder: Path) -> Path:
    rows = "\n".join(f'    /begin MEASUREMENT m{i}.value "a measured value {i}" SWORD CM.LIN 0 0 -100 100\n'
                     f'      ECU_ADDRESS 0x{0x10000 + 2 * i:X} ECU_ADDRESS_EXTENSION 1\n    /end MEASUREMENT'
                     for i in range(20000))
    path = folder / "generated_20000.a2l"
    path.write_text('ASAP2_VERSION 1 71\n/begin PROJECT P ""\n  /begin MODULE M ""\n'
                    '    /begin COMPU_METHOD CM.LIN "" LINEAR "%6.2" "K" COEFFS_LINEAR 0.01 0 /end COMPU_METHOD\n'
                    f'{rows}\n  /end MODULE\n/end PROJECT\n')
    return path


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        files = [Path(a) for a in sys.argv[1:]] or [generated(Path(tmp))]
        print(f"{'file':<28} {'MB':>5}  {'ambdaq':>28}  {'pya2ldb':>28}  time ratio")
        for f in files:
            a, b = run(AMBDAQ, f), run(PYA2LDB, f)
            ratio = f"{a[1] / b[1]:.2f}" if isinstance(b[0], int) and b[1] else "-"
            show = [f"{x[0] if isinstance(x[0], int) else 'refused'} {x[1]:5.2f} s {x[2]:4.0f} MB" for x in (a, b)]
            print(f"{f.name[:28]:<28} {f.stat().st_size / 1e6:5.2f}  {show[0]:>28}  {show[1]:>28}  {ratio}")
            for name, x in (("ambdaq", a), ("pya2ldb", b)):
                if not isinstance(x[0], int):
                    print(f"    {name}: {x[0]}")


if __name__ == "__main__":
    main()
