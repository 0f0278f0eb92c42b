"""Benchmark: `diagnose` of a 25-dwell run set (target: 60 s or less on the project machine).

Generates (seeded) one simulated run of 25 sine dwells (5 frequencies x 5 amplitudes, x / y /
circular motions) with a hidden cubic spring, then times the whole diagnosis (baseline, every
applicable effect of the library, rounds until nothing significant, bootstrap). Prints wall and CPU
time and what was found.

    .venv/bin/python benchmarks/bench_diagnose.py [--effect cubic_stiffness] [--seed 7]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.diagnose import diagnose, load_run  # noqa: E402
from tests.analysis.hidden_effects import make_case  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", default="cubic_stiffness")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--dwells", type=int, default=25)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        case = make_case(Path(tmp), [args.effect] if args.effect != "none" else [], args.seed,
                         n_dwells=args.dwells)
        t_gen = time.perf_counter() - t0
        records = [load_run(p, i) for i, p in enumerate(case.paths)]
        # compile the kernel once (numba cache) so the timing is the diagnosis
        w0, c0 = time.perf_counter(), time.process_time()
        diag = diagnose(records, seed=args.seed)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    n = records[0].n_samples
    print(f"run set: {args.dwells} dwells, {n} samples at {records[0].sample_rate_hz:g} S/s "
          f"({case.duration_s:.1f} s of data; generated in {t_gen:.1f} s)")
    print(f"hidden: {case.effects}")
    print(f"diagnose: {wall:.1f} s wall, {cpu:.1f} s CPU "
          f"({len(diag.rounds)} rounds, target 60 s)")
    for f in diag.findings:
        print(f"  found {f.effect} {f.parameters} gain {f.gain:.3g} "
              f"[{f.gain_interval[0]:.3g}, {f.gain_interval[1]:.3g}]")
    print(f"  unexplained: {diag.unexplained}")
    return 0 if wall <= 60.0 else 1


if __name__ == "__main__":
    sys.exit(main())
