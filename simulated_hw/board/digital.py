"""Digital I/O on the simulated board: a channel's lines as one port value, software-timed and
hardware-timed DO and DI, and the RPCs that read and write lines, ports (uint8/16/32) and
scalars.

A channel's value is its lines' levels as the bits of their port (``port0/line3`` is bit 3), as
DAQmx's port reads and writes give them. A DO task with a sample clock is a stream like AO
(`simulated_hw.board.ao_stream`: regenerating or not, finite or continuous, written before the
start, done at the end of a finite one); its lines take each sample when the clock generates it.
A DI task with a sample clock takes a sample per clock tick: a read waits for them (DAQmx -200284
past the timeout), a finite one ends at its last sample. A line in a DI task reads what drives it
from outside (the emergency-stop loop of the wiring map), else the board's pull-down: low. A DO
task reads back what it drives.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb

from daq.errors import READ_TIMEOUT
from simulated_hw.board.codes import (
    FILL_GROUP_BY_CHANNEL,
    READ_BUFFER_TOO_SMALL,
    SAMPLES_WILL_NEVER_BE_AVAILABLE,
    TASK_NOT_RUNNING,
    WRITE_NUM_CHANS_MISMATCH,
    daq_error,
)
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimChannel, SimTask
from simulated_hw.board.wire import reports_daq_errors


def line_bit(physical: str) -> int:
    """The bit of a line in its port: ``Dev1/port0/line3`` -> 3."""
    return int(physical.rsplit("line", 1)[1])


def channel_value(device: Any, task: SimTask, ch: SimChannel) -> int:
    value = 0
    for p in ch.physical:
        if device.line_level_for(task, p):
            value |= 1 << line_bit(p)
    return value


def lines_of(ch: SimChannel, value: int) -> dict[str, bool]:
    return {p: bool((int(value) >> line_bit(p)) & 1) for p in ch.physical}


# --- the device side ------------------------------------------------------------------------
def read(device: Any, task: SimTask, n: int, timeout_s: float, others: list[SimTask]
         ) -> np.ndarray:
    """``n`` samples of every channel's port value, shape (n_ch, n) (``n < 0``: what is there,
    at least one)."""
    if task.kind not in ("di", "do"):
        task.kind_or_raise("di")
    with device.lock:
        if not task.running:
            device.start(task, others)
            task.auto_started = True
        timed = task.rate_hz is not None and task.kind == "di"
        if timed:
            if n < 0:
                n = (task.samps_per_chan - task.di_read if task.finite
                     else max(device.di_acquired(task) - task.di_read, 1))
            if task.finite and task.di_read + n > task.samps_per_chan:
                raise daq_error(SAMPLES_WILL_NEVER_BE_AVAILABLE,
                                f"read of {n} samples from {task.name!r}: only "
                                f"{task.samps_per_chan - task.di_read} are left",
                                samps_per_chan_read=0)
            ready_at = device.di_due_at(task, task.di_read + n)
        n = max(n, 1)
    if timed and not device.fast:
        now = device.now()
        if timeout_s >= 0 and ready_at > now + timeout_s:
            device.sleep(timeout_s)
            raise daq_error(READ_TIMEOUT, f"read of {n} samples from {task.name!r} timed out "
                            f"after {timeout_s:g} s", samps_per_chan_read=0)
        while now < ready_at and not device.stopping():
            device.sleep(ready_at - now)
            now = device.now()
    with device.lock:
        device.catch_up()
        values = np.array([[channel_value(device, task, ch)] for ch in task.channels],
                          dtype=np.uint32)
        if timed:
            task.di_read += n
            if task.finite and task.di_read >= task.samps_per_chan:
                task.done = True
                if task.auto_started:
                    device.stop(task)
        elif task.auto_started:  # an implicitly started on-demand task ends with the read
            device.stop(task)
    return np.repeat(values, n, axis=1)


def write(device: Any, task: SimTask, block: np.ndarray, auto_start: bool, timeout_s: float,
          others: list[SimTask]) -> int:
    """Write port values (n_ch, n): software-timed, the lines take the last sample now;
    sample-clocked, the samples are queued for the clock (see the module doc)."""
    task.kind_or_raise("do")
    if task.rate_hz is not None:
        return int(device.write_ao(task, block.astype(np.float64), auto_start, timeout_s,
                                   others))
    with device.lock:
        if not task.running:
            if not auto_start:
                raise daq_error(TASK_NOT_RUNNING, f"write to {task.name!r}: task not running")
            device.start(task, others)
        levels: dict[str, bool] = {}
        for ch, value in zip(task.channels, block[:, -1], strict=True):
            levels.update(lines_of(ch, int(value)))
        device.write_lines(list(levels), list(levels.values()))
    return int(block.shape[1])


# --- the RPCs -------------------------------------------------------------------------------
class DigitalRpcs(ServicerParts):
    """Read/WriteDigitalLines, Read/WriteDigitalU8/U16/U32 and their scalars."""

    def _read_ports(self, request: Any, per_value: int) -> tuple[SimTask, np.ndarray]:
        task = self._task(request.task)
        n = request.num_samps_per_chan
        data = read(self.device, task, n, request.timeout, self._others())
        if request.array_size_in_samps < data.size:
            raise daq_error(READ_BUFFER_TOO_SMALL,
                            f"read of {data.shape[1]} samples from {task.name!r}: the client "
                            f"buffer holds only {request.array_size_in_samps}",
                            samps_per_chan_read=0)
        if request.fill_mode_raw != FILL_GROUP_BY_CHANNEL:
            data = data.T
        return task, data

    def _write_ports(self, request: Any, values: Any) -> int:
        task = self._task(request.task)
        n = request.num_samps_per_chan
        flat = np.asarray(values, dtype=np.uint32)
        n_ch = len(task.channels)
        if n <= 0 or flat.size != n * n_ch:
            raise daq_error(WRITE_NUM_CHANS_MISMATCH,
                            f"write to {task.name!r}: {flat.size} values for {n} samples x "
                            f"{n_ch} channels")
        block = (flat.reshape(n_ch, n) if request.data_layout_raw == FILL_GROUP_BY_CHANNEL
                 else flat.reshape(n, n_ch).T)
        return write(self.device, task, block, request.auto_start, request.timeout,
                     self._others())

    @reports_daq_errors
    def ReadDigitalU32(self, request, context):  # noqa: N802
        _, data = self._read_ports(request, 4)
        return pb.ReadDigitalU32Response(read_array=data.ravel().tolist(),
                                         samps_per_chan_read=data.size // max(1, min(data.shape)))

    @reports_daq_errors
    def ReadDigitalU16(self, request, context):  # noqa: N802
        task, data = self._read_ports(request, 2)
        return pb.ReadDigitalU16Response(read_array=(data.ravel() & 0xFFFF).tolist(),
                                         samps_per_chan_read=data.size // len(task.channels))

    @reports_daq_errors
    def ReadDigitalU8(self, request, context):  # noqa: N802
        task, data = self._read_ports(request, 1)
        return pb.ReadDigitalU8Response(read_array=(data.ravel() & 0xFF).astype(np.uint8)
                                        .tobytes(),
                                        samps_per_chan_read=data.size // len(task.channels))

    @reports_daq_errors
    def WriteDigitalU32(self, request, context):  # noqa: N802
        return pb.WriteDigitalU32Response(
            samps_per_chan_written=self._write_ports(request, request.write_array))

    @reports_daq_errors
    def WriteDigitalU16(self, request, context):  # noqa: N802
        return pb.WriteDigitalU16Response(
            samps_per_chan_written=self._write_ports(request, request.write_array))

    @reports_daq_errors
    def WriteDigitalU8(self, request, context):  # noqa: N802
        return pb.WriteDigitalU8Response(samps_per_chan_written=self._write_ports(
            request, np.frombuffer(request.write_array, dtype=np.uint8)))

    @reports_daq_errors
    def ReadDigitalScalarU32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        data = read(self.device, task, 1, request.timeout, self._others())
        return pb.ReadDigitalScalarU32Response(value=int(data[0, 0]))

    @reports_daq_errors
    def WriteDigitalScalarU32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        write(self.device, task, np.array([[request.value]], dtype=np.uint32),
              request.auto_start, request.timeout, self._others())
        return pb.WriteDigitalScalarU32Response(status=0)

    @reports_daq_errors
    def WriteDigitalLines(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("do")
        n = request.num_samps_per_chan
        raw = np.frombuffer(request.write_array, dtype=np.uint8)
        lines = [p for c in task.channels for p in c.physical]
        if n <= 0 or raw.size != n * len(lines):
            raise daq_error(
                WRITE_NUM_CHANS_MISMATCH,
                f"write to {task.name!r}: {raw.size} line values for {n} samples x "
                f"{len(lines)} lines",
            )
        block = np.zeros((len(task.channels), n), dtype=np.uint32)
        grouped = request.data_layout_raw == FILL_GROUP_BY_CHANNEL
        pos = 0
        for i, ch in enumerate(task.channels):
            k = len(ch.physical)
            for j, p in enumerate(ch.physical):
                levels = (raw[pos + j: pos + n * k: k] if grouped
                          else raw[pos + j:: len(lines)][:n])
                block[i] |= (levels != 0).astype(np.uint32) << np.uint32(line_bit(p))
            pos += n * k if grouped else k
        written = write(self.device, task, block, request.auto_start, request.timeout,
                        self._others())
        return pb.WriteDigitalLinesResponse(samps_per_chan_written=written)

    @reports_daq_errors
    def ReadDigitalLines(self, request, context):  # noqa: N802
        """Every channel's lines, one byte per line, padded to the widest channel."""
        task = self._task(request.task)
        data = read(self.device, task, request.num_samps_per_chan, request.timeout,
                    self._others())
        n = data.shape[1]
        per_sample = max(len(c.physical) for c in task.channels)
        if request.array_size_in_bytes < n * per_sample * len(task.channels):
            raise daq_error(READ_BUFFER_TOO_SMALL,
                            f"read of {n} samples from {task.name!r}: the client buffer holds "
                            f"only {request.array_size_in_bytes} bytes", samps_per_chan_read=0)
        out = bytearray()
        for ch, values in zip(task.channels, data, strict=True):
            bits = [line_bit(p) for p in ch.physical]
            for v in values:
                levels = [(int(v) >> b) & 1 for b in bits]
                out += bytes(levels + [0] * (per_sample - len(levels)))
        return pb.ReadDigitalLinesResponse(read_array=bytes(out), samps_per_chan_read=n,
                                           num_bytes_per_samp=per_sample)


def di_due_at(t_start: float | None, rate_hz: float, k: int) -> float:
    """Device time the ``k``-th sample of a sample-clocked DI task is taken."""
    return math.inf if t_start is None else t_start + k / rate_hz
