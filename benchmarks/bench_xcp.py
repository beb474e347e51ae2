"""XCP DAQ at the controller's 10 kHz event: lost samples and CPU of ambdaq's recorder, against
pyxcp's own DAQ decoding of the same list, as a user of pyxcp alone would receive it.

``ambdaq sim serve --xcp tcp:0`` runs the rig and the controller's XCP slave in another process.
Two phases, each in a fresh process of its own and for the same time, on the same DAQ list (the
counter and the 28 measurements of ``ambdaq sim a2l``, one DTO of 117 bytes per control period):

* ambdaq: ``Recorder`` over ``xcp+tcp://`` (ambdaq's own master reads the link, assembles and
  decodes the DTOs by the ODT plan it configured, its device turns them into blocks, the recorder
  maps clocks, counts and writes MCAP);
* baseline: pyxcp's ``DaqOnlinePolicy`` with a callback that keeps each decoded sample in a list
  (the least a Python consumer of pyxcp does; no file).

CPU: the process's user + system seconds over the recording (``resource.getrusage``), in % of
one core.  Lost: gaps in the counter (the recorder's drops; in the baseline the same count).

    python benchmarks/bench_xcp.py [--seconds 20] [--transport tcp|sxi]
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


PYXCP_TYPES = {"ULONG": "U32", "FLOAT32_IEEE": "F32"}  # the A2L's types of the simulated controller, in pyxcp's names


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def phase_ambdaq(url: str, a2l: str, seconds: float, out: Path) -> dict:
    from ambdaq.acquisition.recorder import Recorder, RecordOptions
    from ambdaq.drivers.registry import open_url

    opened = open_url(url, description={"a2l": a2l})
    c0, t0 = cpu_s(), time.monotonic()
    res = Recorder(opened.sources, out, RecordOptions(duration_s=seconds)).run()
    cpu, wall = cpu_s() - c0, time.monotonic() - t0
    opened.close()
    return {"samples": res.samples, "lost": res.drops, "cpu_s": cpu, "wall_s": wall}


def phase_pyxcp(url: str, a2l: str, seconds: float) -> dict:
    from pyxcp.config import create_application_from_config, set_application
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy
    from pyxcp.master import Master

    from ambdaq.drivers.xcp.a2l import read_a2l

    if url.startswith("xcp+tcp://"):
        host, port = url.split("//")[1].rsplit(":", 1)
        layer, settings = "ETH", {"Eth": {"host": host, "port": int(port), "protocol": "TCP"}}
    else:  # the same settings a user of pyxcp would give for this line
        layer, settings = "SXI", {"SxI": {"port": "/" + url.split(":", 1)[1].lstrip("/"), "bitrate": 3_000_000,
                                          "header_format": "HEADER_LEN_CTR_WORD", "tail_format": "NO_CHECKSUM"}}
    app = create_application_from_config({"Transport": settings}, log_level=logging.ERROR)
    app.transport.layer = layer
    set_application(app)
    ms = read_a2l(a2l).measurements
    names = ["control_period", *[n for n in ms if n != "control_period"]]
    kept = []

    class Keep(DaqOnlinePolicy):
        def initialize(self):
            pass

        def finalize(self):
            pass

        def on_daq_list(self, _daq, _ts0, ts1, payload):
            kept.append((ts1, payload))

    policy = Keep([DaqList(name="amb", event_num=0, stim=False, enable_timestamps=True, priority=0, prescaler=1,
                           measurements=[(n, ms[n].address, 0, PYXCP_TYPES[ms[n].datatype]) for n in names])])
    with Master(layer.lower(), config=app, policy=policy) as x:
        x.connect()
        x.getCommModeInfo()
        policy.setup()
        c0, t0 = cpu_s(), time.monotonic()
        policy.start()
        time.sleep(seconds)
        policy.stop()
        cpu, wall = cpu_s() - c0, time.monotonic() - t0
        x.disconnect()
    seq = [p[0] for _t, p in kept]
    lost = sum(b - a - 1 for a, b in zip(seq, seq[1:]))
    return {"samples": len(kept), "lost": lost, "cpu_s": cpu, "wall_s": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--transport", choices=["tcp", "sxi"], default="tcp", help="XCP on TCP, or on SxI (a pty)")
    ap.add_argument("--phase", choices=["ambdaq", "pyxcp"], help=argparse.SUPPRESS)
    ap.add_argument("--url", help=argparse.SUPPRESS)
    ap.add_argument("--a2l", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.phase:  # one phase, in its own process
        with tempfile.TemporaryDirectory() as tmp:
            out = (phase_ambdaq(args.url, args.a2l, args.seconds, Path(tmp) / "x.mcap") if args.phase == "ambdaq"
                   else phase_pyxcp(args.url, args.a2l, args.seconds))
        print(json.dumps(out))
        return
    with tempfile.TemporaryDirectory() as tmp:
        a2l = Path(tmp) / "spindle.a2l"
        subprocess.run([sys.executable, "-m", "ambdaq", "sim", "a2l", "-o", str(a2l)], check=True)
        results = {}
        for phase in ("ambdaq", "pyxcp"):
            proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--rpm", "30000", "--can", "none",
                                     "--xcp", "tcp:0" if args.transport == "tcp" else "sxi"],
                                    stdout=subprocess.PIPE, text=True)
            try:
                line = ""
                while not line.startswith("xcp "):
                    line = proc.stdout.readline()
                url = line.split()[1]
                r = subprocess.run([sys.executable, __file__, "--phase", phase, "--url", url, "--a2l", str(a2l),
                                    "--seconds", str(args.seconds)], capture_output=True, text=True, check=True)
                results[phase] = json.loads(r.stdout.strip().splitlines()[-1])
            finally:
                proc.terminate()
                proc.wait(timeout=10)
    due = int(args.seconds * 10_000)
    print(f"XCP on {args.transport.upper()}, DAQ at 10 kHz for {args.seconds:g} s ({due:,} control periods), "
          "served in another process")
    for phase, r in results.items():
        print(f"  {phase:<7} samples {r['samples']:>9,}  lost {r['lost']:>6,}  CPU {r['cpu_s']:6.2f} s "
              f"= {100 * r['cpu_s'] / r['wall_s']:5.1f} % of a core")
    a, b = results["ambdaq"], results["pyxcp"]
    print(f"  CPU ratio ambdaq / pyxcp: {(a['cpu_s'] / a['wall_s']) / (b['cpu_s'] / b['wall_s']):.2f}")


if __name__ == "__main__":
    main()
