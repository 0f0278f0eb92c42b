"""How far the housing moves after a trip: the peak orbit radius after a displacement trip caused
by an outside change of the shaker gain (an amplifier knob turned x3, at once or over a ramp),
on the dry rig near its resonance, for the AO lead and trip fade in use and shorter ones.

    .venv/bin/python benchmarks/bench_trip.py [--quick]

Issue 11's target: the peak after any trip at most 10 % past the displacement limit (63.5 um).
The drive the trip can stop is the one not yet written: the AO lead (``ahead_blocks`` x
``block_s``) still plays at the new gain, then the fade (`SafetyLimits.fade_s`) begins.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from control.listener import RecordingListener  # noqa: E402
from control.safety import AxisSignals, SafetyLimits  # noqa: E402
from control.sweep import SweepEngine, SweepSpec  # noqa: E402
from daq.channels import default_channel_map  # noqa: E402
from simulated_hw.backend import SimulatedBackend  # noqa: E402
from simulated_hw.params import RigParams  # noqa: E402

FS = 10_000.0
CHANGE_AT_S = 1.0  # the step has converged and is recording by then


class GainChange(RecordingListener):
    """Turns the simulated amplifier gain from 1 to ``gain`` times over ``ramp_s`` from
    `CHANGE_AT_S`, and keeps the largest measured orbit radius and when it occurred."""

    def __init__(self, backend: SimulatedBackend, gain: float, ramp_s: float) -> None:
        super().__init__(keep_blocks=False)
        self.backend, self.gain, self.ramp = backend, gain, ramp_s * FS
        self.at = int(CHANGE_AT_S * FS)
        self.signals = AxisSignals.from_channel_map(default_channel_map())
        self.peak_m, self.peak_sample = 0.0, 0
        assert backend.rig is not None
        self.g0 = backend.rig.params.shaker.force_per_volt_n

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        super().on_block(first_sample, ai, ao)
        d = self.signals.displacement(ai)
        r = np.hypot(d[0], d[1])
        if r.max() > self.peak_m:
            self.peak_m, self.peak_sample = float(r.max()), first_sample + int(np.argmax(r))
        end = first_sample + ai.shape[1]
        if end >= self.at:
            frac = 1.0 if self.ramp <= 0 else min(1.0, (end - self.at) / self.ramp)
            rig = self.backend.rig
            assert rig is not None
            sh = rig.params.shaker
            g = self.g0 * (1.0 + (self.gain - 1.0) * frac)
            if g != sh.force_per_volt_n:
                rig.params = rig.params.model_copy(
                    update={"shaker": sh.model_copy(update={"force_per_volt_n": g})})


def run(motion: str, amp_m: float, freq_hz: float, ramp_s: float, block_s: float, ahead: int,
        fade_s: float) -> tuple[str, float, float]:
    be = SimulatedBackend(RigParams(), seed=0)
    be.configure(default_channel_map())
    spec = SweepSpec(motion=motion, amplitude_m=[amp_m], freq_hz=[freq_hz],
                     control={"block_s": block_s, "ahead_blocks": ahead})
    rec = GainChange(be, 3.0, ramp_s)
    limits = SafetyLimits(fade_s=fade_s)
    SweepEngine(be, spec, limits=limits, listener=rec).run()
    trips = rec.events_of("limit_trip")
    if not trips:
        return "no trip", rec.peak_m / limits.displacement_limit_m, float("nan")
    trip_sample = trips[0][2]
    return (trips[0][1].split(":")[0].split(" ")[0], rec.peak_m / limits.displacement_limit_m,
            (rec.peak_sample - trip_sample) / FS)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one case instead of three")
    args = ap.parse_args(argv)
    cases = [("x", 30e-6, 40.0), ("circular_forward", 30e-6, 45.0), ("x", 40e-6, 60.0)]
    if args.quick:
        cases = cases[:1]
    configs = [(0.01, 3, 0.04), (0.01, 3, 0.01), (0.01, 1, 0.01)]
    print("command: .venv/bin/python benchmarks/bench_trip.py "
          + " ".join(argv if argv is not None else sys.argv[1:]))
    print("dry rig, seal on; amplifier gain x3 from t = 1 s (at once, or over 0.1 / 0.5 s); "
          "limit 63.5 um, journal at 127 um (2.0 x the limit)\n")
    head = (f"{'motion':17} {'target':>9} {'gain x3 over':>12} {'AO lead':>8} {'fade':>6} "
            f"{'trip':>13} {'peak/limit':>10} {'peak after trip':>15}")
    print(head)
    print("-" * len(head))
    for motion, amp, freq in cases:
        for ramp in (0.0, 0.1, 0.5):
            for block, ahead, fade in configs:
                what, ratio, after = run(motion, amp, freq, ramp, block, ahead, fade)
                print(f"{motion:17} {amp * 1e6:3.0f} um {freq:2.0f} Hz {ramp:10.1f} s "
                      f"{block * ahead * 1e3:5.0f} ms {fade * 1e3:3.0f} ms {what:>13} "
                      f"{ratio:10.2f} {after * 1e3:12.0f} ms", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
