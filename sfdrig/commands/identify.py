"""`sfdrig identify`: force coefficients from run files (the report's methods), with a report."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from analysis.errors import summarise_skipped
from analysis.identify import ANALYSES, RunSummary, identify, write_results
from analysis.report import build_report, summary_lines

NAME = "identify"
HELP = ("identify structure, seal and squeeze-film coefficients from run files; write a report "
        "(JSON, PNG figures, HTML)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN.h5", help="run files")
    parser.add_argument("--report", type=Path, metavar="DIR",
                        help="write report.json, figures/ and index.html into DIR")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write every table as JSON")
    parser.add_argument("--only", action="append", choices=ANALYSES, metavar="ANALYSIS",
                        help=f"run only these analyses (repeatable): {', '.join(ANALYSES)}")
    parser.add_argument("--velocity-harmonics", type=int, default=1, metavar="N",
                        help="displacement harmonics used to build V in eq. 3-4 (report: 1)")
    parser.add_argument("--no-store", action="store_true",
                        help="do not write results into the runs' /results group")


def run(args: argparse.Namespace) -> int:
    """The command. What the data lack is said in the skipped lines; a report or table that
    cannot be written is one line (exit 2); anything else is a defect, for the CLI to name
    (exit 70), never a traceback."""
    try:
        return _run(args)
    except BrokenPipeError:
        raise  # stdout's reader has gone: the CLI stops quietly
    except OSError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    ident = identify(args.runs, args.only, velocity_harmonics=args.velocity_harmonics)
    if ident.runs and all(r.n_steps == 0 for r in ident.runs):
        print(f"error: {_no_steps(ident.runs)}", file=sys.stderr)
        return 2
    if not args.no_store:
        ident.skipped.extend(write_results(ident))
    for line in summary_lines(ident):
        print(line)
    for note in ident.notes:
        print(f"note: {note}", file=sys.stderr)
    for line in summarise_skipped(ident.skipped):
        print(f"skipped: {line}", file=sys.stderr)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(ident.to_json(), indent=1, allow_nan=False))
        print(f"tables: {args.json}")
    if args.report:
        page = build_report(ident, args.report)
        print(f"report: {page}")
    identified = (ident.dry or ident.lubricated or ident.static or ident.impact or ident.probe
                  or ident.flow)
    if not ident.runs:
        print("error: no run file could be opened", file=sys.stderr)
        return 2
    if not identified:
        print(f"error: {', '.join(str(p) for p in args.runs)}: nothing identified "
              f"({len(ident.skipped)} item(s) skipped, reasons above)", file=sys.stderr)
        return 1
    return 0


def _no_steps(runs: list[RunSummary]) -> str:
    """Why runs without a step cannot be identified, and what to do."""
    names = ", ".join(Path(r.path).name for r in runs)
    if all(r.kind == "imported" for r in runs):
        return (f"{names}: no steps (dwells) to identify: import the data with its frequency "
                "(--map freq_hz=COLUMN, --map step=COLUMN or --freq-hz HZ); a record without "
                "steps is for sfdrig diagnose")
    how = ", ".join(f"{Path(r.path).name}: {r.kind}, {r.status}" for r in runs)
    return f"{names}: no steps (dwells) to identify: the runs recorded none ({how})"
