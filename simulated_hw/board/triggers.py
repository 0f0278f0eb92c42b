"""Triggers and clocks on the board's external lines (the PXIe-6358's PFI0..15, the chassis'
PXI_Trig0..7 and PXI_Star): accepted as the board accepts them, and, since nothing on the rig
drives those lines, a task armed on one waits for ever.

A 6358 routes any of these to a start or reference trigger, or to a task's sample clock. On this
rig they are unwired, so such a task is armed and never triggered or clocked: it acquires and
generates nothing, its events never fire, a read waits its timeout and ends in DAQmx -200284
(reading what is available of a continuous task returns nothing), and ``wait_until_done`` of a
finite one -200560. Sources the board drives itself (``/Dev1/ai/StartTrigger``,
``/Dev1/ai/SampleClock``) are served by the device's own timing, not here.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb

from daq.errors import ATTR_NOT_SUPPORTED_IN_TASK, INVALID_ATTRIBUTE_VALUE, READ_TIMEOUT, DaqError
from simulated_hw.board.codes import INVALID_ROUTING_SOURCE, daq_error
from simulated_hw.board.device_rpcs import _unsupported
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimTask
from simulated_hw.board.wire import reports_daq_errors

#: the external lines of a PXIe-6358 in a PXIe chassis (terminal names as DAQmx spells them)
_EXTERNAL = re.compile(r"/?(?P<dev>[^/]+)/(PFI(?:[0-9]|1[0-5])|PXI_Trig[0-7]|PXI_Star)",
                       re.IGNORECASE)

#: DAQmx's text for a read that timed out (the board appends the read's properties)
TIMEOUT_TEXT = ("Some or all of the samples requested have not yet been acquired. To wait for the "
                "samples to become available use a longer read timeout or read later in your "
                "program. If your task uses a start trigger, make sure that your start trigger "
                "is configured correctly. It is also possible that you configured the task for "
                "external timing, and no clock was supplied.")


def external_line(device: Any, source: str) -> bool:
    """Whether ``source`` is one of the board's external lines (``/Dev1/PFI0``, ``Dev1/PFI8``)."""
    found = _EXTERNAL.fullmatch(source.strip())
    return found is not None and found["dev"].lower() == device.spec.name.lower()


def check_external(device: Any, source: str, where: str, role: str) -> str:
    """``source`` as the board names it, if it is an external line; else DAQmx -200040."""
    if not external_line(device, source):
        raise daq_error(
            INVALID_ROUTING_SOURCE,
            f"{where}: {role} source {source!r} is not available on the simulated "
            f"{device.spec.name} (a PFI line /{device.spec.name}/PFI0..15, PXI_Trig0..7, "
            f"PXI_Star, or the board's own {device.terminal('StartTrigger')} / "
            f"{device.terminal('SampleClock')})")
    return "/" + source.strip().lstrip("/")


def waits_on_external(task: SimTask) -> bool:
    """Whether the task is triggered or clocked from a line nothing on the rig drives."""
    return bool(task.external)


def source_of(task: SimTask) -> str:
    """What the task waits on, e.g. "/Dev1/PFI0 (start trigger)"."""
    return ", ".join(f"{line} ({role})" for role, line in task.external.items())


def arm(task: SimTask) -> None:
    """Start a task that waits on an external line: running, but nothing happens."""
    task.error = None
    task.done = False
    task.running = True
    task.run_id += 1


def wait_out(device: Any, task: SimTask, timeout_s: float) -> None:
    """Wait a read's ``timeout_s`` on the device clock (-1: until the task stops) for what
    never comes."""
    if device.fast:
        return  # nothing paces a fast board: its timeout passes at once
    if timeout_s >= 0:
        device.sleep(timeout_s)
        return
    while task.running and not device.stopping():
        device.pause(0.05)


def read_times_out(device: Any, task: SimTask, n: int, timeout_s: float) -> np.ndarray:
    """A read of a task armed on an external line: no samples, or what is available of a
    continuous task (nothing) at once; else the wait of ``timeout_s`` (-1: until the task
    stops) and DAQmx -200284."""
    n_ch = max(len(task.channels), 1)
    if n == 0 or (n < 0 and not task.finite):
        return np.zeros((n_ch, 0))
    wait_out(device, task, timeout_s)
    raise samples_not_acquired(task, n, timeout_s,
                               f"it waits on {source_of(task)}, which nothing on the rig drives")


def samples_not_acquired(task: SimTask, n: int, timeout_s: float, why: str) -> DaqError:
    """DAQmx -200284 for a read of ``n`` samples (-1: the finite task's all) that got none."""
    wanted = task.samps_per_chan if n < 0 else n
    return daq_error(
        READ_TIMEOUT,
        f"{TIMEOUT_TEXT}\nTask {task.name!r}: 0 of {wanted} samples acquired after "
        f"{'no limit' if timeout_s < 0 else f'{timeout_s:g} s'}: {why}.",
        samps_per_chan_read=0)


ATTR_START_TRIG_RETRIGGERABLE = 0x190F  # start_trigger.retriggerable
#: triggers.sync_type: a device's role in trigger skew correction across PXIe devices. One
#: board has no skew to correct: the value is kept and read back, and changes no timing.
ATTR_TRIG_SYNC_TYPE = 0x2F80
SYNC_TYPES = {10230: "None", 15888: "Master", 15889: "Slave"}


class TriggerRpcs(ServicerParts):
    """The trigger RPCs beyond the start trigger's (which the servicer serves): reference
    triggers, disabling triggers, retriggering."""

    @reports_daq_errors
    def CfgDigEdgeRefTrig(self, request, context):  # noqa: N802
        task = self._task(request.task)
        where = f"CfgDigEdgeRefTrig on task {task.name!r}"
        if task.kind not in ("ai", "di"):
            raise daq_error(ATTR_NOT_SUPPORTED_IN_TASK,
                            f"{where}: a reference trigger needs an AI or DI task "
                            f"(the task has {task.kind or 'no channels'})")
        task.external["reference trigger"] = check_external(
            self.device, request.trigger_source, where, "reference trigger")
        return pb.CfgDigEdgeRefTrigResponse(status=0)

    @reports_daq_errors
    def DisableStartTrig(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.trigger_source = ""
        task.external.pop("start trigger", None)
        return pb.DisableStartTrigResponse(status=0)

    @reports_daq_errors
    def DisableRefTrig(self, request, context):  # noqa: N802
        self._task(request.task).external.pop("reference trigger", None)
        return pb.DisableRefTrigResponse(status=0)

    @reports_daq_errors
    def SetTrigAttributeBool(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_START_TRIG_RETRIGGERABLE:
            raise _unsupported("trigger", request.attribute_raw)
        task.retriggerable = bool(request.value)
        return pb.SetTrigAttributeBoolResponse(status=0)

    @reports_daq_errors
    def GetTrigAttributeBool(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_START_TRIG_RETRIGGERABLE:
            raise _unsupported("trigger", request.attribute_raw)
        return pb.GetTrigAttributeBoolResponse(value=task.retriggerable)

    @reports_daq_errors
    def SetTrigAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_TRIG_SYNC_TYPE:
            raise _unsupported("trigger", request.attribute_raw)
        if request.value_raw not in SYNC_TYPES:
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"sync_type on task {task.name!r}: {request.value_raw} is not one of "
                            f"{', '.join(f'{v} ({n})' for v, n in SYNC_TYPES.items())}")
        task.sync_type = int(request.value_raw)
        return pb.SetTrigAttributeInt32Response(status=0)

    @reports_daq_errors
    def GetTrigAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_TRIG_SYNC_TYPE:
            raise _unsupported("trigger", request.attribute_raw)
        return pb.GetTrigAttributeInt32Response(value_raw=task.sync_type)

    @reports_daq_errors
    def ResetTrigAttribute(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_TRIG_SYNC_TYPE:
            task.sync_type = 10230
        elif request.attribute_raw == ATTR_START_TRIG_RETRIGGERABLE:
            task.retriggerable = False
        else:
            raise _unsupported("trigger", request.attribute_raw)
        return pb.ResetTrigAttributeResponse(status=0)
