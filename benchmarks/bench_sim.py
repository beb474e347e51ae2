"""Simulator throughput: spindle control steps per second on one core.

Baseline, measured in the same run: the very same step kernel run interpreted by CPython
(``_simulate.py_func``), i.e. what the loop costs without numba.

    python benchmarks/bench_sim.py [--steps 2000000]
"""

from __future__ import annotations

import argparse

import ambdaq.sim.rigs.spindle as spindle
from ambdaq.speed import SpeedProfile

from _common import best_of, row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2_000_000)
    ap.add_argument("--baseline-steps", type=int, default=5_000)
    args = ap.parse_args()

    rig = spindle.SpindleRig(speed=SpeedProfile(30000, 30000))
    rig.run(100)  # compile / load from cache
    t_fast = best_of(lambda: rig.run(args.steps))
    fast = args.steps / t_fast

    compiled = spindle._simulate
    spindle._simulate = compiled.py_func  # the same kernel, interpreted
    try:
        slow_rig = spindle.SpindleRig(speed=SpeedProfile(30000, 30000))
        t_slow = best_of(lambda: slow_rig.run(args.baseline_steps), repeat=2)
    finally:
        spindle._simulate = compiled
    slow = args.baseline_steps / t_slow

    real_time = rig.params.sample_rate
    print(row("spindle steps/s (numba kernel)", fast, "steps/s", f"{fast / real_time:.0f}x real time"))
    print(row("spindle steps/s (same kernel, interpreted)", slow, "steps/s", "baseline"))
    print(f"ratio compiled / interpreted: {fast / slow:.0f}x; real-time factor: {fast / real_time:.0f}x "
          f"(target >= 100x real time = 1,000,000 steps/s)")


if __name__ == "__main__":
    main()
