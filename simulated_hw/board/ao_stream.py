"""A hardware-timed AO task's sample stream: what it generates next, and what its terminals do
once the generation stops.

Three ways a DAQmx AO buffer plays (the same rules as NI-DAQmx):

- non-regenerating: every sample written is generated once, in order; running out of samples
  stops the generation with -200290 (underflow). Once the task runs, the board moves samples
  from the buffer into its on-board FIFO (`fifo_samples`, 8,191 on a PXIe-6358) as soon as
  there is room, so the buffer holds its size plus the FIFO: a write returns while that much is
  still queued, as NI's continuous non-regenerating example relies on;
- regenerating (nidaqmx's default): the buffer written before the start plays in a loop; writes
  while running overwrite it from the write position onwards: the current write position
  (after the last sample written) plus ``out_stream.offset``, or with ``out_stream.relative_to``
  FIRST_SAMPLE the buffer's sample ``offset`` (0 <= offset < the buffer). What is overwritten
  ahead of the generation plays when the generation gets there (a write lands at once: the
  FIFO's copy of those samples is not modelled);
- finite: ``samps_per_chan`` samples are generated (looping a shorter regenerating buffer), then
  the task is done.

When the generation stops (underflow, the end of a finite task, stop, a watchdog expiry) each
terminal goes to its channel's idle output behaviour: 0 V when ``ao_idle_output_behavior`` is
``ZERO_VOLTS``, otherwise it keeps the last sample generated.
"""

from __future__ import annotations

import numpy as np

from daq.errors import INVALID_ATTRIBUTE_VALUE, OUTPUT_UNDERFLOW
from simulated_hw.board.codes import (
    AO_FIFO_SAMPLES,
    IDLE_ZERO_VOLTS,
    WRITE_REL_FIRST_SAMPLE,
    daq_error,
)
from simulated_hw.board.tasks import SimTask


def fifo_samples(task: SimTask) -> int:
    """The on-board FIFO in use by the task, per channel (the PXIe-6358's 8,191 samples are
    shared by the task's channels; ``out_stream.output_onbrd_buf_size`` may shrink it)."""
    return task.onboard_samples or AO_FIFO_SAMPLES // max(len(task.channels), 1)


def fifo_ahead(task: SimTask) -> int:
    """Samples the board has moved from the buffer into its FIFO, ahead of the generation."""
    if not generating(task):
        return 0
    if task.ao.loop is not None:
        return fifo_samples(task)
    return min(task.ao.queued, fifo_samples(task))


def idle_values(task: SimTask) -> np.ndarray:
    """What each channel's terminal shows when the task generates nothing [V]."""
    last = task.ao.last if task.ao.last is not None else np.zeros(len(task.channels))
    zero = np.array([c.idle_behavior == IDLE_ZERO_VOLTS for c in task.channels])
    return np.where(zero, 0.0, last)


def generating(task: SimTask) -> bool:
    return task.running and task.error is None and not task.done


def queue(task: SimTask, block: np.ndarray) -> None:
    """Put ``block`` (n_ch, n) in the task's buffer (see the module doc for the modes)."""
    stream = task.ao
    first = task.write_relative_to == WRITE_REL_FIRST_SAMPLE
    if task.regenerating and task.running and stream.loop is not None:
        size = stream.loop.shape[1]
        if first and not 0 <= task.write_offset < size:
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"task {task.name!r}: write offset {task.write_offset} relative to "
                            f"the first sample is outside the {size}-sample buffer")
        pos = task.write_offset if first else (stream.written + task.write_offset) % size
        stream.overwrite(block, pos)
        return
    if task.regenerating and first and task.write_offset != stream.queued:
        raise daq_error(INVALID_ATTRIBUTE_VALUE,
                        f"task {task.name!r}: before the start the simulated device writes "
                        f"a regenerating buffer in order (offset {stream.queued}), not at "
                        f"offset {task.write_offset}")
    stream.queue(block)


def freeze_regeneration(task: SimTask) -> None:
    """At the start of a regenerating task: the buffer written so far becomes the loop."""
    if task.regenerating:
        task.ao.freeze()


def take(task: SimTask, n: int, into: np.ndarray | None = None) -> np.ndarray:
    """The next ``n`` samples the task's terminals show, shape (n_ch, n) (written to ``into``
    when given). Past the end of the generation (underflow: the error is set on the task; end
    of a finite task: ``done``) the terminals show their idle values."""
    stream = task.ao
    out = np.empty((len(task.channels), n)) if into is None else into
    limit = n if generating(task) else 0
    if task.finite:
        limit = min(limit, max(task.samps_per_chan - stream.generated, 0))
    got = stream.take_into(out[:, :limit])
    if task.finite and stream.generated >= task.samps_per_chan:
        task.done = True  # its last sample is out
    if got < n:
        if generating(task):
            task.error = daq_error(
                OUTPUT_UNDERFLOW,
                f"task {task.name!r}: the AO generation reached sample {stream.generated} "
                "since its start, the end of the samples written (the next ones came too "
                "late); the outputs went to their idle state",
            )
        out[:, got:] = idle_values(task)[:, None]
    return out


def skip(task: SimTask, n: int) -> None:
    """Generate ``n`` samples nobody samples (no AI runs): only the counts, the end of the
    generation and the last value matter, so a long regenerating stretch costs nothing."""
    if n <= 0:
        return
    stream = task.ao
    if stream.loop is not None:
        room = n if not task.finite else min(n, max(task.samps_per_chan - stream.generated, 0))
        jump = max(room - 1, 0)
        stream.generated += jump
        take(task, min(n - jump, room - jump + 1))
    else:
        take(task, min(n, stream.queued + 1))
