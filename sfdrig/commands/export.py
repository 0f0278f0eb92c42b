"""`sfdrig export`: run files to MATLAB .mat, CSV or NI TDMS, for the lab's own tools."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from sfdrig.commands._batch import run_each
from storage.errors import ExportError, RunFileError
from storage.exporters import WRITERS, export_run

NAME = "export"
HELP = ("export run files to MATLAB .mat, CSV or NI TDMS: signals in engineering units, drives, "
        "steps, harmonics and conditions (sfdrig import reads them back)")
#: Samples x columns above which an export reports its progress.
PROGRESS_VALUES = 20_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN.h5", help="run files")
    parser.add_argument("--to", required=True, choices=tuple(WRITERS), help="format")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR",
                        help="folder for the exported files (created if missing); each run "
                             "becomes RUN.mat, RUN.tdms or RUN.csv with its tables beside it")
    parser.add_argument("--steps", default=None, metavar="N|N-M",
                        help="only these steps (counted from 1 as sweep's table and watch "
                             "count them, inclusive) and the samples of their records; time_s "
                             "stays the run's time")
    parser.add_argument("--channels", action="append", default=None, metavar="NAME[,NAME]",
                        help="only these input channels (repeatable); the drives are always "
                             "exported")
    parser.add_argument("--overwrite", action="store_true", help="replace existing files")


class _Progress:
    """One line per tenth of a large export, on stderr."""

    def __init__(self, run: Path) -> None:
        self.run = run
        self.next_tenth = 1
        self.t0 = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        if total <= 0:
            return
        while done * 10 >= self.next_tenth * total and self.next_tenth <= 10:
            print(f"  {self.run.name}: {10 * self.next_tenth} % ({done:,} of {total:,} samples, "
                  f"{time.monotonic() - self.t0:.1f} s)", file=sys.stderr, flush=True)
            self.next_tenth += 1


def _size(run: Path) -> int:
    from storage import open_run

    with open_run(run) as r:
        return r.n_samples * (len(r.channel_names) + len(r.drive_names))


def run(args: argparse.Namespace) -> int:
    def one(path: Path) -> None:
        t0 = time.monotonic()
        progress = _Progress(path) if _size(path) > PROGRESS_VALUES else None
        files = export_run(path, args.to, args.out, steps=args.steps, channels=args.channels,
                           progress=progress, overwrite=args.overwrite)
        print(f"{path} -> {', '.join(str(f) for f in files)} ({time.monotonic() - t0:.1f} s)")

    return 2 if run_each(args.runs, one, (ExportError, RunFileError)) else 0
