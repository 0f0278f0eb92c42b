"""`sfdrig import`: turn measured data from elsewhere (CSV, .mat, TDMS) into a run file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from storage import open_run
from storage.errors import ImportDataError
from storage.importers import CANONICAL, import_file, parse_assignments, parse_scale
from storage.runfile import KINDS

NAME = "import"
HELP = "import measured data (CSV, MATLAB .mat, NI TDMS) into a run file, all or nothing"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="measured data: .csv/.txt, .mat or .tdms")
    parser.add_argument("--out", type=Path, required=True, help="run file to create (.h5)")
    parser.add_argument(
        "--map", action="append", default=[], metavar="CANONICAL=COLUMN",
        help="use COLUMN (CSV column, .mat variable or NAME(:,COL), TDMS [GROUP/]CHANNEL) as "
             f"CANONICAL, one of {', '.join(CANONICAL)}; repeatable",
    )
    parser.add_argument("--fs", type=float, default=None, metavar="HZ",
                        help="sample rate [Hz] when the file has no time_s column")
    parser.add_argument("--scale", action="append", default=[], metavar="CANONICAL=FACTOR",
                        help="multiply a signal by FACTOR (e.g. x_m=1e-6 for micrometres)")
    parser.add_argument("--kind", default="imported", choices=KINDS, help="kind of test")
    parser.add_argument("--notes", default="", help="free-text notes stored in the run")
    parser.add_argument("--operator", default="", help="who measured or imported it")
    parser.add_argument("--run-id", default=None, help="run id (default: imported-<time>-<out>)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")


def run(args: argparse.Namespace) -> int:
    try:
        out = import_file(
            args.file, args.out, mapping=parse_assignments(args.map, "--map"), fs_hz=args.fs,
            scale=parse_scale(args.scale), kind=args.kind, notes=args.notes,
            operator=args.operator, run_id=args.run_id, overwrite=args.overwrite,
        )
    except ImportDataError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    with open_run(out) as run_data:
        print(f"{out}: run {run_data.run_id!r}, {run_data.n_samples} samples at "
              f"{run_data.sample_rate_hz:g} Hz ({run_data.duration_s:.3f} s), channels "
              f"{', '.join(run_data.channel_names)}, {len(run_data.steps)} steps")
    return 0
