"""Benchmark: identification and report on the report's full lubricated test plan.

Records (simulated rig, fast mode) a dry circular sweep (2 loads x 7 frequencies) and the
lubricated plan of section VI.1 (5 amplitudes 13-38 um x 20-60 Hz, 40 recorded cycles), then
times `identify` (reading, harmonics, fits), `build_report` (figures, JSON, HTML) and the
writing of /results. Run: ``.venv/bin/python benchmarks/bench_identify.py [--cycles N]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from analysis.identify import identify, write_results
from analysis.report import build_report
from control.run.files import create_run_writer
from control.run.pump import PumpRelay
from control.run.safety import SafetyLimits
from control.run.sweep.engine import SweepEngine, SweepSpec
from daq.channels import default_channel_map
from rig_model.params import RigParams
from simulated_hw.backend import SimulatedBackend


def record(path: Path, spec: SweepSpec, seed: int, limits: SafetyLimits | None = None) -> float:
    params = RigParams()
    b = SimulatedBackend(params, seed=seed)
    b.configure(default_channel_map())
    w = create_run_writer(path, "sweep", b.channel_map, run_id=path.stem, rig_config=params,
                          test_spec=spec, lubricated=spec.lubricated)
    pump = None
    if spec.lubricated:
        pump = PumpRelay(b)
        pump.set(True)
    out = SweepEngine(b, spec, limits=limits, listener=w, pump=pump).run()
    w.close("completed" if out.status == "completed" else "aborted", out.reason)
    return out.samples / out.sample_rate_hz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--cycles", type=int, default=40, help="recorded cycles per dwell")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        rig_s = record(d / "dry.h5", SweepSpec(
            motion="circular_forward", load_n=[40.0, 33.0],
            freq_hz=[20.0, 30.0, 60.0, 80.0, 100.0, 150.0, 200.0], record_cycles=args.cycles),
            1, SafetyLimits(max_displacement_m=100e-6))
        rig_s += record(d / "lub.h5", SweepSpec(
            motion="x", lubricated=True, amplitude_m=[13e-6, 19e-6, 25e-6, 32e-6, 38e-6],
            freq_start_hz=20.0, freq_stop_hz=60.0, freq_step_hz=10.0,
            record_cycles=args.cycles), 2)
        t_rec = time.perf_counter() - t0
        paths = [d / "dry.h5", d / "lub.h5"]
        mb = sum(p.stat().st_size for p in paths) / 1e6
        t0 = time.perf_counter()
        ident = identify(paths)
        t_id = time.perf_counter() - t0
        n_dwells = sum(len(v) for v in ident.dwells.values())
        t0 = time.perf_counter()
        problems = write_results(ident)
        t_res = time.perf_counter() - t0
        t0 = time.perf_counter()
        build_report(ident, d / "report")
        t_rep = time.perf_counter() - t0
        n_fig = len(list((d / "report" / "figures").glob("*.png")))
    print(f"recorded {rig_s:.1f} s of rig time ({mb:.1f} MB) in {t_rec:.1f} s")
    print(f"identify: {n_dwells} dwells in {t_id:.2f} s ({1e3 * t_id / n_dwells:.1f} ms/dwell)")
    print(f"/results written in {t_res:.2f} s ({len(problems)} problems)")
    print(f"report: {n_fig} figures, JSON and HTML in {t_rep:.2f} s")
    if ident.dry is not None:
        print(f"  F_mu = {ident.dry.f_mu_n:.2f} N, C_rv = {ident.dry.c_rv_ns_per_m:.0f} N.s/m")
    for g in ident.lubricated.sfd_by_amplitude if ident.lubricated else []:
        print(f"  {g['amplitude_m'] * 1e6:4.1f} um: C_sfd {g['eq9']['C_sfd_mean_Ns_per_m']:.0f} "
              f"(eq. 9) / {g['stick_slip']['C_sfd_mean_Ns_per_m']:.0f} (stick-slip) N.s/m")


if __name__ == "__main__":
    main()
