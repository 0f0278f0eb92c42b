"""Benchmark: `sfdrig diagnose --baseline fitted` on the harmonic-balance generator's cases
(target: 8 s CPU or less per case, so every case of tests/independent_hb runs in CI).

Each case (seed 1, as tests/independent_hb/test_judgement.py) is recorded, imported with the
minimal conditions (16 dwells of 1 s at 5 kS/s, lubricated X, no rig description) and
diagnosed in this process; the numba kernel is compiled (or loaded from its cache) before the
first timing. Prints per case the CPU and wall time and what diagnose said.

    .venv/bin/python benchmarks/bench_diagnose_hb.py [clean friction_large ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rig_model import physics  # noqa: E402
from sfdrig.cli import main as sfdrig  # noqa: E402
from tests.independent_hb.cases import cases, generate  # noqa: E402
from tests.independent_hb.generate import import_run  # noqa: E402

SEED = 1
TARGET_CPU_S = 8.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", default=["clean", "friction_large", "probe_delay"],
                    help=f"cases (of {', '.join(cases(SEED))})")
    args = ap.parse_args()
    known = cases(SEED)
    unknown = [n for n in args.names if n not in known]
    if unknown:
        print(f"unknown case(s) {unknown}; the cases are {list(known)}", file=sys.stderr)
        return 2
    physics.warm_up()
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.names:
            run = import_run(generate(known[name], SEED), Path(tmp), name)
            out = Path(tmp) / f"{name}.json"
            w0, c0 = time.perf_counter(), time.process_time()
            rc = sfdrig(["diagnose", str(run), "--baseline", "fitted", "--json", str(out),
                         "--quiet"])
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            if rc != 0:
                print(f"{name}: diagnose exit {rc}", file=sys.stderr)
                return 1
            doc = json.loads(out.read_text())
            found = [(f["effect"], f["evidence"].get("confidence")) for f in doc["findings"]]
            print(f"{name:20s} {cpu:6.1f} s CPU {wall:6.1f} s wall  verdict "
                  f"{doc['verdict']['verdict']!r}, found {found}")
            worst = max(worst, cpu)
    print(f"worst {worst:.1f} s CPU per case (target {TARGET_CPU_S:g} s)")
    return 0 if worst <= TARGET_CPU_S else 1


if __name__ == "__main__":
    sys.exit(main())
