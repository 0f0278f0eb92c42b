"""The daemon's own log of the incidents that happen while no run is going: an emergency stop
pressed (and released) between runs, the board's watchdog expiring while idle.

A run's incidents are in its run file; these are in no run file, and the operator's history of
trips and e-stops (`web.trips`) must hold them too. One JSON object per line in
``RUNS_DIR/incidents.jsonl`` (`LOG_NAME`), appended and fsynced at once, so a line survives the
daemon's death and restarts; a reader skips a line it cannot parse (a torn last line after a
power cut) and counts it. Each line: ``time`` (ISO 8601 UTC, ms), ``incident`` ("e-stop",
"watchdog"), ``what`` (the message), ``pid`` (the daemon's).
"""

from __future__ import annotations

import json
import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

LOG_NAME = "incidents.jsonl"
#: what the log holds (`web.trips` shows them with the runs' incidents)
LOGGED_INCIDENTS = ("e-stop", "watchdog")
#: a line longer than this is not one of ours (a reader never loads a runaway line whole)
MAX_LINE_CHARS = 4096


def log_path(runs_dir: Path) -> Path:
    return Path(runs_dir) / LOG_NAME


def append_incident(runs_dir: Path, incident: str, what: str,
                    when: datetime | None = None) -> dict[str, Any]:
    """Append one incident to ``runs_dir``'s log and fsync it; returns the line's record.

    Raises
    ------
    ValueError
        for an incident not in `LOGGED_INCIDENTS` (naming it).
    OSError
        when the log cannot be written (the caller logs it: the daemon keeps serving).
    """
    if incident not in LOGGED_INCIDENTS:
        raise ValueError(f"incident {incident!r} is not one of {', '.join(LOGGED_INCIDENTS)}")
    record = {"time": (when or datetime.now(UTC)).isoformat(timespec="milliseconds"),
              "incident": incident, "what": what[:1000], "pid": os.getpid()}
    line = (json.dumps(record) + "\n").encode()
    # O_APPEND: one write per line, never interleaved with another writer's
    fd = os.open(log_path(runs_dir), os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
        os.fsync(fd)
    finally:
        os.close(fd)
    return record


def read_incidents(runs_dir: Path) -> tuple[list[dict[str, Any]], int]:
    """The log's records in file order and the count of lines skipped as unreadable
    ([] and 0 when there is no log yet)."""
    try:
        f = open(log_path(runs_dir), encoding="utf-8", errors="replace")  # noqa: SIM115
    except FileNotFoundError:
        return [], 0
    records: list[dict[str, Any]] = []
    skipped = 0
    with f:
        while line := f.readline(MAX_LINE_CHARS + 1):
            if len(line) > MAX_LINE_CHARS:
                skipped += 1
                while line and not line.endswith("\n"):  # the rest of the runaway line
                    line = f.readline(MAX_LINE_CHARS + 1)
                continue
            if not line.strip():
                continue
            try:
                r = json.loads(line)
            except ValueError:
                skipped += 1
                continue
            if (isinstance(r, dict) and r.get("incident") in LOGGED_INCIDENTS
                    and isinstance(r.get("time"), str) and isinstance(r.get("what"), str)):
                records.append(r)
            else:
                skipped += 1
    return records, skipped
