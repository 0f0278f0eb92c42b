"""The run catalog: one row per run file found under a runs directory."""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from storage.errors import RunFileError
from storage.reader import open_run
from storage.recovery import STALE_AFTER_S, writer_gone

__all__ = ["STALE_AFTER_S", "RunRow", "default_runs_dir", "format_table", "read_row",
           "scan_runs"]

#: Environment variable naming the default runs directory (else ./runs).
RUNS_DIR_ENV = "SFDRIG_RUNS_DIR"
SUFFIXES = (".h5", ".hdf5")


@dataclass(frozen=True)
class RunRow:
    """One catalog row.

    Attributes
    ----------
    id : str
        Run id ("" when the file cannot be read).
    date : str
        Start time, ISO 8601 UTC.
    kind : str
        Kind of test (sweep, static, impact, probe_calibration, flow, imported).
    steps : int
        Dwells recorded.
    status : str
        running, completed, aborted, failed; "interrupted" for a run left "running" by a writer
        that is gone (`storage.recovery.writer_gone`), or closed so by a restarted daemon;
        "unreadable" for a broken file (see ``error``).
    duration_s : float
        Recorded span [s] (samples / sample rate).
    file : str
        Path of the run file.
    error : str
        Why the file is unreadable ("" otherwise).
    """

    id: str
    date: str
    kind: str
    steps: int
    status: str
    duration_s: float
    file: str
    error: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def default_runs_dir() -> Path:
    """``$SFDRIG_RUNS_DIR`` if set, else ``./runs``."""
    return Path(os.environ.get(RUNS_DIR_ENV) or "runs")


def read_row(path: Path, now: float | None = None) -> RunRow:
    """The catalog row of one file (an "unreadable" row when it is broken)."""
    try:
        with open_run(path) as run:
            status = run.status
            if status == "running" and writer_gone(run.attrs, path, now):
                status = "interrupted"
            return RunRow(id=run.run_id, date=run.start_time, kind=run.kind,
                          steps=len(run.steps), status=status,
                          duration_s=round(run.duration_s, 6), file=str(path))
    except RunFileError as err:
        return RunRow(id="", date="", kind="", steps=0, status="unreadable", duration_s=0.0,
                      file=str(path), error=str(err))


def scan_runs(directory: str | Path, recursive: bool = True) -> list[RunRow]:
    """Rows for every ``*.h5`` / ``*.hdf5`` under ``directory``, oldest first.

    Temporary files of an import in progress (``.name.*.tmp``) are skipped.

    Raises
    ------
    FileNotFoundError
        When ``directory`` does not exist.
    NotADirectoryError
        When it is a file.
    """
    directory = Path(directory)
    if not directory.exists():
        raise FileNotFoundError(f"{directory}: runs directory does not exist")
    if not directory.is_dir():
        raise NotADirectoryError(f"{directory}: not a directory")
    pattern = directory.rglob("*") if recursive else directory.glob("*")
    files = sorted(p for p in pattern
                   if p.suffix.lower() in SUFFIXES and p.is_file() and not p.name.startswith("."))
    now = time.time()
    rows = [read_row(p, now) for p in files]
    rows.sort(key=lambda r: (r.date == "", r.date, r.file))
    return rows


def format_table(rows: list[RunRow]) -> str:
    """A fixed-width text table of the rows (unreadable files listed with their error)."""
    headers = ("id", "date", "kind", "steps", "status", "duration", "file")
    table = [headers]
    for r in rows:
        table.append((r.id or "-", r.date[:19].replace("T", " ") or "-", r.kind or "-",
                      str(r.steps), r.status, _duration(r.duration_s), r.file))
    widths = [max(len(row[i]) for row in table) for i in range(len(headers))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
             for row in table]
    for r in rows:
        if r.error:
            lines.append(f"unreadable: {r.error}")
    return "\n".join(lines)


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, sec = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes}m{sec:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m"
