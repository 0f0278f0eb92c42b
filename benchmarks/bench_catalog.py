"""How fast the run catalog answers at a lab's year of runs: 10,000 small run files (sweeps,
static tests and imports; completed, aborted, failed; dry and lubricated; three seals, three
motions; start times over a year), listed and filtered through the run index
(`storage.run_index`), and the index rebuilt from the files.

Times: the first look with no index (every header read: the rebuild, and what every look cost
before the index), a look with the index in place (every file's stat checked, nothing read),
filters (kind, status, dates, lubricated/seal/motion, a page), and the look after 10 files changed.
CPU time (user + sys) beside wall time: the machine may be shared.

Usage: .venv/bin/python benchmarks/bench_catalog.py [--runs 10000] [--dir DIR] [--keep]
(``--dir`` with ``--keep`` makes the files once and reuses them: they are made only when the
directory holds fewer than ``--runs``.)
"""

from __future__ import annotations

import argparse
import itertools
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage import RunWriter
from storage.catalog import RunFilter, parse_filter, scan_runs, select_runs
from storage.layout import LIBVER
from storage.records import StepRecord
from storage.run_index import INDEX_NAME

KINDS = ("sweep", "static", "imported")
STATUSES = ("completed", "completed", "aborted", "failed")
SEALS = (None, 0.0, 26.0)  # not stated, none, F_mu = 26 N
MOTIONS = ("x", "y", "circular_forward")


def _template(path: Path, kind: str, status: str, lubricated: bool, seal: float | None,
              motion: str) -> None:
    """One small real run file (2 AI, 1 drive, 1 s at 1 kS/s, 3 steps)."""
    rig = None if seal is None else {"seal": {"enabled": seal > 0, "friction_force_n": seal}}
    with RunWriter.create(path, "template", kind, ["fx", "x"], ["shaker_x"], 1000.0,
                          test_spec={"motion": motion}, rig_config=rig, lubricated=lubricated,
                          swmr=False, flush_interval_s=0, overwrite=True) as w:
        w.on_block(0, np.zeros((2, 1000)), np.zeros((1, 1000)))
        for i in range(3):
            w.on_step(StepRecord.from_wire({"index": i, "freq_hz": 20.0 * (i + 1), "motion": motion,
                       "first_sample": 300 * i, "last_sample": 300 * (i + 1)}))
        if status != "completed":
            w.close(status, "bench")


def make_runs(directory: Path, n: int) -> None:
    """``n`` run files in ``directory``: copies of the templates, each with its own run id and
    start time (one every 52 minutes or so, over a year)."""
    combos = list(itertools.product(KINDS, STATUSES, (False, True), SEALS, MOTIONS))
    tpl_dir = directory / "templates"
    tpl_dir.mkdir(exist_ok=True)
    templates = []
    for i, combo in enumerate(combos):
        p = tpl_dir / f"t{i:03d}.h5"
        _template(p, *combo)
        templates.append(p)
    start = datetime(2026, 1, 1, tzinfo=UTC)
    step = timedelta(days=365) / n
    for i in range(n):
        p = directory / f"run{i:05d}.h5"
        shutil.copyfile(templates[(i * 7) % len(templates)], p)
        with h5py.File(p, "r+", libver=LIBVER) as f:
            f.attrs["run_id"] = f"run-{i:05d}"
            f.attrs["start_time"] = (start + i * step).isoformat(timespec="milliseconds")
    shutil.rmtree(tpl_dir)


def _timed(call: Callable[[], Any]) -> tuple[Any, float, float]:
    c0, w0 = time.process_time(), time.perf_counter()
    out = call()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--dir", type=Path, default=None)
    ap.add_argument("--keep", action="store_true", help="keep the run files in --dir")
    args = ap.parse_args()
    tmp = None
    if args.dir is None or not args.keep:
        tmp = tempfile.TemporaryDirectory(dir=args.dir)
        d = Path(tmp.name)
    else:
        d = args.dir
        d.mkdir(parents=True, exist_ok=True)
    try:
        if len(list(d.glob("run*.h5"))) < args.runs:
            _, wall, cpu = _timed(lambda: make_runs(d, args.runs))
            print(f"made {args.runs:,} run files in {wall:.1f} s")
        (d / INDEX_NAME).unlink(missing_ok=True)
        rows, wall, cpu = _timed(lambda: scan_runs(d))
        print(f"rebuild (no index: every header read) of {len(rows):,} runs: {wall:.2f} s wall, "
              f"{cpu:.2f} s CPU")
        rows, wall, cpu = _timed(lambda: scan_runs(d))
        print(f"list all {len(rows):,}, index in place: {wall:.3f} s wall, {cpu:.3f} s CPU")
        filters: list[tuple[str, dict[str, str]]] = [
            ("newest 50 (the page)", {"limit": "50"}),
            ("kind=sweep", {"kind": "sweep"}),
            ("status=aborted,failed", {"status": "aborted,failed"}),
            ("since/until: March", {"since": "2026-03-01", "until": "2026-03-31"}),
            ("lubricated, seal none, motion x", {"lubricated": "yes", "seal": "none",
                                                 "motion": "x"}),
            ("page 3 of 100 sweeps", {"kind": "sweep", "limit": "100", "offset": "200"}),
        ]
        for label, values in filters:
            flt: RunFilter = parse_filter(values)
            page, wall, cpu = _timed(lambda flt=flt: select_runs(d, flt))
            print(f"filter {label}: {len(page.rows):,} of {page.total:,} rows, {wall:.3f} s "
                  f"wall, {cpu:.3f} s CPU")
        changed = sorted(d.glob("run*.h5"))[:10]
        for p in changed:
            with h5py.File(p, "r+", libver=LIBVER) as f:
                f.attrs["status"] = "aborted"
        old = time.time() - 10
        for p in changed:  # older than the index's racy window: read once, then trusted
            os.utime(p, (old, old))
        rows, wall, cpu = _timed(lambda: scan_runs(d))
        print(f"list after 10 files changed: {wall:.3f} s wall, {cpu:.3f} s CPU "
              f"({sum(r.status == 'aborted' for r in rows):,} aborted)")
    finally:
        if tmp is not None:
            tmp.cleanup()


if __name__ == "__main__":
    main()
