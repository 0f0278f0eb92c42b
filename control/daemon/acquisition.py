"""The daemon's acquisition side: the one acquisition thread that runs the queued runs."""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from control.daemon.lease import OperatorLease
from control.run.engine import Engine
from control.run.errors import InterlockError
from control.run.listener import FanOut
from control.wire.errors import TargetError

if TYPE_CHECKING:
    from storage.runfile import RunWriter  # h5py: loaded with the first run file, not before

log = logging.getLogger("sfdrig.daemon")


# --- the acquisition loop -----------------------------------------------------------------------
@dataclasses.dataclass
class RunJob:
    """One run (a sweep or a programme): what the acquisition thread needs, prepared by the
    command thread."""

    run_id: str
    path: Path
    engine: Engine
    writer: RunWriter  # its own I/O thread keeps the disk out of the loop
    fanout: FanOut
    abort_reason: str = ""
    lease: OperatorLease | None = None  # a test waiting for a person; a sweep has none


class AcquisitionLoop:
    """The one acquisition thread: runs queued sweeps one at a time and reports how each ended
    through ``on_done(job, status, reason, fault)``: status "completed", "aborted" or "failed";
    ``fault`` when the daemon must go to the fault state (a failure, not a refusal)."""

    def __init__(self, on_start: Callable[[RunJob], None],
                 on_done: Callable[[RunJob, str, str, bool], None]) -> None:
        self._jobs: queue.Queue[RunJob | None] = queue.Queue()
        self._on_start = on_start
        self._on_done = on_done
        self._thread = threading.Thread(target=self._loop, name="sfdrig-acquisition", daemon=True)
        self._thread.start()

    def submit(self, job: RunJob) -> None:
        self._jobs.put(job)

    def stop(self, timeout_s: float = 30.0) -> None:
        self._jobs.put(None)
        self._thread.join(timeout_s)

    def _loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                self._on_start(job)
            except Exception:
                log.exception("starting %s failed", job.run_id)
            fault = False
            try:
                outcome = job.engine.run()
                status, reason = outcome.status, outcome.reason
            except (TargetError, InterlockError) as err:  # refused before any output
                status, reason = "failed", f"refused: {err}"
            except Exception as err:  # the engine ramped down already; record why it stopped
                log.exception("sweep %s failed", job.run_id)
                status, reason, fault = "failed", f"{type(err).__name__}: {err}", True
            try:
                self._on_done(job, status, reason, fault or status == "failed"
                              and not reason.startswith("refused"))
            except Exception:  # the thread must live on to run the next sweep
                log.exception("ending %s failed", job.run_id)
