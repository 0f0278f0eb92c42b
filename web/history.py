"""The run history the page shows: the runs directory's files, one run opened, its downloads and
the operator's notes.

The runs are the run catalog of the web process's runs directory (`storage.catalog`, the same
rows as `sfdrig runs`: a file left "running" by a dead writer reads as interrupted). A request
names a run by its id only; the file is always the one the catalog found for that id, never a
path built from the request, so no request reaches a file outside the directory.

Identification reports are made on request by `sfdrig identify --no-store` in a process of its
own (the web process imports no analysis, and the run file is not written) into
``RUNS_DIR/reports/RUN/``; a report's files are served by their names in that folder's listing.

Notes never touch the run file (the recorded data is not opened for writing): each run's notes
are a JSON list beside it, ``RUN.notes.json``, replaced whole by an atomic rename, bounded in
count and length.

`storage` (and h5py with it) is imported on the first use, not when `sfdrig web` starts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import tempfile
import threading
import time
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from web.transfer import COHERENCE_LOW, axes_of, from_segments, segments_of
from web.trips import TripRow, idle_rows, incidents_of_run, select
from web.view import finite, step_point

if TYPE_CHECKING:  # storage (h5py) is imported at first use
    from storage.reader import RunData
    from storage.records import StepRecord
    from storage.run_index import RunFilter, RunIndex, RunPage

FORMATS = ("h5", "mat", "csv", "tdms")
PAGE_RUNS = 100  # a page of the run list, newest first
MAX_RUNS = 1000  # the longest page asked
MAX_NOTES = 200  # per run
MAX_NOTE_CHARS = 4000
NOTES_SUFFIX = ".notes.json"
REPORTS_DIR = "reports"
REPORT_PAGE = "index.html"
log = logging.getLogger(__name__)
INCIDENTS_KEPT = "web.trips/1"  # a run's incidents in the run index (a new layout: a new name)
MAX_CACHED_STEPS = 20_000  # transfer results kept (a recorded step never changes)


class HistoryError(ValueError):
    """A history request that cannot be served; ``status`` is the HTTP answer."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


class RunHistory:
    """The runs of one directory, for the page.

    Parameters
    ----------
    runs_dir : Path
        The daemon's runs directory (the web process's ``--runs-dir``).
    """

    def __init__(self, runs_dir: Path) -> None:
        self.runs_dir = runs_dir
        self._notes_lock = threading.Lock()
        self._paths: dict[str, Path] = {}  # run id -> the file the catalog found for it
        self._transfers: dict[tuple[str, int], list[dict[str, Any]]] = {}

    # --- the list -------------------------------------------------------------------------
    def _page(self, **fixed: object) -> RunPage:
        """The catalog's rows of the files directly in the directory (`storage.catalog`:
        from the run index, brought in line with the files first), as ``fixed`` filters them."""
        return self._select({}, **fixed)

    def _select(self, query: Mapping[str, str], **fixed: object) -> RunPage:
        with self._catalog() as index:
            return index.select(_filter(query, **fixed))

    @contextlib.contextmanager
    def _catalog(self) -> Iterator[RunIndex]:
        """The run index of the directory, in line with its files (`storage.catalog`)."""
        from storage.catalog import open_catalog

        try:
            with open_catalog(self.runs_dir, notice=_notice) as index:
                yield index
        except (FileNotFoundError, NotADirectoryError) as err:
            raise HistoryError(str(err), 404) from None

    def runs(self, query: Mapping[str, str] | None = None) -> dict[str, Any]:
        """A page of the runs (newest first; `PAGE_RUNS` unless ``limit`` says, at most
        `MAX_RUNS`) with their status, conditions and notes count; ``query``: the filters of
        `storage.catalog.FILTERS` as the page's request gives them (400 for a bad one)."""
        query = dict(query or {})
        limit = query.get("limit") or str(PAGE_RUNS)
        if limit.isdigit() and int(limit) > MAX_RUNS:
            raise HistoryError(f"limit={limit!r}: at most {MAX_RUNS} runs a page")
        page = self._select({**query, "limit": limit}, newest_first=True)
        out = []
        for r in page.rows:
            d = r.to_dict()
            d["file"] = Path(r.file).name  # the page needs no path
            d["notes"] = len(self._read_notes(Path(r.file))) if r.id else 0
            out.append(d)
        return {"runs_dir": str(self.runs_dir), "runs": out, "total": page.total,
                "offset": page.offset, "limit": page.limit}

    def path_of(self, run_id: str) -> Path:
        """The file the catalog found for ``run_id`` (404 for any other string); remembered
        while the file is there (the page asks for a running run's transfer at every step)."""
        known = self._paths.get(run_id)
        if known is not None and known.is_file():
            return known
        if run_id:
            for r in self._page(run_id=run_id, limit=1).rows:
                self._paths[run_id] = Path(r.file)
                return Path(r.file)
        raise HistoryError(f"no run {run_id!r} in {self.runs_dir}", 404)

    # --- one run --------------------------------------------------------------------------
    def details(self, run_id: str) -> dict[str, Any]:
        """A run as the page opens it: what it was, how it ended, its step table and events."""
        from storage.errors import RunFileError
        from storage.reader import open_run

        path = self.path_of(run_id)
        try:
            with open_run(path) as run:
                spec = run.test_spec or {}
                tol = (float(spec.get("tolerance_amplitude_pct") or 1.0),
                       float(spec.get("tolerance_phase_deg") or 1.0))
                steps = [{k: finite(v) if isinstance(v, float) else v
                          for k, v in step_point(s, *tol).items()} for s in run.step_records]
                a = run.attrs
                return {
                    "run_id": run_id, "file": path.name, "kind": run.kind,
                    "status": _status(run.status, a, path),
                    "status_reason": str(a.get("status_reason", "")),
                    "operator": str(a.get("operator", "")), "notes_at_start": str(
                        a.get("notes", "")),
                    "start_time": run.start_time, "stop_time": run.stop_time,
                    "duration_s": finite(run.duration_s),
                    "sample_rate_hz": run.sample_rate_hz, "lubricated": _bool(
                        a.get("lubricated")),
                    "channels": run.channel_names, "drives": run.drive_names,
                    "steps": steps,
                    "events": run.events[-200:],
                    "notes": self._read_notes(path),
                    "formats": list(FORMATS),
                    "report": (self.report_dir(path) / REPORT_PAGE).is_file(),
                }
        except RunFileError as err:
            raise HistoryError(f"run {run_id} cannot be read: {err}", 409) from None

    def ended(self, run_id: str, what: str) -> Path:
        """The file of a run that has ended (409 while it is written, or unreadable)."""
        from storage.errors import RunFileError
        from storage.reader import open_run

        path = self.path_of(run_id)
        try:
            with open_run(path) as run:
                status = _status(run.status, run.attrs, path)
        except RunFileError as err:
            raise HistoryError(f"run {run_id} cannot be read: {err}", 409) from None
        if status == "running":
            raise HistoryError(f"run {run_id} is still being written: {what} it once it has "
                               "ended", 409)
        return path

    # --- the transfer function across the sweep ----------------------------------------------
    def transfer(self, run_id: str) -> dict[str, Any]:
        """Each recorded step's X/F, F/X and coherence per driven axis, from the file's samples
        (`web.transfer`); a step whose samples are not yet flushed by a live writer is counted
        in ``pending`` and computed when asked again."""
        from storage.errors import RunFileError
        from storage.reader import open_run

        path = self.path_of(run_id)
        points: list[dict[str, Any]] = []
        pending = 0
        try:
            with open_run(path) as run:
                steps, n, fs = run.step_records, run.n_samples, run.sample_rate_hz
                for step in steps:
                    key = (str(path), step.index)
                    if key not in self._transfers:
                        if step.last_sample > n:
                            pending += 1
                            continue
                        if len(self._transfers) >= MAX_CACHED_STEPS:
                            self._transfers.clear()
                        self._transfers[key] = _step_transfer(run, step, fs)
                    points.extend(self._transfers[key])
                status = _status(run.status, run.attrs, path)
        except RunFileError as err:
            raise HistoryError(f"run {run_id} cannot be read: {err}", 409) from None
        return {"run_id": run_id, "status": status, "points": points, "pending": pending,
                "steps": len(steps), "coherence_low": COHERENCE_LOW}

    # --- trips, e-stops, watchdogs and interrupted runs across runs ---------------------------
    def trips(self, incidents: set[str] | None = None, since: Any = None) -> dict[str, Any]:
        """Every incident (`web.trips`) of the runs that did not complete, read from their
        files, and those of no run, from the daemon's incident log: newest first. A run's
        incidents are kept in the run index (`RunIndex.derived`, by the file's change time and
        size): a file is read again only when it has changed, also by the next web process."""
        from storage.errors import RunFileError
        from storage.incident_log import LOG_NAME, read_incidents
        from storage.reader import open_run

        rows: list[TripRow] = []
        unreadable = 0
        with self._catalog() as index:
            page = index.select(_filter(statuses=("aborted", "failed", "interrupted")))
            kept = index.derived(INCIDENTS_KEPT)
            made: list[tuple[Path, tuple[int, int], list[TripRow]]] = []
            for r in page.rows:
                try:
                    st = os.stat(r.file)
                except OSError:
                    continue
                stamp = (st.st_mtime_ns, st.st_size)
                if r.file in kept and kept[r.file][0] == stamp:
                    rows.extend(kept[r.file][1])
                    continue
                try:
                    with open_run(r.file) as run:
                        found = incidents_of_run(run, r.status, Path(r.file).name,
                                                 st.st_mtime)
                        closed = run.status != "running"
                except (RunFileError, OSError, KeyError, ValueError, RuntimeError):
                    # (h5py's errors on a file a daemon is closing right now: asked again)
                    unreadable += 1
                    continue
                rows.extend(found)
                if closed:  # (a dead writer's file, still to be closed by a daemon: its
                    made.append((Path(r.file), stamp, found))  # change may keep its stamp)
            index.put_derived(INCIDENTS_KEPT, made)
        logged, skipped = read_incidents(self.runs_dir)
        rows.extend(idle_rows(logged, LOG_NAME))
        shown = select(rows, incidents, since)
        return {"runs_dir": str(self.runs_dir), "incidents": shown, "total": len(rows),
                "unreadable": unreadable, "log_lines_skipped": skipped}

    # --- downloads ------------------------------------------------------------------------
    def download(self, run_id: str, fmt: str, work: Path) -> tuple[Path, str]:
        """The file to send for ``run_id`` as ``fmt`` and its download name: the run file
        itself for h5, else `sfdrig export`'s files made in ``work`` (zipped when several)."""
        from storage.errors import ExportError, RunFileError
        from storage.exporters import export_run

        if fmt not in FORMATS:
            raise HistoryError(f"format {fmt!r}: one of {', '.join(FORMATS)}")
        path = self.ended(run_id, "download")
        if fmt == "h5":
            return path, path.name
        try:
            files = export_run(path, fmt, work / "export")
        except (ExportError, RunFileError) as err:
            raise HistoryError(f"export of {run_id} as {fmt} failed: {err}", 500) from None
        if len(files) == 1:
            return files[0], files[0].name
        bundle = work / f"{path.stem}-{fmt}.zip"
        with zipfile.ZipFile(bundle, "w", zipfile.ZIP_STORED) as z:  # CPU over bytes
            for f in files:
                z.write(f, f.name)
        return bundle, bundle.name

    # --- identification reports -------------------------------------------------------------
    def report_dir(self, path: Path) -> Path:
        """Where the report of the run file ``path`` goes."""
        return self.runs_dir / REPORTS_DIR / path.stem

    def report_job(self, run_id: str) -> tuple[Path, Path]:
        """(run file, report folder) of a run that may be identified now (not while written)."""
        path = self.ended(run_id, "identify")
        return path, self.report_dir(path)

    def report_file(self, run_id: str, name: str) -> Path:
        """A file of the run's report, by its name in the report folder's listing (404 else)."""
        folder = self.report_dir(self.path_of(run_id))
        files = {p.relative_to(folder).as_posix(): p for p in folder.rglob("*")
                 if p.is_file() and not p.is_symlink()} if folder.is_dir() else {}
        if name not in files:
            raise HistoryError(f"run {run_id}'s report has no file {name!r}", 404)
        return files[name]

    # --- notes ----------------------------------------------------------------------------
    @staticmethod
    def _notes_file(path: Path) -> Path:
        return path.with_name(path.stem + NOTES_SUFFIX)

    def _read_notes(self, path: Path) -> list[dict[str, Any]]:
        try:
            notes = json.loads(self._notes_file(path).read_text())
        except (OSError, ValueError):
            return []
        return [n for n in notes if isinstance(n, dict)] if isinstance(notes, list) else []

    def notes(self, run_id: str) -> list[dict[str, Any]]:
        return self._read_notes(self.path_of(run_id))

    def add_note(self, run_id: str, author: str, text: Any, now: float | None = None
                 ) -> list[dict[str, Any]]:
        """Append the operator's note to the run's notes file; the notes as they now are."""
        if not isinstance(text, str) or not text.strip():
            raise HistoryError("a note needs some text")
        if len(text) > MAX_NOTE_CHARS:
            raise HistoryError(f"a note holds at most {MAX_NOTE_CHARS} characters, not "
                               f"{len(text)}")
        path = self.path_of(run_id)
        with self._notes_lock:
            notes = self._read_notes(path)
            if len(notes) >= MAX_NOTES:
                raise HistoryError(f"run {run_id} has {MAX_NOTES} notes already", 409)
            notes.append({"time": time.time() if now is None else now, "author": author,
                          "text": text.strip()})
            target = self._notes_file(path)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                                       dir=target.parent)
            try:
                with os.fdopen(fd, "w") as f:
                    json.dump(notes, f, indent=1)
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, target)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        return notes


def _step_transfer(run: RunData, step: StepRecord, fs: float) -> list[dict[str, Any]]:
    """One step's points, one per driven axis that has a force and a displacement signal."""
    first, last, freq = step.first_sample, step.last_sample, step.freq_hz
    spans = segments_of(last - first, freq, fs) if freq > 0 and fs > 0 else []
    out = []
    for axis in axes_of(step.motion):
        if not (run.has_signal(f"f{axis}") and run.has_signal(axis)):
            continue
        # read segment by segment: a long record is never in memory whole
        t = from_segments(((run.signal(f"f{axis}", first + a, first + b),
                            run.signal(axis, first + a, first + b)) for a, b in spans),
                          freq, fs)
        if t is None:
            continue
        coh = t["coherence"]
        out.append({"index": step.index, "freq_hz": freq,
                    "axis": axis, **{k: finite(v) if isinstance(v, float) else v
                                     for k, v in t.items()},
                    "low_coherence": coh is not None and coh < COHERENCE_LOW})
    return out


def _filter(query: Mapping[str, str] | None = None, **fixed: object) -> RunFilter:
    """The catalog's filter of the files directly in the directory (400 for a bad value)."""
    from storage.catalog import parse_filter

    try:
        return parse_filter(query or {}, top_only=True, **fixed)
    except ValueError as err:
        raise HistoryError(str(err)) from None


def _notice(message: str) -> None:
    """The run index's one-line notices (made again, cannot be written) into the web log."""
    log.warning("%s", message)


def _status(status: str, attrs: Mapping[str, object], path: Path) -> str:
    """A file left "running" by a writer that is gone reads as interrupted (as in the catalog)."""
    from storage.recovery import writer_gone

    return "interrupted" if status == "running" and writer_gone(attrs, path) else status


def _bool(value: Any) -> bool | None:
    if value is None:
        return None
    try:
        return bool(value) if not (isinstance(value, float) and math.isnan(value)) else None
    except (TypeError, ValueError):
        return None
