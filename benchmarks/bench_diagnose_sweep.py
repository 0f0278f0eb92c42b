"""Benchmark: `diagnose` of a 100,000-sample sine sweep (target: 60 s or less).

The data come from the independent generator (``tests/independent_rig``, no code shared with the
simulator the diagnosis replays through): a linear X sweep of 40 N on the lubricated rig,
15 -> 75 Hz, 100,000 samples at 5 kS/s (20 s), one probe and one accelerometer, seeded sensor
noise, with a hidden softening cubic spring (k3 = -5e13 N/m^3: 20 % of K at 35 um), written
as the canonical CSV and imported by the real ``sfdrig import`` path (a frequency column that
changes every sample: recorded as a sweep, not dwells), the rig described correctly with
``--rig`` as in the independent cases (no seal, the film's centred damping). The diagnosis is
then timed as a user runs it: fitted baseline, every applicable effect, rounds, bootstrap,
verdict. Prints wall and CPU time and what was found.

    .venv/bin/python benchmarks/bench_diagnose_sweep.py [--samples 100000] [--seed 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.diagnose import diagnose, load_run  # noqa: E402
from analysis.diagnose.report import order_label, order_status  # noqa: E402
from sfdrig.cli import main as sfdrig_main  # noqa: E402
from tests.analysis.independent_cases import RIG_TOML  # noqa: E402
from tests.independent_rig import Generator, RigSpec, Sensors, Sweep  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--fs", type=float, default=5000.0)
    ap.add_argument("--k3", type=float, default=-5e13, help="hidden cubic spring [N/m^3]")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--no-rig", action="store_true",
                    help="import without the rig description (fitted linear baseline, the "
                         "film's centred damping and added mass) instead of the correct one")
    args = ap.parse_args()
    duration = args.samples / args.fs
    k3 = args.k3
    spec = RigSpec(extra_forces=[lambda t, z, v: -k3 * z**3] if k3 else [])
    gen = Generator(spec, Sensors(seed=args.seed), fs_hz=args.fs)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rec = gen.run([Sweep(15.0, 75.0, duration, force_n=40.0, motion="x")])
        csv = Path(tmp) / "sweep.csv"
        rec.to_csv(csv)
        out = Path(tmp) / "sweep.h5"
        rig_args: list[str] = []
        if not args.no_rig:
            rig = Path(tmp) / "rig.toml"
            rig.write_text(RIG_TOML)
            rig_args = ["--rig", str(rig)]
        rc = sfdrig_main(["import", str(csv), "--out", str(out), "--lubricated", "--motion",
                          "x", "--seal", "none", *rig_args])
        if rc != 0:
            raise SystemExit(f"sfdrig import failed on {csv} (exit {rc})")
        t_gen = time.perf_counter() - t0
        record = load_run(out)
        w0, c0 = time.perf_counter(), time.process_time()
        diag = diagnose([record], seed=args.seed)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    print(f"sweep: {record.n_samples} samples at {record.sample_rate_hz:g} S/s "
          f"({duration:.1f} s, 15 -> 75 Hz, 40 N; generated and imported in {t_gen:.1f} s)")
    print(f"hidden: cubic stiffness k3 = {k3:.3g} N/m^3; rig described: {not args.no_rig}; "
          f"baseline {diag.baseline_kind}")
    print(f"diagnose: {wall:.1f} s wall, {cpu:.1f} s CPU "
          f"({len(diag.rounds)} rounds, target 60 s)")
    for row in diag.order:
        print(f"  order: {order_label(row)}, held-out {row.get('held_out_error', float('nan')):.4g}"
              f" m ({order_status(row)})")
    for f in diag.findings:
        print(f"  found {f.effect} {f.parameters} gain {f.gain:.3g} "
              f"[{f.gain_interval[0]:.3g}, {f.gain_interval[1]:.3g}] "
              f"({f.evidence.get('confidence')} confidence; share of the signal "
              f"{f.evidence.get('share_of_signal_explained', float('nan')):.3g}"
              f"{', refinement' if f.evidence.get('refinement') else ''}"
              f"{', ambiguous' if f.evidence.get('ambiguous') else ''})")
    if diag.verdict is not None:
        v = diag.verdict
        print(f"  verdict: {v.text} (explained: baseline {v.baseline.explained:.4f}, final "
              f"{v.final.explained:.4f}; residual {v.final.residual_rms:.3g} against a noise "
              f"floor {v.final.noise_rms:.3g})")
    return 0 if wall <= 60.0 else 1


if __name__ == "__main__":
    sys.exit(main())
