"""`sfdrig runs`: list the run files of a runs directory (id, date, kind, steps, status,
conditions, ...), filtered and a page at a time, from the run index (`storage.catalog`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from storage.catalog import (
    FILTERS,
    INDEX_NAME,
    RUNS_DIR_ENV,
    default_runs_dir,
    format_table,
    parse_filter,
    select_runs,
)

NAME = "runs"
HELP = "list recorded runs (id, date, kind of test, steps, status, duration, conditions, file)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs-dir", "--dir", dest="dir", type=Path, default=None,
                        help=f"runs directory, as the other commands name it (--dir: the old "
                             f"name; default: ${RUNS_DIR_ENV} or ./runs); its run index "
                             f"({INDEX_NAME}) is kept up to date from the files")
    parser.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    for key in ("kind", "status", "since", "until", "seal", "motion", "limit", "offset"):
        parser.add_argument(f"--{key}", default=None, help=FILTERS[key])
    oil = parser.add_mutually_exclusive_group()
    oil.add_argument("--lubricated", dest="lubricated", action="store_const", const="yes",
                     default=None, help="runs with the oil film only")
    oil.add_argument("--dry", dest="lubricated", action="store_const", const="no",
                     help="dry runs only")
    parser.add_argument("--newest-first", action="store_true",
                        help="newest first (default: oldest first, unreadable files last)")


def run(args: argparse.Namespace) -> int:
    directory = args.dir if args.dir is not None else default_runs_dir()
    try:
        flt = parse_filter({key: getattr(args, key) for key in FILTERS},
                           newest_first=args.newest_first)
    except ValueError as err:
        print(f"error: sfdrig runs: {err}", file=sys.stderr)
        return 2
    try:
        page = select_runs(directory, flt, notice=lambda m: print(m, file=sys.stderr))
    except (FileNotFoundError, NotADirectoryError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps([r.to_dict() for r in page.rows], indent=2))
    elif page.rows:
        print(format_table(page.rows))
        if len(page.rows) < page.total:
            print(f"rows {page.offset + 1}-{page.offset + len(page.rows)} of {page.total} "
                  f"(--offset {page.offset + len(page.rows)} for the next)"
                  if page.offset + len(page.rows) < page.total else
                  f"rows {page.offset + 1}-{page.offset + len(page.rows)} of {page.total}")
    elif page.total:
        print(f"no rows from offset {page.offset}: {page.total} runs match")
    elif any(getattr(args, key) for key in FILTERS):
        print(f"no runs in {directory} match")
    else:
        print(f"no run files in {directory}")
    return 0
