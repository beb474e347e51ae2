"""The in-process simulated rig recorded over and over beside a process that burns a whole core:
no sample twice, times in order, and every count exact (issue 12)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from ambdaq.daq import load

pytestmark = pytest.mark.realtime  # devices run in real time (pyproject.toml: each written to hold beside another test)

SECONDS = 2.0


# the burner takes a core from the other test worker too: one run by default, three with -m long
@pytest.mark.parametrize("runs", [1, pytest.param(3, marks=pytest.mark.long)])
def test_in_process_rig_under_cpu_load_counts_every_sample_exactly(runs, run_cli, tmp_path):
    burner = subprocess.Popen([sys.executable, "-c", "while 1: pass"])
    try:
        for i in range(runs):
            out = tmp_path / f"load{i}.mcap"
            r = run_cli("record", "--device", "sim://spindle", "--rpm", "30000", "--duration", SECONDS, "--json",
                        "-q", "-o", out)
            assert r.exit_code == 0, r.output
            summary = json.loads(r.stdout)  # a loaded host may add a warning on stderr
            assert summary["duplicates"] == 0
            info = {t["topic"]: t for t in json.loads(run_cli("info", out, "--json").output)["topics"]}
            rec = load(out)
            for topic, data in rec.topics.items():
                seq = data.seq.astype(np.int64)
                assert np.all(np.diff(seq) > 0) and np.all(np.diff(data.log_time) > 0), topic  # once, in order
                rate = rec[topic].nominal_rate
                drops = info[topic]["drops"]
                # what was due is exactly what was written plus what is counted lost
                assert len(data) + drops == round(SECONDS * rate), (topic, len(data), drops)
                assert drops == summary["topics"][topic]["drops"] and info[topic]["duplicates"] == 0
    finally:
        burner.kill()
        burner.wait()
