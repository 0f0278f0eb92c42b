"""TDMS logging of an AI task (``task.in_stream.configure_logging``), written where NI's gRPC
Device Server writes it: on the server's disk. A relative ``file_path`` is relative to the
server's working directory, as for any file a remote session names.

- LOG_AND_READ: every sample a read returns goes to the file too, in the channel's units;
- LOG: the board logs what it acquires without reads: what was acquired is written when the task
  stops, is done or is cleared (a read is refused, DAQmx -201301);
- the group is ``group_name`` (the task's name when empty), a channel per task channel, with
  NI's waveform properties (``wf_start_time``, ``wf_increment``, ``wf_samples``,
  ``NI_ChannelName``, ``unit_string``); each write is a TDMS segment;
- the operation on the file at the task's first samples: OPEN (it must exist: -201310),
  OPEN_OR_CREATE (append), CREATE_OR_REPLACE, CREATE (it must not exist: -201304);
- only buffered (sample-clocked) AI tasks log: on demand -201299, output tasks -201332.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from daq.errors import INVALID_ATTRIBUTE_VALUE
from simulated_hw.board.codes import daq_error
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimTask
from simulated_hw.board.wire import reports_daq_errors

LOG_OFF, LOG_ONLY, LOG_AND_READ = 10231, 15844, 15842  # LoggingMode
OPEN, OPEN_OR_CREATE, CREATE_OR_REPLACE, CREATE = 10437, 15846, 15847, 15848  # LoggingOperation
READ_NOT_SUPPORTED_FOR_LOGGING_MODE = -201301
LOGGING_MODE_NOT_SUPPORTED_NON_BUFFERED = -201299
LOGGING_NOT_SUPPORT_ON_OUTPUT_TASKS = -201332
TDMS_NOT_FOUND = -201310
FILE_PATH_INVALID = -201304


@dataclass
class TdmsLog:
    """Where and how a task logs."""

    path: Path
    mode: int
    group: str
    operation: int
    opened: bool = False  # the operation was applied (at the task's first samples)


def check_read(task: SimTask) -> None:
    """A read of a task that only logs: DAQmx -201301."""
    log: TdmsLog | None = task.tdms_log
    if log is not None and log.mode == LOG_ONLY:
        raise daq_error(READ_NOT_SUPPORTED_FOR_LOGGING_MODE,
                        f"read from {task.name!r}: the task logs to {str(log.path)!r} without "
                        "reads (logging mode LOG); use LOG_AND_READ to read as well")


def write(device: Any, task: SimTask, data: np.ndarray, t_first: float) -> None:
    """Append the samples ``data`` (n_ch, n), whose first was taken at device time
    ``t_first``, to the task's log file."""
    log: TdmsLog | None = task.tdms_log
    if log is None or data.shape[1] == 0:
        return
    if not log.opened:
        _open(log, task.name)
    t0 = datetime.now(UTC) - timedelta(seconds=device.now() - t_first)
    dt = 1.0 / task.rate_hz if task.rate_hz else 0.0
    objects: list[Any] = [RootObject({"name": log.path.stem}),
                          GroupObject(log.group, {"NI_TaskName": task.name})]
    for ch, samples in zip(task.channels, data, strict=True):
        objects.append(ChannelObject(log.group, ch.name, np.ascontiguousarray(samples), {
            "NI_ChannelName": ch.name, "unit_string": "Volts" if ch.temperature_units is None
            else "Deg C", "wf_start_time": np.datetime64(t0.replace(tzinfo=None), "us"),
            "wf_increment": dt, "wf_samples": int(samples.size), "wf_start_offset": 0.0}))
    with TdmsWriter(str(log.path), mode="a") as writer:
        writer.write_segment(objects)


def _open(log: TdmsLog, task_name: str) -> None:
    exists = log.path.exists()
    if log.operation == OPEN and not exists:
        raise daq_error(TDMS_NOT_FOUND, f"task {task_name!r}: logging operation OPEN, but "
                        f"{str(log.path)!r} does not exist on the server")
    if log.operation == CREATE and exists:
        raise daq_error(FILE_PATH_INVALID, f"task {task_name!r}: logging operation CREATE, "
                        f"but {str(log.path)!r} already exists on the server")
    if log.operation == CREATE_OR_REPLACE and exists:
        log.path.unlink()
        log.path.with_name(log.path.name + "_index").unlink(missing_ok=True)
    log.opened = True


def flush(device: Any, task: SimTask, others: list[SimTask]) -> None:
    """A task that only logs: write what it has acquired and nobody read (at its stop, its
    end, its clearing)."""
    log: TdmsLog | None = task.tdms_log
    if log is None or log.mode != LOG_ONLY or task is not device.ai_task:
        return
    n = device.available(task)
    if n > 0:
        t_first = device.t0 + device.read_pos / task.rate_hz  # the first sample not read
        log.mode = LOG_AND_READ  # this read is the board's own
        try:
            write(device, task, device.read(task, n, 0.0, others), t_first)
        finally:
            log.mode = LOG_ONLY


class LoggingRpcs(ServicerParts):
    """ConfigureLogging."""

    @reports_daq_errors
    def ConfigureLogging(self, request, context):  # noqa: N802
        task = self._task(request.task)
        where = f"ConfigureLogging on task {task.name!r}"
        mode = request.logging_mode_raw
        if mode == LOG_OFF:
            task.tdms_log = None
            return pb.ConfigureLoggingResponse(status=0)
        if mode not in (LOG_ONLY, LOG_AND_READ) or request.operation_raw not in (
                OPEN, OPEN_OR_CREATE, CREATE_OR_REPLACE, CREATE):
            raise daq_error(INVALID_ATTRIBUTE_VALUE, f"{where}: logging mode {mode} or "
                            f"operation {request.operation_raw} is not a valid value")
        if task.kind in ("ao", "do", "co"):
            raise daq_error(LOGGING_NOT_SUPPORT_ON_OUTPUT_TASKS,
                            f"{where}: output tasks do not log")
        if task.kind != "ai" or task.rate_hz is None:
            raise daq_error(LOGGING_MODE_NOT_SUPPORTED_NON_BUFFERED,
                            f"{where}: only a buffered (sample-clocked) AI task logs on the "
                            "simulated board")
        path = Path(request.file_path).expanduser()
        if not request.file_path or path.suffix.lower() != ".tdms" \
                or not path.resolve().parent.is_dir():
            raise daq_error(FILE_PATH_INVALID, f"{where}: {request.file_path!r} is not a .tdms "
                            "file in an existing directory on the server")
        task.tdms_log = TdmsLog(path.resolve(), mode, request.group_name or task.name,
                                request.operation_raw)
        return pb.ConfigureLoggingResponse(status=0)
