"""The reference report's test plan on the simulated rig, in process (fast mode).

Static load steps and impacts without the journal (section IV.1-2), dry circular load orbits at
the report's loads (section IV.3: 40 and 33 N), and lubricated unidirectional dwells along X and Y
at its amplitudes and frequencies (section VI.1, Table 5: 13-38 um, 20-60 Hz in 10 Hz steps).
Each test is one run file that `analysis.identify` reads.
"""

from __future__ import annotations

from pathlib import Path

from analysis.calibration.plan import ReportPlan
from control.run.files import create_run_writer
from control.run.pump import PumpRelay
from control.run.safety import SafetyLimits
from control.run.sweep.engine import SweepEngine, SweepSpec, sweep_spec_from_dict
from daq.channels import default_channel_map
from rig_model.params import RigParams
from sfdrig.commands.structure import run_structure_tests
from simulated_hw.backend import SimulatedBackend

DRY_LIMITS = SafetyLimits(max_displacement_m=110e-6)


def run_report_plan(out_dir: Path, params: RigParams, plan: ReportPlan | None = None,
                    seed: int = 0, log: bool = False) -> list[Path]:
    """Run ``plan`` on the simulated rig ``params``; return the run files written."""
    plan = plan or ReportPlan()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = (run_structure_tests(out_dir, params, seed=seed, only=list(plan.structure),
                                 quiet=not log) if plan.structure else [])
    for i, load in enumerate(plan.dry_loads_n):
        spec = SweepSpec(name=f"report plan: dry circular orbit {load:g} N",
                         motion="circular_forward", lubricated=False, load_n=[load],
                         freq_hz=list(plan.dry_freqs_hz))
        paths.append(_sweep(out_dir / f"dry-{load:g}N.h5", params, spec, seed + 10 + i, log))
    for i, axis in enumerate(plan.lub_axes if plan.lub_amplitudes_m else ()):
        spec = sweep_spec_from_dict({
            "name": f"report plan: lubricated unidirectional {axis.upper()}", "motion": axis,
            "lubricated": True, "amplitude_m": list(plan.lub_amplitudes_m),
            "freq_hz": list(plan.lub_freqs_hz)})
        paths.append(_sweep(out_dir / f"lubricated-{axis}.h5", params, spec, seed + 20 + i, log))
    return paths


def _sweep(path: Path, params: RigParams, spec: SweepSpec, seed: int, log: bool) -> Path:
    backend = SimulatedBackend(params.model_copy(deep=True), seed=seed)
    backend.configure(default_channel_map())
    pump = None
    if spec.lubricated:
        pump = PumpRelay(backend)
        pump.set(True)
    writer = create_run_writer(path, "sweep", backend.channel_map, run_id=path.stem,
                               rig_config=params, test_spec=spec, lubricated=spec.lubricated,
                               overwrite=True, paced=backend.realtime, board=backend.board)
    outcome = SweepEngine(backend, spec, limits=None if spec.lubricated else DRY_LIMITS,
                          listener=writer, pump=pump).run()
    writer.close(outcome.status, outcome.reason)
    if outcome.status != "completed":
        raise RuntimeError(f"{spec.name}: {outcome.status} ({outcome.reason})")
    if log:
        print(f"{spec.name}: {len(spec.steps())} steps -> {path}", flush=True)
    return path
