"""`sfdrig runs`: list the run files of a runs directory (id, date, kind, steps, status, ...)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from storage.catalog import RUNS_DIR_ENV, default_runs_dir, format_table, scan_runs

NAME = "runs"
HELP = "list recorded runs (id, date, kind of test, steps, status, duration, file)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs-dir", "--dir", dest="dir", type=Path, default=None,
                        help=f"runs directory, as the other commands name it (--dir: the old "
                             f"name; default: ${RUNS_DIR_ENV} or ./runs)")
    parser.add_argument("--json", action="store_true", help="print a JSON list instead of a table")


def run(args: argparse.Namespace) -> int:
    directory = args.dir if args.dir is not None else default_runs_dir()
    try:
        rows = scan_runs(directory)
    except (FileNotFoundError, NotADirectoryError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps([r.to_dict() for r in rows], indent=2))
    elif rows:
        print(format_table(rows))
    else:
        print(f"no run files in {directory}")
    return 0
