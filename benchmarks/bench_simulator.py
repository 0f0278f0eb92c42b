"""Simulator speed as a real-time factor (target: >= 600x real time per CPU-second; 1000x the aim).

The lubricated 2-DOF model with the seal, 10 kS/s, all 14 AI channels of the default map, through
`SimulatedBackend` in fast mode: a 19-frequency open-loop sweep (20-200 Hz, 10 Hz steps) of 2 s
dwells, read in 100 ms blocks as the controller does. Prints the median of several repeats, in
wall time and in CPU time (per CPU-second: the figure to compare on a machine busy with other work).

    .venv/bin/python benchmarks/bench_simulator.py [--repeats 5] [--block 1000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from daq import default_channel_map
from rig_model import RigParams
from rig_model.params import Oil
from simulated_hw import SimulatedBackend


def one_sweep(block: int, dwell_s: float = 2.0) -> tuple[float, float, float]:
    """(wall [s], CPU [s], simulated rig time [s]) of one sweep."""
    cm = default_channel_map()
    be = SimulatedBackend(RigParams(oil=Oil(initially_filled=True)), seed=0)
    be.configure(cm)
    be.set_do("pump", True)
    fs = cm.sample_rate_hz
    freqs = np.arange(20.0, 201.0, 10.0)
    per_dwell = int(dwell_s * fs)
    # the drive is synthesised beforehand: this measures the simulator, not the controller
    t = np.arange(per_dwell) / fs
    drives = [np.vstack([2.0 * np.cos(2 * np.pi * f * t), 2.0 * np.sin(2 * np.pi * f * t)])
              for f in freqs]
    be.write_ao(np.zeros((2, block)))
    be.start()
    t0, c0 = time.perf_counter(), time.process_time()
    for drive in drives:
        for k in range(per_dwell // block):
            be.read_ai(block)
            be.write_ao(drive[:, k * block:(k + 1) * block])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return wall, cpu, len(freqs) * per_dwell / fs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--block", type=int, default=1000)
    args = ap.parse_args()
    one_sweep(args.block, dwell_s=0.2)  # JIT warm-up (cached on disk after the first run)
    walls, cpus = [], []
    rig_s = 0.0
    for _ in range(args.repeats):
        wall, cpu, rig_s = one_sweep(args.block)
        walls.append(wall)
        cpus.append(cpu)
    med, cpu_med = statistics.median(walls), statistics.median(cpus)
    print(f"simulated rig time per sweep: {rig_s:.1f} s (19 dwells x 2 s, 14 AI ch, 10 kS/s)")
    print(f"wall time per sweep: median {med:.3f} s, min {min(walls):.3f} s, "
          f"max {max(walls):.3f} s over {args.repeats} repeats")
    print(f"CPU time per sweep: median {cpu_med:.3f} s, min {min(cpus):.3f} s")
    print(f"real-time factor: median {rig_s / med:.0f}x; per CPU-second: median "
          f"{rig_s / cpu_med:.0f}x (target >= 600x), best {rig_s / min(cpus):.0f}x; load average "
          f"{os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
