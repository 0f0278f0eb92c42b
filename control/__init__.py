"""Shaker control: synthesis, lock-in, amplitude controller, safety, pump relay, sweep engine.

Modules (each small, one responsibility):

- `control.synthesis`: phase-continuous sine synthesis with ramps (`SineSynthesizer`).
- `control.lockin`: least-squares lock-in over whole cycles, 1X..5X (`LockIn`).
- `control.controller`: the 2x2 Newton-Broyden amplitude controller (`AmplitudeController`),
  motion shapes, the drive predictor, and a plain proportional loop for comparison.
- `control.safety`: `SafetyLimits`, the per-block `SafetyMonitor`, `validate_targets`.
- `control.pump`: `PumpRelay` and its interlock with the shakers.
- `control.stream`: block-wise AO/AI streaming with the safe shutdown (`DriveStream`).
- `control.dwell`: one step (ramp, converge, settle, record); `control.approach`: the margins
  and the anticipating moves (start, watched raise, break-away); `control.step_result`.
- `control.spec`, `control.sweep`: `SweepSpec` (TOML) and the `SweepEngine` (contract C).
- `control.listener`: the `Listener` protocol (contract A), the one `FanOut`, and helpers.
- `control.errors`: `TargetError`, `InterlockError`, `LimitTrip`, ...
"""
