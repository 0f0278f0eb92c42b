"""Benchmark of the amplitude control: rig time per converged step against the ideal, and
controller updates per step, for the report's lubricated and dry sweeps, with the 2x2
Newton-Broyden controller and a plain proportional level controller side by side.

    .venv/bin/python benchmarks/bench_control.py [--seed N] [--quick]

Ideal time of a step = settling plus recording = (settle_cycles + record_cycles) / f: what a
controller that hit the target with its first drive would need. Rig time of a step = from the
start of its ramp to the end of its recording (samples / fs), so it includes the ramp, every
correction, and the settling after the last one. Targets: <= 1.3 x ideal and <= 4 updates per
step on the lubricated rig.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from control.run.listener import NullListener  # noqa: E402
from control.run.pump import PumpRelay  # noqa: E402
from control.run.safety import SafetyLimits  # noqa: E402
from control.run.sweep.engine import SweepEngine, SweepSpec  # noqa: E402
from daq.channels import default_channel_map  # noqa: E402
from rig_model.params import RigParams  # noqa: E402
from simulated_hw.backend import SimulatedBackend  # noqa: E402

CONTROLLERS = {
    "newton-broyden 2x2 (default)": {"algorithm": "newton_broyden", "predict": True},
    "plain proportional, gain 1": {"algorithm": "proportional", "predict": False},
    "plain proportional, gain 0.5": {"algorithm": "proportional", "predict": False,
                                     "proportional_gain": 0.5},
}


@dataclass
class Row:
    case: str
    controller: str
    steps: int
    converged: int
    ratio_total: float
    ratio_max: float
    updates_mean: float
    updates_max: int
    rig_s: float
    wall_s: float
    status: str


def run_case(case: str, controller: dict, seed: int, quick: bool) -> Row:
    if case == "lubricated X, 13-38 um, 20-60 Hz":
        params = RigParams()
        amps = [13e-6, 38e-6] if quick else [13e-6, 19e-6, 25e-6, 32e-6, 38e-6]
        spec = SweepSpec(motion="x", lubricated=True, amplitude_m=amps, freq_start_hz=20,
                         freq_stop_hz=60, freq_step_hz=10, control=controller,
                         on_not_converged="continue")
        limits = SafetyLimits()
    else:
        params = RigParams()
        if "second mode" in case:
            params = RigParams.model_validate({"effects": {"second_mode": {"enabled": True}}})
        spec = SweepSpec(motion="circular_forward", load_n=[40.0], freq_start_hz=20,
                         freq_stop_hz=200, freq_step_hz=10, control=controller,
                         on_not_converged="continue")
        # 40 N moves the dry rig past the displacement margin near its resonances: those steps
        # stop with that reason and are left out of time/ideal (a limit at the journal is refused)
        limits = SafetyLimits()
    be = SimulatedBackend(params, seed=seed)
    be.configure(default_channel_map())
    pump = None
    if spec.lubricated:
        pump = PumpRelay(be)
        pump.set(True)
    engine = SweepEngine(be, spec, limits=limits, listener=NullListener(), pump=pump)
    t0 = time.perf_counter()
    out = engine.run()
    wall = time.perf_counter() - t0
    fs = out.sample_rate_hz
    ok = [r for r in out.steps if r.converged]
    rig = np.array([(r.last_sample - r.start_sample) / fs for r in ok])
    ideal = np.array([spec.ideal_step_s(r.plan.freq_hz) for r in ok])
    upd = np.array([r.updates for r in out.steps])
    return Row(
        case, next(k for k, v in CONTROLLERS.items() if v == controller), len(out.steps),
        len(ok), float(rig.sum() / ideal.sum()) if ok else float("nan"),
        float((rig / ideal).max()) if ok else float("nan"),
        float(upd.mean()) if upd.size else float("nan"), int(upd.max()) if upd.size else 0,
        out.rig_time_s, wall, out.status + (f" ({out.reason})" if out.reason else ""),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="two amplitudes instead of five")
    args = ap.parse_args(argv)
    cases = ["lubricated X, 13-38 um, 20-60 Hz", "dry circular 40 N, 20-200 Hz",
             "dry circular 40 N, 20-200 Hz, second mode 39 Hz"]
    rows = [run_case(c, ctl, args.seed, args.quick) for c in cases for ctl in CONTROLLERS.values()]
    print("command: .venv/bin/python benchmarks/bench_control.py "
          + " ".join(argv if argv is not None else sys.argv[1:]))
    print("settle 10 + record 40 cycles per step; tolerance +/-1 %, +/-1 deg; fs 10 kS/s\n")
    head = (f"{'case':48} {'controller':29} {'steps':>5} {'conv':>4} {'time/ideal':>10} "
            f"{'worst':>6} {'upd/step':>8} {'max':>4} {'rig s':>7} {'wall s':>6}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r.case:48} {r.controller:29} {r.steps:5d} {r.converged:4d} "
              f"{r.ratio_total:10.3f} {r.ratio_max:6.2f} {r.updates_mean:8.2f} "
              f"{r.updates_max:4d} {r.rig_s:7.1f} {r.wall_s:6.2f}")
    print("\nhow each run ended:")
    for r in rows:
        print(f"  {r.case} / {r.controller}: {r.status}")
    print("\ntime/ideal: sum over converged steps of (ramp start -> end of recording) / sum of "
          "(settle + record); worst: the largest single-step ratio")
    lub = rows[0]
    print(f"lubricated target (<= 1.3 x ideal, <= 4 updates/step): time {lub.ratio_total:.3f} "
          f"x, updates mean {lub.updates_mean:.2f}, max {lub.updates_max}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
