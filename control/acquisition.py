"""The daemon's acquisition side: the one acquisition thread, the fan-out of a sweep's stream to
the run file and the live consumers, and the background run-file writer."""

from __future__ import annotations

import dataclasses
import json
import logging
import queue
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from control.errors import InterlockError, TargetError
from control.listener import FanOut

log = logging.getLogger("sfdrig.daemon")


class BackgroundWriter:
    """Runs a run writer's calls on its own thread, in order, so that disk latency (compression,
    flushes at steps and events) stays out of the acquisition loop, whose AO lead is only tens of
    milliseconds.

    A write error, or a backlog beyond ``max_backlog_samples``, makes the next `on_block` raise:
    the engine then stops the run the safe way and records why.
    """

    def __init__(self, writer: Any, max_backlog_samples: int) -> None:
        self.writer = writer
        self.max_backlog = max_backlog_samples
        self._queue: queue.Queue[tuple[str, tuple[Any, ...]] | None] = queue.Queue()
        self._backlog = 0  # samples queued, not yet written
        self._lock = threading.Lock()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="sfdrig-run-writer",
                                        daemon=True)
        self._thread.start()

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        if self.error is not None:
            raise RuntimeError(f"run file write failed: {self.error}")
        with self._lock:
            if self._backlog > self.max_backlog:
                raise RuntimeError(f"run file writer is {self._backlog} samples behind: the "
                                   "disk cannot keep up")
            self._backlog += ai.shape[1]
        self._queue.put(("on_block", (first_sample, ai, ao)))

    def on_step(self, step: dict[str, Any]) -> None:
        self._queue.put(("on_step", (step,)))

    def on_event(self, kind: str, message: str, sample: int) -> None:
        self._queue.put(("on_event", (kind, message, sample)))

    def drain(self, timeout_s: float = 60.0) -> None:
        """Write everything queued and stop the thread; raise the first write error."""
        self._queue.put(None)
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise TimeoutError(f"run writer did not finish within {timeout_s:g} s")
        if self.error is not None:
            raise RuntimeError(f"run file write failed: {self.error}")

    def _loop(self) -> None:
        while (item := self._queue.get()) is not None:
            if self.error is not None:
                continue  # keep draining so the acquisition side never blocks
            name, args = item
            try:
                getattr(self.writer, name)(*args)
            except BaseException as err:
                log.exception("run writer failed")
                self.error = err
            if name == "on_block":
                with self._lock:
                    self._backlog -= args[1].shape[1]


# --- the acquisition loop -----------------------------------------------------------------------
@dataclasses.dataclass
class RunJob:
    """One sweep to run: what the acquisition thread needs, prepared by the command thread."""

    run_id: str
    path: Path
    engine: Any  # control.sweep.SweepEngine
    writer: BackgroundWriter  # around a storage.RunWriter
    fanout: FanOut
    abort_reason: str = ""


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
                status, reason = outcome_status(outcome)
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


def outcome_status(outcome: Any) -> tuple[str, str]:
    """(status, reason) of a `SweepOutcome`, read from its ``status``/``aborted`` fields."""
    status = getattr(outcome, "status", None)
    reason = str(getattr(outcome, "reason", "") or getattr(outcome, "abort_reason", "") or "")
    if status is None:
        status = "aborted" if getattr(outcome, "aborted", False) else "completed"
    status = str(getattr(status, "value", status))
    if status not in ("completed", "aborted", "failed"):
        status = "failed" if status in ("fault", "error", "tripped") else "aborted"
    return status, reason


def as_dict(obj: Any) -> dict[str, Any]:
    """A JSON-safe dict of a progress/outcome object (pydantic model, dataclass, dict)."""
    if obj is None:
        return {}
    if hasattr(obj, "model_dump"):
        d = obj.model_dump(mode="json")
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        d = dataclasses.asdict(obj)
    elif isinstance(obj, dict):
        d = dict(obj)
    else:
        d = {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    return json.loads(json.dumps(d, default=str))
