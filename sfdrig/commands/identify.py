"""`sfdrig identify`: force coefficients from run files (the report's methods), with a report."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from analysis.identify import ANALYSES, identify, write_results
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
    """The command; anything unforeseen ends in one line naming the run files, never a
    traceback (the internals raise their own errors where they know the column or step)."""
    try:
        return _run(args)
    except Exception as err:  # noqa: BLE001 - the CLI's last line of defence
        where = ", ".join(str(p) for p in args.runs)
        print(f"error: {where}: {type(err).__name__}: {err}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    ident = identify(args.runs, args.only, velocity_harmonics=args.velocity_harmonics)
    if not args.no_store:
        ident.skipped.extend(write_results(ident))
    for line in summary_lines(ident):
        print(line)
    for s in ident.skipped:
        print(f"skipped: {s.message}", file=sys.stderr)
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
