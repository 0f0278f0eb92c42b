"""How long `sfdrig export` takes: a run of 16 AI + 2 drives at 62.5 kS/s (the rig's full board),
with one step per second, exported to MAT, TDMS and CSV; wall time, CPU time and file size per
format, and the round trip back through `sfdrig import` (checked sample for sample).

Usage: .venv/bin/python benchmarks/bench_export.py [--seconds 20] [--dir /tmp] [--formats ...]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from storage import RunWriter, open_run
from storage.exporters import export_run
from storage.importers import import_file
from storage.records import StepRecord

N_AI = 16
FS_HZ = 62_500.0


def make_run(path: Path, seconds: float, seed: int = 0) -> int:
    """A run file of ``seconds`` of realistic samples (sines plus noise), one step per second."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS_HZ)
    chans = [{"name": f"ch{i:02d}", "units": "m" if i % 2 else "N", "kind": "probe",
              "sensor": f"S{i}", "gain_v_per_unit": 1.0, "offset_v": 0.0} for i in range(N_AI)]
    block = 62_500
    with RunWriter.create(path, "bench", "sweep", chans, ["shaker_x", "shaker_y"], FS_HZ,
                          swmr=False, flush_interval_s=0, overwrite=True) as w:
        for a in range(0, n, block):
            t = np.arange(a, a + block) / FS_HZ
            ai = (np.sin(2 * np.pi * 80.0 * t + np.arange(N_AI)[:, None])
                  + 0.01 * rng.standard_normal((N_AI, block)))
            ao = np.stack([np.sin(2 * np.pi * 80.0 * t), np.cos(2 * np.pi * 80.0 * t)])
            w.on_block(a, ai, ao)
            w.on_step(StepRecord.from_wire({
                "index": a // block, "freq_hz": 80.0, "target_kind": "load",
                       "target_value": 40.0, "motion": "x", "first_sample": a,
                       "last_sample": a + block, "updates": 1, "converged": True, "reason": "",
                       "harmonics": {f"ch{i:02d}": [[1.0, 0.0]] * 5 for i in range(N_AI)},
                       "drive_v": {"shaker_x": [1.0, 0.0]}}))
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--dir", type=Path, default=None)
    ap.add_argument("--formats", nargs="+", default=["mat", "tdms", "csv"])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        d = Path(tmp)
        run = d / "run.h5"
        n = make_run(run, args.seconds)
        print(f"run: {n:,} samples x {N_AI} AI + 2 drives at {FS_HZ:g} S/s "
              f"({args.seconds:g} s, {run.stat().st_size / 1e6:.0f} MB HDF5)")
        for fmt in args.formats:
            t0, c0 = time.perf_counter(), time.process_time()
            files = export_run(run, fmt, d / fmt)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            size = sum(f.stat().st_size for f in files) / 1e6
            t0 = time.perf_counter()
            back = import_file(files[0], d / f"back_{fmt}.h5")
            back_s = time.perf_counter() - t0
            with open_run(run) as a, open_run(back) as b:
                same = all(np.array_equal(a.channel(c), b.channel(c))
                           for c in a.channel_names + a.drive_names) and a.steps == b.steps
            print(f"{fmt:5s} export {wall:6.1f} s wall, {cpu:6.1f} s CPU, "
                  f"{n * (N_AI + 2) / wall / 1e6:5.2f} M values/s, {size:7.0f} MB; "
                  f"import back {back_s:6.1f} s, identical: {same}")


if __name__ == "__main__":
    main()
