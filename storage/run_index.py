"""The run index: one SQLite file in a runs directory (`INDEX_NAME`) keeping each run file's
catalog row (`storage.run_row.RunRow`), so that listing a year of runs opens no run file.

The files stay the truth. Every look (`RunIndex.sync`) lists the directory and compares each run
file's size and change time [ns] with its row's: a file that is new, changed, still running,
unreadable (perhaps locked by its writer for a moment), or changed so shortly before its row was
read that a later change could share its time stamp (`RACY_NS`: coarse file-system clocks) is
read again; a row whose file is gone is dropped. A missing index is made from the files; a
damaged one, or one of another layout, is deleted and made again with a one-line notice. It may
be deleted at any time. Where it cannot be written (a read-only archive) a look works from an
index in memory: every header read, as with none.

A run's writer records its row when the run starts and when it ends (`record_run`, in a
directory that has an index), so the first look after a run reads nothing. Two processes share
the file safely: WAL journal (a reader never blocks the writer), a busy timeout, and short write
transactions (a rebuild commits every `BATCH` rows, read before the transaction).
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

from storage.run_row import RunRow, read_row, seal_friction_n

log = logging.getLogger("sfdrig.storage")

#: the index's file name in the runs directory (hidden: no listing shows it)
INDEX_NAME = ".sfdrig-runs.sqlite"
#: the table's layout; an index of another layout is made again
SCHEMA = "3"
#: a row read less than this after its file's last change is read again at the next look [ns]
RACY_NS = 2_000_000_000
#: rows written per transaction while (re)building
BATCH = 200
#: a look with more files than this to read says so first (a rebuild)
NOTICE_AT = 200
BUSY_TIMEOUT_S = 10.0  # a look waits this long for another process's write
WRITER_TIMEOUT_S = 1.0  # a run's writer gives up sooner: the next look reads its file anyway
SUFFIXES = (".h5", ".hdf5")
T = TypeVar("T")

_FIELDS = ("id", "date", "kind", "steps", "status", "duration_s", "error", "lubricated",
           "seal", "motion", "stop_time", "n_samples", "status_reason")
_COLUMNS = ("file", "top", "mtime_ns", "size", "racy", "date_key", "seal_n", *_FIELDS)
_CREATE = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    file TEXT PRIMARY KEY,          -- path under the directory, '/'-separated
    top INTEGER NOT NULL,           -- 1: directly in the directory
    mtime_ns INTEGER NOT NULL, size INTEGER NOT NULL,
    racy INTEGER NOT NULL,          -- 1: read again at the next look
    date_key TEXT NOT NULL,         -- the start time in UTC, sortable ('' when unknown)
    seal_n REAL,                    -- the seal's friction force [N] (NULL: unknown, not stated)
    {", ".join(f"{f} {t}" for f, t in zip(_FIELDS, (
        "TEXT", "TEXT", "TEXT", "INTEGER", "TEXT", "REAL", "TEXT", "INTEGER", "TEXT", "TEXT",
        "TEXT", "INTEGER", "TEXT"),
        strict=True))});
CREATE INDEX IF NOT EXISTS runs_date ON runs (date_key);
CREATE INDEX IF NOT EXISTS runs_id ON runs (id);
CREATE TABLE IF NOT EXISTS derived (  -- what a reader made of a file (`RunIndex.derived`)
    file TEXT NOT NULL, name TEXT NOT NULL, mtime_ns INTEGER NOT NULL, size INTEGER NOT NULL,
    value TEXT NOT NULL, PRIMARY KEY (file, name));
"""


class _Damaged(Exception):
    """The index file is not one this version can use (not a database, another layout)."""


@dataclass(frozen=True)
class RunFilter:
    """Which rows a look returns, and in what order (empty: all of them, oldest first).

    ``kinds``/``statuses``: any of these; ``since``/``until``: the start time from ``since`` on
    and before ``until``; ``seal``: "none", "sealed" (a stated friction force), "unknown",
    "unstated" or a friction force [N]; ``motion``: the run drove it (alone or among others);
    ``top_only``: files directly in the directory (not in its subfolders).
    """

    kinds: tuple[str, ...] = ()
    statuses: tuple[str, ...] = ()
    since: datetime | None = None
    until: datetime | None = None
    lubricated: bool | None = None
    seal: str | float | None = None
    motion: str | None = None
    run_id: str | None = None
    top_only: bool = False
    newest_first: bool = False
    limit: int | None = None
    offset: int = 0


@dataclass(frozen=True)
class RunPage:
    """The rows of one look and how many match the filter in all (``total``)."""

    rows: list[RunRow]
    total: int
    offset: int
    limit: int | None


def date_key(date: str) -> str:
    """A start time as a sortable UTC key (``YYYY-MM-DDTHH:MM:SS.ffffff``; "" if not a time)."""
    try:
        when = datetime.fromisoformat(date.strip().replace("Z", "+00:00"))
    except ValueError:
        return ""
    return utc_key(when)


def utc_key(when: datetime) -> str:
    """``when`` (UTC when it names no zone) as a `date_key`."""
    when = when if when.tzinfo else when.replace(tzinfo=UTC)
    return when.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")


class RunIndex:
    """The index of one runs directory, open (a context manager: `close` at the end).

    ``notice`` receives a one-line message when the index is made again or cannot be written,
    and before a long (re)build.
    """

    def __init__(self, directory: str | Path,
                 notice: Callable[[str], None] | None = None) -> None:
        self.directory = Path(directory)
        self.path = self.directory / INDEX_NAME
        self._notice = notice or (lambda message: log.warning("%s", message))
        self._db = self._open()

    def __enter__(self) -> RunIndex:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self._db.close()

    # --- opening, and making it again ---------------------------------------------------------
    def _open(self) -> sqlite3.Connection:
        try:
            return _connect(self.path, BUSY_TIMEOUT_S, create=True)
        except _Damaged as err:
            self._notice(f"run index {self.path} {err}: deleted, made again from the run files")
            _remove(self.path)
        except (sqlite3.Error, OSError) as err:
            return self._in_memory(err)
        try:
            return _connect(self.path, BUSY_TIMEOUT_S, create=True)
        except (sqlite3.Error, OSError, _Damaged) as err:
            return self._in_memory(err)

    def _in_memory(self, err: BaseException) -> sqlite3.Connection:
        self._notice(f"run index {self.path} cannot be used ({err}): every run file is read "
                     "at each look")
        return _connect(Path(":memory:"), BUSY_TIMEOUT_S, create=True)

    def _guarded(self, call: Callable[[], T]) -> T:
        """``call()``; if the index turns out damaged on the way, made again and asked again."""
        try:
            return call()
        except sqlite3.OperationalError:
            raise
        except sqlite3.DatabaseError as err:  # "database disk image is malformed", ...
            self._db.close()
            self._notice(f"run index {self.path} is damaged ({err}): deleted, made again from "
                         "the run files")
            _remove(self.path)
            self._db = self._open()
            return call()

    # --- a look -------------------------------------------------------------------------------
    def sync(self) -> None:
        """Bring the rows in line with the files (see the module's notes)."""
        self._guarded(self._sync)

    def _sync(self) -> None:
        on_disk: dict[str, tuple[int, int, int]] = {}  # file -> (mtime_ns, size, 0)
        _walk(self.directory, "", on_disk)
        # a row to read again compares unequal: its third item is 1
        known = {r[0]: r[1:] for r in self._db.execute(
            "SELECT file, mtime_ns, size, racy OR status IN ('running', 'unreadable') "
            "FROM runs")}
        gone = [(f,) for f in known if f not in on_disk]
        todo = [f for f, stamp in on_disk.items() if known.get(f) != stamp]
        if gone:
            with self._db:
                self._db.executemany("DELETE FROM runs WHERE file = ?", gone)
                self._db.executemany("DELETE FROM derived WHERE file = ?", gone)
        if len(todo) > NOTICE_AT:
            self._notice(f"indexing {len(todo):,} run files in {self.directory} (once: later "
                         "looks read only the files that changed)")
        now = time.time()
        todo.sort()
        for a in range(0, len(todo), BATCH):
            records = []
            for rel in todo[a:a + BATCH]:
                mtime_ns, size, _ = on_disk[rel]
                racy = time.time_ns() - mtime_ns < RACY_NS  # before the read: the safe side
                row = read_row(self.directory / rel, now)
                records.append(_record(rel, mtime_ns, size, racy, row))
            self._put(records)

    def _put(self, records: list[tuple[Any, ...]]) -> None:
        with self._db:
            self._db.executemany(
                f"INSERT OR REPLACE INTO runs ({', '.join(_COLUMNS)}) "
                f"VALUES ({', '.join('?' * len(_COLUMNS))})", records)

    def select(self, flt: RunFilter) -> RunPage:
        """The rows the filter asks for (call `sync` first)."""
        return self._guarded(lambda: self._select(flt))

    def _select(self, flt: RunFilter) -> RunPage:
        where, params = _where(flt)
        total = int(self._db.execute(f"SELECT count(*) FROM runs WHERE {where}",
                                     params).fetchone()[0])
        way = "DESC" if flt.newest_first else "ASC"
        page = "" if flt.limit is None else f" LIMIT {int(flt.limit)} OFFSET {int(flt.offset)}"
        if flt.limit is None and flt.offset:
            page = f" LIMIT -1 OFFSET {int(flt.offset)}"
        cur = self._db.execute(
            f"SELECT file, {', '.join(_FIELDS)} FROM runs WHERE {where} "
            f"ORDER BY (date_key = '') {way}, date_key {way}, file {way}{page}", params)
        rows = [_row(self.directory, r) for r in cur.fetchall()]
        return RunPage(rows=rows, total=total, offset=flt.offset, limit=flt.limit)


    # --- what readers made of the files ---------------------------------------------------------
    def derived(self, name: str) -> dict[str, tuple[tuple[int, int], Any]]:
        """The values ``name`` kept for files (`put_derived`), by the file's path, with the
        (change time [ns], size) they were made from: only those made from the file as its row
        (call `sync` first) has it, a row trusted (not running, unreadable or racy)."""
        return self._guarded(lambda: {
            str(self.directory / f): ((m, n), json.loads(v)) for f, m, n, v in self._db.execute(
                "SELECT d.file, d.mtime_ns, d.size, d.value FROM derived d JOIN runs r "
                "ON r.file = d.file WHERE d.name = ? AND d.mtime_ns = r.mtime_ns AND "
                "d.size = r.size AND r.racy = 0 AND r.status NOT IN ('running', 'unreadable')",
                (name,))})

    def put_derived(self, name: str, values: list[tuple[Path, tuple[int, int], Any]]) -> None:
        """Keep what a reader made of files (JSON values) under ``name``, each with the
        (change time [ns], size) of the file it was made from: a file changed since is read
        again by its reader (e.g. the page's trips table: a run's incidents)."""
        rows = []
        for path, (mtime_ns, size), value in values:
            rel = Path(path).relative_to(self.directory).as_posix()
            rows.append((rel, name, mtime_ns, size, json.dumps(value)))
        if rows:
            def put() -> None:
                with self._db:
                    self._db.executemany("INSERT OR REPLACE INTO derived VALUES (?, ?, ?, ?, ?)",
                                         rows)
            self._guarded(put)


def record_run(path: Path, row: RunRow, final: bool) -> None:
    """A run's writer records its row in the index of the run's directory, if it has one:
    ``final`` when the run has ended and the file will not change again (the row is trusted
    until the file changes); a running run's row is read again at each look anyway. Never
    raises: an index not updated costs the next look one header read."""
    index = path.parent / INDEX_NAME
    if path.name.startswith(".") or not index.is_file():
        return  # an import's temporary file; a directory nobody lists with an index
    try:
        st = path.stat()
        db = _connect(index, WRITER_TIMEOUT_S, create=False)
        try:
            with db:
                db.execute(f"INSERT OR REPLACE INTO runs ({', '.join(_COLUMNS)}) "
                           f"VALUES ({', '.join('?' * len(_COLUMNS))})",
                           _record(path.name, st.st_mtime_ns, st.st_size, not final, row))
        finally:
            db.close()
    except (sqlite3.Error, OSError, _Damaged) as err:
        log.warning("run index %s not updated for %s (%s): the next look reads the file",
                    index, path.name, err)


# --- helpers ----------------------------------------------------------------------------------
def _connect(path: Path, timeout_s: float, create: bool) -> sqlite3.Connection:
    """A connection to the index at ``path`` (":memory:" for one in memory) in WAL mode, its
    layout checked (`_Damaged` when it is not this version's) and, with ``create``, made."""
    db = sqlite3.connect(str(path), timeout=timeout_s)
    try:
        try:
            db.execute(f"PRAGMA busy_timeout = {int(timeout_s * 1000)}")
            if str(path) != ":memory:":
                db.execute("PRAGMA journal_mode = WAL")
            db.execute("PRAGMA synchronous = NORMAL")  # a cache of the files: no fsync a commit
            tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE "
                                               "type = 'table'")}
        except sqlite3.OperationalError:
            raise
        except sqlite3.DatabaseError as err:
            raise _Damaged(f"is not a database this version reads ({err})") from None
        if "meta" in tables:
            found = db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
            if found is None or found[0] != SCHEMA or "runs" not in tables:
                raise _Damaged(f"has layout {found[0] if found else 'none'!r}, not {SCHEMA!r}")
        elif tables:
            raise _Damaged(f"holds tables {sorted(tables)} and no layout")
        elif not create:
            raise _Damaged("is empty")
        else:
            with db:
                db.executescript(_CREATE)
                db.execute("INSERT OR REPLACE INTO meta VALUES ('schema', ?)", (SCHEMA,))
    except BaseException:
        db.close()
        raise
    return db


def _remove(path: Path) -> None:
    for p in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
        p.unlink(missing_ok=True)


def _walk(directory: Path, prefix: str, out: dict[str, tuple[int, int, int]]) -> None:
    """Into ``out``: path under the top directory -> (change time [ns], size, 0) of every run
    file in ``directory`` and its subfolders; hidden files (an import's temporary file, the
    index) are not run files."""
    try:
        entries = list(os.scandir(directory))
    except OSError:  # a subfolder removed or unreadable meanwhile
        return
    for e in entries:
        name = e.name
        if name[0] == ".":
            continue
        try:
            if name.lower().endswith(SUFFIXES) and e.is_file():
                st = e.stat()
                out[prefix + name] = (st.st_mtime_ns, st.st_size, 0)
            elif e.is_dir(follow_symlinks=False):
                _walk(Path(e.path), f"{prefix}{name}/", out)
        except OSError:  # gone between the listing and the stat
            continue


def _record(rel: str, mtime_ns: int, size: int, racy: bool, row: RunRow) -> tuple[Any, ...]:
    seal_n = seal_friction_n(row.seal) if row.seal else None
    return (rel, "/" not in rel, mtime_ns, size, racy, date_key(row.date),
            seal_n if seal_n == seal_n else None,  # NaN: unknown
            row.id, row.date, row.kind, row.steps, row.status, row.duration_s, row.error,
            row.lubricated, row.seal, row.motion, row.stop_time, row.n_samples,
            row.status_reason)


def _row(directory: Path, r: tuple[Any, ...]) -> RunRow:
    (rel, run_id, date, kind, steps, status, duration, error, lub, seal, motion, stop_time,
     n_samples, reason) = r
    return RunRow(id=run_id, date=date, kind=kind, steps=int(steps), status=status,
                  duration_s=float(duration), file=str(directory / rel), error=error,
                  lubricated=None if lub is None else bool(lub), seal=seal, motion=motion,
                  stop_time=stop_time, n_samples=int(n_samples), status_reason=reason)


def _where(flt: RunFilter) -> tuple[str, list[Any]]:
    """The filter as an SQL condition and its parameters (values are parameters, never text)."""
    parts: list[str] = []
    params: list[Any] = []

    def any_of(column: str, values: tuple[str, ...]) -> None:
        parts.append(f"{column} IN ({', '.join('?' * len(values))})")
        params.extend(values)

    if flt.kinds:
        any_of("kind", flt.kinds)
    if flt.statuses:
        any_of("status", flt.statuses)
    if flt.since is not None:
        parts.append("date_key != '' AND date_key >= ?")
        params.append(utc_key(flt.since))
    if flt.until is not None:
        parts.append("date_key != '' AND date_key < ?")
        params.append(utc_key(flt.until))
    if flt.lubricated is not None:
        parts.append("lubricated = ?")
        params.append(int(flt.lubricated))
    if isinstance(flt.seal, float):
        parts.append("abs(seal_n - ?) <= 1e-9 * max(1.0, abs(?))")
        params.extend((flt.seal, flt.seal))
    elif flt.seal == "sealed":
        parts.append("seal_n > 0")
    elif flt.seal == "unstated":
        parts.append("seal = '' AND status != 'unreadable'")
    elif flt.seal == "none":
        parts.append("seal_n = 0")
    elif flt.seal is not None:
        parts.append("seal = ?")
        params.append(flt.seal)
    if flt.motion is not None:
        parts.append("instr(',' || motion || ',', ?) > 0")
        params.append(f",{flt.motion},")
    if flt.run_id is not None:
        parts.append("id = ?")
        params.append(flt.run_id)
    if flt.top_only:
        parts.append("top = 1")
    return (" AND ".join(parts) or "1"), params
