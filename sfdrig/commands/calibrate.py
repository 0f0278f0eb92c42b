"""`sfdrig calibrate`: the reference report's test plan on the simulated rig, identified with the
report's procedure, compared with its measured tables; the responsible terms fitted and a
calibrated rig TOML written (`analysis.calibration`)."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

from analysis.calibration.compare import Comparison, compare, table_errors
from analysis.calibration.fit import Calibration, Simulate, calibrate
from analysis.calibration.plan import ReportPlan
from analysis.errors import AnalysisError
from analysis.identify import Identification, identify
from rig_model.params import NAMED_RIGS, RigParams, rig_params_named_or_file
from sfdrig.report_plan import run_report_plan

NAME = "calibrate"
HELP = ("run the report's test plan on the simulated rig, compare with the report's tables, fit "
        "the terms responsible and write a calibrated rig TOML")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("out/calibration"), metavar="DIR",
                        help="writes DIR/calibrated-rig.toml and DIR/calibration.json "
                             "(default: %(default)s)")
    parser.add_argument("--rig", default="nominal", metavar="NAME|RIG.toml",
                        help=f"the rig to start from: {' or '.join(NAMED_RIGS)} or a TOML file "
                             "(default: %(default)s)")
    parser.add_argument("--plan", choices=("full", "reduced"), default="full",
                        help="full: the report's amplitudes and frequencies; reduced: fewer "
                             "(minutes instead of several)")
    parser.add_argument("--compare-only", action="store_true",
                        help="only run the plan on --rig and compare with the report (no fit)")
    parser.add_argument("--seed", type=int, default=0, help="simulated rig seed")


def simulator(seed: int) -> Simulate:
    """Run a plan on a rig into a temporary directory and identify it there."""

    def simulate(params: RigParams, plan: ReportPlan) -> Identification:
        with tempfile.TemporaryDirectory(prefix="sfdrig-calibrate-") as tmp:
            paths = run_report_plan(Path(tmp), params, plan, seed=seed)
            with contextlib.redirect_stdout(io.StringIO()):
                return identify(paths)
    return simulate


def table_lines(cal: Calibration | None, rows: list[Comparison]) -> list[str]:
    """The side-by-side table: report, band, default rig, calibrated rig (ok = within)."""
    cal_rows = {r.key: r for r in cal.calibrated} if cal else {}
    head = f"{'table':<20} {'quantity':<36} {'axis':<4} {'report':>10} {'band':>9} {'default':>10}"
    lines = [head + (f" {'calibrated':>13} {'band':>9}  use" if cal else "")]
    for r in rows:
        line = (f"{r.table:<20} {r.quantity:<36} {r.axis:<4} {r.report:>10.4g} {r.band:>9.3g} "
                f"{r.simulated:>10.4g} {'ok' if r.within else '--'}")
        c = cal_rows.get(r.key)
        if cal and c is not None:
            line += f" {c.simulated:>10.4g} {'ok' if c.within else '--'} {c.band:>9.3g}  "
            line += "fit" if r.key in cal.fit_keys else "held out"
        lines.append(line)
    return lines


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except BrokenPipeError:
        raise  # stdout's reader has gone: the CLI stops quietly
    except (AnalysisError, ValueError, OSError, RuntimeError) as err:
        print("sfdrig calibrate: " + " ".join(str(err).split()), file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    start = rig_params_named_or_file(args.rig)
    args.out.mkdir(parents=True, exist_ok=True)
    plan = ReportPlan() if args.plan == "full" else ReportPlan.reduced()
    simulate = simulator(args.seed)
    if args.compare_only:
        rows = compare(simulate(start, plan))
        print("\n".join(table_lines(None, rows)))
        (args.out / "comparison.json").write_text(json.dumps(
            {"rig": str(args.rig), "comparisons": [r.to_dict() for r in rows],
             "per_table": table_errors(rows)}, indent=1))
        return 0
    cal = calibrate(simulate, plan, start, log=lambda s: print(s, flush=True))
    print()
    print("\n".join(table_lines(cal, cal.default)))
    print("\nper table (rows within the band; RMS of |error|/band): default -> calibrated")
    before, after = table_errors(cal.default), table_errors(cal.calibrated)
    for table, b in before.items():
        a = after.get(table, {"within": 0, "rms_normalised_error": float("nan")})
        print(f"  {table:<20} {b['within']:.0f}/{b['rows']:.0f} ({b['rms_normalised_error']:.2f})"
              f" -> {a['within']:.0f}/{b['rows']:.0f} ({a['rms_normalised_error']:.2f})")
    gain = cal.held_out_gain()
    for part in ("fit", "held_out"):
        g = gain[part]
        print(f"  {part.replace('_', ' '):<20} {g['default_within']:.0f}/{g['rows']:.0f} "
              f"({g['default_rms_normalised_error']:.2f}) -> {g['calibrated_within']:.0f}/"
              f"{g['rows']:.0f} ({g['calibrated_rms_normalised_error']:.2f})")
    print("\nfitted terms:")
    for t in cal.terms:
        print(f"  {t.name} = {t.fitted:.6g} {t.unit} (nominal {t.nominal}; from {t.fitted_to})"
              if isinstance(t.fitted, float) else
              f"  {t.name} = {t.fitted} (nominal {t.nominal}; from {t.fitted_to})")
    for r in cal.rejected:
        print(f"  not kept: {r}")
    toml = args.out / "calibrated-rig.toml"
    toml.write_text("# sfdrig calibrate: the simulated rig fitted to the reference report's "
                    f"tables ({args.plan} plan, from {args.rig})\n" + cal.params.to_toml())
    (args.out / "calibration.json").write_text(json.dumps(cal.to_json(), indent=1))
    print(f"\ncalibrated rig: {toml}\ndetails: {args.out / 'calibration.json'}")
    return 0
