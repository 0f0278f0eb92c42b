"""`SimulatedDaqmxServicer`: the NI-DAQmx gRPC service on a `SimDevice`, and NI's wire format
for errors and fast reads."""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Callable
from typing import Any

import grpc
import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx._stubs import nidaqmx_pb2_grpc as pb_grpc
from nidaqmx.utils import unflatten_channel_string
from session_pb2 import Session

from daq.errors import (
    ATTR_NOT_SUPPORTED,
    ATTR_NOT_SUPPORTED_IN_TASK,
    DEVICE_NOT_FOUND,
    INVALID_ATTRIBUTE_VALUE,
    DaqError,
)
from simulated_hw.board import (
    counters,
    events,
    tdms_logging,
    thermocouple,
    triggers,
    waveforms,
)
from simulated_hw.board.chan_attrs import ATTR_TASK_DEVICES, ChannelAttrRpcs, task_devices
from simulated_hw.board.codes import (
    _ERROR_TEXT,
    AO_FIFO_SAMPLES,
    ATTR_AI_MEAS_TYPE,
    ATTR_AO_IDLE_OUTPUT,
    ATTR_AO_OUTPUT_TYPE,
    ATTR_CHAN_TYPE,
    ATTR_DI_BOOLS_PER_CHAN,
    ATTR_DO_BOOLS_PER_CHAN,
    ATTR_DRIVER_MAJOR,
    ATTR_DRIVER_MINOR,
    ATTR_DRIVER_UPDATE,
    ATTR_INCONSISTENT,
    ATTR_INPUT_BUF_SIZE,
    ATTR_OUTPUT_BUF_SIZE,
    ATTR_OUTPUT_ONBRD_BUF_SIZE,
    ATTR_READ_AVAIL,
    ATTR_READ_CHANNELS,
    ATTR_READ_DEFAULT_N,
    ATTR_READ_NUM_CHANS,
    ATTR_READ_POS,
    ATTR_SAMP_CLK_RATE,
    ATTR_SAMP_QUANT_MODE,
    ATTR_SAMP_QUANT_N,
    ATTR_SYS_DEVICES,
    ATTR_TASK_CHANNELS,
    ATTR_TASK_NAME,
    ATTR_TASK_NUM_CHANS,
    ATTR_WRITE_GENERATED,
    ATTR_WRITE_NUM_CHANS,
    ATTR_WRITE_OFFSET,
    ATTR_WRITE_REGEN,
    ATTR_WRITE_REL_TO,
    ATTR_WRITE_SPACE,
    CHAN_AI,
    CHAN_AO,
    CHAN_DI,
    CHAN_DO,
    DRIVER_VERSION,
    DUPLICATE_TASK,
    FILL_GROUP_BY_CHANNEL,
    IDLE_MAINTAIN,
    IDLE_ZERO_VOLTS,
    INIT_ATTACH,
    INIT_NEW,
    INVALID_TASK,
    LINES_PER_CHAN_ALL,
    MEAS_VOLTAGE,
    MODE_CONTINUOUS,
    MODE_FINITE,
    NO_CHANS_IN_TASK,
    PHYSICAL_CHAN_DOES_NOT_EXIST,
    READ_BUFFER_TOO_SMALL,
    REGEN_ALLOW,
    REGEN_DONT_ALLOW,
    REPEATED_PHYSICAL_CHAN,
    TERM_DEFAULT,
    WRITE_NUM_CHANS_MISMATCH,
    WRITE_REL_CURR_POS,
    WRITE_REL_FIRST_SAMPLE,
    daq_error,
    terminal_config_error,
)
from simulated_hw.board.device import SimDevice
from simulated_hw.board.device_rpcs import DeviceRpcs, _unsupported, attribute
from simulated_hw.board.digital import DigitalRpcs
from simulated_hw.board.refusals import install_refusals
from simulated_hw.board.tasks import SimChannel, SimTask
from simulated_hw.board.watchdog import Watchdog
from simulated_hw.board.watchdog_rpcs import WatchdogRpcs
from simulated_hw.board.wire import abort_with, read_reply, reports_daq_errors


# --- the servicer ---------------------------------------------------------------------------
def _chan_handler(kind: str, channel_field: str, name_field: str) -> Callable[..., Any]:
    """One handler for the whole Create*Chan family: the request names the physical channel(s),
    the virtual name and (for analog channels) the range in volts."""

    @reports_daq_errors
    def handler(self: SimulatedDaqmxServicer, request: Any, context: grpc.ServicerContext) -> Any:
        task = self._task(request.task)
        rpc = type(request).__name__.removesuffix("Request")
        where = f"{rpc} on task {task.name!r}"
        if task.running:
            raise daq_error(ATTR_NOT_SUPPORTED, f"{where}: cannot add channels to a running task")
        if task.kind not in (None, kind):
            raise daq_error(
                ATTR_NOT_SUPPORTED,
                f"{where}: task already has {task.kind.upper()} channels; use one task per type",
            )
        physical = self.device.physical(getattr(request, channel_field), kind, where)
        used = {p for c in task.channels for p in c.physical}
        repeated = sorted(used & set(physical))
        if repeated:
            raise daq_error(REPEATED_PHYSICAL_CHAN, f"{where}: {repeated} already in this task")
        name = getattr(request, name_field)
        if kind in ("do", "di") and request.line_grouping_raw == LINES_PER_CHAN_ALL:
            groups = [physical]
        else:
            groups = [[p] for p in physical]
        if name and len(groups) > 1:
            names = [f"{name}{i}" for i in range(len(groups))]
        elif name:
            names = [name]
        elif len(groups) == 1 and len(groups[0]) > 1:  # DAQmx's name for a group of lines
            given = unflatten_channel_string(getattr(request, channel_field))
            names = [given[0] + "..." if len(given) > 1 else given[0]]
        else:
            names = [g[0] for g in groups]
        digital = kind in ("do", "di")
        lo, hi = (request.min_val, request.max_val) if not digital else (0.0, 1.0)
        units = None
        if rpc == "CreateAIThrmcplChan":  # measured on the +/-1 V range, read in temperature
            units = thermocouple.units(request, where)
            lo, hi = -1.0, 1.0
        if not digital:
            limit = self.device.spec.ai_range_v if kind == "ai" else self.device.spec.ao_range_v
            if not (-limit <= lo < hi <= limit):
                raise daq_error(
                    INVALID_ATTRIBUTE_VALUE,
                    f"{where}: range [{lo:g}, {hi:g}] V for {physical} is not within the "
                    f"device's +/-{limit:g} V (or min >= max)",
                )
        if kind == "ai":
            _check_terminal_config(request, physical, where)
        for n, g in zip(names, groups, strict=True):
            task.channels.append(SimChannel(n, kind, g, lo, hi, temperature_units=units))
        return type(self)._responses[rpc](status=0)

    return handler


def _check_terminal_config(request: Any, physical: list[str], where: str) -> None:
    """An AI channel's terminal configuration must be one the device's channels allow."""
    cfg = getattr(request, "terminal_config_raw", TERM_DEFAULT)
    if err := terminal_config_error(cfg, physical, where):
        raise err


# Which Create*Chan RPCs the simulated device serves: rpc -> (kind, channel field, name field).
CREATE_CHAN_RPCS: dict[str, tuple[str, str, str]] = {
    "CreateAIVoltageChan": ("ai", "physical_channel", "name_to_assign_to_channel"),
    "CreateAIThrmcplChan": ("ai", "physical_channel", "name_to_assign_to_channel"),
    "CreateAOVoltageChan": ("ao", "physical_channel", "name_to_assign_to_channel"),
    "CreateDOChan": ("do", "lines", "name_to_assign_to_lines"),
    "CreateDIChan": ("di", "lines", "name_to_assign_to_lines"),
}


class SimulatedDaqmxServicer(counters.CounterRpcs, WatchdogRpcs, DeviceRpcs, DigitalRpcs,
                             ChannelAttrRpcs, triggers.TriggerRpcs, waveforms.WaveformRpcs,
                             tdms_logging.LoggingRpcs, pb_grpc.NiDAQmxServicer):
    """The NI-DAQmx gRPC service on a `SimDevice`. RPCs not defined here answer the DAQmx
    error the board gives for them (`simulated_hw.board.refusals`), never UNIMPLEMENTED."""

    _responses = {rpc: getattr(pb, f"{rpc}Response") for rpc in CREATE_CHAN_RPCS}

    def __init__(self, device: SimDevice) -> None:
        self.device = device
        self.tasks: dict[str, SimTask] = {}
        self._unnamed = itertools.count()
        self._tasks_lock = threading.Lock()
        self.ref_clock: dict[str, tuple[str, float]] = {}  # task -> reference clock, rate

    def _channels(self, task: SimTask, names: str) -> list[SimChannel]:
        return _find_channels(task, names)

    # --- helpers --------------------------------------------------------------------------
    def _task(self, session: Session) -> SimTask:
        task = self.tasks.get(session.name)
        if task is None:
            raise daq_error(INVALID_TASK, f"task {session.name!r} does not exist on this server")
        return task

    def _others(self) -> list[SimTask]:
        return list(self.tasks.values())

    def reset(self) -> None:
        """Stop and clear every task; relays off (as ResetDevice does)."""
        with self._tasks_lock:
            for task in list(self.tasks.values()):
                self.device.stop(task)
                if task.watchdog is not None:
                    self.device.remove_watchdog(task.watchdog)
            self.tasks.clear()
        with self.device.lock:
            self.device.lines.clear()
            self.device.ao_hold.clear()
            self.device.locked_ao.clear()
            self.device.locked_do.clear()

    # --- session and version --------------------------------------------------------------
    @reports_daq_errors
    def GetSystemInfoAttributeUInt32(self, request, context):  # noqa: N802
        versions = dict(zip((ATTR_DRIVER_MAJOR, ATTR_DRIVER_MINOR, ATTR_DRIVER_UPDATE),
                            DRIVER_VERSION, strict=True))
        return pb.GetSystemInfoAttributeUInt32Response(
            value=attribute(versions, "system", request.attribute_raw))

    @reports_daq_errors
    def GetSystemInfoAttributeString(self, request, context):  # noqa: N802
        return pb.GetSystemInfoAttributeStringResponse(value=attribute(
            {ATTR_SYS_DEVICES: self.device.spec.name}, "system", request.attribute_raw))

    @reports_daq_errors
    def CreateTask(self, request, context):  # noqa: N802
        task, new = self._create(request.session_name, request.initialization_behavior)
        return pb.CreateTaskResponse(task=Session(name=task.name), new_session_initialized=new)

    def _create(self, name: str, behaviour: int, watchdog: Watchdog | None = None
                ) -> tuple[SimTask, bool]:
        """(the task, whether it is new) for a Create* RPC's name and initialisation."""
        with self._tasks_lock:
            name = name or f"_unnamedTask<{next(self._unnamed)}>"
            existing = self.tasks.get(name)
            if existing is not None:
                if behaviour == INIT_NEW:
                    raise daq_error(DUPLICATE_TASK, f"task {name!r} already exists")
                return existing, False
            if behaviour == INIT_ATTACH:
                raise daq_error(INVALID_TASK, f"no task {name!r} to attach to")
            task = self.tasks[name] = SimTask(name, watchdog=watchdog)
        if watchdog is not None:
            self.device.add_watchdog(watchdog)
        return task, True

    @reports_daq_errors
    def ClearTask(self, request, context):  # noqa: N802
        with self._tasks_lock:
            task = self.tasks.pop(request.task.name, None)
        if task is None:
            raise daq_error(INVALID_TASK, f"task {request.task.name!r} does not exist")
        tdms_logging.flush(self.device, task, self._others())
        self.device.stop(task)
        if task.watchdog is not None:
            self.device.remove_watchdog(task.watchdog)
        return pb.ClearTaskResponse(status=0)

    @reports_daq_errors
    def StartTask(self, request, context):  # noqa: N802
        self.device.start(self._task(request.task), self._others())
        return pb.StartTaskResponse(status=0)

    @reports_daq_errors
    def TaskControl(self, request, context):  # noqa: N802
        """start, stop, abort, verify, commit / reserve, unreserve (DAQmxTaskControl)."""
        task = self._task(request.task)
        action = request.action_raw or request.action
        if action == 0:  # start
            self.device.start(task, self._others())
        elif action in (1, 6):  # stop; abort (no logging flush: the acquisition is dropped)
            if action == 1:
                tdms_logging.flush(self.device, task, self._others())
            self.device.stop(task)
        elif action == 2:  # verify
            if task.kind is None:
                raise daq_error(NO_CHANS_IN_TASK,
                                f"verify {task.name!r}: the task has no channels")
        elif action in (3, 4):  # commit, reserve
            self.device.reserve(task, self._others())
        elif action == 5:  # unreserve: a running task is aborted first
            self.device.stop(task)
            task.reserved = False
        else:
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"TaskControl on {task.name!r}: action {action} is not one of "
                            "0 (start) .. 6 (abort)")
        return pb.TaskControlResponse(status=0)

    @reports_daq_errors
    def StopTask(self, request, context):  # noqa: N802
        task = self._task(request.task)
        tdms_logging.flush(self.device, task, self._others())
        self.device.stop(task)
        return pb.StopTaskResponse(status=0)

    @reports_daq_errors
    def ResetDevice(self, request, context):  # noqa: N802
        if request.device_name.lower() != self.device.spec.name.lower():
            raise daq_error(DEVICE_NOT_FOUND, f"reset: no device {request.device_name!r}")
        self.reset()
        return pb.ResetDeviceResponse(status=0)

    @reports_daq_errors
    def GetErrorString(self, request, context):  # noqa: N802
        text = _ERROR_TEXT.get(request.error_code, f"NI-DAQmx status {request.error_code}")
        return pb.GetErrorStringResponse(error_string=text)

    # --- timing and triggers --------------------------------------------------------------
    @reports_daq_errors
    def CfgSampClkTiming(self, request, context):  # noqa: N802
        task = self._task(request.task)
        where = f"CfgSampClkTiming on task {task.name!r}"
        self.device.check_rate(request.rate, where)
        source = request.source
        clock = self.device.terminal("SampleClock").lower()
        task.external.pop("sample clock", None)
        if source and source.lower() not in ("onboardclock", clock):
            task.external["sample clock"] = triggers.check_external(
                self.device, source, where, "sample clock")
        if request.sample_mode_raw not in (MODE_CONTINUOUS, MODE_FINITE):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"{where}: sample mode {request.sample_mode_raw} not supported")
        task.rate_hz = coerced_rate(request.rate)
        task.clock_source = "" if source.lower() == "onboardclock" else source
        task.sample_mode = request.sample_mode_raw
        task.samps_per_chan = int(request.samps_per_chan)
        return pb.CfgSampClkTimingResponse(status=0)

    @reports_daq_errors
    def CfgDigEdgeStartTrig(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.external.pop("start trigger", None)
        if request.trigger_source.lower() != self.device.terminal("StartTrigger").lower():
            task.external["start trigger"] = triggers.check_external(
                self.device, request.trigger_source, f"CfgDigEdgeStartTrig on task "
                f"{task.name!r}", "start trigger")
            task.trigger_source = ""  # not the AI start trigger any more
            return pb.CfgDigEdgeStartTrigResponse(status=0)
        task.trigger_source = request.trigger_source
        return pb.CfgDigEdgeStartTrigResponse(status=0)

    @reports_daq_errors
    def CfgInputBuffer(self, request, context):  # noqa: N802
        self._task(request.task).buffer_samples = int(request.num_samps_per_chan)
        return pb.CfgInputBufferResponse(status=0)

    @reports_daq_errors
    def CfgOutputBuffer(self, request, context):  # noqa: N802
        self._task(request.task).buffer_samples = int(request.num_samps_per_chan)
        return pb.CfgOutputBufferResponse(status=0)

    # --- attributes -----------------------------------------------------------------------
    @reports_daq_errors
    def GetTaskAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_TASK_NAME:
            return pb.GetTaskAttributeStringResponse(value=task.name)
        if request.attribute_raw == ATTR_TASK_CHANNELS:
            return pb.GetTaskAttributeStringResponse(value=_channel_list(task))
        if request.attribute_raw == ATTR_TASK_DEVICES:
            return pb.GetTaskAttributeStringResponse(value=task_devices(self.device, task))
        raise _unsupported("task", request.attribute_raw)

    @reports_daq_errors
    def GetTaskAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_TASK_NUM_CHANS:
            raise _unsupported("task", request.attribute_raw)
        return pb.GetTaskAttributeUInt32Response(value=len(task.channels))

    @reports_daq_errors
    def GetChanAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        types = {"ai": CHAN_AI, "ao": CHAN_AO, "do": CHAN_DO, "di": CHAN_DI}
        attr = request.attribute_raw
        values = set()
        for ch in _find_channels(task, request.channel):
            counter_value = counters.chan_int32(ch, attr)
            if counter_value is not None:
                values.add(counter_value)
            elif attr == ATTR_CHAN_TYPE:
                values.add(types[ch.kind])
            elif attr == ATTR_AO_IDLE_OUTPUT and ch.kind == "ao":
                self._idle_output_supported(task)
                values.add(ch.idle_behavior)
            elif (attr == ATTR_AI_MEAS_TYPE and ch.kind == "ai") or (
                    attr == ATTR_AO_OUTPUT_TYPE and ch.kind == "ao"):
                values.add(MEAS_VOLTAGE)
            else:
                raise _unsupported("channel", attr)
        if len(values) != 1:
            raise daq_error(ATTR_INCONSISTENT,
                            f"channel attribute 0x{attr:04X} differs across {request.channel!r}")
        return pb.GetChanAttributeInt32Response(value_raw=values.pop())

    @reports_daq_errors
    def SetChanAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_AO_IDLE_OUTPUT:
            raise _unsupported("channel", request.attribute_raw)
        self._idle_output_supported(task)
        if request.value_raw not in (IDLE_ZERO_VOLTS, IDLE_MAINTAIN):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"ao_idle_output_behavior {request.value_raw} is not supported by "
                            f"{self.device.spec.product} (0 V or maintain existing value)")
        for ch in _find_channels(task, request.channel):
            if ch.kind != "ao":
                raise _unsupported("channel", request.attribute_raw)
            ch.idle_behavior = request.value_raw
        return pb.SetChanAttributeInt32Response(status=0)

    def _idle_output_supported(self, task: SimTask) -> None:
        if not self.device.spec.ao_idle_output_zero:
            raise daq_error(
                ATTR_NOT_SUPPORTED_IN_TASK,
                f"task {task.name!r}: ao_idle_output_behavior is not supported by the "
                f"{self.device.spec.product}",
            )

    @reports_daq_errors
    def GetReadAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_READ_CHANNELS:
            raise _unsupported("read", request.attribute_raw)
        return pb.GetReadAttributeStringResponse(value=_channel_list(task))

    @reports_daq_errors
    def GetReadAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_READ_NUM_CHANS:
            value = len(task.channels)
        elif request.attribute_raw == ATTR_READ_AVAIL:
            value = self.device.available(task)
        elif request.attribute_raw == ATTR_DI_BOOLS_PER_CHAN:
            value = max((len(c.physical) for c in task.channels), default=0)
        elif request.attribute_raw == ATTR_READ_DEFAULT_N:  # what READ_ALL_AVAILABLE reads
            value = (task.samps_per_chan - self.device.read_pos
                     if task.finite and task is self.device.ai_task
                     else task.samps_per_chan if task.finite
                     else self.device.available(task)
                     if task.rate_hz is not None or counters.buffered(task) else 1)
        else:
            raise _unsupported("read", request.attribute_raw)
        return pb.GetReadAttributeUInt32Response(value=value)

    @reports_daq_errors
    def GetReadAttributeUInt64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_READ_POS:
            raise _unsupported("read", request.attribute_raw)
        with self.device.lock:
            value = self.device.read_pos if task is self.device.ai_task else 0
        return pb.GetReadAttributeUInt64Response(value=value)

    @reports_daq_errors
    def GetWriteAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        attr = request.attribute_raw
        if attr == ATTR_WRITE_NUM_CHANS:
            value = len(task.channels)
        elif attr == ATTR_DO_BOOLS_PER_CHAN:
            value = max((len(c.physical) for c in task.channels), default=0)
        elif attr == ATTR_WRITE_SPACE:
            self.device.catch_up()
            value = max(task.output_buffer() - task.ao.queued, 0)
        else:
            raise _unsupported("write", attr)
        return pb.GetWriteAttributeUInt32Response(value=value)

    @reports_daq_errors
    def GetWriteAttributeUInt64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_WRITE_GENERATED:
            raise _unsupported("write", request.attribute_raw)
        return pb.GetWriteAttributeUInt64Response(value=self.device.generated_by(task))

    @reports_daq_errors
    def GetWriteAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        attr = request.attribute_raw
        if attr == ATTR_WRITE_REGEN:
            value = task.regen_mode
        elif attr == ATTR_WRITE_REL_TO and task.kind == "ao":
            value = task.write_relative_to
        elif attr == ATTR_WRITE_OFFSET and task.kind == "ao":
            value = task.write_offset
        else:
            raise _unsupported("write", attr)
        return pb.GetWriteAttributeInt32Response(value_raw=value)

    @reports_daq_errors
    def SetWriteAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        attr, value = request.attribute_raw, request.value_raw
        if attr == ATTR_WRITE_REGEN:
            if value not in (REGEN_ALLOW, REGEN_DONT_ALLOW):
                raise daq_error(INVALID_ATTRIBUTE_VALUE,
                                f"regeneration mode {value} is not a valid value")
            task.regen_mode = value
        elif attr == ATTR_WRITE_REL_TO and task.kind == "ao":
            if value not in (WRITE_REL_FIRST_SAMPLE, WRITE_REL_CURR_POS):
                raise daq_error(INVALID_ATTRIBUTE_VALUE,
                                f"write relative-to {value} is not a valid value")
            task.write_relative_to = value
        elif attr == ATTR_WRITE_OFFSET and task.kind == "ao":
            task.write_offset = value
        else:
            raise _unsupported("write", attr)
        return pb.SetWriteAttributeInt32Response(status=0)

    @reports_daq_errors
    def GetTimingAttributeDouble(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_SAMP_CLK_RATE or task.rate_hz is None:
            raise _unsupported("timing", request.attribute_raw)
        return pb.GetTimingAttributeDoubleResponse(value=task.rate_hz)

    @reports_daq_errors
    def GetTimingAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_SAMP_QUANT_MODE or task.rate_hz is None:
            raise _unsupported("timing", request.attribute_raw)
        return pb.GetTimingAttributeInt32Response(value_raw=task.sample_mode)

    @reports_daq_errors
    def GetTimingAttributeUInt64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_SAMP_QUANT_N or task.rate_hz is None:
            raise _unsupported("timing", request.attribute_raw)
        return pb.GetTimingAttributeUInt64Response(value=task.samps_per_chan)

    @reports_daq_errors
    def IsTaskDone(self, request, context):  # noqa: N802
        return pb.IsTaskDoneResponse(is_task_done=self.device.is_done(self._task(request.task)))

    @reports_daq_errors
    def WaitUntilTaskDone(self, request, context):  # noqa: N802
        task = self._task(request.task)
        self.device.wait_until_done(task, request.time_to_wait)
        tdms_logging.flush(self.device, task, self._others())
        return pb.WaitUntilTaskDoneResponse(status=0)

    @reports_daq_errors
    def GetBufferAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_INPUT_BUF_SIZE and task.rate_hz is not None:
            value = task.input_buffer()
        elif request.attribute_raw == ATTR_OUTPUT_BUF_SIZE:
            value = task.output_buffer()
        elif request.attribute_raw == ATTR_OUTPUT_ONBRD_BUF_SIZE and task.kind == "ao":
            value = task.onboard_samples or AO_FIFO_SAMPLES // max(len(task.channels), 1)
        else:
            raise _unsupported("buffer", request.attribute_raw)
        return pb.GetBufferAttributeUInt32Response(value=value)

    @reports_daq_errors
    def SetBufferAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_OUTPUT_ONBRD_BUF_SIZE and task.kind == "ao":
            most = AO_FIFO_SAMPLES // max(len(task.channels), 1)
            if not 2 <= request.value <= most:
                raise daq_error(INVALID_ATTRIBUTE_VALUE,
                                f"on-board output buffer of {request.value} samples: the "
                                f"device's FIFO holds 2..{most} per channel for this task")
            task.onboard_samples = int(request.value)
            return pb.SetBufferAttributeUInt32Response(status=0)
        if request.attribute_raw not in (ATTR_INPUT_BUF_SIZE, ATTR_OUTPUT_BUF_SIZE):
            raise _unsupported("buffer", request.attribute_raw)
        task.buffer_samples = int(request.value)
        return pb.SetBufferAttributeUInt32Response(status=0)

    # --- data -----------------------------------------------------------------------------
    @reports_daq_errors
    def ReadAnalogF64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ai")
        n = request.num_samps_per_chan
        n_ch = len(task.channels)
        if n >= 0 and request.array_size_in_samps < n * n_ch:
            raise daq_error(
                READ_BUFFER_TOO_SMALL,
                f"read of {n} samples x {n_ch} channels from {task.name!r}: the client buffer "
                f"holds only {request.array_size_in_samps} samples",
                samps_per_chan_read=0,
            )
        tdms_logging.check_read(task)
        t_first = waveforms.first_sample_time(self.device, task) if task.tdms_log else 0.0
        data = self.device.read(task, n, request.timeout, self._others())
        tdms_logging.write(self.device, task, data, t_first)
        samps = data.shape[1]
        if request.fill_mode_raw != FILL_GROUP_BY_CHANNEL:
            data = data.T
        return read_reply(data, samps)  # bytes: see SimulatedDeviceServer

    @reports_daq_errors
    def WriteAnalogF64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ao")
        n, n_ch = request.num_samps_per_chan, len(task.channels)
        flat = np.asarray(request.write_array, dtype=np.float64)
        if n <= 0 or flat.size != n * n_ch:
            raise daq_error(
                WRITE_NUM_CHANS_MISMATCH,
                f"write to {task.name!r}: {flat.size} values for {n} samples x {n_ch} channels",
            )
        block = (flat.reshape(n_ch, n) if request.data_layout_raw == FILL_GROUP_BY_CHANNEL
                 else flat.reshape(n, n_ch).T)
        written = self.device.write_ao(task, block, request.auto_start, request.timeout,
                                       self._others())
        return pb.WriteAnalogF64Response(samps_per_chan_written=written)

    # --- events ---------------------------------------------------------------------------
    def RegisterEveryNSamplesEvent(self, request, context):  # noqa: N802
        """A server stream: one message every N samples (`simulated_hw.board.events`)."""
        try:
            task = self._task(request.task)
            events.check_every_n(task, request.every_n_samples_event_type_raw,
                                 request.n_samples)
        except DaqError as err:
            abort_with(context, err)
        context.send_initial_metadata(())
        yield from events.every_n_samples(
            self.device, task, request.every_n_samples_event_type_raw, request.n_samples,
            lambda: context.is_active() and self.tasks.get(task.name) is task)

    def RegisterDoneEvent(self, request, context):  # noqa: N802
        try:
            task = self._task(request.task)
        except DaqError as err:
            abort_with(context, err)
        context.send_initial_metadata(())
        yield from events.done(self.device, task,
                               lambda: context.is_active() and self.tasks.get(task.name) is task)


for _rpc, (_kind, _chan_field, _name_field) in CREATE_CHAN_RPCS.items():
    setattr(SimulatedDaqmxServicer, _rpc, _chan_handler(_kind, _chan_field, _name_field))
install_refusals(SimulatedDaqmxServicer)


#: the PXIe-6358's sample clock timebase [Hz]: a rate is this divided by a whole number
TIMEBASE_HZ = 100e6


def coerced_rate(rate_hz: float) -> float:
    """The sample rate the board runs at for ``rate_hz``: the timebase over the largest whole
    divisor that is not slower than the request (96,000 S/s -> 100 MHz / 1,041 =
    96,061.48 S/s); rates that divide it evenly stay as asked."""
    divisor = max(math.floor(TIMEBASE_HZ / rate_hz * (1 + 1e-12)), 1)
    return TIMEBASE_HZ / divisor


def _channel_list(task: SimTask) -> str:
    return ", ".join(c.name for c in task.channels)


def _find_channels(task: SimTask, names: str) -> list[SimChannel]:
    """The task's channels named in a channel string ("a, b", "probe0:2"; "" is all)."""
    if not names:
        return list(task.channels)
    whole = [ch for ch in task.channels if ch.name == names.strip()]
    if whole:  # a channel of several lines is named as given ("Dev1/port0/line0:3")
        return whole
    found = []
    for name in unflatten_channel_string(names):
        for ch in task.channels:
            physical = ch.physical[0].lower() if len(ch.physical) == 1 else None
            if name in (ch.name, physical) or physical == name.lower().removeprefix("/"):
                found.append(ch)
                break
        else:
            raise daq_error(
                PHYSICAL_CHAN_DOES_NOT_EXIST,
                f"task {task.name!r} has no channel {name!r} (has {_channel_list(task)})",
            )
    return found
