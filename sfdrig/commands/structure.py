"""`sfdrig structure`: the structure and instrument tests of the report's sections IV-V and
Appendix A (static load steps, impact tests, eddy-current probe calibration, flow against
pressure) on the simulated rig, each stored as a run file that `sfdrig identify` reads."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from control.programs import (
    FlowSpec,
    ImpactSpec,
    ProbeCalSpec,
    StaticSpec,
    create_run_writer,
    run_flow_test,
    run_impact_test,
    run_probe_calibration,
    run_static_test,
)
from daq.channels import default_channel_map, load_channel_map
from sfdrig.simulated_operator import SimulatedHands, StandInOperator
from simulated_hw.backend import SimulatedBackend
from simulated_hw.params import RigParams, rig_params_named_or_file

NAME = "structure"
HELP = ("run the static, impact, probe-calibration and flow tests on the simulated rig and "
        "store one run file each")
TESTS = ("static", "impact", "probe_calibration", "flow")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("runs"), help="directory for the run files")
    p.add_argument("--rig", metavar="NAME|RIG.toml",
                   help="'nominal' (default), 'report' (calibrated) or a rig TOML")
    p.add_argument("--channels", type=Path, help="channel map TOML (default: the report's rig)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", choices=TESTS, action="append", help="run only these tests")
    p.add_argument("--operator", default="", help="name stored in the run files")


def run_structure_tests(out_dir: Path, params: RigParams, channels_path: Path | None = None,
                        seed: int = 0, only: list[str] | None = None,
                        operator: str = "", quiet: bool = False) -> list[Path]:
    """Run the tests and return the run files written, in order."""
    out_dir.mkdir(parents=True, exist_ok=True)
    cm = load_channel_map(channels_path) if channels_path else default_channel_map()
    written: list[Path] = []
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    for i, kind in enumerate(only or TESTS):
        test_params = params.model_copy(deep=True)
        if kind in ("static", "impact", "probe_calibration"):
            # the report's static and impact tests ran without the journal: no seal contact
            test_params.seal.enabled = False
        backend = SimulatedBackend(test_params, seed=seed + i)
        backend.configure(cm)
        hands = SimulatedHands(backend)
        run_id = f"{stamp}-{kind}"
        path = out_dir / f"{run_id}.h5"
        spec: StaticSpec | ImpactSpec | ProbeCalSpec | FlowSpec
        spec = {"static": StaticSpec, "impact": ImpactSpec, "probe_calibration": ProbeCalSpec,
                "flow": FlowSpec}[kind]()
        writer = create_run_writer(path, kind, backend, run_id=run_id,
                                   rig_config=test_params, test_spec=spec, operator=operator,
                                   lubricated=kind == "flow", overwrite=True)
        desk = StandInOperator(_logged_to(writer))
        if not quiet:
            print(f"{kind}: running ...", flush=True)
        if isinstance(spec, StaticSpec):
            outcome = run_static_test(backend, writer, spec, operator=desk, hands=hands)
        elif isinstance(spec, ImpactSpec):
            outcome = run_impact_test(backend, writer, desk, spec, hands=hands)
        elif isinstance(spec, ProbeCalSpec):
            outcome = run_probe_calibration(backend, writer, desk, spec, hands=hands)
        else:
            outcome = run_flow_test(backend, writer, desk, spec, hands=hands)
        status = "completed" if outcome.completed else "aborted"
        writer.close(status, outcome.reason)
        backend.close()
        why = f": {outcome.reason}" if outcome.reason else ""
        if not quiet:
            print(f"{kind}: {outcome.steps} steps, {status}{why} -> {path}", flush=True)
        written.append(path)
    return written


def _logged_to(writer: Any) -> Callable[[str, str], None]:
    return lambda kind, message: writer.on_event(kind, message, writer.samples_received)


def run(args: argparse.Namespace) -> int:
    try:
        params = rig_params_named_or_file(args.rig) if args.rig else RigParams()
        run_structure_tests(args.out, params, args.channels, args.seed, args.only, args.operator)
    except (ValueError, OSError) as err:
        print(f"sfdrig structure: {err}", file=sys.stderr)
        return 2
    return 0
