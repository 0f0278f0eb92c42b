"""The daemon's run files: a new run id, creating the file of a run, listing the runs directory."""

from __future__ import annotations

import errno
import logging
import math
import secrets
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import BaseModel

from control.run.engine import RunSpec
from control.wire.heartbeat import RecoveredRun
from control.wire.protocol import RunListing
from daq.board import Board
from daq.channels import ChannelMap
from storage.records import run_file_status

if TYPE_CHECKING:
    from storage.runfile import RunWriter

log = logging.getLogger("sfdrig.daemon")


def new_run_id() -> str:
    """A unique, sortable run id: UTC time plus a random suffix."""
    return f"{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"


def writer_chunk_samples(sample_rate_hz: float) -> int:
    """About 1/8 s per HDF5 chunk (a power of two, >= 1024 samples).

    h5py keeps the GIL while it compresses a chunk; with one-second chunks at 62.5 kS/s x 18
    channels that is tens of milliseconds at once, which starves the acquisition thread past its
    AO lead (underflow, seen on a loaded 2-core machine). Eighth-second chunks spread the same
    work into pieces of a few milliseconds.
    """
    return int(max(1024, 2 ** round(math.log2(max(sample_rate_hz, 1.0) / 8))))


def create_run_writer(path: str | Path, kind: str, channel_map: ChannelMap, *, run_id: str,
                      test_spec: RunSpec | BaseModel | Mapping[str, object] | None = None,
                      rig_config: BaseModel | None = None,
                      lubricated: bool | None = None, operator: str = "", notes: str = "",
                      overwrite: bool = False, pool: ThreadPoolExecutor | None = None,
                      paced: bool = True, board: Board | None = None) -> RunWriter:
    """A new run file of ``kind`` (a sweep, a structure test) and its `storage.RunWriter`, the
    metadata written: the AI and AO channels from ``channel_map``, the test's spec (a pydantic
    model or a dict), the rig. ``lubricated`` None: the spec's own ``lubricated`` (False without
    one). ``pool``: the daemon's compression pool, shared by its runs
    (`storage.runfile.deflate_pool`). ``paced`` False: the data comes from a producer no clock
    paces (the simulated rig's fast mode), and the writer holds it back when it falls behind
    instead of failing the run. ``board``: the board that records it (`daq.board.Board`; the
    backend's ``board``), written as the file's ``board``, ``backend``, ``device`` and
    ``grpc_target`` attributes."""
    from storage.runfile import RunWriter

    cm = channel_map
    return RunWriter.create(
        path, run_id, kind,
        channels=cm.to_json_dict()["ai"], ao_names=cm.ao_names,
        sample_rate_hz=cm.sample_rate_hz, operator=operator, notes=notes,
        channel_map=cm.to_json_dict(), rig_config=rig_config,
        test_spec=(test_spec.model_dump(mode="json") if isinstance(test_spec, BaseModel)
                   else test_spec),
        lubricated=bool(getattr(test_spec, "lubricated", False)) if lubricated is None
        else lubricated,
        chunk_samples=writer_chunk_samples(cm.sample_rate_hz), pool=pool, overwrite=overwrite,
        wait_when_behind=not paced, board=board.as_dict() if board is not None else None,
    )


def list_runs(runs_dir: Path, active: Path | None, limit: int = 500) -> list[RunListing]:
    """The run files in ``runs_dir`` (not its subfolders), newest first by start time, with
    their status (``active`` is running). From the run index (`storage.catalog`): only the files
    new or changed since the last look are read, so a client asking on every refresh costs the
    daemon, mid-sweep, no header reads of a year of runs."""
    from storage.catalog import select_runs
    from storage.run_index import RunFilter

    page = select_runs(runs_dir, RunFilter(top_only=True, newest_first=True, limit=limit),
                       notice=log.info)
    out: list[RunListing] = []
    for row in page.rows:
        path = Path(row.file)
        if path == active:
            out.append({"path": row.file, "run_id": path.stem, "status": "running"})
        elif row.status == "unreadable":  # a broken file is listed with why it is broken
            out.append({"path": row.file, "run_id": path.stem, "status": "unreadable",
                        "status_reason": row.error})
        else:
            out.append({"path": row.file, "run_id": row.id or path.stem, "kind": row.kind,
                        "status": row.status, "status_reason": row.status_reason,
                        "start_time": row.date, "stop_time": row.stop_time,
                        "n_samples": row.n_samples, "n_steps": row.steps})
    return out


def close_run_file(writer: RunWriter, status: str, reason: str) -> str:
    """Write out what is queued for a run file and close it with ``status`` and ``reason``;
    never raises. Returns "" or what went wrong (the file keeps what was flushed)."""
    try:
        writer.close(run_file_status(status), reason)
    except Exception as err:
        log.exception("closing %s failed", writer.path)
        return f"run file close failed: {err}"
    return ""


#: how long a recovery waits for readers to let go of a run file (a reader holds HDF5's shared
#: lock only while it reads: the web's run list, a transfer of a long run takes seconds)
LOCK_WAIT_S = 30.0


def _locked(err: BaseException) -> bool:
    """Whether ``err`` is HDF5's refusal of a file another process holds open (its lock)."""
    return getattr(err, "errno", None) == errno.EAGAIN or "unable to lock file" in str(err)


def recover_interrupted(runs_dir: Path, lock_wait_s: float = LOCK_WAIT_S,
                        wait: Callable[[float], None] = time.sleep) -> list[RecoveredRun]:
    """Close the runs a dead writer left "running" in ``runs_dir`` as "interrupted", with the
    last sample on disk, so that every reader opens them. A file whose writer may still be alive
    (`storage.recovery.writer_gone`) is left alone; one a reader holds open (a web server
    listing the runs when the daemon starts again) is tried again, with backoff, for up to
    ``lock_wait_s``. Never raises: a file that cannot be recovered is listed with why.

    The candidates come from the run index (`storage.catalog.select_runs`, made here when the
    directory has none, so that the daemon's run writers record their runs in it): only the
    files it lists as running or interrupted are opened, not a year of runs at every start."""
    from storage.catalog import RunFilter, read_row, select_runs
    from storage.reader import open_run
    from storage.recovery import close_interrupted, writer_gone
    from storage.run_index import record_run

    out: list[RecoveredRun] = []
    try:
        candidates = select_runs(runs_dir, RunFilter(statuses=("running", "interrupted"),
                                                     top_only=True)).rows
    except OSError as err:
        log.warning("could not list the runs in %s: %s", runs_dir, err)
        return out
    for path in sorted(Path(r.file) for r in candidates if r.file.endswith(".h5")):
        try:
            with open_run(path) as run:
                running, attrs = run.status == "running", dict(run.attrs)
            if not running or not writer_gone(attrs, path):
                continue
            waited, delay = 0.0, 0.05
            while True:
                try:
                    last = close_interrupted(path, "the writer stopped without closing the run "
                                                   "(killed or crashed); recovered at the next "
                                                   "daemon start")
                    break
                except OSError as err:
                    if not _locked(err) or waited >= lock_wait_s:
                        raise
                    log.info("%s is open in another process: recovering it again in %.2f s",
                             path.name, delay)
                    wait(delay)
                    waited += delay
                    delay = min(2 * delay, 1.0)
            log.warning("run %s was left running by a dead writer: closed as interrupted at "
                        "sample %d", path.name, last)
            record_run(path, read_row(path), final=True)
            out.append({"path": str(path), "status": "interrupted", "last_sample": last})
        except Exception as err:  # a damaged file stays as it is, listed as such
            log.warning("could not recover %s: %s", path, err)
            out.append({"path": str(path), "status": "unrecovered", "error": str(err)})
    return out
