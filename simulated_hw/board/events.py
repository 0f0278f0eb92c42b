"""The board's event streams (DAQmx Register*Event over gRPC): every N samples acquired into or
transferred from the buffer, and done.

Each registration is one server stream that lives until the client cancels it (unregistering,
or clearing the task). The stream sends its initial metadata at once (the client waits for it
before it starts the task), then one message per event, in order:

- every N samples acquired into the buffer (AI): when the acquisition's sample count passes
  each multiple of N (the count restarts with each start of the task);
- every N samples transferred from the buffer (AO, DO): when the generation count plus what the
  on-board FIFO holds ahead of it passes each multiple of N (the board moves samples into its
  FIFO as soon as there is room, so the first events come at the start);
- done: once when a running finite task ends by itself, or when an error stops it (the message
  carries the error code); not when the task is stopped.

The stream follows the device clock: paced, it waits (outside the device lock) until the next
event is due; fast, an acquisition's next N samples are taken once the reader has read what
was there, so the client's callback, not the wall clock, paces it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

from nidaqmx._stubs import nidaqmx_pb2 as pb

from simulated_hw.board import ao_stream
from simulated_hw.board.codes import (
    EVERY_N_ACQ_NOT_SUPPORTED,
    EVERY_N_XFER_NOT_SUPPORTED,
    daq_error,
)
from simulated_hw.board.tasks import SimTask

ACQUIRED_INTO_BUFFER, TRANSFERRED_FROM_BUFFER = 1, 2  # EveryNSamplesEventType
_POLL_S = 0.02  # longest wait between looks at the task (a stop, a cancelled stream)


def check_every_n(task: SimTask, event_type: int, n: int) -> None:
    """Refuse a registration the board refuses (DAQmx -200981 / -200980)."""
    if event_type == ACQUIRED_INTO_BUFFER and (task.kind not in ("ai", "di")
                                               or task.rate_hz is None or n <= 0):
        raise daq_error(EVERY_N_ACQ_NOT_SUPPORTED,
                        f"task {task.name!r}: every N samples acquired into the buffer needs a "
                        "buffered (sample-clocked) input task and N > 0")
    if event_type == TRANSFERRED_FROM_BUFFER and (task.kind not in ("ao", "do")
                                                  or task.rate_hz is None or n <= 0):
        raise daq_error(EVERY_N_XFER_NOT_SUPPORTED,
                        f"task {task.name!r}: every N samples transferred from the buffer needs "
                        "a buffered (sample-clocked) output task and N > 0")


def every_n_samples(device: Any, task: SimTask, event_type: int, n: int,
                    alive: Callable[[], bool]) -> Iterator[Any]:
    """The event stream's messages (see the module doc); ends when ``alive()`` is false."""
    fired = 0
    run = -1
    while alive():
        with device.lock:
            device.catch_up()
            if task.run_id != run:  # a new start of the task: its count starts again
                run, fired = task.run_id, 0
            count, due_at = _progress(device, task, event_type, (fired + 1) * n)
        if count >= (fired + 1) * n:
            fired += 1
            yield pb.RegisterEveryNSamplesEventResponse(
                status=0, every_n_samples_event_type_raw=event_type, n_samples=n)
            continue
        _wait(device, due_at)


def _progress(device: Any, task: SimTask, event_type: int, want: int) -> tuple[int, float]:
    """(samples acquired or transferred so far, device time the ``want``-th is due or inf)."""
    if not task.running or task.error is not None:
        return 0, math.inf
    if event_type == ACQUIRED_INTO_BUFFER:
        if task.kind == "di":
            return device.di_acquired(task), device.di_due_at(task, want)
        if task is not device.ai_task:
            return 0, math.inf
        if device.fast:  # the reader paces a fast board: N more once it has read all
            if device.read_pos >= device.generated and (
                    not task.finite or device.generated < task.samps_per_chan):
                device.advance_to(min(want, task.samps_per_chan) if task.finite else want)
            return device.generated, math.inf
        return device.generated, device.t0 + want / device.ai_rate
    ahead = ao_stream.fifo_ahead(task)
    count = task.ao.generated + ahead
    rate = task.rate_hz or 1.0
    if task.t_start is not None:
        return count, task.t_start + (want - ahead) / rate
    if device.ai_task is not None and not device.fast:  # on the AI sample clock
        return count, device.t0 + (task.first_sample + want - ahead) / device.ai_rate
    return count, math.inf


def _wait(device: Any, due_at: float) -> None:
    if device.fast or not math.isfinite(due_at):
        device.pause(_POLL_S)
        return
    device.pause(min(max(due_at - device.now(), 0.0), _POLL_S))


def done(device: Any, task: SimTask, alive: Callable[[], bool]) -> Iterator[Any]:
    """The done event's messages: status 0 at the end of a finite task, the error's code when
    an error stops one."""
    told = -1
    while alive():
        with device.lock:
            run = task.run_id
            status = None
            if task.running and told != run:
                device.catch_up()
                if task.error is not None:
                    status = task.error.code or -1
                elif task.finite and _ended(device, task):
                    status = 0
            end = device.end_time(task) if status is None else None
        if status is not None:
            told = run
            yield pb.RegisterDoneEventResponse(status=status)
            continue
        if device.fast and end is not None:
            device.wait_until_done(task, -1.0)
            continue
        _wait(device, end if end is not None else math.inf)


def _ended(device: Any, task: SimTask) -> bool:
    if task.kind == "co":  # a pulse generation ends on the counter's timebase
        return bool(device.is_done(task))
    if task is device.ai_task:
        return bool(device.generated >= task.samps_per_chan)
    return task.done

