"""Run-file writer: one HDF5 file per run, written in SWMR mode (contract B); the layout is in
`storage.layout`.

SWMR forbids creating objects or attributes once it is switched on, so everything is created first;
the final status and stop time are written after the SWMR session is closed (file reopened r+).

`RunWriter` implements the sweep listener (contract A): ``on_block``, ``on_step``, ``on_event``.
``on_block`` only copies the block and hands it to a background I/O thread (woken when a chunk
is complete, not for every block), which appends whole chunks (`storage.chunks.ChunkWriter`:
gzip chunks are shuffled and deflated in a small thread pool, then written directly) and
flushes at least every ``flush_interval_s`` seconds; ``on_step`` and ``on_event`` check their
rows and hand them over too, and the thread writes each after the samples before it and flushes
(the one I/O thread of a run: the caller, the acquisition loop, never waits on the disk). A writer
killed mid-run therefore leaves a readable file holding everything up to the last flush (at most
about one second lost).
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage.chunks import ChunkWriter, deflate_pool
from storage.layout import (
    EVENT_KINDS,
    FORMAT,
    FORMAT_VERSION,
    KINDS,
    LIBVER,
    N_HARMONICS,
    STATUSES,
    STEP_KEYS,
    check_name,
    create_layout,
    default_chunk_samples,
    event_row,
    hdf5_text,
    installed_software_version,
    json_attr,
    step_rows,
    utc_now_iso,
)
from storage.records import EventRecord, RunFileStatus, StepRecord
from storage.recovery import writer_identity
from storage.run_index import record_run
from storage.run_row import RunRow, motion_of, seal_of

#: the root attributes naming the board that recorded a run (`board_attrs`)
BOARD_ATTRS = ("board", "backend", "device", "grpc_target")
# At most this long a step or an event waits to be on disk before `on_step`/`on_event` return.
RECORD_WAIT_S = 2.0


def board_attrs(board: Mapping[str, str] | None) -> dict[str, str]:
    """The run file's board attributes from a ``daq.board.Board.as_dict`` (its
    ``description`` as ``board``); "" each when no board is given."""
    board = board or {}
    return {key: hdf5_text(board.get("description" if key == "board" else key, ""))
            for key in BOARD_ATTRS}


class RunWriter:
    """Writes one run to an HDF5 file in SWMR mode; a sweep listener (contract A).

    Create with `RunWriter.create`; feed with `on_block`, `on_step`, `on_event`; finish with
    `close`. Also a context manager: leaving the ``with`` block on an exception closes the run
    with status ``"failed"``, otherwise ``"completed"`` (unless `close` was called already).
    Thread-safe: calls may come from the acquisition thread and others.
    """

    @classmethod
    def create(cls, *args: Any, **kwargs: Any) -> RunWriter:
        """Create the run file and return its writer: same arguments as `RunWriter`."""
        return cls(*args, **kwargs)

    def __init__(
        self,
        path: str | Path,
        run_id: str,
        kind: str,
        channels: Sequence[Mapping[str, Any] | str],
        ao_names: Sequence[str],
        sample_rate_hz: float,
        *,
        operator: str = "",
        notes: str = "",
        software_version: str | None = None,
        channel_map: Mapping[str, Any] | str | None = None,
        rig_config: Any = None,
        test_spec: Any = None,
        lubricated: bool = False,
        start_time: str | None = None,
        compression: str = "gzip",
        chunk_samples: int | None = None,
        flush_interval_s: float = 1.0,
        max_backlog_s: float = 30.0,
        overwrite: bool = False,
        swmr: bool = True,
        pool: ThreadPoolExecutor | None = None,
        wait_when_behind: bool = False,
        board: Mapping[str, str] | None = None,
    ) -> None:
        """Create the run file with every dataset and attribute, then switch SWMR on.

        Parameters
        ----------
        path : str or Path
            The ``.h5`` file to create. Refused if it exists, unless ``overwrite``.
        run_id : str
            Unique run identifier.
        kind : str
            One of ``KINDS`` ("sweep", "static", "impact", "probe_calibration", "flow",
            "imported", "commissioning").
        channels : sequence of dict
            Analog inputs in channel-map order (the row order of ``ai`` in `on_block`). Each dict
            has ``name`` and optionally ``units``, ``kind``, ``sensor``, ``gain_v_per_unit`` [V per
            unit], ``offset_v`` [V], ``physical_channel`` (e.g. the ``ai`` entries of
            ``ChannelMap.to_json_dict()``). A bare string is a name without metadata.
        ao_names : sequence of str
            Analog-output (shaker drive) names, the row order of ``ao`` in `on_block`; may be
            empty.
        sample_rate_hz : float
            Shared sample clock [S/s]; ``t = sample_index / sample_rate_hz``.
        operator, notes : str
            Who ran the test; free-text notes.
        software_version : str, optional
            Defaults to the installed sfdrig version.
        channel_map : dict or JSON str, optional
            The full channel map; defaults to one built from ``channels`` and ``ao_names``.
        rig_config : dict, JSON str, pydantic model or None
            The simulated rig's parameters (``RigParams``); None (stored as "") on real hardware.
        test_spec : dict, JSON str, pydantic model or None
            The sweep/test description.
        lubricated : bool
            Whether the test ran with the oil film.
        start_time : str, optional
            ISO 8601 UTC; defaults to now.
        compression : {"gzip", "lzf"}
            Filter for the channel datasets (byte shuffle is always on). gzip (deflate level 1)
            is built into every HDF5 tool (HDFView, MATLAB, h5dump); lzf is about twice as fast
            but only h5py (or a plugin) can read it.
        chunk_samples : int, optional
            Samples per chunk; defaults to `default_chunk_samples` (about 1/8 s).
        flush_interval_s : float
            Longest time [s] data may stay unflushed. With a positive interval a background
            I/O thread compresses and writes the blocks, steps and events, so `on_block`,
            `on_step` and `on_event` only hand them over (a write error is raised by the next
            call); 0 makes `on_block` write whole chunks itself, and steps and events are
            written and flushed in the call.
        max_backlog_s : float
            Data [s] the I/O thread may fall behind before `on_block` raises (a disk or CPU
            too slow for the sample rate), rather than filling memory.
        wait_when_behind : bool
            Past ``max_backlog_s``, `on_block` waits for the I/O thread instead of raising: for
            a producer not paced by a clock (the simulated rig's fast mode makes data many
            times faster than real time, faster than any disk takes it), never for a board.
        board : mapping, optional
            The board that records the run (``daq.board.Board.as_dict``): written as the root
            attributes ``board`` (its description, e.g. "simulated rig (in process)"),
            ``backend``, ``device`` and ``grpc_target``; all "" when not given (imported data).
        overwrite : bool
            Replace an existing file.
        swmr : bool
            Write in SWMR mode (readers may open the file while it grows).
        pool : ThreadPoolExecutor, optional
            Where gzip chunks are compressed: a pool shared by successive writers (from
            `deflate_pool`; its owner shuts it down, not the writer). By default the writer
            starts its own and shuts it down at close. A process writing run after run should
            share one: new threads per run each take over a malloc arena of their own, and the
            daemon's resident memory grew with every run (`sfdrig.commands._native_memory`).
        """
        path = Path(path)
        chans, ao_list, chunk_samples = _checked_arguments(
            run_id, kind, channels, ao_names, sample_rate_hz, compression, chunk_samples,
            flush_interval_s, max_backlog_s)
        ai_names = [c["name"] for c in chans]
        if channel_map is None:
            channel_map = {
                "sample_rate_hz": float(sample_rate_hz),
                "ai": chans,
                "ao": [{"name": n} for n in ao_list],
            }

        self.path = path
        self.run_id = run_id
        self.kind = kind
        self.sample_rate_hz = float(sample_rate_hz)
        self.ai_names = ai_names
        self.ao_names = ao_list
        self.chunk_samples = int(chunk_samples)
        self.flush_interval_s = float(flush_interval_s)
        self.max_backlog_s = float(max_backlog_s)
        # Two locks: _buf_lock guards the hand-over of blocks (all on_block ever takes, so the
        # acquisition thread never waits for compression or disk); _io_lock serialises file
        # I/O. Order: _io_lock before _buf_lock.
        self._buf_lock = threading.Lock()
        self._io_lock = threading.RLock()
        self._flushed = threading.Condition()
        # the I/O thread took the blocks handed over (a writer waiting when behind wakes)
        self._drained = threading.Condition(self._buf_lock)
        self.wait_when_behind = bool(wait_when_behind)
        self._wake = threading.Event()
        # Samples flow: on_block -> _pending (list of blocks, the hand-over) -> the chunk
        # writer (whole chunks, and at a flush the partly filled last one) -> file.
        self._pending: list[np.ndarray] = []  # (n_ds, n) blocks not yet given to _chunks
        self._pending_n = 0
        self._next_sample = 0  # expected first_sample of the next block
        # steps and events handed over, not yet written (with the I/O thread: it writes them,
        # each after the samples before it, and flushes; the caller never waits on the disk)
        self._records: list[tuple[str, Any]] = []
        self._records_handed = 0   # steps and events handed over so far (under _buf_lock)
        self._records_written = 0  # of those, written and flushed (under _flushed)
        # gzip chunks are shuffled and deflated in threads (zlib releases the GIL) and handed
        # to HDF5 ready-made; HDF5's own filter pipeline would run them one by one.
        self._pool: ThreadPoolExecutor | None = None
        self._own_pool = False
        if compression == "gzip":
            self._pool = pool
            if pool is None:
                self._pool = deflate_pool(f"RunWriter-{run_id}")
                self._own_pool = True
        self._samples_flushed = 0
        self._n_steps = 0
        self._n_events = 0
        self._closed = False
        self.status: str | None = None
        self.flush_error: Exception | None = None

        self._motions: set[str] = set()  # the steps' motions, for the run index's row
        mode = "w" if overwrite else "w-"
        try:
            f = h5py.File(path, mode, libver=LIBVER)
        except FileExistsError:
            raise FileExistsError(
                f"{path}: run file exists already (pass overwrite=True)"
            ) from None
        except OSError as err:
            if path.exists() and not overwrite:
                raise FileExistsError(f"{path}: run file exists already") from None
            raise OSError(f"{path}: cannot create run file: {err}") from None
        self._file = f
        try:
            self._conditions = (start_time or utc_now_iso(), bool(lubricated),
                                json_attr(test_spec, "test_spec"),
                                json_attr(rig_config, "rig_config"))
            layout = create_layout(
                f, chans, ao_list, self.chunk_samples, compression,
                attrs={
                    "format": FORMAT,
                    "format_version": FORMAT_VERSION,
                    "run_id": run_id,
                    "kind": kind,
                    "start_time": self._conditions[0],
                    "stop_time": "",
                    "operator": hdf5_text(operator),
                    "notes": hdf5_text(notes),
                    "software_version": software_version or installed_software_version(),
                    "sample_rate_hz": float(sample_rate_hz),
                    "channel_map": json_attr(channel_map, "channel_map"),
                    "rig_config": self._conditions[3],
                    "test_spec": self._conditions[2],
                    "lubricated": bool(lubricated),
                    "status": "running",
                    "status_reason": "",
                    **board_attrs(board),
                    **writer_identity(),
                },
            )
            self._chunks = ChunkWriter(layout.samples, self.chunk_samples, compression,
                                       self._pool)
            self._steps, self._harm = layout.steps, layout.harmonics
            self._drive_v, self._events = layout.drive_v, layout.events
            f.flush()
            if swmr:
                f.swmr_mode = True
        except BaseException:
            f.close()
            path.unlink(missing_ok=True)
            if self._pool is not None and self._own_pool:
                self._pool.shutdown()
            raise
        self.status = "running"
        self._last_flush = time.monotonic()
        self._io_thread: threading.Thread | None = None
        if self.flush_interval_s > 0:
            self._io_thread = threading.Thread(
                target=self._io_loop, name=f"RunWriter-io-{run_id}", daemon=True
            )
            self._io_thread.start()
        self._record("running")

    # --- contract A ---------------------------------------------------------------------------
    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray | None) -> None:
        """Append one block of samples.

        Parameters
        ----------
        first_sample : int
            Index of the block's first sample from 0 at run start; blocks must be contiguous.
        ai : ndarray, shape (n_ai, n)
            Engineering units, channel order as given to `create`.
        ao : ndarray, shape (n_ao, n), or None when the run has no drives
            Drive volts written for the same samples [V].
        """
        ai = np.asarray(ai, dtype=np.float64)
        n_ai, n_ao = len(self.ai_names), len(self.ao_names)
        if ai.ndim != 2 or ai.shape[0] != n_ai:
            raise ValueError(f"{self.path}: ai block has shape {ai.shape}, expected ({n_ai}, n)")
        n = ai.shape[1]
        if ao is None:
            ao = np.empty((0, n))
        ao = np.asarray(ao, dtype=np.float64)
        if ao.shape != (n_ao, n):
            raise ValueError(f"{self.path}: ao block has shape {ao.shape}, expected ({n_ao}, {n})")
        with self._buf_lock:
            self._check_open()
            if first_sample != self._next_sample:
                raise ValueError(
                    f"{self.path}: block starts at sample {first_sample}, expected "
                    f"{self._next_sample} (blocks must be contiguous and in order)"
                )
            if n == 0:
                return
            backlog_s = (self._pending_n + n) / self.sample_rate_hz
            if self._io_thread is not None and backlog_s > self.max_backlog_s \
                    and self.wait_when_behind:
                # until the I/O thread has taken what waits (a block alone may be longer)
                self._wake.set()
                self._drained.wait_for(lambda: (
                    self._pending_n == 0
                    or (self._pending_n + n) / self.sample_rate_hz <= self.max_backlog_s
                    or self._closed or self.flush_error is not None))
                self._check_open()
            elif self._io_thread is not None and backlog_s > self.max_backlog_s:
                raise OSError(
                    f"{self.path}: the run writer is {backlog_s:.1f} s behind the acquisition "
                    f"(limit {self.max_backlog_s:g} s): disk or CPU too slow for "
                    f"{n_ai + n_ao} channels at {self.sample_rate_hz:g} S/s"
                )
            # Copy: the caller may reuse its buffers.
            self._pending.append(np.concatenate((ai, ao)) if n_ao else ai.copy())
            self._pending_n += n
            self._next_sample += n
            # a chunk completed: the I/O thread compresses and writes it (it writes nothing
            # else until a flush, which it wakes for on its own, so waking it for every block
            # cost a thread switch and its loop per 10 ms block for nothing)
            chunk_done = (first_sample // self.chunk_samples
                          != self._next_sample // self.chunk_samples)
        if self._io_thread is not None:
            if chunk_done:
                self._wake.set()
            return
        with self._io_lock:  # no I/O thread: write completed chunks now
            self._check_open()
            self._write_pending(whole_chunks_only=True)

    def on_step(self, step: StepRecord) -> None:
        """Append one step and flush the file (its rows are checked here; `ValueError` names
        what is wrong)."""
        try:
            rows = step_rows(step, self.ai_names, self.ao_names)
        except ValueError as err:
            raise ValueError(f"{self.path}: {err}") from None
        self._motions.add(step.motion or "")
        self._hand_over("step", rows)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        """Log one event (kind from `EVENT_KINDS`; others are kept as given) and flush."""
        self._hand_over("event", event_row(EventRecord(kind, message, sample)))

    def _hand_over(self, kind: str, record: Any) -> None:
        """A step's or an event's rows, checked: to the I/O thread, which writes them after the
        samples handed over before them and flushes; without one, written and flushed now."""
        with self._buf_lock:
            self._check_open()
            self._records.append((kind, record))
            self._records_handed += 1
            seq = self._records_handed
        if self._io_thread is not None:
            self._wake.set()
            # Wait until it is on disk: the publisher announces it after this returns, and a
            # client that saw it on the wire must find it in the file even after a kill -9.
            # One step a dwell, so the wait (milliseconds) costs the control loop nothing; a
            # stalled disk is bounded by RECORD_WAIT_S (the AO ring covers it) and then reported
            # by the next call as a flush error, as for samples.
            with self._flushed:
                self._flushed.wait_for(
                    lambda: (self._records_written >= seq or self._closed
                             or self.flush_error is not None),
                    RECORD_WAIT_S,
                )
            return
        with self._io_lock:
            self._check_open()
            self._write_records()

    def _write_records(self) -> None:
        """Write the steps and events handed over, in order, each after the samples before it
        (the dwell's samples reach the file before its row), then flush (caller holds
        _io_lock)."""
        with self._buf_lock:
            records, self._records = self._records, []
            handed = self._records_handed
        if not records:
            return
        self._write_pending()
        for kind, record in records:
            if kind == "step":
                row, harm, drive = record
                i = self._n_steps
                self._steps.resize((i + 1,))
                self._steps[i] = row
                self._harm.resize((i + 1, *self._harm.shape[1:]))
                self._harm[i] = harm
                if self.ao_names:
                    self._drive_v.resize((i + 1, len(self.ao_names)))
                    self._drive_v[i] = drive
                self._n_steps = i + 1
            else:
                i = self._n_events
                self._events.resize((i + 1,))
                self._events[i] = record
                self._n_events = i + 1
        self._flush_locked()
        with self._flushed:
            self._records_written = handed
            self._flushed.notify_all()

    # --- flushing -----------------------------------------------------------------------------
    @property
    def samples_received(self) -> int:
        """Samples passed to `on_block` so far."""
        return self._next_sample

    @property
    def samples_flushed(self) -> int:
        """Samples made durable and visible to readers by the last flush."""
        return self._samples_flushed

    def flush(self) -> None:
        """Write every buffered sample, step and event and flush the file to disk (readers see
        it all)."""
        with self._io_lock:
            self._check_open()
            self._write_records()
            self._flush_locked()

    def wait_flushed(self, n_samples: int, timeout_s: float) -> bool:
        """Block until at least ``n_samples`` are flushed; False on timeout."""
        with self._flushed:
            self._flushed.wait_for(
                lambda: (self._samples_flushed >= n_samples or self._closed
                         or self.flush_error is not None),
                timeout_s,
            )
            return self._samples_flushed >= n_samples

    def _write_pending(self, whole_chunks_only: bool = False) -> None:
        """Move the blocks handed over into the datasets: every completed chunk, and with
        ``whole_chunks_only=False`` also the partly filled last chunk (for a flush)."""
        with self._buf_lock:
            blocks, self._pending, self._pending_n = self._pending, [], 0
            self._drained.notify_all()
        self._chunks.write(blocks, whole_chunks_only)

    def _flush_locked(self) -> None:
        """Everything into the file, then flush (caller holds _io_lock)."""
        self._write_pending()
        self._file.flush()
        self._last_flush = time.monotonic()
        with self._flushed:
            self._samples_flushed = self._chunks.written
            self._flushed.notify_all()

    def _unflushed(self) -> bool:
        return bool(self._pending_n or self._chunks.holds_unwritten
                    or self._samples_flushed < self._chunks.written or self._records)

    def _io_loop(self) -> None:
        """Background I/O: write completed chunks as blocks arrive; flush when due."""
        interval = self.flush_interval_s
        while True:
            self._wake.wait(max(0.0, self._last_flush + interval - time.monotonic()))
            self._wake.clear()
            with self._io_lock:
                if self._closed:
                    return
                try:
                    self._write_records()  # (flushes: see `_hand_over`)
                    self._write_pending(whole_chunks_only=True)
                    if time.monotonic() - self._last_flush >= interval:
                        if self._unflushed():
                            self._flush_locked()
                        else:
                            # Heartbeat: a fresh mtime tells the catalog the writer is alive
                            # even while no samples arrive (a paused sweep).
                            os.utime(self.path)
                            self._last_flush = time.monotonic()
                except Exception as err:  # e.g. a full disk: raised by the next call
                    self.flush_error = err
                    with self._flushed:
                        self._flushed.notify_all()
                    with self._buf_lock:
                        self._drained.notify_all()
                    return

    # --- closing ------------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: run writer is closed")
        if self.flush_error is not None:
            raise OSError(f"{self.path}: background flush failed: {self.flush_error}")

    def close(self, status: RunFileStatus = "completed", reason: str = "") -> None:
        """Flush everything, end the SWMR session, and record the final status and stop time.

        Parameters
        ----------
        status : {"completed", "aborted", "failed"}
            How the run ended.
        reason : str
            Why, when it did not complete ("" otherwise).
        """
        if status not in STATUSES[1:]:
            raise ValueError(f"close status {status!r} is not one of {STATUSES[1:]}")
        error: BaseException | None = None
        with self._io_lock:
            if self._closed:
                return
            try:
                if self.flush_error is None:
                    self._write_records()
                    self._flush_locked()
            except Exception as err:  # e.g. disk full: still end the run as cleanly as possible
                error = err
            finally:
                with self._buf_lock:
                    self._closed = True
                    self._drained.notify_all()
                self._wake.set()
                try:
                    self._file.close()
                except Exception as err:
                    error = error or err
                with self._flushed:
                    self._flushed.notify_all()
        if self._io_thread is not None and self._io_thread is not threading.current_thread():
            self._io_thread.join()
        if self._pool is not None and self._own_pool:
            self._pool.shutdown()
        error = error or self.flush_error
        if error is not None:
            lost = (f"samples from {self._samples_flushed} on may be lost: "
                    f"{type(error).__name__}: {error}")
            status = "failed"
            reason = f"{reason}; {lost}" if reason else lost
        # Attributes cannot change under SWMR: reopen without it for the final word.
        final = {"stop_time": utc_now_iso(), "status": status,
                 "status_reason": hdf5_text(reason)}
        try:
            try:
                f = h5py.File(self.path, "r+", libver=LIBVER)
            except BlockingIOError:
                # A live SWMR reader (another process) holds a shared lock. It reads the root
                # attributes only when it opens, so rewriting them under it is safe.
                f = h5py.File(self.path, "r+", libver=LIBVER, locking=False)
            with f:
                for key, value in final.items():
                    f.attrs[key] = value
        except Exception as err:
            error = error or err
        self.status = status
        if error is None:  # (else the file may hold less than this writer knows: read it)
            self._record(status, final["stop_time"], final["status_reason"])
        if error is not None:
            raise OSError(f"{self.path}: run closed with errors: {error}") from error

    def _record(self, status: str, stop_time: str = "", reason: str = "") -> None:
        """The run's row in its directory's run index (`storage.run_index.record_run`): when
        it starts, and when it has ended (the file changes no more)."""
        start, lubricated, spec_text, rig_text = self._conditions
        try:
            spec = json.loads(spec_text) if spec_text else None
            rig = json.loads(rig_text) if rig_text else None
            row = RunRow(id=self.run_id, date=start, kind=self.kind,
                         steps=self._n_steps if status != "running" else 0, status=status,
                         duration_s=round(self._samples_flushed / self.sample_rate_hz, 6),
                         file=str(self.path), lubricated=lubricated, seal=seal_of(spec, rig),
                         motion=motion_of(self._motions, spec), stop_time=stop_time,
                         n_samples=self._samples_flushed, status_reason=reason)
        except (ValueError, TypeError):  # a spec the index cannot state: the next look reads
            return  # the file (an index never fails a run)
        record_run(self.path, row, final=status != "running")

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        if self._closed:
            return
        if exc is None:
            self.close("completed")
        elif isinstance(exc, KeyboardInterrupt):
            self.close("aborted", "interrupted (KeyboardInterrupt)")
        else:
            self.close("failed", f"{type(exc).__name__}: {exc}")

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<RunWriter {self.run_id!r} {self.path} {state}, {self._next_sample} samples>"


def _checked_arguments(run_id: str, kind: str, channels: Sequence[Mapping[str, Any] | str],
                       ao_names: Sequence[str], sample_rate_hz: float, compression: str,
                       chunk_samples: int | None, flush_interval_s: float,
                       max_backlog_s: float) -> tuple[list[dict[str, Any]], list[str], int]:
    """`RunWriter`'s arguments checked (`ValueError` naming the one at fault): the channels'
    metadata, the drive names and the chunk length."""
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} is not one of {KINDS}")
    if not isinstance(run_id, str) or not run_id:
        raise ValueError(f"run_id must be a non-empty string, got {run_id!r}")
    try:
        rate_ok = math.isfinite(float(sample_rate_hz)) and float(sample_rate_hz) > 0
    except (TypeError, ValueError):
        rate_ok = False
    if not rate_ok:
        raise ValueError(f"sample_rate_hz must be a positive number, got {sample_rate_hz!r}")
    if not flush_interval_s >= 0 or not max_backlog_s > 0:
        raise ValueError(f"flush_interval_s ({flush_interval_s}) must be >= 0 and "
                         f"max_backlog_s ({max_backlog_s}) > 0")
    if compression not in ("lzf", "gzip"):
        raise ValueError(f"compression {compression!r} is not 'lzf' or 'gzip'")
    chans: list[dict[str, Any]] = []
    for i, ch in enumerate(channels):
        meta = {"name": ch} if isinstance(ch, str) else dict(ch)
        check_name(meta.get("name"), f"channels[{i}]")
        chans.append(meta)
    if not chans:
        raise ValueError("a run needs at least one analog-input channel")
    ai_names = [c["name"] for c in chans]
    ao_list = [check_name(n, f"ao_names[{i}]") for i, n in enumerate(ao_names)]
    for label, names in (("channels", ai_names), ("ao_names", ao_list)):
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"{label}: duplicate names {sorted(dup)}")
    if chunk_samples is None:
        chunk_samples = default_chunk_samples(float(sample_rate_hz))
    if chunk_samples < 1:
        raise ValueError(f"chunk_samples must be >= 1, got {chunk_samples}")
    return chans, ao_list, int(chunk_samples)


__all__ = [
    "EVENT_KINDS", "FORMAT", "FORMAT_VERSION", "KINDS", "LIBVER", "N_HARMONICS", "STATUSES",
    "STEP_KEYS", "RunWriter", "default_chunk_samples", "deflate_pool", "hdf5_text", "utc_now_iso",
]
