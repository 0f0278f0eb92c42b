"""The run catalog: one row per run file under a runs directory, answered from the run index
(`storage.run_index`: the files stay the truth, only those that changed are read), with filters
and pages (`RunFilter`, parsed from people's words by `parse_filter`)."""

from __future__ import annotations

import difflib
import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from datetime import datetime, timedelta
from pathlib import Path

from storage.layout import KINDS, STATUSES
from storage.recovery import STALE_AFTER_S
from storage.run_index import INDEX_NAME, RunFilter, RunIndex, RunPage
from storage.run_row import RunRow, read_row

__all__ = ["FILTERS", "INDEX_NAME", "STALE_AFTER_S", "RunFilter", "RunPage", "RunRow",
           "default_runs_dir", "format_table", "open_catalog", "parse_filter", "read_row",
           "scan_runs", "select_runs"]

#: Environment variable naming the default runs directory (else ./runs).
RUNS_DIR_ENV = "SFDRIG_RUNS_DIR"
#: the statuses a row may have (the file's, and the catalog's own two)
ROW_STATUSES = (*STATUSES, "interrupted", "unreadable")
MOTIONS = ("x", "y", "circular_forward", "circular_backward", "elliptical")
SEALS = ("none", "sealed", "unknown", "unstated")
#: what `parse_filter` reads, and what each takes
FILTERS = {
    "kind": f"{', '.join(KINDS)} (several: comma-separated)",
    "status": f"{', '.join(ROW_STATUSES)} (several: comma-separated)",
    "since": "a date or time (ISO 8601, UTC unless it names a zone): started then or later",
    "until": "a date (through that day) or time (before it)",
    "lubricated": "yes or no",
    "seal": f"{', '.join(SEALS)}, or the seal's friction force F_mu in N",
    "motion": ", ".join(MOTIONS),
    "limit": "rows at most (a page)",
    "offset": "rows skipped before the page",
}


def default_runs_dir() -> Path:
    """``$SFDRIG_RUNS_DIR`` if set, else ``./runs``."""
    return Path(os.environ.get(RUNS_DIR_ENV) or "runs")


@contextmanager
def open_catalog(directory: str | Path,
                 notice: Callable[[str], None] | None = None) -> Iterator[RunIndex]:
    """The run index of ``directory`` brought in line with the files, open: for a reader that
    asks it more than one thing (the page's trips table: the runs that did not complete, then
    the incidents it kept of them, `RunIndex.derived`). ``notice``: see `RunIndex`.

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
    with RunIndex(directory, notice) as index:
        index.sync()
        yield index


def select_runs(directory: str | Path, flt: RunFilter | None = None,
                notice: Callable[[str], None] | None = None) -> RunPage:
    """The rows of the run files under ``directory`` that ``flt`` asks for, from the run index
    brought in line with the files first. Raises as `open_catalog`."""
    with open_catalog(directory, notice) as index:
        return index.select(flt or RunFilter())


def scan_runs(directory: str | Path, recursive: bool = True,
              notice: Callable[[str], None] | None = None) -> list[RunRow]:
    """Rows for every ``*.h5`` / ``*.hdf5`` under ``directory``, oldest first (unreadable files
    last); hidden files (an import's temporary ``.name.*.tmp``) are skipped. Raises as
    `select_runs`."""
    return select_runs(directory, RunFilter(top_only=not recursive), notice).rows


def parse_filter(values: Mapping[str, str | None], **fixed: object) -> RunFilter:
    """A `RunFilter` from people's words: ``{"kind": "sweep,static", "since": "2026-03-01",
    "lubricated": "yes", "limit": "50"}`` (the names of `FILTERS`; None or "" : not given);
    ``fixed``: further `RunFilter` fields as they are (``newest_first=True``...).

    Raises
    ------
    ValueError
        One line naming the filter, the value and what it takes.
    """
    unknown = sorted(set(values) - set(FILTERS))
    if unknown:
        raise ValueError(f"unknown filter {_shown(unknown[0])}: {_hint(unknown[0], FILTERS)}"
                         f"the filters are {', '.join(FILTERS)}")
    given = {k: v.strip() for k, v in values.items() if v is not None and v.strip()}
    out: dict[str, object] = {}
    if "kind" in given:
        out["kinds"] = _names("kind", given["kind"], KINDS)
    if "status" in given:
        out["statuses"] = _names("status", given["status"], ROW_STATUSES)
    if "since" in given:
        out["since"] = _when("since", given["since"])[0]
    if "until" in given:
        when, day = _when("until", given["until"])
        out["until"] = when + timedelta(days=1) if day else when
    if "lubricated" in given:
        answer = given["lubricated"].lower()
        if answer not in ("yes", "no", "true", "false", "1", "0"):
            raise ValueError(f"lubricated={_shown(given['lubricated'])}: {FILTERS['lubricated']}")
        out["lubricated"] = answer in ("yes", "true", "1")
    if "seal" in given:
        out["seal"] = _seal(given["seal"])
    if "motion" in given:
        out["motion"] = _names("motion", given["motion"], MOTIONS, several=False)[0]
    for key in ("limit", "offset"):
        if key in given:
            text = given[key]
            if not text.isdigit() or (key == "limit" and int(text) == 0):
                raise ValueError(f"{key}={_shown(text)}: a whole number"
                                 + (" above 0" if key == "limit" else " (0 or more)"))
            out[key] = int(text)
    out.update(fixed)
    return RunFilter(**out)  # type: ignore[arg-type]


def _shown(text: str) -> str:
    """A value as an error message quotes it (a long one cut)."""
    return repr(text if len(text) <= 40 else text[:40] + "...")


def _hint(word: str, known: Mapping[str, object] | tuple[str, ...]) -> str:
    close = difflib.get_close_matches(word, list(known), n=1)
    return f"did you mean {close[0]!r}? " if close else ""


def _names(key: str, text: str, known: tuple[str, ...], several: bool = True) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not several and len(names) != 1:
        raise ValueError(f"{key}={_shown(text)}: one of {', '.join(known)}")
    for n in names:
        if n not in known:
            raise ValueError(f"{key}={_shown(n)} is not one of {', '.join(known)}"
                             + (f" ({_hint(n, known).rstrip()})" if _hint(n, known) else ""))
    return names


def _when(key: str, text: str) -> tuple[datetime, bool]:
    """(the time, whether it was a date alone)."""
    try:
        when = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"{key}={_shown(text)} is not an ISO 8601 date or time (e.g. "
                         "2026-03-01 or 2026-03-01T08:00)") from None
    return when, len(text) <= 10


def _seal(text: str) -> str | float:
    if text in SEALS:
        return text
    try:
        force = float(text)
    except ValueError:
        force = -1.0
    if not force >= 0 or force == float("inf"):
        raise ValueError(f"seal={_shown(text)}: {FILTERS['seal']}")
    return force


def format_table(rows: list[RunRow]) -> str:
    """A fixed-width text table of the rows (unreadable files listed with their error)."""
    headers = ("id", "date", "kind", "steps", "status", "duration", "conditions", "file")
    table = [headers]
    for r in rows:
        table.append((r.id or "-", r.date[:19].replace("T", " ") or "-", r.kind or "-",
                      str(r.steps), r.status, _duration(r.duration_s), _conditions(r),
                      r.file))
    widths = [max(len(row[i]) for row in table) for i in range(len(headers))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
             for row in table]
    for r in rows:
        if r.error:
            lines.append(f"unreadable: {r.error}")
    return "\n".join(lines)


def _conditions(r: RunRow) -> str:
    """``lubricated x seal 26 N``: what the run was recorded under ("-" for none known)."""
    if r.lubricated is None:
        return "-"
    seal = {"": "", "none": "no seal", "unknown": "seal unknown"}.get(
        r.seal, f"seal {r.seal.removesuffix('.0')} N")
    return " ".join(w for w in ("lubricated" if r.lubricated else "dry", r.motion, seal) if w)


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, sec = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes}m{sec:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m"
