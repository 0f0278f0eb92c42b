"""What the simulated board answers to an RPC it does not serve: the DAQmx error a PXIe-6358 (or
the driver) gives for that request, never gRPC UNIMPLEMENTED.

`install_refusals` gives every RPC of the NI-DAQmx service that the servicer does not define a
handler that raises `daq.errors.DaqError` (status UNKNOWN with ``ni-error``, so the client raises
``nidaqmx.errors.DaqError``):

- a ``Create*Chan`` for a channel the device lacks (``Dev1/power``): -200170, as the driver
  says for any physical channel that does not exist; a measurement on an AI channel the
  simulated board does not make (strain, current, RTD, ...): -200431
  (``PHYS_CHAN_MEAS_TYPE``); a counter measurement the simulated counters do not make
  (encoders, velocity, GPS; `simulated_hw.board.counters` serves the rest): -201380
  (``DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION``);
- a ``Get/Set/Reset...Attribute``: -200197 (``ATTRIBUTE_NOT_SUPPORTED_IN_TASK_CONTEXT``);
- signal events: -200982 (``SIGNAL_EVENTS_NOT_SUPPORTED_BY_DEVICE``);
- another kind of trigger (analog, pattern, ...): -200040 with its source;
- anything else: -201380 with the RPC's name.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx._stubs import nidaqmx_pb2_grpc as pb_grpc

from daq.errors import ATTR_NOT_SUPPORTED, DaqError
from simulated_hw.board.codes import (
    DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION,
    INVALID_ROUTING_SOURCE,
    PHYS_CHAN_MEAS_TYPE,
    PHYSICAL_CHAN_DOES_NOT_EXIST,
    SIGNAL_EVENTS_NOT_SUPPORTED,
    daq_error,
)
from simulated_hw.board.wire import reports_daq_errors

_COUNTER = re.compile(r"/?(?P<dev>[^/]+)/ctr(?P<n>\d+)$", re.IGNORECASE)
_COUNTERS = 4  # a PXIe-6358 has ctr0..ctr3


def refusal_for(servicer: Any, rpc: str, request: Any) -> DaqError:
    """The DAQmx error the board gives for ``rpc`` with ``request``."""
    device = servicer.device
    name = device.spec.name
    if rpc.startswith("Create") and "Chan" in rpc:
        where = f"{rpc} on task {getattr(request.task, 'name', '')!r}"
        channel = getattr(request, "counter", "") or getattr(request, "physical_channel", "")
        for part in [p.strip() for p in channel.split(",") if p.strip()]:
            counter = _COUNTER.match(part)
            if counter and counter["dev"].lower() == name.lower() \
                    and int(counter["n"]) < _COUNTERS:
                return daq_error(
                    DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION,
                    f"{where}: {part} is one of the {device.spec.product}'s counters; the "
                    "simulated board's counters count edges, measure frequency, period and "
                    "pulses and generate pulses, but do not simulate encoders, velocity or "
                    "GPS (nothing on the rig is wired to them)")
            if not part.lower().lstrip("/").split("/", 1)[-1].startswith("ai"):
                device.physical(part, "ai", where)  # raises -200220 / -200170 as the driver
                raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST, f"{where}: {part!r} does not exist")
            device.physical(part, "ai", where)
        return daq_error(
            PHYS_CHAN_MEAS_TYPE,
            f"{where}: the measurement type is not supported by the physical channel on the "
            f"simulated {device.spec.product} (it measures voltage and thermocouples)")
    if "Attribute" in rpc:
        return daq_error(ATTR_NOT_SUPPORTED,
                         f"{rpc} 0x{getattr(request, 'attribute_raw', 0):04X}: the attribute is "
                         "not supported by the simulated device")
    if rpc == "RegisterSignalEvent":
        return daq_error(SIGNAL_EVENTS_NOT_SUPPORTED,
                         f"signal events are not supported by the simulated {name}")
    if "RefTrig" in rpc or "StartTrig" in rpc:
        source = getattr(request, "trigger_source", "")
        return daq_error(INVALID_ROUTING_SOURCE,
                         f"{rpc}: trigger source {source!r} is not available on the simulated "
                         f"{name} (nothing is wired to its PFI lines)")
    return daq_error(DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION,
                     f"{rpc} is not supported by the simulated {device.spec.product}")


def _handler(rpc: str) -> Callable[..., Any]:
    @reports_daq_errors
    def refuse(self: Any, request: Any, context: Any) -> Any:
        raise refusal_for(self, rpc, request)

    refuse.__name__ = rpc
    return refuse


def install_refusals(cls: type) -> None:
    """Give ``cls`` a refusing handler for every NI-DAQmx RPC it does not define."""
    service = pb.DESCRIPTOR.services_by_name["NiDAQmx"]
    for method in service.methods:
        if getattr(cls, method.name) is getattr(pb_grpc.NiDAQmxServicer, method.name):
            setattr(cls, method.name, _handler(method.name))
