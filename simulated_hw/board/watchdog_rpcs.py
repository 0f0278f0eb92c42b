"""The watchdog timer task's RPCs (nidaqmx ``system.WatchdogTask``), mixed into the servicer."""

from __future__ import annotations

import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx.utils import unflatten_channel_string
from session_pb2 import Session

from daq.errors import ATTR_NOT_SUPPORTED, INVALID_ATTRIBUTE_VALUE, WATCHDOG_TIMER_NOT_SUPPORTED
from simulated_hw.board.codes import (
    ACTION_NOT_SUPPORTED_TASK_NOT_WATCHDOG,
    ATTR_WDT_EXPIRED,
    ATTR_WDT_TIMEOUT,
    DEVICE_NOT_FOUND,
    LEVEL_HIGH,
    LEVEL_LOW,
    NO_CHANGE,
    WATCHDOG_TIMEOUT_OUT_OF_RANGE,
    WDT_AO_VOLTAGE,
    WDT_CLEAR_EXPIRATION,
    WDT_RESET_TIMER,
    daq_error,
)
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimTask
from simulated_hw.board.watchdog import Watchdog
from simulated_hw.board.wire import reports_daq_errors


class WatchdogRpcs(ServicerParts):
    """CreateWatchdogTimerTaskEx, the expiration states, ControlWatchdogTask and the watchdog
    attributes."""

    def _watchdog(self, session: Session) -> tuple[SimTask, Watchdog]:
        task = self._task(session)
        if task.watchdog is None:
            raise daq_error(ACTION_NOT_SUPPORTED_TASK_NOT_WATCHDOG,
                            f"task {task.name!r} is not a watchdog timer task")
        return task, task.watchdog

    @reports_daq_errors
    def CreateWatchdogTimerTaskEx(self, request, context):  # noqa: N802
        spec = self.device.spec
        if request.device_name.lower() != spec.name.lower():
            raise daq_error(DEVICE_NOT_FOUND,
                            f"watchdog: device {request.device_name!r} does not exist (this "
                            f"server has {spec.name})")
        timeout = request.timeout
        if timeout != -1 and not 0 < timeout <= 429.0:  # the X-series timer's range
            raise daq_error(WATCHDOG_TIMEOUT_OUT_OF_RANGE,
                            f"watchdog timeout {timeout:g} s is out of range (0 < timeout <= "
                            "429 s, or -1 for never)")
        watchdog = Watchdog(spec.name, timeout)
        task, new = self._create(request.session_name, request.initialization_behavior,
                                 watchdog)
        return pb.CreateWatchdogTimerTaskExResponse(task=Session(name=task.name),
                                                    new_session_initialized=new)

    @reports_daq_errors
    def CfgWatchdogAOExpirStates(self, request, context):  # noqa: N802
        task, w = self._watchdog(request.task)
        if not self.device.spec.ao_watchdog:
            raise daq_error(WATCHDOG_TIMER_NOT_SUPPORTED,
                            f"the {self.device.spec.product} has no analog-output watchdog "
                            "expiration states")
        where = f"CfgWatchdogAOExpirStates on {task.name!r}"
        physical = self.device.physical(request.channel_names, "ao", where)
        states = np.asarray(request.expir_state_array, dtype=float)
        types = list(request.output_type_array)
        if len(states) != len(physical) or len(types) != len(physical):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"{where}: {len(physical)} channels but {len(states)} states and "
                            f"{len(types)} output types")
        limit = self.device.spec.ao_range_v
        for p, v, kind in zip(physical, states, types, strict=True):
            if kind == NO_CHANGE:
                w.ao_states.pop(p, None)
            elif kind != WDT_AO_VOLTAGE or not -limit <= v <= limit:
                raise daq_error(INVALID_ATTRIBUTE_VALUE,
                                f"{where}: {p}: expiration state {v:g} (type {kind}) must be "
                                f"a voltage within +/-{limit:g} V")
            else:
                w.ao_states[p] = float(v)
        return pb.CfgWatchdogAOExpirStatesResponse(status=0)

    @reports_daq_errors
    def CfgWatchdogDOExpirStates(self, request, context):  # noqa: N802
        task, w = self._watchdog(request.task)
        where = f"CfgWatchdogDOExpirStates on {task.name!r}"
        physical = [p for name in unflatten_channel_string(request.channel_names)
                    for p in self.device.physical(name, "do", where)]
        states = list(request.expir_state_array)
        if len(states) == 1 and len(physical) > 1:  # one state for a whole port or range
            states *= len(physical)
        if len(states) != len(physical):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"{where}: {len(physical)} lines but {len(states)} states")
        for p, level in zip(physical, states, strict=True):
            if level == NO_CHANGE:
                w.do_states.pop(p, None)
            elif level in (LEVEL_HIGH, LEVEL_LOW):
                w.do_states[p] = level == LEVEL_HIGH
            else:
                raise daq_error(INVALID_ATTRIBUTE_VALUE,
                                f"{where}: {p}: expiration state {level} is not supported "
                                "(high, low or no change)")
        return pb.CfgWatchdogDOExpirStatesResponse(status=0)

    @reports_daq_errors
    def ControlWatchdogTask(self, request, context):  # noqa: N802
        task, _ = self._watchdog(request.task)
        if request.action_raw == WDT_RESET_TIMER:
            self.device.feed_watchdog(task)
        elif request.action_raw == WDT_CLEAR_EXPIRATION:
            self.device.clear_expiration(task)
        else:
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"watchdog action {request.action_raw} is not valid")
        return pb.ControlWatchdogTaskResponse(status=0)

    @reports_daq_errors
    def GetWatchdogAttributeBool(self, request, context):  # noqa: N802
        _, w = self._watchdog(request.task)
        if request.attribute_raw != ATTR_WDT_EXPIRED:
            raise _unsupported(request.attribute_raw)
        with self.device.lock:
            self.device.watchdog_timer.check()
            return pb.GetWatchdogAttributeBoolResponse(value=w.expired)

    @reports_daq_errors
    def GetWatchdogAttributeDouble(self, request, context):  # noqa: N802
        _, w = self._watchdog(request.task)
        if request.attribute_raw != ATTR_WDT_TIMEOUT:
            raise _unsupported(request.attribute_raw)
        return pb.GetWatchdogAttributeDoubleResponse(value=w.timeout_s)


def _unsupported(attribute: int) -> Exception:
    return daq_error(ATTR_NOT_SUPPORTED, f"watchdog attribute 0x{attribute:04X} is not "
                     "supported by the simulated device")
